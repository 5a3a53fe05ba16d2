"""Will this run fit in memory? Implements no paper section: every method's memory estimate
is refused here.

Memory refused up front: what this process may still allocate, and a one-line refusal.

Every operation whose memory grows with an input or an option estimates its peak
before allocating (a formula next to the operation, saying what it counts) and calls
:func:`require`, which raises :class:`MemoryBudgetError` when the estimate exceeds
:func:`available_memory`. The error names the parameter to lower and the largest
value of it that fits.

``GEOSYNTH_MEMORY_LIMIT`` (bytes, or with a K, M, G or T suffix, powers of 1024) caps
the budget, e.g. for tests.
"""

from __future__ import annotations

import os
import resource
from collections.abc import Callable

from geosynth.core.config import ENV_MEMORY_LIMIT, memory_limit_setting

__all__ = ["ENV_LIMIT", "MemoryBudgetError", "available_memory", "format_bytes", "largest_fitting", "parse_bytes",
           "peak_resident_bytes", "require"]

ENV_LIMIT = ENV_MEMORY_LIMIT
_UNITS = {"": 1, "B": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
_NO_LIMIT = 1 << 62  # nothing known: do not refuse


def parse_bytes(text: str) -> int:
    """``"512M"`` -> 536870912: an integer or decimal with an optional K/M/G/T suffix
    (powers of 1024; "KiB", "MB" and the like are read the same).

    Raises:
        ValueError: not a non-negative number of bytes.
    """
    s = str(text).strip().upper().removesuffix("IB").removesuffix("B")
    unit = s[-1:] if s[-1:] in _UNITS and s[-1:] != "" else ""
    number = s[: len(s) - len(unit)].strip()
    try:
        value = float(number)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise ValueError(f"{ENV_LIMIT} must be a number of bytes, optionally with a K, M, G or T suffix "
                         f"(e.g. 512M), got {text!r}.")
    return int(value * _UNITS[unit])


def _read_int(path: str) -> int | None:
    try:
        with open(path) as f:
            text = f.read().strip()
    except OSError:
        return None
    if text == "max":
        return None
    try:
        return int(text)
    except ValueError:
        return None


def _meminfo_available() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_headroom() -> int | None:
    """The tightest (limit - usage) of this process's cgroups, v2 (memory.max,
    memory.current, up the hierarchy) and v1 (memory.limit_in_bytes, usage_in_bytes)."""
    try:
        with open("/proc/self/cgroup") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    room: list[int] = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, path = parts
        if controllers == "":  # v2: walk from our cgroup up to the root
            rel = path.strip("/")
            while True:
                base = os.path.join("/sys/fs/cgroup", rel)
                limit = _read_int(os.path.join(base, "memory.max"))
                usage = _read_int(os.path.join(base, "memory.current"))
                if limit is not None and usage is not None:
                    room.append(limit - usage)
                if not rel:
                    break
                rel = os.path.dirname(rel)
        elif "memory" in controllers.split(","):  # v1 (inside a container the mount is our cgroup)
            for base in (os.path.join("/sys/fs/cgroup/memory", path.strip("/")), "/sys/fs/cgroup/memory"):
                limit = _read_int(os.path.join(base, "memory.limit_in_bytes"))
                usage = _read_int(os.path.join(base, "memory.usage_in_bytes"))
                if limit is not None and usage is not None and limit < _NO_LIMIT:
                    room.append(limit - usage)
                    break
    return max(0, min(room)) if room else None


def _address_space_headroom() -> int | None:
    """RLIMIT_AS minus the address space in use (VmSize), if there is such a limit."""
    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (OSError, ValueError):
        return None
    if soft == resource.RLIM_INFINITY or soft < 0:
        return None
    used = 0
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    used = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return max(0, soft - used)


def available_memory() -> int:
    """Bytes this process may still allocate now.

    The smallest of: ``MemAvailable`` of /proc/meminfo (else free pages by
    ``os.sysconf``), the cgroup limit minus usage (v2 and v1), RLIMIT_AS minus the
    address space in use, and ``GEOSYNTH_MEMORY_LIMIT`` when set. 2^62 when nothing
    is known.

    Raises:
        ValueError: ``GEOSYNTH_MEMORY_LIMIT`` is not a number of bytes.
    """
    found = []
    env = memory_limit_setting()
    if env:
        found.append(parse_bytes(env))
    system = _meminfo_available()
    if system is None:
        try:
            system = int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            system = None
    for v in (system, _cgroup_headroom(), _address_space_headroom()):
        if v is not None:
            found.append(v)
    return min(found) if found else _NO_LIMIT


def peak_resident_bytes() -> int:
    """This process's peak resident memory in bytes: VmHWM (resettable through
    /proc/self/clear_refs), ru_maxrss where /proc is absent. Not ru_maxrss first: Linux
    carries it across exec, so a process spawned by a large one starts with its parent's
    peak (measured: an 800 MiB parent's child reads 827 MiB, VmHWM 11 MiB)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def format_bytes(n: float) -> str:
    """``1288490188`` -> ``"1.2 GiB"`` (binary units, one decimal; bytes below 1 KiB)."""
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{int(n)} B" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError  # unreachable


def _format_value(v) -> str:
    if isinstance(v, (tuple, list)):  # a (z, y, x) shape, shown in the user's x y z order
        return " x ".join(_format_value(x) for x in v[::-1]) + " (x y z)"
    try:
        return f"{int(v):,}" if int(v) == v else str(v)
    except (TypeError, ValueError):
        return str(v)


class MemoryBudgetError(MemoryError):
    """An operation refused before allocating: its memory estimate exceeds what is available.

    Attributes:
        option: the API parameter to lower (e.g. "size", "resolution", "count",
            "texture_size", "source_resolution"); a CLI flag is ``"--" + option.replace("_", "-")``.
        largest: the largest value of that option that fits (same kind as the value
            given), or None when not even the smallest does.
        estimate: estimated peak bytes of the operation as asked.
        available: bytes available (:func:`available_memory`).
    """

    def __init__(self, message: str, *, option: str, largest, estimate: int, available: int):
        super().__init__(message)
        self.option = option
        self.largest = largest
        self.estimate = int(estimate)
        self.available = int(available)


def largest_fitting(estimate_fn: Callable[[int], int], available: int, smallest: int, below: int,
                    step: int = 1) -> int | None:
    """The largest multiple of ``step`` v in [smallest, below) with
    ``estimate_fn(v) <= available`` (estimate_fn nondecreasing), by bisection; None
    when not even the smallest fits."""
    lo, hi = -(-int(smallest) // step), (int(below) - 1) // step
    if hi < lo or estimate_fn(lo * step) > available:
        return None
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if estimate_fn(mid * step) <= available:
            lo = mid
        else:
            hi = mid - 1
    return lo * step


def require(
    estimate: int,
    *,
    option: str,
    value,
    largest_fn: Callable[[int], int] | None = None,
    what: str,
    smallest: int = 1,
    step: int = 1,
    largest=None,
    available: int | None = None,
) -> None:
    """Refuse, before allocating, an operation estimated to need more than is available.

    Args:
        estimate: estimated peak bytes of the operation as asked.
        option: the API parameter to lower (see :class:`MemoryBudgetError`).
        value: its value as given (an int, or for ``largest`` a sequence is shown as
            ``a x b x c``).
        largest_fn: the estimate as a function of an int value of the option
            (nondecreasing); the largest value that fits is found by bisection over
            [smallest, value), multiples of ``step`` only (:func:`largest_fitting`).
            Without it (and without ``largest``) the error has ``largest=None``.
        what: what is being made, for the message, e.g. ``"size 100 x 100 x 24"``.
        smallest: the smallest valid value of the option.
        step: values must be multiples of it (e.g. the level factor of a size).
        largest: the largest value that fits, when known in closed form.
        available: bytes available (default :func:`available_memory`).

    Raises:
        MemoryBudgetError: ``estimate`` > available. Its message is one line: what,
            the estimate, what is available, and the largest value that fits.
    """
    avail = available_memory() if available is None else int(available)
    if estimate <= avail:
        return
    if largest is None and largest_fn is not None:
        largest = largest_fitting(largest_fn, avail, smallest, int(value), step)
    flag = option
    if largest is not None:
        fix = f"lower {flag} to at most {_format_value(largest)} (or free memory)"
    else:
        fix = f"even the smallest {flag} does not fit; free memory"
    raise MemoryBudgetError(
        f"{what} needs about {format_bytes(estimate)}, more than the {format_bytes(avail)} available; {fix}.",
        option=option, largest=largest, estimate=estimate, available=avail,
    )
