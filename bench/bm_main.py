"""Run every bench/bm_*.py in its own subprocess, each under a time limit; their reports
and logs go to the output folder, with a summary (each benchmark's status and time) in
bm_main.md there.

Usage: python bench/bm_main.py [--quick] [--devices cpu,opencl:0:0] [--out FOLDER]
       [--timeout SECONDS] [--only fields,volume]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from harness import Step, finish, parse_args, run_step, start, steps_table  # noqa: E402


def benchmarks() -> list[Path]:
    """Every benchmark script beside this one, by name."""
    return sorted(p for p in HERE.glob("bm_*.py") if p.name != "bm_main.py")


def run_benchmarks(scripts: list[Path], devices: list[str], out_dir: Path, *, quick: bool,
                   timeout: float) -> list[Step]:
    """Run each script with ``--devices`` and ``--out out_dir/<name>.md`` (and ``--quick``),
    its output in ``out_dir/<name>.log``, each killed past ``timeout`` seconds."""
    steps = []
    for script in scripts:
        command = [sys.executable, str(script), "--devices", ",".join(devices),
                   "--out", str(out_dir / f"{script.stem}.md"), *(["--quick"] if quick else [])]
        steps.append(run_step(script.stem + (" --quick" if quick else ""), command, timeout=timeout,
                              log=out_dir / f"{script.stem}.log"))
    return steps


def _options(parser) -> None:
    parser.add_argument("--timeout", type=float, default=4 * 3600.0,
                        help="seconds each benchmark may run before it is stopped (default 4 h)")
    parser.add_argument("--only", default=None,
                        help="comma-separated benchmark names to run, e.g. fields,volume (default: all)")


def options(argv=None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    return parse_args(__doc__, argv, quick="every benchmark's --quick mode", extras=_options,
                      out="the folder for the reports, logs and bm_main.md (default bench/out)",
                      default_out=str(HERE / "out"))


def main(argv=None) -> int:
    args = options(argv)
    scripts = benchmarks()
    if args.only:
        wanted = {name.strip().removeprefix("bm_").removesuffix(".py") for name in args.only.split(",")}
        unknown = wanted - {s.stem.removeprefix("bm_") for s in scripts}
        if unknown:
            args.parser.error(f"--only {args.only}: no benchmark {', '.join(sorted(unknown))}; "
                              f"choose among {', '.join(s.stem.removeprefix('bm_') for s in scripts)}")
        scripts = [s for s in scripts if s.stem.removeprefix("bm_") in wanted]
    devices = start(args)
    out_dir = Path(args.out)
    steps = run_benchmarks(scripts, devices, out_dir, quick=args.quick, timeout=args.timeout)
    failed = [s.name for s in steps if s.status != "ok"]
    args.out = str(out_dir / "bm_main.md")
    finish(steps_table(steps, out_dir) + ("\n\nNot ok: " + ", ".join(failed) if failed else ""), args)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
