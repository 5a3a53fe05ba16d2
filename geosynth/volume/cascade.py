"""Which source block is nearest to a query, by lower bounds over every block?

M1's exact nearest-block search without the tree: the lower bound of Lagae, Dumont and
Dutré, "Geometry Synthesis", Sec. 4.2 (eq. 2, cell sums of coarser levels bound the
block distance), evaluated over every block of the source at a few levels coarse to
fine, then exact distances of the survivors. It returns the block that the paper's
best-first search (Sec. 4.3, :class:`geosynth.volume.tree.BlockSearch`) returns. The
fused form runs in one launch of ``kernels/cascade.py`` / ``kernels/cascade.cl``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.compute.scoring import GatherScorer
from geosynth.core.arrays import DeviceArray
from geosynth.volume.blocks import block_offsets, block_shape, box_sums
from geosynth.volume.pyramid import check_block_shape, check_field, check_memory, check_query

__all__ = ["CascadeSearch", "tally_alive"]

# Lower bounds are summed in float32 (exact integer cell sums, rounded squares); a
# candidate is dropped only when its bound exceeds the best SSD by more than this
# relative margin, far above the float32 error of sums of <= 512 positive terms.
_BOUND_MARGIN = 1e-4
_MAX_BOUND_CELL = 32  # c^3 * 255 < 2^24: cell sums stay exact in float32
# The cascade runs only when scoring every block directly costs more than this many
# launches' worth of work (backend.launch_work); below, one launch does it all.
_CASCADE_MIN_LAUNCHES = 10
# Block sizes the fused kernel (cascade.cl cascade_search) runs by default. It takes any
# multiple of 8 up to 32 (8-byte rows, SSDs below 2^31); its stages are fixed: 2^3 cells
# of side N/2, each split into 2^3 of N/4. At N = 32 its 8^3-sample fine cells leave
# ~100 k blocks of 32^3 samples to score exactly: 105 ms a match at 256^3 on PoCL, where
# the staged search's (N/4)^3 cells take 53 ms; at N = 8 and 16 it is 3x faster.
_FUSED_BLOCKS = (8, 16)
_INT32_MAX = 2**31 - 1
# The fused bound's centred-norm terms (C_q - C_b)^2 carry float32 rounding of the norms
# (each <= 127.5 sqrt(m) for m samples): <= 2 |d| 2^-23 (C_q + C_b) < 0.008 m per cell.
# The limit gets 0.08 m more for its 8 coarse cells (N = 8: 5 SSD units).
_NORM_SLACK = 0.08
_TERMS_CHUNK = 64  # queries whose terms are summed at a time (int32 copies: 12 B a sample)
# A batch of searches small enough to score every block directly (no stages, no fused
# kernel) scores all its queries against the source's blocks unpacked as rows, one dense
# launch per chunk, instead of one launch per query: on Warp's CPU device a launch costs
# ~1.7 ms of Python, far more than such a search. The rows are kept while the search
# lives, so only sources of at most this many block samples are unpacked.
_DENSE_BATCH_SAMPLES = 1 << 23
_DENSE_SCORES = 1 << 16  # scores (uint32) per dense launch at most: 256 KiB
_DENSE_QUERIES = 1024  # queries per dense launch at most (the optimizer's chunk)
_DENSE_MIN_QUERIES = 16  # a source of more blocks than _DENSE_SCORES / 16 loops per query


def tally_alive(sums: list, alive) -> int:
    """Add per-match lists of blocks alive after each stage (``last_info["alive"]``) into
    ``sums`` (per stage; a shorter list adds 0 at the stages it lacks), in place; returns
    the number of matches added. A running sum, not the lists: a tile of millions of
    matches would hold ~150 B of Python list per match."""
    n = 0
    for counts in alive:
        if len(counts) > len(sums):
            sums.extend([0] * (len(counts) - len(sums)))
        for k, v in enumerate(counts):
            sums[k] += int(v)
        n += 1
    return n


def _divisor_cells(side: int, count: int) -> int:
    """The cell side along an axis of ``side`` samples split into at most ``count``
    equal cells (the largest count that divides the side)."""
    k = max(d for d in range(1, max(1, min(count, side)) + 1) if side % d == 0)
    return side // k


def _centred_norms(sums: np.ndarray, squares: np.ndarray, m: int) -> np.ndarray:
    """Norms of cells minus their mean, sqrt(sum x^2 - (sum x)^2 / m), float64 from exact
    integer sums and sums of squares of m samples each."""
    s = np.asarray(sums, np.float64)
    return np.sqrt(np.maximum(np.asarray(squares, np.float64) - s * s / m, 0.0))


class CascadeSearch:
    """Exact nearest block by lower bounds over every block, coarse to fine.

    The paper's bound (eq. 2) without the tree: for a level with cell size c, the
    Cauchy-Schwarz form ``sum over cells (S_q - S_b)^2 / c^3`` of the exact cell sums is
    a lower bound of the block SSD. One gather-kernel launch scores that bound for every
    block at the first stage (by default the only one: 4^3 cells), a short guess phase
    finds a good block (the smallest bounds, refined at the next stage if any, then full
    SSDs), and each finer stage keeps only blocks whose bound does not exceed the best
    SSD found. The survivors are
    scored exactly; the answer is the block of smallest SSD, the lowest block index on
    ties: the same answer as :meth:`BlockSearch.nearest_linear` and
    :meth:`BlockSearch.nearest`, with no tree to build and no per-node host work.

    Args:
        field: (Z, Y, X) uint8 source.
        block: the block size N, a power of two <= every side of ``field``; or an
            anisotropic block (bz, by, bx), each side <= the field's (a slab's block:
            its full thickness along z). An anisotropic block runs the staged search
            (no fused kernel) with box cells: each stage's ``bound_cells_per_side``
            count split per axis into the largest count that divides that side.
        device: a device string; None means ``"auto"``.
        guesses: blocks scored exactly in the guess phase of the staged search (default
            32; the fused search needs none: its work-items share the best SSD found).
        min_work: sample comparisons (blocks x N^3) below which every block is scored
            in one launch instead (None: 10 launches' worth on the device; 0: always
            run the stages).
        cells: the bound stages' cell sizes, coarse to fine (powers of two, 2 <= c <
            N), each a launch of its own. None: for N = 8 and 16 the fused search,
            one launch per query or per batch of queries (``fused``); for other N the backend's
            ``bound_cells_per_side``: on PoCL one stage of
            (N/4)^3-sample cells, 64 cell sums a block, over every block (the fast
            lattice kernel), then the exact SSDs of its few survivors: measured with
            synthesis queries 1.2x faster than 8 then 64 cells at N = 16 and 4x at N = 32
            (the 8-cell bound keeps a third of the blocks, scored again by index); on
            Warp's one CPU thread 8 then 64 cells, 4x faster there than 64 at once.

    The fused search (``cells=None``, N = 8 or 16) runs the stages (N/2, N/4) and the
    exact SSDs in one kernel: work-items scan rows of blocks 16 at a time, refine a
    block's bound cell by cell only while it stays below the best SSD any of them has
    found (shared through an atomic minimum) and score the survivors exactly; no bounds
    come back to the host, only each item's best block. On synthesis queries (PoCL, 2
    cores) 3-4x faster than the staged launches at 64^3 / 8 and 2-3x at 128^3 / 16.

    Attributes:
        stages: the cell sizes of the bound stages, coarse to fine (an anisotropic
            block's: (cz, cy, cx) boxes); empty for N <= 2
            and for searches small enough that scoring every block in one launch is
            cheaper (fewer than ``min_work`` comparisons).
        fused: whether the stages run fused in one launch.
        batch_fused: whether :meth:`nearest_batch` runs the fused kernel, the whole batch
            in one launch (N = 8 or 16, ``cells=None``): also for searches small enough
            that a single query is scored directly (``fused`` false, no stages).
        batch_dense: whether :meth:`nearest_batch` scores its queries against every
            block unpacked as rows (no stages, no fused kernel, at most 2^23 block
            samples, at most 4,096 blocks), one dense launch per chunk of queries.
        last_info: per query, the number of blocks alive after each stage (fused: all
            blocks, then the blocks scored exactly).

    Example:
        >>> import numpy as np
        >>> f = np.random.default_rng(0).integers(0, 256, (20, 20, 20), dtype=np.uint8)
        >>> CascadeSearch(f, 8, device="cpu").nearest(f[3:11, 2:10, 5:13])
        ((3, 2, 5), 0)
    """

    def __init__(self, field: np.ndarray, block: int, *, device: str | None = None, guesses: int = 32,
                 min_work: float | None = None, cells: Sequence[int] | None = None):
        from geosynth.compute.backend import to_device

        field = check_field(field)
        block = check_block_shape(block, field.shape)
        self.field = field
        self.block = block  # N for a cube, else (bz, by, bx)
        self.block_shape = block_shape(block)
        self.block_samples = int(np.prod(self.block_shape))
        self.lattice = tuple(int(s) - b + 1 for s, b in zip(field.shape, self.block_shape))
        self.n_blocks = int(np.prod(self.lattice))
        backend = _checks.resolve_backend(device)
        cubic = np.ndim(block) == 0
        fused = cubic and cells is None and self.block in _FUSED_BLOCKS
        if not cubic:
            if cells is not None:
                raise ValueError(f"cells are chosen for an anisotropic block {self.block}; give cells=None.")
            boxes = []
            for n in backend.bound_cells_per_side:
                box = tuple(_divisor_cells(b, n) for b in self.block_shape)
                if box != self.block_shape and np.prod(box) >= 2 and box not in boxes:
                    boxes.append(box)
            cells = boxes
        else:
            if cells is None:  # fused, or the backend's choice (Backend.bound_cells_per_side)
                per_side = (2, 4) if fused else backend.bound_cells_per_side
                cells = [self.block // n for n in per_side if self.block // n >= 2]
            cells = [int(c) for c in cells]
            for c in cells:
                if c < 2 or c >= self.block or c & (c - 1) or c > _MAX_BOUND_CELL:
                    raise ValueError(f"cells must be powers of two in [2, {min(self.block - 1, _MAX_BOUND_CELL)}] "
                                     f"for block {self.block}, got {cells}.")
            if cells != sorted(cells, reverse=True) or len(set(cells)) != len(cells):
                raise ValueError(f"cells must go coarse to fine (strictly decreasing), got {cells}.")
        self.stages = cells
        # A batch of queries runs the fused kernel whenever the block allows it: one launch
        # for the batch costs less than one direct launch per query, however small the search.
        self.batch_fused = fused
        self._fused_cells = tuple(cells) if fused else ()
        if min_work is None:
            min_work = _CASCADE_MIN_LAUNCHES * backend.launch_work
        if self.n_blocks * self.block_samples < min_work:
            self.stages = []  # one launch over every block costs less than the stages' launches
            fused = False
        self.fused = fused
        per_sample = (1 + 4 * 3 + 8 if self.batch_fused else 1) + 12 * (0 if fused else len(self.stages))
        self.batch_dense = (not self.stages and not self.batch_fused
                            and self.n_blocks * self.block_samples <= _DENSE_BATCH_SAMPLES
                            and self.n_blocks * _DENSE_MIN_QUERIES <= _DENSE_SCORES)
        # the rows on the host and on the device, one launch's scores on both
        dense = 2 * self.n_blocks * (self.block_samples + 4 * self._dense_step()) if self.batch_dense else 0
        check_memory(field.size * per_sample + (0 if fused else self.n_blocks * 40) + dense,
                     f"the cascade search of a {field.shape} field (block {block})")
        dev = "auto" if device is None else device
        self._backend = backend
        self._field_device = to_device(field, dev)
        self._exact_scorer = GatherScorer(self._field_device, block_offsets(self.block))
        self._bound_scorers = {} if fused else {
            c: GatherScorer(to_device(box_sums(field, c).astype(np.float32), dev),
                            np.asarray(block_shape(c)) * block_offsets(self._cells_per_side(c)))
            for c in self.stages
        }
        if self.batch_fused:
            self._fused_setup(dev)
        self._dense_rows: DeviceArray | None = None  # made by the first dense batch
        self.guesses = max(1, int(guesses))
        self.guess_skip = 16384  # blocks under a given threshold above which a guess pays off
        self.last_info: dict = {}

    def _cells_per_side(self, cell) -> tuple[int, int, int]:
        """Cells of side (or box) ``cell`` per block side, (z, y, x)."""
        return tuple(b // c for b, c in zip(self.block_shape, block_shape(cell)))

    def _fused_setup(self, dev: str) -> None:
        """Cell sums (sides N/2 and N/4) and coarse centred norms at every field position,
        in the field's strides (0 where the cube leaves the field), and the cell offsets."""
        from geosynth.compute.backend import to_device

        shape = self.field.shape
        cc, cf = self._fused_cells

        def padded(values: np.ndarray) -> DeviceArray:
            out = np.zeros(shape, np.float32)
            out[:values.shape[0], :values.shape[1], :values.shape[2]] = values
            return to_device(out, dev)

        s1 = box_sums(self.field, cc)
        s2 = box_sums(self.field.astype(np.int64) ** 2, cc)
        self._fused_arrays = (padded(s1), padded(_centred_norms(s1, s2, cc**3)), padded(box_sums(self.field, cf)))
        sy, sz = shape[2], shape[2] * shape[1]
        lz, ly, lx = self.lattice
        self._fused_geometry = (lx, ly, lz, sy, sz)  # lattice and field strides, as the kernel takes them
        coarse = np.indices((2, 2, 2)).reshape(3, -1).T  # (8, 3) coarse cells, C order
        fine = (2 * coarse[:, None, :] + coarse[None, :, :]).reshape(-1, 3)  # grouped by coarse cell
        strides = np.array([sz, sy, 1])
        offsets = np.concatenate([cc * coarse @ strides, cf * fine @ strides]).astype(np.int32)
        self._fused_offsets = to_device(offsets, dev)
        # the query's samples in the order of the cells: fine cells in the offsets' order, C order within
        n = self.block
        inner = np.indices((cf, cf, cf)).reshape(3, -1).T
        samples = (cf * fine)[:, None, :] + inner[None, :, :]  # (64, cf^3, 3)
        self._fused_order = (samples @ np.array([n * n, n, 1])).reshape(-1).astype(np.intp)

    def _fused_terms(self, queries: np.ndarray) -> np.ndarray:
        """(Q, 80) float32: per query its 8 coarse sums, 8 coarse centred norms and 64 fine
        sums, the kernel's ``query_terms`` (exact integer sums; the norms from float64).
        _TERMS_CHUNK queries at a time: the int32 copies stay small beside the batch."""
        cc = self._fused_cells[0]
        out = np.empty((len(queries), 80), np.float32)
        for lo in range(0, len(queries), _TERMS_CHUNK):
            part = queries[lo:lo + _TERMS_CHUNK]
            q = len(part)
            flat = part.reshape(q, -1).astype(np.int32)[:, self._fused_order]  # fine cell by fine cell
            fine = flat.reshape(q, 64, -1).sum(axis=2)
            s1 = fine.reshape(q, 8, 8).sum(axis=2)
            s2 = (flat * flat).reshape(q, 8, -1).sum(axis=2)
            out[lo:lo + q] = np.concatenate([s1, _centred_norms(s1, s2, cc**3), fine], axis=1)
        return out

    def _fused_batch(self, queries: np.ndarray, thresholds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The fused search of (Q, N, N, N) queries in one launch, each starting from its
        threshold (int64, -1: none).

        Returns (Q,) int64 best SSDs and lattice indices (-1 where no block is within the
        threshold) and the blocks each query scored exactly."""
        be, n = self._backend, self.block
        cc, cf = self._fused_cells
        q = len(queries)
        # Work-items per query: the device's count shared out over the batch (one each on a
        # CPU: a query scanned by one item prunes best); the answer does not depend on it.
        n_rows = self.lattice[0] * self.lattice[1]
        per_query = max(1, min(n_rows, self._backend.search_items // q))
        rows = -(-n_rows // per_query)
        items = -(-n_rows // rows)
        start = np.where(thresholds < 0, _INT32_MAX, np.minimum(thresholds, _INT32_MAX)).astype(np.int32)
        out = be.empty((q * items, 3), np.int32)
        be.cascade_search(
            self._field_device, *self._fused_arrays, *self._fused_geometry, n,
            self._fused_offsets, be.to_device(self._fused_terms(queries).reshape(-1)), 1.0 / cc**3, 1.0 / cf**3,
            be.to_device(np.ascontiguousarray(queries.reshape(-1))), rows, items, q, 1.0 + _BOUND_MARGIN,
            1.0 + _NORM_SLACK * cc**3, be.to_device(start), out,
        )
        res = be.to_host(out).reshape(q, items, 3).astype(np.int64)  # sync: one line per work-item
        found = res[:, :, 1] >= 0
        ssd = np.where(found, res[:, :, 0], np.iinfo(np.int64).max)
        best = ssd.min(axis=1)
        index = np.where(found & (ssd == best[:, None]), res[:, :, 1], np.iinfo(np.int64).max).min(axis=1)
        missing = ~found.any(axis=1) | ((thresholds >= 0) & (best > thresholds))
        index[missing] = -1
        return best, index, res[:, :, 2].sum(axis=1)

    def _nearest_fused_batch(self, queries: np.ndarray, thresholds: np.ndarray
                             ) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
        """The fused search's answers: ((Q, 3) origins, (Q,) SSDs, alive), the queries whose
        threshold was too low searched again without it (a second launch)."""
        best, index, scored = self._fused_batch(queries, thresholds)
        again = np.flatnonzero(index < 0)
        if len(again):  # the threshold was too low
            best[again], index[again], more = self._fused_batch(queries[again], np.full(len(again), -1, np.int64))
            scored[again] += more
        origins = np.stack(np.unravel_index(index, self.lattice), axis=1).astype(np.int64)
        return origins, best, [[self.n_blocks, int(v)] for v in scored]

    def _dense_step(self) -> int:
        """Queries per dense launch."""
        return max(1, min(_DENSE_QUERIES, _DENSE_SCORES // self.n_blocks))

    def _nearest_dense_batch(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
        """Every block scored against every query (``batch_dense``), chunk by chunk: the
        (Q, 3) origins and (Q,) SSDs of the smallest SSD, lowest index on ties (the
        answers of :meth:`nearest`, whatever its thresholds), and the blocks alive."""
        from geosynth.compute.backend import to_device
        from geosynth.compute.scoring import score_dense

        if self._dense_rows is None:
            windows = np.lib.stride_tricks.sliding_window_view(self.field, self.block_shape)
            # rows in lattice order, samples in C order: the layout of block_offsets and of a query
            self._dense_rows = to_device(windows.reshape(self.n_blocks, self.block_samples), self._field_device.device)
        q = len(queries)
        index = np.empty(q, np.int64)
        ssds = np.empty(q, np.int64)
        step = self._dense_step()
        for lo in range(0, q, step):
            part = queries[lo:lo + step].reshape(-1, self.block_samples)
            scores = score_dense(self._dense_rows, part)  # (q, n_blocks) uint32, exact
            best = scores.argmin(axis=1)  # the first minimum: the lowest index on ties
            index[lo:lo + len(part)] = best
            ssds[lo:lo + len(part)] = scores[np.arange(len(part)), best]
        origins = np.stack(np.unravel_index(index, self.lattice), axis=1).astype(np.int64)
        return origins, ssds, [[self.n_blocks] for _ in range(q)]

    def _bound(self, cell: int, query_sums: dict, alive: np.ndarray | None) -> np.ndarray:
        """Lower bounds (float32, SSD units) of the blocks ``alive`` (None: all)."""
        scorer = self._bound_scorers[cell]
        if alive is None:
            bounds = scorer(query_sums[cell])
        else:  # block indices are lattice indices: no origins to gather and check
            bounds = scorer.score_bases(query_sums[cell], scorer.lattice_bases(alive))
        # a cube's c^3 is a power of two (exact); a box's 1/m rounds by 2^-24, far inside the margin
        bounds *= np.float32(1.0 / int(np.prod(block_shape(cell))))
        return bounds

    def _exact(self, alive: np.ndarray, query: np.ndarray, threshold=None) -> np.ndarray:
        scorer = self._exact_scorer
        return scorer.score_bases(query.reshape(-1), scorer.lattice_bases(alive), threshold=threshold)

    def nearest(self, query: np.ndarray, threshold: int | None = None) -> tuple[tuple[int, int, int], int]:
        """The exact nearest block of ``query``.

        Args:
            query: (N, N, N) uint8 block.
            threshold: optional upper bound on the best SSD (e.g. the SSD of any one
                block, a coherence guess); it only speeds the search up.

        Returns:
            ((z, y, x) origin, SSD) of the block of smallest SSD, lowest index on ties.
        """
        query = check_query(query, self.block)
        n_all = self.n_blocks
        if self.fused:
            origins, ssds, alive = self._nearest_fused_batch(query[None], np.array([-1 if threshold is None
                                                                                   else int(threshold)]))
            self.last_info = {"alive": alive[0]}
            return tuple(int(v) for v in origins[0]), int(ssds[0])
        if not self.stages:  # every block, on the lattice (the fast path of the kernel)
            scores = self._exact_scorer(query.reshape(-1), threshold=threshold, keep_on_device=True)
            # sync: the reduction runs where the scores are; one index and score come back
            best, best_score = self._exact_scorer.backend.argmin(scores)
            if threshold is not None and int(best_score) > threshold:  # the threshold was too low
                return self.nearest(query)
            self.last_info = {"alive": [n_all]}
            return self.origin_of(best), int(best_score)
        q64 = query.astype(np.int64)
        query_sums = {}
        for c in self.stages:
            (nz, ny, nx), (cz, cy, cx) = self._cells_per_side(c), block_shape(c)
            query_sums[c] = q64.reshape(nz, cz, ny, cy, nx, cx).sum(axis=(1, 3, 5)).reshape(-1).astype(np.float32)
        bounds = self._bound(self.stages[0], query_sums, None)
        best_ssd = None if threshold is None else int(threshold)
        if best_ssd is None or np.count_nonzero(bounds <= best_ssd * (1 + _BOUND_MARGIN) + 1) > self.guess_skip:
            best_ssd = self._guess(bounds, query_sums, query, best_ssd)
        limit = best_ssd * (1 + _BOUND_MARGIN) + 1
        counts = [n_all]
        alive = np.flatnonzero(bounds <= limit)
        counts.append(len(alive))
        for c in self.stages[1:]:
            if len(alive) == 0:
                break
            alive = alive[self._bound(c, query_sums, alive) <= limit]
            counts.append(len(alive))
        self.last_info = {"alive": counts}
        if len(alive) == 0:  # the caller's threshold was below the best SSD: search without it
            return self.nearest(query)
        # Every block of SSD <= best_ssd survives (its bounds are <= its SSD), so the
        # minimum over the survivors is the global minimum and their order is the index order.
        scores = self._exact(alive, query, best_ssd)
        i = int(np.argmin(scores))
        if int(scores[i]) > best_ssd:  # no block within the caller's threshold: it was too low
            return self.nearest(query)
        return self.origin_of(int(alive[i])), int(scores[i])

    def _guess(self, bounds: np.ndarray, query_sums: dict, query: np.ndarray, best_ssd: int | None) -> int:
        """An upper bound of the best SSD: the exact SSD of the blocks of smallest
        bound (refined at the second stage), or ``best_ssd`` if that is lower."""
        n_pool = 64 * self.guesses
        if len(bounds) <= n_pool:
            pool = np.arange(len(bounds))
        else:
            # About the n_pool smallest bounds, by a cut estimated on a subsample
            # (a full partition of millions of bounds costs more than the search).
            step = max(1, len(bounds) // (16 * n_pool))
            sub = bounds[::step]
            cut = np.partition(sub, min(len(sub) - 1, n_pool // step))[min(len(sub) - 1, n_pool // step)]
            pool = np.flatnonzero(bounds <= cut)
            if len(pool) > n_pool:
                pool = pool[np.argpartition(bounds[pool], n_pool)[:n_pool]]
        fine = self._bound(self.stages[1], query_sums, pool) if len(self.stages) > 1 else bounds[pool]
        if len(pool) > self.guesses:
            pool = pool[np.argpartition(fine, self.guesses)[:self.guesses]]
        guess = int(self._exact(np.sort(pool), query).min())
        return guess if best_ssd is None else min(guess, best_ssd)

    def origin_of(self, index: int) -> tuple[int, int, int]:
        """Origin (z, y, x) of block ``index``."""
        z, y, x = np.unravel_index(int(index), self.lattice)
        return int(z), int(y), int(x)

    def nearest_batch(self, queries: np.ndarray, thresholds: Sequence[int | None] | None = None
                      ) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
        """The exact nearest block of each of several queries.

        The fused search (N = 8, 16) scores the whole batch in one launch (a second one
        for queries whose threshold was below their best SSD); a search small enough to
        score every block directly (``batch_dense``) scores the batch against all blocks
        in dense launches; the other searches loop over :meth:`nearest`. The answers are those of one call per query.

        Args:
            queries: (Q, N, N, N) uint8 blocks.
            thresholds: None, or one upper bound of the best SSD per query (None
                entries allowed), as in :meth:`nearest`.

        Returns:
            ((Q, 3) int64 origins, (Q,) int64 SSDs, per query the blocks alive after
            each stage).
        """
        queries = np.asarray(queries)
        if queries.dtype != np.uint8:
            raise TypeError(f"queries have dtype {queries.dtype}: expected uint8, like the source field.")
        if queries.ndim != 4 or queries.shape[1:] != self.block_shape:
            raise ValueError(f"queries must have shape (Q, {', '.join(str(v) for v in self.block_shape)}), "
                             f"got {queries.shape}.")
        n = len(queries)
        if n and (self.fused or (self.batch_fused and n > 1)):
            limits = np.array([-1 if thresholds is None or thresholds[i] is None else int(thresholds[i])
                               for i in range(n)], np.int64)
            return self._nearest_fused_batch(np.ascontiguousarray(queries), limits)
        if n and self.batch_dense:
            return self._nearest_dense_batch(queries)
        origins = np.empty((n, 3), np.int64)
        ssds = np.empty(n, np.int64)
        alive = []
        for i in range(n):
            t = None if thresholds is None else thresholds[i]
            origin, ssd = self.nearest(queries[i], threshold=None if t is None else int(t))
            origins[i], ssds[i] = origin, ssd
            alive.append(list(self.last_info.get("alive", [])))
        return origins, ssds, alive
