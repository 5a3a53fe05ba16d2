"""Memory refused up front (geosynth.core.memory): the estimates against measured peaks, and
the refusals (fast, naming the option, with a largest value that really fits).

What is measured, per operation:
- RSS: the high-water mark (VmHWM, the ``ru_maxrss`` of the process, reset before each
  call through /proc/self/clear_refs) minus the resident size just before the call, in a
  fresh subprocess after a tiny warm-up (kernels compiled), glibc told to give large
  blocks back when freed. Used where memory outside NumPy matters: Warp CPU and PoCL
  device buffers (host memory), scipy's and pykdtree's trees.
- tracemalloc: the traced peak of the call (NumPy reports its allocations to it). Used
  where the memory is NumPy's (volume synthesis, geometry, procedural textures).
Each estimate must be within 1.5x of the peak, both ways, on a small and a 4x larger case.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
import tracemalloc

import numpy as np
import pytest

from geosynth.core.memory import (
    ENV_LIMIT, MemoryBudgetError, available_memory, format_bytes, largest_fitting, parse_bytes, require,
)

RATIO = 1.5

_RUNNER = textwrap.dedent('''
    import gc, json, os, resource, sys
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    spec = json.loads(sys.argv[1])
    exec(spec["setup"])
    exec(spec["warmup"])
    def rss():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    from geosynth.core.memory import peak_resident_bytes as high_water
    def reset_high_water():
        try:  # Linux >= 4.0: "5" resets the peak RSS to the current RSS
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")
        except OSError:
            pass
    try:
        import ctypes
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        trim = lambda pad: 0
    out = []
    for case in spec["cases"]:
        # once unmeasured: a kernel the warm-up did not reach is built (a cold PoCL cache
        # compiles it, and LLVM's memory is no part of the operation's peak)
        exec(case["run"])
        exec("result = None")
        gc.collect()
        trim(0)
        reset_high_water()
        base = rss()
        hw0 = high_water()
        exec(case["run"])
        hw1 = high_water()
        out.append({"peak": hw1 - base, "rose": hw1 > hw0, "estimate": eval(case["estimate"])})
        exec("result = None")
    print("RESULT " + json.dumps(out))
''')


def _rss_peaks(setup: str, warmup: str, cases: list[tuple[str, str]]) -> list[dict]:
    """Run ``cases`` ((code, estimate expression)) in a fresh interpreter, in order; each
    gets its RSS high-water delta and its estimate."""
    spec = {"setup": textwrap.dedent(setup), "warmup": warmup,
            "cases": [{"run": run, "estimate": est} for run, est in cases]}
    env = {k: v for k, v in os.environ.items() if k != ENV_LIMIT}
    # glibc: large blocks always mmap'ed and unmapped when freed, so that what an earlier
    # case freed is not reused unseen (the dynamic mmap threshold would keep it)
    env.update(MALLOC_MMAP_THRESHOLD_="65536", MALLOC_TRIM_THRESHOLD_="0")
    proc = subprocess.run([sys.executable, "-c", _RUNNER, json.dumps(spec)], capture_output=True, text=True,
                          timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def _check_ratios(results: list[dict], label: str) -> None:
    for r in results:
        assert r["rose"], f"{label}: the high-water mark did not rise; the measurement says nothing"
        ratio = r["estimate"] / r["peak"]
        assert 1 / RATIO <= ratio <= RATIO, (
            f"{label}: estimate {format_bytes(r['estimate'])} vs measured peak {format_bytes(r['peak'])} "
            f"(ratio {ratio:.2f})")


def _traced_peak(fn) -> tuple[int, object]:
    tracemalloc.start()
    try:
        out = fn()
        return tracemalloc.get_traced_memory()[1], out
    finally:
        tracemalloc.stop()


def _assert_ratio(estimate: int, peak: int, label: str) -> None:
    ratio = estimate / peak
    assert 1 / RATIO <= ratio <= RATIO, f"{label}: estimate {estimate:,} vs peak {peak:,} (ratio {ratio:.2f})"


# ------------------------------------------------------------------ the module itself


def test_parse_and_format_bytes():
    assert parse_bytes("1000") == 1000
    assert parse_bytes("64K") == 64 << 10
    assert parse_bytes("1.5G") == 3 << 29
    assert parse_bytes("2 MiB") == 2 << 20
    for bad in ("", "lots", "-1M", "1X"):
        with pytest.raises(ValueError, match=ENV_LIMIT):
            parse_bytes(bad)
    assert format_bytes(1000) == "1000 B"
    assert format_bytes(1.2 * 2**40) == "1.2 TiB"


def test_available_memory_is_capped_by_the_environment(monkeypatch):
    monkeypatch.delenv(ENV_LIMIT, raising=False)
    real = available_memory()
    assert 0 < real
    monkeypatch.setenv(ENV_LIMIT, "3M")
    assert available_memory() == 3 << 20
    monkeypatch.setenv(ENV_LIMIT, "nonsense")
    with pytest.raises(ValueError, match=ENV_LIMIT):
        available_memory()


def test_require_finds_the_largest_by_bisection():
    def fn(v):
        return 10 * v * v

    require(1000, option="size", value=10, largest_fn=fn, what="x", available=1000)  # fits: no error
    with pytest.raises(MemoryBudgetError) as info:
        require(fn(1000), option="size", value=1000, largest_fn=fn, what="size 1000", available=1000, step=2)
    err = info.value
    assert isinstance(err, MemoryError)
    assert (err.option, err.largest, err.estimate, err.available) == ("size", 10, fn(1000), 1000)
    assert "\n" not in str(err)
    assert str(err) == ("size 1000 needs about 9.5 MiB, more than the 1000 B available; "
                        "lower size to at most 10 (or free memory).")
    with pytest.raises(MemoryBudgetError) as info:
        require(fn(1000), option="count", value=1000, largest_fn=fn, what="c", available=5, smallest=16)
    assert info.value.largest is None and "even the smallest count does not fit" in str(info.value)
    assert largest_fitting(fn, 1000, 1, 1000) == 10


# ------------------------------------------------------------------ estimates vs peaks

_FIELDS_SETUP = """
import trimesh
from geosynth.geometry.meshes import grid_distance_bytes, mesh_distance
from geosynth.texturing.models import point_model
from geosynth.geometry.pointsets import default_radius, grid_mls_bytes, pointset_distance
mesh = trimesh.creation.icosphere(3)
ps = point_model("sphere", 2000)
h = default_radius(ps.positions)
DEVICE = %r
"""


def test_distance_field_estimates_match_rss(device):
    """mesh_distance and pointset_distance on grids of 56^3 and 89^3 (4x): RSS, as the
    device buffers are host memory outside NumPy."""
    cases = []
    for r in (56, 89):
        cases.append((f"result = mesh_distance(mesh, resolution={r}, device=DEVICE)",
                      "grid_distance_bytes(result.shape)"))
        cases.append((f"result = pointset_distance(ps, resolution={r}, device=DEVICE)[0]",
                      "grid_mls_bytes(result.values.size, ps.positions, h)"))
    res = _rss_peaks(_FIELDS_SETUP % device, "mesh_distance(mesh, resolution=8, device=DEVICE); "
                     "pointset_distance(ps, resolution=8, device=DEVICE)", cases)
    _check_ratios(res[0::2], f"mesh_distance on {device}")
    _check_ratios(res[1::2], f"pointset_distance on {device}")


def test_point_model_estimates_match_rss():
    """point_model (blob, the largest per point), 10k and 40k points, and sample_mesh_points,
    25k and 100k points:
    RSS, as scipy's kd-tree is outside NumPy."""
    setup = """
    import trimesh
    from geosynth.texturing.models import POINT_MODELS, point_model, sample_mesh_points, _MESH_SAMPLE_BYTES, _MESH_FACE_BYTES
    mesh = trimesh.creation.icosphere(4)
    """
    cases = []
    for n in (10_000, 40_000):
        cases.append((f"result = point_model('blob', {n})", f"POINT_MODELS['blob'].bytes_per_point * {n}"))
    for n in (25_000, 100_000):
        cases.append((f"result = sample_mesh_points(mesh, {n})",
                      f"_MESH_SAMPLE_BYTES * {n} + _MESH_FACE_BYTES * len(mesh.faces)"))
    res = _rss_peaks(setup, "point_model('blob', 100); sample_mesh_points(mesh, 100)", cases)
    _check_ratios(res[:2], "point_model")
    _check_ratios(res[2:], "sample_mesh_points")


def test_texture_points_estimates_match_rss(device):
    """texture_points: the point work (param, 4k and 16k points, a tiny texture) and the
    texel search (param with the quality numbers, 2k points, m = 8 and 16 on 32^2: 4x the
    supersampled pixels): RSS, as the kernels' buffers and pykdtree's tree are outside NumPy."""
    setup = f"""
    from geosynth.texturing.models import point_model
    from geosynth.texturing.synthesis import texture_bytes, texture_points
    from geosynth.texturing.textures import texture_example
    DEVICE = {device!r}
    tex16, tex32 = texture_example("noise", 16), texture_example("noise", 32)
    models = {{n: point_model("blob", n) for n in (300, 2000, 4000, 16000)}}
    """
    warm = "texture_points(models[300], tex16, method='param', k=9, m=2, device=DEVICE, quality_samples=10)"
    cases = []
    for n in (4000, 16000):
        cases.append((f"result = texture_points(models[{n}], tex16, method='param', quality=False, device=DEVICE)",
                      f"texture_bytes({n}, 16, 16, method='param', quality=False)"))
    for m in (8, 16):
        cases.append((f"result = texture_points(models[2000], tex32, method='param', m={m}, quality_samples=20, "
                      "device=DEVICE)", f"texture_bytes(2000, 32, 32, method='param', m={m})"))
    res = _rss_peaks(setup, warm, cases)
    _check_ratios(res[:2], f"texture_points (points) on {device}")
    _check_ratios(res[2:], f"texture_points (texture) on {device}")


def test_volume_estimate_matches_traced_peak(device):
    """synthesize_volume, targets 8 x 48 x 48 and 8 x 96 x 96: tracemalloc (the target,
    its upsampling and the scan are NumPy; the 16^3 source's device buffers are small)."""
    from geosynth.volume.synthesis import synthesize_volume, volume_bytes

    z, y, x = np.mgrid[:16, :16, :16]
    src = (np.sin(x / 2.5) * np.cos(y / 3.0) * 4 + (z - 8)).astype(np.float32)
    synthesize_volume(src, 16, levels=2, block=8, iterations=2, device=device, progress=False)
    for n in (48, 96):
        peak, res = _traced_peak(lambda: synthesize_volume(src, (8, n, n), levels=2, block=8, iterations=2, device=device,
                                                           progress=False))
        estimate = volume_bytes((8, n, n), src.shape, [lv.block for lv in res.levels], "cascade", True,
                                method=res.method)
        _assert_ratio(estimate, peak, f"synthesize_volume 8 x {n} x {n} on {device}")


@pytest.mark.parametrize("name, kind", [("balls", "elements"), ("terrain", "surface")])
def test_geometry_estimate_matches_traced_peak(warp_cpu, name, kind):
    """synthesize_geometry at source resolution 16, sizes 32 and 64 (4x the samples), with
    the quality numbers and each kind of structure metrics: tracemalloc (fields, marching
    cubes, smoothing and the metrics are NumPy)."""
    from geosynth.volume.examples import exemplar_mesh
    from geosynth.volume.synthesis import _exemplar_grid_geometry, geometry_bytes, synthesize_geometry

    mesh = exemplar_mesh(name, seed=0)
    synthesize_geometry(mesh, 16, source_resolution=16, levels=2, block=8, iterations=2, device=warp_cpu,
                        progress=False, quality_samples=5)
    for n in (32, 64):
        peak, res = _traced_peak(lambda: synthesize_geometry(mesh, n, source_resolution=16, levels=2, block=8,
                                                             iterations=2, device=warp_cpu, progress=False,
                                                             quality_samples=10))
        assert res.quality["synthesis"]["structure"]["kind"] == kind
        shape, _, spacing = _exemplar_grid_geometry(mesh, 16, multiple=2)
        estimate = geometry_bytes(shape, spacing, mesh.area, res.volume.quantized.shape,
                                  [lv.block for lv in res.volume.levels], "cascade", 10, 10, res.method, kind)
        _assert_ratio(estimate, peak, f"synthesize_geometry {name} size {n}")
        # before the exemplar's field is known, the smaller kind's memory is counted
        assert geometry_bytes(shape, spacing, mesh.area, res.volume.quantized.shape,
                              [lv.block for lv in res.volume.levels], "cascade", 10, 10, res.method) <= estimate


@pytest.mark.parametrize("name", ["bricks", "checker", "noise"])
def test_texture_example_estimate_matches_traced_peak(name):
    from geosynth.texturing.textures import TEXTURES, texture_example

    for size in (256, 512):
        peak, _ = _traced_peak(lambda: texture_example(name, size))
        _assert_ratio(TEXTURES[name].bytes_per_texel * size**2 + (64 << 10), peak, f"{name} {size}")


# ------------------------------------------------------------------ refusals


def _refuses(fn, option: str) -> MemoryBudgetError:
    t0 = time.perf_counter()
    with pytest.raises(MemoryBudgetError) as info:
        fn()
    seconds = time.perf_counter() - t0
    err = info.value
    assert seconds < 0.5, f"refusing took {seconds:.2f} s"
    assert err.option == option
    assert err.estimate > err.available
    assert "\n" not in str(err) and option in str(err) and "available" in str(err)
    return err


def _check_refusals(monkeypatch, checks) -> None:
    """Each (option, call, huge value, budget): the huge value is refused quickly, naming
    the option and a largest value, and that largest value runs under the budget."""
    for option, run, huge, budget in checks:
        monkeypatch.setenv(ENV_LIMIT, budget)
        limit = parse_bytes(budget)
        err = _refuses(lambda: run(huge), option)
        assert err.largest is not None and err.available == limit
        largest = err.largest[-1] if isinstance(err.largest, tuple) else err.largest
        assert largest < huge
        run(largest)  # once unmeasured: first-call costs (imports, kernel loading) are not the run's
        peak, _ = _traced_peak(lambda: run(largest))  # the largest really runs under the limit
        assert peak <= limit, f"{option}={err.largest}: traced peak {peak:,} > limit {limit:,}"


def test_device_free_huge_inputs_are_refused_quickly_with_the_largest_that_fits(monkeypatch):
    """The host-only operations (no device argument), once."""
    import trimesh

    from geosynth.texturing.models import point_model, sample_mesh_points
    from geosynth.texturing.textures import texture_example

    mesh = trimesh.creation.icosphere(2)
    _check_refusals(monkeypatch, [
        ("count", lambda v: point_model("sphere", v), 10**9, "8M"),
        ("count", lambda v: sample_mesh_points(mesh, v), 10**9, "8M"),
        ("texture_size", lambda v: texture_example("noise", v), 100_000, "8M"),
    ])


def test_huge_inputs_are_refused_quickly_with_the_largest_that_fits(monkeypatch, device):
    import trimesh

    from geosynth.geometry.meshes import mesh_distance
    from geosynth.geometry.pointsets import pointset_distance
    from geosynth.texturing.models import point_model
    from geosynth.texturing.synthesis import texture_points
    from geosynth.texturing.textures import texture_example
    from geosynth.volume.synthesis import synthesize_geometry, synthesize_volume

    mesh = trimesh.creation.icosphere(2)
    ps = point_model("sphere", 1000)
    tex = texture_example("noise", 16)
    source = np.zeros((16, 16, 16), np.float32) + np.linspace(-4, 4, 16, dtype=np.float32)
    many = point_model("sphere", 50_000)

    # (option, call, huge value, budget): budgets small enough that the largest runs fast
    checks = [
        ("resolution", lambda v: mesh_distance(mesh, resolution=v, device=device), 100_000, "8M"),
        ("resolution", lambda v: pointset_distance(ps, resolution=v, device=device), 100_000, "40M"),
        ("size", lambda v: synthesize_volume(source, v, levels=2, block=8, iterations=2, device=device, progress=False),
         100_000, "4M"),
        ("size", lambda v: synthesize_volume(source, (16, v, v), levels=2, block=8, iterations=2, device=device,
                                             progress=False), 100_000, "4M"),
    ]
    _check_refusals(monkeypatch, checks)

    # synthesize_geometry names size, or source_resolution when no size fits
    monkeypatch.setenv(ENV_LIMIT, "4M")
    err = _refuses(lambda: synthesize_geometry(mesh, 100_000, source_resolution=16, levels=2, block=8, iterations=2,
                                               device=device, progress=False), "size")
    assert err.largest is not None and err.largest % 2 == 0 and err.largest < 100_000
    err = _refuses(lambda: synthesize_geometry(mesh, 16, source_resolution=100_000, levels=2, block=8, iterations=2,
                                               device=device, progress=False), "source_resolution")
    assert err.largest is not None and 8 <= err.largest < 100_000
    # the largest that fits does fit, quality numbers and structure metrics included
    fits = lambda: synthesize_geometry(mesh, 16, source_resolution=err.largest, levels=2, block=8,  # noqa: E731
                                       iterations=2, device=device, progress=False, quality_samples=5)
    fits()  # once unmeasured: the metrics' first imports are not the run's
    peak, _ = _traced_peak(fits)
    assert peak <= 4 << 20

    # texture_points: a huge texture names texture_size; many points name count
    monkeypatch.setenv(ENV_LIMIT, "64M")
    big = np.zeros((4096, 4096, 3), np.uint8)
    err = _refuses(lambda: texture_points(ps, big, method="param", device=device), "texture_size")
    assert err.largest is not None and err.largest < 4096
    err = _refuses(lambda: texture_points(many, tex, method="match", device=device), "count")
    assert err.largest is not None and err.largest < len(many)
