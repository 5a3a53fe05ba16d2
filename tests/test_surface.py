"""Geometry out: marching cubes, smoothing, mesh files."""

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from geosynth.geometry.field import Field
from geosynth.geometry.surface import field_to_mesh, save_mesh, smooth_mesh
from geosynth.volume.synthesis import quantize_field

ORIGIN = np.array([-1.3, 2.1, 0.4])
SPACING = np.array([0.05, 0.04, 0.06])  # x, y, z: anisotropic on purpose
SHAPE = (30, 40, 44)  # z, y, x
CENTRE = ORIGIN + SPACING * (np.array(SHAPE[::-1]) - 1) / 2 + np.array([0.03, -0.02, 0.01])
RADIUS = 0.6


def sphere_field(shape=SHAPE, origin=ORIGIN, spacing=SPACING, centre=CENTRE, radius=RADIUS):
    f = Field(np.zeros(shape, np.float32), origin, spacing)
    d = np.linalg.norm(f.points() - centre, axis=1) - radius
    f.values = d.reshape(shape).astype(np.float32)
    return f


def test_sphere_mesh_in_world_coordinates():
    mesh = field_to_mesh(sphere_field())
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # faces outward
    r = np.linalg.norm(mesh.vertices - CENTRE, axis=1)
    assert np.abs(r - RADIUS).max() < 0.1 * SPACING.min()
    np.testing.assert_allclose(mesh.volume, 4 / 3 * np.pi * RADIUS**3, rtol=0.02)
    # normals point away from the centre
    out = ((mesh.triangles_center - CENTRE) * mesh.face_normals).sum(1)
    assert (out > 0).all()


def test_inverted_field_gives_inward_faces():
    f = sphere_field()
    f.values = -f.values  # now the inside is outside the sphere: the surface faces the centre
    mesh = field_to_mesh(f)
    out = ((mesh.triangles_center - CENTRE) * mesh.face_normals).sum(1)
    assert (out < 0).all()


def test_uint8_field_default_level():
    f = sphere_field()
    q = Field(quantize_field(f.values, 0.3), f.origin, f.spacing)
    mesh = field_to_mesh(q)  # level 127.5
    r = np.linalg.norm(mesh.vertices - CENTRE, axis=1)
    assert np.abs(r - RADIUS).max() < 0.5 * SPACING.max()
    assert mesh.volume > 0


def test_level_selects_the_offset_surface():
    mesh = field_to_mesh(sphere_field(), level=0.2)
    r = np.linalg.norm(mesh.vertices - CENTRE, axis=1)
    assert np.abs(r - (RADIUS + 0.2)).max() < 0.1 * SPACING.min()


def test_close_caps_the_border():
    f = sphere_field(centre=ORIGIN + np.array([0.0, 0.8, 0.9]))  # cut by the x = origin face
    open_mesh = field_to_mesh(f)
    closed = field_to_mesh(f, close=True)
    assert not open_mesh.is_watertight
    assert closed.is_watertight and closed.volume > 0
    assert closed.bounds[0, 0] >= ORIGIN[0] - SPACING[0] - 1e-9


@pytest.mark.parametrize("method", ["taubin", "laplacian"])
def test_smoothing_keeps_the_volume(method):
    f = sphere_field()
    rng = np.random.default_rng(0)
    f.values = f.values + rng.uniform(-0.01, 0.01, f.values.shape).astype(np.float32)  # a rough surface
    rough = field_to_mesh(f)
    smooth = field_to_mesh(f, smooth=10, method=method)
    np.testing.assert_allclose(smooth.volume, rough.volume, rtol=0.03)
    r_rough = np.linalg.norm(rough.vertices - CENTRE, axis=1)
    r_smooth = np.linalg.norm(smooth.vertices - CENTRE, axis=1)
    assert r_smooth.std() < r_rough.std()  # the bumps are gone
    np.testing.assert_array_equal(smooth.faces, rough.faces)


def test_invalid_input():
    f = sphere_field()
    with pytest.raises(TypeError, match="Field"):
        field_to_mesh(f.values)
    with pytest.raises(ValueError, match="no surface"):
        field_to_mesh(f, level=100.0)
    with pytest.raises(ValueError, match="no surface"):
        field_to_mesh(Field(np.ones((4, 4, 4), np.float32), 0, 1))
    with pytest.raises(ValueError, match="finite"):
        field_to_mesh(f, level=float("nan"))
    bad = sphere_field()
    bad.values[3, 3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        field_to_mesh(bad)
    with pytest.raises(ValueError, match="scalar"):
        field_to_mesh(Field(np.zeros((4, 4, 4, 2), np.float32), 0, 1))
    with pytest.raises(ValueError, match="at least 2"):
        field_to_mesh(Field(np.zeros((1, 4, 4), np.float32), 0, 1))
    with pytest.raises(ValueError, match="smoothing method"):
        field_to_mesh(f, smooth=2, method="bilateral")
    with pytest.raises(ValueError, match="iterations"):
        field_to_mesh(f, smooth=-1)
    with pytest.raises(ValueError, match="iterations"):
        smooth_mesh(trimesh.creation.box(), 1.5)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl", ".PLY"])
def test_save_load_round_trip(tmp_path, suffix):
    mesh = field_to_mesh(sphere_field(shape=(12, 14, 16), spacing=0.12, radius=0.5))
    path = save_mesh(mesh, tmp_path / f"sphere{suffix}")
    assert path.exists() and not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]
    back = trimesh.load(path, force="mesh")
    assert len(back.faces) == len(mesh.faces)
    np.testing.assert_allclose(back.volume, mesh.volume, rtol=1e-5)
    np.testing.assert_allclose(back.bounds, mesh.bounds, atol=1e-5)


def test_save_refuses(tmp_path):
    mesh = trimesh.creation.box()
    with pytest.raises(ValueError, match="unknown mesh suffix"):
        save_mesh(mesh, tmp_path / "box.glb")
    with pytest.raises(ValueError, match="unknown mesh suffix"):
        save_mesh(mesh, tmp_path / "box")
    src = tmp_path / "in.ply"
    save_mesh(mesh, src)
    before = src.read_bytes()
    with pytest.raises(ValueError, match="is an input file"):
        save_mesh(trimesh.creation.icosphere(), tmp_path / "." / "in.ply", inputs=[str(src)])
    assert src.read_bytes() == before
    with pytest.raises(TypeError, match="Trimesh"):
        save_mesh("box", tmp_path / "x.ply")
    with pytest.raises(ValueError, match="empty"):
        save_mesh(trimesh.Trimesh(), tmp_path / "x.ply")


def test_save_is_atomic(tmp_path, monkeypatch):
    target = tmp_path / "out.stl"
    target.write_bytes(b"old")

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        save_mesh(trimesh.creation.box(), target)
    assert target.read_bytes() == b"old"  # the old file is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.stl"]  # no partial file left
    monkeypatch.undo()
    assert Path(save_mesh(trimesh.creation.box(), target)).stat().st_size > 3


def test_outputs_get_the_usual_file_mode(tmp_path):
    old = os.umask(0o022)
    try:
        path = Path(save_mesh(trimesh.creation.box(), tmp_path / "box.ply"))
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644  # not mkstemp's 0600
