"""Bad input: one assertion each, every error names the argument at fault."""

from __future__ import annotations

import numpy as np
import pytest

import geosynth
from conftest import TEST_DEVICES
from geosynth.compute.backend import resolve_device

X = np.zeros((10, 4), np.float32)
Q = np.zeros((2, 4), np.float32)
GRID = np.zeros((8, 8, 8), np.uint8)
OFF = np.array([[0, 0, 0], [1, 1, 1]])
VALS = np.zeros(2, np.uint8)
RNG = np.random.default_rng(14)


def test_score_dense_invalid_input(device):
    with pytest.raises(ValueError, match="candidates must have 2 dimensions"):
        geosynth.score_dense(np.zeros(10, np.float32), Q, device=device)
    with pytest.raises(ValueError, match=r"queries must have shape \(B, 4\)"):
        geosynth.score_dense(X, np.zeros((2, 5), np.float32), device=device)
    with pytest.raises(TypeError, match="candidates has unsupported dtype int64"):
        geosynth.score_dense(X.astype(np.int64), Q, device=device)
    with pytest.raises(TypeError, match="queries has dtype float32 but candidates is uint8"):
        geosynth.score_dense(X.astype(np.uint8), Q, device=device)
    with pytest.raises(ValueError, match="queries contains 1 NaN or inf"):
        geosynth.score_dense(X, np.array([[0, np.nan, 0, 0]], np.float32), device=device)
    with pytest.raises(ValueError, match="queries contains 1 NaN or inf"):
        geosynth.score_dense(X, np.array([[0, np.inf, 0, 0]], np.float32), device=device)
    with pytest.raises(ValueError, match="candidates contains"):
        geosynth.score_dense(np.full((3, 4), np.nan, np.float32), Q, device=device)
    with pytest.raises(ValueError, match="candidates is empty"):
        geosynth.score_dense(np.zeros((0, 4), np.float32), Q, device=device)
    with pytest.raises(ValueError, match="queries is empty"):
        geosynth.score_dense(X, np.zeros((0, 4), np.float32), device=device)
    with pytest.raises(ValueError, match=r"weights must have shape \(4,\)"):
        geosynth.score_dense(X, Q, np.ones(3), device=device)
    with pytest.raises(ValueError, match="weights must be non-negative"):
        geosynth.score_dense(X, Q, np.array([1, -1, 1, 1.0]), device=device)
    with pytest.raises(TypeError, match="weights has dtype float64: uint8 data is scored exactly"):
        geosynth.score_dense(X.astype(np.uint8), Q.astype(np.uint8), np.ones(4), device=device)
    with pytest.raises(ValueError, match="beyond uint32"):
        geosynth.score_dense(X.astype(np.uint8), Q.astype(np.uint8), np.full(4, 20_000), device=device)
    # float32 scores that could overflow to inf: refused, host or DeviceArray inputs alike
    big = RNG.random((10, 4)).astype(np.float32) * np.float32(1e30)
    overflow = (r"candidates and queries span values from .* could reach .* beyond float32's largest value "
                r".* divide it by 1e\+12")
    with pytest.raises(ValueError, match=overflow):
        geosynth.score_dense(big, Q, device=device)
    with pytest.raises(ValueError, match=overflow):
        geosynth.score_dense(geosynth.to_device(big, device), geosynth.to_device(Q, device))
    with pytest.raises(ValueError, match=r"total weight 4e\+38.*or use smaller weights"):
        geosynth.score_dense(np.ones((10, 4), np.float32), Q, np.full(4, 1e38, np.float32), device=device)
    # DeviceArrays are checked too: recorded by to_device, or read back once when made otherwise
    with pytest.raises(ValueError, match="candidates contains 12 NaN or inf"):
        geosynth.score_dense(geosynth.to_device(np.full((3, 4), np.nan, np.float32), device), Q)
    with pytest.raises(ValueError, match="queries contains 1 NaN or inf"):
        geosynth.score_dense(X, geosynth.to_device(np.array([0, 0, np.inf, 0], np.float32), device))
    with pytest.raises(ValueError, match="candidates contains 1 NaN or inf"):
        raw = geosynth.get_backend(device).to_device(np.array([[0, 0, 0, np.inf]], np.float32))
        geosynth.score_dense(raw, Q)


def test_score_dense_accepts_a_1d_device_query(device):
    x = RNG.random((50, 4)).astype(np.float32)
    q = RNG.random(4).astype(np.float32)
    want = geosynth.score_dense(x, q, device=device)
    got = geosynth.score_dense(geosynth.to_device(x, device), geosynth.to_device(q, device))
    assert got.shape == (50,)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(want, ((x - q) ** 2).sum(1), rtol=1e-6)


def test_score_gather_invalid_input(device):
    with pytest.raises(ValueError, match=r"offsets must have shape \(K, 2\) or \(K, 3\)"):
        geosynth.score_gather(GRID, np.zeros((2, 4), int), VALS, device=device)
    with pytest.raises(ValueError, match="offsets is empty"):
        geosynth.score_gather(GRID, np.zeros((0, 3), int), VALS[:0], device=device)
    with pytest.raises(TypeError, match="offsets must be integers"):
        geosynth.score_gather(GRID, OFF + 0.5, VALS, device=device)
    with pytest.raises(ValueError, match="grid must have 3 or 4 dimensions"):
        geosynth.score_gather(np.zeros((8, 8), np.uint8), OFF, VALS, device=device)
    with pytest.raises(TypeError, match="grid has unsupported dtype int32"):
        geosynth.score_gather(GRID.astype(np.int32), OFF, VALS, device=device)
    with pytest.raises(ValueError, match=r"values must have shape \(2, 1\) or \(2,\)"):
        geosynth.score_gather(GRID, OFF, np.zeros(3, np.uint8), device=device)
    with pytest.raises(ValueError, match="values contains 1 NaN"):
        geosynth.score_gather(GRID.astype(np.float32), OFF, np.array([0, np.nan], np.float32), device=device)
    with pytest.raises(ValueError, match="offsets reach outside the grid .* first origins\\[1\\] = \\(7, 0, 0\\)"):
        geosynth.score_gather(GRID, OFF, VALS, origins=np.array([[0, 0, 0], [7, 0, 0]]), device=device)
    with pytest.raises(ValueError, match="origins is empty"):
        geosynth.score_gather(GRID, OFF, VALS, origins=np.zeros((0, 3), int), device=device)
    with pytest.raises(ValueError, match="no valid candidate"):
        geosynth.score_gather(GRID, np.array([[0, 0, 0], [9, 0, 0]]), VALS, device=device)
    with pytest.raises(ValueError, match="stride must be a positive integer"):
        geosynth.score_gather(GRID, OFF, VALS, stride=0, device=device)
    fgrid = GRID.astype(np.float32)
    overflow = r"grid and values span values from .* beyond float32's largest value"
    with pytest.raises(ValueError, match=overflow):
        geosynth.score_gather(fgrid + np.float32(1e30), OFF, np.zeros(2, np.float32), device=device)
    with pytest.raises(ValueError, match=overflow):
        geosynth.score_gather(geosynth.to_device(fgrid + np.float32(1e30), device), OFF, np.zeros(2, np.float32))
    with pytest.raises(ValueError, match=overflow):
        geosynth.score_gather(fgrid, OFF, np.array([0, -1e30], np.float32), device=device)
    with pytest.raises(ValueError, match="total weight 2e\\+38"):
        geosynth.score_gather(fgrid + 1, OFF, np.zeros(2, np.float32), np.full(2, 1e38), device=device)
    with pytest.raises(ValueError, match="grid contains 1 NaN or inf"):
        nan_grid = fgrid.copy()
        nan_grid[3, 3, 3] = np.nan
        geosynth.score_gather(geosynth.to_device(nan_grid, device), OFF, np.zeros(2, np.float32))


def test_argmin_invalid_input(device):
    """NaN or inf scores never give an index: the host check, scores uploaded by to_device
    (their recorded stats) and scores the device reduces itself all refuse them alike."""
    backend = geosynth.get_backend(device)
    msg = "scores contains NaN or inf; every score must be finite"
    inf_all = np.full(10, np.inf, np.float32)
    with pytest.raises(ValueError, match=msg):
        geosynth.argmin(inf_all, device=device)  # host scores
    with pytest.raises(ValueError, match=msg):
        geosynth.argmin(geosynth.to_device(inf_all, device))  # recorded stats
    for n in (10, 70_000):  # reduced on the host side of the backend, and by the partials kernel
        for bad in (np.inf, np.nan):
            for where in (0, n // 2, n - 1):
                scores = np.arange(n, dtype=np.float32)
                scores[where] = bad
                with pytest.raises(ValueError, match=msg):
                    geosynth.argmin(backend.to_device(scores))  # not checked on the host
        with pytest.raises(ValueError, match=msg):
            geosynth.argmin(backend.to_device(np.full(n, np.inf, np.float32)))
    with pytest.raises(ValueError, match=msg):
        geosynth.within_tolerance(backend.to_device(np.r_[np.ones(99, np.float32), np.float32(np.inf)]), 0.1)
    with pytest.raises(ValueError, match=msg):
        geosynth.best_fraction(backend.to_device(np.r_[np.ones(99, np.float32), np.float32(np.nan)]), 0.5)
    with pytest.raises(ValueError, match="scores must be non-negative"):
        geosynth.argmin(geosynth.to_device(np.array([1, -1], np.float32), device))
    # finite scores still select as before on every path
    scores = np.array([3, 1, 2, 1], np.float32)
    assert geosynth.argmin(scores, device=device) == 1
    assert geosynth.argmin(backend.to_device(scores)) == 1
    assert geosynth.argmin(backend.to_device(np.r_[np.ones(70_000, np.float32), np.float32(0)])) == 70_000


def test_selection_invalid_input(device):
    with pytest.raises(ValueError, match="scores is empty"):
        geosynth.argmin(np.zeros(0, np.float32), device=device)
    with pytest.raises(ValueError, match="scores must be 1-D"):
        geosynth.argmin(np.zeros((3, 3), np.float32), device=device)
    with pytest.raises(ValueError, match="scores contains NaN"):
        geosynth.argmin(np.array([1, np.nan], np.float32), device=device)
    with pytest.raises(TypeError, match="scores has dtype int64"):
        geosynth.argmin(np.array([1, 2]), device=device)
    with pytest.raises(ValueError, match="eps must be a finite number >= 0"):
        geosynth.within_tolerance(np.ones(3, np.float32), -0.1, device=device)
    with pytest.raises(ValueError, match=r"fraction must be in \(0, 1\]"):
        geosynth.best_fraction(np.ones(3, np.float32), 0.0, device=device)
    with pytest.raises(ValueError, match="indices must be a non-empty 1-D array"):
        geosynth.random_pick(np.array([], np.int64), seed=0)


def test_unknown_and_absent_devices():
    for bad in ["gpu", "cuda:x", "opencl:1", "", "CPU0"]:
        with pytest.raises(ValueError, match="Malformed device"):
            geosynth.score_dense(X, Q, device=bad)
    with pytest.raises(ValueError, match="device must be a string"):
        geosynth.get_backend(0)
    for absent in ["cuda:7", "opencl:9:0", "opencl:0:9"]:
        with pytest.raises(RuntimeError, match=r"is not present.*Present devices: .*cpu"):
            geosynth.score_dense(X, Q, device=absent)


def test_inputs_on_different_devices(device_pair):
    a, b = device_pair
    xd = geosynth.to_device(X, a)
    with pytest.raises(RuntimeError, match="inputs live on"):
        geosynth.score_dense(xd, geosynth.to_device(Q, b))
    with pytest.raises(RuntimeError, match="inputs live on"):
        geosynth.score_dense(xd, Q, device=b)
    with pytest.raises(RuntimeError, match="inputs live on"):
        geosynth.score_dense(geosynth.to_device(X, b), geosynth.to_device(Q, a))


def test_synthesize_volume_invalid_input():
    """Every option is checked before any work: no truncation, no constant fields."""
    from geosynth.volume.synthesis import synthesize_volume

    source = RNG.standard_normal((16, 16, 16)).astype(np.float32)

    def run(**options):
        synthesize_volume(source, **{"size": 16, "levels": 1, "block": 8, "progress": False, **options})

    band = r"band must be a finite number from 1e-15 to 1e\+15"
    cases = [
        (ValueError, band, dict(band=0)),
        (ValueError, band, dict(band=-1)),
        (ValueError, band, dict(band=np.nan)),
        (ValueError, band, dict(band=np.inf)),
        (TypeError, "band must be a number", dict(band="4")),
        (TypeError, r"levels must be an integer from 1 to 4, got 1.5", dict(levels=1.5)),
        (ValueError, r"levels must be an integer from 1 to 4 \(each level halves the source", dict(levels=0)),
        (ValueError, r"levels must be an integer from 1 to 4 .*got 5", dict(levels=5)),
        (TypeError, "levels must be an integer", dict(levels=True)),
        (TypeError, r"block must be an integer \(a power of two >= 2\) or one per level, got 8.5", dict(block=8.5)),
        (TypeError, "block must be an integer", dict(block=[4, 8.0], levels=2)),
        (ValueError, "block must be one size or one per level", dict(block=[4, 8, 8], levels=2)),
        (ValueError, "block sizes must be powers of two", dict(block=6)),
        (TypeError, r"size must be a positive integer or three of them \(z, y, x\), got 8.5", dict(size=8.5)),
        (TypeError, "size must be a positive integer or three", dict(size=(16, 16))),
        (TypeError, "size must be a positive integer or three", dict(size=(16, 16, 16.5))),
        (ValueError, "size must be a positive integer or three", dict(size=0)),
        (ValueError, "seed must be an integer >= 0, got -1", dict(seed=-1)),
        (TypeError, "seed must be an integer >= 0, got 1.5", dict(seed=1.5)),
        (TypeError, "tileable must be True or False, got 'no'", dict(tileable="no")),
        (TypeError, "progress must be True or False", dict(progress=None)),
        (TypeError, "baseline must be True or False", dict(baseline=1)),
        (ValueError, r"spacing must be a finite number from 1e-15 to 1e\+15", dict(spacing=0)),
        (ValueError, "spacing must be a finite number", dict(spacing=np.nan)),
        (ValueError, "Malformed device 'gpu'", dict(device="gpu")),
        (ValueError, "search must be one of cascade, tree, linear, got 'fast'", dict(search="fast")),
    ]
    for error, match, options in cases:
        with pytest.raises(error, match=match):
            run(**options)
    with pytest.raises(ValueError, match=r"source is empty"):
        synthesize_volume(np.zeros((0, 16, 16), np.float32), 16, levels=1, block=8, progress=False)


def test_synthesize_geometry_invalid_input():
    from geosynth.volume.synthesis import synthesize_geometry

    def run(**options):
        synthesize_geometry("terrain", **{"size": 32, "progress": False, **options})

    cases = [
        (TypeError, r"size must be a positive integer or three of them \(z, y, x\), got 8.5", dict(size=8.5)),
        (ValueError, "size must be a positive integer", dict(size=-4)),
        (ValueError, "source_resolution must be an integer >= 8, got 7", dict(source_resolution=7)),
        (TypeError, "source_resolution must be an integer >= 8, got 32.0", dict(source_resolution=32.0)),
        (TypeError, "levels must be an integer from 1 to 6, got 1.5", dict(levels=1.5)),
        (ValueError, r"levels must be an integer from 1 to 6 \(each level halves the source of "
                     r"source_resolution=64 samples\), got 7", dict(levels=7)),
        (TypeError, "block must be an integer", dict(block=8.5)),
        (TypeError, "tileable must be True or False", dict(tileable="yes")),
        (ValueError, "seed must be an integer >= 0", dict(seed=-3)),
        (ValueError, "Malformed device", dict(device="cuda:x")),
        (ValueError, "search must be one of", dict(search=None)),
        (ValueError, "smooth must be an integer >= 0, got -1", dict(smooth=-1)),
        (TypeError, "smooth must be an integer >= 0, got 2.5", dict(smooth=2.5)),
        (ValueError, "quality_samples must be an integer >= 0, got -1", dict(quality_samples=-1)),
        (TypeError, "quality_samples must be an integer >= 0, got 1.5", dict(quality_samples=1.5)),
        (TypeError, "progress must be True or False", dict(progress="no")),
    ]
    for error, match, options in cases:
        with pytest.raises(error, match=match):
            run(**options)


def test_estimate_normals_invalid_input():
    from geosynth.geometry.pointsets import estimate_normals

    plane = np.c_[RNG.random((60, 2)), np.zeros(60)]
    with pytest.raises(ValueError, match="points: all 10 points coincide, so no point has a defined normal"):
        estimate_normals(np.ones((10, 3)))
    with pytest.raises(ValueError, match=r"points: 20 of 80 points have no defined normal \(first at index 60\): "
                                         r"their k=16 nearest neighbours .* coincide or lie on one line"):
        estimate_normals(np.r_[plane, np.full((20, 3), 5.0)])  # a cluster of 20 copies of one point
    with pytest.raises(ValueError, match=r"10 of 10 points have no defined normal .*lie on one line"):
        estimate_normals(np.c_[np.arange(10.0), 2 * np.arange(10.0), np.zeros(10)])
    with pytest.raises(ValueError, match="at least 3 points"):
        estimate_normals(plane[:2])
    with pytest.raises(ValueError, match="k must be an integer >= 3"):
        estimate_normals(plane, k=2)
    with pytest.raises(ValueError, match="points contains 1 NaN"):
        estimate_normals(np.r_[plane, [[np.nan, 0, 0]]])
    np.testing.assert_allclose(np.abs(estimate_normals(plane)), np.tile([0, 0, 1], (60, 1)), atol=1e-6)


def test_pointset_distance_invalid_input(device):
    from geosynth.geometry.pointsets import pointset_distance, project_points, smallest_radius

    g = np.stack(np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1, 1, 21)), -1).reshape(-1, 2)
    pts = np.c_[g, np.zeros(len(g))]
    nrm = np.tile([0, 0, 1.0], (len(pts), 1))
    q = [[0.0, 0.0, 0.05]]
    assert smallest_radius(pts) == 2 * 2.0**-16
    small = r"radius 1e-07 is too small for points spanning 2: .*the smallest radius that works is 3.05176e-05"
    with pytest.raises(ValueError, match=small):
        pointset_distance(pts, nrm, q, radius=1e-7, device=device)
    with pytest.raises(ValueError, match="radius 1e-300 is too small"):
        pointset_distance(pts, nrm, resolution=8, radius=1e-300, device=device)
    with pytest.raises(ValueError, match="radius 1e-07 is too small"):
        project_points(pts, nrm, q, radius=1e-7, device=device)
    with pytest.raises(ValueError, match="radius must be a finite number > 0"):
        pointset_distance(pts, nrm, q, radius=np.nan, device=device)
    with pytest.raises(TypeError, match="radius must be a number"):
        pointset_distance(pts, nrm, q, radius="0.1", device=device)
    d, _ = pointset_distance(pts, nrm, q, radius=smallest_radius(pts), device=device)  # the smallest works
    assert np.isfinite(d).all()


def test_mesh_distance_invalid_input(one_device):
    import trimesh

    from geosynth.geometry.meshes import mesh_distance

    box = trimesh.creation.box()
    p = np.zeros((1, 3), np.float32)
    with pytest.raises(TypeError, match="signed must be True or False, got 'no'"):
        mesh_distance(box, p, signed="no", device=one_device)
    with pytest.raises(TypeError, match="drop_degenerate must be True or False, got 1"):
        mesh_distance(box, p, drop_degenerate=1, device=one_device)
    with pytest.raises(TypeError, match="band must be a number"):
        mesh_distance(box, p, band=True, device=one_device)
    with pytest.raises(ValueError, match="band must be a finite number > 0"):
        mesh_distance(box, p, band=0.0, device=one_device)


# ---------------------------------------------------------------------------------- quiet
def _run_python(code: str, env_extra: dict[str, str]) -> "subprocess.CompletedProcess[str]":
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "GEOSYNTH_VERBOSE"}
    env.update(env_extra)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)


QUIET_RUN = """
import numpy as np, geosynth
geosynth.devices()
x = np.ones((10, 4), np.float32)
for dev in DEVICES:
    geosynth.argmin(geosynth.score_dense(x, x[0], device=dev), device=dev)
"""


def _quiet_run(devices) -> str:
    return QUIET_RUN.replace("DEVICES", repr(tuple(devices)))


def test_import_and_devices_print_nothing():
    """The default import, devices() and a kernel on every test device (and on "auto" when
    it picks one of them) are silent (Warp's missing-CUDA-driver warning included);
    GEOSYNTH_VERBOSE=1 lets Warp speak."""
    auto = ("auto",) if resolve_device("auto") in TEST_DEVICES else ()
    r = _run_python(_quiet_run(auto + tuple(TEST_DEVICES)), {})
    assert r.returncode == 0, r.stderr
    assert r.stdout == "" and r.stderr == ""
    if "cuda:0" not in geosynth.devices():  # without a GPU Warp warns about the driver when asked to speak
        r = _run_python("import geosynth; geosynth.devices()", {"GEOSYNTH_VERBOSE": "1"})
        assert "CUDA driver" in r.stdout + r.stderr
        with pytest.raises(RuntimeError, match=r"Device 'cuda:0' is not present \(.*CUDA driver"):
            geosynth.get_backend("cuda:0")


def test_pocl_cache_does_not_grow_on_a_second_run(tmp_path):
    from geosynth.compute.backend import _opencl_status

    cl, _ = _opencl_status()
    names = [p.name for p in cl.get_platforms()] if cl is not None else []
    if "Portable Computing Language" not in names:
        pytest.skip(f"PoCL is not an OpenCL platform here (platforms: {names or 'none'})")
    opencl = [d for d in TEST_DEVICES if d.startswith("opencl")]
    if not opencl:
        pytest.skip(f"no OpenCL test device ({TEST_DEVICES})")
    env = {"POCL_CACHE_DIR": str(tmp_path / "pocl"), "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    code = _quiet_run(opencl)

    def files() -> set[str]:
        return {str(f.relative_to(tmp_path)) for f in (tmp_path / "pocl").rglob("*") if f.is_file()}

    seen = []
    for _ in range(3):
        r = _run_python(code, env)
        assert r.returncode == 0, r.stderr
        seen.append(files())
    assert seen[0]  # the kernels were built and cached there
    assert seen[1] == seen[0] and seen[2] == seen[0], f"new files: {sorted((seen[1] | seen[2]) - seen[0])}"
    assert (tmp_path / "xdg" / "geosynth" / "opencl-devices.json").is_file()  # remembered, not rebuilt
