"""Which points are nearest? Implements no paper section: the one k-nearest-neighbour path
of every method (issue 33 item 5), for the queries the methods make on the host: normals by
PCA, spacings, MLS neighbourhoods, colour and height interpolation, stencils.

Backed by pykdtree's k-d tree: exact in float64, its OpenMP query uses every core (1.3-1.5x
faster than SciPy's cKDTree with all workers on the M3 models, about half the CPU time on
M2's blend queries; bench/RESULTS.md). Each row's neighbours come nearest first, ties by
lower index, whatever order the tree visits them in, so a decision fed by them does not
depend on the tree. Fixed-radius pairs (:func:`pairs_within`) are SciPy's: pykdtree has none.
The M2 warp's own exact grid search (:func:`geosynth.pointtexture.blending.nearest_k`) is a
compiled host step, not a second path through a library.
"""

from __future__ import annotations

import numpy as np

__all__ = ["NeighbourIndex", "nearest", "pairs_within"]

# measured on the M3 models: 8 -> 32 is 10% faster, beyond that flat
LEAF_SIZE = 32


def _ties_by_index(d: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of (distances, indices) reordered so that equal distances list the lower index
    first (a no-op, and no copy, where no row holds a tie)."""
    if d.shape[1] < 2:
        return d, idx
    tie = (d[:, 1:] == d[:, :-1]) & (idx[:, 1:] < idx[:, :-1])
    if not tie.any():
        return d, idx
    rows = np.flatnonzero(tie.any(axis=1))
    order = np.lexsort((idx[rows], d[rows]), axis=-1)
    d, idx = d.copy(), idx.copy()
    d[rows] = np.take_along_axis(d[rows], order, axis=1)
    idx[rows] = np.take_along_axis(idx[rows], order, axis=1)
    return d, idx


class NeighbourIndex:
    """A k-d tree over (N, D) points (D = 2 or 3), queried as often as needed.

    Args:
        points: (N, D) float positions (copied to contiguous float64).
    """

    def __init__(self, points: np.ndarray):
        from geosynth.core.config import passive_openmp_threads

        passive_openmp_threads()  # pykdtree's OpenMP threads sleep after a query (see there)
        from pykdtree.kdtree import KDTree

        self.points = np.ascontiguousarray(points, np.float64)
        if self.points.ndim != 2:
            raise ValueError(f"points must be (N, D), got shape {self.points.shape}.")
        self._tree = KDTree(self.points, leafsize=LEAF_SIZE) if len(self.points) else None

    def __len__(self) -> int:
        return len(self.points)

    def query(self, queries: np.ndarray, k: int = 1, upper: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest points of each query.

        Args:
            queries: (M, D) float positions.
            k: neighbours per query, >= 1.
            upper: only points nearer than this count (cKDTree's ``distance_upper_bound``);
                a missing neighbour has distance inf and index N.

        Returns:
            (distances (M, k) float64, indices (M, k) int64), nearest first, ties by lower index.
        """
        q = np.ascontiguousarray(queries, np.float64).reshape(-1, self.points.shape[1])
        k = int(k)
        n = len(self.points)
        if self._tree is None or len(q) == 0:
            return np.full((len(q), k), np.inf), np.full((len(q), k), n, np.int64)
        kw = {} if upper is None else {"distance_upper_bound": float(upper)}

        def ranked(rows, kq):  # the kq nearest of the queries ``rows``, ties by lower index
            d, idx = self._tree.query(q[rows], k=kq, **kw)
            d = np.asarray(d, np.float64).reshape(len(rows), kq)
            idx = np.asarray(idx).reshape(len(rows), kq).astype(np.int64)
            missing = ~np.isfinite(d)
            if missing.any():  # pykdtree marks a missing neighbour by index N, as cKDTree does
                idx[missing] = n
            return _ties_by_index(d, idx)

        # one neighbour more than asked: where it ties with the k-th, the tree chose which of the
        # tied points made the cut; those rows are asked again with more until the tie is whole
        kq = min(k + 1, n)
        rows = np.arange(len(q))
        d, idx = ranked(rows, kq)
        d_out, i_out = d[:, :k].copy(), idx[:, :k].copy()
        while kq > k and kq < n:
            open_ = np.isfinite(d[:, k - 1]) & (d[:, kq - 1] == d[:, k - 1])
            if not open_.any():
                break
            rows, kq = rows[open_], min(2 * kq, n)
            d, idx = ranked(rows, kq)
            d_out[rows], i_out[rows] = d[:, :k], idx[:, :k]
        if k > kq:  # more asked than there are points: the rest is missing
            d_out = np.concatenate([d_out, np.full((len(q), k - kq), np.inf)], axis=1)
            i_out = np.concatenate([i_out, np.full((len(q), k - kq), n, np.int64)], axis=1)
        return d_out, i_out

    def around(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest other points of every indexed point (itself excluded; a point
        that coincides with it counts as a neighbour at distance 0).

        Returns:
            (distances (N, k) float64, indices (N, k) int64), nearest first, ties by lower index.
        """
        n = len(self.points)
        k = int(k)
        kk = min(k + 1, n)
        d, idx = self.query(self.points, kk)
        own = np.arange(n)
        if (idx[:, 0] == own).all():  # the usual case: each point first in its own list
            return d[:, 1:k + 1], idx[:, 1:k + 1]
        # a coincident point listed before it: drop its own entry wherever it is (the last one
        # when it is not listed at all, k + 1 points at distance 0)
        keep = idx != own[:, None]
        extra = keep.sum(axis=1) > kk - 1
        last = np.flatnonzero(extra)
        keep[last, kk - 1] = False
        return d[keep].reshape(n, kk - 1)[:, :k], idx[keep].reshape(n, kk - 1)[:, :k]


def nearest(points: np.ndarray, queries: np.ndarray | None = None, k: int = 1, *,
            upper: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest of ``points`` to each of ``queries`` (:meth:`NeighbourIndex.query`),
    or, ``queries`` None, to each point itself, itself excluded (:meth:`NeighbourIndex.around`).

    Returns:
        (distances (M, k) float64, indices (M, k) int64), nearest first, ties by lower index.

    >>> import numpy as np
    >>> d, i = nearest(np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]]), k=1)
    >>> d[:, 0].tolist(), i[:, 0].tolist()
    ([1.0, 1.0, 2.0], [1, 0, 1])
    """
    index = NeighbourIndex(points)
    if queries is None:
        if upper is not None:
            raise ValueError("upper applies to queries; give queries= for a bounded search.")
        return index.around(k)
    return index.query(queries, k, upper)


def pairs_within(points: np.ndarray, radius: float) -> np.ndarray:
    """(P, 2) int64 index pairs i < j of ``points`` (N, D) nearer than ``radius``, in SciPy's
    cKDTree.query_pairs order (the same for the same points; pykdtree has no fixed-radius search)."""
    from scipy.spatial import cKDTree

    p = np.ascontiguousarray(points, np.float64)
    return cKDTree(p).query_pairs(float(radius), output_type="ndarray").astype(np.int64).reshape(-1, 2)
