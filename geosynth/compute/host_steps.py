"""Where do the compiled host steps run? Implements no paper section.

Some steps decide bits that go straight into an output (M2's blended positions, the float64
recomputation of a search's flagged samples, the warped points): they must give the same
bits whatever ``device=`` a run uses. DESIGN.md allows two ways: the same values on every
backend, or computed once in one place for all of them. These steps take the second:
they are Warp kernels (``geosynth.kernels.host_*``, float64) launched on Warp's ``"cpu"``
device for every run, whichever device the run's kernels use, so cpu, opencl and cuda
runs share them bit for bit. They replace per-element NumPy passes (each a Python call
and a pass over memory) with one compiled loop per query. Warp's CPU device runs a launch
on one thread; a launch whose threads are independent (``split=True``) is cut into one
part per core, the parts launched at once from a pool of Python threads (Warp lets go of
the GIL while a CPU launch runs): each item is computed by the same code whichever part
holds it, so the bits do not depend on the number of cores. :func:`run_parts` does the
same for NumPy loops over independent chunks.

Each such kernel has a plain NumPy twin (its oracle, beside the caller or in a
method's ``reference`` module) and a test comparing them to a float64 tolerance; they are not
required to agree bit for bit with NumPy (its sums are pairwise, the kernels' sequential).
"""

from __future__ import annotations

import contextlib
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np

from geosynth.core.config import (HOST_LAUNCHED, HOST_LOAD_LOCK, HOST_POOL_LOCK, HOST_POOLS, HOST_SHARE, HOST_WARP_DTYPES,
                             HOST_WARP_STATE, host_threads_setting)


def _warp():
    wp = HOST_WARP_STATE.get("wp")
    if wp is not None:
        return wp
    with HOST_LOAD_LOCK:
        if "wp" not in HOST_WARP_STATE:
            _load()
    return HOST_WARP_STATE["wp"]


def _load() -> None:
    """Warp, its cpu device and every host kernel module, loaded once: loading a module
    (hashing it and the modules it uses) is not safe from two threads at once, and the
    steps run from several (run_parts, and M2's growth of two rows)."""
    from geosynth.compute.backend import warp_module
    from geosynth.kernels import host_blend, host_search, host_warp

    wp = warp_module()
    HOST_WARP_DTYPES.update({np.dtype(np.float64): wp.float64, np.dtype(np.float32): wp.float32,
                             np.dtype(np.int32): wp.int32, np.dtype(np.int64): wp.int64,
                             np.dtype(np.uint8): wp.uint8, np.dtype(np.int8): wp.int8,
                             np.dtype(np.uint32): wp.uint32})
    HOST_WARP_STATE["cpu"] = wp.get_device("cpu")
    for module in (host_search, host_warp, host_blend):
        wp.load_module(module, device=HOST_WARP_STATE["cpu"])
    HOST_WARP_STATE["wp"] = wp


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
    kind = HOST_WARP_DTYPES.get(a.dtype)
    if kind is None:  # a programming error of a caller, never user input
        raise TypeError(f"host_array: dtype {a.dtype} has no Warp twin here; use one of "
                        f"{', '.join(str(d) for d in HOST_WARP_DTYPES)}.")
    view = wp.array(ptr=flat.__array_interface__["data"][0], shape=(flat.size,), dtype=kind,
                    device=HOST_WARP_STATE["cpu"])
    view._geosynth_memory = flat  # the memory lives as long as the view
    return view, a


class CoreShare:
    """The threads that now run work of a group (M2's growth of two rows at once): within
    :meth:`busy`, a thread counts on 1 / (threads busy) of the cores, so that their parts
    do not oversubscribe them, and a thread left alone (the other waiting, or done) gets
    all of them back (measured, chainmail on 2 cores: two rows with whole launches
    3.8-4.0 s, with launches split in two as well 4.3-4.5 s)."""

    def __init__(self):
        self.threads = 0
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def busy(self):
        before = getattr(HOST_SHARE, "group", None)
        with self._lock:
            self.threads += 1
        HOST_SHARE.group = self
        try:
            yield
        finally:
            with self._lock:
                self.threads -= 1
            HOST_SHARE.group = before


def host_threads() -> int:
    """How many parts :func:`host_launch` (``split=True``) and :func:`run_parts` cut work
    into: the cores this process may use (``GEOSYNTH_HOST_THREADS`` overrides; at most 16),
    divided among the busy threads of the calling thread's :class:`CoreShare`."""
    count = host_threads_setting()
    if count is None:
        count = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    group = getattr(HOST_SHARE, "group", None)
    return max(1, min(16, count) // max(1, group.threads if group is not None else 1))


def _pool(helpers: int) -> ThreadPoolExecutor:
    with HOST_POOL_LOCK:
        pool = HOST_POOLS.get(helpers)
        if pool is None:
            pool = ThreadPoolExecutor(max_workers=helpers, thread_name_prefix="geosynth-host")
            HOST_POOLS[helpers] = pool
        return pool


def part_bounds(count: int, parts: int, quantum: int = 1) -> list[tuple[int, int]]:
    """``count`` items cut into at most ``parts`` contiguous ``(lo, hi)`` ranges of nearly
    equal size, every boundary but the last a multiple of ``quantum`` (empty ranges left out)."""
    blocks = -(-int(count) // int(quantum))
    parts = max(1, min(int(parts), blocks))
    cuts = [min(count, (blocks * j // parts) * quantum) for j in range(parts + 1)]
    return [(lo, hi) for lo, hi in zip(cuts[:-1], cuts[1:]) if hi > lo]


def run_parts(fn: Callable[[int, int], None], count: int, *, quantum: int = 1, min_part: int = 1) -> None:
    """Call ``fn(lo, hi)`` over ``count`` items cut into :func:`host_threads` contiguous
    ranges (boundaries multiples of ``quantum``; no part smaller than ``min_part`` items
    unless there is only one), at once: the calling thread runs the first part, pool
    threads the others. ``fn`` must touch only its own range's outputs and let go of the
    GIL for its heavy work (NumPy's large ufuncs and products, Warp's CPU launches) for
    this to gain anything. An exception in any part is raised here once all have ended."""
    if count <= 0:
        return
    parts = max(1, min(host_threads(), int(count) // max(1, int(min_part))))
    bounds = part_bounds(count, parts, quantum)
    if len(bounds) == 1:
        fn(*bounds[0])
        return
    futures = [_pool(len(bounds) - 1).submit(fn, lo, hi) for lo, hi in bounds[1:]]
    try:
        fn(*bounds[0])
    finally:
        errors = [f.exception() for f in futures]
    for error in errors:
        if error is not None:
            raise error


def host_launch(kernel, dim: int, inputs: Sequence[Any], *, split: bool = False, min_part: int = 64) -> None:
    """Launch a ``geosynth.kernels.host_*`` kernel over ``dim`` threads on Warp's CPU
    device (no-op for ``dim == 0``); ``inputs`` as :func:`warp.launch` takes them (Warp
    arrays from :func:`host_array`, Python ints and floats for scalars).

    split: the kernel's last parameter is ``part_start: int``, the index of its thread 0 (its
        thread t computes item ``part_start + t`` and writes only that item's outputs or its
        own scratch slot; this function appends ``part_start``): the launch is cut by
        :func:`run_parts` into one part of at least ``min_part`` threads per core, run at
        once, the same bits as one launch. The first launch of a kernel runs whole, one
        thread at a time (it may load the kernel's module; the host_* modules are loaded
        with Warp, before any launch)."""
    wp = _warp()
    if dim <= 0:
        return
    device = HOST_WARP_STATE["cpu"]
    args = list(inputs) + ([0] if split else [])
    launched = (kernel.module.name, kernel.key)
    if launched not in HOST_LAUNCHED:  # its module may load now: one thread at a time, whole
        with HOST_LOAD_LOCK:
            wp.launch(kernel, dim=int(dim), inputs=args, device=device)
            HOST_LAUNCHED.add(launched)
        return
    if not split:
        wp.launch(kernel, dim=int(dim), inputs=args, device=device)
        return
    args.pop()

    def part(lo: int, hi: int) -> None:
        wp.launch(kernel, dim=hi - lo, inputs=args + [lo], device=device)

    run_parts(part, int(dim), min_part=min_part)
