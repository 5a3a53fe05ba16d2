"""How does a Warp device launch the block pyramid kernels? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.1-4.3.

Warp backend methods for block pyramids (mixed into WarpBackend).

Launches the kernels of ``geosynth.kernels.pyramid`` (one method per kernel, same
arguments in the same order as ``OpenCLPyramidOps``). Methods use the host
WarpBackend's helpers: self.device, self._launch(kernel, dim, inputs),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from geosynth._backends.interfaces import PyramidOps
from geosynth.core.arrays import DeviceArray
from geosynth.kernels import pyramid as pyramid_kernels

_WIDE = {np.dtype(np.int64): wp.int64, np.dtype(np.uint64): wp.uint64}


class WarpPyramidOps(PyramidOps):
    """Mixin: the block-pyramid kernels on a Warp device."""

    # -- memory for the 64-bit arrays the pyramid kernels use -----------------------
    def pyramid_empty(self, shape, dtype) -> DeviceArray:
        dtype = np.dtype(dtype)
        if dtype not in _WIDE:
            return self.empty(shape, dtype)
        size = int(np.prod(shape, dtype=np.int64))
        data = wp.empty(max(size, 1), dtype=_WIDE[dtype], device=self.device)
        return DeviceArray(data, self, shape, dtype)

    def pyramid_read(self, array: DeviceArray, count: int) -> np.ndarray:
        # sync: the orchestrator needs these values now.
        return array.data[:count].numpy().copy() if count else np.zeros(0, array.dtype)

    def pyramid_read_all(self, array: DeviceArray) -> np.ndarray:
        # sync: read back for host-side grouping.
        return array.data.numpy()[: array.size].reshape(array.shape).copy()

    def pyramid_write(self, array: DeviceArray, host: np.ndarray) -> None:
        src = wp.array(np.ascontiguousarray(host).reshape(-1), dtype=array.data.dtype, device=self.device)
        wp.copy(array.data, src, count=src.size)

    # -- kernels --------------------------------------------------------------------
    def pyramid_init(self, field, sums, total) -> None:
        self._launch(pyramid_kernels.pyramid_init_kernel, total, [field.data, sums.data, total])

    def pyramid_double(self, sums, src_off, dst_off, c, nz, ny, nx) -> None:
        self._launch(pyramid_kernels.pyramid_double_kernel, nz * ny * nx, [sums.data, src_off, dst_off, c, nz, ny, nx])

    def pyramid_quantize(self, sums, off, lc, total, out) -> None:
        self._launch(pyramid_kernels.pyramid_quantize_kernel, total, [sums.data, off, lc, total, out.data])

    def pyramid_compare(self, sums, total, ny, nx, log_block, node_base, node_code, ids, first, count,
                        query, query_off, out) -> None:
        if count:
            self._launch(
                pyramid_kernels.pyramid_compare_kernel, count,
                [sums.data, total, ny, nx, log_block, node_base.data, node_code.data, ids.data, first, count,
                 query.data, query_off.data, out.data],
            )

    def pyramid_hash_init(self, sums, off, lc, quantized, total, out) -> None:
        self._launch(pyramid_kernels.pyramid_hash_init_kernel, total, [sums.data, off, lc, quantized, total, out.data])

    def pyramid_hash_step(self, src, dst, total, stride, mult) -> None:
        self._launch(pyramid_kernels.pyramid_hash_step_kernel, total, [src.data, dst.data, total, stride, wp.uint64(mult)])

    def pyramid_pair_equal(self, sums, total, ny, nx, lc, n, quantized, base_a, base_b, count, out) -> None:
        if count:
            self._launch(
                pyramid_kernels.pyramid_pair_equal_kernel, count,
                [sums.data, total, ny, nx, lc, n, quantized, base_a.data, base_b.data, count, out.data],
            )
