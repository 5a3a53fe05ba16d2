"""Which source block is nearest to a query, by the paper's search tree?

Implements M1's geometry matching of Lagae, Dumont and Dutré, "Geometry Synthesis",
Sec. 4.1 (search tree construction), 4.2 (block similarity, eqs. 2 and 3), 4.3 (the
best-first matching algorithm) and 4.4 (branching factor: parent nodes).

:class:`BlockSearch` builds, once per source field and block size, the global pyramid
(:mod:`geosynth.volume.pyramid`) and a search tree over every block of the source, keeps
both on the device, and answers nearest-block queries:

- :meth:`BlockSearch.nearest`: exact best-first search (A*-like, eq. 2 as the
  bound). It returns exactly what a linear search returns: the block of smallest
  SSD, the lowest block index on ties (index = raster order of block origins, z
  slowest, as :func:`geosynth.compute.scoring.candidate_origins` enumerates them).
- :meth:`BlockSearch.nearest_linear`: the baseline, every block scored through
  :func:`geosynth.compute.scoring.score_gather` and reduced by :func:`geosynth.compute.selection.argmin`.
- ``nearest(query, prune_eps=eps)``: the paper's queue pruning with eq. 3, opt-in
  and APPROXIMATE (eq. 3 holds only for valid distance fields, not for synthesis
  queries with random samples); :meth:`BlockSearch.pruned_disagreement` measures how
  often it differs from the exact answer.

The tree (paper Fig. 3)
-----------------------
Stages, coarse to fine, for levels l = 1 .. L (L = log2(N) + 1, level L = the block):

- ``E_l`` (exact nodes, Fig. 3b): blocks grouped by identical exact cell sums of
  level l. Exact sums of level l determine those of every coarser level, so the
  groups nest; identical full blocks share one leaf ``E_L``, which references the
  lowest-index block among them.
- ``P_l`` (parent nodes, Fig. 3c, for l < L): the children of an ``E_{l-1}`` node
  (or of the root) that are *partially identical*, i.e. whose level-l means agree
  once rounded to uint8 (the paper's 256-value quantization: at most 256 of them
  under the root), are grouped under one parent. A parent's bound is computed from
  the rounded means alone, as the distance of each query cell sum to the interval
  of exact sums that round to that mean: weaker than its children's exact bounds
  but still a lower bound of every block below it (evaluated "incrementally": the
  child's exact bound is computed when the parent is expanded).
- Chains are compressed: a node with a single child is replaced by that child (its
  bound is at least as tight, so nothing is lost), which is why the tree reports
  fewer nodes per level than there are groups.

Nodes store no level contents: each references its lowest-index block (a flat
origin into the global pyramid) plus a level and a kind; children are CSR lists.
Groups are proposed by 64-bit polynomial hashes of the level contents computed by
kernels (built by doubling, O(log n) per position) and every merge is then verified
exactly by a kernel; a hash collision only splits a group again, never merges
different contents.

The bound and exactness
-----------------------
A node's priority is an integer key = 4 * N^3 * (a lower bound of the full SSD of
every block below it): exact nodes use Cauchy-Schwarz on exact cell sums
(D_l / c^3, see :mod:`geosynth.volume.pyramid`), parent nodes the rounded-interval form,
leaves the exact SSD (key = 4 N^3 SSD). A child's key is raised to its parent's key
when lower (still a valid bound). Entries are ordered by (key, lowest block index
below the node), so the first leaf popped has the smallest SSD and, among equal
SSDs, the lowest index: exactly the linear search's answer. Expanding extra nodes
never changes that answer, so several queue fronts may be expanded in one batched
kernel launch (``batch``).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from geosynth.compute.scoring import score_gather
from geosynth.compute.selection import argmin
from geosynth.core.arrays import DeviceArray
from geosynth.volume.blocks import block_offsets, block_origins
from geosynth.volume.pyramid import (
    BlockPyramid,
    build_pyramid,
    check_block,
    check_field,
    check_memory,
    check_query,
    pyramid_bytes,
    query_arrays,
)

__all__ = ["BlockSearch", "TreeStats"]

# Odd 64-bit multipliers of the polynomial hash, one per axis (x, y, z).
_HASH_MULT = (0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9)
_MASK64 = (1 << 64) - 1
# Tests narrow the hashes to force collisions (the exact verification must split them).
HASH_MASK = _MASK64
# Queue fronts expanded per kernel launch (exactness does not depend on it). By default
# it adapts: 1 for the first launches (easy queries end after a few expansions), then
# doubling every 2 launches up to MAX_BATCH (hard queries, e.g. with random samples,
# expand thousands of nodes and are bound by the per-launch overhead).
DEFAULT_BATCH = 4  # sizes the staging buffers; larger batches grow them
MAX_BATCH = 512


@dataclass
class TreeStats:
    """Size of a search tree; ``str()`` gives a readable summary."""

    blocks: int
    leaves: int
    nodes: int
    exact_per_level: list[int]
    parents_per_level: list[int]
    groups_per_stage: list[tuple[str, int]]
    root_children: int
    mean_branching: float
    max_branching: int
    tree_bytes: int
    build_seconds: float

    def as_dict(self) -> dict:
        return dict(self.__dict__)

    def __str__(self) -> str:
        lines = [
            f"{self.blocks} blocks, {self.leaves} leaves (distinct blocks), {self.nodes} nodes, "
            f"root children {self.root_children}, mean branching {self.mean_branching:.2f}, "
            f"max {self.max_branching}, {self.tree_bytes / 2**20:.1f} MiB, built in {self.build_seconds:.2f} s",
        ]
        for lev, (e, p) in enumerate(zip(self.exact_per_level, self.parents_per_level), start=1):
            lines.append(f"  level {lev}: {e} exact nodes, {p} parent nodes")
        lines.append("  groups before chain compression: " + ", ".join(f"{k}={v}" for k, v in self.groups_per_stage))
        return "\n".join(lines)


def _group(parent: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group blocks by (parent group, hash); groups numbered by lowest block index.

    Returns:
        (B,) int64 group of each block, (G,) int64 lowest block index of each group.
    """
    b = parent.size
    order = np.lexsort((np.arange(b), h, parent))
    ps, hs = parent[order], h[order]
    new = np.empty(b, bool)
    new[0] = True
    new[1:] = (ps[1:] != ps[:-1]) | (hs[1:] != hs[:-1])
    gid_sorted = np.cumsum(new) - 1
    reps = order[new]  # the first of each run has the lowest index (index is the last sort key)
    group = np.empty(b, np.int64)
    group[order] = gid_sorted
    return _renumber(group, reps)


def _renumber(group: np.ndarray, reps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Renumber groups by ascending representative (canonical, hash-independent)."""
    rank = np.empty(reps.size, np.int64)
    order = np.argsort(reps, kind="stable")
    rank[order] = np.arange(reps.size)
    return rank[group], reps[order]


class BlockSearch:
    """Nearest-block search in one quantized source field, for one block size.

    Args:
        field: (Z, Y, X) uint8 source (a quantized distance field).
        block: the block size N, a power of two <= every side of ``field``.
        device: a device string (see :mod:`geosynth.compute.backend`); None means ``"auto"``.
        parents: introduce the parent nodes of Fig. 3c (default True).
        compress: replace single-child nodes by their child (default True); False keeps
            every level of every chain (more, cheaper intermediate bounds).

    Attributes:
        field: the host copy of the source.
        block, levels: N and L = log2(N) + 1.
        pyramid: the global pyramid on the device.
        n_blocks: number of blocks (candidates).

    Raises:
        TypeError: field not uint8, block not an integer.
        ValueError: field not 3-D, block not a power of two or larger than the field.
        MemoryError: the memory estimate exceeds what is available (before allocating).

    Example:
        >>> import numpy as np
        >>> f = np.random.default_rng(0).integers(0, 256, (12, 12, 12), dtype=np.uint8)
        >>> s = BlockSearch(f, 4, device="cpu")
        >>> s.nearest(f[3:7, 2:6, 5:9])
        ((3, 2, 5), 0)
    """

    def __init__(self, field: np.ndarray, block: int, *, device: str | None = None, parents: bool = True,
                 compress: bool = True):
        import time

        t0 = time.perf_counter()
        field = check_field(field)
        log_block = check_block(block, field.shape)
        self.field = field
        self.block = int(block)
        self.levels = log_block + 1
        self.lattice = tuple(int(s) - self.block + 1 for s in field.shape)
        self.n_blocks = int(np.prod(self.lattice))
        n_stages = 2 * self.levels - 1 if parents else self.levels
        check_memory(self.memory_estimate(field.shape, self.block, parents), f"the search tree of a {field.shape} field (block {block})")
        self.pyramid: BlockPyramid = build_pyramid(field, self.block, device=device)
        self.backend = self.pyramid.backend
        self._offsets = block_offsets(self.block)
        self._compress = bool(compress)
        self._build_tree(parents, n_stages)
        self._build_seconds = time.perf_counter() - t0
        self.last_info: dict = {}

    # -- sizes -------------------------------------------------------------------------
    @staticmethod
    def memory_estimate(shape, block: int, parents: bool = True) -> int:
        """Bytes the build needs at its peak (device + host), for the refusal check."""
        total = int(np.prod(shape))
        levels = int(block).bit_length()
        n_blocks = int(np.prod([max(0, int(s) - block + 1) for s in shape]))
        stages = 2 * levels - 1 if parents else levels
        # pyramid + field; two hash buffers and one host copy; per block: group ids and
        # reps per stage, hashes, sort temporaries; nodes (at most one per block and stage).
        return pyramid_bytes(tuple(shape), int(block)) + total + 24 * total + n_blocks * (stages * 24 + 80)

    # -- indices -----------------------------------------------------------------------
    def block_origins(self) -> np.ndarray:
        """(B, 3) int64 origins of every block, in block-index order."""
        return block_origins(self.field.shape, self.block)

    def origin_of(self, index: int) -> tuple[int, int, int]:
        """Origin (z, y, x) of block ``index``."""
        z, y, x = np.unravel_index(int(index), self.lattice)
        return int(z), int(y), int(x)

    def index_of(self, origin) -> int:
        """Block index of an origin (z, y, x)."""
        return int(np.ravel_multi_index(tuple(int(v) for v in origin), self.lattice))

    # -- tree construction -------------------------------------------------------------
    def _stage_hash(self, level: int, quantized: bool, buf_a: DeviceArray, buf_b: DeviceArray, lattice_idx: np.ndarray) -> np.ndarray:
        """(B,) uint64 hash of every block's level content (exact sums or rounded means)."""
        be, pyr = self.backend, self.pyramid
        total = pyr.total
        _, ny, nx = self.field.shape
        n = 1 << (level - 1)
        lc = self.levels - level
        c = 1 << lc
        be.pyramid_hash_init(pyr.sums, lc * total, lc, int(quantized), total, buf_a)
        src, dst = buf_a, buf_b
        for axis_stride, mult in zip((1, nx, ny * nx), _HASH_MULT):
            w = 1
            while w < n:
                be.pyramid_hash_step(src, dst, total, w * c * axis_stride, pow(mult, w, 1 << 64))
                src, dst = dst, src
                w *= 2
        # sync: the hashes of every position come back for the host-side grouping.
        return be.pyramid_read_all(src)[lattice_idx] & np.uint64(HASH_MASK)

    def _verify(self, level: int, quantized: bool, group: np.ndarray, reps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Check every merge exactly; split any group that a hash collision formed."""
        be, pyr = self.backend, self.pyramid
        sizes = np.bincount(group, minlength=reps.size)
        members = np.flatnonzero(sizes[group] >= 2)
        members = members[members != reps[group[members]]]
        if members.size == 0:
            return group, reps
        _, ny, nx = self.field.shape
        n = 1 << (level - 1)
        lc = self.levels - level
        base_a = be.to_device(self._base[members].astype(np.int32))
        base_b = be.to_device(self._base[reps[group[members]]].astype(np.int32))
        flags = be.empty((members.size,), np.int32)
        be.pyramid_pair_equal(pyr.sums, pyr.total, ny, nx, lc, n, int(quantized), base_a, base_b, members.size, flags)
        # sync: the verdicts decide whether any group must be split.
        ok = be.pyramid_read(flags, members.size).astype(bool)
        if ok.all():
            return group, reps
        # A collision: regroup the affected groups by their actual contents (rare, slow, exact).
        bad_groups = np.unique(group[members[~ok]])
        c = 1 << lc
        slab = pyr.cell_sums(c)
        if quantized:
            sh = 3 * lc
            slab = (slab + np.uint32((1 << sh) >> 1)) >> np.uint32(sh)
        origins = self.block_origins()
        ax = c * np.arange(n)
        group = group.copy()
        next_id = reps.size
        for g in bad_groups:
            blocks = np.flatnonzero(group == g)
            o = origins[blocks]
            content = slab[
                o[:, 0, None, None, None] + ax[None, :, None, None],
                o[:, 1, None, None, None] + ax[None, None, :, None],
                o[:, 2, None, None, None] + ax[None, None, None, :],
            ].reshape(blocks.size, -1)
            _, sub = np.unique(content, axis=0, return_inverse=True)
            sub = sub.reshape(-1)
            # the subgroup holding the lowest index keeps the id g; others get new ids
            keep = sub[0]
            for s in np.unique(sub):
                if s != keep:
                    group[blocks[sub == s]] = next_id
                    next_id += 1
        new_reps = np.full(next_id, np.iinfo(np.int64).max, np.int64)
        np.minimum.at(new_reps, group, np.arange(group.size))
        return _renumber(group, new_reps)

    def _build_tree(self, parents: bool, n_stages: int) -> None:
        be = self.backend
        nz, ny, nx = self.field.shape
        origins = self.block_origins()
        self._base = origins @ np.array([ny * nx, nx, 1], np.int64)  # flat origin of every block
        b = self.n_blocks
        stages: list[tuple[int, int]] = []  # (level, kind): kind 1 = parent node, 0 = exact
        for lev in range(1, self.levels + 1):
            if parents and lev < self.levels:
                stages.append((lev, 1))
            stages.append((lev, 0))
        assert len(stages) == n_stages

        buf_a = be.pyramid_empty((self.pyramid.total,), np.uint64)
        buf_b = be.pyramid_empty((self.pyramid.total,), np.uint64)
        groups, reps = [], []
        prev = np.zeros(b, np.int64)
        for lev, kind in stages:
            h = self._stage_hash(lev, bool(kind), buf_a, buf_b, self._base)
            g, r = _group(prev, h)
            g, r = self._verify(lev, bool(kind), g, r)
            groups.append(g)
            reps.append(r)
            prev = g
        del buf_a, buf_b

        # Child counts per group; a group with one child is compressed into it.
        kept, node_of = [], []
        offset = 0
        for s in range(n_stages):
            if s == n_stages - 1:
                k = np.ones(reps[s].size, bool)
            else:
                parent_of_next = groups[s][reps[s + 1]]
                k = np.bincount(parent_of_next, minlength=reps[s].size) >= (2 if self._compress else 1)
            ids = np.full(reps[s].size, -1, np.int64)
            ids[k] = offset + np.arange(int(k.sum()))
            offset += int(k.sum())
            kept.append(k)
            node_of.append(ids)
        m = offset
        node_parent = np.empty(m, np.int64)
        node_rep = np.empty(m, np.int64)
        node_level = np.empty(m, np.int32)
        node_kind = np.empty(m, np.int32)
        anc = np.full(b, m, np.int64)  # nearest kept ancestor of each block; m = the root
        for s, (lev, kind) in enumerate(stages):
            ks = np.flatnonzero(kept[s])
            ids = node_of[s][ks]
            node_parent[ids] = anc[reps[s][ks]]
            node_rep[ids] = reps[s][ks]
            node_level[ids] = lev
            node_kind[ids] = kind
            here = node_of[s][groups[s]]
            anc = np.where(here >= 0, here, anc)
        self.leaf_of_block = node_of[-1][groups[-1]]

        order = np.lexsort((node_rep, node_parent))  # children of a node: contiguous, by lowest index
        counts = np.bincount(node_parent, minlength=m + 1)
        self._child_ptr = np.zeros(m + 2, np.int64)
        self._child_ptr[1:] = np.cumsum(counts)
        self._child_list = order.astype(np.int32)  # node ids; the root's children are listed under m
        self._node_rep = node_rep
        self._node_parent = node_parent
        self._node_level = node_level
        self._node_kind = node_kind
        self._is_leaf = node_level == self.levels
        # key = D << shift: 4 * N^3 * (D / c^3) = D * 4 * n^3
        self._shift = (2 + 3 * (node_level.astype(np.int64) - 1))
        self.n_nodes = m
        self._root = m

        self._dev_base = be.to_device(self._base[node_rep].astype(np.int32))
        self._dev_code = be.to_device((node_level * 2 + node_kind).astype(np.int32))
        self._dev_children = be.to_device(self._child_list)
        cap = int(counts.max()) * DEFAULT_BATCH if m else 1
        self._cap = max(cap, 1)
        self._dev_ids = be.pyramid_empty((self._cap,), np.int32)
        self._dev_out = be.pyramid_empty((self._cap,), np.int64)

        internal = int((counts > 0).sum())
        self._stats_parts = dict(
            blocks=b,
            leaves=int(self._is_leaf.sum()),
            nodes=m,
            exact_per_level=[int(((node_level == lev) & (node_kind == 0)).sum()) for lev in range(1, self.levels + 1)],
            parents_per_level=[int(((node_level == lev) & (node_kind == 1)).sum()) for lev in range(1, self.levels + 1)],
            groups_per_stage=[(f"{'P' if k else 'E'}{lev}", int(r.size)) for (lev, k), r in zip(stages, reps)],
            root_children=int(counts[m]),
            mean_branching=m / max(internal, 1),
            max_branching=int(counts.max()) if m else 0,
            tree_bytes=int(m * (4 + 4 + 4 + 8 + 8 + 4 + 4 + 8) + self._child_ptr.nbytes),
        )

    def stats(self) -> TreeStats:
        """Tree size: nodes per level (exact and parent nodes), leaves, branching factor.

        ``mean_branching`` = edges / internal nodes (the root included).
        """
        return TreeStats(**self._stats_parts, build_seconds=self._build_seconds)

    def children(self, node: int | None = None) -> np.ndarray:
        """Node ids of the children of ``node`` (None: the root)."""
        a = self._root if node is None else int(node)
        return self._child_list[self._child_ptr[a]:self._child_ptr[a + 1]].astype(np.int64)

    # -- searches ----------------------------------------------------------------------
    def _evaluate(self, nodes: list[int], q, qoff) -> tuple[np.ndarray, np.ndarray]:
        """Children of ``nodes`` and their integer D, in one kernel launch."""
        be = self.backend
        _, ny, nx = self.field.shape
        if len(nodes) == 1:
            a = nodes[0]
            first, end = int(self._child_ptr[a]), int(self._child_ptr[a + 1])
            ids = self._child_list[first:end]
            ids_dev, count = self._dev_children, end - first
        else:
            ids = np.concatenate([self._child_list[self._child_ptr[a]:self._child_ptr[a + 1]] for a in nodes])
            first, count = 0, ids.size
            be.pyramid_write(self._dev_ids, ids)
            ids_dev = self._dev_ids
        be.pyramid_compare(
            self.pyramid.sums, self.pyramid.total, ny, nx, self.levels - 1,
            self._dev_base, self._dev_code, ids_dev, first, count, q, qoff, self._dev_out,
        )
        return ids, be.pyramid_read(self._dev_out, count)

    def nearest(self, query: np.ndarray, *, prune_eps: float | None = None, batch: int | None = None) -> tuple[tuple[int, int, int], int]:
        """The source block nearest to ``query`` (smallest SSD; lowest index on ties).

        Exact best-first search over the tree; the same answer as
        :meth:`nearest_linear`, always. With ``prune_eps`` the queue is pruned with
        eq. 3 (paper 4.3): a node whose bound exceeds the smallest upper bound
        ``N^3 * (dist_l + (L - l) * eps)`` of an exact node is dropped. That is
        APPROXIMATE: eq. 3 holds for valid distance fields with eps the squared
        largest difference of neighbouring samples, not for queries with random
        samples; if the queue runs dry, the dropped entries come back and the search
        finishes exactly.

        Args:
            query: (N, N, N) uint8 block; any values (random samples included).
            prune_eps: None (exact) or eps >= 0, in squared uint8 units per sample.
            batch: queue fronts expanded per kernel launch (>= 1; speed only);
                None adapts it (see ``MAX_BATCH``).

        Returns:
            (origin (z, y, x), ssd): the block's origin and its exact integer SSD.
            ``self.last_info`` holds the expansions, launches and nodes evaluated.

        Raises:
            TypeError: query not uint8. ValueError: wrong shape, bad prune_eps or batch.
        """
        query = check_query(query, self.block)
        if prune_eps is not None and not (isinstance(prune_eps, (int, float, np.integer, np.floating))
                                          and math.isfinite(prune_eps) and prune_eps >= 0):
            raise ValueError(f"prune_eps must be None or a finite number >= 0, got {prune_eps!r}.")
        if batch is not None and (isinstance(batch, bool) or not isinstance(batch, (int, np.integer))
                                  or not 1 <= batch <= 4096):
            raise ValueError(f"batch must be None or an integer in [1, 4096], got {batch!r}.")
        self._grow(MAX_BATCH if batch is None else int(batch))
        q, qoff = query_arrays(self.backend, query, self.block)
        n3 = self.block ** 3
        levels = self.levels
        is_leaf = self._is_leaf
        shift = self._shift
        rep = self._node_rep
        kind = self._node_kind
        lev = self._node_level
        prune = prune_eps is not None
        if prune:
            slack = [int(math.ceil(4 * n3 * n3 * (levels - lv) * float(prune_eps))) for lv in range(levels + 1)]
        upper = None  # best upper key (pruned mode)
        dropped: list = []
        heap: list = []
        fronts = [self._root]
        parent_keys = [0]
        expansions = launches = evaluated = 0
        while True:
            ids, d = self._evaluate(fronts, q, qoff)
            launches += 1
            expansions += len(fronts)
            evaluated += ids.size
            keys = d << shift[ids]
            if len(fronts) == 1:
                keys = np.maximum(keys, parent_keys[0])
            else:
                cnt = [int(self._child_ptr[a + 1] - self._child_ptr[a]) for a in fronts]
                keys = np.maximum(keys, np.repeat(np.asarray(parent_keys, np.int64), cnt))
            if prune:
                exact = kind[ids] == 0
                if exact.any():
                    ub = keys[exact] + np.asarray(slack, np.int64)[lev[ids[exact]]]
                    best_ub = int(ub.min())
                    upper = best_ub if upper is None else min(upper, best_ub)
                keep = keys <= upper if upper is not None else np.ones(keys.size, bool)
                for k, r, i in zip(keys[~keep].tolist(), rep[ids[~keep]].tolist(), ids[~keep].tolist()):
                    dropped.append((k, r, i))
                ids, keys = ids[keep], keys[keep]
            for k, r, i in zip(keys.tolist(), rep[ids].tolist(), ids.tolist()):
                heapq.heappush(heap, (k, r, i))
            # pop the front; a leaf there is the answer
            while True:
                if not heap:
                    # pruned mode only: eq. 3 failed; restore the dropped entries, go on exactly
                    heap = dropped
                    heapq.heapify(heap)
                    dropped, upper, prune = [], None, False
                key, r, node = heapq.heappop(heap)
                if prune and upper is not None and key > upper:
                    dropped.append((key, r, node))
                    continue
                break
            if is_leaf[node]:
                self.last_info = dict(expansions=expansions, launches=launches, evaluated=evaluated, queue=len(heap))
                ssd = key >> (2 + 3 * (levels - 1))
                return self.origin_of(r), int(ssd)
            fronts, parent_keys = [node], [key]
            width = batch if batch is not None else 1 << min(MAX_BATCH.bit_length() - 1, launches // 2)
            while heap and len(fronts) < width and not is_leaf[heap[0][2]]:
                key, r, node = heapq.heappop(heap)
                if prune and upper is not None and key > upper:
                    dropped.append((key, r, node))
                    continue
                fronts.append(node)
                parent_keys.append(key)

    def _grow(self, batch: int) -> None:
        need = int(np.diff(self._child_ptr).max()) * batch
        if need > self._cap:
            self._cap = need
            self._dev_ids = self.backend.pyramid_empty((need,), np.int32)
            self._dev_out = self.backend.pyramid_empty((need,), np.int64)

    def nearest_linear(self, query: np.ndarray) -> tuple[tuple[int, int, int], int]:
        """The same answer as :meth:`nearest`, by scoring every block (the baseline).

        Runs :func:`geosynth.compute.scoring.score_gather` over every block origin on the
        device and :func:`geosynth.compute.selection.argmin` there (lowest index on ties).
        """
        query = check_query(query, self.block)
        scores = score_gather(self.pyramid.field, self._offsets, query.reshape(-1), keep_on_device=True)
        best = argmin(scores)
        o = self.origin_of(best)
        z, y, x = o
        n = self.block
        diff = self.field[z:z + n, y:y + n, x:x + n].astype(np.int64) - query
        return o, int((diff * diff).sum())

    def pruned_disagreement(self, queries, prune_eps: float) -> dict:
        """How often the pruned search differs from the exact one on some queries.

        Args:
            queries: iterable of (N, N, N) uint8 blocks.
            prune_eps: as for :meth:`nearest`.

        Returns:
            dict with ``queries``, ``disagreement`` (fraction of queries whose pruned
            answer differs from the exact one), ``mean_excess`` and ``max_excess``
            (pruned SSD minus exact SSD, over all queries).
        """
        diff, excess = 0, []
        for qb in queries:
            o_exact, s_exact = self.nearest(qb)
            o_pr, s_pr = self.nearest(qb, prune_eps=prune_eps)
            diff += o_exact != o_pr
            excess.append(s_pr - s_exact)
        k = len(excess)
        return dict(queries=k, disagreement=diff / max(k, 1),
                    mean_excess=float(np.mean(excess)) if k else 0.0, max_excess=int(max(excess)) if k else 0)
