"""One BLAS thread while a block of code runs (:func:`single_threaded`).

Why: the M2 synthesis (``geosynth.geometry_texture``) multiplies many small, thin
matrices (the thin-plate spline's (S, n) kernel matrix by its (n, 3) weights, n ~ 200,
once per patch). A multi-threaded OpenBLAS splits such a product over its threads and
its idle threads spin while they wait: measured on the shared 2-core VM, the spline
evaluation of a 9,736-point chainmail patch took 226 ms of CPU with OpenBLAS's default
2 threads against 35 ms with one, and the spinning threads also took the cores from
PoCL's workers (the "opencl" device) and from the other processes. The sums of a
threaded product also depend on the thread count (the output then depends on the
machine's core count); with one thread they do not.

Hand-written rather than threadpoolctl (not a dependency here): the wheels of NumPy and
SciPy each load their own OpenBLAS (``scipy_openblas``), whose ``*_set_num_threads``
functions are called through ctypes on the copies this process has loaded (read from
``/proc/self/maps``). Where that is not possible (no such library, not Linux) it does
nothing.
"""

from __future__ import annotations

import ctypes
from contextlib import contextmanager

__all__ = ["single_threaded"]

# (get, set) symbol pairs: scipy-openblas 64-bit-integer builds (NumPy's), 32-bit (SciPy's), plain OpenBLAS
_SYMBOLS = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)

_controls: list | None = None


def _find() -> list:
    """[(get, set)] ctypes functions of every OpenBLAS loaded in this process."""
    found = []
    try:
        with open("/proc/self/maps") as f:
            paths = sorted({line.split()[-1] for line in f if "openblas" in line.lower() and "/" in line})
    except OSError:
        return found
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get_name, set_name in _SYMBOLS:
            get_f, set_f = getattr(lib, get_name, None), getattr(lib, set_name, None)
            if get_f is not None and set_f is not None:
                get_f.restype, get_f.argtypes = ctypes.c_int, []
                set_f.restype, set_f.argtypes = None, [ctypes.c_int]
                found.append((get_f, set_f))
                break
    return found


@contextmanager
def single_threaded():
    """Run the block with one OpenBLAS thread in every loaded OpenBLAS (NumPy's and
    SciPy's), restoring each one's thread count after it."""
    global _controls
    if _controls is None:
        import numpy  # noqa: F401  (load both BLAS copies before looking for them)
        import scipy.linalg  # noqa: F401

        _controls = _find()
    saved = [(get_f(), set_f) for get_f, set_f in _controls]
    for n, set_f in saved:
        if n != 1:
            set_f(1)
    try:
        yield
    finally:
        for n, set_f in saved:
            if n != 1:
                set_f(n)
