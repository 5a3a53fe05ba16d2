"""M2, geometry texture synthesis on point-set surfaces: the search against brute force, the
patch field cut from D(T_in), synthesis on a flat plane, determinism across devices and
seeds, tileable output, and bad input."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from geosynth.geometry.pointsets import MLS_REACH, pointset_distance
from geosynth.pointtexture.examples import point_texture_example
from geosynth.pointtexture.patch_search import PatchSearch, brute_force_scores, host_mls, quantized_fields
from geosynth.pointtexture.synthesis import synthesize_point_texture
from geosynth.pointtexture.texture import PointTexture, texture_from_image, texture_from_points

SMALL = dict(scale=1.2, patch=0.5, resolution=24, quality=False)


def _wavy(n_side=70, pad=0.25, seed=0):
    """A small wavy height field over [0, 1]^2 plus padding, with analytic normals."""
    rng = np.random.default_rng(seed)
    u = np.linspace(-pad, 1 + pad, n_side)
    x, y = np.meshgrid(u, u)
    s = u[1] - u[0]
    x = x.ravel() + rng.uniform(-0.2, 0.2, x.size) * s
    y = y.ravel() + rng.uniform(-0.2, 0.2, y.size) * s
    k = 2 * np.pi * 2.5
    z = 0.04 * np.sin(k * x) * np.cos(k * y)
    n = np.stack([-0.04 * k * np.cos(k * x) * np.cos(k * y), 0.04 * k * np.sin(k * x) * np.sin(k * y),
                  np.ones_like(x)], 1)
    return PointTexture(np.c_[x, y, z], n, [0, 0, -0.04], [1, 1, 0.04], name="wavy")


@pytest.fixture(scope="module")
def wavy():
    return _wavy()


@pytest.fixture(scope="module")
def small_weave():
    return point_texture_example("weave", count=10_000)


def _search(tex, device, resolution=16, patch=6, extra=2):
    cell = 1.0 / (resolution - 1)
    h = 2 * tex.spacing
    return PatchSearch(tex, cell, patch, extra, h, MLS_REACH * h, device)


def test_host_mls_matches_the_kernel(wavy, one_device, rng):
    q = rng.uniform([0.1, 0.1, -0.08], [0.9, 0.9, 0.08], (200, 3))
    h = 2 * wavy.spacing
    d, g = host_mls(wavy.points, wavy.normals, q, h)
    dk, gk = pointset_distance(wavy.points.astype(np.float32), wavy.normals.astype(np.float32), q.astype(np.float32),
                               radius=h, device=one_device)
    np.testing.assert_allclose(d, dk, atol=2e-5 * h)
    np.testing.assert_allclose(g, gk, atol=2e-5)


def _mls_f(points, normals, y, h):
    """f(y) = n(y) . (y - a(y)) of the MLS surface in plain NumPy, float64 ((m,) NaN where
    no point lies within reach)."""
    p, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    d2 = ((y[:, None, :] - p[None]) ** 2).sum(axis=2)
    w = np.where(d2 < (MLS_REACH * h) ** 2, np.exp(-d2 / h ** 2), 0.0)
    ws = w.sum(axis=1)
    m = w @ n
    ml = np.linalg.norm(m, axis=1)
    ok = (ws > 0) & (ml > 0)
    a = (w @ p) / np.where(ok, ws, 1.0)[:, None]
    f = np.einsum("ij,ij->i", m / np.where(ok, ml, 1.0)[:, None], y - a)
    return np.where(ok, f, np.nan)


def test_fixed_step_kernel_residual_and_projection(wavy, device, rng):
    """kernel_mls on every device: FIXED_STEPS steps (stopping early only at an exact fixed
    point) give the float64 host projection's distance and normal to float32 accuracy where
    they converge, and the residual, computed in the same launch, is f at the returned
    projection (NumPy reference; what a fresh one-step launch from there gives), reach
    where no point is within reach."""
    from geosynth.pointtexture.patch_search import FIXED_STEPS, RESIDUAL_TOL, kernel_mls

    h = 2 * wavy.spacing
    reach = MLS_REACH * h
    near = rng.uniform([0.1, 0.1, -0.08], [0.9, 0.9, 0.08], (300, 3))
    far = np.array([[0.5, 0.5, 1.0], [0.2, 0.7, -0.9]])  # nothing within reach
    q = np.concatenate([near, far])
    d, g, proj, res, cells = kernel_mls(wavy.points, wavy.normals, q, h, device, FIXED_STEPS)
    want = _mls_f(wavy.points, wavy.normals, proj[:300], h)
    support = np.isfinite(want)  # a projection can wander out of every point's reach
    assert support.sum() > 280
    np.testing.assert_allclose(res[:300][support], want[support], atol=1e-5 * h)
    np.testing.assert_array_equal(res[:300][~support], np.float32(reach))
    conv = np.flatnonzero(np.abs(res[:300]) <= RESIDUAL_TOL * h)  # the pipeline's converged test
    assert 250 < conv.size < 300  # most converge in FIXED_STEPS steps, the farthest do not
    dh, gh = host_mls(wavy.points, wavy.normals, near[conv], h, fixed=True)
    np.testing.assert_allclose(d[conv], dh, atol=2e-5 * h)
    np.testing.assert_allclose(g[conv], gh, atol=2e-5)
    np.testing.assert_array_equal(res[300:], np.float32(reach))
    np.testing.assert_array_equal(d[300:], np.float32(reach))
    # one step from the projection: a residual of f there (the same definition, a fresh launch)
    d1, _, _, _, _ = kernel_mls(wavy.points, wavy.normals, proj[:300], h, device, 1, cells)
    np.testing.assert_allclose(np.abs(res[:300]), np.abs(d1), atol=1e-6 * h)


def test_patch_field_cut_from_d_tin_equals_the_direct_field(wavy, device):
    s = _search(wavy, device)
    o = s.origins[len(s.origins) // 2 + 3]
    lo = s.window_world(o)
    span = (s.patch + s.extra) * s.cell
    reach = s.band
    # the patch's own points (with a margin), moved far away, as a pasted patch would be
    sel = ((wavy.points[:, :2] >= lo - 2 * reach) & (wavy.points[:, :2] <= lo + span + 2 * reach)).all(axis=1)
    shift = np.array([5.0, -3.0, 0.0])
    k, j, i = np.meshgrid(*(np.arange(c) for c in (s.shape[0], s.patch, s.patch)), indexing="ij")
    world = np.stack([lo[0] + i.ravel() * s.cell, lo[1] + j.ravel() * s.cell, s.z0 + k.ravel() * s.cell], 1)
    direct, _ = quantized_fields(wavy.points[sel] + shift, wavy.normals[sel], world + shift, s.h, s.band, device)
    cut = s.codes[o[0] + k.ravel(), o[1] + j.ravel(), o[2] + i.ravel()]
    assert cut.std() > 5  # the field is not constant
    np.testing.assert_array_equal(direct, cut)


def test_search_equals_brute_force(wavy, device):
    s = _search(wavy, device)
    sides = [("-x", 2), ("-y", 2)]
    off = s.overlap_offsets(sides)
    assert len(off) == s.shape[0] * (2 * 6 * 2 - 4)
    values = s.codes[off[:, 0], 4 + off[:, 1], 3 + off[:, 2]].copy()  # a candidate's window...
    values[::7] = 255 - values[::7]  # ...changed, so that the best is not an exact copy
    want = brute_force_scores(s.codes, s.origins, off, values)
    got = s.scores(off, values)
    np.testing.assert_array_equal(got.astype(np.int64), want)
    eps = 0.5
    choice = s.choose(off, values, eps, np.random.default_rng(7))
    near = np.flatnonzero(want <= np.floor((1 + eps) * want.min()))
    assert choice.best == want.min() > 0
    assert choice.candidates == len(near)
    assert choice.index == near[np.random.default_rng(7).integers(len(near))]


def test_flat_plane_gives_a_flat_plane(one_device):
    rng = np.random.default_rng(3)
    u = np.linspace(-0.25, 1.25, 60)
    x, y = np.meshgrid(u, u)
    p = np.c_[x.ravel() + rng.uniform(-0.004, 0.004, x.size), y.ravel() + rng.uniform(-0.004, 0.004, x.size),
              np.zeros(x.size)]
    tex = texture_from_points(p, np.tile([0, 0, 1.0], (len(p), 1)), box=[[0, 0, 0], [1, 1, 0]])
    pts, report, _ = synthesize_point_texture(tex, device=one_device, **SMALL)
    z = pts.positions[:, 2]
    assert np.abs(z).max() < 1e-4
    assert np.abs(pts.normals[:, 2]).min() > 0.999
    # the plane is covered: every 0.05 cell of the output holds points
    cells = np.floor(pts.positions[:, :2] / 0.05).astype(int)
    assert len(np.unique(cells, axis=0)) == int(np.ceil(1.2 / 0.05)) ** 2
    assert report.points_out == len(pts)


@pytest.mark.parametrize("name", ["weave", "flowers"])  # flowers: thin petals, slow MLS convergence
def test_same_seed_same_points_on_every_device(device_pair, name):
    tex = point_texture_example(name, count=10_000)
    a, _, _ = synthesize_point_texture(tex, device=device_pair[0], seed=5, **SMALL)
    b, _, _ = synthesize_point_texture(tex, device=device_pair[1], seed=5, **SMALL)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.normals, b.normals)


def test_the_seed_decides_the_points(one_device, small_weave):
    a, _, _ = synthesize_point_texture(small_weave, device=one_device, seed=5, **SMALL)
    again, _, _ = synthesize_point_texture(small_weave, device=one_device, seed=5, **SMALL)
    other, _, _ = synthesize_point_texture(small_weave, device=one_device, seed=6, **SMALL)
    np.testing.assert_array_equal(a.positions, again.positions)
    assert a.positions.shape != other.positions.shape or not np.array_equal(a.positions, other.positions)


def test_no_device_given_runs_on_auto(small_weave):
    # device=None (the CLI without --device) means "auto", resolved once for every stage (it once
    # reached the gather scorer as None and failed)
    from geosynth.compute.backend import resolve_device

    auto = resolve_device("auto")
    a, report, _ = synthesize_point_texture(small_weave, device=None, seed=5, **SMALL)
    b, _, _ = synthesize_point_texture(small_weave, device=auto, seed=5, **SMALL)
    assert report.device == auto
    np.testing.assert_array_equal(a.positions, b.positions)


# Weave over 3 seeds: (worst, mean) bounds of each ratio. Measured over seeds 0-5 with the
# smoothed, height-keeping warp (issue 32; the same bits on every device and CPU), mean / worst:
# field distance / random pasting's 0.392 / 0.518; seam after / before blending 0.739 / 0.772
# (the warp leaves a smaller seam to blend: before / random pasting's 0.274 / 0.340, the
# paper's interpolating spline 0.449 / 0.534); stray points 0.029 / 0.031.
WEAVE_BEATS = {"field": (0.7, 0.5), "seam_after_before": (0.85, 0.8), "seam_before_baseline": (0.5, 0.4),
               "stray": (0.1, 0.06)}


def test_synthesis_beats_random_pasting(one_device, small_weave):
    got = {k: [] for k in WEAVE_BEATS}
    for seed in range(3):
        _, report, timings = synthesize_point_texture(small_weave, device=one_device, seed=seed,
                                                      **{**SMALL, "quality": True, "quality_samples": 6})
        q = report.quality
        got["field"].append(q["field_distance"][2] / q["field_distance_baseline"][2])
        got["seam_after_before"].append(q["seam_after"] / q["seam_before"])
        got["seam_before_baseline"].append(q["seam_before"] / q["seam_baseline"])
        got["stray"].append(q["stray"])
        assert set(timings) >= {"search", "warp", "blend", "other", "total"}
    for key, (worst, mean) in WEAVE_BEATS.items():
        assert max(got[key]) < worst and np.mean(got[key]) < mean, (key, got[key])


@pytest.mark.parametrize("name, expected", [("flowers", True), ("heightfield", False), ("chainmail", False),
                                            ("weave", False)])
def test_only_the_flowers_have_disconnected_pieces(name, expected):
    """The overlap is cut rather than blended only for an exemplar with disconnected pieces
    (blending.has_pieces): the flowers; the other built-ins' outputs are left as they were."""
    from geosynth.pointtexture.blending import has_pieces

    tex = point_texture_example(name, count=10_000)
    assert has_pieces(tex.points, tex.spacing) is expected


def test_blending_lowers_the_seam_error_on_flowers_over_seeds(one_device):
    """Flowers (small disconnected pieces on a plane): blending alone hardly lowered the
    seam error (a flower one side lacks cannot be blended away); with the pieces N_k or
    the patch lacks cut whole (blending.cut_pieces) it does on average, and a patch whose
    blend would raise its seam error is pasted as warped (issue 40: the blend made the
    seam worse on a third of the seeds). A claim over seeds, on the mean and the worst:
    measured over 20 seeds (0-19), after/before mean 0.900 / worst 0.940, the same as
    native, AVX2 and SSE4 (bench/RESULTS.md); here 6 seeds."""
    tex = point_texture_example("flowers", count=10_000)
    ratios = []
    for seed in range(6):
        _, report, _ = synthesize_point_texture(tex, device=one_device, seed=seed,
                                                **{**SMALL, "patch": 0.4, "quality": True, "quality_samples": 4})
        q = report.quality
        ratios.append(q["seam_after"] / q["seam_before"])
        assert report.kept_warp < report.patches
    assert max(ratios) <= 1.0 and np.mean(ratios) <= 0.95, ratios


def test_tileable_output_continues_across_its_borders(one_device, wavy):
    """The points near the right border, moved by one period, lie on the surface of those near
    the left: median distance in spacings over seeds 0-2, worst < 0.3 and mean < 0.18 (measured
    over seeds 0-19 as native, AVX2 and SSE4: 0.084 mean, 0.147 worst, sd 0.039)."""
    medians = []
    for seed in range(3):
        pts, report, _ = synthesize_point_texture(wavy, device=one_device, tileable=True, seed=seed, **SMALL)
        assert report.tileable
        w = np.asarray(report.size)
        p, n = pts.positions.astype(np.float64), pts.normals
        assert p[:, 0].min() >= 0 and p[:, 0].max() < w[0]
        h = 2 * report.spacing
        right = p[:, 0] > w[0] - 2 * h
        left = p[:, 0] < 4 * h
        moved = p[right] - [w[0], 0, 0]
        d, _ = pointset_distance(np.r_[p[left], moved].astype(np.float32), np.r_[n[left], n[right]],
                                 moved.astype(np.float32), radius=h, device=one_device)
        medians.append(np.median(np.abs(d)) / report.spacing)
    assert max(medians) < 0.3 and np.mean(medians) < 0.18, medians


# ------------------------------------------------------------------ bad input


def test_no_normals_and_too_few_neighbours():
    t = np.linspace(0, 1, 40)
    p = np.c_[np.r_[t, t], np.r_[np.zeros(40), np.full(40, 10.0)], np.zeros(80)]  # two far lines: no plane near
    with pytest.raises(ValueError, match="no normals and they cannot be estimated"):
        texture_from_points(p)


def test_collinear_points_are_refused_as_such():
    t = np.linspace(0, 1, 40)
    with pytest.raises(ValueError, match="lie on one line"):
        texture_from_points(np.c_[t, t, 0.5 * t])  # with or without normals: no surface over xy
    with pytest.raises(ValueError, match="span no extent in y"):
        texture_from_points(np.c_[t, np.zeros(40), np.sin(9 * t)], np.tile([0, 0, 1.0], (40, 1)))


def test_empty_box(wavy):
    with pytest.raises(ValueError, match="is empty"):
        PointTexture(wavy.points, wavy.normals, [0.5, 0.5, 0], [0.5, 0.9, 0])


def test_patch_larger_than_the_exemplar(wavy, one_device):
    with pytest.raises(ValueError, match="use a smaller patch"):
        synthesize_point_texture(wavy, patch=1.0, device=one_device, quality=False)


def test_nan_positions(wavy):
    p = wavy.points.copy()
    p[7, 1] = np.nan
    with pytest.raises(ValueError, match="NaN or inf, the first at index 7"):
        texture_from_points(p, wavy.normals)


def test_constant_image():
    with pytest.raises(ValueError, match="constant"):
        texture_from_image(np.full((32, 32), 128, np.uint8))


def test_cli_bad_input_is_one_line_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "geosynth", "pointtexture", "--example", "weave", "-o",
                        str(tmp_path / "o.ply"), "--patch", "1.0", "--count", "2000", "--no-quality"],
                       capture_output=True, text=True, timeout=120,
                       env={k: v for k, v in os.environ.items() if k != "GEOSYNTH_VERBOSE"})  # set by --verbose tests
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "smaller --patch" in r.stderr


def test_mesh_of_the_output_is_watertight(one_device, wavy):
    from geosynth.pointtexture.synthesis import output_mesh

    pts, report, _ = synthesize_point_texture(wavy, device=one_device, **SMALL)
    mesh = output_mesh(pts.positions, pts.normals, report.spacing, resolution=40, device=one_device)
    assert mesh.is_watertight and len(mesh.faces) > 100
    lo, hi = mesh.bounds
    assert hi[0] - lo[0] > 1.1  # spans the output


def test_an_output_that_cannot_fit_is_refused(wavy, one_device):
    from geosynth.core.memory import MemoryBudgetError

    with pytest.raises(MemoryBudgetError, match="size"):
        synthesize_point_texture(wavy, size=(3e4, 3e4), device=one_device, quality=False)


def test_relaxed_plane_stays_a_plane(one_device):
    rng = np.random.default_rng(4)
    p = np.c_[rng.uniform(-0.25, 1.25, (4000, 2)), np.zeros(4000)]
    tex = texture_from_points(p, np.tile([0, 0, 1.0], (len(p), 1)), box=[[0, 0, 0], [1, 1, 0]])
    pts, report, _ = synthesize_point_texture(tex, device=one_device, relax=True, **SMALL)
    assert np.abs(pts.positions[:, 2]).max() < 1e-4
    assert len(pts) > 0.9 * 4000 * 1.44 / 2.25


def _iterate_every_step(p, nrm, q, h, steps, tol):
    """host_mls's projection loop as first written: each query's points within reach asked
    of the k-d tree at every step, sums per query by bincount in ascending point order (the
    oracle of the cached gathering, which must give the same bits)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(p)
    reach = MLS_REACH * h
    m = len(q)
    y, proj, grad, f0 = q.copy(), q.copy(), np.zeros((m, 3)), np.full(m, np.nan)
    active = np.arange(m)
    pn = np.concatenate([p, nrm], axis=1)
    for _ in range(steps):
        if active.size == 0:
            break
        lists = tree.query_ball_point(y[active], reach * (1 + 1e-9), return_sorted=True)
        counts = np.array([len(v) for v in lists], np.int64)
        flat = np.concatenate([np.asarray(v, np.int64) for v in lists] + [np.zeros(0, np.int64)])
        row = np.repeat(np.arange(len(lists)), counts)
        nb = pn[flat]
        diff = nb[:, :3] - y[active][row]
        d2 = np.einsum("ij,ij->i", diff, diff)
        w = np.where(d2 < reach * reach, np.exp(-d2 / (h * h)), 0.0)
        ws = np.bincount(row, w, len(lists))
        sums = np.stack([np.bincount(row, w * nb[:, c], len(lists)) for c in range(6)], axis=1)
        mlen = np.linalg.norm(sums[:, 3:], axis=1)
        ok = (ws > 0) & (mlen > 0)
        a_idx = active[ok]
        n = sums[ok, 3:] / mlen[ok, None]
        f = np.einsum("mc,mc->m", n, y[a_idx] - sums[ok, :3] / ws[ok, None])
        first = np.isnan(f0[a_idx])
        f0[a_idx[first]] = f[first]
        grad[a_idx] = n
        proj[a_idx] = y[a_idx] - f[:, None] * n
        y[a_idx] = proj[a_idx]
        active = a_idx[np.abs(f) > tol]
    return f0, grad, proj


@pytest.mark.parametrize("fixed", [True, False])
def test_host_projection_gathers_once_with_the_same_bits(wavy, rng, fixed):
    """host_mls's loop gathers each query's points within reach + slack once (again only when
    the iterate moved farther) and stops at an exact fixed point: the same bits as asking
    the tree at every step, also for queries a reach away from the surface (first steps
    move them far: regathered) and on two sheets closer than the MLS width (where the
    projections do not converge)."""
    from scipy.spatial import cKDTree

    from geosynth.geometry.pointsets import MLS_MAX_ITER, MLS_TOL
    from geosynth.pointtexture.patch_search import FIXED_STEPS, FIXED_TOL, _iterate

    h = 2 * wavy.spacing
    sheet = wavy.points[::2] * [1, 1, 0]
    away = np.concatenate([np.tile([0.0, 0.0, -1.0], (len(sheet), 1)), np.tile([0.0, 0.0, 1.0], (len(sheet), 1))])
    cases = [(wavy.points, wavy.normals / np.linalg.norm(wavy.normals, axis=1, keepdims=True),
              rng.uniform([0.1, 0.1, -MLS_REACH * h], [0.9, 0.9, MLS_REACH * h], (300, 3)))]
    for gap in (0.8, 1.2):  # two sheets facing away, gap h apart: at 1.2 h no projection converges
        cases.append((np.concatenate([sheet, sheet + [0, 0, gap * h]]), away,
                      rng.uniform([0.1, 0.1, -h], [0.9, 0.9, 2 * h], (200, 3))))
    steps, tol = (FIXED_STEPS, FIXED_TOL * h) if fixed else (MLS_MAX_ITER, MLS_TOL * h)
    for p, n, q in cases:
        got = _iterate(p, n, cKDTree(p), q, h, fixed)
        want = _iterate_every_step(p, n, q, h, steps, tol)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["heightfield", "flowers"])
def test_two_rows_at_once_give_one_threads_bits(one_device, monkeypatch, name):
    """The growth's two threads (even and odd rows, the lower row a few patches behind)
    give the points one thread gives, bit for bit; the two-row path is really taken."""
    import geosynth.pointtexture.synthesis as gt

    tex = point_texture_example(name, count=6000)
    opts = dict(scale=2.0, resolution=24, quality=False)
    calls = []
    real = gt._grow_two_rows
    monkeypatch.setattr(gt, "_grow_two_rows", lambda *a, **k: (calls.append(1), real(*a, **k))[1])
    monkeypatch.setenv("GEOSYNTH_HOST_THREADS", "2")
    two, _, t2 = synthesize_point_texture(tex, device=one_device, seed=3, **opts)
    assert calls == [1]
    monkeypatch.setenv("GEOSYNTH_HOST_THREADS", "1")
    one, _, _ = synthesize_point_texture(tex, device=one_device, seed=3, **opts)
    assert calls == [1]  # one thread: the scan order on the caller's thread
    np.testing.assert_array_equal(two.positions, one.positions)
    np.testing.assert_array_equal(two.normals, one.normals)


def test_row_lag_keeps_the_rows_reads_and_writes_apart():
    """The lag: L patch steps cover a box (patch + extra) and the reads beyond it."""
    from types import SimpleNamespace

    from geosynth.pointtexture.synthesis import _row_lag

    lay = SimpleNamespace(cell=1.0, patch=19, extra=4, step=14)
    assert _row_lag(lay, reach=3.0, margin=2.0, cut=False) == 3  # (23 + 8) / 14 -> 3
    assert _row_lag(lay, reach=0.5, margin=0.0, cut=False) == 2  # (23 + 1) / 14 -> 2
    assert _row_lag(lay, reach=0.5, margin=0.0, cut=True) == 3  # half a patch read: (23 + 9.5) / 14
    lag = _row_lag(lay, reach=3.0, margin=2.0, cut=False)
    assert lag * lay.step >= lay.patch + lay.extra + 2 * 3.0 + 2.0 > (lag - 1) * lay.step


def test_a_bad_host_thread_count_is_refused_before_any_work(monkeypatch, small_weave):
    import geosynth.pointtexture.patch_search as ps

    monkeypatch.setattr(ps, "PatchSearch", lambda *a, **k: pytest.fail("work started"))
    monkeypatch.setenv("GEOSYNTH_HOST_THREADS", "0")
    with pytest.raises(ValueError, match="GEOSYNTH_HOST_THREADS must be a whole number >= 1"):
        synthesize_point_texture(small_weave, seed=0, **SMALL)


def test_point_texture_options_are_checked_once_and_equal_the_keywords(wavy, one_device):
    """PointTextureOptions (issue 33 item 2): every setting checked when made, before any work;
    the options object and the keyword form give the same points; not both at once."""
    import dataclasses

    from geosynth.pointtexture.synthesis import PointTextureOptions

    for bad, error, words in [(dict(size=(1.0,)), ValueError, "size must be two numbers > 0"),
                              (dict(scale=0), ValueError, r"scale must be in \(0, 10000\]"),
                              (dict(patch=1.5), ValueError, r"patch must be in \(0, 1\]"),
                              (dict(extra="wide"), TypeError, "extra must be a number"),
                              (dict(overlap=0.7), ValueError, r"overlap must be in \(0, 0.5\]"),
                              (dict(resolution=7), ValueError, "resolution must be an integer >= 8"),
                              (dict(weights=(1, 2)), TypeError, "weights must be a geosynth.pointtexture"),
                              (dict(eps=-1), ValueError, "eps must be a finite number >= 0"),
                              (dict(tileable="yes"), TypeError, "tileable must be True or False"),
                              (dict(relax=1), TypeError, "relax must be True or False"),
                              (dict(quality_samples=0), ValueError, "quality_samples must be an integer >= 1")]:
        with pytest.raises(error, match=words):
            PointTextureOptions(**bad)
    opts = PointTextureOptions(**SMALL)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.patch = 0.4  # type: ignore[misc]
    a, _, _ = synthesize_point_texture(wavy, device=one_device, seed=3, options=opts)
    b, _, _ = synthesize_point_texture(wavy, device=one_device, seed=3, **SMALL)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.normals, b.normals)
    with pytest.raises(ValueError, match=r"either as options= or as keywords, not both \(scale given"):
        synthesize_point_texture(wavy, scale=1.5, device=one_device, options=opts)
