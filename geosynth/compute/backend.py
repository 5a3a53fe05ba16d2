"""Which backend runs a device string? Implements no paper section: every method's kernels
run through it.

The device switch: device strings -> backend objects.

Every public operation of geosynth takes ``device=``. This module resolves that
string once and returns a backend; the two backends (Warp, OpenCL) expose the same
methods with the same arguments and results, so nothing above them branches on
the device.

Device strings:

- ``"cpu"``: Warp on the CPU (one thread).
- ``"cuda"`` / ``"cuda:N"``: Warp on an NVIDIA GPU.
- ``"opencl"`` / ``"opencl:P:D"``: PyOpenCL, platform P, device D (``"opencl"`` is
  the first usable OpenCL device; on a machine with no GPU that is PoCL). An OpenCL
  device whose compiler cannot build every geosynth program (PyPI's PoCL 3.0 with LLVM 14
  on a CPU that LLVM 14 does not know, such as AMD Zen 5) is not usable: ``devices()`` leaves it
  out, ``describe_devices()`` shows it with the compiler's reason, and asking for it is
  a RuntimeError with that reason.
- ``"auto"``: the first CUDA GPU if present, else the fastest CPU backend as
  measured by ``bench/bm_scoring.py`` (OpenCL on PoCL, which uses every core),
  else Warp's ``cpu``.

A malformed string raises ValueError; a well-formed string naming a device that is
not present raises RuntimeError listing what is present. There is never a silent
fallback from one device to another.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform as _platform
import re
import sys
import tempfile
from dataclasses import dataclass
from typing import Any

import numpy as np

from geosynth.core.arrays import DeviceArray, float_stats
from geosynth.core.config import WARP_INIT_NOTES, cache_root, default_pocl_environment, pocl_settings, verbose

__all__ = ["devices", "get_backend", "parse_device", "to_device"]

_DEVICE_RE = re.compile(r"^(auto|cpu|cuda(?::(\d+))?|opencl(?::(\d+):(\d+))?)$")


@dataclass(frozen=True)
class DeviceSpec:
    """A parsed device string: ``kind`` is auto, cpu, cuda or opencl."""

    kind: str
    index: int | None = None  # cuda ordinal
    platform: int | None = None  # opencl platform index
    device: int | None = None  # opencl device index within the platform


def parse_device(device: str) -> DeviceSpec:
    """Parse a device string without touching any runtime.

    Args:
        device: one of ``"auto"``, ``"cpu"``, ``"cuda"``, ``"cuda:N"``,
            ``"opencl"``, ``"opencl:P:D"``.

    Returns:
        The parsed DeviceSpec.

    Raises:
        ValueError: if ``device`` is not a string of that form.
    """
    if not isinstance(device, str):
        raise ValueError(f"device must be a string such as 'cpu', 'cuda:0', 'opencl:0:0' or 'auto', got {device!r}.")
    m = _DEVICE_RE.match(device.strip().lower())
    if m is None:
        raise ValueError(
            f"Malformed device {device!r}: expected 'auto', 'cpu', 'cuda', 'cuda:N', 'opencl' or 'opencl:P:D'."
        )
    text = m.group(1)
    if text.startswith("cuda"):
        return DeviceSpec("cuda", index=int(m.group(2)) if m.group(2) is not None else 0)
    if text.startswith("opencl"):
        if m.group(3) is None:  # the first usable OpenCL device, chosen by resolve_device
            return DeviceSpec("opencl")
        return DeviceSpec("opencl", platform=int(m.group(3)), device=int(m.group(4)))
    return DeviceSpec(text)


# ----------------------------------------------------------------------------------
# Optional runtimes, imported lazily; their import errors surface only when asked for.


# Lines that Warp's native init wrote to stderr and that were held back (the missing CUDA
# driver on a machine without a GPU); asking for a CUDA device shows them in its error.


def _capture_native_stderr(fn) -> str:
    """Run ``fn()`` with file descriptor 2 sent to a temporary file; return what it got.

    Warp's native init prints with C ``fprintf(stderr)``, which no Python setting silences.
    """
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable fd 2: nothing to capture
        fn()
        return ""
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            fn()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        tmp.seek(0)
        return tmp.read().decode("utf-8", "replace")


@functools.lru_cache(maxsize=1)
def _warp_status() -> tuple[Any, Exception | None]:
    try:
        import warp as wp

        if verbose():
            wp.init()
            return wp, None
        # Warp 1.19 replaced `config.quiet` with `config.log_level`; keep both quiet.
        if hasattr(wp, "LOG_WARNING"):
            wp.config.log_level = wp.LOG_WARNING
        else:
            wp.config.quiet = True
        said = _capture_native_stderr(wp.init)
        # Without a GPU, the CUDA driver probe's warning is expected: hold it back. Anything
        # else Warp says at init is passed on.
        for line in said.splitlines():
            if "NVIDIA CUDA driver" in line:
                WARP_INIT_NOTES.append(line.strip())
            elif line.strip():
                print(line, file=sys.stderr)
        return wp, None
    except Exception as exc:  # ImportError, or a broken install
        return None, exc


def warp_module():
    """Warp, initialized quietly as every backend here does (the host steps' way in:
    :mod:`geosynth.compute.host_steps`); a broken install raises a RuntimeError saying why."""
    wp, err = _warp_status()
    if wp is None:  # Warp is a dependency: a broken install is an error, never skipped
        raise RuntimeError(f"Warp failed to load ({err}); reinstall warp-lang (make test builds .venv with it).")
    return wp


@functools.lru_cache(maxsize=1)
def _opencl_status() -> tuple[Any, Exception | None]:
    try:
        default_pocl_environment()
        import pyopencl as cl

        cl.get_platforms()
        return cl, None
    except Exception as exc:  # ImportError, or no ICD loader / no platform
        return None, exc


def _warp_device_names() -> list[str]:
    wp, _ = _warp_status()
    if wp is None:
        return []
    return [str(d) for d in wp.get_devices()]


def _probe_memo_path() -> str:
    return os.path.join(cache_root(), "opencl-devices.json")


def _probe_key(platform, dev, programs: str) -> str:
    """What decides whether a device builds geosynth's programs: the driver, the device,
    this CPU, PoCL's settings (not where it caches) and the programs (``programs``: their
    digest)."""
    cpu = _platform.processor()
    try:
        with open("/proc/cpuinfo") as fh:  # the first processor's identity and features
            first = fh.read().split("\n\n", 1)[0]
        cpu = [ln for ln in first.splitlines() if ln.split(":", 1)[0].strip() in
               ("vendor_id", "cpu family", "model", "model name", "flags")]
    except OSError:
        pass
    env = pocl_settings()
    parts = [platform.name, platform.version, dev.name, dev.version, dev.driver_version, _platform.machine(), cpu, env,
             programs]
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()[:32]


def _read_probe_memo() -> dict[str, str]:
    try:
        with open(_probe_memo_path()) as fh:
            memo = json.load(fh)
        return {str(k): str(v) for k, v in memo.items()} if isinstance(memo, dict) else {}
    except (OSError, ValueError):
        return {}


def _write_probe_memo(memo: dict[str, str]) -> None:
    """Best effort: a cache that cannot be written only means building again next run."""
    try:
        os.makedirs(cache_root(), exist_ok=True)
        tmp = f"{_probe_memo_path()}.{os.getpid()}.tmp"
        with open(tmp, "w") as fh:
            json.dump(memo, fh)
        os.replace(tmp, _probe_memo_path())
    except OSError:
        pass


def _build_programs(p: int, i: int) -> str | None:
    """Build every geosynth program for OpenCL device ``i`` of platform ``p``: None, or the
    first failing program and its compiler's first error."""
    from geosynth._backends import opencl_backend  # imports pyopencl: only once OpenCL loaded

    try:
        opencl_backend.build_all(p, i)
    except opencl_backend.ProgramBuildError as exc:
        return str(exc)
    except Exception as exc:  # no context for the device, or the driver failed otherwise
        return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:300]
    return None


@functools.lru_cache(maxsize=1)
def _opencl_inventory() -> tuple[tuple[str, str, str | None], ...]:
    """Every OpenCL device as ``(name, description, why_unusable or None)``.

    A device is usable only if its compiler builds every geosynth program
    (``geosynth._backends.opencl_backend.PROGRAMS``): an ICD can list a CPU that its
    compiler cannot target (PyPI's PoCL 3.0 with LLVM 14 on AMD Zen 5), or a compiler can
    reject what the programs use (clang's vector extensions). The outcome is remembered
    per machine (``~/.cache/geosynth/opencl-devices.json``, keyed by driver, device, CPU,
    PoCL settings and the programs' sources and options), so that each process need not
    build them all: warm in PoCL's cache that still took 0.39-0.59 s (0.17-0.28 s of CPU)
    per device here (PoCL 3.1, 2 shared cores), against 6 ms to read the memo; and a failed
    build, which PoCL does not cache, leaves three temporary files in its cache folder each
    time. The programs built here are kept in the device's context for its backend. Delete
    that file to check the devices anew.
    """
    cl, _ = _opencl_status()
    if cl is None:
        return ()
    memo = _read_probe_memo()
    memo_changed = False
    programs = None
    out = []
    for p, platform in enumerate(cl.get_platforms()):
        try:
            devs = platform.get_devices()
        except Exception:  # a platform with no devices raises on some ICDs
            continue
        version = platform.version.strip().split("  ")[0]  # "OpenCL 3.0 PoCL 3.1+debian"
        for i, dev in enumerate(devs):
            desc = f"{platform.name.strip()} ({version}): {dev.name.strip()}, {dev.max_compute_units} compute units"
            if programs is None:
                from geosynth._backends.opencl_backend import programs_digest

                programs = programs_digest()
            key = _probe_key(platform, dev, programs)
            if key in memo:
                why = memo[key] or None
            else:
                why = _build_programs(p, i)
                memo[key] = why or ""
                memo_changed = True
            out.append((f"opencl:{p}:{i}", desc, why))
    if memo_changed:
        _write_probe_memo(memo)
    return tuple(out)


def _opencl_device_names() -> list[str]:
    return [name for name, _, why in _opencl_inventory() if why is None]


def unusable_devices() -> dict[str, str]:
    """``{device string: reason}`` for OpenCL devices that are listed by an ICD but whose
    compiler fails on a geosynth program (left out of :func:`devices`); the reason names
    the first failing program and the compiler's first error."""
    return {name: why for name, _, why in _opencl_inventory() if why is not None}


def devices() -> list[str]:
    """List every device present, as the strings ``device=`` accepts.

    Returns:
        Warp's ``"cpu"``, then every ``"cuda:N"``, then every ``"opencl:P:D"``.
    """
    return _warp_device_names() + _opencl_device_names()


def describe_devices() -> list[tuple[str, str]]:
    """``(device string, human description)`` for every present device."""
    out = []
    wp, _ = _warp_status()
    if wp is not None:
        for d in wp.get_devices():
            desc = "Warp on the CPU (one thread)" if d.is_cpu else f"Warp on {d.name}"
            out.append((str(d), desc))
    for name, desc, why in _opencl_inventory():
        out.append((name, desc if why is None else f"{desc}; UNUSABLE, its compiler fails: {why}"))
    return out


def _absent(device: str, why: str = "") -> RuntimeError:
    present = ", ".join(devices()) or "none"
    extra = f" ({why})" if why else ""
    return RuntimeError(f"Device {device!r} is not present{extra}. Present devices: {present}.")


def resolve_device(device: str) -> str:
    """Turn a device string into the canonical name of a present device.

    ``"auto"`` becomes ``"cuda:0"`` when a GPU is present, else ``"opencl:P:D"``
    for the first OpenCL CPU device, else ``"cpu"``.

    Raises:
        ValueError: malformed string.
        RuntimeError: the device is not present (the message lists what is).
    """
    spec = parse_device(device)
    if spec.kind == "auto":
        names = _warp_device_names()
        if "cuda:0" in names:
            return "cuda:0"
        cl_names = _opencl_device_names()
        if cl_names:
            return cl_names[0]
        if "cpu" in names:
            return "cpu"
        raise _absent(device, "no backend could be loaded")
    if spec.kind in ("cpu", "cuda"):
        wp, err = _warp_status()
        if wp is None:
            raise _absent(device, f"Warp failed to load: {err}; install it with `pip install warp-lang`")
        name = "cpu" if spec.kind == "cpu" else f"cuda:{spec.index}"
        if name not in _warp_device_names():
            raise _absent(device, "; ".join(WARP_INIT_NOTES) if spec.kind == "cuda" else "")
        return name
    cl, err = _opencl_status()
    if cl is None:
        raise _absent(
            device,
            f"OpenCL failed to load: {err}; install it with `pip install pyopencl pocl-binary-distribution`",
        )
    usable = _opencl_device_names()
    if spec.platform is None:
        if not usable:
            why = "; ".join(f"{n}: {w}" for n, w in unusable_devices().items()) or "no OpenCL device is listed"
            raise _absent(device, f"no usable OpenCL device ({why}); `make test` or `make demo` installs "
                                  "Debian's pocl-opencl-icd where PyPI's PoCL cannot compile for this CPU")
        return usable[0]
    name = f"opencl:{spec.platform}:{spec.device}"
    if name not in usable:
        why = unusable_devices().get(name)
        raise _absent(device, f"listed, but its OpenCL compiler fails: {why}" if why else "")
    return name


@functools.lru_cache(maxsize=None)
def _backend_for(name: str):
    if name.startswith("opencl:"):
        from geosynth._backends.opencl_backend import OpenCLBackend

        _, p, d = name.split(":")
        return OpenCLBackend(int(p), int(d))
    from geosynth._backends.warp_backend import WarpBackend

    return WarpBackend(name)


def get_backend(device: str = "auto"):
    """Return the backend object for a device string (cached per device).

    Args:
        device: a device string, see the module docstring.

    Returns:
        A ``WarpBackend`` or ``OpenCLBackend``; both expose the same methods.

    Raises:
        ValueError: malformed device string.
        RuntimeError: the device is not present.
    """
    return _backend_for(resolve_device(device))


def to_device(array: np.ndarray | DeviceArray, device: str = "auto") -> DeviceArray:
    """Upload a NumPy array to a device once, to reuse across operations.

    For float arrays, how many values are NaN or inf and the range of the others are
    recorded with it (see :meth:`DeviceArray.value_stats`), so that operations can check
    it without reading it back.

    Args:
        array: any NumPy array of a dtype geosynth uses (float32, uint8, int32,
            uint32); a DeviceArray already on ``device`` is returned as is.
        device: a device string.

    Returns:
        A DeviceArray on the resolved device.

    Raises:
        RuntimeError: ``array`` is a DeviceArray on another device.
    """
    backend = get_backend(device)
    if isinstance(array, DeviceArray):
        if array.backend is not backend:
            raise RuntimeError(f"inputs live on different devices ({array.device} vs {backend.name}).")
        return array
    host = np.ascontiguousarray(array)
    out = backend.to_device(host)
    if host.dtype.kind == "f":
        out._stats = float_stats(host)
    return out
