"""May this path be written, and how is it written safely? Implements no paper section:
every output goes through it.

Files in and out: the one output guard every command and writer goes through,
atomic writes that never leave a partial or temporary file behind, and pictures
written as their extension says.

- :func:`note_input`: readers record each file they read; no writer of this process
  may then replace it.
- :func:`check_input`: what every reader does first: the file exists, is a file and
  not a folder, is not empty; it is noted as an input.
- :func:`check_output`: refuse an output path before any work (an input of the run
  after symlinks and ``..`` are resolved, a folder, a path under a file, an unwritable
  folder, the wrong extension).
- :func:`atomic_write`: fill a temporary file beside the target, then rename it into
  place; on an exception, Ctrl-C or SIGTERM the temporary file is removed.
- :func:`staged_outputs`: one commit step for a whole command: inside it, what this
  thread's atomic writes (and :func:`defer`'d publications, e.g. a tiled run's store)
  would move into place waits, in temporaries, until the block ends, and is then moved
  in together with SIGINT and SIGTERM held back; an exception, Ctrl-C or SIGTERM before
  that removes every temporary and leaves every old output as it was.
- :func:`temporary_path`: the name of such a temporary (file or folder):
  ``.NAME.geosynth-PID-RANDOM.tmp[SUFFIX]``. A process killed outright (SIGKILL, a lost
  machine) cannot remove its temporaries; the next write of the same output removes
  those whose writer is gone (:func:`remove_stale_temporaries`).
- :func:`write_image`: an 8-bit grey or RGB picture as PNG or JPEG (Pillow), by suffix.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import threading
import uuid
from contextlib import contextmanager
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from geosynth.core.config import INPUT_PATHS

__all__ = ["IMAGE_SUFFIXES", "atomic_write", "check_finite_output", "check_input", "check_output", "defer", "note_input", "noted_inputs",
           "remove_stale_temporaries", "staged_outputs", "staged_section",
           "temporary_path", "write_image"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
_IMAGE_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}

# Every file a reader of this process opened, by resolved path: writers refuse them.


def _resolved(path: str | os.PathLike) -> str:
    return os.path.realpath(os.fspath(path))


def note_input(path: str | os.PathLike) -> None:
    """Record ``path`` as an input of this process: no writer here will replace it."""
    INPUT_PATHS.add(_resolved(path))


def noted_inputs() -> list[str]:
    """The resolved paths readers of this process noted (:func:`note_input`), sorted."""
    return sorted(INPUT_PATHS)


def check_input(path: str | os.PathLike, what: str) -> Path:
    """Check a file a reader is about to open, and note it as an input (:func:`note_input`).

    Args:
        path: the file.
        what: how messages name it (``"mesh"``, ``"point set"``, ``"texture image"``, ...).

    Returns:
        ``path`` as a Path.

    Raises:
        FileNotFoundError: ``"<what> file 'X' does not exist."`` (a dangling symlink too).
        ValueError: it is a folder, not a regular file, or empty (0 bytes).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{what} file {str(p)!r} does not exist.")
    if p.is_dir():
        raise ValueError(f"{what} file {str(p)!r} is a folder, not a file; give a file inside it.")
    if not p.is_file():
        raise ValueError(f"{what} file {str(p)!r} is not a regular file (a device, pipe or socket).")
    note_input(p)
    if p.stat().st_size == 0:
        raise ValueError(f"{what} file {str(p)!r} is empty (0 bytes).")
    return p


def _is_input(out: str, inputs: Iterable[str | os.PathLike | None]) -> str | None:
    """The input that ``out`` (resolved) names, or None."""
    for item in list(inputs) + sorted(INPUT_PATHS):
        if item is None:
            continue
        real = _resolved(item)
        if real == out:
            return os.fspath(item)
        try:  # hard links, bind mounts: the same file under another name
            if os.path.exists(real) and os.path.exists(out) and os.path.samefile(real, out):
                return os.fspath(item)
        except OSError:
            pass
    return None


def check_output(path: str | os.PathLike, *, inputs: Sequence[str | os.PathLike | None] = (),
                 suffixes: Sequence[str] | None = None, what: str = "output") -> Path:
    """Refuse an output path that would lose data or fail only after the work is done.

    Args:
        path: the file to be written.
        inputs: the run's input files (None entries are skipped); the files readers of
            this process recorded with :func:`note_input` are inputs too.
        suffixes: the accepted extensions (lower case, with the dot), or None for any.
        what: how error messages name the path (``"-o/--output"``, ``"--png"``, ...).

    Returns:
        ``path`` as a Path.

    Raises:
        ValueError: the path resolves (symlinks, ``..``, hard links) to an input, has
            another extension, is a folder, lies under a file, or its folder cannot be
            written.
    """
    out = Path(path)
    if suffixes is not None and out.suffix.lower() not in suffixes:
        raise ValueError(f"{what} {str(out)!r} must end in {', '.join(suffixes)}; got "
                         f"{out.suffix or 'no extension'}.")
    real = _resolved(out)
    source = _is_input(real, inputs)
    if source is not None:
        raise ValueError(f"{what} {str(out)!r} is an input file ({source!r}); choose another name "
                         "(inputs are never overwritten).")
    if os.path.isdir(real):
        raise ValueError(f"{what} {str(out)!r} is a folder; give a file name inside it.")
    folder = os.path.dirname(real)
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ValueError(f"{what} {str(out)!r} cannot be created: {folder!r} is a file, not a folder.")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {str(out)!r} cannot be written: no write permission in {folder!r}.")
    return out


# ------------------------------------------------------------------ temporaries

_TMP_TAG = ".geosynth-"


def check_finite_output(path: str | os.PathLike, what: str, **arrays) -> None:
    """Refuse to write ``path`` when one of ``arrays`` holds NaN or inf: such a file
    would pass for a valid one. Called before any file is created.

    Args:
        path: the output file, named in the message.
        what: one record of the arrays' first axis ("point", "vertex"), or of their
            first three for grids ("sample (z, y, x)").
        arrays: by what their values are in the file (``position=``, ``normal=``):
            (N, 3) arrays, or (Z, Y, X[, C]) grids; None and non-float ones are skipped.

    Raises:
        ValueError: one line: the file, how many values are not finite, of which array,
            and the first record that holds one.
    """
    for label, a in arrays.items():
        if a is None:
            continue
        a = np.asarray(a)
        if a.dtype.kind != "f" or a.size == 0:
            continue
        bad = ~np.isfinite(a)
        count = int(np.count_nonzero(bad))
        if not count:
            continue
        first = np.unravel_index(int(np.argmax(bad.reshape(-1))), a.shape)
        are = "is" if count == 1 else "are"
        if a.ndim <= 2:
            rows = int(np.count_nonzero(bad.reshape(len(a), -1).any(axis=1)))
            many = "vertices" if what == "vertex" else what + "s"
            found = (f"{count:,} of its {a.size:,} {label} coordinates {are} NaN or inf, in {rows:,} "
                     f"{what if rows == 1 else many} (the first: {what} {first[0]:,}, counting from 0)")
            fix = f"remove {'that ' + what if rows == 1 else 'those ' + many} or correct {'it' if rows == 1 else 'them'} first"
        else:
            found = (f"{count:,} of its {a.size:,} {label} values {are} NaN or inf (the first: {what} = "
                     f"({', '.join(f'{i:,}' for i in first[:3])}))")
            fix = "correct those values first"
        raise ValueError(f"refusing to write {str(path)!r}: {found}; nothing was written: {fix}.")


def temporary_path(target: str | os.PathLike, suffix: str = "") -> Path:
    """A fresh temporary name beside ``target``: ``.NAME.geosynth-PID-RANDOM.tmp`` + ``suffix``.

    The writer's process id in the name lets a later run tell its own stale temporaries
    (their writer is gone) from those of a run still going (:func:`remove_stale_temporaries`).
    Nothing is created.
    """
    out = Path(target)
    return out.parent / f".{out.name}{_TMP_TAG}{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp{suffix}"


def _process_started(pid: int) -> float | None:
    """When process ``pid`` started (seconds since the epoch), None when it is gone.

    Linux: field 22 of /proc/PID/stat (clock ticks after boot) plus the boot time of
    /proc/stat; elsewhere only whether it exists (then 0: it counts as started before).
    """
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()  # after the command name, which may hold spaces
        with open("/proc/stat", "rb") as f:
            boot = next(int(line.split()[1]) for line in f if line.startswith(b"btime "))
        return boot + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except FileNotFoundError:
        if os.path.isdir("/proc/self"):
            return None
    except (OSError, ValueError, IndexError, StopIteration):
        pass
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except OSError:  # it exists, owned by someone else
        pass
    return 0.0


def remove_stale_temporaries(target: str | os.PathLike) -> list[str]:
    """Remove the temporaries of ``target`` (:func:`temporary_path`) left by writers that are
    gone: a process that no longer exists, or a process id reused by a process that started
    after the temporary was last written. Temporaries of a live writer are kept.

    Returns:
        The paths removed.
    """
    out = Path(target)
    folder = out.parent if str(out.parent) else Path(".")
    pattern = re.compile(rf"^\.{re.escape(out.name)}{re.escape(_TMP_TAG)}(\d+)-[0-9a-f]+\.tmp")
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        m = pattern.match(name)
        if m is None:
            continue
        path = folder / name
        try:
            written = os.lstat(path).st_mtime
        except OSError:
            continue
        started = _process_started(int(m.group(1)))
        if started is not None and started <= written + 1.0:  # its writer may still be at work
            continue
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
            removed.append(str(path))
        except OSError:
            pass
    return removed


# ------------------------------------------------------------------ one commit step per command


class _Stage:
    """The publications a command's outputs wait for: (commit, abort) pairs, in order."""

    def __init__(self, thread: int, interrupted: Callable[[], bool]):
        self.thread = thread
        self.interrupted = interrupted
        self.pending: list[tuple[Callable[[], None], Callable[[], None]]] = []


_STAGE: _Stage | None = None


def defer(commit: Callable[[], None], abort: Callable[[], None]) -> bool:
    """Inside :func:`staged_outputs` (on the thread that opened it): keep ``commit`` (what
    puts a finished output in place) for the end of the block, and ``abort`` (what removes
    its temporaries) for a failure; returns True. Elsewhere returns False: the caller
    commits now."""
    stage = _STAGE
    if stage is None or threading.get_ident() != stage.thread:
        return False
    stage.pending.append((commit, abort))
    return True


@contextmanager
def staged_outputs(interrupted: Callable[[], bool] = lambda: False):
    """Every output written inside the block is put in place together when it ends.

    Args:
        interrupted: asked before the outputs are put in place; True (an interrupt was
            seen, even one that some library swallowed) aborts them as an exception
            would, raising KeyboardInterrupt.

    While the outputs are moved in, SIGINT and SIGTERM are held back (main thread); one
    that arrived meanwhile is delivered afterwards, with every new output in place.
    """
    global _STAGE
    if _STAGE is not None:  # nested: the outer block commits
        yield
        return
    stage = _Stage(threading.get_ident(), interrupted)
    _STAGE = stage
    try:
        yield
        if stage.interrupted():
            raise KeyboardInterrupt
    except BaseException:
        _STAGE = None
        for _, abort in reversed(stage.pending):
            try:
                abort()
            except OSError:
                pass
        raise
    _STAGE = None
    main = threading.current_thread() is threading.main_thread()
    held = {signal.SIGINT, signal.SIGTERM}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held) if main else None
    try:
        for commit, _ in stage.pending:
            commit()
    finally:
        if main:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


@contextmanager
def staged_section():
    """Inside :func:`staged_outputs` (on its thread): the outputs written in this block are
    dropped, their temporaries removed, when the block raises; the exception goes on. The
    other outputs of the command stay staged (a gallery's failed entry leaves no half of
    its files behind). Elsewhere it does nothing."""
    stage = _STAGE
    if stage is None or threading.get_ident() != stage.thread:
        yield
        return
    start = len(stage.pending)
    try:
        yield
    except BaseException:
        for _, abort in reversed(stage.pending[start:]):
            try:
                abort()
            except OSError:
                pass
        del stage.pending[start:]
        raise


class _Terminated(BaseException):
    """SIGTERM arrived during an atomic write (raised by the temporary handler)."""


def _on_sigterm(signum, frame):  # pragma: no cover - exercised through a subprocess
    raise _Terminated()


def atomic_write(path: str | os.PathLike, write: Callable[[str], None], *,
                 inputs: Sequence[str | os.PathLike | None] = (), stage: bool = True) -> Path:
    """Call ``write(tmp_path)`` to fill a temporary file, then move it to ``path``.

    A failure, Ctrl-C or SIGTERM while writing removes the temporary file and leaves
    any existing ``path`` as it was. SIGTERM is then passed on as it would have
    ended the process (the previous handler, or termination). Temporaries of ``path``
    left by a killed earlier run are removed first (:func:`remove_stale_temporaries`).
    Inside :func:`staged_outputs` (same thread) the filled temporary is moved in at the
    end of that block, with the command's other outputs.

    Args:
        path: the output file; its folder is created.
        write: writes the whole content to the path it is given (the temporary file
            keeps ``path``'s suffix, for writers that pick the format from it).
        inputs: files this output must never replace, besides those readers noted.
        stage: False: move it in now even inside :func:`staged_outputs` (files a run
            must see at once, such as a checkpoint).

    Returns:
        The output path.

    Raises:
        ValueError: ``path`` fails :func:`check_output`.
    """
    out = check_output(path, inputs=inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    # SIGTERM's default action would skip the cleanup below: while writing, it raises.
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if main else None
    if main:
        signal.signal(signal.SIGTERM, _on_sigterm)
    tmp = None
    try:
        remove_stale_temporaries(out)
        tmp = str(temporary_path(out, out.suffix))
        os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # created 0600; outputs get the usual mode
        done = tmp
        if not (stage and defer(lambda: os.replace(done, out), lambda: _remove(done))):
            os.replace(tmp, out)
        tmp = None
    except _Terminated:
        _remove(tmp)
        _pass_on_sigterm(previous)
        raise
    except BaseException:
        _remove(tmp)
        raise
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)
    return out


def _remove(tmp: str | None) -> None:
    if tmp is not None and os.path.exists(tmp):
        os.unlink(tmp)


def _pass_on_sigterm(previous) -> None:
    """After cleaning up, give SIGTERM to whoever would have had it."""
    if callable(previous):
        previous(signal.SIGTERM, None)
    elif previous in (signal.SIG_DFL, None):
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
    # SIG_IGN: the signal was to be ignored; the write still failed, so raise.


def write_image(path: str | os.PathLike, image: np.ndarray, *,
                inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Write an 8-bit grey (H, W) or RGB (H, W, 3) image, atomically, as the suffix says.

    Args:
        path: a .png, .jpg or .jpeg file (JPEG at quality 95).
        image: (H, W) or (H, W, 3) uint8 array.
        inputs: files never to overwrite.

    Returns:
        The path written.

    Raises:
        ValueError: another suffix, or an image of another shape or dtype.
    """
    from PIL import Image

    out = check_output(path, inputs=inputs, suffixes=IMAGE_SUFFIXES, what="picture")
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"image must be (H, W) or (H, W, 3) uint8, got {img.shape} {img.dtype}.")
    fmt = _IMAGE_FORMATS[out.suffix.lower()]
    pil = Image.fromarray(np.ascontiguousarray(img), "L" if img.ndim == 2 else "RGB")

    def write(tmp: str) -> None:
        pil.save(tmp, format=fmt, **({"quality": 95} if fmt == "JPEG" else {}))

    return atomic_write(out, write, inputs=inputs)
