"""Atomic file output: write beside the target, then rename into place, so that a
failure never leaves a half-written file and an existing file is replaced whole."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path


def atomic_write(path: str | os.PathLike, write: Callable[[str], None], *,
                 inputs: Sequence[str | os.PathLike] = ()) -> Path:
    """Call ``write(tmp_path)`` to fill a temporary file, then move it to ``path``.

    Args:
        path: the output file; its folder is created.
        write: writes the whole content to the path it is given (the temporary file
            keeps ``path``'s suffix, for writers that pick the format from it).
        inputs: files this output must never replace (the inputs of the command).

    Returns:
        The output path.

    Raises:
        ValueError: ``path`` is one of ``inputs``.
    """
    out = Path(path)
    for item in inputs:
        if Path(item).exists() and out.exists() and os.path.samefile(item, out):
            raise ValueError(f"the output {str(out)!r} is an input file; choose another name (inputs are never overwritten).")
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=f".tmp{out.suffix}")
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; outputs get the usual mode
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return out
