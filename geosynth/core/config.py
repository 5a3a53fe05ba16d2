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
| ``NPY_DISABLE_CPU_FEATURES`` | set (default: NumPy's AVX-512 groups) | :func:`numpy_same_on_every_cpu` (``import geosynth``, before NumPy loads) | NumPy's AVX-512 code rounds float64 exp, log, arctan2, power (and SciPy's Gaussian kernels through them) differently from every other CPU's: same seed, different bits |

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
import sys
import threading
import warnings


__all__ = ["ENV_HOST_THREADS", "ENV_MEMORY_LIMIT", "ENV_NUMPY_FEATURES", "ENV_VERBOSE", "NUMPY_AVX512",
           "cache_root", "default_pocl_environment", "host_threads_setting", "memory_limit_setting",
           "numpy_same_on_every_cpu", "passive_openmp_threads", "pocl_settings", "set_verbose", "verbose"]

ENV_VERBOSE = "GEOSYNTH_VERBOSE"
ENV_HOST_THREADS = "GEOSYNTH_HOST_THREADS"
ENV_MEMORY_LIMIT = "GEOSYNTH_MEMORY_LIMIT"
ENV_NUMPY_FEATURES = "NPY_DISABLE_CPU_FEATURES"
# NumPy's names of its AVX-512 code groups: 2.4 groups them as X86_V4 (+ ICL, SPR); earlier
# releases name each set. A name a NumPy does not dispatch is skipped with an ImportWarning,
# hidden by Python's default filters.
NUMPY_AVX512 = {"new": "X86_V4 AVX512_ICL AVX512_SPR",
                "old": "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"}

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

OPENCL_CONTEXTS: dict[tuple[int, int], tuple[object, object, dict]] = {}
WARP_INIT_NOTES: list[str] = []
HOST_WARP_DTYPES: dict[object, object] = {}
HOST_WARP_STATE: dict[str, object] = {}
HOST_POOLS: dict[int, object] = {}
HOST_POOL_LOCK = threading.Lock()
HOST_LOAD_LOCK = threading.RLock()
HOST_LAUNCHED: set = set()
HOST_SHARE = threading.local()
BLEND_TABLES = threading.local()
PATCH_SEARCH_LOCK = threading.Lock()
TILE_MATCHERS: dict = {}
TILE_LOCK = threading.Lock()
INPUT_PATHS: set[str] = set()


def _numpy_groups() -> str:
    """The AVX-512 group names of the installed NumPy, from its ``version.py`` read as text:
    neither NumPy nor ``importlib.metadata`` is imported (the command line catches Ctrl-C only
    once its package has loaded)."""
    import re
    from importlib.util import find_spec

    try:
        spec = find_spec("numpy")
        with open(os.path.join(list(spec.submodule_search_locations)[0], "version.py")) as f:
            text = f.read()
        major, minor = (int(v) for v in re.search(r'version\s*[:=][^"\']*["\'](\d+)\.(\d+)', text).groups())
    except (AttributeError, ImportError, OSError, TypeError, ValueError, IndexError):
        return NUMPY_AVX512["new"]
    return NUMPY_AVX512["new" if (major, minor) >= (2, 4) else "old"]


def numpy_same_on_every_cpu() -> None:
    """Make NumPy round as it does on every CPU: ``NPY_DISABLE_CPU_FEATURES`` set to NumPy's
    AVX-512 groups (unless the user set it), when NumPy is not loaded yet.

    Same seed and input must give the same bits on every machine. On an AVX-512 CPU NumPy
    dispatches float64 exp, log, log10, arctan2, arccos, power and cbrt (and whatever calls
    them: SciPy's Gaussian filter builds its kernel with exp) to code that rounds differently
    from its AVX2 and SSE code (measured on an AVX-512 Zen VM, NumPy 2.4: M2's heightfield
    exemplar and M4's golf ball changed bits; with these groups off every output is the
    AVX2 machine's). Elementwise + - * / and sqrt, and NumPy's sin and cos, round alike
    everywhere; the AVX2 code stays. Called by ``import geosynth``, which loads nothing
    else. When NumPy was loaded first, its dispatch is fixed: a warning says so once (see
    :func:`warn_if_numpy_differs`).
    """
    if "numpy" in sys.modules:
        warn_if_numpy_differs()
        return
    os.environ.setdefault(ENV_NUMPY_FEATURES, _numpy_groups())


def warn_if_numpy_differs() -> None:
    """Warn (once per process) when the loaded NumPy runs AVX-512 code: its float64
    transcendentals then round unlike other CPUs', and results may differ from another
    machine's in their last bits."""
    global _numpy_warned
    if _numpy_warned:
        return
    import numpy as np

    core = getattr(np, "_core", None) or np.core  # NumPy 2, NumPy 1
    features = core._multiarray_umath.__cpu_features__
    # the hardware's features, not what NumPy dispatches: a group named in the variable (read when
    # NumPy loaded) is off; NumPy 2.4 dispatches its AVX-512 code as X86_V4, earlier ones by set
    disabled = set(os.environ.get(ENV_NUMPY_FEATURES, "").split())
    groups = ("X86_V4",) if "X86_V4" in features else ("AVX512F", "AVX512_SKX")
    active = [k for k in groups if features.get(k) and k not in disabled]
    if active:
        _numpy_warned = True
        warnings.warn(f"NumPy was imported before geosynth and runs its AVX-512 code ({', '.join(active)}), whose "
                      "float64 exp/log/arctan2 round unlike other CPUs': results may differ from another machine's "
                      f"in their last bits. Import geosynth first, or set {ENV_NUMPY_FEATURES}=\"{_numpy_groups()}\" "
                      "before Python starts.", RuntimeWarning, stacklevel=3)


_numpy_warned = False
