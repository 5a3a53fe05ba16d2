"""Run every bench/bm_*.py in its own subprocess; reports go to bench/out/."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    out_dir = HERE / "out"
    out_dir.mkdir(exist_ok=True)
    failed = []
    for script in sorted(HERE.glob("bm_*.py")):
        if script.name == "bm_main.py":
            continue
        report = out_dir / f"{script.stem}.md"
        print(f"== {script.name} -> {report}", flush=True)
        rc = subprocess.call([sys.executable, str(script), "--out", str(report), *sys.argv[1:]])
        if rc:
            failed.append(script.name)
    if failed:
        print(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
