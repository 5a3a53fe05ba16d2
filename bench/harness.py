"""Benchmark harness: warm up, synchronize, repeat to a time budget, report throughput.

Each benchmark builds its inputs once, then times closures that launch work and wait
for it (the closure itself synchronizes, so queued device work is never missed).
Every bench/bm_*.py reads its command line through :func:`parse_args`, prints the
machine and devices through :func:`start` and writes its report through :func:`finish`;
:func:`run_step` runs one under a time limit (bm_main.py, tools/gpu_check.py).
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import argparse
import os
import platform
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence


@dataclass
class Row:
    case: str
    impl: str
    seconds: float  # best time per call
    elements: float  # work items per call (e.g. candidate x dimension x query)
    nbytes: float  # bytes of candidate data read per call
    peer: bool  # a peer (not geosynth)
    note: str = ""
    extra: dict = field(default_factory=dict)


def time_call(fn: Callable[[], object], min_time: float = 0.1, max_repeats: int = 50, warmup: int = 1) -> float:
    """Best wall time of ``fn()`` in seconds: warm-up calls first, then repeats until
    ``min_time`` has passed (at least 2 calls, at most ``max_repeats``)."""
    for _ in range(warmup):
        fn()
    best, spent, count = float("inf"), 0.0, 0
    while count < 2 or (spent < min_time and count < max_repeats):
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        best, spent, count = min(best, dt), spent + dt, count + 1
    return best


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, Python {platform.python_version()}"


def table(rows: list[Row]) -> str:
    """A Markdown table per case: time, throughput, GB/s, ratio to the fastest peer."""
    out = []
    cases = list(dict.fromkeys(r.case for r in rows))
    out.append("| case | implementation | time/call | elements/s | GB/s | vs fastest peer | note |")
    out.append("|---|---|---:|---:|---:|---:|---|")
    for case in cases:
        group = [r for r in rows if r.case == case]
        peers = [r.seconds for r in group if r.peer]
        fastest = min(peers) if peers else None
        for r in group:
            ratio = f"{fastest / r.seconds:.2f}x" if fastest else "-"
            t = f"{r.seconds * 1e3:.2f} ms" if r.seconds < 10 else f"{r.seconds:.1f} s"
            out.append(
                f"| {case} | {r.impl} | {t} | {r.elements / r.seconds:.3g} | {r.nbytes / r.seconds / 1e9:.2f} | {ratio} | {r.note} |"
            )
    out.append("")
    out.append("'vs fastest peer' is the fastest peer's time divided by this row's: above 1.00x is faster than every peer.")
    return "\n".join(out)


# --- command line, header and report: shared by every bench/bm_*.py -------------------------


def parse_args(doc: str, argv: Sequence[str] | None = None, *, quick: str,
               extras: Callable[[argparse.ArgumentParser], None] | None = None,
               out: str = "also write the Markdown report here", default_out: str | None = None) -> argparse.Namespace:
    """Parse a benchmark's command line: ``--quick``, ``--devices``, ``--out`` and its extras.

    Args:
        doc: the benchmark's module docstring (the ``--help`` text).
        argv: the arguments (default ``sys.argv[1:]``).
        quick: what ``--quick`` runs, for ``--help``.
        extras: adds the benchmark's own options to the parser.
        out: the help of ``--out``; ``default_out`` its default (None: no file).

    Returns:
        The namespace; ``devices`` is a list of device strings, or None for every present
        device (resolved by :func:`start`); ``parser`` is the parser, for ``parser.error``.
    """
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help=quick)
    parser.add_argument("--devices", default=None, type=_device_list,
                        help="comma-separated devices, e.g. cpu,opencl:0:0 (default: every present one)")
    parser.add_argument("--out", default=default_out, help=out)
    if extras is not None:
        extras(parser)
    args = parser.parse_args(argv)
    args.parser = parser
    return args


def _device_list(text: str) -> list[str]:
    from geosynth.compute.backend import parse_device

    names = [d.strip() for d in text.split(",") if d.strip()]
    if not names:
        raise argparse.ArgumentTypeError("give at least one device, e.g. cpu,opencl:0:0")
    for name in names:
        try:
            parse_device(name)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return names


def start(args: argparse.Namespace) -> list[str]:
    """Print the machine line and every present device; resolve ``args.devices``.

    Returns:
        The devices to run on (``args.devices`` is set to them too). An asked-for device
        that is not present ends the run with its one-line error.
    """
    import geosynth
    from geosynth.compute.backend import describe_devices

    print(f"Machine: {machine()}")
    for name, desc in describe_devices():
        print(f"  {name}: {desc}")
    if args.devices is None:
        args.devices = geosynth.devices()
    for dev in args.devices:
        try:
            geosynth.get_backend(dev)
        except RuntimeError as exc:
            args.parser.error(f"--devices {dev}: {exc}")
    print(f"Running on: {', '.join(args.devices)}" + (" (--quick: small fixed sizes)" if args.quick else ""), flush=True)
    return args.devices


def finish(body: str, args: argparse.Namespace, *, title: str | None = None) -> int:
    """Print the report and write it to ``args.out`` (atomically) when given.

    The report is ``title`` (if any), the machine line, the devices, then ``body``
    (Markdown). Returns 0, the benchmark's exit status.
    """
    from geosynth.io.files import atomic_write

    head = [title, ""] if title else []
    head += [f"Machine: {machine()}", "", f"Devices: {', '.join(args.devices)}"
             + (" (--quick: small fixed sizes, a smoke run, not the measured cases)" if args.quick else ""), ""]
    report = "\n".join(head) + body.rstrip("\n") + "\n"
    print()
    print(report, end="")
    if args.out:
        written = atomic_write(args.out, lambda tmp: Path(tmp).write_text(report))
        print(f"written {written}")
    return 0


# --- steps run as subprocesses under a time limit: bm_main.py and tools/gpu_check.py --------


@dataclass
class Step:
    name: str
    status: str  # "ok", "failed (exit N)" or "timed out after T s"
    seconds: float
    log: Path


def run_step(name: str, command: Sequence[str], *, timeout: float, log: Path,
             env: dict | None = None) -> Step:
    """Run ``command`` with its output in ``log``, killed (its whole process group) past
    ``timeout`` seconds. Returns the step's status and wall time."""
    timeout = max(1.0, timeout)
    log.parent.mkdir(parents=True, exist_ok=True)
    print(f"== {name} (limit {timeout:.0f} s, log {log})", flush=True)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        proc = subprocess.Popen(list(command), stdout=f, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            rc = proc.wait(timeout=timeout)
            status = "ok" if rc == 0 else f"failed (exit {rc})"
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            status = f"timed out after {timeout:.0f} s"
        except BaseException:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
    step = Step(name, status, time.perf_counter() - t0, log)
    print(f"   {step.status} in {step.seconds:.1f} s", flush=True)
    return step


def steps_table(steps: Sequence[Step], root: Path) -> str:
    """A Markdown table of steps: name, status, wall time, log (relative to ``root``)."""
    lines = ["| step | status | time | log |", "|---|---|---:|---|"]
    for s in steps:
        try:
            log = s.log.resolve().relative_to(root.resolve())
        except ValueError:
            log = s.log
        lines.append(f"| {s.name} | {s.status} | {s.seconds:.1f} s | {log} |")
    return "\n".join(lines)
