"""Built-in exemplars: documented sizes, finite, watertight, seeded."""

import numpy as np
import pytest

from geosynth.volume import examples
from geosynth.volume.examples import EXEMPLARS, exemplar_field, exemplar_mesh

NAMES = sorted(EXEMPLARS)
SLABS = {"domes", "rings"}  # the thin slab exemplars
GROWN_AS_SLABS = SLABS | {"chainmail"}  # geosynth.volume.synthesis.is_slab at the default resolution


@pytest.fixture(scope="module")
def built():
    """Every exemplar with seeds 0 (twice) and 1, built once for the module."""
    return {name: (exemplar_mesh(name, 0), exemplar_mesh(name, 0), exemplar_mesh(name, 1)) for name in NAMES}


def test_registry_names():
    assert set(EXEMPLARS) == {"chainmail", "balls", "grid", "fibers", "terrain", "domes", "rings"}
    for name, ex in EXEMPLARS.items():
        assert ex.name == name and ex.summary and ex.faces[0] <= ex.faces[1]


@pytest.mark.parametrize("name", NAMES)
def test_exemplar_is_a_clean_solid_of_the_documented_size(built, name):
    mesh = built[name][0]
    lo, hi = EXEMPLARS[name].faces
    assert lo <= len(mesh.faces) <= hi, f"{name}: {len(mesh.faces)} faces, documented {lo}..{hi}"
    assert np.isfinite(mesh.vertices).all()
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward faces
    # units: the footprint is about the unit square, z up, height at most 1
    b = mesh.bounds
    assert np.all(b[0] > -0.05) and np.all(b[1][:2] < 1.05) and b[1][:2].max() > 0.95
    assert (0.03 if name in SLABS else 0.2) < b[1][2] <= (0.2 if name in SLABS else 1.0)


@pytest.mark.parametrize("name", NAMES)
def test_exemplar_seeded(built, name):
    a, again, other = built[name]
    np.testing.assert_array_equal(a.vertices, again.vertices)
    np.testing.assert_array_equal(a.faces, again.faces)
    assert a.vertices.shape != other.vertices.shape or not np.array_equal(a.vertices, other.vertices)


def test_unknown_exemplar_lists_the_names():
    with pytest.raises(ValueError, match="chainmail, balls, grid, fibers, terrain"):
        exemplar_mesh("teapot")
    with pytest.raises(ValueError, match="unknown exemplar"):
        exemplar_field("teapot")


def test_balls_do_not_overlap_and_rest():
    centres, radii = examples._balls_layout(3)
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert (d >= radii[:, None] + radii[None] + 0.005 - 1e-9).all()
    assert (centres[:, 2] >= radii - 1e-12).all()
    assert (centres[:, :2] >= radii[:, None] - 1e-12).all() and (centres[:, :2] <= 1 - radii[:, None] + 1e-12).all()
    # settled: every sphere touches the floor or another sphere (within the gap)
    touching = (np.abs(d - radii[:, None] - radii[None] - 0.005) < 1e-6).any(1) | np.isclose(centres[:, 2], radii)
    assert touching.all()


def test_balls_field_is_the_exact_distance():
    field = exemplar_field("balls", resolution=24, seed=0)
    centres, radii = examples._balls_layout(0)
    pts = field.points()
    exact = (np.linalg.norm(pts[:, None, :] - centres[None], axis=-1) - radii).min(1)
    np.testing.assert_allclose(field.values.ravel(), exact, atol=1e-5)
    # the same grid as mesh_distance(exemplar_mesh("balls"), resolution=24)
    from geosynth.geometry.field import cubic_grid

    grid = cubic_grid(exemplar_mesh("balls").bounds, 24, 0.1)
    np.testing.assert_allclose(field.origin, grid.origin)
    assert field.shape == grid.shape


def test_terrain_heights_tile():
    h = examples.terrain_heights(32, seed=2)
    assert h.shape == (32, 32) and h.min() == 0 and h.max() == 1
    # periodic: the jump across the wrap is like the jumps inside
    inside = np.abs(np.diff(h, axis=0)).max()
    assert np.abs(h[0] - h[-1]).max() <= inside + 1e-12


def test_tube_mesh_is_closed_and_outward():
    t = np.linspace(0, 1, 20)
    path = np.column_stack([t, 0.1 * np.sin(6 * t), 0.05 * np.cos(4 * t)])
    tube = examples.tube_mesh(path, 0.05, sections=10)
    assert tube.is_watertight and tube.volume > 0
    assert len(tube.faces) == 2 * 10 * 19 + 2 * 10
    np.testing.assert_allclose(tube.volume, np.pi * 0.05**2 * np.linalg.norm(np.diff(path, axis=0), axis=1).sum(),
                               rtol=0.08)
    with pytest.raises(ValueError, match="path"):
        examples.tube_mesh(np.zeros((1, 3)), 0.1)


def test_exemplar_field_from_the_mesh(device):
    field = exemplar_field("terrain", resolution=16, seed=0, device=device)
    assert field.shape[2] == 16 and field.values.dtype == np.float32
    # a column through the slab: inside (negative) at the bottom, outside at the top
    k_mid = field.values[:, 8, 8]
    assert k_mid[2] < 0 < k_mid[-1]


def test_slab_exemplars_are_slabs_and_the_others_are_not():
    """The automatic slab choice (geosynth.volume.synthesis.is_slab) on every built-in exemplar's
    source grid at the default resolution; the rings are separate pieces."""
    from geosynth.volume.synthesis import _exemplar_grid_geometry, is_slab, target_size

    for name in NAMES:
        shape = _exemplar_grid_geometry(exemplar_mesh(name), 64, multiple=4)[0]
        assert is_slab(shape, target_size(128, shape, 3)) == (name in GROWN_AS_SLABS), (name, shape)
    assert len(exemplar_mesh("rings").split(only_watertight=False)) == 16
