"""How does an OpenCL device launch the block pyramid kernels? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.1-4.3.

OpenCL backend methods for block pyramids (mixed into OpenCLBackend).

Launches the kernels of ``kernels/pyramid.cl`` (one method per kernel, same arguments
in the same order as ``WarpPyramidOps``). Methods use the host OpenCLBackend's helpers:
self.queue, self.context, self._kernel("pyramid", name, np.uint8),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from geosynth._backends.interfaces import PyramidOps
from geosynth.core.arrays import DeviceArray

_LOCAL = 64  # work-items per group; always explicit (see opencl_backend._LOCAL_1D)


def _range(count: int) -> tuple[int]:
    return (max(1, -(-count // _LOCAL)) * _LOCAL,)


class OpenCLPyramidOps(PyramidOps):
    """Mixin: the block-pyramid kernels on an OpenCL device."""

    def _pyr(self, name: str) -> cl.Kernel:
        return self._kernel("pyramid", name, np.uint8)

    # -- memory ---------------------------------------------------------------------
    def pyramid_empty(self, shape, dtype) -> DeviceArray:
        return self.empty(shape, dtype)

    def pyramid_read(self, array: DeviceArray, count: int) -> np.ndarray:
        host = np.empty(count, array.dtype)
        if count:
            # sync: a blocking copy waits for the kernel that wrote it.
            cl.enqueue_copy(self.queue, host, array.data, is_blocking=True)
        return host

    def pyramid_read_all(self, array: DeviceArray) -> np.ndarray:
        return self.to_host(array)

    def pyramid_write(self, array: DeviceArray, host: np.ndarray) -> None:
        host = np.ascontiguousarray(host)
        if host.size:
            cl.enqueue_copy(self.queue, array.data, host, is_blocking=False)

    # -- kernels --------------------------------------------------------------------
    def pyramid_init(self, field, sums, total) -> None:
        self._pyr("pyramid_init")(self.queue, _range(total), (_LOCAL,), field.data, sums.data, np.int32(total))

    def pyramid_double(self, sums, src_off, dst_off, c, nz, ny, nx) -> None:
        i32 = np.int32
        self._pyr("pyramid_double")(
            self.queue, _range(nz * ny * nx), (_LOCAL,), sums.data,
            i32(src_off), i32(dst_off), i32(c), i32(nz), i32(ny), i32(nx),
        )

    def pyramid_quantize(self, sums, off, lc, total, out) -> None:
        i32 = np.int32
        self._pyr("pyramid_quantize")(self.queue, _range(total), (_LOCAL,), sums.data, i32(off), i32(lc), i32(total), out.data)

    def pyramid_compare(self, sums, total, ny, nx, log_block, node_base, node_code, ids, first, count,
                        query, query_off, out) -> None:
        if not count:
            return
        i32 = np.int32
        self._pyr("pyramid_compare")(
            self.queue, _range(count), (_LOCAL,), sums.data, i32(total), i32(ny), i32(nx), i32(log_block),
            node_base.data, node_code.data, ids.data, i32(first), i32(count), query.data, query_off.data, out.data,
        )

    def pyramid_hash_init(self, sums, off, lc, quantized, total, out) -> None:
        i32 = np.int32
        self._pyr("pyramid_hash_init")(
            self.queue, _range(total), (_LOCAL,), sums.data, i32(off), i32(lc), i32(quantized), i32(total), out.data,
        )

    def pyramid_hash_step(self, src, dst, total, stride, mult) -> None:
        self._pyr("pyramid_hash_step")(
            self.queue, _range(total), (_LOCAL,), src.data, dst.data, np.int32(total), np.int32(stride), np.uint64(mult),
        )

    def pyramid_pair_equal(self, sums, total, ny, nx, lc, n, quantized, base_a, base_b, count, out) -> None:
        if not count:
            return
        i32 = np.int32
        self._pyr("pyramid_pair_equal")(
            self.queue, _range(count), (_LOCAL,), sums.data, i32(total), i32(ny), i32(nx), i32(lc), i32(n),
            i32(quantized), base_a.data, base_b.data, i32(count), out.data,
        )
