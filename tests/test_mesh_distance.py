"""Mesh distance fields on every present device, against the brute-force oracles of
geosynth.geometry.reference and analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import geosynth
from conftest import TEST_DEVICES
from geosynth.geometry import reference
from geosynth.geometry.distance import mesh_distance
from geosynth.geometry.field import Field, cubic_grid
from geosynth.geometry.meshes import check_mesh, load_mesh, orient_faces
from geosynth.volume.examples import chainmail_mesh

# float32 kernels against a float64 oracle: relative to the mesh size
ATOL = 2e-6


def _points(mesh, rng, n_box=300, n_near=200, n_far=50):
    """Uniform points around the mesh, points within 1e-3 of its surface, far points."""
    lo, hi = mesh.bounds
    ext = (hi - lo).max()
    box = rng.uniform(lo - 0.3 * ext, hi + 0.3 * ext, (n_box, 3))
    near = mesh.sample(n_near, seed=int(rng.integers(1 << 30))) + rng.normal(0, 1e-3 * ext, (n_near, 3))
    far = rng.normal(0, 1, (n_far, 3))
    far = far / np.linalg.norm(far, axis=1, keepdims=True) * rng.uniform(3, 20, (n_far, 1)) * ext
    return np.concatenate([box, near, far]).astype(np.float32)


def _torus():
    return trimesh.creation.torus(1.0, 0.3, major_sections=24, minor_sections=12)


SMALL_MESHES = {
    "icosphere": lambda: trimesh.creation.icosphere(2),
    "box": lambda: trimesh.creation.box((1.0, 2.0, 0.5)),
    "torus": _torus,
}


@pytest.mark.parametrize("name", sorted(SMALL_MESHES))
def test_against_bruteforce_oracle(device, rng, name):
    mesh = SMALL_MESHES[name]()
    p = _points(mesh, rng)
    want = reference.mesh_distance_naive(mesh, p)
    got = mesh_distance(mesh, p, device=device)
    assert got.dtype == np.float32 and got.shape == (len(p),)
    scale = np.abs(mesh.bounds).max()
    np.testing.assert_allclose(np.abs(got), np.abs(want), atol=ATOL * scale * 10, rtol=2e-6)
    far_enough = np.abs(want) > 1e-5 * scale
    np.testing.assert_array_equal(np.sign(got)[far_enough], np.sign(want)[far_enough])
    unsigned = mesh_distance(mesh, p, signed=False, device=device)
    np.testing.assert_allclose(unsigned, np.abs(want), atol=ATOL * scale * 10, rtol=2e-6)
    band = 0.1 * scale
    banded = mesh_distance(mesh, p, band=band, device=device)
    np.testing.assert_allclose(banded, np.clip(got, -band, band), atol=ATOL * scale * 10, rtol=2e-6)
    assert np.abs(banded).max() <= np.float32(band)


def test_sign_against_trimesh_contains(device, rng):
    pytest.importorskip("rtree")  # trimesh's containment test needs it
    for mesh in (trimesh.creation.icosphere(2), _torus(), trimesh.creation.box((1.0, 2.0, 0.5))):
        p = _points(mesh, rng, n_near=0)
        inside = mesh.contains(p.astype(np.float64))
        got = mesh_distance(mesh, p, device=device)
        np.testing.assert_array_equal(got < 0, inside)


def test_sphere_analytic(device, rng):
    mesh = trimesh.creation.icosphere(4, radius=1.0)
    # the icosphere's faces lie inside the unit sphere by at most this sagitta
    sag = 1.0 - np.abs(np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center)).min()
    p = rng.normal(0, 1, (2000, 3))
    p = (p / np.linalg.norm(p, axis=1, keepdims=True) * rng.uniform(0.05, 3.0, (2000, 1))).astype(np.float32)
    r = np.linalg.norm(p.astype(np.float64), axis=1)
    got = mesh_distance(mesh, p, device=device)
    np.testing.assert_allclose(got, r - 1.0, atol=sag * 1.01 + 1e-6)
    clear = np.abs(r - 1.0) > sag
    np.testing.assert_array_equal(got[clear] < 0, r[clear] < 1.0)


def test_plane_analytic(device, rng):
    # a big flat square at z = 0, normal +z. Its distance above the interior is |z|. An
    # open sheet encloses nothing: its winding number is -1/2 < w < 1/2 on both sides
    # (w -> +-1/2 only as the sheet grows infinite), so it is outside (+) for either
    # orientation; the winding number itself follows the orientation.
    vertices = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    xy = rng.uniform(-2, 2, (500, 2))
    z = rng.uniform(-1, 1, 500)
    z[np.abs(z) < 1e-3] = 0.5
    p = np.column_stack([xy, z]).astype(np.float32)
    got = mesh_distance(mesh, p, device=device)
    np.testing.assert_allclose(got, np.abs(p[:, 2]), atol=1e-6)
    flipped = trimesh.Trimesh(vertices=vertices, faces=faces[:, ::-1], process=False)
    np.testing.assert_allclose(mesh_distance(flipped, p, device=device), np.abs(p[:, 2]), atol=1e-6)
    w = reference.winding_number_naive(vertices, faces, p)
    assert (np.sign(w) == np.sign(p[:, 2]) * -1).all() and (np.abs(w) < 0.5).all()
    # closed by a second, reversed sheet just below, the slab between them is inside
    slab = trimesh.Trimesh(
        vertices=np.vstack([vertices, vertices - [0, 0, 0.5]]), faces=np.vstack([faces, faces[:, ::-1] + 4]), process=False
    )
    q = np.column_stack([xy, rng.uniform(-0.45, -0.05, 500)]).astype(np.float32)
    np.testing.assert_allclose(mesh_distance(slab, q, device=device), -np.minimum(-q[:, 2], q[:, 2] + 0.5), atol=1e-6)


def test_box_corners_analytic(device, rng):
    half = np.array([0.5, 1.0, 0.25])
    mesh = trimesh.creation.box(2 * half)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    offs = rng.uniform(0.01, 1.0, (8, 40, 3))  # strictly beyond the corner on every axis
    p = (signs[:, None, :] * (half + offs)).reshape(-1, 3)
    corner = np.repeat(signs * half, 40, axis=0)
    got = mesh_distance(mesh, p.astype(np.float32), device=device)
    np.testing.assert_allclose(got, np.linalg.norm(p.astype(np.float32) - corner, axis=1), rtol=1e-5, atol=1e-6)


def test_torus_analytic(device, rng):
    big, small = 1.0, 0.3
    mesh = trimesh.creation.torus(big, small, major_sections=128, minor_sections=64)
    p = rng.uniform([-1.6, -1.6, -0.6], [1.6, 1.6, 0.6], (2000, 3)).astype(np.float32)
    q = p.astype(np.float64)
    exact = np.hypot(np.hypot(q[:, 0], q[:, 1]) - big, q[:, 2]) - small
    # polygonal tessellation error: sagitta of both the major and the minor polygon
    tol = (big + small) * (1 - np.cos(np.pi / 128)) + small * (1 - np.cos(np.pi / 64)) + 1e-5
    got = mesh_distance(mesh, p, device=device)
    np.testing.assert_allclose(got, exact, atol=tol)


def _hole_mesh():
    mesh = trimesh.creation.icosphere(3)
    keep = mesh.triangles_center[:, 2] < 0.9  # a hole around the north pole
    return trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)


def _flipped_mesh(rng):
    mesh = trimesh.creation.icosphere(3)
    faces = mesh.faces.copy()
    flip = rng.choice(len(faces), len(faces) // 10, replace=False)
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(mesh.vertices, faces, process=False)


def test_hole_and_flipped_faces_sign(device, rng):
    p = rng.uniform(-1.5, 1.5, (3000, 3)).astype(np.float32)
    r = np.linalg.norm(p.astype(np.float64), axis=1)
    sphere_sag = 0.01  # icosphere(3) vs the unit sphere
    hole = _hole_mesh()
    got = mesh_distance(hole, p, device=device)
    away = (np.abs(r - 1) > sphere_sag) & (np.linalg.norm(p - [0, 0, 1], axis=1) > 0.8)
    np.testing.assert_array_equal(got[away] < 0, r[away] < 1)
    np.testing.assert_allclose(np.abs(got), reference.mesh_unsigned_distance_naive(hole.vertices, hole.faces, p), atol=1e-5)
    flipped = _flipped_mesh(rng)
    got = mesh_distance(flipped, p, device=device)
    clear = np.abs(r - 1) > sphere_sag
    np.testing.assert_array_equal(got[clear] < 0, r[clear] < 1)


def test_orient_faces_repairs_flips_and_inside_out(rng):
    sphere = trimesh.creation.icosphere(3)
    flipped = _flipped_mesh(rng)
    np.testing.assert_array_equal(np.sort(orient_faces(flipped.vertices, flipped.faces), 1), np.sort(sphere.faces, 1))
    fixed = orient_faces(flipped.vertices, flipped.faces)
    assert trimesh.Trimesh(flipped.vertices, fixed, process=False).volume > 0
    inside_out = orient_faces(sphere.vertices, sphere.faces[:, ::-1])
    assert trimesh.Trimesh(sphere.vertices, inside_out, process=False).volume > 0


def test_backends_agree_on_sign(device_pair):
    rng = np.random.default_rng(7)
    for mesh in (_hole_mesh(), _flipped_mesh(rng)):
        a, b = (mesh_distance(mesh, resolution=32, device=d).values for d in device_pair)
        np.testing.assert_array_equal(np.sign(b), np.sign(a))
        np.testing.assert_allclose(b, a, atol=1e-5)


def test_grid_output(device, rng):
    mesh = _torus()
    f = mesh_distance(mesh, resolution=20, device=device)
    want = cubic_grid(mesh.bounds, 20, 0.1)
    assert isinstance(f, Field) and f.values.dtype == np.float32
    assert f.shape == want.shape
    np.testing.assert_allclose(f.origin, want.origin)
    np.testing.assert_allclose(f.spacing, want.spacing)
    np.testing.assert_allclose(f.values.reshape(-1), mesh_distance(mesh, f.points(), device=device), atol=1e-5)
    bounds = np.array([[-2.0, -1.0, -0.5], [2.0, 1.0, 0.5]])
    g = mesh_distance(mesh, bounds=bounds, resolution=9, padding=0.0, device=device)
    np.testing.assert_allclose(g.bounds[:, 0], bounds[:, 0])
    template = Field(np.ones((5, 6, 7), np.float32), origin=[-1.0, -1.0, -0.5], spacing=0.25)
    h = mesh_distance(mesh, field=template, device=device)
    assert h.shape == (5, 6, 7) and h is not template and (template.values == 1).all()
    np.testing.assert_allclose(h.origin, template.origin)
    np.testing.assert_allclose(h.values.reshape(-1), mesh_distance(mesh, template.points(), device=device), atol=1e-5)


def test_load_mesh_and_path_input(tmp_path, device):
    mesh = _torus()
    path = tmp_path / "torus.ply"
    mesh.export(path)
    assert len(load_mesh(path).faces) == len(mesh.faces)
    p = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], np.float32)
    np.testing.assert_allclose(mesh_distance(str(path), p, device=device), mesh_distance(mesh, p, device=device))


def test_drop_degenerate(device):
    mesh = trimesh.creation.icosphere(2)
    faces = np.vstack([mesh.faces, [[0, 0, 1], [3, 4, 3]]])
    bad = trimesh.Trimesh(mesh.vertices, faces, process=False)
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]], np.float32)
    np.testing.assert_allclose(
        mesh_distance(bad, p, drop_degenerate=True, device=device), mesh_distance(mesh, p, device=device), atol=1e-6
    )
    v, f = check_mesh(bad, drop_degenerate=True)
    assert f.shape == mesh.faces.shape and v.dtype == np.float32 and f.dtype == np.int32


def test_invalid_input():
    mesh = trimesh.creation.icosphere(1)
    p = np.zeros((4, 3), np.float32)
    empty = trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=np.zeros((0, 3), np.int64), process=False)
    with pytest.raises(ValueError, match="mesh is empty"):
        mesh_distance(empty, p)
    nan_v = np.array(mesh.vertices)
    nan_v[0, 1] = np.nan
    with pytest.raises(ValueError, match="mesh has 1 vertices with NaN"):
        mesh_distance(trimesh.Trimesh(nan_v, mesh.faces, process=False), p)
    degenerate = trimesh.Trimesh(mesh.vertices, np.vstack([mesh.faces, [[0, 0, 1]]]), process=False)
    with pytest.raises(ValueError, match="1 degenerate .*drop_degenerate=True"):
        mesh_distance(degenerate, p)
    with pytest.raises(ValueError, match="face indices out of range"):
        mesh_distance(trimesh.Trimesh(mesh.vertices, np.vstack([mesh.faces, [[0, 1, 999]]]), process=False), p)
    with pytest.raises(ValueError, match="resolution must be an integer >= 2"):
        mesh_distance(mesh, resolution=1)
    with pytest.raises(ValueError, match="bounds have zero extent"):
        mesh_distance(mesh, bounds=[[0, 0, 0], [0, 0, 0]], resolution=8)
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        mesh_distance(mesh, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="points contains 1 NaN"):
        mesh_distance(mesh, np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match="band must be"):
        mesh_distance(mesh, p, band=0.0)
    with pytest.raises(TypeError, match="mesh must be a trimesh.Trimesh or a path"):
        mesh_distance(np.zeros((3, 3)), p)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        mesh_distance("/nonexistent/mesh.obj", p)
    with pytest.raises(ValueError, match="resolution is required"):
        mesh_distance(mesh)


@pytest.mark.parametrize("name", sorted(SMALL_MESHES))
def test_grid_against_bruteforce_oracle(device, name):
    # the grid kernel (OpenCL: tiles of 4 x 2 x 2 samples as SIMD lanes) against the
    # oracle at every sample; 13 x 13 x 13-ish grids end in partial tiles on every axis
    mesh = SMALL_MESHES[name]()
    scale = np.abs(mesh.bounds).max()
    tol = dict(atol=ATOL * scale * 10, rtol=2e-6)
    f = mesh_distance(mesh, resolution=13, device=device)
    p = f.points().astype(np.float32)
    want = reference.mesh_distance_naive(mesh, p)
    got = f.values.reshape(-1)
    np.testing.assert_allclose(np.abs(got), np.abs(want), **tol)
    far_enough = np.abs(want) > 1e-5 * scale
    np.testing.assert_array_equal(np.sign(got)[far_enough], np.sign(want)[far_enough])
    unsigned = mesh_distance(mesh, resolution=13, signed=False, device=device).values.reshape(-1)
    np.testing.assert_allclose(unsigned, np.abs(want), **tol)
    band = 0.1 * scale
    banded = mesh_distance(mesh, resolution=13, band=band, device=device).values.reshape(-1)
    np.testing.assert_allclose(banded, np.clip(got, -band, band), **tol)
    assert np.abs(banded).max() <= np.float32(band)


def test_grid_thin_triangles(device):
    # slivers and a needle-like triangle (tiny normal): the branch-free lane test must
    # still give the exact distance on a grid, every sample in every region
    v = np.array(
        [[0, 0, 0], [1, 0, 0], [0.5, 1e-4, 0], [0, 0, 1], [2, 0.3, 1], [1, 0.15, 1 + 1e-5], [0, 1, 0], [0, 1, 1], [1e-3, 0.5, 0.5]],
        np.float64,
    )
    faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    mesh = trimesh.Trimesh(v, faces, process=False)
    f = mesh_distance(mesh, bounds=[[-0.5, -0.5, -0.5], [2.5, 1.5, 1.5]], resolution=24, padding=0.0, signed=False, device=device)
    p = f.points().astype(np.float32)
    want = reference.mesh_unsigned_distance_naive(v, faces, p)
    np.testing.assert_allclose(f.values.reshape(-1), want, atol=2e-5, rtol=2e-6)


def test_grid_matches_points_larger_mesh(device):
    # a mesh deep enough for a real traversal (thousands of faces): grid == points
    mesh = trimesh.creation.torus(1.0, 0.3, major_sections=96, minor_sections=48)
    f = mesh_distance(mesh, resolution=30, device=device)
    pts = mesh_distance(mesh, f.points(), device=device)
    np.testing.assert_allclose(f.values.reshape(-1), pts, atol=1e-5)
    far_enough = np.abs(pts) > 1e-5
    np.testing.assert_array_equal(np.sign(f.values.reshape(-1))[far_enough], np.sign(pts)[far_enough])


def test_tri_lanes_layout():
    from geosynth.geometry.meshes import tri_lanes_layout

    tri = np.array([[[0, 0, 0], [2, 0, 0], [0, 1, 0]], [[0, 0, 0], [1e-30, 0, 0], [0, 1e-30, 0]]], np.float64)
    lanes = tri_lanes_layout(tri)
    assert lanes.shape == (2, 32) and lanes.dtype == np.float32 and np.isfinite(lanes[:, :28]).all()
    t = lanes[0]
    np.testing.assert_allclose(t[9:12], [0, 0, 2])  # n = ab x ac
    np.testing.assert_allclose(t[12:15], [-2, 1, 0])  # bc
    np.testing.assert_allclose(t[[21, 22, 23, 27]], [0.25, 1.0, 0.2, 0.25])
    inside = np.array([0.5, 0.25, 0.0])  # the three edge tests of a point inside are >= 0
    assert (inside @ t[15:18] >= 0) and ((inside - [2, 0, 0]) @ t[18:21] >= 0) and (inside @ t[24:27] >= 0)
    assert t[28] == 0 and lanes[1, 28] == np.inf  # a normal lost in float32: never "inside"


# ------------------------------------------------------------------ one result on every device


def _device_pairs():
    """(first, other) for every other present test device; a skip when there is one."""
    if len(TEST_DEVICES) < 2:
        pytest.skip(f"needs two devices to compare, only {TEST_DEVICES} present")
    return [(TEST_DEVICES[0], d) for d in TEST_DEVICES[1:]]


def _kernel_grid_points(field: Field) -> np.ndarray:
    """(Z * Y * X, 3) float32 sample positions as the kernels compute them:
    float32 origin + float32 spacing * float32 index, one rounding per operation."""
    nz, ny, nx = field.shape
    o, s = field.origin.astype(np.float32), field.spacing.astype(np.float32)
    axes = [o[a] + s[a] * np.arange(n, dtype=np.float32) for a, n in enumerate((nx, ny, nz))]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    return np.stack([x, y, z], -1).reshape(-1, 3)


def _mesh_cases(rng):
    chain = chainmail_mesh(2, major_sections=24, minor_sections=12)
    return {"chainmail": chain, "holed": _hole_mesh(), "flipped": _flipped_mesh(rng)}


def test_mesh_distance_bit_identical_across_devices(rng):
    # every path (grid tiles, point tiles, banded, unsigned) gives the same float32 bits
    # on every device: same arithmetic, no FMA contraction, order-free minimum
    pairs = _device_pairs()
    for name, mesh in _mesh_cases(rng).items():
        pts = _points(mesh, rng)
        scale = float(np.abs(mesh.bounds).max())
        calls = {
            "grid": lambda d: mesh_distance(mesh, resolution=23, device=d).values,
            "grid banded": lambda d: mesh_distance(mesh, resolution=17, band=0.05 * scale, device=d).values,
            "points": lambda d: mesh_distance(mesh, pts, device=d),
            "points unsigned": lambda d: mesh_distance(mesh, pts, signed=False, device=d),
        }
        for what, call in calls.items():
            for first, other in pairs:
                a, b = call(first), call(other)
                assert a.tobytes() == b.tobytes(), (
                    f"{name} {what}: {first} and {other} differ at {int((a != b).sum())} of {a.size} "
                    f"samples (max {np.abs(a - b).max():.3g})"
                )


def test_points_equal_grid_values(device, rng):
    # point queries in any order return exactly the grid path's value at grid points
    for name, mesh in _mesh_cases(rng).items():
        for band in (None, 0.1):
            f = mesh_distance(mesh, resolution=21, band=band, device=device)
            pts = _kernel_grid_points(f)
            perm = rng.permutation(len(pts))
            got = mesh_distance(mesh, pts[perm], band=band, device=device)
            want = f.values.reshape(-1)[perm]
            assert got.tobytes() == want.tobytes(), (
                f"{name} band={band}: {int((got != want).sum())} of {got.size} points differ from the grid"
            )
            in_order = mesh_distance(mesh, pts, band=band, device=device)
            assert in_order.tobytes() == f.values.reshape(-1).tobytes()


def test_points_order_and_duplicates(device, rng):
    # results come back in the caller's order, whatever the internal (Morton) order;
    # repeated and single points, and counts that end in a partial tile of 16
    mesh = _torus()
    pts = _points(mesh, rng)[:37]
    want = reference.mesh_distance_naive(mesh, pts)
    got = mesh_distance(mesh, pts, device=device)
    np.testing.assert_allclose(got, want, atol=ATOL * 10, rtol=2e-6)
    rev = mesh_distance(mesh, pts[::-1].copy(), device=device)
    assert rev[::-1].tobytes() == got.tobytes()
    dup = mesh_distance(mesh, np.repeat(pts[:3], 7, axis=0), device=device)
    assert dup.tobytes() == np.repeat(got[:3], 7).tobytes()
    one = mesh_distance(mesh, pts[5:6], device=device)
    assert one.tobytes() == got[5:6].tobytes()


def test_synthesize_geometry_same_file_on_every_device(tmp_path):
    # end to end from a mesh: the same exemplar and seed write byte-identical PLY files
    from geosynth.geometry.surface import save_mesh
    from geosynth.volume.synthesis import synthesize_geometry

    pairs = _device_pairs()
    mesh = chainmail_mesh(2, major_sections=24, minor_sections=12)

    def run(dev):
        r = synthesize_geometry(mesh, 32, source_resolution=32, levels=2, block=8, seed=7, device=dev,
                                quality_samples=0, progress=False)
        return r, save_mesh(r.mesh, tmp_path / f"out-{dev.replace(':', '_')}.ply").read_bytes()

    first, data = run(pairs[0][0])
    assert len(first.mesh.faces) > 0
    for _, other in pairs:
        r, other_data = run(other)
        assert r.exemplar_field.values.tobytes() == first.exemplar_field.values.tobytes()
        assert other_data == data, f"{other} wrote a different mesh than {pairs[0][0]}"


def _lane_min_dist2(lanes: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(P,) float32 minimum over every triangle of the kernels' per-triangle squared
    distance (tri_min_dist2 in kernels/sdf_mesh.*), emulated in NumPy float32 with the
    same operations in the same order (NumPy rounds each one, as the kernels do)."""
    t = [lanes[None, :, k] for k in range(29)]  # (1, F) each
    px, py, pz = (p[:, k : k + 1] for k in range(3))  # (P, 1) each
    zero, one = np.float32(0), np.float32(1)

    def clamp01(s):
        s = np.where(s > zero, s, zero)
        return np.where(s < one, s, one)

    def vmin(a, b):
        return np.where(a < b, a, b)

    apx, apy, apz = px - t[0], py - t[1], pz - t[2]
    s = clamp01((apx * t[3] + apy * t[4] + apz * t[5]) * t[21])
    ex, ey, ez = apx - s * t[3], apy - s * t[4], apz - s * t[5]
    d = ex * ex + ey * ey + ez * ez
    s = clamp01((apx * t[6] + apy * t[7] + apz * t[8]) * t[22])
    ex, ey, ez = apx - s * t[6], apy - s * t[7], apz - s * t[8]
    d = vmin(d, ex * ex + ey * ey + ez * ez)
    bpx, bpy, bpz = apx - t[3], apy - t[4], apz - t[5]
    s = clamp01((bpx * t[12] + bpy * t[13] + bpz * t[14]) * t[23])
    ex, ey, ez = bpx - s * t[12], bpy - s * t[13], bpz - s * t[14]
    d = vmin(d, ex * ex + ey * ey + ez * ez)
    inside = ((apx * t[15] + apy * t[16] + apz * t[17]) >= t[28]) & ((bpx * t[18] + bpy * t[19] + bpz * t[20]) >= t[28]) \
        & ((apx * t[24] + apy * t[25] + apz * t[26]) >= t[28])
    h = apx * t[9] + apy * t[10] + apz * t[11]
    d = np.where(inside, h * h * t[27], d)
    return d.min(axis=1)


@pytest.mark.parametrize("name", ["box", "torus", "chainmail"])
def test_distance_is_the_minimum_over_every_triangle(device, rng, name):
    # the pruned searches (per point on Warp, 16 lanes at once on OpenCL) never miss the
    # triangle with the smallest float32 distance: the result is that minimum, bit for
    # bit, also on symmetric grids full of ties, and for points 10^3 extents away
    from geosynth.geometry.meshes import prepare_mesh

    mesh = chainmail_mesh(2, major_sections=16, minor_sections=8) if name == "chainmail" else SMALL_MESHES[name]()
    bvh = prepare_mesh(mesh)
    ext = float((mesh.bounds[1] - mesh.bounds[0]).max())
    far = rng.normal(0, 1, (40, 3))
    far = far / np.linalg.norm(far, axis=1, keepdims=True) * rng.uniform(10, 1000, (40, 1)) * ext
    f = Field(np.zeros((7, 9, 11), np.float32), mesh.bounds[0] - 0.25 * ext, np.full(3, 0.125 * ext))  # ties: symmetric samples
    pts = np.concatenate([_points(mesh, rng, 150, 150, 10), far.astype(np.float32), _kernel_grid_points(f)])
    m = _lane_min_dist2(bvh.tri_lanes, pts)
    got = mesh_distance(mesh, pts, signed=False, device=device)
    assert got.tobytes() == np.sqrt(m).tobytes(), f"{int((got != np.sqrt(m)).sum())} of {len(pts)} points differ"
    grid = mesh_distance(mesh, field=f, signed=False, device=device).values.reshape(-1)
    assert grid.tobytes() == np.sqrt(m[-grid.size:]).tobytes()
    band = np.float32(0.05 * ext)
    banded = mesh_distance(mesh, pts, signed=False, band=float(band), device=device)
    want = np.where(m < band * band, np.sqrt(m), band)
    assert banded.tobytes() == np.where(want < band, want, band).tobytes()


# ------------------------------------------------------------------ units (issue 37)


def _plate() -> trimesh.Trimesh:
    """The reported mesh: a 4 x 4 x 0.4 box with 16 spheres of radius 0.3 on top, concatenated."""
    parts = [trimesh.creation.box(extents=(4, 4, 0.4))]
    for i in range(4):
        for j in range(4):
            ball = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
            ball.apply_translation((-1.5 + i, -1.5 + j, 0.2))
            parts.append(ball)
    return trimesh.util.concatenate(parts)


@pytest.fixture(scope="module")
def plate_queries():
    mesh = _plate()
    lo, hi = mesh.bounds
    pts = np.random.default_rng(0).uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), (20000, 3))
    return mesh, pts


def _scaled(mesh, s):
    out = mesh.copy()
    out.apply_scale(s)
    return out


def test_the_sign_does_not_depend_on_the_mesh_units(device, plate_queries):
    # the plate at 1e-6 had 126 of 20,000 signs flipped (its small faces' plane distances
    # underflowed float32 to 0, and -0 is no sign); distances are computed in units of the
    # mesh's size: the same signs at any scale, distances equal to float32 rounding
    mesh, pts = plate_queries
    base = mesh_distance(mesh, pts, device=device)
    assert (base < 0).sum() > 1000 and (base > 0).sum() > 1000 and (base != 0).all()
    for s in (1e-6, 1e6):
        got = mesh_distance(_scaled(mesh, s), pts * s, device=device)
        assert np.array_equal(got < 0, base < 0), f"scale {s:g}: {int(((got < 0) != (base < 0)).sum())} signs differ"
        assert (got != 0).all()
        np.testing.assert_allclose(got / s, base, rtol=1e-4, atol=1e-5)
    for k in (-20, 20):  # a power of two scales exactly: the same bits, scaled
        got = mesh_distance(_scaled(mesh, 2.0**k), pts * 2.0**k, device=device)
        assert got.tobytes() == (base * np.float32(2.0**k)).tobytes()
    f = Field(np.zeros((10, 12, 14), np.float32), mesh.bounds[0] - 0.3, np.full(3, 0.37))
    grid = mesh_distance(mesh, field=f, device=device).values
    tiny = mesh_distance(_scaled(mesh, 1e-6), field=Field(f.values, f.origin * 1e-6, f.spacing * 1e-6),
                         device=device).values
    assert np.array_equal(tiny < 0, grid < 0) and (tiny != 0).all() and (grid < 0).any()


def test_the_reference_agrees_at_a_micrometre(one_device, plate_queries):
    mesh, pts = plate_queries
    tiny = _scaled(mesh, 1e-6)
    got = mesh_distance(tiny, pts[:150] * 1e-6, device=one_device)
    want = reference.mesh_distance_naive(tiny, pts[:150] * 1e-6)
    assert np.array_equal(got < 0, want < 0)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-11)


def test_queries_beyond_float32_reach_are_refused(one_device):
    mesh = trimesh.creation.box()
    far = np.array([[0.0, 0.0, 0.0], [3e18, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"^points lie up to 3e\+18 beyond the mesh's bounding box, more than "
                                         r"2\^60 \(1.15e\+18\) times its size \(diagonal 1.73\): their squared "
                                         r"distances would leave float32; query points nearer the mesh.$"):
        mesh_distance(mesh, far, device=one_device)
    tiny = _scaled(mesh, 1e-20)  # the same limit, relative to the mesh's size
    with pytest.raises(ValueError, match=r"^points lie up to 1 beyond the mesh's bounding box, more than 2\^60 .*"
                                         r"\(diagonal 1.73e-20\)"):
        mesh_distance(tiny, np.array([[1.0, 0.0, 0.0]]), device=one_device)
    assert mesh_distance(tiny, np.array([[1e-3, 0.0, 0.0]]), device=one_device)[0] == pytest.approx(1e-3, rel=1e-5)


def test_the_volume_pipelines_exemplar_field_does_not_depend_on_the_mesh_units(tmp_path):
    # issue 37 item 4: the volume pipeline (the exemplar's field at a source resolution, in
    # samples) gives the same signs for the plate at 1e-6, 1 and 1e6 (measured: 0 flips,
    # distances within 2e-6 samples)
    from geosynth.volume.tiled import exemplar_source

    fields, spacings = {}, {}
    for s in (1e-6, 1.0, 1e6):
        path = tmp_path / f"plate_{s:g}.ply"
        _scaled(_plate(), s).export(path)
        fields[s], spacings[s], _ = exemplar_source(str(path), 24, 2, 0, TEST_DEVICES[0])
    base = fields[1.0]
    assert (base < 0).sum() > 100 and (base > 0).sum() > 100
    for s in (1e-6, 1e6):
        assert spacings[s] == pytest.approx(s * spacings[1.0], rel=1e-6)
        assert fields[s].shape == base.shape and ((fields[s] < 0) == (base < 0)).all(), s
        np.testing.assert_allclose(fields[s], base, atol=1e-4)
