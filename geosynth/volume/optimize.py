"""Texture optimization of one synthesis level (Kwatra et al. 2005, "Texture
Optimization for Example-based Synthesis"), on uint8 distance-field codes.

The level's target x starts from an initialization (the upsampled coarser result, or
random source blocks at the coarsest level). Each iteration:

1. M-step: for every output block on a lattice of stride ``stride`` (the blocks
   overlap), the exact nearest source block z_p (the cascade search: lowest index on
   ties, the same block on every device);
2. E-step: every sample becomes the weighted mean of the matched source samples of
   the blocks covering it, with Kwatra's IRLS weights w_p = ||x_p - z_p||^(r - 2),
   r = 0.8 (a robust vote: a block that fits badly counts little), rounded to uint8.

It stops when fewer than ``tolerance`` of the blocks changed their match, when the
energy sum_p ||x_p - z_p||^r rises (the rounded, reweighted vote is not a strict
descent; the field before that vote is kept), or after ``iterations``. The vote runs in float64 on the host in a fixed order, so the same
matches give the same bits everywhere.
"""

from __future__ import annotations

import numpy as np

from geosynth.volume.blocks import block_shape
from geosynth.volume.cascade import tally_alive

__all__ = ["IRLS_R", "irls_weights", "lattice_positions", "memory_estimate", "optimize_level", "random_blocks", "vote"]

IRLS_R = 0.8  # Kwatra's robust exponent: E = sum_p ||x_p - z_p||^r
CHUNK = 1024  # queries copied and searched at a time
# Peak bytes per query sample of a chunk (the uint8 copies, the previous matches' blocks,
# their int32 differences and squares): 10.5 measured with tracemalloc (block 8, 96^2 x 18).
_QUERY_SAMPLE_BYTES = 11
# Per lattice block, alive through the level: its origin, its matched origin now and
# in the iteration before, SSD, match index now and before, IRLS weight (int64 /
# float64): ~100 measured (block 4 at stride 1, where blocks ~ samples).
_POSITION_BYTES = 104
# Per sample of the vote: two float64 accumulators, the covered mask, the uint8 result
# and the field before the vote (18.0 measured; no float64 temporaries since the
# quotient is taken in place).
_VOTE_SAMPLE_BYTES = 19
# Per sample more with given samples (``fixed``): the mask's copy, the given values and
# the feathering band's weights, nearest anchors and values (~21 B per band sample; the
# band is a block wide). The summed-volume table (int32) and the one-plane distance
# transform that find them are gone before the first vote.
_FIXED_SAMPLE_BYTES = 6
# Lattice stride = block / divisor: coarser levels are cheap and set the structure,
# so they get the denser lattice.
COARSE_DIVISOR = 4
FINEST_DIVISOR = 4
# Each block's vote falls off from its centre (a Gaussian, sigma in blocks): the
# samples a block's match explains best count most. Measured on the built-in balls
# and chainmail: elements 0.61 -> 0.79 and 0.31 -> 0.40 with sigma 0.3 against a flat
# vote; 0.2 at the coarser levels (which set the layout) lifts chainmail to 0.52 and
# fibers to 0.50, but lowers terrain's slopes score at the finest level, kept at 0.3.
FALLOFF_SIGMA = 0.2


FALLOFF_SIGMA_FINEST = 0.3


def level_sigma(finest: bool) -> float | None:
    """The falloff sigma of a level's votes (blocks): FALLOFF_SIGMA at the coarser levels,
    FALLOFF_SIGMA_FINEST at the finest."""
    return FALLOFF_SIGMA_FINEST if finest else FALLOFF_SIGMA


# The last vote of a level, "mean" or "max" (copy the heaviest patch per sample). "max"
# at the finest level measured: terrain slopes 0.80 -> 0.96 but small cracks and pits
# show and 4 surface pieces instead of 1; chainmail elements 0.49 -> 0.44. Off.
FINAL_VOTE = {"coarse": "mean", "finest": "mean"}


def level_final(finest: bool) -> str:
    """The last vote of a level: FINAL_VOTE's "mean" or "max"."""
    return FINAL_VOTE["finest" if finest else "coarse"]


def falloff(block, sigma: float | None = None) -> np.ndarray | None:
    """(bz, by, bx) Gaussian weights around the block centre (sigma in block sides, per
    axis; ``block`` N or (bz, by, bx)), or None."""
    sigma = FALLOFF_SIGMA if sigma is None else sigma
    if sigma is None:
        return None
    gz, gy, gx = (np.exp(-0.5 * ((np.arange(b) - (b - 1) / 2) / (sigma * b)) ** 2) for b in block_shape(block))
    return gz[:, None, None] * gy[None, :, None] * gx[None, None, :]


def level_stride(block: int, finest: bool) -> int:
    """The lattice stride of a level: block / 4 (block / FINEST_DIVISOR at the finest), >= 1."""
    return max(1, block // (FINEST_DIVISOR if finest else COARSE_DIVISOR))


def memory_estimate(shape, block, stride: int | None = None, wrap: bool = False, fixed: bool = False) -> int:
    """Peak bytes :func:`optimize_level` needs beyond its inputs for a (Z, Y, X) target
    and a block N or (bz, by, bx) (``stride`` None: the finest level's).

    What it counts (tracemalloc, tests/test_memory.py and tests/test_tiled_memory.py):
    _POSITION_BYTES per lattice block (alive throughout), plus the larger of the vote
    (_VOTE_SAMPLE_BYTES per sample, padded by a block when ``wrap``) and a chunk of at
    most CHUNK queries (_QUERY_SAMPLE_BYTES per query sample); with ``fixed`` (given
    samples) _FIXED_SAMPLE_BYTES per sample more and every lattice block counted (an
    upper bound: blocks of given samples only are skipped)."""
    bs = block_shape(block)
    n = int(np.prod([int(v) for v in shape]))
    padded = int(np.prod([int(v) + b for v, b in zip(shape, bs)])) if wrap else n
    stride = level_stride(bs[-1], True) if stride is None else int(stride)
    positions = int(np.prod([len(lattice_positions(int(v), b, stride, wrap)) for v, b in zip(shape, bs)]))
    chunk = min(CHUNK, positions) * int(np.prod(bs)) * _QUERY_SAMPLE_BYTES
    vote = _VOTE_SAMPLE_BYTES * padded + (padded if wrap else 0)  # + the padded copy of a periodic target
    return _POSITION_BYTES * positions + max(vote, chunk) + (_FIXED_SAMPLE_BYTES * n if fixed else 0)


def lattice_positions(size: int, block: int, stride: int, wrap: bool) -> list[int]:
    """Block origins along one axis: every ``stride`` from 0; without wrap the last
    block is aligned to the end (so every sample is covered), with wrap blocks run up
    to the end and cross it. A block that spans the axis (a slab's block along z) has
    the one origin 0, wrap or not."""
    stride = max(1, int(stride))
    if block >= size:
        return [0]
    if wrap:
        return list(range(0, size, stride))
    pos = list(range(0, size - block + 1, stride))
    if pos[-1] != size - block:
        pos.append(size - block)
    return pos


def _positions(shape, block, stride: int, wrap: bool) -> np.ndarray:
    axes = [lattice_positions(n, b, stride, wrap) for n, b in zip(shape, block_shape(block))]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    return grid.reshape(-1, 3).astype(np.int64)


def _padded(values: np.ndarray, block, wrap: bool) -> np.ndarray:
    return np.pad(values, [(0, b) for b in block_shape(block)], mode="wrap") if wrap else values


def _blocks(values: np.ndarray, positions: np.ndarray, block) -> np.ndarray:
    """(Q, bz, by, bx) copies of the blocks at ``positions`` (already within ``values``)."""
    bz, by, bx = block_shape(block)
    out = np.empty((len(positions), bz, by, bx), values.dtype)
    for i, (z, y, x) in enumerate(positions):
        out[i] = values[z:z + bz, y:y + by, x:x + bx]
    return out


class _SourceBlocks:
    """The source blocks at ``origins``, read one at a time (no (Q, N, N, N) copy)."""

    def __init__(self, source: np.ndarray, origins: np.ndarray, block):
        self.source, self.origins, self.block = source, origins, block_shape(block)
        self.shape = (len(origins), *self.block)

    def __len__(self) -> int:
        return len(self.origins)

    def __iter__(self):
        bz, by, bx = self.block
        for z, y, x in self.origins:
            yield self.source[z:z + bz, y:y + by, x:x + bx]


def irls_weights(ssd: np.ndarray, r: float = IRLS_R) -> np.ndarray:
    """Kwatra's IRLS weights ||x_p - z_p||^(r - 2) from the blocks' SSDs (float64);
    an SSD below 1 counts as 1 (a perfect match gets a large, finite weight)."""
    d2 = np.maximum(np.asarray(ssd, np.float64), 1.0)
    return d2 ** ((r - 2.0) / 2.0)


def vote(shape, positions: np.ndarray, patches: np.ndarray, weights: np.ndarray, wrap: bool,
         fallback: np.ndarray | None = None, falloff: np.ndarray | None = None, mode: str = "mean") -> np.ndarray:
    """The weighted mean per sample of the patches covering it, rounded to uint8.

    Args:
        shape: (Z, Y, X) of the output.
        positions: (Q, 3) block origins (with ``wrap``, blocks may cross the far faces).
        patches: (Q, bz, by, bx) uint8 matched source blocks.
        weights: (Q,) float weights.
        wrap: the output is periodic.
        fallback: values for samples no patch covers (None: every sample is covered).
        falloff: (bz, by, bx) float weights of a block's samples (None: all 1).
        mode: "mean" (the weighted mean) or "max" (each sample copies the patch of the
            largest weight there, the first one on ties: whole pieces, no blending).

    Returns:
        (Z, Y, X) uint8.
    """
    bz, by, bx = bs = tuple(patches.shape[1:4])
    pshape = tuple(n + b for n, b in zip(shape, bs)) if wrap else tuple(shape)
    g = np.ones(bs) if falloff is None else np.asarray(falloff, np.float64)
    if mode == "max":
        return _vote_max(shape, positions, patches, weights, wrap, g, fallback)
    acc = np.zeros(pshape, np.float64)
    wsum = np.zeros(pshape, np.float64)
    for (z, y, x), patch, w in zip(positions, patches, weights):
        acc[z:z + bz, y:y + by, x:x + bx] += (w * g) * patch
        wsum[z:z + bz, y:y + by, x:x + bx] += w * g
    if wrap:  # fold the overhang back onto the opposite faces
        for axis, n in enumerate(shape):
            block = bs[axis]
            for a in (acc, wsum):
                head = [slice(None)] * 3
                tail = [slice(None)] * 3
                head[axis], tail[axis] = slice(0, block), slice(n, n + block)
                a[tuple(head)] += a[tuple(tail)]
        acc, wsum = acc[:shape[0], :shape[1], :shape[2]], wsum[:shape[0], :shape[1], :shape[2]]
    covered = wsum > 0
    # in place on acc (no float64 temporaries of the field; the same quotients): a sample
    # no patch covers has acc 0 and stays 0
    np.divide(acc, wsum, out=acc, where=covered)
    acc += 0.5
    np.floor(acc, out=acc)
    np.clip(acc, 0, 255, out=acc)
    result = acc.astype(np.uint8)
    if fallback is not None:
        result[~covered] = fallback[~covered]
    return result


def _vote_max(shape, positions, patches, weights, wrap, g, fallback):
    bz, by, bx = bs = tuple(patches.shape[1:4])
    pshape = tuple(n + b for n, b in zip(shape, bs)) if wrap else tuple(shape)
    best = np.full(pshape, -1.0)
    value = np.zeros(pshape, np.uint8)
    for (z, y, x), patch, w in zip(positions, patches, weights):
        sl = (slice(z, z + bz), slice(y, y + by), slice(x, x + bx))
        wg = w * g
        better = wg > best[sl]
        best[sl] = np.where(better, wg, best[sl])
        value[sl] = np.where(better, patch, value[sl])
    if wrap:  # fold: the overhang's sample wins where its weight is larger (ties: the face's)
        for axis, n in enumerate(shape):
            block = bs[axis]
            head = [slice(None)] * 3
            tail = [slice(None)] * 3
            head[axis], tail[axis] = slice(0, block), slice(n, n + block)
            h, t = tuple(head), tuple(tail)
            better = best[t] > best[h]
            best[h] = np.where(better, best[t], best[h])
            value[h] = np.where(better, value[t], value[h])
        best, value = best[:shape[0], :shape[1], :shape[2]], value[:shape[0], :shape[1], :shape[2]]
    out = value.copy()
    if fallback is not None:
        out[best < 0] = fallback[best < 0]
    return out


def random_blocks(source: np.ndarray, shape, block, rng: np.random.Generator, wrap: bool) -> np.ndarray:
    """An initial target of random source blocks (uint8, ``shape``; ``block`` N or
    (bz, by, bx)), tiled edge to edge (the last block aligned to the end)."""
    bz, by, bx = bs = block_shape(block)
    axes = [lattice_positions(n, b, b, wrap) for n, b in zip(shape, bs)]
    pos = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    last = np.array(source.shape) - np.array(bs)
    out = np.zeros(tuple(n + b for n, b in zip(shape, bs)) if wrap else tuple(shape), np.uint8)
    for z, y, x in pos:
        o = [int(rng.integers(n + 1)) for n in last]
        out[z:z + bz, y:y + by, x:x + bx] = source[o[0]:o[0] + bz, o[1]:o[1] + by, o[2]:o[2] + bx]
    return np.ascontiguousarray(out[:shape[0], :shape[1], :shape[2]])


def _nearest_batch(search, queries: np.ndarray, thresholds):
    if hasattr(search, "nearest_batch"):
        return search.nearest_batch(queries, thresholds)
    origins = np.empty((len(queries), 3), np.int64)
    ssds = np.empty(len(queries), np.int64)
    for i, q in enumerate(queries):
        o, d = search.nearest(q, threshold=None if thresholds is None else int(thresholds[i]))
        origins[i], ssds[i] = o, d
    return origins, ssds, []


def _free_positions(target: np.ndarray, positions: np.ndarray, block: tuple[int, int, int], wrap: bool,
                     fixed) -> tuple:
    """The lattice blocks covering at least one free (not ``fixed``) sample, and
    (mask, values, feathering) of the fixed samples to restore after each vote."""
    mask = np.asarray(fixed)
    if mask.shape != target.shape or mask.dtype != np.bool_:
        raise ValueError(f"fixed must be a bool mask of the target's shape {target.shape}, got "
                         f"{mask.dtype} {mask.shape}.")
    free = _padded(~mask, block, wrap)
    count_type = np.int32 if free.size < 2**31 else np.int64  # the counts fit: half the table of int64
    table = np.zeros(tuple(n + 1 for n in free.shape), count_type)  # summed-volume table of free samples
    inner = table[1:, 1:, 1:]
    np.cumsum(free, axis=0, dtype=count_type, out=inner)  # in place: no temporary tables
    np.cumsum(inner, axis=1, out=inner)
    np.cumsum(inner, axis=2, out=inner)
    padded_shape = free.shape
    del free, inner
    z, y, x = positions.T
    bz, by, bx = block
    count = (table[z + bz, y + by, x + bx] - table[z, y + by, x + bx] - table[z + bz, y, x + bx]
             - table[z + bz, y + by, x] + table[z, y, x + bx] + table[z, y + by, x] + table[z + bz, y, x]
             - table[z, y, x])
    positions = positions[count > 0]
    # The free samples near the given ones take a share of the given samples' residual
    # (given value - vote there), falling off linearly over a block: a hard constraint
    # otherwise leaves a step of the size of the match error where the two meet.
    covered = np.zeros(padded_shape, bool)
    for z0, y0, x0 in positions:
        covered[z0:z0 + bz, y0:y0 + by, x0:x0 + bx] = True
    if wrap:
        covered = _fold_any(covered, target.shape, block)
    anchors = mask & covered
    del covered
    feather = None
    if anchors.any():
        feather = _feather(target, mask, anchors, max(block[1:]))
    return positions, (mask.copy(), target[mask].copy(), feather)


def _feather(target: np.ndarray, mask: np.ndarray, anchors: np.ndarray, reach: int) -> tuple:
    """(near, weight, nearest anchor, given value there) of the free samples within
    ``reach`` samples of an anchor (a given sample in a free block): weight = 1 -
    distance / reach, the nearest anchor by the exact Euclidean distance transform.

    A mask the same in every z plane (a tile's given columns, every sample of a margin)
    takes the transform of one plane (its nearest anchors lie in the same plane): the
    3D transform's index arrays and float64 distances cost ~60 B per sample."""
    from scipy import ndimage

    columns = bool((anchors == anchors[:1]).all() and (mask == mask[:1]).all())
    if columns:
        dist, nearest = ndimage.distance_transform_edt(~anchors[0], return_indices=True)
    else:
        dist, nearest = ndimage.distance_transform_edt(~anchors, return_indices=True)
    # weight = clip(1 - dist / reach, 0, 1) on the free samples (in place on dist)
    dist /= reach
    np.subtract(1.0, dist, out=dist)
    np.clip(dist, 0.0, 1.0, out=dist)
    dist[mask[0] if columns else mask] = 0.0
    near = dist > 0
    if columns:
        z = target.shape[0]
        count = int(near.sum())
        weight = np.tile(dist[near], z)
        picked = tuple(np.tile(i[near], z) for i in nearest)
        nearest = (np.repeat(np.arange(z, dtype=picked[0].dtype), count),) + picked
        near = np.broadcast_to(near, target.shape)
    else:
        weight = dist[near]
        nearest = tuple(i[near] for i in nearest)
    # the given values at each near sample's anchor (given samples keep their values: fixed for the run)
    return near, weight, nearest, target[nearest]


def _fold_any(values: np.ndarray, shape, block: tuple[int, int, int]) -> np.ndarray:
    """A padded periodic bool field folded back onto ``shape`` (or over the faces)."""
    out = values.copy()
    for axis, n in enumerate(shape):
        head = [slice(None)] * 3
        tail = [slice(None)] * 3
        head[axis], tail[axis] = slice(0, block[axis]), slice(n, n + block[axis])
        out[tuple(head)] |= out[tuple(tail)]
    return out[:shape[0], :shape[1], :shape[2]]


def _restore(target: np.ndarray, given) -> None:
    """Put the given samples back after a vote, feathering their residual into their free neighbours."""
    mask, values, feather = given
    if feather is not None:
        near, weight, nearest, given_there = feather
        # the residual (given - voted) at each near sample's anchor, without a field of it
        moved = target[near] + weight * (given_there.astype(np.float64) - target[nearest])
        target[near] = np.clip(np.floor(moved + 0.5), 0, 255).astype(np.uint8)
    target[mask] = values


def optimize_level(source: np.ndarray, target: np.ndarray, block: int, search, *, stride: int | None = None,
                   wrap: bool = False, iterations: int = 8, tolerance: float = 0.01, r: float | None = None,
                   progress=None, sigma: float | None = None, final: str = "mean",
                   fixed: np.ndarray | None = None) -> dict:
    """Texture optimization of one level, in place on ``target``.

    Args:
        source: (Z, Y, X) uint8 source of this level.
        target: (Z, Y, X) uint8 initialization; overwritten with the result.
        block: block size N, or an anisotropic block (bz, by, bx).
        search: an object with ``nearest_batch(queries, thresholds)`` returning
            ((Q, 3) origins, (Q,) SSDs, alive) -- :class:`geosynth.volume.cascade.CascadeSearch`
            -- or with ``nearest(query, threshold=)`` returning (origin, SSD).
        stride: lattice stride (default N/4, at least 1).
        wrap: periodic target.
        iterations: the most iterations.
        tolerance: stop once the share of blocks whose match changed is below it.
        r: the robust exponent of the IRLS weights (None: IRLS_R, 0.8).
        progress: a callable taking the iteration's number of matches, or None.
        sigma: the falloff of each block's vote, in blocks (None: FALLOFF_SIGMA).
        final: "mean", or "max": the last vote again with each sample copied from the
            one patch of largest weight (sharp, unblended pieces).
        fixed: (Z, Y, X) bool, or None: samples that are given (constrained synthesis,
            e.g. a neighbouring tile's finished border): they enter the queries of the
            blocks that cover them and those blocks' votes for the other samples, but
            keep their values; lattice blocks made only of fixed samples are skipped.

    Returns:
        {"iterations": int, "matches": int (block searches made), "changed": [share of
        blocks whose match changed, per iteration; the first is 1.0], "mean_distance":
        mean SSD / N^3 of the last iteration's matches (squared uint8 units), "alive":
        the cascade's mean blocks alive after each stage over the matches (a stage a
        match did not reach counts 0; empty for other searches), "energy": Kwatra's
        energy per iteration, "stopped": "matches settled", "energy rose" or
        "iteration cap"}.
    """
    shape = target.shape
    block = block_shape(block)
    r = IRLS_R if r is None else float(r)
    stride = max(1, block[-1] // 4) if stride is None else int(stride)
    positions = _positions(shape, block, stride, wrap)
    given = None
    if fixed is not None:
        positions, given = _free_positions(target, positions, block, wrap, fixed)
        if len(positions) == 0:  # nothing free: the target is the given samples
            return {"iterations": 0, "matches": 0, "changed": [], "mean_distance": 0.0, "alive": [],
                    "energy": [], "stopped": "all fixed"}
    sz, sy, sx = (n - b + 1 for n, b in zip(source.shape, block))
    prev = prev_index = None
    changed: list[float] = []
    matches = 0
    alive_sums: list[int] = []  # per stage, summed over the matches (no per-match lists: see tally_alive)
    alive_matches = 0
    mean = 0.0
    energy = []
    before = None
    stopped = "iteration cap"
    for _ in range(max(1, int(iterations))):
        padded = _padded(target, block, wrap)
        origins = np.empty((len(positions), 3), np.int64)
        ssds = np.empty(len(positions), np.int64)
        for lo in range(0, len(positions), CHUNK):  # chunks bound the memory of the query copies
            hi = min(lo + CHUNK, len(positions))
            queries = _blocks(padded, positions[lo:hi], block)
            thresholds = None
            if prev is not None:
                # the previous match's SSD bounds the best: the search drops blocks that cannot win
                diff = _blocks(source, prev[lo:hi], block).astype(np.int32) - queries
                thresholds = (diff * diff).reshape(hi - lo, -1).sum(axis=1)
            origins[lo:hi], ssds[lo:hi], info = _nearest_batch(search, queries, thresholds)
            alive_matches += tally_alive(alive_sums, info)
        matches += len(positions)
        energy.append(float((np.maximum(ssds, 1.0) ** (r / 2)).sum()))  # Kwatra's E = sum ||x_p - z_p||^r
        index = (origins[:, 0] * sy + origins[:, 1]) * sx + origins[:, 2]
        share = 1.0 if prev is None else float(np.mean(index != prev_index))
        changed.append(share)
        if share >= tolerance and len(energy) > 1 and energy[-1] > energy[-2]:
            # the rounded, reweighted vote raised the energy: keep the field before it
            target[...] = before
            stopped = "energy rose"
            break
        prev, prev_index = origins, index
        before = target.copy()
        target[...] = vote(shape, positions, _SourceBlocks(source, origins, block), irls_weights(ssds, r), wrap,
                           falloff=falloff(block, sigma))
        if given is not None:
            _restore(target, given)
        voted = (origins, ssds)
        mean = float(ssds.mean()) / int(np.prod(block))
        if progress is not None:
            progress(len(positions))
        if share < tolerance:
            stopped = "matches settled"
            break
    if final == "max":
        origins, ssds = voted
        target[...] = vote(shape, positions, _SourceBlocks(source, origins, block), irls_weights(ssds, r), wrap,
                           falloff=falloff(block, sigma), mode="max")
        if given is not None:
            _restore(target, given)
    return {"iterations": len(changed), "matches": matches, "changed": changed, "mean_distance": mean,
            "alive": [v / alive_matches for v in alive_sums] if alive_matches else [], "energy": energy,
            "stopped": stopped}
