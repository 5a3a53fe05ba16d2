"""OpenCL backend: builds ``kernels/*.cl`` once per context and dtype, launches them.

Buffers are plain ``cl.Buffer`` objects with 64 spare bytes past the data, so that
the 16-wide kernels (``ssd_gather_x16``) may read a full vector at the last element.
"""

from __future__ import annotations

from importlib import resources

import numpy as np
import pyopencl as cl

from geosynth._backends.base import Backend
from geosynth.backend import DeviceArray

_SPARE_BYTES = 64  # >= 16 elements of the widest type read by a 16-wide load
_DENSE_LOCAL = 64  # work-items per group in ssd_dense; the range is padded to it


def _kernel_dir() -> str:
    return str(resources.files("geosynth.kernels"))


def _read_source(name: str) -> str:
    return (resources.files("geosynth.kernels") / name).read_text()


class OpenCLBackend(Backend):
    """PyOpenCL on ``"opencl:P:D"`` (platform P, device D)."""

    def __init__(self, platform_index: int, device_index: int):
        platform = cl.get_platforms()[platform_index]
        self.cl_device = platform.get_devices()[device_index]
        self.name = f"opencl:{platform_index}:{device_index}"
        self.kind = "opencl"
        self.context = cl.Context([self.cl_device])
        self.queue = cl.CommandQueue(self.context)
        self.is_cpu = bool(self.cl_device.type & cl.device_type.CPU)
        self.partial_threads = 4096 if self.is_cpu else 65536
        self._programs: dict[tuple, cl.Program] = {}
        self._kernels: dict[tuple, cl.Kernel] = {}
        self._dummies: dict[np.dtype, DeviceArray] = {}

    # -- programs -------------------------------------------------------------------
    def _kernel(self, family: str, name: str, data_dtype, tb: int = 1) -> cl.Kernel:
        """The kernel ``name`` of ``kernels/{family}.cl`` built for one data dtype."""
        u8 = np.dtype(data_dtype) in (np.dtype(np.uint8), np.dtype(np.uint32))
        key = (family, name, u8, tb)
        kernel = self._kernels.get(key)
        if kernel is None:
            pkey = (family, u8, tb)
            program = self._programs.get(pkey)
            if program is None:
                options = ["-I", _kernel_dir(), f"-DGS_TB={tb}"] + (["-DGS_U8"] if u8 else [])
                program = cl.Program(self.context, _read_source(f"{family}.cl")).build(options=options)
                self._programs[pkey] = program
            kernel = self._kernels[key] = getattr(program, name)
        return kernel

    # -- memory -------------------------------------------------------------------
    def to_device(self, array: np.ndarray) -> DeviceArray:
        host = np.ascontiguousarray(array)
        buf = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, host.nbytes + _SPARE_BYTES)
        if host.nbytes:
            cl.enqueue_copy(self.queue, buf, host, is_blocking=False)
        # The spare bytes are zeroed so that a 16-wide read past the end is harmless.
        cl.enqueue_fill_buffer(self.queue, buf, np.uint8(0), host.nbytes, _SPARE_BYTES)
        return DeviceArray(buf, self, host.shape, host.dtype)

    def empty(self, shape, dtype) -> DeviceArray:
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        buf = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, nbytes + _SPARE_BYTES)
        return DeviceArray(buf, self, shape, dtype)

    def to_host(self, array: DeviceArray) -> np.ndarray:
        host = np.empty(array.shape, array.dtype)
        if host.size:
            # sync: a blocking copy waits for every kernel queued before it.
            cl.enqueue_copy(self.queue, host, array.data, is_blocking=True)
        return host

    def synchronize(self) -> None:
        self.queue.finish()

    def _dummy(self, dtype) -> cl.Buffer:
        dtype = np.dtype(dtype)
        if dtype not in self._dummies:
            self._dummies[dtype] = self.to_device(np.zeros(1, dtype))
        return self._dummies[dtype].data

    # -- kernels --------------------------------------------------------------------
    def ssd_dense(self, candidates, queries, weights, n, d, b, out) -> None:
        tb = 1 if b == 1 else (4 if b <= 4 else 8)
        kernel = self._kernel("ssd", "ssd_dense", candidates.dtype, tb)
        w = weights.data if weights is not None else self._dummy(out.dtype)
        gsize = -(-n // _DENSE_LOCAL) * _DENSE_LOCAL
        kernel(
            self.queue, (gsize,), (_DENSE_LOCAL,),
            candidates.data, queries.data, w, np.int32(weights is not None),
            np.int32(n), np.int32(d), np.int32(b), out.data,
        )

    def ssd_gather(self, grid, bases, lattice, steps, base0, offsets, values, weights, kc, out) -> None:
        nx, ny, nz = lattice
        vector_x = bases is None and steps[0] == 1
        name = "ssd_gather_x16" if vector_x else "ssd_gather"
        kernel = self._kernel("ssd", name, grid.dtype)
        gsize = (-(-nx // 16) if vector_x else nx, ny, nz)
        b = bases.data if bases is not None else self._dummy(np.int32)
        w = weights.data if weights is not None else self._dummy(out.dtype)
        kernel(
            self.queue, gsize, None,
            grid.data, b, np.int32(bases is not None),
            np.int32(nx), np.int32(ny), np.int32(nz),
            *(np.int32(s) for s in steps), np.int32(base0),
            offsets.data, values.data, w, np.int32(weights is not None), np.int32(kc), out.data,
        )

    def argmin_partials(self, scores, n, part_val, part_idx) -> None:
        kernel = self._kernel("ssd", "argmin_partials", scores.dtype)
        kernel(self.queue, (part_idx.size,), None, scores.data, np.int32(n), part_val.data, part_idx.data)

    def count_selected(self, scores, n, chunk, thr, mode, counts) -> None:
        kernel = self._kernel("ssd", "count_selected", scores.dtype)
        kernel(self.queue, (counts.size,), None, scores.data, np.int32(n), np.int32(chunk), thr.data, np.int32(mode), counts.data)

    def compact_selected(self, scores, n, chunk, thr, mode, starts, out_idx) -> None:
        kernel = self._kernel("ssd", "compact_selected", scores.dtype)
        kernel(
            self.queue, (starts.size,), None,
            scores.data, np.int32(n), np.int32(chunk), thr.data, np.int32(mode), starts.data, out_idx.data,
        )
