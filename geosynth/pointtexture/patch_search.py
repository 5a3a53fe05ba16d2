"""Which exemplar patch best continues the output here? Finding a similar patch, Sec. 5.1 of
"Geometry texture synthesis with point-set surfaces".

D(S) is the MLS signed distance of a point set S plus its gradient (4 channels) on a
regular grid (the quasi-orthogonal projection of Adamson and Alexa, through
:func:`geosynth.geometry.pointsets.pointset_distance`, i.e. the ``PointsOps.mls_project`` kernel).
D(T_in) is computed once on a coarse grid over the whole exemplar box B; every candidate
patch's overlap field D(O^P) is read from it by the gather SSD kernel
(:class:`geosynth.compute.scoring.GatherScorer`: the windows are never unpacked); D(O^N) of the
output neighbourhood's overlap is computed on the fly from the output's points near it.
The candidates within (1 + eps) of the best score are kept (:func:`geosynth.compute.selection.
within_tolerance`) and one is drawn with the seeded generator (step 2 and 3 of Sec. 4).

Identical on every device: the fields are quantized to uint8 (the distance over the band
[-band, band] and each gradient component over [-1, 1] to the codes 0..254, zero at 127)
and scored in exact integer arithmetic. Near or far (a point within reach or not) is
decided on the host in float64 (the nearest points by a compiled host kernel, exact where
it matters); only the near queries and the far ones' nearest points are projected by the
kernel, with at most FIXED_STEPS steps, stopping at ``|f| <= FIXED_TOL h`` (two devices
may stop a step apart there, and then differ by about FIXED_TOL h: ~4e-5 of a distance
code, ~1e-4 of a gradient code where the curvature is 1 / h, far below ARBITER_TOL) or at
an exact fixed point, and it gives each projection's residual in the same launch; a value
it gives within ARBITER_TOL of a rounding boundary (where two devices' float32 results, a
few ulps apart, could round apart), a projection that has not converged (thin sheets closer
than the MLS width make it oscillate: devices then disagree by more than rounding), and
the few ambiguous near/far cases are recomputed on the host in float64 (:func:`host_mls`,
the same definitions and steps, one compiled host kernel launch on Warp's CPU for every
device: ``geosynth.kernels.host_search``) and quantized from there. Every device then gives
the same codes as long as its error on the rest stays below ARBITER_TOL of a code (2.4e-5
of the band for the distance, where converged float32 projections are good to ~1e-7).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from geosynth.core.config import PATCH_SEARCH_LOCK

__all__ = [
    "ARBITER_TOL",
    "CODE_SCALE",
    "FIXED_STEPS",
    "FIXED_TOL",
    "RESIDUAL_TOL",
    "PatchSearch",
    "SearchChoice",
    "host_mls",
    "kernel_mls",
    "quantized_fields",
]

# One thread at a time on the run's device (kernel arguments and queues are shared): M2's
# growth may run two patches at once (geometry_texture._grow), their host steps in parallel.
CODE_SCALE = 127.0  # a unit of the normalized value is 127 codes; zero is code 127
ARBITER_TOL = 0.003  # codes: values nearer than this to a rounding boundary are recomputed on the host
FIXED_STEPS = 12  # projection steps of the coded fields at most
FIXED_TOL = 1e-6  # of h: the coded fields' projections stop at |f| <= this (devices a step apart differ by less)
RESIDUAL_TOL = 1e-5  # of h: a projection one more step would move farther is not converged (host)
_GATHER_SLACK = 0.5  # of h: host_mls gathers each query's points within reach + this, again once it moved farther


# ------------------------------------------------------------------ the fields


def host_mls(points: np.ndarray, normals: np.ndarray, queries: np.ndarray, h: float, tree=None,
             fixed: bool = False, nearest=None, compiled: bool = True, cells=None):
    """The MLS signed distance and gradient of :func:`geosynth.geometry.pointsets.pointset_distance`
    (far="nearest"), vectorized over queries, in float64 on the host.

    The same definitions as the kernel and :func:`geosynth.geometry.reference.mls_project_naive`:
    Gaussian weights of width h cut off at MLS_REACH * h, ``f(y) = n(y) . (y - a(y))``,
    steps ``y <- y - f n`` until ``|f| <= MLS_TOL h`` or MLS_MAX_ITER steps, distance
    ``sign(f(x)) min(|x - proj|, reach)``, gradient the last MLS normal; a query with no
    point within reach gets the signed distance to its nearest point's projection.

    Args:
        points, normals: (N, 3) float positions and unit normals.
        queries: (M, 3) float query points.
        h: the kernel width.
        tree: an optional ``scipy.spatial.cKDTree`` of ``points``.
        fixed: at most FIXED_STEPS projection steps, stopping at ``|f| <= FIXED_TOL h``,
            as :func:`quantized_fields`'s kernel (the codes are made this way).
        nearest: optional ((M,) float distance, (M,) int index) of each query's nearest
            point (as ``tree.query(queries, k=1)`` gives them), to skip that query; exact
            where the distance is >= (1 - 1e-5) reach, elsewhere any point nearer than that
            (as :meth:`_HostCells.nearest` with ``enough`` gives them).
        compiled: the projection loop by the float64 host kernel
            (``geosynth.kernels.host_search.mls_project_f64``, the same on every device);
            False: by its NumPy oracle :func:`_iterate` (the sums in another order: equal
            to float64 rounding where the projections converge).
        cells: optional, the :class:`_HostCells` of these points (unit normals) for reach
            MLS_REACH h, for the compiled loop.

    Returns:
        ((M,) distance, (M, 3) gradient), float64.
    """
    from scipy.spatial import cKDTree

    from geosynth.geometry.pointsets import MLS_REACH

    p = np.asarray(points, np.float64)
    x = np.asarray(queries, np.float64).reshape(-1, 3)
    reach = MLS_REACH * h
    m = len(x)
    if m == 0:
        return np.zeros(0), np.zeros((0, 3))
    if compiled and cells is not None:
        nrm = None  # the cells hold the unit normals
    else:
        nrm = np.asarray(normals, np.float64)
        nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    if compiled:
        cells = _HostCells(p, nrm, reach) if cells is None else cells

        def run(q):
            return cells.project(q, h, fixed)

        def exact_nearest(q):
            return cells.nearest(q)[1]
    else:
        tree = cKDTree(p) if tree is None else tree

        def run(q):
            return _iterate(p, nrm, tree, q, h, fixed)

        def exact_nearest(q):
            return tree.query(q, k=1)[1]
    if nearest is None:
        nearest_d, nearest = (cells.nearest(x) if compiled else tree.query(x, k=1))
    else:
        nearest_d, nearest = np.asarray(nearest[0], np.float64), np.asarray(nearest[1], np.int64)
    # The nearest points of the queries that are probably far are projected in the same loop
    # as the queries (which are far is known only after it): one loop instead of two. A far
    # query left out (no weight although its nearest point is within reach: rounding at the
    # reach, or normals that cancel) gets its nearest point projected in a second loop.
    likely_far = np.flatnonzero(nearest_d >= reach * (1 - 1e-6))
    used, inverse = np.unique(nearest[likely_far], return_inverse=True)
    f0, grad, proj = run(np.concatenate([x, p[used]]))
    gn, yp = grad[m:], proj[m:]
    f0, grad, proj = f0[:m], grad[:m], proj[:m]
    near = ~np.isnan(f0)
    dist = np.full(m, reach)
    length = np.minimum(np.linalg.norm(x - proj, axis=1), reach)
    dist[near] = np.where(f0[near] < 0, -length[near], length[near])
    far = np.flatnonzero(~near)
    if far.size:
        slot = np.full(m, -1, np.int64)  # each far query's row in (gn, yp)
        slot[likely_far] = inverse
        missing = far[slot[far] < 0]
        if missing.size:  # (their given nearest points need not be the nearest: asked again)
            more, more_inverse = np.unique(exact_nearest(x[missing]), return_inverse=True)
            _, g_more, y_more = run(p[more])
            slot[missing] = len(used) + more_inverse
            gn, yp = np.concatenate([gn, g_more]), np.concatenate([yp, y_more])
        yv, nv = yp[slot[far]], gn[slot[far]]
        v = x[far] - yv
        side = np.where(np.einsum("ij,ij->i", v, nv) < 0, -1.0, 1.0)
        dist[far] = side * np.linalg.norm(v, axis=1)
        grad[far] = nv
    return dist, grad


class _HostCells:
    """A point set sorted by cell in float64, for the host projection kernel
    (``geosynth.kernels.host_search.mls_project_f64``; layout of
    :func:`geosynth.geometry.pointsets.cell_sort`).

    Args:
        p, nrm: (N, 3) float64 positions and unit normals, N >= 1; reach: MLS_REACH h.
        grid: optional, the :class:`geosynth.geometry.pointsets.CellGrid` of the same points (their
            float32 copies) for this reach: its layout is reused (no second sort). A float64
            point may then lie outside its cell by the float32 rounding of the positions; the
            kernel's cell and row ranges are widened by twice the largest such rounding.
    """

    def __init__(self, p: np.ndarray, nrm: np.ndarray, reach: float, grid=None):
        from geosynth.compute.host_steps import host_array
        from geosynth.geometry.pointsets import cell_sort

        if grid is None:
            rel, order, start, self.shift, self.origin, self.cell, self.dims = cell_sort(p, reach)
            rel = rel[order]
            self.slack = 0.0
        else:
            order, start = grid.order, grid.cell_start
            self.shift, self.origin, self.cell, self.dims = grid.shift, grid.origin, grid.cell, grid.dims
            sorted_p = np.take(p, order, axis=0)
            rel = sorted_p - self.shift
            keyed = np.take(p.astype(np.float32), order, axis=0).astype(np.float64) - self.shift  # what set the keys
            self.slack = 2.0 * float(np.abs(rel - keyed).max())
        pn = np.empty((len(p), 6))
        pn[:, :3] = rel
        pn[:, 3:] = np.take(nrm, order, axis=0)
        self.reach = float(reach)
        self._pn = host_array(pn, np.float64)
        self._start = host_array(start, np.int32)
        self._order = host_array(order, np.int32)

    def nearest(self, q: np.ndarray, enough: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Each (M, 3) float64 query's nearest point: ((M,) float64 distance, (M,) int64
        index; the lowest index on ties), exact in float64 (as a k-d tree's), by one launch
        of ``nearest_point_f64`` (a query within reach needs one pass over its cells).
        ``enough`` (<= reach): a query with a point nearer than it gets the first such point
        met instead (its distance < enough, not necessarily the nearest): exact only where
        the result is >= enough."""
        from geosynth.compute.host_steps import host_array, host_launch
        from geosynth.kernels.host_search import nearest_point_f64

        m = len(q)
        queries = host_array(q - self.shift, np.float64)
        d2 = host_array(np.empty(m), np.float64)
        idx = host_array(np.empty(m, np.int32), np.int32)
        host_launch(nearest_point_f64, m, [
            self._pn[0], self._start[0], self._order[0], *(float(v) for v in self.origin), float(self.cell),
            *(int(v) for v in self.dims), self.slack, self.reach, float(enough) ** 2, queries[0], d2[0], idx[0]],
            split=True)
        return np.sqrt(d2[1]), idx[1].astype(np.int64)

    def project(self, q: np.ndarray, h: float, fixed: bool):
        """:func:`_iterate`'s outputs for (M, 3) float64 queries: (f at the query (NaN:
        no point within reach), last MLS normal, projection), float64, by one launch."""
        from geosynth.compute.host_steps import host_array, host_launch
        from geosynth.geometry.pointsets import MLS_MAX_ITER, MLS_TOL
        from geosynth.kernels.host_search import mls_project_f64

        steps, tol = (FIXED_STEPS, FIXED_TOL * h) if fixed else (MLS_MAX_ITER, MLS_TOL * h)
        m = len(q)
        queries = host_array(q - self.shift, np.float64)
        f0 = host_array(np.empty(m), np.float64)
        found = host_array(np.empty(m, np.int32), np.int32)
        grad = host_array(np.empty((m, 3)), np.float64)
        proj = host_array(np.empty((m, 3)), np.float64)
        host_launch(mls_project_f64, m, [
            self._pn[0], self._start[0], *(float(v) for v in self.origin), float(self.cell),
            *(int(v) for v in self.dims), 1.0 / (h * h), self.reach, self.slack, float(tol), int(steps), queries[0],
            f0[0], found[0], grad[0], proj[0]], split=True, min_part=16)
        have = found[1] != 0
        y = proj[1] + self.shift
        y[~have] = q[~have]  # no support: the query itself, not its round trip through the shift
        return np.where(have, f0[1], np.nan), grad[1], y


def _gather(tree, y: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The points within ``radius`` of each (m, 3) query, as one flat (L,) int64 index list
    in ascending index order per query, and (m,) int64 counts."""
    lists = tree.query_ball_point(y, radius, return_sorted=True)
    counts = np.fromiter(map(len, lists), np.int64, len(lists))
    flat = np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(counts.sum()))
    return flat, counts


def _iterate(p, nrm, tree, q, h, fixed: bool = False):
    """The projection loop: (f at the query (NaN: no point within reach), last MLS normal,
    projection), float64, for (M, 3) queries: at most MLS_MAX_ITER steps, stopping at
    ``|f| <= MLS_TOL h``; ``fixed``: at most FIXED_STEPS, stopping at ``|f| <= FIXED_TOL h``
    (as :func:`quantized_fields`'s kernel); either also stops at an exact fixed point, where
    every later step would repeat the last one bit for bit. The NumPy oracle of
    :class:`_HostCells`'s kernel."""
    from geosynth.geometry.pointsets import MLS_MAX_ITER, MLS_REACH, MLS_TOL

    reach = MLS_REACH * h
    steps, tol = (FIXED_STEPS, FIXED_TOL * h) if fixed else (MLS_MAX_ITER, MLS_TOL * h)
    m = len(q)
    y = q.copy()
    grad = np.zeros((m, 3))
    proj = q.copy()
    f0 = np.full(m, np.nan)
    active = np.arange(m)
    pn = np.concatenate([p, nrm], axis=1)  # one gather for positions and normals
    # Each query's points within reach + slack of an anchor, gathered once and kept while the
    # iterate stays within slack of the anchor (after the first step it hardly moves): a superset
    # of the points within reach, in ascending index order, as the exact set. Those beyond reach
    # get weight 0, and adding 0 changes no sum: the same bits as gathering at every step.
    slack = _GATHER_SLACK * h
    radius = reach * (1 + 1e-9) + slack
    anchor = q.copy()
    # The cache holds the active queries' entries only: (L,) query ids and (L, 6) neighbours;
    # a query's entries are consecutive, in ascending point index order (the sums' order).
    c_qid = np.zeros(0, np.int64)
    c_nb = np.zeros((0, 6))
    fresh = active  # queries to gather for
    pos = np.zeros(m, np.int64)
    chan = np.arange(7)
    bins = None
    for _ in range(steps):
        if active.size == 0:
            break
        if fresh.size:
            anchor[fresh] = y[fresh]
            flat, counts = _gather(tree, y[fresh], radius)
            stale = np.zeros(m, bool)
            stale[fresh] = True
            keep = ~stale[c_qid]
            c_qid = np.concatenate([c_qid[keep], np.repeat(fresh, counts)])
            c_nb = np.concatenate([c_nb[keep], np.take(pn, flat, axis=0)])  # take: fancy indexing's rows, faster
            bins = None
        na = active.size
        if bins is None:  # each entry's (query, channel) bins, while the cache is unchanged
            pos[active] = np.arange(na)
            row = pos[c_qid]
            bins = (row[:, None] * 7 + chan).ravel()
        diff = c_nb[:, :3] - np.take(np.take(y, active, axis=0), row, axis=0)
        d2 = np.einsum("ij,ij->i", diff, diff)
        w = np.where(d2 < reach * reach, np.exp(-d2 / (h * h)), 0.0)
        # sum w, sum w p, sum w n in one bincount: each (query, channel) bin sums in entry order
        terms = np.empty((len(w), 7))
        terms[:, 0] = w
        np.multiply(w[:, None], c_nb, out=terms[:, 1:])
        sums = np.bincount(bins, terms.ravel(), 7 * na).reshape(na, 7)
        ws = sums[:, 0]
        msum = sums[:, 4:]
        mlen = np.linalg.norm(msum, axis=1)
        ok = (ws > 0) & (mlen > 0)
        a_idx = active[ok]
        n = msum[ok] / mlen[ok, None]
        a = sums[ok, 1:4] / ws[ok, None]
        ya = y[a_idx]
        f = np.einsum("mc,mc->m", n, ya - a)
        first = np.isnan(f0[a_idx])
        f0[a_idx[first]] = f[first]
        grad[a_idx] = n
        pa = ya - f[:, None] * n
        proj[a_idx] = pa
        y[a_idx] = pa
        # an exact fixed point (a step that leaves y's bits unchanged) would repeat forever: stop
        go = (np.abs(f) > tol) & (pa != ya).any(axis=1)
        fresh = a_idx[:0]
        if go.all() and a_idx.size == na:
            off = pa - anchor[active]
            fresh = active[np.einsum("ij,ij->i", off, off) > slack * slack]
            continue
        active = a_idx[go]
        live = np.zeros(m, bool)
        live[active] = True
        keep = live[c_qid]
        c_qid, c_nb = c_qid[keep], c_nb[keep]
        bins = None
        if active.size:
            off = y[active] - anchor[active]
            fresh = active[np.einsum("ij,ij->i", off, off) > slack * slack]
    return f0, grad, proj


def _codes(d: np.ndarray, g: np.ndarray, band: float) -> np.ndarray:
    """(M, 4) float64 unrounded codes of distance and gradient."""
    v = np.empty((len(d), 4))
    v[:, 0] = np.asarray(d, np.float64) / band * CODE_SCALE
    v[:, 1:] = np.asarray(g, np.float64) * CODE_SCALE
    return v


def _round_codes(v: np.ndarray) -> np.ndarray:
    return (np.clip(np.round(v), -CODE_SCALE, CODE_SCALE) + CODE_SCALE).astype(np.uint8)


def kernel_mls(points: np.ndarray, normals: np.ndarray, queries: np.ndarray, h: float, device, steps: int,
               cells=None, tol: float = 0.0, grid=None):
    """The MLS projection by the ``PointsOps.mls_project`` kernel with at most ``steps``
    steps, stopping at ``|f| <= tol`` (tol 0: exactly ``steps``; a projection at a fixed
    point stops there, which changes nothing), in one launch.

    With tol > 0 two devices can stop a step apart: their results then differ by about
    tol (:func:`quantized_fields` takes FIXED_TOL h, far below a code's ARBITER_TOL).

    Args:
        points, normals: (N, 3) the point set; queries: (M, 3) float positions.
        h: the kernel width; device: a device string; steps: projection steps, >= 1.
        cells: the ``cells`` this function returned for the same points, h and device
            (the points' :class:`geosynth.geometry.pointsets.CellGrid`, already on the device).
        tol: world units, >= 0.
        grid: optional, the points' float32 :class:`geosynth.geometry.pointsets.CellGrid` for reach
            MLS_REACH h, when already built (and ``cells`` is None).

    Returns:
        ((M,) float32 signed distance (reach where no point is within reach), (M, 3)
        float32 last MLS normal (0 there), (M, 3) float64 projection, (M,) float32
        residual f at the projection (how far one more step would move it; reach where
        no point is within reach of the projection; where the projection stopped at
        ``|f| <= tol``, that last step's f), cells).
    """
    from geosynth.geometry.pointsets import MLS_REACH, CellGrid

    reach = MLS_REACH * h
    if grid is None and cells is None:
        grid = CellGrid(np.asarray(points, np.float32), np.asarray(normals, np.float32), reach)
    with PATCH_SEARCH_LOCK:
        return _kernel_mls_locked(points, normals, queries, h, device, steps, cells, tol, grid, reach)


def _kernel_mls_locked(points, normals, queries, h, device, steps, cells, tol, grid, reach):
    from geosynth.compute import checks as _checks

    if cells is None:
        backend = _checks.resolve_backend(device)
        cells = (grid, backend, backend.to_device(grid.pn), backend.to_device(grid.cell_start))
    grid, backend, pn, start = cells
    m = len(queries)
    rel = np.ascontiguousarray((np.asarray(queries, np.float64) - grid.shift).astype(np.float32)).reshape(-1)
    dist = backend.empty((m,), np.float32)
    grad = backend.empty((m * 3,), np.float32)
    proj = backend.empty((m * 3,), np.float32)
    resid = backend.empty((m,), np.float32)
    backend.mls_project(pn, start, tuple(grid.origin), 1.0 / grid.cell, tuple(int(d) for d in grid.dims),
                        1.0 / (h * h), reach, float(tol), int(steps), backend.to_device(rel), None, m, dist, grad, proj,
                        resid)
    return (dist.numpy(), grad.numpy().reshape(m, 3), proj.numpy().reshape(m, 3).astype(np.float64) + grid.shift,
            resid.numpy(), cells)


def quantized_fields(points: np.ndarray, normals: np.ndarray, queries: np.ndarray, h: float, band: float,
                     device: str | None) -> tuple[np.ndarray, int]:
    """D(S) at the queries as uint8 codes, the same on every device.

    The kernel (:func:`kernel_mls`, FIXED_STEPS steps) gives distance and gradient; each
    is mapped to a code (distance / band and each gradient component times CODE_SCALE,
    rounded, clamped, shifted to 0..254). A query with no point within reach gets the far
    value of :func:`geosynth.geometry.pointsets.pointset_distance` (far="nearest"): the signed
    distance to its nearest point's projection, that projection's normal as gradient.
    Recomputed with :func:`host_mls` (float64, the same fixed steps) and coded from that:
    values within ARBITER_TOL codes of a rounding boundary; queries whose projection has
    not converged (one more step would move it by more than RESIDUAL_TOL h: two devices
    may then disagree by more than rounding); queries whose nearest point lies within
    1e-5 of the reach (near or far is then a matter of rounding); far queries whose side
    is nearly tangential or whose nearest point's projection has not converged.

    Args:
        points, normals: (N, 3) the point set S (N >= 1) and unit normals.
        queries: (M, 3) where to sample, world units.
        h: MLS kernel width; band: the distance at which the code saturates (> 0).
        device: a device string (None: "auto").

    Returns:
        ((M, 4) uint8 codes (distance, gx, gy, gz), how many queries the host recomputed).
    """
    from geosynth.geometry.pointsets import MLS_REACH, CellGrid

    q = np.ascontiguousarray(queries, np.float64).reshape(-1, 3)
    if len(q) == 0:
        return np.zeros((0, 4), np.uint8), 0
    p = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    reach = MLS_REACH * h
    # one cell layout for the device kernel (float32) and the host's float64 steps: the nearest
    # points (exact in float64, as a k-d tree's) and the recomputation of the flagged samples
    grid = CellGrid(p.astype(np.float32), nrm.astype(np.float32), reach)
    host = _HostCells(p, nrm / np.linalg.norm(nrm, axis=1, keepdims=True), reach, grid)
    # only whether a point lies within reach (and how near where that is a matter of rounding,
    # or far) is needed: a query stops at the first point within (1 - 1e-5) reach
    nearest_d, nearest = host.nearest(q, enough=(1 - 1e-5) * reach)
    # near or far is decided on the host (float64, the same on every device); the kernel agrees
    # but where the nearest point lies at the reach, to rounding: those go to the host. Only the
    # near queries are projected (a far one's kernel values would be replaced), and in the same
    # launch the far queries' nearest points.
    is_near = nearest_d < reach
    near, far = np.flatnonzero(is_near), np.flatnonzero(~is_near)
    used, inverse = np.unique(nearest[far], return_inverse=True)
    dk, gk, proj, res, _ = kernel_mls(p, nrm, np.concatenate([q[near], p[used]]), h, device, FIXED_STEPS,
                                      tol=FIXED_TOL * h, grid=grid)
    m, k = len(q), len(near)
    gn, yp, rp = gk[k:], proj[k:], res[k:]
    d = np.empty(m)
    g = np.empty((m, 3))
    d[near], g[near] = dk[:k], gk[:k]
    flag = np.abs(nearest_d - reach) <= 1e-5 * reach
    flag[near] |= ~gk[:k].any(axis=1) | (np.abs(res[:k]) > RESIDUAL_TOL * h)
    if far.size:
        v = q[far] - yp[inverse]
        nv = gn[inverse].astype(np.float64)
        along = np.einsum("ij,ij->i", v, nv)
        length = np.linalg.norm(v, axis=1)
        d[far] = np.where(along < 0, -length, length)
        g[far] = nv
        flag[far] |= (np.abs(along) <= 1e-4 * length) | (np.abs(rp[inverse]) > RESIDUAL_TOL * h) | ~nv.any(axis=1)
    v = _codes(d, g, band)
    frac = np.abs(v - np.floor(v) - 0.5)
    flag |= ((frac < ARBITER_TOL) & (np.abs(v) < CODE_SCALE + 0.5 + ARBITER_TOL)).any(axis=1)
    bad = np.flatnonzero(flag)
    if bad.size:
        dh, gh = host_mls(p, nrm, q[bad], h, fixed=True, nearest=(nearest_d[bad], nearest[bad]), cells=host)
        v[bad] = _codes(dh, gh, band)
    return _round_codes(v), int(bad.size)


# ------------------------------------------------------------------ the search


@dataclass(frozen=True)
class SearchChoice:
    """One search's outcome: the chosen candidate (index into ``PatchSearch.origins``),
    its score, the best score, and how many candidates were within (1 + eps) of the best."""

    index: int
    score: int
    best: int
    candidates: int


class PatchSearch:
    """D(T_in) on a grid over the exemplar box, and the patch search against it.

    The grid: samples every ``cell`` from ``(box_min x, box_min y, z0)``, (nz, ny, nx)
    of them, covering B in x and y and B's height plus one cell above and below.
    A patch of ``patch`` cells (plus ``extra`` cells of E) has its origin at a grid
    sample; the candidates are every origin whose patch plus extra region lies in the
    grid (in B).

    Args:
        texture: the :class:`geosynth.pointtexture.texture.PointTexture`.
        cell: grid spacing, world units.
        patch, extra: patch side and extra-region width, in cells.
        h: MLS kernel width; band: the distance code's saturation distance.
        device: a device string.

    Attributes:
        codes: (nz, ny, nx, 4) uint8, D(T_in).
        origins: (C, 3) int64 candidate origins (z, y, x) in grid samples (z always 0).
        z0: height of the grid's first layer; shape: (nz, ny, nx).
        arbitrated: samples of D(T_in) the host recomputed.
    """

    def __init__(self, texture, cell: float, patch: int, extra: int, h: float, band: float, device):
        self.texture, self.cell, self.patch, self.extra = texture, float(cell), int(patch), int(extra)
        self.h, self.band, self.device = float(h), float(band), device
        lo, hi = texture.box_min, texture.box_max
        nx = int(np.floor((hi[0] - lo[0]) / cell + 1e-9)) + 1
        ny = int(np.floor((hi[1] - lo[1]) / cell + 1e-9)) + 1
        nz = int(np.ceil((hi[2] - lo[2]) / cell - 1e-9)) + 3
        self.z0 = float(lo[2] - cell)
        self.shape = (nz, ny, nx)
        span = self.patch + self.extra + 1
        if span > min(nx, ny):
            raise ValueError(
                f"the patch ({self.patch} cells) plus its extra region ({self.extra}) spans {span} samples but the "
                f"exemplar's box is only {nx} x {ny} samples of the search grid; use a smaller patch (or a larger "
                "exemplar box / resolution).")
        self.origin_xy = lo[:2].copy()
        pts = self.sample_points(np.zeros(3, np.int64), np.array(self.shape))
        codes, self.arbitrated = quantized_fields(texture.points, texture.normals, pts, self.h, self.band, device)
        self.codes = codes.reshape(nz, ny, nx, 4)
        oy, ox = np.meshgrid(np.arange(ny - span + 1), np.arange(nx - span + 1), indexing="ij")
        self.origins = np.stack([np.zeros(ox.size, np.int64), oy.ravel(), ox.ravel()], axis=1)
        self._scorers: dict = {}
        self._grid_dev = None

    def sample_points(self, start: np.ndarray, count: np.ndarray) -> np.ndarray:
        """World positions of the grid samples ``start + (k, j, i)`` for (k, j, i) < count,
        in (z, y, x) C order, (prod(count), 3) float64."""
        k, j, i = np.meshgrid(*(start[a] + np.arange(count[a]) for a in range(3)), indexing="ij")
        return np.stack([self.origin_xy[0] + i.ravel() * self.cell, self.origin_xy[1] + j.ravel() * self.cell,
                         self.z0 + k.ravel() * self.cell], axis=1)

    def window_world(self, origin: np.ndarray) -> np.ndarray:
        """(2,) world xy of candidate origin (z, y, x)'s first sample."""
        return self.origin_xy + self.cell * np.array([origin[2], origin[1]], np.float64)

    def overlap_offsets(self, sides) -> np.ndarray:
        """(K, 3) int64 offsets (dz, dy, dx) of the overlap samples of a patch: the columns
        within ``width`` cells of each given side ((side, width) with side in "-x", "-y",
        "+x", "+y"), every height; K = 0 for no side."""
        p = self.patch
        jy, ix = np.meshgrid(np.arange(p), np.arange(p), indexing="ij")
        mask = np.zeros((p, p), bool)
        for side, width in sides:
            w = int(width)
            if side == "-x":
                mask |= ix < w
            elif side == "+x":
                mask |= ix >= p - w
            elif side == "-y":
                mask |= jy < w
            elif side == "+y":
                mask |= jy >= p - w
            else:
                raise ValueError(f"side must be one of -x, +x, -y, +y, got {side!r}.")
        cols = np.argwhere(mask)  # (dy, dx)
        nz = self.shape[0]
        dz = np.repeat(np.arange(nz), len(cols))
        return np.column_stack([dz, np.tile(cols[:, 0], nz), np.tile(cols[:, 1], nz)]).astype(np.int64)

    def _scorer(self, offsets: np.ndarray):
        from geosynth.compute.backend import to_device
        from geosynth.compute.scoring import GatherScorer

        key = offsets.tobytes()
        s = self._scorers.get(key)
        if s is None:
            if self._grid_dev is None:
                self._grid_dev = to_device(self.codes, self.device)
            s = GatherScorer(self._grid_dev, offsets, device=self.device)
            self._scorers[key] = s
        return s

    def scores(self, offsets: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(C,) uint32 SSD of the query codes ``values`` ((K, 4) uint8 at ``offsets``)
        against every candidate's window of D(T_in), by the gather kernel."""
        return self._scorer(offsets)(values, origins=self.origins)

    def choose(self, offsets: np.ndarray, values: np.ndarray, eps: float, rng: np.random.Generator) -> SearchChoice:
        """Steps 2 and 3 of Sec. 4: the candidates within (1 + eps) of the best score,
        one drawn with ``rng``. With no offsets (the seed patch) every candidate is in."""
        from geosynth.compute.selection import random_pick, tolerance_threshold

        if len(offsets) == 0:
            i = random_pick(np.arange(len(self.origins)), rng)
            return SearchChoice(i, 0, 0, len(self.origins))
        # the scores are exact integers (uint32): selected on the host, after the one read-back
        # they need anyway, they are what selection.argmin / within_tolerance give on any device
        with PATCH_SEARCH_LOCK:
            sc = self._scorer(offsets)(values, origins=self.origins)
        best = int(np.argmin(sc))  # the lowest index on ties
        near = np.flatnonzero(sc <= tolerance_threshold(sc[best], eps, sc.dtype))
        i = random_pick(near, rng)
        return SearchChoice(int(i), int(sc[i]), int(sc[best]), int(len(near)))


def brute_force_scores(codes: np.ndarray, origins: np.ndarray, offsets: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The search's scores in plain NumPy (int64), for tests: for each origin, the sum of
    squared code differences over the offsets and the 4 channels."""
    out = np.zeros(len(origins), np.int64)
    v = values.astype(np.int64)
    for c, o in enumerate(origins):
        idx = o[None, :] + offsets
        win = codes[idx[:, 0], idx[:, 1], idx[:, 2]].astype(np.int64)
        out[c] = int(((win - v) ** 2).sum())
    return out
