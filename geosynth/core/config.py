"""What does the process environment say to geosynth, and what does geosynth set in it?
Implements no paper section: every environment variable geosynth reads or sets is read or
set here (issue 33, "configuration in one place").

A leaf module: it imports nothing from geosynth, so the backends, the API modules and the CLI
can all import it without a cycle.

| variable | read or set | used by | meaning |
|---|---|---|---|
| ``GEOSYNTH_VERBOSE`` | read | :func:`verbose` (the runtimes' loading, OpenCL builds) | ``1``: let Warp and PoCL print their own messages. The CLI's ``--verbose`` calls :func:`set_verbose` instead; processes started by the tiled path (Dask workers) read only the variable |
| ``GEOSYNTH_HOST_THREADS`` | read | :func:`host_threads_setting` (``geosynth.compute.host_steps.host_threads``) | how many parts the compiled host steps cut work into (a whole number >= 1; default: the cores this process may use) |
| ``GEOSYNTH_MEMORY_LIMIT`` | read | :func:`memory_limit_setting` (``geosynth.core.memory.available_memory``) | a cap on the memory budget (bytes, or with a K, M, G or T suffix) |
| ``XDG_CACHE_HOME`` | read | :func:`cache_root` | where geosynth keeps its OpenCL device probe memo (``$XDG_CACHE_HOME/geosynth``, default ``~/.cache/geosynth``) |
| ``POCL_*`` | read | :func:`pocl_settings` | PoCL's settings that change what its compiler builds: part of the probe memo's key |
| ``POCL_AFFINITY`` | set (default ``1``) | :func:`default_pocl_environment` | pin PoCL's worker threads, when this process may run on every core |
| ``POCL_SIGFPE_HANDLER`` | set (default ``0``) | :func:`default_pocl_environment` | no SIGFPE handler (PoCL's leaves a temporary file per start) |
| ``OMP_WAIT_POLICY`` | set (default ``PASSIVE``) | :func:`passive_openmp_threads` | pykdtree's OpenMP threads sleep after a query |

"Set" means set only when the user has not: a value in the environment always wins.

Process-wide state: every module-level cache and lock is made here and named in this table
(the modules that use one import it from here; ``tests/test_config.py`` finds any other).

| object | used by | what it holds |
|---|---|---|
| ``OPENCL_CONTEXTS`` | ``geosynth._backends.opencl_backend`` | (platform, device) -> (device, context, built programs), one context per device per process |
| ``WARP_INIT_NOTES`` | ``geosynth.compute.backend`` | what Warp's start-up said and was held back (the missing CUDA driver), shown when a cuda device is asked for |
| ``HOST_WARP_DTYPES``, ``HOST_WARP_STATE`` | ``geosynth.compute.host_steps`` | NumPy -> Warp dtypes; Warp's module and its cpu device, once loaded |
| ``HOST_POOLS``, ``HOST_POOL_LOCK`` | ``geosynth.compute.host_steps`` | the helper threads of the compiled host steps, by count, and the lock that makes them |
| ``HOST_LOAD_LOCK``, ``HOST_LAUNCHED`` | ``geosynth.compute.host_steps`` | Warp's module loading, one thread at a time; the kernels launched once (later launches may run in parallel) |
| ``HOST_SHARE`` | ``geosynth.compute.host_steps`` | per thread: the ``CoreShare`` it counts in |
| ``BLEND_TABLES`` | ``geosynth.pointtexture.blending`` | per thread: the Gauss table, wrapped for Warp once |
| ``PATCH_SEARCH_LOCK`` | ``geosynth.pointtexture.patch_search`` | one patch search on a device at a time (the device queues are not shared) |
| ``TILE_MATCHERS``, ``TILE_LOCK`` | ``geosynth.volume.tiled`` | per worker process: (key, level) -> M1 matcher; one tile at a time per process |
| ``INPUT_PATHS`` | ``geosynth.io.files`` | the input files this process read (an output may never replace one) |

Not here, on purpose: the memoized functions (``functools.lru_cache``: the runtimes' loading and
the OpenCL device inventory in ``geosynth.compute.backend``, ``geosynth.io.pictures``'s and
``geosynth.pointtexture.warping``'s tables), each a cache of its own function's result; ``geosynth.io.files``'
current output stage (rebound per ``staged_outputs`` block); the CLI's signal lists
(``geosynth.cli``, ``geosynth._launch``), which belong to the command line's process only.
"""

from __future__ import annotations

import os
import threading
from typing import Any

__all__ = ["ENV_HOST_THREADS", "ENV_MEMORY_LIMIT", "ENV_VERBOSE", "cache_root", "default_pocl_environment",
           "host_threads_setting", "memory_limit_setting", "passive_openmp_threads", "pocl_settings", "set_verbose",
           "verbose"]

ENV_VERBOSE = "GEOSYNTH_VERBOSE"
ENV_HOST_THREADS = "GEOSYNTH_HOST_THREADS"
ENV_MEMORY_LIMIT = "GEOSYNTH_MEMORY_LIMIT"

_verbose: bool | None = None  # set_verbose's value; None: the environment decides


def verbose() -> bool:
    """Whether the runtimes may print their own messages: :func:`set_verbose`'s value when it
    was given one, else ``GEOSYNTH_VERBOSE`` (anything but empty, 0, false or no)."""
    if _verbose is not None:
        return _verbose
    return os.environ.get(ENV_VERBOSE, "").strip().lower() not in ("", "0", "false", "no")


def set_verbose(on: bool | None) -> None:
    """Say (True/False) whether the runtimes may print their messages in this process, or
    (None) leave it to ``GEOSYNTH_VERBOSE`` again. Read when a runtime loads (once per
    process) and at each OpenCL program build. The CLI passes ``--verbose`` here."""
    global _verbose
    _verbose = None if on is None else bool(on)


def host_threads_setting() -> int | None:
    """``GEOSYNTH_HOST_THREADS`` as a whole number >= 1, None when unset.

    Raises:
        ValueError: it is set to anything else (one line naming the variable).
    """
    text = os.environ.get(ENV_HOST_THREADS, "").strip()
    if not text:
        return None
    try:
        count = int(text)
    except ValueError:
        count = 0
    if count < 1:
        raise ValueError(f"{ENV_HOST_THREADS} must be a whole number >= 1, got {text!r}.")
    return count


def memory_limit_setting() -> str | None:
    """``GEOSYNTH_MEMORY_LIMIT`` as written (``geosynth.core.memory.parse_bytes`` reads it), None
    when unset or blank."""
    text = os.environ.get(ENV_MEMORY_LIMIT, "").strip()
    return text or None


def cache_root() -> str:
    """geosynth's cache folder: ``$XDG_CACHE_HOME/geosynth``, else ``~/.cache/geosynth``."""
    return os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "geosynth")


# PoCL variables that say where it caches or how it runs, not what its compiler builds
_POCL_UNRELATED = ("POCL_CACHE_DIR", "POCL_AFFINITY", "POCL_SIGFPE_HANDLER")


def pocl_settings() -> list[tuple[str, str]]:
    """The ``POCL_*`` variables that may change what PoCL's compiler builds, sorted (name, value)."""
    return sorted((k, v) for k, v in os.environ.items() if k.startswith("POCL_") and k not in _POCL_UNRELATED)


def default_pocl_environment() -> None:
    """PoCL's settings geosynth chooses, each unless the user chose otherwise; read once, when
    PoCL starts (a no-op for other OpenCL drivers):

    - ``POCL_AFFINITY=1``: pin its worker threads, one per core, when this process may run on
      every core (PoCL pins thread i to CPU i). Measured (PoCL 3.1, 2 cores): M1's fused
      search, one ~0.1 ms launch per query, 0.17-0.18 ms a match pinned against 0.26-0.34 ms
      unpinned (the threads' wake-ups and migrations between launches cost more than the kernel).
    - ``POCL_SIGFPE_HANDLER=0``: PoCL 3.0/3.1 install a SIGFPE handler (it skips integer
      divisions by zero in kernels) and, to order LLVM's signal handlers first, create an empty
      ``tempfile_XXXXXX`` in the cache folder that is never removed: one per PoCL library per
      process. geosynth's kernels only divide by sizes the API has checked (>= 1), and Warp's
      CPU kernels run without such a handler too.
    """
    try:
        every_core = os.sched_getaffinity(0) == set(range(os.cpu_count() or 0))
    except (AttributeError, OSError):  # not Linux
        every_core = False
    if every_core:
        os.environ.setdefault("POCL_AFFINITY", "1")
    os.environ.setdefault("POCL_SIGFPE_HANDLER", "0")


def passive_openmp_threads() -> None:
    """``OMP_WAIT_POLICY=PASSIVE`` unless the user set it: the kNN query's OpenMP threads
    (pykdtree's own libgomp reads it once, when it loads, which is at the first
    ``geosynth.texturing.models.knn_table``) then sleep when the query ends instead of spinning
    on, which took a core from the one-work-item kernels that follow. Measured (2 cores,
    16k-point sphere): the growth right after the kNN 9.0 ms median against 14.5 ms; the whole
    parameterization row 27-29 ms against 32-37 ms in alternating runs; the kNN itself and the
    larger models' rows unchanged."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


# ---------------------------------------------------------------- process-wide state (table above)

OPENCL_CONTEXTS: dict[tuple[int, int], tuple[Any, Any, dict]] = {}
WARP_INIT_NOTES: list[str] = []
HOST_WARP_DTYPES: dict[Any, Any] = {}
HOST_WARP_STATE: dict[str, Any] = {}
HOST_POOLS: dict[int, Any] = {}
HOST_POOL_LOCK = threading.Lock()
HOST_LOAD_LOCK = threading.RLock()
HOST_LAUNCHED: set = set()
HOST_SHARE = threading.local()
BLEND_TABLES = threading.local()
PATCH_SEARCH_LOCK = threading.Lock()
TILE_MATCHERS: dict = {}
TILE_LOCK = threading.Lock()
INPUT_PATHS: set[str] = set()
