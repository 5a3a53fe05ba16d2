"""The zoo of exemplars (bench/zoo.py) and the measures of bench/bm_zoo.py (#32): members are
drawn the same way for the same seed, every writer's file reads back through geosynth's
readers, and the relief measures find a capture's own ground truth within the issue's
tolerance (a measure that fails the truth would call good results bad, or bad ones good)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import ONE_DEVICE

ROOT = Path(__file__).resolve().parent.parent


def _load(name: str):
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        spec = importlib.util.spec_from_file_location(f"_zoo_{name}", ROOT / "bench" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(ROOT / "bench"))


zoo = _load("zoo")


def test_members_are_drawn_again_for_the_same_seed_and_cover_every_family():
    for method in zoo.METHODS:
        a, b = zoo.zoo(method, 12, seed=3), zoo.zoo(method, 12, seed=3)
        assert [m.params for m in a] == [m.params for m in b]
        assert [m.params for m in a] != [m.params for m in zoo.zoo(method, 12, seed=4)]
    assert {m.family for m in zoo.zoo("volume", 12)} == set(zoo.VOLUME_FAMILIES)
    assert {m.family for m in zoo.zoo("pointtexture", 12)} == set(zoo.POINT_FAMILIES)
    captures = zoo.zoo("complete", 12)
    assert {m.params["surface"] for m in captures} == set(zoo.SURFACES)
    assert {m.params["relief"] for m in captures} == set(zoo.RELIEFS)
    assert {m.params["writer"] for m in captures} == {"trimesh-ply", "plyfile-ascii", "plyfile-binary", "obj"}
    with pytest.raises(ValueError, match="unknown method"):
        zoo.zoo("carving")


@pytest.mark.parametrize("index", [0, 1, 2, 3])  # one capture per writer: trimesh PLY, plyfile ASCII, OBJ, plyfile binary
def test_every_capture_writer_reads_back_with_its_positions_and_colours(tmp_path, index):
    from geosynth.geometry.pointsets import read_geometry

    member = zoo.zoo("complete", 4)[index]
    verts, faces, colours, _ = zoo.capture_surface(member)
    got = read_geometry(member.write(tmp_path))
    positions = np.asarray(got.vertices if hasattr(got, "vertices") else got.positions)
    assert positions.shape == verts.shape
    np.testing.assert_allclose(positions, verts, atol=1e-5)
    if colours is not None:
        got_colours = got.visual.vertex_colors if hasattr(got, "visual") else got.colors
        assert np.array_equal(np.asarray(got_colours)[:, :3], colours)


def test_relief_measures_find_the_ground_truth():
    bm_zoo = _load("bm_zoo")
    member = zoo.zoo("complete", 12)[10]  # diagonal ridges on a cylinder
    whole, _, _, _ = zoo.capture_surface(member, whole=True)
    captured, _, _, _ = zoo.capture_surface(member)
    from scipy.spatial import cKDTree

    cap = cKDTree(captured).query(whole)[0] < 1e-9
    uv, h, usable = bm_zoo._surface_uv(member, whole)
    spacing = 1.5 * member.params["spacing"]  # coarser than the benchmark: quicker, as exact here
    r = bm_zoo.compare_reliefs(bm_zoo._grid(uv[cap & usable], h[cap & usable], spacing),
                               bm_zoo._grid(uv[~cap & usable], h[~cap & usable], spacing), spacing)
    assert abs(r["size"] - 1) < 0.05 and abs(r["height"] - 1) < 0.05
    assert r["angle_diff"] < 3
    # and a wrong relief is caught: the hidden part's heights halved, its period stretched
    stretched = uv[~cap & usable] * [1.3, 1.3]
    worse = bm_zoo.compare_reliefs(bm_zoo._grid(uv[cap & usable], h[cap & usable], spacing),
                                   bm_zoo._grid(stretched, 0.5 * h[~cap & usable], spacing), spacing)
    assert worse["size"] > 1.2 and worse["height"] < 0.6


def test_colour_measure_compares_with_the_capture_files_own_colours(tmp_path):
    """The output's uncompleted part also holds the oversampling's new vertices, coloured by
    averaging their neighbours (colours between the stripes'); a completion that copies the
    capture's colours exactly scores as such against the capture file, not against those."""
    import plyfile

    bm_zoo = _load("bm_zoo")
    member = zoo.zoo("complete", 3)[2]  # ridges on a sphere, coloured
    src = member.write(tmp_path)
    whole, _, colours, _ = zoo.capture_surface(member, whole=True)
    captured, _, cap_colours, _ = zoo.capture_surface(member)
    from scipy.spatial import cKDTree

    done = cKDTree(captured).query(whole)[0] > 1e-9
    mixed = ((cap_colours.astype(np.int64) + np.roll(cap_colours, 3, axis=0)) // 2).astype(np.uint8)
    pos = np.concatenate([whole, captured])
    col = np.concatenate([colours, mixed])
    flag = np.concatenate([done, np.zeros(len(captured), bool)])
    v = np.empty(len(pos), [(k, "f4") for k in "xyz"] + [(k, "u1") for k in ("red", "green", "blue", "completed")])
    for i, k in enumerate("xyz"):
        v[k] = pos[:, i]
    for i, k in enumerate(("red", "green", "blue")):
        v[k] = col[:, i]
    v["completed"] = flag
    out = tmp_path / "out.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")]).write(str(out))
    assert bm_zoo.measure_complete(member, out, src)["colour_hist"] > 0.9
    assert bm_zoo.measure_complete(member, out)["colour_hist"] < 0.85


def test_random_bumps_on_a_cylinder_are_not_a_directed_relief():
    """The zoo's bumped cylinder: its spectrum's anisotropy reads 0.22 (a handful of bumps),
    above the directed threshold, but its slopes point every way (slope order ~0.06, the
    tower's arches 0.54): R 4 in the paper's frames, not one unturned copy (1.18x its size)."""
    from geosynth.completion.fit import fit_surface
    from geosynth.completion.prep import Capture
    from geosynth.completion.synthesis import choose_settings

    member = zoo.zoo("complete", 5)[4]
    verts, faces, _, _ = zoo.capture_surface(member)
    cap = Capture(verts, faces=faces)
    a = choose_settings(cap, fit_surface(verts, "cylinder"))
    assert a.spectrum.anisotropy >= 0.2 and (a.rotations, a.frames) == (4, "paper"), a.reason
    assert "slopes in every direction" in a.reason, a.reason


def test_a_slice_of_the_zoo_meets_the_target_on_every_device(tmp_path, capsys, device):
    """Three members through the command line with the defaults, measured as bench/bm_zoo.py
    does, on every device and over seeds: a plate with rivets grown by M1 (at --size 64, the
    exemplar's own extent), bumps grown by M2 and a ridged plane completed by M4 keep their
    size and height within 15%, beat random tiling / pasting, and keep the ridges' direction.
    Measured over seeds 1-6 (opencl; bench/RESULTS.md, the zoo): M1 size 1.03-1.11, height
    0.94-1.05, 0.10-0.16 of random; M2 (member 06, whose height the paper's spline squashed
    to 0.82-0.89) size 0.94-0.98, height 0.94-0.98; M4 size 0.93, height 1.00, 0.26 degrees
    on every seed. The seeds run on ONE_DEVICE (cuda where present, else OpenCL: the quality
    claim over seeds); every other device runs the first seed of each (the same path on that
    device; it keeps `make test` within its 10 minutes)."""
    from geosynth.cli import main

    bm = _load("bm_zoo")
    all_seeds = device == ONE_DEVICE

    def seeds(*s):
        return s if all_seeds else s[:1]

    plate = zoo.zoo("volume", 1)[0]
    src = plate.write(tmp_path / "inputs")
    (tmp_path / "outputs").mkdir()
    for seed in seeds(1, 2, 3):
        out = tmp_path / "outputs" / f"plate-{seed}.ply"
        assert main(["volume", str(src), "-o", str(out), "--size", "64", "--device", device, "--seed", str(seed)]) == 0
        row = bm.measure_volume(plate, src, out, capsys.readouterr().out)
        assert row["kind"] == "relief" and bm.verdict(row), (seed, row)
    bumps = zoo.zoo("pointtexture", 7)[6]  # bumps of several sizes on a plane, a plyfile ASCII file
    ex = bumps.write(tmp_path / "inputs")
    for seed, quality in seeds((1, []), (2, ["--no-quality"])):  # (random pasting's baseline once: ~6 s on cpu)
        out = tmp_path / "outputs" / f"bumps-{seed}.ply"
        assert main(["pointtexture", str(ex), "-o", str(out), "--device", device, "--seed", str(seed), *quality]) == 0
        row = bm.measure_points(bumps, ex, out, capsys.readouterr().out)
        assert bm.verdict(row) and (quality or row["vs_random"] < 0.9), (seed, row)
    ridges = zoo.zoo("complete", 10)[9]  # a ridged plane without colour, missing a band across its middle
    cap = ridges.write(tmp_path / "inputs")
    for seed in seeds(1, 2):
        done = tmp_path / "outputs" / f"ridges-{seed}.ply"
        assert main(["complete", str(cap), "-o", str(done), "--device", device, "--seed", str(seed), "--quiet"]) == 0
        row = bm.measure_complete(ridges, done, cap)
        assert bm.verdict(row) and row["angle_diff"] <= 10, (seed, row)
