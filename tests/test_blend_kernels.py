"""M2 blending's compiled host steps (geosynth.kernels.host_blend, Sec. 5.3) against their
NumPy twins in geosynth.pointtexture.blending: the k nearest points of a cell grid against SciPy's k-d
tree, counterparts and blend_patch against _counterparts_numpy / _blend_patch_numpy
(line crossings, re-gathering, projection fallback, no neighbours, no convergence, fewer
points than an evaluation's neighbours), pieces against SciPy's labelling."""

from __future__ import annotations

import numpy as np
import pytest

from geosynth.pointtexture import blending as B
from test_blending import SP, flowers_scene, grid_xy, height, normal, scene

TOL = 1e-9 * SP  # float64 tolerance on positions (world units); normals: 1e-9


def assert_same_counterparts(args, **kw):
    got = B.counterparts(*args, **kw)
    want = B._counterparts_numpy(*args, **kw)
    np.testing.assert_array_equal(got[2], want[2])
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=TOL)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-9)
    return got


@pytest.mark.parametrize("offset", [0.5, 2.0, 3.5])  # 3.5 spacings: crossings beyond h, gathered again
def test_counterparts_equal_numpy(rng, offset):
    (p, n), (nbp, nbn) = scene(offset, rng)
    _, _, how = assert_same_counterparts((p, n, nbp, nbn, SP))
    assert (how == B.RAY).sum() > 1000 and (how == B.NO_SURFACE).sum() > 500  # both kinds seen


def test_counterparts_projection_fallback_and_refusals(rng):
    (p, n), (nbp, nbn) = scene(1.0, rng)
    # normals 60 degrees off, crossings ~3 spacings away, max_ray 2: projections
    x = np.c_[p[:300, :2], height(p[:300, :2]) + 1.5 * SP]
    tilted = np.tile([0.0, np.sin(np.pi / 3), 0.5], (300, 1))
    _, _, how = assert_same_counterparts((x, tilted, nbp, nbn, SP), max_ray=2.0)
    assert (how == B.PROJECTION).sum() >= 100
    # grazing normals (the line never crosses) and points far off the surface (projections
    # beyond max_ray): none
    grazing = np.tile([1.0, 0.0, 0.05], (300, 1))
    far = np.c_[p[:300, :2], height(p[:300, :2]) + 5.5 * SP]
    _, _, how = assert_same_counterparts((far, grazing, nbp, nbn, SP), max_ray=1.0)
    assert (how == B.NO_SURFACE).sum() > 100


def test_counterparts_without_neighbours_or_with_few(rng):
    (p, n), (nbp, nbn) = scene(1.0, rng)
    # no point of N_k within reach: every point is its own counterpart
    away = p[:50] + [0.0, 0.0, 1.0]
    c, cn, how = B.counterparts(away, n[:50], nbp, nbn, SP)
    assert (how == B.NO_SURFACE).all()
    np.testing.assert_array_equal(c, away)
    np.testing.assert_allclose(cn, n[:50], rtol=0, atol=1e-15)  # (made unit length again)
    assert_same_counterparts((away, n[:50], nbp, nbn, SP))
    # N_k of 10 points (fewer than an evaluation's 24) under the queries
    few = np.c_[grid_xy(0.0, 0.1, 0.0, 0.04), np.zeros(10)]
    q = np.c_[few[:, :2] + 0.3 * SP, np.full(10, 0.5 * SP)]
    _, _, how = assert_same_counterparts((q, np.tile([0.0, 0, 1], (10, 1)), few, np.tile([0.0, 0, 1], (10, 1)), SP))
    assert (how == B.RAY).all()
    # an empty N_k
    c, _, how = B.counterparts(q, np.tile([0.0, 0, 1], (10, 1)), np.zeros((0, 3)), np.zeros((0, 3)), SP)
    assert (how == 0).all() and np.array_equal(c, q)


@pytest.mark.parametrize("relative", [True, False])
def test_blend_patch_equals_numpy(rng, relative):
    for offset in (0.5, 2.0):
        (p, n), (nbp, nbn) = scene(offset, rng)
        ramp = B.overlap_ramp(p, [0, 0], [1, 1], 0.3, 0.3)
        got = B.blend_patch(p, n, ramp, nbp, nbn, SP, relative=relative)
        want = B._blend_patch_numpy(p, n, ramp, nbp, nbn, SP, relative=relative)
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=TOL)
        np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-9)
        assert np.abs(got[0] - p).max() > 0.1 * SP  # it did blend
    (p, n, _), (q, qn, _) = flowers_scene(rng)  # pieces floating over a plane
    ramp = B.overlap_ramp(p, [0, 0, -1], [1, 1, 1], 0.3, 0.3)
    got = B.blend_patch(p, n, ramp, q, qn, SP, relative=relative)
    want = B._blend_patch_numpy(p, n, ramp, q, qn, SP, relative=relative)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=TOL)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-9)


def _nearest_lists(points, queries, k, reach, cell):
    """host_blend.nearest for each query: (m, k) input indices (-1 beyond the count)."""
    import warp as wp

    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels.host_blend import nearest

    grid = B._CellGrid(points, normal(points[:, :2]), cell)
    cap = B._list_room(k)
    wq, _ = host_array(queries, np.float64)
    wn, nbr = host_array(np.empty(len(queries) * cap, np.int32))
    wd, _ = host_array(np.empty(len(queries) * cap, np.float64))
    wc, counts = host_array(np.empty(len(queries), np.int32))
    host_launch(_nearest_kernel(nearest), len(queries), [*grid.launch_args(), k, cap, reach, wq, wn, wd, wc])
    out = np.full((len(queries), k), -1)
    for i, c in enumerate(counts):
        out[i, :c] = np.sort(grid.ids[nbr[i * cap:i * cap + c]])
    return out


_KERNELS = {}


def _nearest_kernel(nearest):
    import warp as wp

    if "k" not in _KERNELS:
        @wp.kernel
        def nearest_kernel(pn: wp.array(dtype=wp.float64), ids: wp.array(dtype=wp.int32),
                           cell_start: wp.array(dtype=wp.int32), g: wp.vec3d, cell: wp.float64, nx: int, ny: int,
                           nz: int, k: int, cap: int, reach: wp.float64, queries: wp.array(dtype=wp.float64),
                           nbr: wp.array(dtype=wp.int32), nd2: wp.array(dtype=wp.float64),
                           counts: wp.array(dtype=wp.int32)):
            i = wp.tid()
            q = wp.vec3d(queries[3 * i], queries[3 * i + 1], queries[3 * i + 2])
            counts[i] = nearest(pn, ids, cell_start, g, cell, nx, ny, nz, q, k, reach, nbr, nd2, cap * i, cap)

        _KERNELS["k"] = nearest_kernel
    return _KERNELS["k"]


@pytest.mark.parametrize("cell", [1.0, 3.0, 40.0])  # in spacings: the result never depends on it
def test_nearest_is_the_k_nearest_within_reach(rng, cell):
    from pykdtree.kdtree import KDTree

    xy = grid_xy(0, 0.6, 0, 0.6, rng, 0.3)
    pts = np.c_[xy, height(xy)]
    # queries near the surface, off it, outside the grid's box and far away
    q = np.concatenate([pts[::7] + rng.normal(0, SP, (len(pts[::7]), 3)), [[-0.05, 0.3, 0.0], [0.3, 0.3, 0.5],
                                                                         [1e6, -1e6, 3.0]]])
    for k, reach in ((24, 6 * SP), (24, 2.5 * SP), (5, 6 * SP)):
        got = _nearest_lists(pts, q, k, reach, cell * SP)
        _, idx = KDTree(pts, leafsize=16).query(q, k=k, distance_upper_bound=reach)
        idx = idx.astype(np.int64).reshape(len(q), k)
        want = np.sort(np.where(idx < len(pts), idx, 1 << 40), axis=1)  # the found ones first, sorted
        want[want == 1 << 40] = -1
        np.testing.assert_array_equal(got, want)
        assert (got[-1] == -1).all() and (got[:-3] >= 0).sum() > len(q)  # far away: none


def test_nearest_breaks_ties_by_lowest_index():
    # a lattice queried at lattice points: many points at equal distances
    pts = np.c_[grid_xy(0, 0.2, 0, 0.2), np.zeros(100)]
    q = pts[[0, 11, 44, 55]] + [0.0, 0.0, 0.0]
    got = _nearest_lists(pts, q, 24, 6 * SP, 2 * SP)
    d2 = ((pts[None] - q[:, None]) ** 2).sum(-1)
    for i in range(len(q)):
        order = np.lexsort((np.arange(len(pts)), d2[i]))  # by distance, then index
        np.testing.assert_array_equal(got[i], np.sort(order[:24]))


def test_pieces_equal_scipy_labels(rng):
    (p, _, lp), (q, _, _) = flowers_scene(rng)
    for x in (p, q, rng.uniform(0, 0.3, (500, 3))):
        got, want = B.pieces(x, 3.5 * SP), B._pieces_numpy(x, 3.5 * SP)
        assert got.max() == want.max()
        # the same partition: each label of one side is one label of the other
        pairs = np.unique(np.c_[got, want], axis=0)
        assert len(pairs) == got.max() + 1
        assert got[0] == 0 and set(np.unique(got)) == set(range(got.max() + 1))
    assert len(np.unique(B.pieces(p, 3.5 * SP)[lp >= 0])) == lp.max() + 1  # each blob a piece
    assert B.pieces(np.zeros((0, 3)), 1.0).shape == (0,)


def test_counterparts_and_blend_are_the_same_bits_on_any_number_of_host_threads(rng, monkeypatch):
    """The compiled steps' workers are shared among the cores (host_launch's split)."""
    (p, n), (nbp, nbn) = scene(2.0, rng)
    runs = []
    for threads in ("1", "2", "4"):
        monkeypatch.setenv("GEOSYNTH_HOST_THREADS", threads)
        c, cn, how = B.counterparts(p, n, nbp, nbn, SP)
        runs.append((c, cn, how))
    for got in runs[1:]:
        for a, b in zip(got, runs[0]):
            np.testing.assert_array_equal(a, b)
