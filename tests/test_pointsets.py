"""Oriented point sets: the MLS distance field on every present device against the
NumPy oracle and analytic shapes; normal estimation; PLY input/output; bad input."""

from __future__ import annotations

import numpy as np
import pytest

from geosynth.geometry import reference
from geosynth.geometry.distance import pointset_distance as distance_pointset_distance
from geosynth.geometry.field import Field, cubic_grid
from geosynth.geometry.pointsets import (
    MLS_REACH,
    PointSet,
    default_radius,
    estimate_normals,
    pointset_distance,
    project_points,
    read_point_set,
    write_point_set,
)

# float32 kernels against the float64 oracle, in units of h: the sums carry ~1e-6
# relative rounding and the projection stops at |f| <= 1e-4 h.
ATOL_H = 5e-4
GRAD_ATOL = 1e-3


def sphere_points(n: int, radius: float = 1.0) -> np.ndarray:
    """Fibonacci sphere: n nearly uniform points, (n, 3) float32."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5**0.5) * i
    return (radius * np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)).astype(np.float32)


def plane_points(side: int, spacing: float = 0.1) -> np.ndarray:
    g = (np.arange(side) - (side - 1) / 2) * spacing
    xx, yy = np.meshgrid(g, g)
    return np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], 1).astype(np.float32)


def bumpy_set(rng, n: int = 400):
    """A small wavy sheet with slightly perturbed normals."""
    xy = rng.uniform(-1, 1, (n, 2))
    z = 0.15 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])
    p = np.c_[xy, z].astype(np.float32)
    nrm = np.c_[-0.45 * np.cos(3 * xy[:, 0]) * np.cos(2 * xy[:, 1]), 0.3 * np.sin(3 * xy[:, 0]) * np.sin(2 * xy[:, 1]), np.ones(n)]
    nrm = nrm + 0.05 * rng.standard_normal(nrm.shape)
    return p, (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)


# ------------------------------------------------------------------------ oracle


def test_matches_oracle(device, rng):
    p, n = bumpy_set(rng)
    h = default_radius(p)
    q = np.c_[rng.uniform(-0.9, 0.9, (300, 2)), rng.uniform(-0.3, 0.3, 300)].astype(np.float32)
    d, g = pointset_distance(p, n, q, radius=h, far="reach", device=device)  # the oracle's far value
    want_d, want_g, want_p = reference.mls_project_naive(p, n, q, h)
    assert d.dtype == np.float32 and d.shape == (300,) and g.shape == (300, 3)
    assert np.isfinite(d).all() and np.isfinite(g).all()
    np.testing.assert_allclose(d, want_d, atol=ATOL_H * h)
    np.testing.assert_allclose(g, want_g, atol=GRAD_ATOL)
    proj = project_points(p, n, q, radius=h, device=device)
    np.testing.assert_allclose(proj, want_p, atol=ATOL_H * h)


def test_backends_agree(device_pair, rng):
    p, n = bumpy_set(rng)
    q = np.c_[rng.uniform(-1.2, 1.2, (500, 2)), rng.uniform(-0.4, 0.4, 500)].astype(np.float32)
    h = default_radius(p)
    (d0, g0), (d1, g1) = (pointset_distance(p, n, q, device=dev) for dev in device_pair)
    np.testing.assert_allclose(d1, d0, atol=1e-5 * h, err_msg=" vs ".join(device_pair))
    np.testing.assert_allclose(g1, g0, atol=1e-5, err_msg=" vs ".join(device_pair))


# ------------------------------------------------------------------------ analytic shapes


def test_sphere(device, rng):
    p = sphere_points(4000)
    h = default_radius(p)
    dirs = rng.standard_normal((400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    r = rng.uniform(1 - 2 * h, 1 + 2 * h, 400)
    q = (dirs * r[:, None]).astype(np.float32)
    d, g = pointset_distance(p, p, q, device=device)  # on the unit sphere, normal = position
    # The MLS surface of a sphere is a sphere, shrunk by about h^2 / (2 r) (a(x) is a
    # mean of points on a curved cap); by symmetry the distance is then |x| - r'.
    r_mls = np.median(r - d)
    assert 0 < 1 - r_mls < h * h
    np.testing.assert_allclose(d, r - r_mls, atol=0.01 * h)
    np.testing.assert_allclose(g, dirs, atol=0.01)


def test_plane(device, rng):
    p = plane_points(41, 0.05)  # 2 x 2 square at z = 0
    n = np.tile(np.float32([0, 0, 1]), (len(p), 1))
    h = default_radius(p)
    q = np.c_[rng.uniform(-0.5, 0.5, (300, 2)), rng.uniform(-2.5 * h, 2.5 * h, 300)].astype(np.float32)
    d, g = pointset_distance(p, n, q, device=device)
    np.testing.assert_allclose(d, q[:, 2], atol=1e-5)
    np.testing.assert_allclose(g, np.tile([0, 0, 1], (300, 1)), atol=1e-5)
    proj = project_points(p, n, q, device=device)
    np.testing.assert_allclose(proj, q * [1, 1, 0], atol=1e-5)


def test_far_value(device):
    p = sphere_points(500)
    h = 0.1
    q = np.float32([[5, 0, 0], [0, 0, -3], [0, 0, 0], [1e4, -1e4, 1e4]])  # the centre is 10h inside
    d, g = pointset_distance(p, p, q, radius=h, far="reach", device=device)
    np.testing.assert_array_equal(d, np.float32(MLS_REACH * h))
    np.testing.assert_array_equal(g, 0)
    np.testing.assert_array_equal(project_points(p, p, q, radius=h, device=device), q)


def test_far_nearest_gives_signed_distance_everywhere(device):
    """Beyond reach the default takes the nearest sample's projection: the sign is
    right deep inside and far outside, the size within about a sample spacing."""
    p = sphere_points(2000)
    h = 0.08
    q = np.float32([[5, 0, 0], [0, 0, -3], [0, 0, 0], [0.3, -0.2, 0.1], [0, 2, 0]])
    want = np.linalg.norm(q, axis=1) - 1
    d, g = pointset_distance(p, p, q, radius=h, device=device)
    assert np.all(np.abs(d) > MLS_REACH * h) and np.all(np.sign(d) == np.sign(want))
    spacing = np.sqrt(4 * np.pi / len(p))
    np.testing.assert_allclose(d, want, atol=spacing)
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1, atol=1e-5)
    # a grid through the sphere: inside negative, outside positive, everywhere
    dist, _ = pointset_distance(p, p, bounds=[[-1, -1, -1], [1, 1, 1]], resolution=9, radius=h, device=device)
    r = np.linalg.norm(dist.points(), axis=1).reshape(dist.shape) - 1
    far_from_surface = np.abs(r) > spacing
    assert np.all(np.sign(dist.values[far_from_surface]) == np.sign(r[far_from_surface]))


def test_grid_output(device):
    p = sphere_points(2000)
    bounds = np.array([[-1, -1, -1], [1, 1, 0.5]])
    dist, grad = pointset_distance(p, p, bounds=bounds, resolution=12, padding=0.1, device=device)
    want = cubic_grid(bounds, 12, 0.1)
    assert isinstance(dist, Field) and isinstance(grad, Field)
    assert dist.values.shape == want.shape and dist.values.dtype == np.float32
    assert grad.values.shape == want.shape + (3,)
    for f in (dist, grad):
        np.testing.assert_allclose(f.origin, want.origin)
        np.testing.assert_allclose(f.spacing, want.spacing)
    # Same values as querying the grid's points (raster order z, y, x; gradient x, y, z).
    d, g = pointset_distance(p, p, want.points(), device=device)
    np.testing.assert_allclose(dist.values.reshape(-1), d, atol=1e-5)
    np.testing.assert_allclose(grad.values.reshape(-1, 3), g, atol=1e-5)
    # field= takes the grid of an existing Field; resolution alone boxes the points.
    again, _ = distance_pointset_distance(PointSet(p, p), field=want, device=device)
    np.testing.assert_array_equal(again.values, dist.values)
    boxed, _ = pointset_distance(p, p, resolution=8, device=device)
    assert boxed.shape == cubic_grid(np.stack([p.min(0), p.max(0)]), 8, 0.1).shape


# ------------------------------------------------------------------------ normals


def angle_deg(a, b):
    cos = np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_estimate_normals_sphere():
    p = sphere_points(3000)
    n = estimate_normals(p)
    assert n.dtype == np.float32 and n.shape == p.shape
    assert angle_deg(n, p).max() < 5  # outward, not just parallel
    # Two separate closed shapes: each component oriented outward on its own.
    q = sphere_points(1000, 0.5) + np.float32([4, 0, 0])
    n2 = estimate_normals(np.r_[p, q])
    assert angle_deg(n2, np.r_[p, (q - [4, 0, 0]) / 0.5]).max() < 5


def test_estimate_normals_plane(rng):
    p = np.c_[rng.uniform(-1, 1, (2000, 2)), np.zeros(2000)].astype(np.float32)
    n = estimate_normals(PointSet(p), k=12)
    np.testing.assert_allclose(n, np.tile([0, 0, 1], (2000, 1)), atol=1e-5)  # an open sheet faces +z


# ------------------------------------------------------------------------ PLY


def test_ply_round_trip(tmp_path, rng):
    p = rng.standard_normal((50, 3)).astype(np.float32)
    n = estimate_normals(p)
    c = rng.integers(0, 256, (50, 3), dtype=np.uint8)
    path = write_point_set(tmp_path / "a.ply", PointSet(p, n, c))
    back = read_point_set(path)
    np.testing.assert_array_equal(back.positions, p)
    np.testing.assert_allclose(back.normals, n, atol=1e-6)
    np.testing.assert_array_equal(back.colors, c)
    before = path.read_bytes()
    with pytest.raises(ValueError, match="overwrite the input"):
        write_point_set(path, back)
    assert path.read_bytes() == before
    bare = read_point_set(write_point_set(tmp_path / "b.ply", PointSet(p)))
    assert bare.normals is None and bare.colors is None
    assert sorted(f.name for f in tmp_path.iterdir()) == ["a.ply", "b.ply"]  # no temporary left


# ------------------------------------------------------------------------ bad input


def test_invalid_input(one_device):
    p = sphere_points(100)
    q = np.zeros((2, 3), np.float32)
    with pytest.raises(ValueError, match="normals are required.*estimate_normals"):
        pointset_distance(p, None, q, device=one_device)
    with pytest.raises(ValueError, match="normals are required"):
        pointset_distance(PointSet(p), query=q, device=one_device)
    zero = p.copy()
    zero[7] = 0
    with pytest.raises(ValueError, match="zero-length normal.*index 7"):
        pointset_distance(p, zero, q, device=one_device)
    nan = p.copy()
    nan[3, 1] = np.nan
    with pytest.raises(ValueError, match="points contains 1 NaN"):
        pointset_distance(nan, p, q, device=one_device)
    with pytest.raises(ValueError, match="normals must have shape"):
        pointset_distance(p, p[:50], q, device=one_device)
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        pointset_distance(p[:, :2], p[:, :2], q, device=one_device)
    with pytest.raises(ValueError, match=r"query must have shape \(N, 3\)"):
        pointset_distance(p, p, q[:, :2], device=one_device)
    with pytest.raises(ValueError, match="resolution must be"):
        pointset_distance(p, p, resolution=1, device=one_device)
    with pytest.raises(ValueError, match="zero extent"):
        pointset_distance(p, p, bounds=[[0, 0, 0], [0, 0, 0]], resolution=8, device=one_device)
    with pytest.raises(ValueError, match="radius must be"):
        pointset_distance(p, p, q, radius=0.0, device=one_device)
    with pytest.raises(ValueError, match="radius must be"):
        pointset_distance(p, p, q, radius=-1, device=one_device)
    with pytest.raises(ValueError, match="points is empty"):
        pointset_distance(np.zeros((0, 3)), np.zeros((0, 3)), q, device=one_device)
    with pytest.raises(ValueError, match="query is empty"):
        pointset_distance(p, p, np.zeros((0, 3)), device=one_device)
    with pytest.raises(ValueError, match="exactly one of"):
        pointset_distance(p, p, device=one_device)
    with pytest.raises(ValueError, match="exactly one of"):
        pointset_distance(p, p, q, resolution=8, device=one_device)
    with pytest.raises(ValueError, match="at least 3 points"):
        estimate_normals(p[:2])
    with pytest.raises(ValueError, match="k must be"):
        estimate_normals(p, k=2)
    with pytest.raises(ValueError, match="pass radius="):
        pointset_distance(p[:1], p[:1], q, device=one_device)
