"""geosynth relief (issue 34): every example kind parses, closed meshes stay closed, the relief has
the example's amplitude, inputs are never overwritten, bad inputs are one line, the same seed gives
the same bytes, and the synthesis is the same on every device. Small meshes: the whole file runs in
well under a minute on 2 cores."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import geosynth
from conftest import ONE_DEVICE
from geosynth.cli import main
from geosynth.io.files import write_image
from geosynth.relief.examples import BUILTINS, builtin_heights, builtin_image, load_example
from geosynth.relief.write import read_3mf, write_relief

SPHERE = dict(scale=16.0)  # icosphere(1) of radius 1: about 640 vertices, 5 periods around
FAST = dict(progress=False, search="coherent", baseline=False, refine=0, remesh="no")


def _sphere():
    return trimesh.creation.icosphere(1)


def _cylinder():
    return trimesh.creation.cylinder(radius=0.5, height=1.5, sections=24)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("relief")
    write_image(d / "knurl.png", builtin_image("knurl"))
    h, col = builtin_heights("cobbles")
    write_image(d / "cobbles.png", np.rint(h * 255).astype(np.uint8))
    write_image(d / "cobbles_rgb.png", col)
    write_image(d / "small_rgb.png", np.zeros((8, 8, 3), np.uint8))
    from PIL import Image

    Image.new("CMYK", (16, 16)).save(d / "cmyk.tif")
    (d / "not_image.png").write_bytes(b"not an image at all")
    # a captured patch: a 41 x 30 grid (5 whole periods along x) of a ridged relief on a tilted plane, coloured
    yy, xx = np.meshgrid(np.arange(30) * 0.1, np.arange(41) * 0.1, indexing="ij")
    z = 0.05 * np.sin(2 * np.pi * xx / 0.8)
    pts = np.stack([xx.ravel(), yy.ravel(), z.ravel()], 1)
    rot = trimesh.transformations.rotation_matrix(0.3, [1, 0, 0])[:3, :3]
    i, j = np.meshgrid(np.arange(29), np.arange(40), indexing="ij")
    a = (i * 41 + j).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + 42], 1), np.stack([a, a + 42, a + 41], 1)])
    patch = trimesh.Trimesh(pts @ rot.T, faces, process=False)
    patch.visual.vertex_colors = np.tile([120, 80, 40, 255], (len(pts), 1)).astype(np.uint8)
    patch.export(d / "patch.ply")
    _sphere().export(d / "sphere.stl")
    return d


# ---------------------------------------------------------------------- examples


@pytest.mark.parametrize("name", BUILTINS)
def test_builtins_parse_tile_and_are_seeded(name):
    h, col = builtin_heights(name, seed=0)
    assert h.shape == (128, 128) and h.min() == 0 and h.max() == 1
    assert col is None or (col.shape == (128, 128, 3) and col.dtype == np.uint8)
    again, _ = builtin_heights(name, seed=0)
    np.testing.assert_array_equal(h, again)
    ex = load_example(name, size=2.0)
    assert ex.periodic and ex.spacing == pytest.approx(0.5 / 128) and ex.depth == pytest.approx(0.02)
    # tiling: the step across the wrap is like a step inside
    assert np.abs(h[:, 0] - h[:, -1]).mean() < 3 * np.abs(np.diff(h, axis=1)).mean() + 1e-9


def test_image_colour_and_patch_examples(files):
    ex = load_example(files / "knurl.png", size=4.0, depth=0.1)
    assert ex.shape == (128, 128) and ex.depth == pytest.approx(0.1, rel=1e-3) and ex.colours is None
    ex = load_example(files / "cobbles.png", size=4.0, colour=files / "cobbles_rgb.png")
    assert ex.colours.shape == (128, 128, 3) and ex.depth == pytest.approx(0.04, rel=1e-2)
    patch = load_example(files / "patch.ply", size=4.0)
    assert patch.spacing == pytest.approx(0.1, rel=0.05)
    assert patch.depth == pytest.approx(0.1, rel=0.15)  # a sine of amplitude 0.05, measured over its tilted plane
    assert patch.colours is not None and (patch.colours == [120, 80, 40]).all()
    assert min(patch.shape) >= 25


# ---------------------------------------------------------------------- geometry


@pytest.mark.parametrize("make", [_sphere, _cylinder], ids=["icosphere", "cylinder"])
def test_closed_input_stays_closed(make, tmp_path, one_device):
    mesh = make()
    assert mesh.is_watertight
    for method in ("project", "synth"):
        r = geosynth.grow_relief(mesh, "cobbles", method=method, device=one_device, **SPHERE,
                                 **dict(FAST, remesh="auto"))  # the cylinder's slivers remeshed
        out = r.to_mesh()
        assert out.is_watertight and out.is_winding_consistent, method
        assert len(r.vertices) > 4 * len(mesh.vertices)
        for suffix in (".stl", ".ply", ".3mf"):
            path = write_relief(tmp_path / f"{method}{suffix}", r.vertices, r.faces, r.colours)
            if suffix == ".3mf":
                v, f, col = read_3mf(path)
                back = trimesh.Trimesh(v, f, process=False)
                np.testing.assert_array_equal(col, r.colours)
            else:
                back = trimesh.load(path, force="mesh")  # an STL merged on load
            assert back.is_watertight, (method, suffix)


def test_stl_soup_is_merged_before_displacement(files, one_device):
    r = geosynth.grow_relief(files / "sphere.stl", "knurl", method="project", device=one_device, **SPHERE, **FAST)
    assert r.input_watertight and r.to_mesh().is_watertight


@pytest.mark.parametrize("method", ["project", "synth"])
def test_displacement_has_the_examples_amplitude(method, one_device):
    mesh = trimesh.creation.icosphere(2)
    r = geosynth.grow_relief(mesh, "cobbles", method=method, device=one_device, scale=8.0, **FAST)
    along = np.einsum("ij,ij->i", r.vertices - r.base, r.normals)
    np.testing.assert_allclose(along, r.heights, atol=1e-12)
    got, want = along.std(), r.example.heights.std()
    tol = 0.15 if method == "synth" else 0.35  # the projection's blends flatten its relief (the baseline's seams)
    assert abs(got / want - 1) < tol, (got, want)
    assert r.quality.amplitude.shape == r.quality.period.shape and np.isfinite(r.quality.example_period)


def test_mask_keeps_faces_bare(one_device):
    mesh = _sphere()
    bare = mesh.triangles_center[:, 2] > 0.3
    r = geosynth.grow_relief(mesh, "knurl", method="project", mask=bare, device=one_device, **SPHERE, **FAST)
    top = r.base[:, 2] > 0.5
    assert np.all(r.heights[top] == 0) and r.heights[r.base[:, 2] < 0].max() > 0


def test_colour_mask_keeps_vertices_bare(one_device):
    mesh = _sphere()
    col = np.tile([200, 200, 200, 255], (len(mesh.vertices), 1)).astype(np.uint8)
    col[mesh.vertices[:, 2] > 0.3] = (255, 0, 0, 255)
    mesh.visual.vertex_colors = col
    for mask in (np.array([250, 10, 5]), mesh.vertices[:, 2] > 0.3):  # a colour, then vertex booleans
        r = geosynth.grow_relief(mesh, "knurl", method="project", mask=mask, device=one_device, **SPHERE, **FAST)
        assert np.all(r.heights[r.base[:, 2] > 0.5] == 0) and r.heights[r.base[:, 2] < 0].max() > 0
        # the knurl has no colour: the mesh keeps its own (red cap, grey below)
        assert (r.colours[r.base[:, 2] > 0.5] == [255, 0, 0]).all() and (r.colours[r.base[:, 2] < -0.6] == 200).all()


def test_clearance_limits_relief_in_a_narrow_gap():
    # two parallel plates 0.02 apart, relief 0.05 deep: the two facing sides never meet (each moves less
    # than half the gap)
    a = trimesh.creation.box([1, 1, 0.1])
    b = a.copy()
    b.apply_translation([0, 0, 0.12])
    mesh = trimesh.util.concatenate([a, b])
    r = geosynth.grow_relief(mesh, "hammered", method="project", depth=0.05, scale=4.0, resolution=0.02, **FAST)
    inner = (np.abs(r.base[:, :2]) < 0.49).all(1)  # off the rims (their smoothed normals lean outward)
    gap = inner & (np.abs(r.base[:, 2] - 0.05) < 1e-9)  # the lower plate's top face
    assert r.heights[gap].max() < 0.01 and r.limited > 0
    facing = inner & (np.abs(r.base[:, 2] - 0.07) < 1e-9)  # the upper plate's bottom face
    assert r.vertices[gap, 2].max() < r.vertices[facing, 2].min()
    assert r.heights[r.base[:, 2] > 0.169].max() > 0.04  # the top, facing nothing, keeps its relief


# ---------------------------------------------------------------------- files and errors


def test_never_overwrites_an_input(files, tmp_path):
    mesh = files / "sphere.stl"
    before = mesh.read_bytes()
    with pytest.raises(ValueError, match="input"):
        write_relief(mesh, np.zeros((3, 3)), np.array([[0, 1, 2]]), inputs=[mesh])
    rc = main(["relief", str(mesh), "knurl", "-o", str(mesh), "--method", "project", "--scale", "16", "--quiet"])
    assert rc == 2 and mesh.read_bytes() == before


@pytest.mark.parametrize("argv, says", [
    (["{d}/missing.stl", "knurl"], "does not exist"),
    (["{d}/sphere.stl", "{d}/missing.png"], "does not exist"),
    (["{d}/sphere.stl", "{d}/cmyk.tif"], "no grey value"),
    (["{d}/sphere.stl", "{d}/not_image.png"], "not a readable image"),
    (["{d}/sphere.stl", "knurl", "--depth", "-1"], "--depth"),
    (["{d}/sphere.stl", "{d}/knurl.png", "--colour", "{d}/small_rgb.png"], "same size"),
    (["{d}/sphere.stl", "marble"], "neither a built-in"),
])
def test_bad_inputs_are_one_line(files, tmp_path, capsys, argv, says):
    argv = ["relief"] + [a.format(d=files) for a in argv] + ["-o", str(tmp_path / "out.ply"), "--quiet",
                                                             "--method", "project", "--scale", "16"]
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's range checks
        rc = exc.code
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert rc == 2 and len(err) == 1 and says in err[0], err
    assert not (tmp_path / "out.ply").exists()


def test_api_errors_are_one_line():
    with pytest.raises(ValueError, match="depth must be"):
        geosynth.grow_relief(_sphere(), "knurl", depth=-0.1)
    with pytest.raises(ValueError, match="method must be"):
        geosynth.grow_relief(_sphere(), "knurl", method="paint")
    with pytest.raises(FileNotFoundError):
        geosynth.grow_relief("/nonexistent/mesh.ply", "knurl")


def test_memory_refused_up_front():
    from geosynth.core.memory import MemoryBudgetError

    with pytest.raises(MemoryBudgetError, match="--resolution"):
        geosynth.grow_relief(_sphere(), "knurl", resolution=1e-5, **FAST)


def test_cli_writes_mesh_and_picture(files, tmp_path, capsys):
    out = tmp_path / "ball.glb"
    rc = main(["relief", str(files / "sphere.stl"), "cobbles", "-o", str(out), "--method", "project", "--scale", "16"])
    text = capsys.readouterr().out
    assert rc == 0 and out.exists() and out.with_suffix(".png").exists()
    assert "project: amplitude" in text and "written" in text
    back = trimesh.load(out, force="mesh")
    assert back.visual.kind == "vertex"


# ---------------------------------------------------------------------- determinism and devices


def test_same_seed_same_bytes(tmp_path, one_device):
    paths = []
    for k in range(2):
        r = geosynth.grow_relief(_sphere(), "cobbles", seed=3, device=one_device, **SPHERE, **FAST)
        paths.append(write_relief(tmp_path / f"r{k}.ply", r.vertices, r.faces, r.colours))
    assert paths[0].read_bytes() == paths[1].read_bytes()
    other = geosynth.grow_relief(_sphere(), "cobbles", seed=4, device=one_device, **SPHERE, **FAST)
    assert not np.array_equal(other.vertices, r.vertices)


def test_synthesis_is_the_same_on_every_device(device_pair):
    a, b = device_pair
    fast = dict(FAST, refine=1, remesh="yes")  # the remesh, the growth, a refinement pass and the output level
    ra = geosynth.grow_relief(_sphere(), "cobbles", device=a, **SPHERE, **fast)
    rb = geosynth.grow_relief(_sphere(), "cobbles", device=b, **SPHERE, **fast)
    np.testing.assert_array_equal(ra.vertices, rb.vertices)
    np.testing.assert_array_equal(ra.colours, rb.colours)


def test_patch_example_grows_with_its_colour(files, one_device):
    r = geosynth.grow_relief(_sphere(), files / "patch.ply", device=one_device, **FAST)
    assert r.colours is not None and (r.colours == [120, 80, 40]).all()
    assert r.to_mesh().is_watertight and r.heights.max() > 0.5 * r.example.depth


def test_cli_synth_with_an_image_and_its_colours(files, tmp_path, capsys):
    out = tmp_path / "ball.3mf"
    rc = main(["relief", str(files / "sphere.stl"), str(files / "cobbles.png"),
               "--colour", str(files / "cobbles_rgb.png"),
               "-o", str(out), "--scale", "16", "--search", "coherent", "--refine", "0", "--remesh", "no",
               "--device", ONE_DEVICE])
    text = capsys.readouterr().out
    assert rc == 0 and "M4's growth" in text and "project: amplitude" in text
    v, f, col = read_3mf(out)
    assert trimesh.Trimesh(v, f, process=False).is_watertight and col is not None and len(np.unique(col, axis=0)) > 5


# ---------------------------------------------------------------------- coarse to fine (transfer.py)


def _plane(n: int, step: float):
    yy, xx = np.meshgrid(np.arange(n) * step, np.arange(n) * step, indexing="ij")
    v = np.stack([xx.ravel(), yy.ravel(), np.zeros(n * n)], 1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    f = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return v, f


def test_transfer_reproduces_a_coherent_copy_and_is_continuous_across_patches():
    from geosynth.relief.refine import refine_mesh
    from geosynth.relief.transfer import sample, transfer, vertex_faces

    ex = load_example("cobbles", size=4.0)  # 128 x 128 cells of 1/128, tiling
    s_c = 4 * ex.spacing  # the coarse level: 4 example cells an edge
    vc, fc = _plane(12, s_c)
    frames = np.tile(np.eye(3), (len(vc), 1, 1))
    rot = np.zeros(len(vc), np.int64)
    place = vc[:, :2] / s_c + [3.0, 5.0]  # one coherent copy, in coarse cells
    v, f, src = refine_mesh(vc, fc, 1.01 * ex.spacing)
    vface = vertex_faces(f, src, len(v))
    h, col, where = transfer(ex, vc, fc, frames, place, rot, 1, s_c, v, vface)
    want, want_col = sample(ex, v[:, :2] / ex.spacing + [12.0, 20.0])
    np.testing.assert_allclose(h, want, atol=1e-12)  # every fine vertex: the example's own relief
    assert np.abs(col.astype(np.int64) - want_col).max() <= 0.5 + 1e-9  # rounded (the three weights' sum)
    # a second patch from an unrelated place on the right half, turned by 180 degrees (R = 2), on a smooth
    # example (a step at the border would be as large as the relief's range; blended, it stays a slope)
    from dataclasses import replace

    yy, xx = np.meshgrid(np.arange(128), np.arange(128), indexing="ij")
    smooth = replace(ex, heights=0.02 + 0.02 * np.sin(2 * np.pi * xx / 16) * np.sin(2 * np.pi * yy / 16), colours=None)
    right = vc[:, 0] > 5.5 * s_c
    place2 = place.copy()
    place2[right] = [5.0, 5.0] - vc[right, :2] / s_c
    rot2 = np.where(right, 1, 0)
    h2, col2, _ = transfer(smooth, vc, fc, frames, place2, rot2, 2, s_c, v, vface)
    assert col2 is None
    left_says = sample(smooth, v[:, :2] / ex.spacing + [12.0, 20.0])[0]
    right_says = sample(smooth, (np.array([5.0, 5.0]) - v[:, :2] / s_c) * 4)[0]
    far = v[:, 0] > 7 * s_c
    np.testing.assert_allclose(h2[far], right_says[far], atol=1e-12)
    border = np.abs(v[:, 0] - 5.5 * s_c) < s_c
    assert np.abs(left_says - right_says)[border].max() > 0.6 * smooth.depth  # a hard switch would step this much
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]]])
    step = np.abs(h2[e[:, 0]] - h2[e[:, 1]])
    inside = np.abs(left_says[e[:, 0]] - left_says[e[:, 1]])
    assert step.max() < 0.5 * smooth.depth and step.max() < 2.5 * inside.max(), (step.max(), inside.max())


def test_remesh_makes_a_slivered_closed_mesh_even_and_keeps_it_closed():
    from geosynth.relief.refine import SLIVER_SHARE, isotropic_remesh, sliver_share

    mesh = _cylinder()  # side faces as tall as the cylinder, 1/24 of the way around wide
    assert sliver_share(mesh.vertices, mesh.faces, 0.06) > SLIVER_SHARE
    v, f = isotropic_remesh(mesh.vertices, mesh.faces, 0.05)
    out = trimesh.Trimesh(v, f, process=False)
    assert out.is_watertight and out.is_winding_consistent and out.volume > 0
    assert sliver_share(v, f, 0.06) < 0.02
    assert abs(out.volume / mesh.volume - 1) < 0.01  # projected back onto the input; the rims kept as features
    assert sliver_share(_sphere().vertices, _sphere().faces, 0.06) == 0  # an even mesh is left alone ("auto")


@pytest.mark.parametrize("make", [_sphere, _cylinder], ids=["icosphere", "cylinder"])
def test_uniform_subdivision_keeps_a_closed_mesh_closed(make):
    from geosynth.relief.refine import subdivide_uniform

    mesh = make()
    v, f, src = subdivide_uniform(mesh.vertices, mesh.faces, 0.1)
    out = trimesh.Trimesh(v, f, process=False)
    assert out.is_watertight and out.is_winding_consistent and out.volume == pytest.approx(mesh.volume, rel=1e-9)
    assert out.edges_unique_length.max() <= 0.1 and len(np.unique(f)) == len(v)
    np.testing.assert_array_equal(v[:len(mesh.vertices)], mesh.vertices)  # the input's vertices keep their ids
    # every new face lies in its source face (all three corners on the source face's plane)
    n = mesh.face_normals[src]
    d = np.einsum("fkj,fj->fk", v[f] - mesh.vertices[mesh.faces[src, 0]][:, None, :], n)
    assert np.abs(d).max() < 1e-12


def test_element_aspect_reads_a_stretch():
    """The features' distortion measure (issue 34 item 4): an isotropic relief's elements read
    about 1, the same stretched twice along one axis about 2, and a built-in knurl stretched
    1.5x about 1.5; a flat grid has none."""
    from scipy.ndimage import gaussian_filter, zoom

    from geosynth.relief.examples import builtin_heights
    from geosynth.relief.quality import element_aspect

    noise = np.random.default_rng(0).standard_normal((96, 96))
    assert 1.0 <= element_aspect(gaussian_filter(noise, 3, mode="wrap")) < 1.25
    assert 1.7 < element_aspect(gaussian_filter(noise, (3, 6), mode="wrap")) < 2.3
    knurl, _ = builtin_heights("knurl")
    assert element_aspect(knurl) < 1.1 and 1.35 < element_aspect(zoom(knurl, (1.0, 1.5), order=1)) < 1.7
    assert np.isnan(element_aspect(np.zeros((32, 32))))
