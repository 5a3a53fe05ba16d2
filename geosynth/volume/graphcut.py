"""Overlap-aware pasting for the scan-order block copying: a minimum-error cut through
the overlap (Kwatra et al. 2003, "Graphcut Textures").

When a matched source block B is pasted where the target already holds synthesized
samples A, each overlapping sample keeps A or takes B. The choice is a minimum s-t cut
on the 6-connected sample grid of the block: the edge between neighbours s and t costs
``|A(s) - B(s)| + |A(t) - B(t)| + 1`` when they end up on different sides (Kwatra's
seam cost, plus one so that among equally good seams the shortest wins). Samples not
yet synthesized must take B (tied to the source terminal); synthesized samples next to
a synthesized sample outside the block must keep A (tied to the sink), so the seam
stays inside the block. The max flow is
``scipy.sparse.csgraph.maximum_flow`` (Dinic, integer capacities, deterministic); the
B side is what the residual graph reaches from the source.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

__all__ = ["cut_cost", "min_cut"]

_INF = 1 << 30  # terminal ties: above any seam (at most 3 N^3 edges of cost <= 511: 50e6 at N = 32), within int32


def _edges(shape) -> tuple[np.ndarray, np.ndarray]:
    """(E,) pairs of flat indices of 6-neighbours in a (Z, Y, X) box."""
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    a, b = [], []
    for axis in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        a.append(idx[tuple(lo)].reshape(-1))
        b.append(idx[tuple(hi)].reshape(-1))
    return np.concatenate(a), np.concatenate(b)


def cut_cost(old: np.ndarray, new: np.ndarray, take_new: np.ndarray) -> int:
    """The seam cost of a labelling: the sum over 6-neighbour pairs labelled
    differently of ``|old - new|`` at both samples plus one."""
    diff = np.abs(old.astype(np.int64) - new.astype(np.int64)).reshape(-1)
    a, b = _edges(old.shape)
    lab = take_new.reshape(-1)
    cut = lab[a] != lab[b]
    return int((diff[a] + diff[b] + 1)[cut].sum())


def min_cut(old: np.ndarray, new: np.ndarray, must_new: np.ndarray, must_old: np.ndarray) -> np.ndarray:
    """Which samples of a block take the new values: a minimum-cost seam.

    Args:
        old: (Z, Y, X) uint8 values already in the target.
        new: (Z, Y, X) uint8 values of the matched source block.
        must_new: (Z, Y, X) bool: samples that must take ``new`` (not yet synthesized).
        must_old: (Z, Y, X) bool: samples that must keep ``old`` (next to synthesized
            samples outside the block); ``must_new`` wins where both are set.

    Returns:
        (Z, Y, X) bool, True where the sample takes ``new``; among the labellings that
        respect the ties it has the lowest :func:`cut_cost` (the cut reached from the
        new side, so the same on every run).
    """
    shape = old.shape
    n = int(np.prod(shape))
    must_new = must_new.reshape(-1)
    must_old = must_old.reshape(-1) & ~must_new
    if not must_old.any():
        return np.ones(shape, bool)
    if not must_new.any():
        return np.zeros(shape, bool)
    diff = np.abs(old.astype(np.int64) - new.astype(np.int64)).reshape(-1)
    a, b = _edges(shape)
    w = diff[a] + diff[b] + 1
    s, t = n, n + 1
    tied_new = np.flatnonzero(must_new)
    tied_old = np.flatnonzero(must_old)
    rows = np.concatenate([a, b, np.full(tied_new.size, s), tied_old])
    cols = np.concatenate([b, a, tied_new, np.full(tied_old.size, t)])
    caps = np.concatenate([w, w, np.full(tied_new.size + tied_old.size, _INF)]).astype(np.int32)
    graph = csr_matrix((caps, (rows, cols)), shape=(n + 2, n + 2))
    graph.sort_indices()
    flow = maximum_flow(graph, s, t, method="dinic").flow
    residual = (graph - flow).tocsr()
    residual.data[residual.data < 0] = 0
    residual.eliminate_zeros()
    reach = breadth_first_order(residual, s, directed=True, return_predecessors=False)
    take = np.zeros(n + 2, bool)
    take[reach] = True
    return take[:n].reshape(shape)


def must_keep(done: np.ndarray, origin, block, wrap: bool) -> np.ndarray:
    """(bz, by, bx) bool: synthesized samples of the block at ``origin`` that touch (6-
    neighbours) a synthesized sample outside it: the seam may not pass there.

    Args:
        done: (Z, Y, X) bool, the target's synthesized samples.
        origin: the block's (z, y, x) origin.
        block: N, or (bz, by, bx).
        wrap: the target is periodic (the neighbour across a face is on the other side).
    """
    from geosynth.volume.blocks import block_shape

    shape = done.shape
    sides = block_shape(block)
    axes = [np.arange(o, o + b) for o, b in zip(origin, sides)]
    inside = done[np.ix_(*[a % n for a, n in zip(axes, shape)])] if wrap else done[np.ix_(*axes)]
    keep = np.zeros(sides, bool)
    for axis in range(3):
        block = sides[axis]
        for side, face in ((-1, 0), (1, block - 1)):
            j = int(origin[axis]) + (block if side > 0 else -1)
            if not wrap and not 0 <= j < shape[axis]:
                continue
            if wrap and block >= shape[axis]:
                continue  # the block spans the axis: its neighbour is itself
            idx = list(axes)
            idx[axis] = np.array([j % shape[axis]])
            outside = done[np.ix_(*[a % n for a, n in zip(idx, shape)])]
            sl = [slice(None)] * 3
            sl[axis] = slice(face, face + 1)
            keep[tuple(sl)] |= outside & inside[tuple(sl)]
    return keep
