"""`make gpu-check`: the test suite on CUDA (with Warp's cpu for the cross-device
comparisons) and every benchmark's --quick mode on CUDA beside the CPU backends, in at
most 8 minutes, on a machine with an NVIDIA GPU.

It installs nothing (the GPU machine may have no network): the Python that runs it must
already import this checkout's geosynth (.venv from `make test`, or another one; see the
README). Steps, each under its own time limit, all within --budget seconds:

1. probe: the devices present; no CUDA device ends the run at once with one line, exit 2;
2. tests: pytest with GEOSYNTH_TEST_DEVICES=<--test-devices> (default cuda,cpu);
3. one step per bench/bm_*.py --quick on <--bench-devices> (default every present device).

Writes bench/out/gpu-check.md (each step's status and time, the pytest summary line and
the benchmarks' reports) and, under bench/out/gpu-check/, tests.log and each benchmark's
report (bm_*.md) and log (bm_*.log). Exit 0 when every step is ok, else 1.

Usage: python tools/gpu_check.py [--test-devices cuda,cpu] [--bench-devices LIST]
       [--budget 450] [--tests PYTEST_ARGS]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
from bm_main import benchmarks, run_benchmarks  # noqa: E402
from harness import Step, machine, run_step, steps_table  # noqa: E402

OUT = ROOT / "bench" / "out"
PROBE_SECONDS = 90  # Warp's CUDA start-up and the OpenCL platforms
TEST_SECONDS = 270  # the suite on cuda + cpu, kernels compiled from cold caches
BENCH_SECONDS = 90  # at most, per benchmark; they share what the tests left of the budget
BENCH_FLOOR = 20  # each benchmark gets at least this much, so the budget is not overrun by much

_PROBE = """
import json, sys
import geosynth, geosynth.kernels
from geosynth.compute.backend import describe_devices
print(json.dumps({"geosynth": geosynth.__file__, "kernels": list(geosynth.kernels.__path__)[0],
                  "devices": geosynth.devices(), "describe": describe_devices()}))
"""


class CheckError(Exception):
    """A reason to stop at once; its message is the one line printed."""


def probe(env: dict) -> dict:
    """What this Python imports and which devices are present (in a subprocess, so a
    hanging driver is stopped by the time limit)."""
    try:
        run = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, env=env,
                             timeout=PROBE_SECONDS, cwd=ROOT)
    except subprocess.TimeoutExpired:
        raise CheckError(f"gpu-check: listing the devices took over {PROBE_SECONDS} s (a hung GPU driver?)") from None
    if run.returncode != 0:
        last = (run.stderr.strip().splitlines() or ["no output"])[-1]
        raise CheckError(f"gpu-check: {sys.executable} cannot import geosynth ({last}); "
                         "run `make test` first (it builds .venv) or give a Python that has it: make gpu-check GPU_PYTHON=...")
    info = json.loads(run.stdout.strip().splitlines()[-1])
    for name, want in (("geosynth", ROOT / "geosynth"), ("geosynth.kernels", ROOT / "geosynth" / "kernels")):
        got = Path(info["geosynth"]).parent if name == "geosynth" else Path(info["kernels"])
        if got.resolve() != want.resolve():
            raise CheckError(f"gpu-check: {sys.executable} imports {name} from {got}, not from this checkout ({want}); "
                             "reinstall it here (pip install -e . with this Python) or run from that checkout")
    return info


def check_devices(wanted: list[str], present: list[str], what: str) -> None:
    """Every device in ``wanted`` is present; a CUDA one asked for where none is present
    is the one-line 'no CUDA device' error."""
    from geosynth.compute.backend import parse_device

    for dev in wanted:
        spec = parse_device(dev)
        name = f"cuda:{spec.index}" if spec.kind == "cuda" else dev
        if spec.kind == "cuda" and not any(d.startswith("cuda") for d in present):
            raise CheckError(f"gpu-check: no CUDA device present (present: {', '.join(present)}); "
                             "run it on a machine with an NVIDIA GPU and its driver")
        if spec.kind in ("cpu", "cuda") and name not in present or spec.kind == "opencl" and ":" in dev and dev not in present:
            raise CheckError(f"gpu-check: {what} {dev} is not present (present: {', '.join(present)})")


def pytest_summary(log: Path) -> str:
    """The last line of pytest's output (e.g. '290 passed in 95.1s'), or '-'."""
    try:
        lines = [line.strip() for line in log.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return "-"
    return lines[-1].strip("= ") if lines else "-"


def summary(steps: list[Step], info: dict, args, reports: list[Path], elapsed: float) -> str:
    bad = [s.name for s in steps if s.status != "ok"]
    verdict = "every step ok" if not bad else "NOT ok: " + ", ".join(bad)
    gpus = [f"{name}: {desc}" for name, desc in info["describe"] if name.startswith("cuda")]
    lines = [f"# gpu-check: {verdict} ({elapsed:.0f} s of a {args.budget:.0f} s budget)", "",
             f"Machine: {machine()}", "", *[f"- {g}" for g in gpus],
             f"- Python: {sys.executable}; geosynth from {Path(info['geosynth']).parent}",
             f"- tests on: {args.test_devices}; benchmarks (--quick) on: {', '.join(args.bench_devices)}", "",
             steps_table(steps, OUT), "", f"pytest's last line: {pytest_summary(OUT / 'gpu-check' / 'tests.log')}"]
    for report in reports:
        if report.is_file():
            lines += ["", f"## {report.relative_to(OUT)}", "", report.read_text(errors="replace").rstrip()]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--test-devices", default="cuda,cpu", help="GEOSYNTH_TEST_DEVICES for the suite (default cuda,cpu)")
    parser.add_argument("--bench-devices", default=None, help="devices of the --quick benchmarks (default: every present one)")
    parser.add_argument("--budget", type=float, default=450.0, help="seconds for all steps together (default 450)")
    parser.add_argument("--tests", default="", help="pytest arguments, e.g. 'tests/test_devices.py' (default: the whole suite)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    deadline = t0 + args.budget
    os.environ["PYTHONUNBUFFERED"] = "1"  # a step stopped at its limit still leaves its output in the log
    os.environ.pop("GEOSYNTH_TEST_DEVICES", None)
    env = dict(os.environ)
    try:
        info = probe(env)
        present = info["devices"]
        args.bench_devices = args.bench_devices.split(",") if args.bench_devices else present
        check_devices([d.strip() for d in args.test_devices.split(",")], present, "--test-devices")
        check_devices(args.bench_devices, present, "--bench-devices")
    except CheckError as exc:
        print(exc, file=sys.stderr)
        return 2

    work = OUT / "gpu-check"
    test_env = dict(env, GEOSYNTH_TEST_DEVICES=args.test_devices)
    steps = [run_step(f"tests (GEOSYNTH_TEST_DEVICES={args.test_devices})",
                      [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *shlex.split(args.tests)],
                      timeout=min(TEST_SECONDS, deadline - time.perf_counter() - BENCH_FLOOR * len(benchmarks())),
                      log=work / "tests.log", env=test_env)]
    scripts = benchmarks()
    for i, script in enumerate(scripts):
        share = (deadline - time.perf_counter()) / (len(scripts) - i)
        steps += run_benchmarks([script], args.bench_devices, work, quick=True,
                                timeout=max(BENCH_FLOOR, min(BENCH_SECONDS, share)))
    from geosynth.io.files import atomic_write

    text = summary(steps, info, args, [work / f"{s.stem}.md" for s in scripts], time.perf_counter() - t0)
    written = atomic_write(OUT / "gpu-check.md", lambda tmp: Path(tmp).write_text(text))
    print(text.splitlines()[0].lstrip("# "))
    print(f"written {written} (logs and reports in {work})")
    return 0 if all(s.status == "ok" for s in steps) else 1


if __name__ == "__main__":
    sys.exit(main())
