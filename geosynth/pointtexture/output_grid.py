"""Which output points lie near here? The output texture T_out of "Geometry texture synthesis
with point-set surfaces", Sec. 4 ("T_out is encoded as a hashed regular grid of buckets of
points"), with its operations: insert, remove inside a box, points in a box, neighbours
within a radius, all points.

Points live in growing arrays (positions, normals, an alive flag); a bucket is the list of
point ids whose cell (an xy cell of side ``cell``: patches and their boxes span the full
height, so the grid is 2D over the reference plane) is its key, in a dict. Everything is
NumPy; points come out in the order of their rank (an insert's, default: the order of the
inserts), then of insertion, so a run is reproducible even when its inserts come from two
threads in an order of their own. One operation runs at a time (a lock): threads may share
a grid.

With ``period`` (a tileable output), positions are stored wrapped into [0, period) in x
and y, and the box queries see the periodic images (the points are returned translated
into the frame of the box asked for).
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["PointGrid"]


class PointGrid:
    """A hashed regular grid of point buckets over the xy plane.

    Args:
        cell: the buckets' side, world units, > 0 (about the MLS reach is a good size).
        period: None, or (px, py): the plane is periodic with these periods.
    """

    def __init__(self, cell: float, period=None):
        if not (np.isfinite(cell) and cell > 0):
            raise ValueError(f"cell must be a finite number > 0, got {cell!r}.")
        self.cell = float(cell)
        self.period = None if period is None else np.asarray(period, np.float64).reshape(2)
        self._pos = np.zeros((0, 3))
        self._nrm = np.zeros((0, 3))
        self._alive = np.zeros(0, bool)
        self._rank = np.zeros(0, np.int64)
        self._src = np.zeros(0, np.int64)  # each point's source id (-1: none given), carried along
        self._next_rank = 0
        self._lock = threading.RLock()
        self._count = 0
        self._buckets: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        with self._lock:
            return int(self._alive[: self._count].sum())

    # ------------------------------------------------------------------ keys

    def _cells(self, xy: np.ndarray) -> np.ndarray:
        c = np.floor(xy / self.cell).astype(np.int64)
        return c

    @staticmethod
    def _key(ix, iy):
        return (np.asarray(ix, np.int64) << 32) ^ (np.asarray(iy, np.int64) & 0xFFFFFFFF)

    def _grow(self, extra: int) -> None:
        need = self._count + extra
        if need <= len(self._pos):
            return
        cap = max(need, 2 * len(self._pos), 1024)
        for name in ("_pos", "_nrm"):
            old = getattr(self, name)
            new = np.zeros((cap, 3))
            new[: self._count] = old[: self._count]
            setattr(self, name, new)
        alive = np.zeros(cap, bool)
        alive[: self._count] = self._alive[: self._count]
        self._alive = alive
        rank = np.zeros(cap, np.int64)
        rank[: self._count] = self._rank[: self._count]
        self._rank = rank
        src = np.full(cap, -1, np.int64)
        src[: self._count] = self._src[: self._count]
        self._src = src

    # ------------------------------------------------------------------ operations

    def insert(self, points: np.ndarray, normals: np.ndarray, rank: int | None = None, sources=None) -> None:
        """Add (M, 3) points with their (M, 3) normals (wrapped into the period when periodic).
        ``rank`` (an integer in [0, 2^31)): where they come in the grid's order (default: after
        every rank given so far). ``sources``: (M,) int64 ids carried with the points (e.g. the
        exemplar point each was copied from), read back by ``in_box``/``all_points`` with
        ``sources=True``; -1 when not given."""
        with self._lock:
            self._insert(points, normals, rank, sources)

    def _insert(self, points, normals, rank, sources=None) -> None:
        p = np.asarray(points, np.float64).reshape(-1, 3).copy()
        n = np.asarray(normals, np.float64).reshape(-1, 3)
        if len(p) != len(n):
            raise ValueError(f"got {len(p)} points and {len(n)} normals.")
        if rank is None:
            rank = self._next_rank
        if not (isinstance(rank, (int, np.integer)) and 0 <= rank < 2**31):
            raise ValueError(f"rank must be an integer in [0, 2^31), got {rank!r}.")
        self._next_rank = max(self._next_rank, int(rank) + 1)
        if len(p) == 0:
            return
        if self.period is not None:
            p[:, :2] = np.mod(p[:, :2], self.period)
            p[:, :2] = np.where(p[:, :2] >= self.period, 0.0, p[:, :2])  # mod of -tiny rounds up to the period
        self._grow(len(p))
        ids = np.arange(self._count, self._count + len(p))
        self._pos[ids], self._nrm[ids], self._alive[ids], self._rank[ids] = p, n, True, int(rank)
        self._src[ids] = -1 if sources is None else np.asarray(sources, np.int64).reshape(len(p))
        self._count += len(p)
        c = self._cells(p[:, :2])
        keys = self._key(c[:, 0], c[:, 1])
        order = np.argsort(keys, kind="stable")
        keys, ids = keys[order], ids[order]
        starts = np.r_[0, np.flatnonzero(np.diff(keys)) + 1, len(keys)]
        for a, b in zip(starts[:-1], starts[1:]):
            k = int(keys[a])
            old = self._buckets.get(k)
            self._buckets[k] = ids[a:b] if old is None else np.concatenate([old, ids[a:b]])

    def _images(self, lo: np.ndarray, hi: np.ndarray):
        """The (shift, lo, hi) boxes, in stored coordinates, whose points are the box's
        (shift added to a stored point gives its position in the asked frame)."""
        if self.period is None:
            return [(np.zeros(2), lo, hi)]
        out = []
        per = self.period
        kx = range(int(np.floor(lo[0] / per[0])), int(np.floor(hi[0] / per[0])) + 1)
        ky = range(int(np.floor(lo[1] / per[1])), int(np.floor(hi[1] / per[1])) + 1)
        for i in kx:
            for j in ky:
                shift = np.array([i * per[0], j * per[1]])
                a, b = np.maximum(lo - shift, 0.0), np.minimum(hi - shift, per)
                if (a <= b).all():
                    out.append((shift, a, b))
        return out

    def _ids_in(self, lo: np.ndarray, hi: np.ndarray, closed_hi: bool = True) -> np.ndarray:
        """Ids of alive stored points with lo <= xy <= hi (or < hi), in the grid's order."""
        c0, c1 = self._cells(lo), self._cells(hi)
        parts = []
        for ix in range(int(c0[0]), int(c1[0]) + 1):
            for iy in range(int(c0[1]), int(c1[1]) + 1):
                b = self._buckets.get(int(self._key(ix, iy)))
                if b is not None:
                    parts.append(b)
        if not parts:
            return np.zeros(0, np.int64)
        ids = np.concatenate(parts)
        ids = ids[self._alive[ids]]
        xy = self._pos[ids, :2]
        ok = (xy >= lo).all(axis=1) & ((xy <= hi) if closed_hi else (xy < hi)).all(axis=1)
        return self._ordered(ids[ok])

    def _ordered(self, ids: np.ndarray) -> np.ndarray:
        """``ids`` sorted by (rank, id): one sort of rank * 2^32 + id."""
        return np.sort((self._rank[ids] << 32) | ids) & 0xFFFFFFFF

    def in_box(self, lo, hi, sources: bool = False):
        """Points (and normals) whose x and y lie in the box [lo, hi] ((2,) xy corners; a
        point's height is not tested), in insertion order, (K, 3) float64 each; periodic
        images are translated into the box's frame. With ``sources``, their (K,) int64
        source ids too."""
        lo, hi = np.asarray(lo, np.float64)[:2], np.asarray(hi, np.float64)[:2]
        with self._lock:
            out = self._in_box(lo, hi)
        return out if sources else out[:2]

    def _in_box(self, lo, hi):
        ps, ns, ss = [], [], []
        for shift, a, b in self._images(lo, hi):
            ids = self._ids_in(a, b)
            p = self._pos[ids].copy()
            p[:, :2] += shift
            ps.append(p)
            ns.append(self._nrm[ids])
            ss.append(self._src[ids])
        if not ps:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
        return np.concatenate(ps), np.concatenate(ns), np.concatenate(ss)

    def remove_box(self, lo, hi) -> int:
        """Remove every point whose x and y lie in [lo, hi) (half-open, so that boxes that
        tile the plane remove each point once); returns how many were removed."""
        lo, hi = np.asarray(lo, np.float64)[:2], np.asarray(hi, np.float64)[:2]
        with self._lock:
            return self._remove_box(lo, hi)

    def _remove_box(self, lo, hi) -> int:
        removed = 0
        for _, a, b in self._images(lo, hi):
            ids = self._ids_in(a, b, closed_hi=False)
            self._alive[ids] = False
            removed += len(ids)
        if removed > max(4096, int(self._alive[: self._count].sum())):  # prune dead ids from the buckets now and then
            self._compact_buckets()
        return removed

    def _compact_buckets(self) -> None:
        for k in list(self._buckets):
            b = self._buckets[k]
            b = b[self._alive[b]]
            if len(b):
                self._buckets[k] = b
            else:
                del self._buckets[k]

    def neighbours(self, queries, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Points within ``radius`` (3D distance) of any of the (Q, 3) queries: their
        positions and normals, (K, 3) each, in the grid's order (periodic images translated
        into the queries' frame)."""
        q = np.asarray(queries, np.float64).reshape(-1, 3)
        if len(q) == 0:
            return np.zeros((0, 3)), np.zeros((0, 3))
        p, n = self.in_box(q[:, :2].min(axis=0) - radius, q[:, :2].max(axis=0) + radius)
        if len(p) == 0:
            return p, n
        from geosynth.core.neighbours import nearest

        d = nearest(q, p, 1, upper=radius * (1 + 1e-12))[0][:, 0]
        keep = np.isfinite(d)
        return p[keep], n[keep]

    def all_points(self, sources: bool = False):
        """Every alive point and its normal, (N, 3) float64 each, in the grid's order (and,
        with ``sources``, their (N,) int64 source ids)."""
        with self._lock:
            alive = self._ordered(np.flatnonzero(self._alive[: self._count]))
        out = self._pos[alive].copy(), self._nrm[alive].copy()
        return out + (self._src[alive].copy(),) if sources else out
