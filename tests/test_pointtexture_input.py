"""M2 pointtexture, refused up front or handled: options that scale memory (--count, for a
built-in and for a sampled mesh, --resolution, --scale, --size, --mesh-resolution) refused
before any work or output with the largest value that fits; --patch/--extra/--overlap
combinations the growth cannot use; point sets with coincident, collinear or upright points,
NaN normals or too few points (issues 31 and 37); and a hypothesis fuzz of such point sets
through the reader."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement

from geosynth.cli import main
from geosynth.core.memory import MemoryBudgetError
from geosynth.pointtexture.examples import point_texture_example
from geosynth.pointtexture.synthesis import check_synthesis, synthesize_point_texture
from geosynth.pointtexture.texture import PointTexture, read_point_texture, texture_from_points

GIB = 1 << 30


def _run(argv, capsys, monkeypatch, limit: str | None = None, quiet: bool = True) -> tuple[int, str, str]:
    """The CLI in this process (faster than a subprocess), every warning an error."""
    if limit is not None:
        monkeypatch.setenv("GEOSYNTH_MEMORY_LIMIT", limit)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code = main(["pointtexture", *argv, "--device", "cpu"] + (["--quiet"] if quiet else []))
    out, err = capsys.readouterr()
    return code, out, err


def _write_ply(path, positions, normals=None):
    """A PLY point set written with plyfile (NaN allowed, unlike geosynth's writer)."""
    layout = [(c, "<f4") for c in "xyz"] + ([(c, "<f4") for c in ("nx", "ny", "nz")] if normals is not None else [])
    v = np.empty(len(positions), dtype=layout)
    for i, c in enumerate("xyz"):
        v[c] = positions[:, i]
    if normals is not None:
        for i, c in enumerate(("nx", "ny", "nz")):
            v[c] = normals[:, i]
    PlyData([PlyElement.describe(v, "vertex")]).write(str(path))
    return path


def _sheet(n=600, seed=0):
    """A wavy sheet over [-0.25, 1.25]^2 with its normals."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.25, 1.25, (n, 2))
    k = 2 * np.pi * 2
    z = 0.05 * np.sin(k * xy[:, 0]) * np.cos(k * xy[:, 1])
    nrm = np.c_[-0.05 * k * np.cos(k * xy[:, 0]) * np.cos(k * xy[:, 1]),
                0.05 * k * np.sin(k * xy[:, 0]) * np.sin(k * xy[:, 1]), np.ones(n)]
    return np.c_[xy, z], nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


# ------------------------------------------------------------------ memory, before any work


def test_huge_count_is_refused_under_an_address_limit_in_seconds(tmp_path):
    """Issue 31: --count 100000000 under an 8 GB address limit, refused in seconds, one line."""
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (8_000_000_000, 8_000_000_000))

    env = {k: v for k, v in os.environ.items() if k not in ("GEOSYNTH_VERBOSE", "GEOSYNTH_MEMORY_LIMIT")}
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "geosynth", "pointtexture", "--example", "weave", "--count", "100000000",
                        "--scale", "1.3", "-o", str(tmp_path / "r.ply"), "--no-quality"],
                       capture_output=True, text=True, timeout=120, env=env, preexec_fn=limit)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("geosynth pointtexture: --count:"), r.stderr
    assert "lower --count to at most" in r.stderr
    assert time.monotonic() - t0 < 30
    assert not list(tmp_path.iterdir())


def test_the_largest_count_named_fits():
    t = point_texture_example("weave", 1000)
    share = t.inside_mask(t.points, t.box_min, t.box_max).mean()
    avail = 2 * GIB
    with pytest.raises(MemoryBudgetError) as info:
        check_synthesis(t.box_min, t.box_max, 10**8, int(1e8 * share), scale=1.3, quality=False, count=True,
                        available=avail)
    assert info.value.option == "count"
    best = info.value.largest
    assert 1000 < best < 10**8
    check_synthesis(t.box_min, t.box_max, best, int(best * share), scale=1.3, quality=False, count=True,
                    available=avail)  # fits
    with pytest.raises(MemoryBudgetError):
        check_synthesis(t.box_min, t.box_max, int(best * 1.01) + 1, int((best * 1.01 + 1) * share), scale=1.3,
                        quality=False, count=True, available=avail)


def test_a_mesh_count_is_refused_before_sampling(tmp_path, capsys, monkeypatch):
    import trimesh

    mesh = trimesh.creation.box(extents=(1.0, 1.0, 0.1))
    path = tmp_path / "plate.stl"
    mesh.export(str(path))
    code, _, err = _run([str(path), "-o", str(tmp_path / "o.ply"), "--count", "100000000", "--no-quality"], capsys,
                        monkeypatch, limit="2G")
    assert code == 2 and err.startswith("geosynth pointtexture: --count:") and "at most" in err, err
    assert err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plate.stl"]


@pytest.mark.parametrize("options, flag", [(["--scale", "5000"], "--scale"), (["--size", "300", "300"], "--size")])
def test_an_output_too_large_is_refused_naming_its_option(tmp_path, capsys, monkeypatch, options, flag):
    code, _, err = _run(["--example", "weave", "--count", "2000", "-o", str(tmp_path / "o.ply"), "--no-quality",
                         *options], capsys, monkeypatch, limit="4G")
    assert code == 2 and err.startswith(f"geosynth pointtexture: {flag}:") and f"lower {flag} to at most" in err, err
    assert not list(tmp_path.iterdir())


def test_largest_scale_named_fits():
    t = point_texture_example("weave", 1000)
    with pytest.raises(MemoryBudgetError) as info:
        check_synthesis(t.box_min, t.box_max, 40_000, 18_000, scale=5000.0, quality=True, available=GIB)
    assert info.value.option == "scale"
    check_synthesis(t.box_min, t.box_max, 40_000, 18_000, scale=info.value.largest, quality=True, available=GIB)


def test_mesh_resolution_is_refused_before_any_output(tmp_path, capsys, monkeypatch):
    """Issue 37: refused under its own name, before m.ply is written."""
    code, _, err = _run(["--example", "heightfield", "--count", "2000", "-o", str(tmp_path / "m.ply"),
                         "--mesh", str(tmp_path / "m.stl"), "--mesh-resolution", "100000", "--no-quality"],
                        capsys, monkeypatch, limit="6G")
    assert code == 2 and err.startswith("geosynth pointtexture: --mesh-resolution:"), err
    assert "lower --mesh-resolution to at most" in err and "--resolution" not in err.replace("--mesh-resolution", "")
    assert not list(tmp_path.iterdir())


def test_resolution_is_refused_with_the_largest_that_works(tmp_path, capsys, monkeypatch):
    """Issue 37: --resolution 20000 (6 GB) refused up front, not NumPy's 'Unable to allocate'."""
    code, _, err = _run(["--example", "heightfield", "--count", "2000", "-o", str(tmp_path / "r.ply"),
                         "--resolution", "20000", "--no-quality"], capsys, monkeypatch, limit="6G")
    assert code == 2 and err.startswith("geosynth pointtexture: --resolution 20,000"), err
    assert "use --resolution at most" in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("quality", [False, True])
def test_largest_resolution_named_works(quality):
    t = point_texture_example("weave", 1000)
    for avail in (8 << 20, 8 * GIB):  # bound by the memory, then by the search's uint32 sums
        try:
            check_synthesis(t.box_min, t.box_max, 2000, 900, resolution=5000, quality=quality, available=avail)
        except MemoryBudgetError as exc:
            best = exc.largest
        except ValueError as exc:
            best = int(str(exc).split("at most ")[1].split(" ")[0].replace(",", ""))
        else:
            raise AssertionError("resolution 5000 was accepted")
        assert 8 <= best < 5000
        check_synthesis(t.box_min, t.box_max, 2000, 900, resolution=best, quality=quality, available=avail)
        with pytest.raises((ValueError, MemoryBudgetError)):
            check_synthesis(t.box_min, t.box_max, 2000, 900, resolution=best + 1, quality=quality, available=avail)


# ------------------------------------------------------------------ combinations of options


def test_overlaps_that_leave_no_interior_are_refused(tmp_path, capsys, monkeypatch):
    code, _, err = _run(["--example", "weave", "--count", "2000", "-o", str(tmp_path / "o.ply"), "--overlap", "0.5",
                         "--extra", "0.5", "--no-quality"], capsys, monkeypatch)
    assert code == 2 and err.startswith("geosynth pointtexture: --overlap 0.5 ") and "no interior" in err, err
    assert "--overlap at most 0.47" in err
    assert not list(tmp_path.iterdir())
    t = point_texture_example("weave", 1000)
    lay = check_synthesis(t.box_min, t.box_max, 4000, 1800, overlap=0.47, extra=0.5, quality=False)
    assert 2 * lay.overlap < lay.patch


def test_patch_and_extra_beyond_the_exemplar_are_refused_at_parse_time():
    t = point_texture_example("weave", 1000)
    check_synthesis(t.box_min, t.box_max, 4000, 1800, patch=0.75, extra=0.2, quality=False)
    with pytest.raises(ValueError, match="plus its extra region .* use a smaller patch"):
        check_synthesis(t.box_min, t.box_max, 4000, 1800, patch=0.75, extra=0.5, quality=False)


# ------------------------------------------------------------------ point sets


def test_coincident_points_are_merged_and_said(tmp_path, capsys, monkeypatch, one_device):
    t = point_texture_example("weave", 3000)
    twice = np.r_[t.points, t.points]  # every point twice: the spacing was 0 ("negative dimensions")
    path = _write_ply(tmp_path / "dups.ply", twice, np.r_[t.normals, t.normals])
    tex = read_point_texture(path)
    assert tex.merged == len(t) and len(tex) == len(t) and tex.spacing > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pts, _, _ = synthesize_point_texture(tex, scale=0.4, patch=0.5, resolution=16, quality=False,
                                             device=one_device)
    assert len(pts) > 0 and np.isfinite(pts.positions).all()
    # the run says how many it merged (here before refusing an option, to stay fast)
    code, out, err = _run([str(path), "-o", str(tmp_path / "b.ply"), "--overlap", "0.5", "--no-quality"], capsys,
                          monkeypatch, quiet=False)
    assert f"{len(t):,} coincident point(s) merged" in out, out
    assert code == 2 and "Warning" not in err and "--overlap 0.5" in err, err


def test_merging_keeps_the_first_point_and_its_normal():
    p, n = _sheet(100)
    q = np.r_[p, p[:5]]
    m = np.r_[n, -n[:5]]  # the repeats' normals point the other way: the first ones are kept
    tex = texture_from_points(q, m)
    assert tex.merged == 5 and len(tex) == 100
    np.testing.assert_array_equal(tex.points, p)
    np.testing.assert_allclose(tex.normals, n)
    direct = PointTexture(q, m, [0, 0, -0.1], [1, 1, 0.1])
    assert direct.merged == 5 and len(direct) == 100


@pytest.mark.parametrize("case, message", [
    ("same", "1 distinct position"),
    ("few", "holds 10 points"),
    ("line", "lie on one line"),
    ("upright", "span no extent in y"),
    ("nan normal", "NaN"),
    ("nan position", "NaN"),
])
def test_degenerate_point_sets_are_one_line_errors(tmp_path, capsys, monkeypatch, case, message):
    p, n = _sheet(300)
    t = np.linspace(0, 1, 300)
    if case == "same":
        p = np.tile([0.5, 0.5, 0.1], (300, 1))
    elif case == "few":
        p, n = p[:10], n[:10]
    elif case == "line":
        p = np.c_[t, 2 * t, 0.1 * t]
    elif case == "upright":
        p = np.c_[t, np.zeros(300), np.sin(7 * t)]
    elif case == "nan normal":
        n[3] = np.nan
    else:
        p[3, 0] = np.nan
    path = _write_ply(tmp_path / f"{case.replace(' ', '_')}.ply", p, n)
    code, _, err = _run([str(path), "-o", str(tmp_path / "o.ply"), "--no-quality"], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1 and path.name in err and message in err, err


def test_a_flat_plane_is_a_valid_exemplar(one_device):
    rng = np.random.default_rng(1)
    p = np.c_[rng.uniform(-0.25, 1.25, (1500, 2)), np.full(1500, 0.3)]
    tex = texture_from_points(p)  # normals estimated: +z
    assert np.allclose(tex.normals, [0, 0, 1])
    pts, report, _ = synthesize_point_texture(tex, scale=0.8, patch=0.5, resolution=24, quality=False,
                                              device=one_device)
    assert len(pts) > 0 and np.allclose(pts.positions[:, 2], 0.3, atol=1e-4)


# ------------------------------------------------------------------ fuzz


def _mutated(draw_ops, seed: int):
    p, n = _sheet(120, seed)
    for op, a, b in draw_ops:
        k = len(p)
        i, j = int(a * (k - 1)), int(b * (k - 1))
        if op == "dup":  # repeat a run of points
            lo, hi = min(i, j), max(i, j) + 1
            p, n = np.r_[p, p[lo:hi]], None if n is None else np.r_[n, n[lo:hi]]
        elif op == "collinear":
            t = np.linspace(0, 1, k)
            p = np.c_[t, a * t, b * t]
        elif op == "upright":
            p = p.copy()
            p[:, 1] = a
        elif op == "coplanar":
            p = p.copy()
            p[:, 2] = b
        elif op == "nan normal" and n is not None:
            n = n.copy()
            n[i] = np.nan
        elif op == "zero normal" and n is not None:
            n = n.copy()
            n[i] = 0.0
        elif op == "identical":
            p = np.tile(p[i], (k, 1))
        elif op == "truncate":
            p, n = p[: 1 + i // 4], None if n is None else n[: 1 + i // 4]
        elif op == "drop normals":
            n = None
    return p, n


_OPS = st.lists(st.tuples(st.sampled_from(["dup", "collinear", "upright", "coplanar", "nan normal", "zero normal",
                                           "identical", "truncate", "drop normals"]),
                          st.floats(0, 1), st.floats(0, 1)), min_size=1, max_size=3)


# GEOSYNTH_FUZZ_EXAMPLES=1000 for a longer hunt; 60 keeps it ~3 s
@settings(max_examples=int(os.environ.get("GEOSYNTH_FUZZ_EXAMPLES", 60)), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=_OPS, seed=st.integers(0, 3))
def test_fuzzed_point_sets_read_into_a_texture_or_one_line_error(tmp_path, ops, seed):
    p, n = _mutated(ops, seed)
    path = _write_ply(tmp_path / "fuzz.ply", p, n)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # never a NumPy warning
        try:
            tex = read_point_texture(path)
        except ValueError as exc:
            msg = str(exc)
            assert "\n" not in msg and "fuzz.ply" in msg, msg
            assert "negative dimensions" not in msg
            return
        assert len(tex) >= 16 and np.isfinite(tex.points).all() and np.isfinite(tex.normals).all()
        assert np.allclose(np.linalg.norm(tex.normals, axis=1), 1.0)
        assert len(np.unique(tex.points, axis=0)) == len(tex)  # no coincident points left
        assert tex.merged == len(p) - len(tex)
        assert tex.spacing > 0


def test_a_files_padding_is_what_the_border_needs_and_the_rest_is_texture(tmp_path):
    """read_point_texture's default box: 8 mean point spacings a side (the MLS support and
    the warp's reach), at most 20%; a mesh by the spacing of its uniform sample; a given
    padding is kept."""
    import trimesh

    from geosynth.pointtexture.texture import FILE_PADDING_SPACINGS, _area_fixed, file_padding, read_point_texture

    g = np.stack(np.meshgrid(np.arange(200.0), np.arange(100.0), indexing="ij"), -1).reshape(-1, 2) * 0.01
    pts = np.c_[g, 0.02 * np.sin(9 * g[:, 0])]
    pad = file_padding(pts)  # spacing 0.01 over the smaller extent 0.99
    assert abs(pad - FILE_PADDING_SPACINGS * 0.01 / 0.99) < 1e-3
    assert file_padding(pts.reshape(200, 100, 3)[::10, ::10].reshape(-1, 3)) == 0.2  # spacing 0.1: the cap
    path = tmp_path / "grid.ply"
    trimesh.PointCloud(pts).export(path)
    tex = read_point_texture(path)
    lo, hi = pts[:, :2].min(0), pts[:, :2].max(0)
    np.testing.assert_allclose(tex.box_min[:2], lo + pad * (hi - lo), atol=1e-6)
    assert np.allclose(read_point_texture(path, padding=0.2).box_min[:2], lo + 0.2 * (hi - lo), atol=1e-6)
    plane = trimesh.creation.box([2.0, 1.0, 0.01])
    assert abs(_area_fixed(plane) - plane.area) < 1e-12 * plane.area  # (summed in a fixed order)
    # a mesh's B is told to the pre-sampling check with its share of the mesh (no longer 0.36)
    plane.export(tmp_path / "plane.ply")
    seen = []
    tex = read_point_texture(tmp_path / "plane.ply", before_sampling=lambda lo, hi, share: seen.append(share))
    pad = file_padding(plane.vertices, 40_000, _area_fixed(plane))
    assert len(seen) == 1 and abs(seen[0] - (1 - 2 * pad) ** 2) < 1e-9 and seen[0] > 0.36
    assert abs(file_padding(plane.vertices, 40_000, plane.area) - FILE_PADDING_SPACINGS * 0.5 * np.sqrt(plane.area / 40_000)) < 1e-9
