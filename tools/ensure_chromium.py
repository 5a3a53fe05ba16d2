"""Make sure the viewer's browser tests (tests/test_viewer.py) have a headless Chromium, or
say why they will skip. Run by ``make test`` before the suite:
``.venv/bin/python tools/ensure_chromium.py``.

A Chromium already on PATH (``chromium``, ``chromium-browser``, ``google-chrome``) is used
as it is. Otherwise, where this runs as root on Debian or Ubuntu (CI's fresh machine),
Debian's ``chromium`` package is installed with apt-get, never prompting; anywhere else
(no root: apt would ask for a password) nothing is installed. Either way the exit status
is 0: a browser that cannot be had makes the browser tests skip with their reason, never
a failed build.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
SKIP = "the viewer's browser tests will be skipped"


def _found() -> str | None:
    return next((shutil.which(n) for n in NAMES if shutil.which(n)), None)


def main() -> int:
    found = _found()
    if found:
        print(f"Chromium: {found} (the viewer's browser tests run)")
        return 0
    if shutil.which("apt-get") is None or os.geteuid() != 0:
        print(f"Chromium: none on PATH; {SKIP} (install Debian's chromium package, e.g. "
              "`sudo apt-get install chromium`, to run them)")
        return 0
    print("Installing Debian's chromium with apt-get (for the viewer's browser tests) ...", flush=True)
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    try:
        subprocess.run(["apt-get", "update", "-qq"], check=True, env=env, stdout=subprocess.DEVNULL, timeout=600)
        subprocess.run(["apt-get", "install", "-y", "-qq", "--no-install-recommends", "chromium"], check=True,
                       env=env, stdout=subprocess.DEVNULL, timeout=1200)
    except (OSError, subprocess.SubprocessError) as exc:
        print(f"Chromium: apt-get could not install it ({exc}); {SKIP}")
        return 0
    found = _found()
    print(f"Chromium: {found} (the viewer's browser tests run)" if found else f"Chromium: still none; {SKIP}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
