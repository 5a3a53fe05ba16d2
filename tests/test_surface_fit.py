"""The least-squares fits of the underlying surface, the paper's frames, and the relief
preparation (Breckon and Fisher, "Plausible 3D colour surface completion using
non-parametric techniques", Sec. 3 and 4). Host-only: no device is involved."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geosynth.completion.fit import fit_surface, tangent_frames
from geosynth.completion.prep import Capture, prepare_relief, ring_neighbourhoods


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _perp(axis):
    u, v = tangent_frames(np.asarray(axis, float)[None])
    return u[0], v[0]


def test_plane_recovered_from_noisy_samples(rng):
    n = _unit([0.3, -0.2, 1.0])
    e0, e1 = _perp(n)
    q = rng.uniform(-1, 1, (600, 2))
    p = 0.4 * n + q[:, :1] * e0 + q[:, 1:] * e1 + rng.normal(0, 0.01, (600, 1)) * n
    f = fit_surface(p, "plane")
    assert f.kind == "plane"
    assert abs(abs(f.axis @ n) - 1) < 1e-3
    assert abs(f.center @ f.axis - 0.4 * (n @ f.axis)) < 5e-3
    assert 0.008 < f.rms < 0.012
    assert fit_surface(p).kind == "plane"  # chosen by residual


def test_sphere_recovered_from_a_noisy_half(rng):
    d = rng.normal(size=(1500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d[:, 0] > 0]
    c = np.array([1.0, -2.0, 0.5])
    p = c + 2.5 * d * (1 + rng.normal(0, 0.002, (len(d), 1)))
    f = fit_surface(p)
    assert f.kind == "sphere"
    assert np.allclose(f.center, c, atol=0.02)
    assert abs(f.radius - 2.5) < 0.01


def test_cylinder_recovered_from_a_noisy_half(rng):
    axis = _unit([0.2, 0.1, 1.0])
    e0, e1 = _perp(axis)
    a = rng.uniform(0, math.pi, 1200)
    h = rng.uniform(0, 3, 1200)
    c = np.array([0.5, -1.0, 0.0])
    p = c + 1.3 * (np.cos(a)[:, None] * e0 + np.sin(a)[:, None] * e1) * (1 + rng.normal(0, 0.003, (1200, 1))) \
        + h[:, None] * axis
    f = fit_surface(p)
    assert f.kind == "cylinder"
    assert abs(abs(f.axis @ axis) - 1) < 1e-3
    assert abs(f.radius - 1.3) < 0.01
    # the fit's axis passes through c: c's distance to the axis line is ~0
    w = c - f.center
    assert np.linalg.norm(w - (w @ f.axis) * f.axis) < 0.02


def test_projection_parameters_and_normals_round_trip(rng):
    for kind, pts in [("sphere", None), ("cylinder", None)]:
        if kind == "sphere":
            d = rng.normal(size=(400, 3))
            pts = 3 * d / np.linalg.norm(d, axis=1, keepdims=True)
        else:
            a = rng.uniform(0, 2 * math.pi, 400)
            pts = np.stack([np.cos(a), np.sin(a), rng.uniform(0, 2, 400)], 1)
        f = fit_surface(pts, kind)
        q = f.to_param(pts)
        assert np.allclose(f.from_param(q), f.project(pts), atol=1e-9)
        assert np.allclose(np.linalg.norm(f.normal(pts), axis=1), 1)
        assert np.abs(f.distance(pts)).max() < 1e-6


def test_displacements_are_zero_on_a_perfect_fit():
    j, i = np.mgrid[0:20, 0:20]
    p = np.stack([i.ravel() * 0.05, j.ravel() * 0.05, np.full(400, 0.25)], 1)
    cap = Capture(p)
    f = fit_surface(p, "plane")
    rs = prepare_relief(cap, f, region=((0.0, 1.5), (0.0, 0.95)))
    assert np.abs(rs.displacement[: rs.n_samples]).max() < 1e-12
    assert rs.n_targets > 0 and rs.n_samples > 2 * len(p)  # oversampled once
    assert abs(rs.spacing - 0.05) < 1e-9  # the minimum edge length


def test_frames_follow_the_paper():
    n = np.array([[0.1, 0.6, 0.8], [0.6, 0.1, 0.8], [0.6, 0.8, 0.0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    u, v = tangent_frames(n)
    x, y, z = n.T
    assert np.allclose(u[0], _unit([0, -z[0], y[0]]))  # |x| smallest
    assert np.allclose(u[1], _unit([z[1], 0, -x[1]]))  # |y| smallest (the same construct, cyclically)
    assert np.allclose(u[2], _unit([-y[2], x[2], 0]))  # |z| smallest
    assert np.allclose(v, np.cross(n, u))
    assert np.allclose((u * n).sum(1), 0)


def test_cylinder_triangulation_closes_over_the_seam():
    a = np.arange(0, 2 * math.pi, 2 * math.pi / 60)
    z = np.arange(0, 1.0, 0.1)
    aa, zz = np.meshgrid(a[a < math.pi], z)
    p = np.stack([np.cos(aa.ravel()), np.sin(aa.ravel()), zz.ravel()], 1)
    f = fit_surface(p, "cylinder")
    rs = prepare_relief(Capture(p), f)
    deg = np.diff(rs.adjacency[0])
    assert deg.min() >= 3
    # every vertex of a closed cylinder band keeps neighbours on both sides of angle 0
    ang = rs.param[:, 0]
    near_seam = np.flatnonzero((ang < 0.06) & (rs.param[:, 1] > 0.2) & (rs.param[:, 1] < 0.7))
    assert len(near_seam) >= 3
    ptr, idx = rs.adjacency
    for v in near_seam[:5]:
        nb = idx[ptr[v]:ptr[v + 1]]
        assert (ang[nb] > 2 * math.pi - 0.3).any()
    rp, ri, rd = ring_neighbourhoods(rs.adjacency, near_seam[:3], 2)
    assert set(rd.tolist()) == {1, 2}


def test_bad_fits_are_clear():
    d = np.random.default_rng(0).normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    with pytest.raises(ValueError, match=r"far from the capture: RMS residual [0-9.]+"):
        fit_surface(d[d[:, 2] > -0.5], "plane")
    with pytest.raises(ValueError, match="must be one of"):
        fit_surface(d, "cone")
    with pytest.raises(ValueError, match="NaN"):
        fit_surface(np.vstack([d, [[np.nan, 0, 0]]]))
    t = np.linspace(0, 1, 50)
    thin = np.stack([t, 2 * t, 3 * t], 1) + np.random.default_rng(0).normal(0, 1e-3, (50, 3))
    with pytest.raises(ValueError, match="sphere fit did not converge"):
        fit_surface(thin, "sphere")
    j, i = np.mgrid[0:10, 0:10]
    flat = np.stack([i.ravel(), j.ravel(), np.zeros(100)], 1).astype(float)
    with pytest.raises(ValueError, match="sphere fit (did not converge|is far from the capture: RMS residual)"):
        fit_surface(flat, "sphere")
    with pytest.raises(ValueError, match="lie on a line"):
        fit_surface(np.stack([t, t, t], 1))
    with pytest.raises(ValueError, match="empty"):
        j, i = np.mgrid[0:10, 0:10]
        p = np.stack([i.ravel() * 0.1, j.ravel() * 0.1, np.zeros(100)], 1)
        prepare_relief(Capture(p), fit_surface(p, "plane"))  # the default region is the capture's own box
