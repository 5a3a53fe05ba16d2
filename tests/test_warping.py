"""M2 warping (Sec. 5.2): a rigidly moved patch is moved back, the thin-plate spline
interpolates its pairs and keeps its fixed corner pairs, its Jacobian gives the analytic
normals of a known warp, the greedy pairing respects the thresholds and never raises its
cost. Host-only code: no device is involved."""

from __future__ import annotations

import numpy as np
import pytest

from geosynth.pointtexture.warping import (
    WARP_PRESETS,
    ThinPlateSpline,
    WarpWeights,
    greedy_pairing,
    surface_variation,
    warp_patch,
)

SP = 1.0 / 30  # grid spacing of the test patches


def height(xy):
    return 0.06 * np.sin(6 * xy[:, 0]) * np.cos(5 * xy[:, 1])


def normal(xy):
    hx = 0.06 * 6 * np.cos(6 * xy[:, 0]) * np.cos(5 * xy[:, 1])
    hy = -0.06 * 5 * np.sin(6 * xy[:, 0]) * np.sin(5 * xy[:, 1])
    n = np.c_[-hx, -hy, np.ones(len(xy))]
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def bumpy_patch(lo=0.0, hi=1.0):
    g = np.arange(lo, hi + 1e-9, SP)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return np.c_[xy, height(xy)], normal(xy)


BOX = (np.array([0.0, 0.0, -0.2]), np.array([1.0, 1.0, 0.2]))


def rigid(points, normals, degrees, shift):
    th = np.deg2rad(degrees)
    rot = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    c = points.mean(axis=0)
    return (points - c) @ rot.T + c + np.asarray(shift) * SP, normals @ rot.T


def angle_deg(a, b):
    return np.rad2deg(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1, 1)))


def test_presets_are_the_papers_weights():
    got = {k: (w.w_p, w.w_n, w.w_v, w.w_l, w.w_d) for k, w in WARP_PRESETS.items()}
    assert got == {"heightfield": (1, 3, 30, 9, 7), "chainmail": (1, 1, 10, 8, 6),
                   "weave": (1, 2, 15, 6, 5), "flowers": (1, 2, 2, 6, 6)}


def test_rigidly_moved_copy_is_moved_back():
    p, n = bumpy_patch()
    s, ns = rigid(p, n, 0.5, [0.3, -0.2, 0.3])
    res = warp_patch(s, ns, p, n, *BOX, WARP_PRESETS["heightfield"], SP, np.random.default_rng(0))
    assert len(res.fixed) == 0  # the targets cover the box: no free corner
    inner = ((p[:, :2] > 0.1) & (p[:, :2] < 0.9)).all(axis=1)
    before = np.linalg.norm(s - p, axis=1)[inner].mean() / SP
    err = np.linalg.norm(res.points - p, axis=1)[inner] / SP
    assert before > 0.4
    assert err.mean() < 0.02 and err.max() < 0.1, (err.mean(), err.max())
    assert angle_deg(res.normals, n)[inner].max() < 1.0


def test_larger_rotation_lands_on_the_surface():
    # Beyond half a spacing per point the pairs are no longer the true correspondences
    # (any shift along the surface fits as well); the warped points still lie on the
    # target surface with its normals.
    p, n = bumpy_patch()
    s, ns = rigid(p, n, 3.0, [0.3, -0.2, 0.5])
    res = warp_patch(s, ns, p, n, *BOX, WARP_PRESETS["heightfield"], SP, np.random.default_rng(0))
    w = res.points
    inner = ((w[:, :2] > 0.1) & (w[:, :2] < 0.9)).all(axis=1)
    off_before = np.abs(s[:, 2] - height(s[:, :2]))[inner].mean() / SP
    off = np.abs(w[:, 2] - height(w[:, :2]))[inner] / SP
    assert off_before > 0.3
    assert off.mean() < 0.02 and off.max() < 0.1, (off.mean(), off.max())
    nerr = angle_deg(res.normals, normal(w[:, :2]))[inner]
    assert nerr.mean() < 0.75 and nerr.max() < 3.0, (nerr.mean(), nerr.max())  # (smoothed spline: 0.52)


def test_spline_interpolates_its_pairs(rng):
    c = rng.uniform(-1, 1, (60, 3))
    y = c + 0.1 * rng.normal(size=c.shape)
    spline = ThinPlateSpline(c, y)
    np.testing.assert_allclose(spline(c), y, atol=1e-9)
    # An affine map is reproduced exactly, with its Jacobian.
    a = np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.3], [0.05, 0.0, 1.2]])
    spline = ThinPlateSpline(c, c @ a.T + [0.3, -0.2, 0.1])
    x = rng.uniform(-1, 1, (50, 3))
    np.testing.assert_allclose(spline(x), x @ a.T + [0.3, -0.2, 0.1], atol=1e-9)
    np.testing.assert_allclose(spline.jacobian(x), np.broadcast_to(a, (50, 3, 3)), atol=1e-9)


def test_degenerate_pairs_leave_the_undetermined_direction_alone():
    # Pairs on one plane (z = 0) moved up by 0.1: the affine part along z is undetermined;
    # the least-norm solution moves the plane and leaves no NaN.
    g = np.stack(np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 6)), -1).reshape(-1, 2)
    c = np.c_[g, np.zeros(len(g))]
    spline = ThinPlateSpline(c, c + [0, 0, 0.1])
    out = spline(np.array([[0.5, 0.5, 0.0], [0.2, 0.7, 0.0]]))
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out[:, 2], 0.1, atol=1e-6)


def test_jacobian_normals_match_a_known_smooth_warp():
    # W0(x, y, z) = (x + 0.03 sin 2y, y, z + 0.05 sin 3x cos 2y), sampled at a 3D grid of
    # pairs; the spline's normals of the plane z = 0 against the analytic ones, J0^-T n.
    def w0(p):
        x, y, z = p.T
        return np.c_[x + 0.03 * np.sin(2 * y), y, z + 0.05 * np.sin(3 * x) * np.cos(2 * y)]

    def j0(p):
        x, y, _ = p.T
        j = np.zeros((len(p), 3, 3))
        j[:, 0, 0] = 1
        j[:, 0, 1] = 0.06 * np.cos(2 * y)
        j[:, 1, 1] = 1
        j[:, 2, 0] = 0.15 * np.cos(3 * x) * np.cos(2 * y)
        j[:, 2, 1] = -0.1 * np.sin(3 * x) * np.sin(2 * y)
        j[:, 2, 2] = 1
        return j

    g = np.linspace(-0.2, 1.2, 9)
    c = np.stack(np.meshgrid(g, g, [-0.2, 0.0, 0.2]), -1).reshape(-1, 3)
    spline = ThinPlateSpline(c, w0(c))
    xy = np.stack(np.meshgrid(np.linspace(0.1, 0.9, 15), np.linspace(0.1, 0.9, 15)), -1).reshape(-1, 2)
    p = np.c_[xy, np.zeros(len(xy))]
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    wp, wn = spline.transform(p, n)
    want = np.einsum("mkj,mk->mj", np.linalg.inv(j0(p)), n)  # J^-T n
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    assert np.abs(wp - w0(p)).max() < 2e-3
    assert angle_deg(wn, want).max() < 0.5
    # Against a finite-difference Jacobian of the spline itself: the analytic one is exact.
    eps = 1e-6
    fd = np.stack([(spline(p + eps * e) - spline(p - eps * e)) / (2 * eps) for e in np.eye(3)], axis=2)
    np.testing.assert_allclose(spline.jacobian(p), fd, atol=1e-6)


def test_corner_pairs_stay_fixed():
    # Targets only in the -x strip: the two +x corners are free and keep their points.
    p, n = bumpy_patch()
    t_sel = p[:, 0] < 0.25
    s = p + [0.0, 0.0, 0.4 * SP]  # the patch sits 0.4 spacing too high
    corners = np.array([[1.0, 0.0, -0.2], [1.0, 1.0, -0.2], [1.0, 0.0, 0.2], [1.0, 1.0, 0.2]])
    src = np.concatenate([s, corners])
    nsrc = np.concatenate([n, np.tile([0.0, 0.0, 1.0], (4, 1))])
    res = warp_patch(src, nsrc, p[t_sel], n[t_sel], *BOX, WARP_PRESETS["heightfield"], SP, np.random.default_rng(0))
    assert len(res.fixed) == 4
    assert {tuple(np.round(f, 9)) for f in res.fixed} == {tuple(c) for c in corners}
    # (within a hundredth of a spacing: the spline is smoothed and keeps the height scale,
    # so the fixed pairs are no longer interpolated exactly; 0.004 spacings here)
    np.testing.assert_allclose(res.points[-4:], corners, atol=0.01 * SP)
    # The overlap is pulled onto the targets; the far side moves less.
    moved = res.points[:-4] - s
    near, far = p[:, 0] < 0.2, p[:, 0] > 0.8
    assert np.abs(res.points[:-4][near, 2] - p[near, 2]).mean() < 0.05 * SP
    assert np.abs(moved[far, 2]).mean() < np.abs(moved[near, 2]).mean()


def test_pairing_respects_thresholds_and_never_raises_cost(rng):
    ps = rng.uniform(0, 1, (400, 3)) * [1, 1, 0.1]
    ns = rng.normal(size=(400, 3)) + [0, 0, 2]
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    q = rng.choice(400, 80, replace=False)
    pq = ps[q] + rng.normal(scale=0.02, size=(80, 3))
    nq = ns[q] + rng.normal(scale=0.3, size=(80, 3))
    nq /= np.linalg.norm(nq, axis=1, keepdims=True)
    vs, vq = surface_variation(ps), rng.uniform(0, 0.2, 80)
    w = WarpWeights(1, 2, 15, 6, 5, max_distance=2.0, max_normal=0.3, max_variation=0.08)
    spacing = 0.05
    pairs, costs = greedy_pairing(ps, ns, vs, pq, nq, vq, w, spacing, np.random.default_rng(3), iterations=4)
    assert len(pairs) > 20
    s, t = pairs[:, 0], pairs[:, 1]
    assert len(np.unique(s)) == len(s) and len(np.unique(t)) == len(t)
    assert (np.linalg.norm(ps[s] - pq[t], axis=1) <= w.max_distance * spacing + 1e-12).all()
    assert (1 - np.einsum("ij,ij->i", ns[s], nq[t]) <= w.max_normal + 1e-12).all()
    assert (np.abs(vs[s] - vq[t]) <= w.max_variation + 1e-12).all()
    assert all(b <= a for a, b in zip(costs, costs[1:]))


def test_first_pass_is_the_sequential_greedy(rng):
    # The vectorized first pass equals scanning the allowed pairs in increasing cost.
    ps = rng.uniform(0, 1, (120, 3))
    ns = np.tile([0.0, 0.0, 1.0], (120, 1))
    pq = rng.uniform(0, 1, (40, 3))
    nq = ns[:40]
    v = np.zeros(120)
    w = WarpWeights(1, 1, 1, 1, 1, max_distance=5.0)
    spacing = 0.05
    pairs, _ = greedy_pairing(ps, ns, v, pq, nq, v[:40], w, spacing, np.random.default_rng(0), iterations=0, candidates=120)
    d = np.linalg.norm(pq[:, None] - ps[None], axis=2)
    edges = sorted((d[i, j], i, j) for i in range(40) for j in range(120) if d[i, j] <= 5 * spacing)
    used_q, used_s, want = set(), set(), []
    for _, i, j in edges:
        if i not in used_q and j not in used_s:
            used_q.add(i)
            used_s.add(j)
            want.append((j, i))
    assert sorted(map(tuple, pairs.tolist())) == sorted(want)


def test_same_seed_same_warp():
    p, n = bumpy_patch()
    s, ns = rigid(p, n, 1.0, [0.2, 0.1, 0.3])
    a = warp_patch(s, ns, p[p[:, 1] < 0.3], n[p[:, 1] < 0.3], *BOX, WARP_PRESETS["weave"], SP, np.random.default_rng(5))
    b = warp_patch(s, ns, p[p[:, 1] < 0.3], n[p[:, 1] < 0.3], *BOX, WARP_PRESETS["weave"], SP, np.random.default_rng(5))
    assert np.array_equal(a.points, b.points) and np.array_equal(a.normals, b.normals)
    assert np.array_equal(a.pairs, b.pairs)


def test_surface_variation():
    p, _ = bumpy_patch()
    flat = np.c_[p[:, :2], np.zeros(len(p))]
    assert np.abs(surface_variation(flat)).max() < 1e-12
    rng = np.random.default_rng(0)
    blob = rng.normal(size=(500, 3))
    v = surface_variation(blob)
    assert 0.1 < v.mean() <= 1 / 3 + 1e-12


def test_no_target_is_the_identity():
    p, n = bumpy_patch()
    res = warp_patch(p, n, np.zeros((0, 3)), np.zeros((0, 3)), *BOX, WarpWeights(), SP, np.random.default_rng(0))
    np.testing.assert_array_equal(res.points, p)
    assert len(res.pairs) == 0


@pytest.mark.parametrize("bad, match", [
    (dict(spacing=0.0), "spacing"),
    (dict(src_points=np.full((3, 3), np.nan)), "NaN"),
    (dict(box_max=np.array([0.0, 1.0, 0.2])), "extent"),
    (dict(src_normals=np.zeros((3, 3))), "zero-length"),
])
def test_bad_input(bad, match):
    args = dict(src_points=np.eye(3), src_normals=np.tile([0, 0, 1.0], (3, 1)), target_points=np.eye(3),
                target_normals=np.tile([0, 0, 1.0], (3, 1)), box_min=BOX[0], box_max=BOX[1],
                weights=WarpWeights(), spacing=SP, rng=np.random.default_rng(0))
    args.update(bad)
    with pytest.raises(ValueError, match=match):
        warp_patch(**args)
    with pytest.raises(ValueError, match="w_n"):
        WarpWeights(w_n=-1)


def test_float32_evaluation_is_within_a_thousandth_of_a_spacing(rng):
    c = rng.uniform(0, 1, (150, 3)) * [1, 1, 0.1]
    y = c + rng.normal(scale=0.3 * SP, size=c.shape)
    x = rng.uniform(0, 1, (3000, 3)) * [1, 1, 0.1]
    n = np.tile([0.0, 0.0, 1.0], (3000, 1))
    p64, n64 = ThinPlateSpline(c, y).transform(x, n)
    p32, n32 = ThinPlateSpline(c, y, dtype=np.float32).transform(x, n)
    assert np.abs(p32 - p64).max() < 1e-3 * SP
    assert angle_deg(n32, n64).max() < 0.01


def test_synthesis_and_spline_hold_one_blas_thread_and_restore(monkeypatch):
    """The spline evaluation runs with one BLAS thread (threadpoolctl) and gives the count back."""
    import scipy.linalg  # noqa: F401  (SciPy's own OpenBLAS copy too)
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    if not blas_threads():
        pytest.skip("no BLAS with a thread control is loaded")
    rng = np.random.default_rng(0)
    c = rng.uniform(0, 1, (30, 3))
    spline = ThinPlateSpline(c, c + 0.01)
    seen = []
    real = ThinPlateSpline._eval
    monkeypatch.setattr(ThinPlateSpline, "_eval", lambda self, *a: (seen.append(blas_threads()), real(self, *a))[1])
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        spline(c)
        assert seen and all(n == 1 for n in seen[-1])
        assert blas_threads() == before


@pytest.mark.parametrize("name", ["_adaptive_clusters", "_adaptive_clusters_numpy"])
def test_one_pass_clustering_with_fallback_equals_two_runs(name):
    """_adaptive_clusters with ``fallback_size`` gives, in one pass, what two runs gave: the
    variation clustering when it stays within the limit, else the size-only clustering
    from scratch. Point sets where the first run passes the limit and where it does not,
    with coincident points (clusters that cannot be split)."""
    import math

    import geosynth.pointtexture.warping

    _adaptive_clusters = getattr(geosynth.pointtexture.warping, name)
    rng = np.random.default_rng(5)
    fallbacks = firsts = 0
    for trial in range(60):
        n = int(rng.integers(20, 3000))
        if trial % 3 == 0:
            p = rng.random((n, 3)) * [10, 10, 1]
        elif trial % 3 == 1:
            t = rng.random(n) * 20
            p = np.c_[3 * np.cos(t) + rng.random(n), 3 * np.sin(t), rng.normal(0, 0.3, n)]
        else:
            p = np.round(rng.random((n, 3)) * [20, 20, 2]) / 2  # many coincident points
        limit = int(rng.integers(5, 300))
        size = max(12, math.ceil(n / limit))
        fallback = max(size, math.ceil(1.5 * n / limit))
        first = _adaptive_clusters(p, size, 0.05, limit=limit)
        want = first if first is not None else _adaptive_clusters(p, fallback, math.inf)
        if first is None:
            fallbacks += 1
            assert len(want) <= len(_adaptive_clusters(p, size, 0.05))  # the fallback is coarser
        else:
            firsts += 1
            assert len(first) <= limit
        np.testing.assert_array_equal(_adaptive_clusters(p, size, 0.05, limit=limit, fallback_size=fallback), want)
    assert fallbacks > 5 and firsts > 5
    with pytest.raises(ValueError, match="fallback_size"):
        _adaptive_clusters(p, 20, 0.05, limit=10, fallback_size=10)


def test_greedy_match_is_the_sequential_scan():
    """_greedy_match (vectorized rounds of "first remaining edge of its q and its s") takes
    exactly the edges a sequential scan in the given order takes, in that order."""
    from geosynth.pointtexture.warping import _greedy_match_numpy as _greedy_match

    rng = np.random.default_rng(11)
    for trial in range(40):
        e = int(rng.integers(1, 600))
        eq = rng.integers(0, int(rng.integers(1, 60)), e)
        es = rng.integers(0, int(rng.integers(1, 200)), e)
        order = rng.permutation(e)
        used_q, used_s, want = set(), set(), []
        for k in order:
            if eq[k] not in used_q and es[k] not in used_s:
                used_q.add(eq[k])
                used_s.add(es[k])
                want.append(k)
        np.testing.assert_array_equal(_greedy_match(eq, es, order), np.array(want, np.int64))
    assert _greedy_match(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)).size == 0


def test_neighbour_mean_is_the_mean_bit_for_bit(rng):
    from geosynth.pointtexture.warping import _neighbour_mean

    p = rng.normal(size=(500, 3)) * [3.0, 1.0, 0.01] + 100.0
    for k in (1, 2, 7, 16):
        idx = rng.integers(0, len(p), (500, k))
        assert np.array_equal(_neighbour_mean(p, idx), p[idx].mean(axis=1))


def test_spline_evaluation_is_the_plain_formula(rng):
    """The chunked evaluation (r^2 as one float64 product |u|^2 + |c|^2 - 2 u.c, entries
    within rounding of 0 taken as r = 0, reused buffers) gives the formula written out with
    direct differences in float64 (masked log): to float64 rounding with dtype float64, to
    float32's with float32; including points that are centres and a last, partial chunk."""
    c = rng.uniform(0, 1, (90, 3)) * [1, 1, 0.1]
    y = c + rng.normal(scale=0.3 * SP, size=c.shape)
    x = np.concatenate([rng.uniform(0, 1, (700, 3)) * [1, 1, 0.1], c[::3]])  # some points are centres
    spline = ThinPlateSpline(c, y)
    u = (x - spline.shift) / spline.scale
    r2 = ThinPlateSpline._r2(u, spline.centres)
    pos = r2 > 0
    log_r2 = np.log(r2, out=np.zeros_like(r2), where=pos)
    disp = 0.5 * ((r2 * log_r2) @ spline.w) + spline.affine[0] + u @ spline.affine[1:]
    psi = (log_r2 + 1.0) * pos
    e = u[:, None, :] - spline.centres[None]  # (m, n, 3)
    jac = np.einsum("mi,ik,mij->mkj", psi, spline.w, e) + np.eye(3) + spline.affine[1:].T
    want_p = x + disp * spline.scale
    assert not pos.all()  # the centres among x hit r = 0
    for dtype, tol_p, tol_j in ((np.float64, 1e-12, 1e-10), (np.float32, 1e-5, 1e-4)):
        s = ThinPlateSpline(c, y, dtype=dtype)
        assert len(x) % s._CHUNK != 0  # a partial last chunk
        np.testing.assert_allclose(s(x), want_p, rtol=0, atol=tol_p)
        np.testing.assert_allclose(s.jacobian(x), jac, rtol=0, atol=tol_j)


# ---------------------------------------------------------------- compiled host steps vs NumPy


def _general_position_sets(rng, count):
    """Point sets without exact ties (no point on a splitting plane): boxes, rings, sheets."""
    for trial in range(count):
        n = int(rng.integers(1, 2500))
        kind = trial % 3
        if kind == 0:
            p = rng.random((n, 3)) * [10, 10, 1]
        elif kind == 1:
            t = rng.random(n) * 20
            p = np.c_[3 * np.cos(t) + rng.random(n), 3 * np.sin(t), rng.normal(0, 0.3, n)]
        else:
            xy = rng.random((n, 2)) * 5
            p = np.c_[xy, 0.2 * np.sin(3 * xy[:, 0]) + 1e-3 * rng.normal(size=n)]
        yield n, p


def test_cluster_kernel_equals_numpy():
    """The compiled clustering (depth first, closed-form eigenvalues) gives the NumPy
    clustering's representatives exactly on point sets in general position, with and
    without the limit and the size-only fallback, and None where both give up."""
    import math

    from geosynth.pointtexture.warping import _adaptive_clusters, _adaptive_clusters_numpy

    rng = np.random.default_rng(21)
    nones = 0
    for n, p in _general_position_sets(rng, 60):
        limit = int(rng.integers(3, 300))
        size = max(12, math.ceil(n / limit))
        fallback = max(size, math.ceil(1.5 * n / limit))
        for kw in (dict(), dict(limit=limit), dict(limit=limit, fallback_size=fallback)):
            got, want = _adaptive_clusters(p, size, 0.05, **kw), _adaptive_clusters_numpy(p, size, 0.05, **kw)
            if want is None:
                nones += 1
                assert got is None
            else:
                assert got.dtype == np.int64
                np.testing.assert_array_equal(got, want)
    assert nones > 5
    # edge cases: no point, one point, coincident points (never split: the lowest index)
    for p in (np.zeros((0, 3)), np.ones((1, 3)), np.ones((40, 3)), np.r_[np.ones((20, 3)), np.zeros((20, 3))]):
        np.testing.assert_array_equal(_adaptive_clusters(p, 12), _adaptive_clusters_numpy(p, 12))
    np.testing.assert_array_equal(_adaptive_clusters(np.ones((40, 3)), 12), [0])


def test_cluster_kernel_splits_coincident_grids_sensibly():
    """On points with many exact ties (a coarse grid) the split of a point on the plane
    may differ from LAPACK's axis sign; the clusterings still have about as many clusters
    and valid, distinct representatives."""
    from geosynth.pointtexture.warping import _adaptive_clusters, _adaptive_clusters_numpy

    rng = np.random.default_rng(4)
    for _ in range(10):
        p = np.round(rng.random((int(rng.integers(50, 2000)), 3)) * [20, 20, 2]) / 2
        got, want = _adaptive_clusters(p, 12), _adaptive_clusters_numpy(p, 12)
        assert len(np.unique(got)) == len(got) and got.min() >= 0 and got.max() < len(p)
        assert abs(len(got) - len(want)) <= 0.1 * len(want) + 2


def _pairing_case(rng, n_s, n_q, spread):
    ps = rng.uniform(0, 1, (n_s, 3)) * [1, 1, 0.1]
    ns = rng.normal(size=(n_s, 3)) + [0, 0, 2]
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    q = rng.choice(n_s, min(n_q, n_s), replace=False)
    pq = ps[q] + rng.normal(scale=spread, size=(len(q), 3))
    nq = ns[q] + rng.normal(scale=0.2, size=(len(q), 3))
    nq /= np.linalg.norm(nq, axis=1, keepdims=True)
    return ps, ns, rng.uniform(0, 0.1, n_s), pq, nq, rng.uniform(0, 0.1, len(q))


def test_pairing_kernel_equals_numpy():
    """The passes in one compiled launch give the NumPy passes' pairs and costs (to
    float64 rounding); they may part only where rounding decides between two pairings of
    equal cost (a later pass whose cost equals the last one's to ~1e-15): then the pairs
    of the common passes agree."""
    from geosynth.pointtexture.warping import _greedy_pairing

    rng = np.random.default_rng(8)
    w = WarpWeights(1, 2, 15, 6, 5)
    same = 0
    for trial in range(40):
        n_s = int(rng.integers(30, 2500))
        ps, ns, vs, pq, nq, vq = _pairing_case(rng, n_s, int(rng.integers(1, 220)), 0.02)
        sp = 1 / np.sqrt(n_s)
        for it in (0, 3):
            got = _greedy_pairing(ps, ns, vs, pq, nq, vq, w, sp, np.random.default_rng(trial), iterations=it)
            want = _greedy_pairing(ps, ns, vs, pq, nq, vq, w, sp, np.random.default_rng(trial), iterations=it,
                                   numpy_oracle=True)
            common = min(len(got[1]), len(want[1]))
            np.testing.assert_allclose(got[1][:common], want[1][:common], rtol=1e-12)
            if len(got[1]) == len(want[1]):
                same += 1
                np.testing.assert_array_equal(got[0], want[0])
            else:  # an extra pass of equal cost on one side
                longer = got[1] if len(got[1]) > len(want[1]) else want[1]
                assert abs(longer[-1] - longer[-2]) <= 1e-12 * abs(longer[-1])
    assert same >= 70
    # normals opposite (few allowed edges), all targets out of reach (no edge: no pair,
    # every q at miss cost), one q (no neighbour r in Q)
    ps, ns, vs, pq, nq, vq = _pairing_case(rng, 200, 20, 0.01)
    strict = WarpWeights(1, 2, 15, 6, 5, max_normal=0.3)
    for args in ((ps, ns, vs, pq, -nq, vq), (ps, ns, vs, pq + 10.0, nq, vq), (ps, ns, vs, pq[:1], nq[:1], vq[:1])):
        got = _greedy_pairing(*args, strict, 0.05, np.random.default_rng(0))
        want = _greedy_pairing(*args, strict, 0.05, np.random.default_rng(0), numpy_oracle=True)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
    far = _greedy_pairing(ps, ns, vs, pq + 10.0, nq, vq, strict, 0.05, np.random.default_rng(0))
    assert len(far[0]) == 0 and far[1] == (pytest.approx(20 * (4.0 / 32 + 0.5 * 2 * 0.3 + 15 * 0.01 + 5)),)


def test_jacobian_normals_kernel_equals_numpy(rng):
    """The compiled normals from Jacobians equal the NumPy form to float64 rounding,
    including normals near +-x (the other tangent helper) and collapsed Jacobians."""
    from geosynth.pointtexture.warping import _jacobian_normals, _jacobian_normals_numpy

    m = 500
    n = rng.normal(size=(m, 3))
    n[:50] = [1.0, 0.0, 0.0] + 0.05 * rng.normal(size=(50, 3))  # |n_x| >= 0.9
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    jac = np.eye(3) + 0.3 * rng.normal(size=(m, 3, 3))
    jac[-20:] = 0.0  # collapsed: the normal is kept
    jac[-40:-20] = np.outer([1.0, 2.0, 0.5], [0.3, -0.2, 1.0])  # rank 1: collapsed too
    got, want = _jacobian_normals(jac, n), _jacobian_normals_numpy(jac, n)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got[-40:], n[-40:])
    assert _jacobian_normals(np.zeros((0, 3, 3)), np.zeros((0, 3))).shape == (0, 3)


def test_variation_and_outskirt_kernels_equal_numpy(rng):
    """The compiled surface variation and outskirt test equal their NumPy forms (float64
    rounding; the outskirt flags exactly away from the threshold), on a bumpy sheet, a
    blob, and degenerate neighbourhoods (coincident points: variation 0; a line: 0)."""
    from geosynth.pointtexture.warping import _outskirts, _outskirts_numpy, _variation_of, _variation_of_numpy

    p, _ = bumpy_patch()
    blob = rng.normal(size=(400, 3))
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    same = np.ones((30, 3))
    for pts in (p, blob, line, same):
        for k in (3, 7, 16):
            idx = rng.integers(0, len(pts), (200, k))
            np.testing.assert_allclose(_variation_of(pts, idx), _variation_of_numpy(pts, idx), rtol=0, atol=1e-12)
    assert np.all(_variation_of(same, np.zeros((5, 16), np.int64)) == 0)
    assert np.abs(_variation_of(line, np.arange(50)[None])).max() < 1e-12
    edge = p[(p[:, 0] < 0.3) | (p[:, 1] > 0.7)]  # an L-shaped strip: outskirts along its borders
    for pts in (edge, blob):
        got, got_idx = _outskirts(pts, 16)
        want, want_idx = _outskirts_numpy(pts, 16)
        np.testing.assert_array_equal(got_idx, want_idx)
        np.testing.assert_array_equal(got, want)
        assert 0 < got.sum() < len(pts)


def test_float32_transform_kernel_equals_the_numpy_jacobian_normals(rng):
    """With float32 kernel matrices, transform assembles each Jacobian from its kernel sums
    inside the compiled host step; the NumPy route (jacobian(), then the normals' NumPy
    form) gives the same positions and normals to float64 rounding, points on centres included."""
    from geosynth.pointtexture.warping import _jacobian_normals_numpy

    c = rng.uniform(0, 1, (80, 3)) * [1, 1, 0.1]
    y = c + rng.normal(scale=0.3 * SP, size=c.shape)
    x = np.concatenate([rng.uniform(0, 1, (600, 3)) * [1, 1, 0.1], c[::4]])
    n = rng.normal(size=x.shape) + [0, 0, 3]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    spline = ThinPlateSpline(c, y, dtype=np.float32)
    p, wn = spline.transform(x, n)
    np.testing.assert_array_equal(p, spline(x))
    np.testing.assert_allclose(wn, _jacobian_normals_numpy(spline.jacobian(x), n), rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_spline_evaluation_is_the_same_bits_on_any_number_of_host_threads(rng, monkeypatch, dtype):
    """The evaluation's chunks are shared among the cores (host_steps.run_parts): 1, 2 or
    3 parts give the same bits, positions and normals."""
    c = rng.uniform(0, 1, (120, 3)) * [1, 1, 0.1]
    y = c + rng.normal(scale=0.3 * SP, size=c.shape)
    x = rng.uniform(0, 1, (3000, 3)) * [1, 1, 0.1]  # 12 chunks of 256 rows: up to 3 parts
    n = rng.normal(size=x.shape) + [0, 0, 3]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    spline = ThinPlateSpline(c, y, dtype=dtype)
    got = []
    for threads in ("1", "2", "3"):
        monkeypatch.setenv("GEOSYNTH_HOST_THREADS", threads)
        got.append(spline.transform(x, n))
    for p, wn in got[1:]:
        np.testing.assert_array_equal(p, got[0][0])
        np.testing.assert_array_equal(wn, got[0][1])


def test_compiled_nearest_neighbours_are_pykdtrees(rng, monkeypatch):
    """The warp's k nearest (warping._KDTree, by blending.nearest_k's compiled step): the
    distances and indices of pykdtree, bit for bit, with and without an upper bound; on a
    grid's exact ties the same distances, ties ordered by lower index."""
    from pykdtree.kdtree import KDTree

    from geosynth.pointtexture.warping import _kdtree

    xy = rng.uniform(0, 1, (3000, 2))
    p = np.c_[xy, 0.05 * np.sin(7 * xy[:, 0])]
    q = np.concatenate([p[::5] + rng.normal(scale=0.003, size=(600, 3)), [[5.0, 5.0, 5.0]]])  # one far query
    for threads in ("1", "2"):
        monkeypatch.setenv("GEOSYNTH_HOST_THREADS", threads)
        for k, bound in [(16, None), (12, 0.02), (1, None), (3000, None)]:
            d, i = KDTree(p, leafsize=16).query(q, k=k, distance_upper_bound=bound)
            got_d, got_i = _kdtree(p).query(q, k=k, distance_upper_bound=bound)
            np.testing.assert_array_equal(got_d, d.reshape(len(q), k))
            np.testing.assert_array_equal(got_i, i.reshape(len(q), k))
        assert (got_i[-1] < 3000).all()  # every point for a far query without a bound
    _, i = _kdtree(p).query(q, k=12, distance_upper_bound=0.02)
    assert (i[-1] == 3000).all()  # none within the bound: index N, distance inf
    g = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0), indexing="ij"), -1).reshape(-1, 2)
    grid = np.c_[g, np.zeros(len(g))][rng.permutation(len(g))]  # whole numbers: exact ties
    d, _ = KDTree(grid, leafsize=16).query(grid[::7], k=9)
    got_d, got_i = _kdtree(grid).query(grid[::7], k=9)
    np.testing.assert_array_equal(got_d, d)
    # within a row: by distance, then index (pykdtree orders exact ties otherwise)
    assert all(np.array_equal(np.lexsort((got_i[r], got_d[r])), np.arange(9)) for r in range(len(got_d)))
    assert (got_d[:, 1:] == got_d[:, :-1]).sum() > 50  # ties were there to order


def _interior_height_scale(keep_height_scale, smoothing):
    """The slope of the warped heights on the source's heights inside the patch (away from
    the overlap) when the neighbourhood in the -x and -y overlap is the source's relief at
    half its height (a neighbour that matches only approximately)."""
    p, n = bumpy_patch()
    strip = (p[:, 0] < 0.25) | (p[:, 1] < 0.25)
    t = p[strip] * [1.0, 1.0, 0.5]
    res = warp_patch(p, n, t, n[strip], *BOX, WARP_PRESETS["heightfield"], SP, np.random.default_rng(0),
                     keep_height_scale=keep_height_scale, smoothing=smoothing)
    inner = (p[:, :2] > 0.4).all(axis=1)
    z0 = p[inner, 2] - p[inner, 2].mean()
    z1 = res.points[inner, 2] - res.points[inner, 2].mean()
    return float(z0 @ z1 / (z0 @ z0)), res


def test_warp_keeps_the_interior_relief_height():
    # The pairs lie on a thin sheet: the paper's spline reads the neighbour's lower relief
    # as a vertical scaling and squashes the patch also where it has no neighbour; the
    # default drops the spline's vertical scaling and keeps the heights' scale.
    paper, _ = _interior_height_scale(False, 0.0)
    kept, res = _interior_height_scale(True, 0.1)
    assert paper < 0.9, paper
    assert kept > 0.94, kept
    assert len(res.pairs) > 20  # the overlap was paired (else nothing was tested)


@pytest.mark.parametrize("bad", [-1.0, float("nan"), True, "1"])
def test_smoothing_is_checked(bad):
    p, n = bumpy_patch()
    with pytest.raises(ValueError, match="smoothing"):
        warp_patch(p, n, p[:10], n[:10], *BOX, WARP_PRESETS["heightfield"], SP, np.random.default_rng(0),
                   smoothing=bad)
