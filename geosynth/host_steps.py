"""Where do the compiled host steps run? Implements no paper section.

Some steps decide bits that go straight into an output (M2's blended positions, the float64
recomputation of a search's flagged samples, the warped points): they must give the same
bits whatever ``device=`` a run uses. DESIGN.md allows two ways: the same values on every
backend, or computed once in one place for all of them. These steps take the second:
they are Warp kernels (``geosynth.kernels.host_*``, float64) launched on Warp's ``"cpu"``
device for every run, whichever device the run's kernels use, so cpu, opencl and cuda
runs share them bit for bit. They replace per-element NumPy passes (each a Python call
and a pass over memory) with one compiled loop per query; Warp's CPU device runs them on
one thread, like the NumPy they replace.

Each such kernel has a plain NumPy twin (its oracle, beside the caller or in
``geosynth.reference``) and a test comparing them to a float64 tolerance; they are not
required to agree bit for bit with NumPy (its sums are pairwise, the kernels' sequential).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

_DTYPES: dict[np.dtype, Any] = {}
_STATE: dict[str, Any] = {}  # Warp's module and its cpu device, once loaded


def _warp():
    wp = _STATE.get("wp")
    if wp is not None:
        return wp
    from geosynth.backend import warp_module

    wp = warp_module()
    _DTYPES.update({np.dtype(np.float64): wp.float64, np.dtype(np.float32): wp.float32,
                    np.dtype(np.int32): wp.int32, np.dtype(np.int64): wp.int64,
                    np.dtype(np.uint8): wp.uint8, np.dtype(np.int8): wp.int8,
                    np.dtype(np.uint32): wp.uint32})
    _STATE["cpu"] = wp.get_device("cpu")
    _STATE["wp"] = wp
    return wp


def host_array(array: np.ndarray, dtype=None):
    """A Warp ``"cpu"`` array over ``array``'s memory (no copy), flattened.

    Args:
        array: any shape; made C-contiguous in ``dtype`` (default its own) first, which
            copies only when it is not already. Writes by a kernel land in the returned
            array's memory: pass an array you own (e.g. from ``np.empty``) for outputs.
        dtype: a NumPy dtype among float64, float32, int64, int32, int8, uint8, uint32.

    Returns:
        ``(warp_array, numpy_array)``: the Warp view and the contiguous NumPy array it
        views (the Warp view also holds a reference to that memory, so either may be kept
        alone).
    """
    wp = _warp()
    a = np.ascontiguousarray(array, dtype=dtype)
    flat = a.reshape(-1)
    if flat.size == 0:  # Warp wants memory behind a launch argument
        flat = np.zeros(1, a.dtype)
    # From the pointer: about half the Python work of wp.array(flat, copy=False) (~13 us
    # against ~24 us a call; a patch of M2 wraps about 80 arrays).
    kind = _DTYPES.get(a.dtype)
    if kind is None:  # a programming error of a caller, never user input
        raise TypeError(f"host_array: dtype {a.dtype} has no Warp twin here; use one of "
                        f"{', '.join(str(d) for d in _DTYPES)}.")
    view = wp.array(ptr=flat.__array_interface__["data"][0], shape=(flat.size,), dtype=kind, device=_STATE["cpu"])
    view._geosynth_memory = flat  # the memory lives as long as the view
    return view, a


def host_launch(kernel, dim: int, inputs: Sequence[Any]) -> None:
    """Launch a ``geosynth.kernels.host_*`` kernel over ``dim`` threads on Warp's CPU
    device (no-op for ``dim == 0``); ``inputs`` as :func:`warp.launch` takes them (Warp
    arrays from :func:`host_array`, Python ints and floats for scalars)."""
    wp = _warp()
    if dim <= 0:
        return
    wp.launch(kernel, dim=int(dim), inputs=list(inputs), device=_STATE["cpu"])
