"""How does a warped patch meet the points already there? The blending step of "Geometry
texture synthesis with point-set surfaces" (Sec. 5.3, blending; and step 8 of Sec. 4,
the final border cut).

After warping (Sec. 5.2) small gaps remain between the warped patch F'_k and the
output's neighbourhood N_k. Blending removes them with a progressive linear
interpolation over the overlap: each point p' of F'_k moves to

    p'' = (1 - r) p' + r c,        n'' = normalize((1 - r) n' + r n_c)

(the paper's form; by default :func:`blend_patch` moves by the gap between the two MLS
surfaces instead, ``p'' = p' + r (c - c')`` with c' the same construction on F'_k's own
MLS surface, which leaves a patch that already matches N_k where it is)

where r is its interpolation parameter (:func:`overlap_ramp`: 1 at the overlap's outer
edge, where N_k is kept, 0 where the patch is kept) and c its counterpart on N_k's MLS
surface with the MLS normal n_c there. The counterpart is the intersection of the line
through p' along +-n' with the surface (the paper's limited ray intersection, which
keeps points over a valley from sliding to its sides), else the quasi-orthogonal
projection of p' (Adamson and Alexa).

The MLS surface is the one of :mod:`geosynth.geometry.pointsets` (Gaussian weights of width h cut
off at 3h, ``a(x)`` the weighted mean of the points, ``n(x)`` the normalized weighted
mean of the normals, ``f(x) = n(x) . (x - a(x))``), evaluated here on the host in
float64 over each query's ``MLS_NEIGHBOURS`` nearest points within reach: the blended
positions are output positions that later searches read, and float64 host arithmetic
makes them the same bits whichever device runs the rest. The device's float32 MLS
kernel (:func:`geosynth.geometry.pointsets.project_points`) agrees with another device's only to
about 1e-6, and a pipeline that fed such positions to its next search would diverge
between devices. The host evaluation is a compiled host step
(:mod:`geosynth.kernels.host_blend`, Warp's CPU device for every run, one thread per
point doing its k nearest points, every iteration and the fallback; see
:mod:`geosynth.compute.host_steps`); :class:`MLSSurface` and the ``_numpy`` functions are its
NumPy twins (the oracles of tests/test_blend_kernels.py). ``device=`` is therefore only
checked (so that a bad device string fails here as elsewhere); it never changes the
result.

Choices where the paper is vague: the line search is the ray-plane iteration of
Adamson and Alexa's ray tracing of point-set surfaces (``t <- t - f(x + t n') / (n(y) . n')``
from t = 0), which finds the crossing nearest p' along the line, within ``max_ray``
spacings; a crossing whose surface faces away from n' (n_c . n' < 0.2) is refused, and
so is a projection that does or that lies farther than ``max_ray`` spacings: such a
point has no counterpart (N_k lacks its geometry there) and is left where the warp put it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from geosynth.compute.checks import as_points3, as_unit_vectors, check_positive
from geosynth.core.config import BLEND_TABLES

__all__ = [
    "NO_SURFACE",
    "PROJECTION",
    "RAY",
    "MLSSurface",
    "border_cut",
    "blend_patch",
    "counterparts",
    "cut_pieces",
    "has_pieces",
    "overlap_ramp",
    "pieces",
    "relax_points",
    "seam_error",
    "seam_errors",
]

MLS_NEIGHBOURS = 24  # nearest points within reach that enter a host MLS evaluation
_REACH = 3.0  # weights cut off at 3h, as in geosynth.geometry.pointsets
_TOL = 1e-3  # |f| <= _TOL * h ends a line search or a projection
_LINE_ITER = 12
_PROJ_ITER = 20
_MIN_FACING = 0.2  # a counterpart whose MLS normal faces n' less than this is refused
_MIN_SLOPE = 0.3  # the line search stops where the line grazes the surface (|n(y) . n'| below)

NO_SURFACE, RAY, PROJECTION = 0, 1, 2  # how a counterpart was found (counterparts())


# ------------------------------------------------------------------------ input checks


def _box(box_min, box_max) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(box_min, np.float64).reshape(-1)
    hi = np.asarray(box_max, np.float64).reshape(-1)
    if lo.shape not in ((2,), (3,)) or hi.shape != lo.shape:
        raise ValueError(f"box_min and box_max must be (2,) or (3,) arrays of the same shape, got {lo.shape} and {hi.shape}.")
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise ValueError("box_min and box_max must be finite.")
    if not (hi[:2] > lo[:2]).all():
        raise ValueError(f"the box must have a positive x and y extent, got box_min {lo} and box_max {hi}.")
    return lo[:2], hi[:2]


def _check_device(device) -> None:
    """A malformed or absent device string fails here, as in every other call."""
    if device is not None:
        from geosynth.compute.backend import get_backend

        get_backend(device)


# ------------------------------------------------------------------------ the ramp


_SIDES = ("-x", "+x", "-y", "+y")


def overlap_ramp(points, box_min, box_max, overlap_x: float, overlap_y: float,
                 sides: Iterable[str] = ("-x", "-y")) -> np.ndarray:
    """Each point's interpolation parameter across the overlap (Sec. 5.3, Fig. 3 c).

    For each listed side of the box, ``1 - d / overlap`` clipped to [0, 1], d the
    point's distance inside the box from that side (overlap_x for the x sides,
    overlap_y for the y sides); the largest over the sides. So 1 on the box's edge and
    beyond it (where N_k is kept), falling linearly to 0 at the overlap's inner edge
    (where the patch is kept). The scan-line order overlaps the -x and -y sides; a
    tileable output that wraps adds "+x" and/or "+y".

    Args:
        points: (M, 2) or (M, 3) float positions (x, y used).
        box_min, box_max: (2,) or (3,) the patch's box B_k.
        overlap_x, overlap_y: overlap widths (world units, >= 0; 0 leaves that side out).
        sides: any of "-x", "+x", "-y", "+y".

    Returns:
        (M,) float64 in [0, 1].
    """
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ValueError(f"points must have shape (M, 2) or (M, 3), got {p.shape}.")
    lo, hi = _box(box_min, box_max)
    sides = tuple(sides)
    unknown = [s for s in sides if s not in _SIDES]
    if unknown:
        raise ValueError(f"sides must be among {_SIDES}, got {unknown}.")
    widths = {}
    for name, v in (("overlap_x", overlap_x), ("overlap_y", overlap_y)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not (
            math.isfinite(float(v)) and float(v) >= 0
        ):
            raise ValueError(f"{name} must be a finite number >= 0, got {v!r}.")
        widths[name] = float(v)
    ramp = np.zeros(len(p))
    for s in sides:
        axis = 0 if s[1] == "x" else 1
        width = widths["overlap_x" if axis == 0 else "overlap_y"]
        if width == 0:
            continue
        d = p[:, axis] - lo[axis] if s[0] == "-" else hi[axis] - p[:, axis]
        ramp = np.maximum(ramp, np.clip(1.0 - d / width, 0.0, 1.0))
    return ramp


# ------------------------------------------------------------------------ the MLS surface on the host


class MLSSurface:
    """The MLS surface of an oriented point set, evaluated on the host in float64.

    Args:
        points, normals: (K, 3) float; normals are normalized.
        radius: the Gaussian width h (world units).
        neighbours: the nearest points (within reach 3h) that enter each evaluation.
    """

    def __init__(self, points, normals, radius: float, neighbours: int = MLS_NEIGHBOURS):
        from geosynth.core.neighbours import NeighbourIndex

        self.p = as_points3("neighbourhood_points", points)
        self.n = as_unit_vectors("neighbourhood_normals", as_points3("neighbourhood_normals", normals, len(self.p))) if len(self.p) else np.zeros((0, 3))
        self.h = check_positive("radius", radius)
        self.reach = _REACH * self.h
        self.k = int(max(1, min(neighbours, len(self.p))))
        self.tree = NeighbourIndex(self.p) if len(self.p) else None
        self.pn = np.concatenate([self.p, self.n], axis=1)

    def neighbours(self, x: np.ndarray):
        """``(nb, valid, sq)``: (m, k, 6) positions and normals of each query's k nearest
        points, (m, k) whether each lies within reach and (m, k) each one's squared norm
        |p|^2 (reused by every evaluation with these neighbours; inf where not valid). Any rows of the three
        (:func:`_rows`) are the neighbours of those queries."""
        m = len(x)
        _, idx = self.tree.query(x, self.k, upper=self.reach)
        valid = idx < len(self.p)
        # np.take: the same rows as fancy indexing, several times faster on (K, 6) arrays
        nb = np.take(self.pn, np.where(valid, idx, 0), axis=0)
        pos = nb[:, :, :3]
        sq = np.einsum("mkj,mkj->mk", pos, pos)
        sq[~valid] = np.inf  # an absent neighbour is infinitely far: weight 0 in evaluate()
        return nb, valid, sq

    def evaluate(self, x: np.ndarray, gathered=None):
        """``(f, n, support)`` at (m, 3) points: the implicit function (m,), the MLS
        normal (m, 3) (zero without support) and whether any point lies within reach.

        ``gathered``: :meth:`neighbours` at nearby points, to use instead of each query's
        own nearest points."""
        m = len(x)
        if self.tree is None or m == 0:
            return np.zeros(m), np.zeros((m, 3)), np.zeros(m, bool)
        nb, valid, sq = self.neighbours(x) if gathered is None else gathered
        pos = nb[:, :, :3]
        d2 = sq - 2.0 * np.einsum("mkj,mj->mk", pos, x) + np.einsum("mj,mj->m", x, x)[:, None]
        w = d2 * (-1.0 / (self.h * self.h))
        np.exp(w, out=w)
        w[d2 > self.reach * self.reach] = 0.0  # beyond reach, or not valid (sq = inf)
        wsum = w.sum(axis=1)
        sums = np.einsum("mk,mkc->mc", w, nb)  # sum w p, sum w n
        nn = sums[:, 3:]
        length = np.sqrt(np.einsum("mj,mj->m", nn, nn))
        support = (wsum > 0) & (length > 1e-12)
        nn = nn / np.where(support, length, 1.0)[:, None]
        nn[~support] = 0.0
        # f = n . (x - a), a = sum w p / sum w
        f = np.einsum("mj,mj->m", nn, x - sums[:, :3] / np.where(support, wsum, 1.0)[:, None])
        return f, nn, support

    def _iterate(self, x, step_fn, max_iter, gathered=None):
        """Run ``step_fn`` (one projection or line step) from x until each query
        converges. Each query's neighbours are gathered once, where it starts, and
        gathered again where it converged if that is more than h away (up to 3
        times): the surface a query sees is the MLS surface of the k points nearest
        to a place within h of where it converged."""
        y = x.copy()
        normal = np.zeros_like(x)
        ok = np.zeros(len(x), bool)
        state = np.zeros(len(x))  # the line parameter t (unused by projections)
        todo = np.arange(len(x))
        for _round in range(3):
            if todo.size == 0:
                break
            start = y[todo].copy()
            near = gathered if (_round == 0 and gathered is not None) else self.neighbours(start)
            active = np.arange(todo.size)
            conv_here = np.zeros(todo.size, bool)
            for it in range(max_iter):
                if active.size == 0:
                    break
                q = todo[active]
                g = near if it == 0 else _rows(near, active)
                f, nn, sup = self.evaluate(np.take(y, q, axis=0), g)
                normal[q] = nn
                conv = sup & (np.abs(f) <= _TOL * self.h)
                conv_here[active[conv]] = True
                go = step_fn(q, f, nn, sup & ~conv, y, state)
                active = active[go]
            moved = np.linalg.norm(y[todo] - start, axis=1) > self.h
            ok[todo[conv_here & ~moved]] = True
            todo = todo[conv_here & moved]
        ok[todo] = True  # converged again after the last gathering
        return y, normal, ok, state

    def project(self, x: np.ndarray, max_move: float = math.inf, gathered=None):
        """Quasi-orthogonal projection (m, 3) -> ``(y, n(y), ok)``; a query that moves
        farther than ``max_move`` from x is given up (ok False). ``gathered``: the
        queries' :meth:`neighbours` at x, when already known."""

        def step(q, f, nn, go, y, state):
            qg = q[go]
            y[qg] -= f[go, None] * nn[go]
            if math.isfinite(max_move):
                far = np.einsum("mj,mj->m", y[qg] - x[qg], y[qg] - x[qg]) > max_move * max_move
                go[np.flatnonzero(go)[far]] = False
            return go

        y, normal, ok, _ = self._iterate(x, step, _PROJ_ITER, gathered)
        return y, normal, ok

    def intersect_line(self, x: np.ndarray, d: np.ndarray, tmax: float, gathered=None):
        """The crossing of the lines ``x + t d`` (d unit) with the surface nearest x,
        |t| <= tmax, by the ray-plane iteration: ``(t, n at the crossing, ok)``.
        ``gathered``: the queries' :meth:`neighbours` at x, when already known."""

        def step(q, f, nn, go, y, state):
            slope = np.einsum("mj,mj->m", nn, np.take(d, q, axis=0))
            go = go & (np.abs(slope) >= _MIN_SLOPE)
            qg = q[go]
            state[qg] -= f[go] / slope[go]
            inside = np.abs(state[qg]) <= tmax
            state[qg[~inside]] = 0.0
            y[qg] = x[qg] + state[qg, None] * d[qg]
            go[np.flatnonzero(go)[~inside]] = False
            return go

        _, normal, ok, t = self._iterate(x, step, _LINE_ITER, gathered)
        return t, normal, ok


def _rows(gathered, rows):
    """The :meth:`MLSSurface.neighbours` of the queries ``rows`` out of those of all."""
    return tuple(np.take(a, rows, axis=0) for a in gathered)


# ------------------------------------------------------------------------ the compiled host steps

_CELL_REACHES = 0.5  # the kernels' cell grid: cells half a reach (1.5 h) wide (the speed only)
# Launch width of the host_blend kernels: each worker thread does every _WORKERS-th point with one
# scratch slot, hot in the cache (one slot per point made every point's lists cold memory).
_WORKERS = 4


def _list_room(k: int) -> int:
    """Room of a compiled neighbour list of k (kernels.host_blend.nearest): candidates
    within reach are collected unsorted and cut to the k nearest when it is full."""
    return 4 * k + 8


def _gauss_table():
    """kernels.host_blend.gauss()'s table exp(-j / GAUSS_STEPS), j = 0 .. 9 GAUSS_STEPS + 1
    (float64, libm's exp), wrapped for Warp once per thread (``geosynth.core.config.BLEND_TABLES``)."""
    held = getattr(BLEND_TABLES, "gauss", None)
    if held is None:
        from geosynth.compute.host_steps import host_array
        from geosynth.kernels.host_blend import GAUSS_STEPS

        held = host_array(np.exp(-np.arange(9 * int(GAUSS_STEPS) + 2) / float(GAUSS_STEPS)), np.float64)
        BLEND_TABLES.gauss = held
    return held[0]


def _scratch(entries: int):
    """(int32, float64) Warp scratch arrays of ``entries`` entries (the workers' lists)."""
    from geosynth.compute.host_steps import host_array

    return host_array(np.empty(entries, np.int32))[0], host_array(np.empty(entries, np.float64))[0]


class _CellGrid:
    """An oriented point set binned into a dense grid of cubic cells, for the compiled host
    steps (:mod:`geosynth.kernels.host_blend`, whose ``nearest`` finds a query's k nearest
    points in it exactly, whatever the cell size).

    Args:
        points: (K, 3) float64, K >= 1; normals: (K, 3) float64 unit normals.
        cell: the cell side (world units, > 0); made larger when the points' box would
            need more than ``4 K + 64`` cells (scattered points: fewer, fuller cells).
        auto_k: > 0: instead of ``cell``, cells about as wide as a point's ``auto_k``
            nearest on a surface (0.5 sqrt(area auto_k / K), area the product of the
            box's two longest sides).

    Attributes (host arrays, kept alive with their Warp views): ``pn`` (K * 6,) float64
    points and normals sorted by linear cell index ``(cz * ny + cy) * nx + cx`` (stably:
    input order within a cell), ``ids`` (K,) int32 each sorted point's input index,
    ``cell_start`` (nx * ny * nz + 1,) int32, ``origin`` (3,) the points' minimum corner,
    ``cell``, ``dims`` (nx, ny, nz).
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, cell: float, auto_k: int = 0):
        from geosynth.compute.host_steps import host_array, host_launch
        from geosynth.kernels.host_blend import build_grid_kernel

        count = len(points)
        max_cells = 4 * count + 64
        wp_p, self._p = host_array(points, np.float64)
        wp_n, self._n = host_array(normals, np.float64)
        self.wp_pn, self.pn = host_array(np.empty(6 * count, np.float64))
        self.wp_ids, self.ids = host_array(np.empty(count, np.int32))
        self.wp_start, self.cell_start = host_array(np.empty(max_cells + 1, np.int32))
        wp_cursor, self._cursor = host_array(np.empty(max_cells, np.int32))
        wp_cell_of, self._cell_of = host_array(np.empty(count, np.int32))
        wp_info, info = host_array(np.empty(7, np.float64))
        host_launch(build_grid_kernel, 1, [wp_p, wp_n, count, float(cell), int(auto_k), max_cells, self.wp_pn, self.wp_ids,
                                          self.wp_start, wp_cursor, wp_cell_of, wp_info])
        self.origin, self.cell = info[:3].copy(), float(info[3])
        self.dims = tuple(int(v) for v in info[4:7])

    def launch_args(self) -> list:
        """The grid's leading arguments of the host_blend kernels."""
        import warp as wp

        return [self.wp_pn, self.wp_ids, self.wp_start, wp.vec3d(*(float(v) for v in self.origin)),
                self.cell, *self.dims]


def nearest_k(points: np.ndarray, queries: np.ndarray, k: int, distance_upper_bound: float | None = None, *,
              grid: _CellGrid | None = None):
    """The k nearest points of each query, exact in float64, in pykdtree's form, by the
    compiled host step ``host_blend.knn_kernel`` (its workers split over the cores; the
    same bits on any number of them).

    Args:
        points: (N, 3) float64, N >= 1; queries: (M, 3) float64; k: 1 <= k <= N.
        distance_upper_bound: only points strictly nearer count (world units; None: all).
        grid: the points' cell grid from :func:`knn_grid` (the same points; any k: the
            cell size sets the speed only), when a caller queries them more than once.

    Returns:
        ``(distances, indices)``: (M, k) float64, nearest first (ties by lower index, as
        pykdtree's), and (M, k) int64; where fewer than k lie within the bound, the rest
        are inf and N.
    """
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels.host_blend import knn_kernel

    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    q = np.ascontiguousarray(queries, np.float64).reshape(-1, 3)
    n, m, k = len(p), len(q), int(k)
    if m == 0:
        return np.zeros((0, k)), np.zeros((0, k), np.int64)
    if grid is None:
        grid = knn_grid(p, k)
    reach = math.inf if distance_upper_bound is None else float(distance_upper_bound)
    if not reach < 1e150:  # every point: a reach whose square is still finite
        reach = 1e150
    cap = _list_room(k)
    workers = min(m, _WORKERS)
    wp_nbr, wp_nd2 = _scratch(workers * cap)
    wp_d, d = host_array(np.empty((m, k), np.float64))
    wp_i, idx = host_array(np.empty((m, k), np.int32))
    host_launch(knn_kernel, workers, [*grid.launch_args(), k, cap, reach, n, host_array(q, np.float64)[0], wp_nbr, wp_nd2,
                                      wp_d, wp_i, m, workers], split=True, min_part=1)
    return d, idx.astype(np.int64)


def knn_grid(points: np.ndarray, k: int) -> _CellGrid:
    """The cell grid :func:`nearest_k` searches for (N >= 1, 3) float64 ``points``: cells
    about as wide as a query's k nearest on a surface (the cell size sets the speed only);
    the normals' slots unused (the points themselves fill them)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    return _CellGrid(p, p, 0.0, auto_k=int(k))


def _counterparts_compiled(p: np.ndarray, n: np.ndarray, nb_p: np.ndarray, nb_n: np.ndarray, h: float,
                           tmax: float):
    """:func:`counterparts`'s search, one ``host_blend.counterparts_kernel`` thread per point:
    p, n (M, 3) float64 points and unit normals, nb_p, nb_n (K >= 1, 3) N_k's points and
    unit normals, h the MLS width, tmax the line's reach and the farthest projection
    (world units). Returns ``(positions, normals, how)`` as :func:`counterparts` does."""
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels.host_blend import counterparts_kernel

    m = len(p)
    k = int(max(1, min(MLS_NEIGHBOURS, len(nb_p))))
    reach = _REACH * h
    grid = _CellGrid(nb_p, nb_n, _CELL_REACHES * reach)
    wp_x, x = host_array(p, np.float64)
    wp_d, d = host_array(n, np.float64)
    cap = _list_room(k)
    wp_nbr, wp_nd2 = _scratch(_WORKERS * 2 * cap)
    wp_op, out_p = host_array(np.empty((m, 3), np.float64))
    wp_on, out_n = host_array(np.empty((m, 3), np.float64))
    wp_how, how = host_array(np.empty(m, np.int8))
    host_launch(counterparts_kernel, min(m, _WORKERS),
                [_gauss_table(), *grid.launch_args(), k, cap, h, reach, _TOL * h, tmax, _MIN_SLOPE, _MIN_FACING, _LINE_ITER,
                 _PROJ_ITER, wp_x, wp_d, wp_nbr, wp_nd2, wp_op, wp_on, wp_how, m, min(m, _WORKERS)], split=True, min_part=1)
    return out_p, out_n, how


def _blend_compiled(p: np.ndarray, n: np.ndarray, ps: np.ndarray, ns: np.ndarray, r: np.ndarray, c: np.ndarray,
                    nc: np.ndarray, how: np.ndarray, h: float, relative: bool):
    """:func:`blend_patch`'s blend by ``host_blend.blend_kernel``: p, n (M, 3) float64 F'_k
    and its unit normals (its own MLS surface), ps, ns (s, 3) the points to blend (those
    with ramp > 0), r (s,) their ramp and c, nc, how their :func:`counterparts`. Returns
    (s, 3) float64 blended points and unit normals."""
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels.host_blend import blend_kernel

    s = len(ps)
    k = int(max(1, min(MLS_NEIGHBOURS, len(p))))
    reach = _REACH * h
    grid = _CellGrid(p, n, _CELL_REACHES * reach) if relative else None
    args = grid.launch_args() if relative else [*_CellGrid(p[:1], n[:1], reach).launch_args()]
    wp_x, x = host_array(ps, np.float64)
    wp_d, d = host_array(ns, np.float64)
    wp_r, rr = host_array(r, np.float64)
    wp_c, cc = host_array(c, np.float64)
    wp_nc, ncc = host_array(nc, np.float64)
    wp_how, hh = host_array(how, np.int8)
    cap = _list_room(k)
    wp_nbr, wp_nd2 = _scratch(_WORKERS * cap)
    wp_op, out_p = host_array(np.empty((s, 3), np.float64))
    wp_on, out_n = host_array(np.empty((s, 3), np.float64))
    host_launch(blend_kernel, min(s, _WORKERS), [_gauss_table(), *args, k, cap, h, reach, _MIN_SLOPE, int(bool(relative)), wp_x, wp_d, wp_r, wp_c,
                                  wp_nc, wp_how, wp_nbr, wp_nd2, wp_op, wp_on, s, min(s, _WORKERS)], split=True, min_part=1)
    return out_p, out_n


# ------------------------------------------------------------------------ counterparts and blending


def counterparts(points, normals, neighbourhood_points, neighbourhood_normals, spacing: float,
                 device: str | None = None, *, radius: float | None = None, max_ray: float = 4.0):
    """Each point's counterpart on N_k's MLS surface (Sec. 5.3): the crossing of the line
    through the point along +-its normal nearest to it (within ``max_ray`` spacings),
    else its projection (if within ``max_ray`` spacings too: blending closes small gaps,
    it does not move geometry N_k lacks onto another part of N_k).

    Computed by the compiled host step ``geosynth.kernels.host_blend.counterparts_kernel``
    (Warp's CPU device, float64, one thread per point); :func:`_counterparts_numpy`
    is its NumPy twin (:class:`MLSSurface`), equal to a float64 tolerance.

    Args:
        points, normals: (M, 3) float, the warped patch's points F'_k (normals need not
            be unit length).
        neighbourhood_points, neighbourhood_normals: (K, 3) float, N_k.
        spacing: the point spacing (world units, > 0).
        device: the run's device string, only checked: the evaluation runs on the
            host in float64, the same bits on every device (see the module docstring).
        radius: the MLS width h, default 2 spacings.
        max_ray: the line search's reach and the farthest projection, in spacings.

    Returns:
        ``(positions, normals, how)``: (M, 3) float64 counterparts (the point itself
        where there is none), (M, 3) float64 unit MLS normals there (the point's own
        normal where there is none), (M,) int8: 1 ray intersection, 2 projection, 0 no
        usable surface in reach.
    """
    return _counterparts(points, normals, neighbourhood_points, neighbourhood_normals, spacing, device,
                         radius, max_ray, compiled=True)


def _counterparts_numpy(points, normals, neighbourhood_points, neighbourhood_normals, spacing: float,
                        device: str | None = None, *, radius: float | None = None, max_ray: float = 4.0):
    """:func:`counterparts` in NumPy on :class:`MLSSurface` (pykdtree neighbours): the
    oracle of the compiled host step. Same arguments and results."""
    return _counterparts(points, normals, neighbourhood_points, neighbourhood_normals, spacing, device,
                         radius, max_ray, compiled=False)


def _checked_search(spacing, radius, max_ray, device):
    """counterparts()'s scalar arguments checked: (spacing, h, max_ray), floats > 0."""
    spacing = check_positive("spacing", spacing)
    h = 2.0 * spacing if radius is None else check_positive("radius", radius)
    max_ray = check_positive("max_ray", max_ray)
    _check_device(device)
    return spacing, h, max_ray


def _checked_neighbourhood(neighbourhood_points, neighbourhood_normals):
    """N_k checked: ((K, 3) float64 points, (K, 3) unit normals)."""
    nb_p = as_points3("neighbourhood_points", neighbourhood_points)
    nb_n = as_unit_vectors("neighbourhood_normals", as_points3("neighbourhood_normals", neighbourhood_normals,
                                                               len(nb_p))) if len(nb_p) else np.zeros((0, 3))
    return nb_p, nb_n


def _counterparts(points, normals, neighbourhood_points, neighbourhood_normals, spacing, device, radius,
                  max_ray, *, compiled: bool):
    p = as_points3("points", points)
    n = as_unit_vectors("normals", as_points3("normals", normals, len(p))) if len(p) else np.zeros((0, 3))
    spacing, h, max_ray = _checked_search(spacing, radius, max_ray, device)
    if compiled:
        nb_p, nb_n = _checked_neighbourhood(neighbourhood_points, neighbourhood_normals)
        if len(p) == 0 or len(nb_p) == 0:
            return p.copy(), n.copy(), np.zeros(len(p), np.int8)
        return _counterparts_compiled(p, n, nb_p, nb_n, h, max_ray * spacing)
    surface = MLSSurface(neighbourhood_points, neighbourhood_normals, h)
    out_p, out_n = p.copy(), n.copy()
    how = np.zeros(len(p), np.int8)
    if len(p) == 0 or surface.tree is None:
        return out_p, out_n, how
    near = surface.neighbours(p)  # both searches start at p
    t, nc, ok = surface.intersect_line(p, n, max_ray * spacing, near)
    ok &= np.einsum("mj,mj->m", nc, n) >= _MIN_FACING
    out_p[ok] = p[ok] + t[ok, None] * n[ok]
    out_n[ok] = nc[ok]
    how[ok] = RAY
    rest = np.flatnonzero(~ok)
    if rest.size:
        y, ny, good = surface.project(p[rest], max_move=max_ray * spacing, gathered=_rows(near, rest))
        good &= np.einsum("mj,mj->m", ny, n[rest]) >= _MIN_FACING
        good &= np.linalg.norm(y - p[rest], axis=1) <= max_ray * spacing
        keep = rest[good]
        out_p[keep] = y[good]
        out_n[keep] = ny[good]
        how[keep] = PROJECTION
    return out_p, out_n, how


def blend_patch(points, normals, ramp, neighbourhood_points, neighbourhood_normals, spacing: float,
                device: str | None = None, *, radius: float | None = None, max_ray: float = 4.0,
                relative: bool = True):
    """Blend the warped patch F'_k into N_k (Sec. 5.3): ``p'' = p' + r (c - c')`` and
    ``n'' = normalize(n' + r (n_c - n_c'))`` with c, n_c from :func:`counterparts`.

    ``c'`` is the same construction on F'_k's own MLS surface (the crossing of the same
    line with it, or its projection onto it) and n_c' its MLS normal at p': each point
    moves by the gap between the two MLS surfaces and its normal turns by the difference
    of their normals, so that where they already agree nothing changes. With
    ``relative=False``, ``c' = p'``: the paper's literal ``p'' = (1 - r) p' + r c`` and
    ``n'' = normalize((1 - r) n' + r n_c)``, which puts the points of the outer edge on N_k's MLS surface; on curved geometry (rings,
    threads) that surface lies inside the sampled one by the MLS smoothing, and a blended
    patch that matched N_k exactly would come out shrunk there.

    Computed by the compiled host steps of ``geosynth.kernels.host_blend`` (Warp's CPU
    device, float64, one thread per point); :func:`_blend_patch_numpy` is the NumPy twin,
    equal to a float64 tolerance.

    Args:
        points, normals: (M, 3) float F'_k.
        ramp: (M,) float in [0, 1], each point's parameter (:func:`overlap_ramp`).
        neighbourhood_points, neighbourhood_normals: (K, 3) float N_k (K may be 0).
        spacing, device, radius, max_ray: as in :func:`counterparts`.
        relative: move by the gap between the surfaces (True) or onto N_k's (False).

    Returns:
        ``(points, normals)``: (M, 3) float64 blended positions and unit normals.
        Points with r == 0, or with no usable surface of N_k in reach, are unchanged.
    """
    return _blend_patch(points, normals, ramp, neighbourhood_points, neighbourhood_normals, spacing, device,
                        radius, max_ray, relative, compiled=True)


def _blend_patch_numpy(points, normals, ramp, neighbourhood_points, neighbourhood_normals, spacing: float,
                       device: str | None = None, *, radius: float | None = None, max_ray: float = 4.0,
                       relative: bool = True):
    """:func:`blend_patch` in NumPy on :class:`MLSSurface` (:func:`_counterparts_numpy`): the
    oracle of the compiled host steps. Same arguments and results."""
    return _blend_patch(points, normals, ramp, neighbourhood_points, neighbourhood_normals, spacing, device,
                        radius, max_ray, relative, compiled=False)


def _blend_patch(points, normals, ramp, neighbourhood_points, neighbourhood_normals, spacing, device, radius,
                 max_ray, relative, *, compiled: bool):
    from geosynth.compute import checks as _checks

    p = as_points3("points", points)
    n = as_unit_vectors("normals", as_points3("normals", normals, len(p))) if len(p) else np.zeros((0, 3))
    r = np.asarray(ramp, np.float64).reshape(-1)
    if r.shape != (len(p),):
        raise ValueError(f"ramp must have shape ({len(p)},) to match points, got {np.shape(ramp)}.")
    if not (np.isfinite(r).all() and (r >= 0).all() and (r <= 1).all()):
        raise ValueError("ramp must hold finite values in [0, 1] (see overlap_ramp).")
    if relative:
        _checks.check_bool("relative", relative)
    out_p, out_n = p.copy(), n.copy()
    sel = np.flatnonzero(r > 0)
    if sel.size == 0 or len(np.asarray(neighbourhood_points).reshape(-1, 3)) == 0:
        check_positive("spacing", spacing)
        return out_p, out_n
    if compiled:  # counterparts() without checking p[sel] and n[sel] again
        spacing, h, max_ray = _checked_search(spacing, radius, max_ray, device)
        nb_p, nb_n = _checked_neighbourhood(neighbourhood_points, neighbourhood_normals)
        ps, ns = p[sel], n[sel]
        c, nc, how = _counterparts_compiled(ps, ns, nb_p, nb_n, h, max_ray * spacing)
        out_p[sel], out_n[sel] = _blend_compiled(p, n, ps, ns, r[sel], c, nc, how, h, relative)
        return out_p, out_n
    c, nc, how = _counterparts_numpy(p[sel], n[sel], neighbourhood_points, neighbourhood_normals, spacing, device,
                                     radius=radius, max_ray=max_ray)
    h = 2.0 * spacing if radius is None else check_positive("radius", radius)
    own = p[sel].copy()
    rs = r[sel, None]
    if relative:
        f_own, n_own, sup = np.zeros(sel.size), np.zeros((sel.size, 3)), np.zeros(sel.size, bool)
        found = np.flatnonzero(how != NO_SURFACE)  # only where N_k gave a counterpart
        if found.size:
            f_own[found], n_own[found], sup[found] = MLSSurface(p, n, h).evaluate(p[sel[found]])
        slope = np.einsum("mj,mj->m", n_own, n[sel])
        ray = (how == RAY) & sup & (np.abs(slope) >= _MIN_SLOPE)
        own[ray] -= (f_own[ray] / slope[ray])[:, None] * n[sel][ray]  # one ray-plane step
        proj = (how == PROJECTION) & sup
        own[proj] -= f_own[proj, None] * n_own[proj]  # one projection step
        # Normals likewise: turned by the difference of the two MLS normals.
        turn = np.where((ray | proj)[:, None], nc - n_own, 0.0)
        blended = n[sel] + rs * turn
    else:
        blended = (1.0 - rs) * n[sel] + rs * nc
    out_p[sel] = p[sel] + rs * (c - own)
    length = np.linalg.norm(blended, axis=1)
    good = length > 1e-9
    out_n[sel[good]] = blended[good] / length[good, None]
    return out_p, out_n


# ------------------------------------------------------------------------ border cut, relaxation, seam error


def border_cut(points, normals, box_min, box_max, width: float):
    """Remove a border ``width`` wide along the output's sides (step 8 of Sec. 4):
    keep the points with ``box_min + width <= (x, y) <= box_max - width``.

    Args:
        points, normals: (M, 3) float.
        box_min, box_max: (2,) or (3,) the output's box (x, y used).
        width: the border width w_E (world units, >= 0).

    Returns:
        ``(points, normals)`` of the kept points, float64, in their input order.

    Raises:
        ValueError: nothing would be left (width at least half the box's smaller side).
    """
    p = as_points3("points", points)
    n = as_points3("normals", normals, len(p))
    lo, hi = _box(box_min, box_max)
    if isinstance(width, bool) or not isinstance(width, (int, float, np.integer, np.floating)) or not (
        math.isfinite(float(width)) and float(width) >= 0
    ):
        raise ValueError(f"width must be a finite number >= 0, got {width!r}.")
    w = float(width)
    if 2 * w >= float((hi - lo).min()):
        raise ValueError(f"width {w:g} leaves nothing of a box {hi - lo} wide; use a width below half its smaller side.")
    keep = ((p[:, :2] >= lo + w) & (p[:, :2] <= hi - w)).all(axis=1)
    return p[keep], n[keep]


def relax_points(points, normals, spacing: float, iterations: int = 2, *, device: str | None = None):
    """A short relaxation of the final point set (Sec. 6: "a relaxation of the point-sets
    as a post-processing step to improve local sampling density"): each point is pushed
    away from neighbours closer than ``spacing`` (half the overlap, in its tangent plane,
    at most half a spacing a step), then moved along the MLS normal so that its signed
    offset ``f`` from the MLS surface of the points before relaxing is what it was before
    the step. Not projected onto that surface: the MLS surface (width 2 spacings) is a
    smoothed one, and projecting every point onto it would round off the geometry
    (stones into soft bumps). Each point keeps its own normal.

    Args:
        points, normals: (M, 3) float.
        spacing: the target spacing (world units, > 0).
        iterations: relaxation steps (>= 0).
        device: the run's device string, only checked (host float64, as :func:`counterparts`).

    Returns:
        ``(points, normals)``: (M, 3) float64 relaxed positions and their unit normals
        (the input's).
    """
    from geosynth.core.neighbours import nearest

    p = as_points3("points", points)
    n = as_unit_vectors("normals", as_points3("normals", normals, len(p))) if len(p) else np.zeros((0, 3))
    spacing = check_positive("spacing", spacing)
    _check_device(device)
    if not isinstance(iterations, (int, np.integer)) or iterations < 0:
        raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}.")
    if len(p) < 2 or iterations == 0:
        return p.copy(), n.copy()
    surface = MLSSurface(p, n, 2.0 * spacing)
    x, nx = p.copy(), n.copy()
    k = int(min(9, len(p)))
    for _ in range(int(iterations)):
        dist, idx = nearest(x, k=k - 1)
        push = np.clip(spacing - dist, 0.0, None) / np.where(dist > 0, dist, 1.0)  # overlap / distance
        push = np.where(dist > 0, push, 0.0)
        move = 0.5 * np.einsum("mk,mkj->mj", push, x[:, None, :] - x[idx])
        move -= np.einsum("mj,mj->m", move, nx)[:, None] * nx  # tangential only
        limit = 0.5 * spacing
        length = np.linalg.norm(move, axis=1)
        move *= np.minimum(1.0, limit / np.where(length > 0, length, 1.0))[:, None]
        f0, _, s0 = surface.evaluate(x)
        moved = x + move
        f1, n1, s1 = surface.evaluate(moved)
        ok = s0 & s1 & (np.einsum("mj,mj->m", n1, nx) > 0.5)
        x[ok] = moved[ok] - (f1[ok] - f0[ok])[:, None] * n1[ok]
    return x, nx


def seam_errors(candidates, points_b, normals_b, samples, spacing: float) -> list[float]:
    """:func:`seam_error` of each of several point sets against one neighbourhood, in one
    pass: N_k's MLS is evaluated once, and each set enters only with its points within
    reach of a sample (the others cannot be among a sample's MLS neighbours).

    Args:
        candidates: sequence of ((., 3) points, (., 3) normals), e.g. a patch as warped and
            as blended.
        points_b, normals_b, samples, spacing: as :func:`seam_error`.

    Returns:
        One RMS difference in spacings per candidate (NaN where no sample has support in both).
    """
    from geosynth.core.neighbours import NeighbourIndex

    spacing = check_positive("spacing", spacing)
    x = as_points3("samples", samples)
    h = 2.0 * spacing
    if len(x) == 0:
        return [float("nan")] * len(candidates)
    near = NeighbourIndex(x)

    def within_reach(points, normals):
        p = as_points3("points", points)
        if len(p) == 0:
            return p, np.asarray(normals, np.float64).reshape(-1, 3)
        d = near.query(p, 1, upper=_REACH * h * (1 + 1e-9))[0][:, 0]
        keep = np.isfinite(d)
        return p[keep], np.asarray(normals)[keep]

    fb, _, sb = MLSSurface(*within_reach(points_b, normals_b), h).evaluate(x)
    out = []
    for points_a, normals_a in candidates:
        fa, _, sa = MLSSurface(*within_reach(points_a, normals_a), h).evaluate(x)
        both = sa & sb
        out.append(float(np.sqrt(np.mean((fa[both] - fb[both]) ** 2)) / spacing) if both.any() else float("nan"))
    return out


def seam_error(points_a, normals_a, points_b, normals_b, samples, spacing: float) -> float:
    """How far apart two point sets' surfaces are at some samples: the RMS difference of
    their MLS implicit functions ``f_a(x) - f_b(x)`` (signed distances near the
    surfaces) over the samples where both have support, in spacings.

    For the seam error of a pasted patch: a = the patch (warped or blended), b = N_k,
    samples = points in a thin band along the overlap's outer edge.

    Args:
        points_a, normals_a, points_b, normals_b: (., 3) float oriented point sets.
        samples: (L, 3) float sample positions.
        spacing: the point spacing (world units, > 0); the MLS width is 2 spacings.
            Evaluated on the host in float64 (the same number on every device).

    Returns:
        The RMS difference in spacings; NaN when no sample has support in both.
    """
    spacing = check_positive("spacing", spacing)
    x = as_points3("samples", samples)
    fa, _, sa = MLSSurface(points_a, normals_a, 2.0 * spacing).evaluate(x)
    fb, _, sb = MLSSurface(points_b, normals_b, 2.0 * spacing).evaluate(x)
    both = sa & sb
    if not both.any():
        return float("nan")
    return float(np.sqrt(np.mean((fa[both] - fb[both]) ** 2)) / spacing)


# ------------------------------------------------------------------------ cutting disconnected pieces


def pieces(points, link: float) -> np.ndarray:
    """Connected pieces of a point set: (M,) int labels (0, 1, ...). The points are binned
    into cubic cells of side ``link / 2`` and a piece is a set of occupied cells joined
    through faces, edges or corners (SciPy's ``ndimage.label``, 26-connectivity): points
    less than ``link / 2`` apart are always in one piece, points whose x, y or z differ by
    ``link`` or more are joined only through other points between them. Cheaper than the
    k-d tree's pairs within ``link`` (:func:`has_pieces`; 5-8 times the CPU time) and
    sometimes finer: the flowers' pieces are about the same, the chainmail's interlinked
    rings (within ``link`` of each other, one piece by the pairs) come apart.

    Labels number the pieces in the order of their first points. Computed by the compiled
    host step ``geosynth.kernels.host_blend.pieces_kernel`` (union-find over the points);
    :func:`_pieces_numpy` is its NumPy twin (SciPy's labels, numbered in the cells' raster
    order: the same pieces)."""
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels.host_blend import pieces_kernel

    p = np.asarray(points, np.float64)
    if len(p) == 0:
        return np.zeros(0, np.int64)
    lo = np.array([p[:, 0].min(), p[:, 1].min(), p[:, 2].min()])
    ijk = np.floor((p - lo) / (0.5 * float(link))).astype(np.int32)
    dims = [int(ijk[:, a].max()) + 1 for a in range(3)]
    wp_cells, _cells = host_array(ijk, np.int32)
    wp_voxel, _voxel = host_array(np.full(dims[0] * dims[1] * dims[2], -1, np.int32))
    wp_parent, _parent = host_array(np.empty(len(p), np.int32))
    wp_labels, labels = host_array(np.empty(len(p), np.int32))
    host_launch(pieces_kernel, 1, [wp_cells, len(p), *dims, wp_voxel, wp_parent, wp_labels])
    return labels.astype(np.int64)


def _pieces_numpy(points, link: float) -> np.ndarray:
    """:func:`pieces` by SciPy's ``ndimage.label`` (labels in the cells' raster order): the
    oracle of the compiled host step."""
    from scipy import ndimage

    p = np.asarray(points, np.float64)
    if len(p) == 0:
        return np.zeros(0, np.int64)
    ijk = np.floor((p - p.min(axis=0)) / (0.5 * float(link))).astype(np.int64)
    occupied = np.zeros(ijk.max(axis=0) + 1, bool)
    occupied[tuple(ijk.T)] = True
    labels, _ = ndimage.label(occupied, structure=np.ones((3, 3, 3), bool))
    return labels[tuple(ijk.T)].astype(np.int64) - 1


def has_pieces(points, spacing: float, *, link: float = 3.5, min_points: int = MLS_NEIGHBOURS) -> bool:
    """Whether a point set (an exemplar) has disconnected pieces: a connected component of
    its graph of pairs less than ``link`` spacings apart (SciPy's k-d tree pairs and
    connected components, exact) that has at least ``min_points`` points and keeps
    ``link`` away from the set's xy bounds. The flowers have them; a height field, the
    chainmail's interlinked rings and the weave's threads do not (each is one or a few
    components reaching the bounds). :func:`cut_pieces` is for exemplars that have them."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from geosynth.core.neighbours import pairs_within

    p = as_points3("points", points)
    r = check_positive("link", link) * check_positive("spacing", spacing)
    if len(p) == 0:
        return False
    pairs = pairs_within(p, r)
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(p), len(p)))
    _, labels = connected_components(graph, directed=False)
    big = np.bincount(labels) >= int(min_points)
    return bool((_whole(p, labels, (p[:, :2].min(axis=0), p[:, :2].max(axis=0)), r) & big).any())


def _whole(points, labels, window, tol, beyond=None):
    """(L,) whether each piece keeps ``tol`` away from the borders of the xy ``window``
    ((lo, hi)) the points were cut out of: only such a piece is all there. ``beyond``: (M,)
    bool, points whose nearness to the border does not count (a patch piece cut only by
    the window's overlap sides is the part of a piece that N_k would hold)."""
    lo, hi = (np.asarray(w, np.float64)[:2] for w in window)
    xy = points[:, :2]
    near = ((xy - lo < tol) | (hi - xy < tol)).any(axis=1)
    if beyond is not None:
        near &= ~beyond
    bad = np.zeros(labels.max() + 1 if len(labels) else 0, bool)
    bad[labels[near]] = True
    return ~bad


def cut_pieces(points, ramp, neighbourhood_points, neighbourhood_ramp, box_min, box_max, spacing: float, *,
               window=None, neighbourhood_window=None, link: float = 3.5, match: float = 2.0,
               min_points: int = MLS_NEIGHBOURS):
    """Cut the overlap instead of blending it for the disconnected pieces N_k lacks (or the
    patch lacks): the choice per piece, whole, of one side.

    Blending (:func:`blend_patch`) moves the patch's points onto surfaces N_k already has:
    it cannot remove a piece (a flower) that one side has in the overlap and the other
    lacks, and it drags such a piece's points toward whatever surface lies within reach (a
    petal toward the ground). Here a *piece* is a connected component (:func:`pieces`,
    points chained less than ``link`` spacings apart) with at least ``min_points`` points
    (fewer, by default fewer than one MLS evaluation's neighbours, are sampling debris) that
    lies wholly inside the window its set was cut from. One touching the window's border is
    part of a larger surface (the ground plane, a thread) and is blended as before; but a
    patch piece that the window cuts only across the overlap's sides (ramp 1, outside the
    box) counts: it continues into what N_k holds. A piece is *unmatched* when fewer than
    half of its points in the overlap (ramp > 0; N_k's: inside the box too) have a point of
    the other set within ``match`` spacings. Unmatched pieces are not blended but
    kept or dropped whole, by the mean ramp of their points (>= 1/2: N_k's side):

    - a patch piece is dropped where N_k's side is kept, and where it reaches outside the
      box (the paste would cut it); otherwise kept, and not blended (no counterpart to
      move toward);
    - an N_k piece inside the box is restored (the paste removes the box) where N_k's
      side is kept, and always where it reaches outside the box (it cannot be removed
      whole); otherwise it goes with the box;
    - a patch piece kept that touches (less than ``link`` spacings) a restored N_k piece,
      or, unmatched, a piece of N_k that stays outside the box, is dropped: one flower,
      never two in one place.

    On a connected surface (a height field, a weave's threads) nothing is a piece and
    nothing changes; :func:`geosynth.pointtexture.synthesis.synthesize_point_texture` calls this
    only for an exemplar that has pieces (:func:`has_pieces`). Host float64 and integer
    decisions only: the same on every device.

    Args:
        points: (M, 3) float, the warped patch F'_k; ramp: (M,) its overlap ramp.
        neighbourhood_points: (K, 3) float, N_k (may reach farther than the blend's N_k,
            so that its pieces are whole); neighbourhood_ramp: (K,) its overlap ramp.
        box_min, box_max: the patch box B_k (x and y used), into which the patch is pasted.
        spacing: the point spacing (world units, > 0).
        window, neighbourhood_window: (lo, hi) xy boxes the two sets were cut out of;
            default each set's bounds.
        link, match: in spacings (> 0).
        min_points: the fewest points of a piece (>= 1).

    Returns:
        ``(drop, unblend, restore)``: (M,) bool patch points not to paste, (M,) bool patch
        points not to blend (ramp 0), (K,) bool N_k points to keep inside the box.
    """
    p = as_points3("points", points)
    q = as_points3("neighbourhood_points", neighbourhood_points)
    r = np.asarray(ramp, np.float64).reshape(-1)
    rq = np.asarray(neighbourhood_ramp, np.float64).reshape(-1)
    if r.shape != (len(p),) or rq.shape != (len(q),):
        raise ValueError(f"ramp and neighbourhood_ramp must have shapes ({len(p)},) and ({len(q)},), got "
                         f"{np.shape(ramp)} and {np.shape(neighbourhood_ramp)}.")
    spacing = check_positive("spacing", spacing)
    link = check_positive("link", link) * spacing
    match = check_positive("match", match) * spacing
    if isinstance(min_points, bool) or not isinstance(min_points, (int, np.integer)) or min_points < 1:
        raise ValueError(f"min_points must be an integer >= 1, got {min_points!r}.")
    lo, hi = _box(box_min, box_max)
    drop, unblend, restore = np.zeros(len(p), bool), np.zeros(len(p), bool), np.zeros(len(q), bool)
    if len(p) == 0 or len(q) == 0:
        return drop, unblend, restore
    from geosynth.core.neighbours import nearest

    def bounds(x):
        return x[:, :2].min(axis=0), x[:, :2].max(axis=0)

    def in_box(x):
        return ((x[:, :2] >= lo) & (x[:, :2] < hi)).all(axis=1)

    def near_other(x, other):  # whether each point of x has a point of other within match
        if len(x) == 0:
            return np.zeros(0, bool)
        lo_x, hi_x = x.min(axis=0) - match, x.max(axis=0) + match
        local = other[((other >= lo_x) & (other <= hi_x)).all(axis=1)]  # a small tree: only near x
        if len(local) == 0:
            return np.zeros(len(x), bool)
        return np.isfinite(nearest(local, x, 1, upper=match)[0][:, 0])

    inb_p, inb_q = in_box(p), in_box(q)
    sides = []  # per set: labels, whole, unmatched, mean ramp, reaches outside the box
    # The patch's points outside the box with ramp 1 lie across an overlap side: a patch piece
    # cut by the window only there is a candidate too (it reaches outside the box: unmatched,
    # it would be pasted as half a piece, so it is dropped).
    for x, rx, other, win, counted, beyond, inb in (
            (p, r, q, window or bounds(p), r > 0, (r >= 1) & ~inb_p, inb_p),
            (q, rq, p, neighbourhood_window or bounds(q), (rq > 0) & inb_q, None, inb_q)):
        lab = pieces(x, link)
        n_lab = lab.max() + 1
        size = np.bincount(lab, minlength=n_lab)
        total = np.bincount(lab[counted], minlength=n_lab)
        whole = _whole(x, lab, win, link, beyond)
        candidate = whole & (size >= min_points) & (total > 0)
        ask = counted & candidate[lab]  # only the candidates' points are asked for a match
        near = np.bincount(lab[ask], weights=near_other(x[ask], other).astype(np.float64), minlength=n_lab)
        unmatched = candidate & (2 * near < total)
        # which side a piece is on: the mean ramp of its points (1 beyond the box's edge)
        rc = np.bincount(lab, weights=rx, minlength=n_lab) / size
        outside = np.zeros(n_lab, bool)
        outside[lab[~inb]] = True
        sides.append((lab, whole, unmatched, rc, outside))
    (lp, wp, up, rcp, op), (lq, wq, uq, rcq, oq) = sides
    keep_q = uq & ((rcq >= 0.5) | oq)
    restore = keep_q[lq] & inb_q
    drop_piece = up & ((rcp >= 0.5) | op)
    unblend = (up & ~drop_piece)[lp]
    drop = drop_piece[lp]
    # One flower, never two in one place: a whole patch piece kept goes if it touches (less
    # than link) a restored N_k piece, or, unmatched, an N_k piece that stays outside the box.
    stays = wq[lq] & (restore | ~inb_q)
    may_go = (_whole(p, lp, window or bounds(p), link) & ~drop_piece)[lp]  # only these are asked
    if stays.any() and may_go.any():
        ask = np.flatnonzero(may_go)
        d, i = (a[:, 0] for a in nearest(q[stays], p[ask], 1, upper=link))
        hit = np.isfinite(d)
        n_lab = lp.max() + 1
        touch_restored = np.zeros(n_lab, bool)
        touch_restored[lp[ask[hit][restore[np.flatnonzero(stays)[i[hit]]]]]] = True
        touch = np.zeros(n_lab, bool)
        touch[lp[ask[hit]]] = True
        gone = touch_restored | (touch & up)
        drop |= gone[lp]
        unblend &= ~drop
    return drop, unblend, restore
