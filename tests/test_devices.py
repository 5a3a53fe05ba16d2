"""The device switch: parsing, listing, resolution, backends."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import geosynth
from conftest import TEST_DEVICES
from geosynth.compute.backend import parse_device, resolve_device


def test_devices_lists_warp_cpu_and_opencl():
    present = geosynth.devices()
    assert present[0] == "cpu"
    # pocl-binary-distribution is a runtime dependency: OpenCL is always present.
    assert any(d.startswith("opencl:") for d in present)


@pytest.mark.parametrize(
    "text, kind, fields",
    [
        ("cpu", "cpu", {}),
        ("auto", "auto", {}),
        ("cuda", "cuda", {"index": 0}),
        ("cuda:3", "cuda", {"index": 3}),
        ("opencl", "opencl", {"platform": None, "device": None}),
        ("opencl:1:2", "opencl", {"platform": 1, "device": 2}),
    ],
)
def test_parse_device(text, kind, fields):
    spec = parse_device(text)
    assert spec.kind == kind
    for key, value in fields.items():
        assert getattr(spec, key) == value


def test_resolve_names_present_devices():
    first_opencl = next(d for d in geosynth.devices() if d.startswith("opencl:"))
    assert resolve_device("opencl") == first_opencl
    assert resolve_device("cpu") == "cpu"
    auto = resolve_device("auto")
    assert auto in geosynth.devices()
    if "cuda:0" in geosynth.devices():
        assert auto == "cuda:0"
    else:  # no GPU: the fastest CPU backend measured by bench/bm_scoring.py is PoCL
        assert auto.startswith("opencl:")


def test_backends_are_cached_and_named(device):
    backend = geosynth.get_backend(device)
    assert backend is geosynth.get_backend(device)
    assert backend.name == resolve_device(device)


def test_round_trip(device, rng):
    for dtype in (np.float32, np.uint8, np.int32, np.uint32, np.int64, np.float64):
        a = (rng.random((7, 5, 3)) * 100).astype(dtype)
        d = geosynth.to_device(a, device)
        assert d.shape == a.shape and d.dtype == a.dtype
        np.testing.assert_array_equal(d.numpy(), a)


def test_to_host_is_a_copy_that_later_kernels_leave_alone(device):
    # (Warp's .numpy() on the CPU is a view of the device memory itself)
    backend = geosynth.get_backend(device)
    cand = backend.to_device(np.arange(12, dtype=np.float32).reshape(4, 3))
    out = backend.empty((4,), np.float32)
    backend.ssd_dense(cand, backend.to_device(np.zeros(3, np.float32)), None, 4, 3, 1, out)
    first = backend.to_host(out)
    backend.ssd_dense(cand, backend.to_device(np.full(3, 100, np.float32)), None, 4, 3, 1, out)
    np.testing.assert_array_equal(first, [5, 50, 149, 302])
    assert not np.array_equal(backend.to_host(out), first)


def test_to_device_refuses_another_devices_array():
    present = geosynth.devices()
    if len(present) < 2:
        pytest.skip("needs two devices")
    d = geosynth.to_device(np.zeros(3, np.float32), present[0])
    with pytest.raises(RuntimeError, match="different devices"):
        geosynth.to_device(d, present[1])


def test_no_top_level_kernels_package():
    """The kernels live in geosynth/kernels/ and import as geosynth.kernels, never as a top-level `kernels`."""
    code = "import importlib.util, sys; sys.path = [p for p in sys.path if p not in ('', '.')]; " \
           "print(importlib.util.find_spec('kernels') is None, importlib.util.find_spec('geosynth.kernels') is not None)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/", check=True)
    assert out.stdout.split() == ["True", "True"]


def test_an_opencl_device_whose_compiler_fails_is_left_out_and_refused(monkeypatch):
    from geosynth.compute import backend

    fake = (
        ("opencl:0:0", "OpenCL PoCL 3.0: pthread-AMD EPYC", "error: unknown target CPU 'generic'"),
        ("opencl:1:0", "OpenCL PoCL 3.1: pthread-skylake-avx512", None),
    )
    monkeypatch.setattr(backend, "_opencl_inventory", lambda: fake)
    assert [d for d in backend.devices() if d.startswith("opencl")] == ["opencl:1:0"]
    assert backend.unusable_devices() == {"opencl:0:0": "error: unknown target CPU 'generic'"}
    assert resolve_device("opencl") == "opencl:1:0"  # the first usable one
    with pytest.raises(RuntimeError, match="unknown target CPU 'generic'"):
        resolve_device("opencl:0:0")
    assert any("UNUSABLE" in desc for _, desc in backend.describe_devices())
    monkeypatch.setattr(backend, "_opencl_inventory", lambda: fake[:1])
    with pytest.raises(RuntimeError, match="no usable OpenCL device"):
        resolve_device("opencl")


BROKEN_PROGRAM = r"""
import json, sys
from geosynth.compute import backend
from geosynth._backends import opencl_backend
from geosynth.cli import main

read = opencl_backend._read_source
opencl_backend._read_source = lambda name: (
    "__kernel void broken(__global float *out) { out[0] = not_declared; }" if name == "broken.cl" else read(name))
opencl_backend.PROGRAMS = (("broken", False),) + opencl_backend.PROGRAMS  # first: nothing else is built
first = dict(backend.unusable_devices())
backend._opencl_inventory.cache_clear()  # a second look reads the memo, builds nothing
opencl_backend.build_all = lambda p, i: sys.exit("built again")
print(json.dumps([backend.devices(), first, backend.unusable_devices()]))
main(["devices"])
"""


def test_an_opencl_device_that_fails_a_program_is_unusable_with_its_message(tmp_path):
    """A program its compiler rejects (planted in the program list, in a subprocess with its
    own PoCL cache and memo) makes each OpenCL device unusable: left out of devices(), the
    failing program and the compiler's message in unusable_devices() and `geosynth devices`,
    remembered for the next look."""
    import json

    opencl = [d for d in TEST_DEVICES if d.startswith("opencl")]
    if not opencl:
        pytest.skip(f"no OpenCL test device ({TEST_DEVICES})")
    env = {k: v for k, v in os.environ.items() if k != "GEOSYNTH_VERBOSE"}  # no runtime's messages on stdout
    env.update(POCL_CACHE_DIR=str(tmp_path / "pocl"), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    out = subprocess.run([sys.executable, "-c", BROKEN_PROGRAM], capture_output=True, text=True, env=env,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    listing = next(ln for ln in out.stdout.splitlines() if ln.startswith("[["))
    report = out.stdout.split(listing, 1)[1]
    present, first, again = json.loads(listing)
    for name in opencl:
        assert name not in present
        assert first[name].startswith("broken.cl: error") and "not_declared" in first[name], first[name]
        assert again[name] == first[name]
        line = next(ln for ln in report.splitlines() if ln.split()[:1] == [name])
        assert "UNUSABLE" in line and "broken.cl: error" in line and "not_declared" in line, report
    assert (tmp_path / "xdg" / "geosynth" / "opencl-devices.json").is_file()


def test_every_program_builds_on_the_test_devices(device):
    """The suite's OpenCL devices build every program, in the one context their backend uses."""
    if not device.startswith("opencl"):
        pytest.skip(f"{device} is a Warp device: Warp builds its kernels per module, at first launch")
    from geosynth._backends import opencl_backend

    _, p, i = device.split(":")
    opencl_backend.build_all(int(p), int(i))
    _, context, programs = opencl_backend.device_context(int(p), int(i))
    assert set(programs) == set(opencl_backend.PROGRAMS)
    import pyopencl as cl

    for key, program in programs.items():  # a driver's cache can hand back a program without kernels
        assert program.get_info(cl.program_info.KERNEL_NAMES), key
    backend = geosynth.get_backend(device)
    assert backend.context is context and backend._programs is programs  # built once per context


def test_the_program_list_names_every_kernel_source():
    from importlib import resources

    from geosynth._backends import opencl_backend

    sources = {f.name[:-3] for f in resources.files("geosynth.kernels").iterdir() if f.name.endswith(".cl")}
    assert sources == {family for family, _ in opencl_backend.PROGRAMS}


def test_pocl_threads_pinned_only_when_every_core_is_ours(monkeypatch):
    """POCL_AFFINITY=1 by default; a user's value is kept; no pinning where the process
    may not run on every core (PoCL would pin its threads to CPUs 0..n-1)."""
    import os

    from geosynth.core import config

    monkeypatch.delenv("POCL_AFFINITY", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 4)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    config.default_pocl_environment()
    assert os.environ["POCL_AFFINITY"] == "1"
    monkeypatch.setenv("POCL_AFFINITY", "0")
    config.default_pocl_environment()
    assert os.environ["POCL_AFFINITY"] == "0"
    monkeypatch.delenv("POCL_AFFINITY")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {2, 3})
    config.default_pocl_environment()
    assert "POCL_AFFINITY" not in os.environ


def test_a_program_without_kernels_is_a_build_error(monkeypatch):
    """A driver that hands back a program without kernels (PoCL's cache after a build that
    died in code generation) is a ProgramBuildError naming the cache, not an
    INVALID_KERNEL_NAME at the first launch."""
    opencl = [d for d in TEST_DEVICES if d.startswith("opencl")]
    if not opencl:
        pytest.skip(f"no OpenCL test device ({TEST_DEVICES})")
    from geosynth._backends import opencl_backend

    _, p, i = opencl[0].split(":")
    _, context, _ = opencl_backend.device_context(int(p), int(i))
    monkeypatch.setattr(opencl_backend, "_read_source", lambda name: "// no kernel here\n")
    with pytest.raises(opencl_backend.ProgramBuildError, match=r"^ssd\.cl: .*without kernels.*cache") as err:
        opencl_backend.build_program(context, "ssd", False)
    assert "\n" not in str(err.value)
