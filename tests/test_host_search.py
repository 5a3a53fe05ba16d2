"""The search's compiled host steps (Sec. 5.1, D(S)): the float64 host projection kernel
(geosynth.kernels.host_search) against its NumPy oracle (patch_search._iterate), the
host recomputation host_mls both ways, the device kernel's tolerance stop, and the host
selection of the patch search against geosynth.compute.selection's device reductions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from geosynth.geometry.pointsets import MLS_REACH, CellGrid
from geosynth.pointtexture.patch_search import (FIXED_STEPS, FIXED_TOL, RESIDUAL_TOL, PatchSearch, _HostCells, _iterate,
                                   host_mls, kernel_mls)


def _wavy(n_side=50, seed=0, offset=(0.0, 0.0, 0.0)):
    """A wavy height field over [0, 1]^2 (jittered grid), unit normals, spacing ~1/49."""
    rng = np.random.default_rng(seed)
    u = np.linspace(0, 1, n_side)
    x, y = np.meshgrid(u, u)
    s = u[1] - u[0]
    x = x.ravel() + rng.uniform(-0.2, 0.2, x.size) * s
    y = y.ravel() + rng.uniform(-0.2, 0.2, y.size) * s
    k = 2 * np.pi * 2.0
    z = 0.04 * np.sin(k * x) * np.cos(k * y)
    n = np.stack([-0.04 * k * np.cos(k * x) * np.cos(k * y), 0.04 * k * np.sin(k * x) * np.sin(k * y),
                  np.ones_like(x)], 1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.c_[x, y, z] + np.asarray(offset), n, 2 * s


def _sheets(gap_h: float):
    """Two flat sheets gap_h * h apart, normals facing away (projections between them that
    do not converge at gap 1.2 h)."""
    u = np.linspace(0, 1, 40)
    x, y = np.meshgrid(u, u)
    sheet = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    h = 2 * (u[1] - u[0])
    p = np.concatenate([sheet, sheet + [0, 0, gap_h * h]])
    n = np.concatenate([np.tile([0, 0, -1.0], (len(sheet), 1)), np.tile([0, 0, 1.0], (len(sheet), 1))])
    return p, n, h


def _cases(rng):
    p, n, h = _wavy()
    reach = MLS_REACH * h
    q = rng.uniform([0.1, 0.1, -reach], [0.9, 0.9, reach], (300, 3))
    far = np.array([[0.5, 0.5, 5.0], [-3.0, 0.5, 0.0], [0.2, 0.3, -4 * reach]])  # nothing within reach
    yield "wavy", p, n, h, np.concatenate([q, far])
    for gap in (0.8, 1.2):
        p, n, h = _sheets(gap)
        yield f"sheets {gap}", p, n, h, rng.uniform([0.1, 0.1, -h], [0.9, 0.9, 2 * h], (200, 3))


@pytest.mark.parametrize("fixed", [True, False])
def test_host_kernel_equals_the_numpy_loop(rng, fixed):
    """The compiled projection (cell order sums) gives _iterate's (ascending index order)
    f at the query, last normal and projection to float64 rounding where the projection
    converged; the same support (NaN f, zero normal, the query itself where no point is
    within reach)."""
    for name, p, n, h, q in _cases(rng):
        f_n, g_n, y_n = _iterate(p, n, cKDTree(p), q, h, fixed)
        f_k, g_k, y_k = _HostCells(p, n, MLS_REACH * h).project(q, h, fixed)
        np.testing.assert_array_equal(np.isnan(f_k), np.isnan(f_n), err_msg=name)
        none = np.isnan(f_n)
        np.testing.assert_array_equal(g_k[none], 0.0)
        np.testing.assert_array_equal(y_k[none], q[none])
        np.testing.assert_allclose(f_k[~none], f_n[~none], atol=1e-12 * h, rtol=0, err_msg=name)
        # where the projection has converged (f at it below the step tolerance), the iterates agree
        residual = np.abs(_iterate(p, n, cKDTree(p), y_n, h, fixed)[0])
        conv = ~none & (residual <= 10 * (FIXED_TOL if fixed else 1e-4) * h)
        if name != "sheets 1.2":
            assert conv.sum() > 0.8 * (~none).sum(), name
        np.testing.assert_allclose(y_k[conv], y_n[conv], atol=1e-9 * h, rtol=0, err_msg=name)
        np.testing.assert_allclose(g_k[conv], g_n[conv], atol=1e-9, rtol=0, err_msg=name)
        if name == "wavy":
            assert none[-3:].all() and none.sum() < 0.2 * len(q)


def test_host_kernel_detects_a_wrong_sum():
    """The comparison above can fail: the kernel with a wrong kernel width disagrees."""
    p, n, h = _wavy()
    q = np.array([[0.5, 0.5, 0.03], [0.3, 0.6, -0.02]])
    f_n, _, _ = _iterate(p, n, cKDTree(p), q, h, True)
    f_k, _, _ = _HostCells(p, n, MLS_REACH * h).project(q, 1.3 * h, True)
    assert np.abs(f_k - f_n).max() > 1e-6 * h


def test_host_kernel_with_the_device_layout_far_from_the_origin(rng):
    """Reusing the device grid's layout (keys from float32 positions) misses no point: far
    from the origin the float32 rounding is ~1e-3 of h, and the kernel widens its ranges."""
    p, n, h = _wavy(offset=(3000.0, -2000.0, 500.0))
    reach = MLS_REACH * h
    q = p[rng.choice(len(p), 300, replace=False)] + rng.uniform(-reach, reach, (300, 3))
    grid = CellGrid(p.astype(np.float32), n.astype(np.float32), reach)
    shared = _HostCells(p, n, reach, grid)
    assert shared.slack > 1e-4 * h
    own = _HostCells(p, n, reach)
    f_n, g_n, y_n = _iterate(p, n, cKDTree(p), q, h, True)
    for cells in (shared, own):
        f_k, g_k, y_k = cells.project(q, h, True)
        np.testing.assert_array_equal(np.isnan(f_k), np.isnan(f_n))
        ok = ~np.isnan(f_n)
        np.testing.assert_allclose(f_k[ok], f_n[ok], atol=1e-9 * h, rtol=0)
        np.testing.assert_allclose(g_k[ok], g_n[ok], atol=1e-7)


def test_host_mls_compiled_equals_numpy(rng):
    """host_mls (near and far queries, the far ones by their nearest point's projection) by
    the compiled kernel equals the NumPy loop; the nearest points may be passed in (exact
    only where far, as quantized_fields passes them) with the cells; no queries give
    empty results."""
    p, n, h = _wavy()
    reach = MLS_REACH * h
    q = np.concatenate([rng.uniform([0.1, 0.1, -reach], [0.9, 0.9, reach], (200, 3)),
                        rng.uniform([0.1, 0.1, 2 * reach], [0.9, 0.9, 4 * reach], (30, 3))])
    d_n, g_n = host_mls(p, n, q, h, fixed=True, compiled=False)
    d_k, g_k = host_mls(p, n, q, h, fixed=True)
    cells = _HostCells(p, n, reach, CellGrid(p.astype(np.float32), n.astype(np.float32), reach))
    d_t, g_t = host_mls(p, n, q, h, fixed=True, nearest=cells.nearest(q, enough=(1 - 1e-5) * reach), cells=cells)
    far = cKDTree(p).query(q, k=1)[0] >= reach
    assert far.sum() >= 30
    for d, g in ((d_k, g_k), (d_t, g_t)):
        np.testing.assert_allclose(d, d_n, atol=1e-9 * h, rtol=0)
        np.testing.assert_allclose(g, g_n, atol=1e-8, rtol=0)
    d0, g0 = host_mls(p, n, np.zeros((0, 3)), h, fixed=True)
    assert d0.shape == (0,) and g0.shape == (0, 3)


def test_kernel_tolerance_stop_and_its_residual(device, rng):
    """kernel_mls with tol: every device stops a converged projection at |f| <= tol and
    gives that last f as residual; the results stay within the tolerance of the fixed-step
    ones and of the float64 host values; a query without support gets reach, unchanged."""
    p, n, h = _wavy()
    reach = MLS_REACH * h
    q = np.concatenate([rng.uniform([0.1, 0.1, -0.9 * reach], [0.9, 0.9, 0.9 * reach], (300, 3)),
                        [[0.5, 0.5, 3.0]]])
    d0, g0, y0, r0, cells = kernel_mls(p, n, q, h, device, FIXED_STEPS)
    d1, g1, y1, r1, _ = kernel_mls(p, n, q, h, device, FIXED_STEPS, cells, tol=FIXED_TOL * h)
    conv = np.abs(r1[:300]) <= FIXED_TOL * h
    assert conv.sum() > 250
    np.testing.assert_allclose(d1[:300][conv], d0[:300][conv], atol=3e-6 * h, rtol=0)
    np.testing.assert_allclose(g1[:300][conv], g0[:300][conv], atol=3e-6, rtol=0)
    dh, gh = host_mls(p, n, q[:300][conv], h, fixed=True)
    np.testing.assert_allclose(d1[:300][conv], dh, atol=2e-5 * h, rtol=0)
    np.testing.assert_allclose(g1[:300][conv], gh, atol=2e-5, rtol=0)
    # not converged at the tolerance: the residual is f at the projection, as without it
    rest = np.flatnonzero(~conv)
    if rest.size:
        assert (np.abs(r1[rest]) > FIXED_TOL * h).all()
    assert d1[300] == np.float32(reach) and r1[300] == np.float32(reach) and not g1[300].any()


def test_quantized_fields_flags_unconverged_sheets(one_device):
    """Between two sheets 1.2 h apart the projections do not converge: quantized_fields
    sends them to the host (the residual test), and its codes are the host's there."""
    from geosynth.pointtexture.patch_search import _codes, _round_codes, quantized_fields

    p, n, h = _sheets(1.2)
    q = np.random.default_rng(0).uniform([0.1, 0.1, -h], [0.9, 0.9, 2 * h], (50, 3))
    band = MLS_REACH * h
    codes, flagged = quantized_fields(p, n, q, h, band, one_device)
    _, _, _, res, _ = kernel_mls(p, n, q, h, one_device, FIXED_STEPS, tol=FIXED_TOL * h)
    unconverged = np.abs(res) > RESIDUAL_TOL * h
    assert unconverged.sum() >= 1 and flagged >= unconverged.sum()
    dh, gh = host_mls(p, n, q[unconverged], h, fixed=True)
    np.testing.assert_array_equal(codes[unconverged], _round_codes(_codes(dh, gh, band)))


def test_host_choice_equals_the_device_selection(one_device):
    """PatchSearch.choose selects on the host: the same candidate set, best score and pick
    as selection.argmin / within_tolerance on the device scores, for several eps."""
    from geosynth.compute.selection import argmin, random_pick, within_tolerance
    from geosynth.pointtexture.texture import PointTexture

    p, n, h = _wavy()
    tex = PointTexture(p, n, [0, 0, -0.04], [1, 1, 0.04], name="wavy")
    s = PatchSearch(tex, 1.0 / 15, 6, 2, 2 * tex.spacing, MLS_REACH * 2 * tex.spacing, one_device)
    offsets = s.overlap_offsets([("-x", 2)])
    rng = np.random.default_rng(5)
    for eps in (0.0, 0.1, 0.5):
        values = s.codes[offsets[:, 0], offsets[:, 1], offsets[:, 2] + 3]
        values = np.clip(values.astype(np.int32) + rng.integers(-3, 4, values.shape), 0, 254).astype(np.uint8)
        got = s.choose(offsets, values, eps, np.random.default_rng(7))
        sc = s._scorer(offsets)(values, origins=s.origins, keep_on_device=True)
        best = argmin(sc)
        near = within_tolerance(sc, eps)
        i = random_pick(near, np.random.default_rng(7))
        host = sc.numpy()
        assert (got.index, got.score, got.best, got.candidates) == (i, int(host[i]), int(host[best]), len(near))


def test_host_nearest_points_equal_the_k_d_tree(rng):
    """_HostCells.nearest: the nearest point and its distance as cKDTree gives them, for
    queries within reach, far above and below the sheet, outside the grid's box, and far
    from the origin with the device layout; the lowest index among equidistant points."""
    for offset in ((0.0, 0.0, 0.0), (3000.0, -2000.0, 500.0)):
        p, n, h = _wavy(offset=offset)
        reach = MLS_REACH * h
        o = np.asarray(offset)
        q = o + np.concatenate([rng.uniform([0, 0, -reach], [1, 1, reach], (300, 3)),
                                rng.uniform([0, 0, 2 * reach], [1, 1, 20 * reach], (50, 3)),
                                rng.uniform([-3, -3, -3], [4, 4, 3], (50, 3))])
        grid = CellGrid(p.astype(np.float32), n.astype(np.float32), reach)
        want_d, want_i = cKDTree(p).query(q, k=1)
        for cells in (_HostCells(p, n, reach), _HostCells(p, n, reach, grid)):
            d, i = cells.nearest(q)
            np.testing.assert_array_equal(i, want_i)
            np.testing.assert_allclose(d, want_d, rtol=1e-12, atol=1e-12 * reach)
    # ties: a query equidistant from two points gets the lower index, whatever the cell order
    p = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 5.0, 0.0]])
    n = np.tile([0, 0, 1.0], (3, 1))
    for reach in (0.5, 3.0):
        d, i = _HostCells(p, n, reach).nearest(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 7.0]]))
        np.testing.assert_array_equal(i, [0, 0])
        np.testing.assert_allclose(d, [1.0, np.sqrt(50.0)])


def test_host_nearest_stops_at_a_point_near_enough(rng):
    """With ``enough``, a query with a point nearer than it gets such a point (not always
    the nearest), and every other query its exact nearest point."""
    p, n, h = _wavy()
    reach = MLS_REACH * h
    q = rng.uniform([0, 0, -2 * reach], [1, 1, 2 * reach], (400, 3))
    cells = _HostCells(p, n, reach)
    want_d, want_i = cKDTree(p).query(q, k=1)
    enough = 0.9 * reach
    d, i = cells.nearest(q, enough=enough)
    close = want_d < enough
    assert 50 < close.sum() < 350
    np.testing.assert_array_equal(i[~close], want_i[~close])
    np.testing.assert_allclose(d[~close], want_d[~close], rtol=1e-12)
    assert (d[close] < enough).all()
    np.testing.assert_allclose(d[close], np.linalg.norm(p[i[close]] - q[close], axis=1), rtol=1e-12)
    assert (i[close] != want_i[close]).any()  # it stops early: some are not the nearest
