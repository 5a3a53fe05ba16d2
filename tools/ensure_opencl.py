"""Make sure the venv's OpenCL sees at least one device that can build a kernel.

PyPI's PoCL (bundled with pyopencl / pocl-binary-distribution) is PoCL 3.0 on LLVM 14,
which cannot compile for CPUs newer than LLVM 14 knows (AMD Zen 5 fails with
"unknown target CPU 'generic'"). Where that happens and this runs as root on Debian,
Debian's pocl-opencl-icd (PoCL 3.1 on LLVM 15, which falls back to a known CPU model)
is installed beside it; geosynth then lists only the usable device. Run by the
Makefile once per venv: ``.venv/bin/python tools/ensure_opencl.py``.
Exit status 0 when a usable OpenCL device is there afterwards, 1 otherwise.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

_QUERY = (
    "import json; from geosynth.compute.backend import devices, unusable_devices; "
    "print(json.dumps([[d for d in devices() if d.startswith('opencl')], unusable_devices()]))"
)


def _inventory() -> tuple[list[str], dict[str, str]]:
    # A fresh interpreter each time: the ICD loader reads its vendor list once.
    out = subprocess.run([sys.executable, "-c", _QUERY], capture_output=True, text=True, check=True)
    usable, unusable = json.loads(out.stdout.strip().splitlines()[-1])
    return usable, unusable


def main() -> int:
    usable, unusable = _inventory()
    if usable:
        print(f"OpenCL: usable {', '.join(usable)}" + (f"; unusable {unusable}" if unusable else ""))
        return 0
    reason = "; ".join(f"{k}: {v}" for k, v in unusable.items()) or "no OpenCL device listed"
    print(f"OpenCL: no usable device ({reason}).")
    if shutil.which("apt-get") is None or os.geteuid() != 0:
        print("Install a PoCL that supports this CPU (Debian/Ubuntu: `sudo apt-get install pocl-opencl-icd`), "
              "then run make again.", file=sys.stderr)
        return 1
    print("Installing Debian's pocl-opencl-icd (PoCL 3.1, LLVM 15) with apt-get ...", flush=True)
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    subprocess.run(["apt-get", "update", "-qq"], check=True, env=env)
    subprocess.run(["apt-get", "install", "-y", "-qq", "--no-install-recommends", "pocl-opencl-icd"],
                   check=True, env=env, stdout=subprocess.DEVNULL)
    usable, unusable = _inventory()
    if not usable:
        print(f"OpenCL: still no usable device after installing pocl-opencl-icd: {unusable}", file=sys.stderr)
        return 1
    print(f"OpenCL: usable {', '.join(usable)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
