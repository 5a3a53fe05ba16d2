"""How does the ``geosynth`` command catch Ctrl-C from its first instant? Implements no
paper section.

The console script and ``python -m geosynth`` start here. Before anything that takes
time is imported (NumPy, trimesh, the device runtimes: some optional imports catch
every exception, an interrupt included, and would swallow it), SIGINT and SIGTERM are
only recorded; :func:`geosynth.cli.main` then installs its own handlers and ends a run
that was interrupted while it loaded (exit 130 or 143), before anything is written.
"""

from __future__ import annotations

# The C module, not ``signal``: importing ``signal`` builds its enum classes first (a few ms on
# a loaded machine, in which a Ctrl-C still raised KeyboardInterrupt with a traceback).
import _signal

_EARLY: list[int] = []  # the signals that arrived while the command line loaded


def _record(signum, frame) -> None:  # pragma: no cover - exercised through a subprocess
    _EARLY.append(signum)


def main() -> int:
    """Run the ``geosynth`` command line; returns its exit code (see :func:`geosynth.cli.main`)."""
    for sig in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(sig, _record)
    from geosynth.cli import main as cli_main  # the heavy imports: an interrupt here is recorded

    return cli_main(early=_EARLY)
