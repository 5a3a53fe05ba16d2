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

from geosynth.arrays import DeviceArray
from geosynth.kernels import pyramid as pyramid_kernels

_WIDE = {np.dtype(np.int64): wp.int64, np.dtype(np.uint64): wp.uint64}


class WarpPyramidOps:
    """Mixin: the block-pyramid kernels on a Warp device."""

    # -- memory for the 64-bit arrays the pyramid kernels use -----------------------
    def pyramid_empty(self, shape, dtype) -> DeviceArray:
        """An uninitialised device array; also int64 / uint64 (hashes, distances)."""
        dtype = np.dtype(dtype)
        if dtype not in _WIDE:
            return self.empty(shape, dtype)
        size = int(np.prod(shape, dtype=np.int64))
        data = wp.empty(max(size, 1), dtype=_WIDE[dtype], device=self.device)
        return DeviceArray(data, self, shape, dtype)

    def pyramid_read(self, array: DeviceArray, count: int) -> np.ndarray:
        """The first ``count`` entries of a flat device array, as a host copy."""
        # sync: the orchestrator needs these values now.
        return array.data[:count].numpy().copy() if count else np.zeros(0, array.dtype)

    def pyramid_read_all(self, array: DeviceArray) -> np.ndarray:
        """Every entry of a device array (any dtype, shape kept)."""
        # sync: read back for host-side grouping.
        return array.data.numpy()[: array.size].reshape(array.shape).copy()

    def pyramid_write(self, array: DeviceArray, host: np.ndarray) -> None:
        """Copy a host array into the start of an existing device array."""
        src = wp.array(np.ascontiguousarray(host).reshape(-1), dtype=array.data.dtype, device=self.device)
        wp.copy(array.data, src, count=src.size)

    # -- kernels --------------------------------------------------------------------
    def pyramid_init(self, field, sums, total) -> None:
        """sums[:total] <- field widened to uint32 (the cell size 1 slab)."""
        self._launch(pyramid_kernels.pyramid_init_kernel, total, [field.data, sums.data, total])

    def pyramid_double(self, sums, src_off, dst_off, c, nz, ny, nx) -> None:
        """Slab at dst_off <- sums of 2c-cubes from the cell size c slab at src_off."""
        self._launch(pyramid_kernels.pyramid_double_kernel, nz * ny * nx, [sums.data, src_off, dst_off, c, nz, ny, nx])

    def pyramid_quantize(self, sums, off, lc, total, out) -> None:
        """out <- the slab's means rounded half up, uint8."""
        self._launch(pyramid_kernels.pyramid_quantize_kernel, total, [sums.data, off, lc, total, out.data])

    def pyramid_compare(self, sums, total, ny, nx, log_block, node_base, node_code, ids, first, count,
                        query, query_off, out) -> None:
        """out[:count] <- integer level distance D of nodes ids[first:first+count]."""
        if count:
            self._launch(
                pyramid_kernels.pyramid_compare_kernel, count,
                [sums.data, total, ny, nx, log_block, node_base.data, node_code.data, ids.data, first, count,
                 query.data, query_off.data, out.data],
            )

    def pyramid_hash_init(self, sums, off, lc, quantized, total, out) -> None:
        """out <- per-position hash seeds (value + 1) of a slab, exact or rounded."""
        self._launch(pyramid_kernels.pyramid_hash_init_kernel, total, [sums.data, off, lc, quantized, total, out.data])

    def pyramid_hash_step(self, src, dst, total, stride, mult) -> None:
        """dst <- src + mult * src shifted by stride (mod 2^64)."""
        self._launch(pyramid_kernels.pyramid_hash_step_kernel, total, [src.data, dst.data, total, stride, wp.uint64(mult)])

    def pyramid_pair_equal(self, sums, total, ny, nx, lc, n, quantized, base_a, base_b, count, out) -> None:
        """out[t] <- 1 where the level at base_a[t] equals the level at base_b[t]."""
        if count:
            self._launch(
                pyramid_kernels.pyramid_pair_equal_kernel, count,
                [sums.data, total, ny, nx, lc, n, quantized, base_a.data, base_b.data, count, out.data],
            )
