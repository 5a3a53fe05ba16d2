"""How does a Warp device launch the kernels? Implements no paper section.

Warp backend: launches the kernels of ``geosynth.kernels.ssd`` on a Warp device.

Warp compiles one binary per Python module per device; ``geosynth.kernels.ssd`` is
loaded once per device and reused. On the CPU Warp runs kernels on one thread.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from geosynth._backends.base import Backend
from geosynth._backends.warp_cascade import WarpCascadeOps
from geosynth._backends.warp_growth import WarpGrowthOps
from geosynth._backends.warp_mesh import WarpMeshOps
from geosynth._backends.warp_points import WarpPointsOps
from geosynth._backends.warp_pyramid import WarpPyramidOps
from geosynth._backends.warp_relief import WarpReliefOps
from geosynth._backends.warp_texel import WarpTexelOps
from geosynth.core.arrays import DeviceArray
from geosynth.kernels import ssd as ssd_kernels

_WARP_DTYPES = {
    np.dtype(np.float32): wp.float32,
    np.dtype(np.float64): wp.float64,
    np.dtype(np.uint8): wp.uint8,
    np.dtype(np.uint32): wp.uint32,
    np.dtype(np.int32): wp.int32,
    np.dtype(np.int64): wp.int64,
}


class WarpBackend(WarpCascadeOps, WarpGrowthOps, WarpMeshOps, WarpPointsOps, WarpPyramidOps, WarpTexelOps, WarpReliefOps, Backend):
    """Warp on ``"cpu"`` or ``"cuda:N"``."""

    def __init__(self, name: str):
        self.name = name
        self.device = wp.get_device(name)
        self.kind = "cpu" if self.device.is_cpu else "cuda"
        # One thread per share of a reduction; many on a GPU, few on one CPU thread.
        self.partial_threads = 65536 if self.device.is_cuda else 256
        self.host_reduce_below = 0 if self.device.is_cuda else 1 << 16
        self.search_items = 1 << 16 if self.device.is_cuda else 1  # one CPU thread: one item, the best pruning
        self._dummies: dict[np.dtype, DeviceArray] = {}

    # -- memory -------------------------------------------------------------------
    def to_device(self, array: np.ndarray) -> DeviceArray:
        flat = np.ascontiguousarray(array).reshape(-1)
        data = wp.array(flat, dtype=_WARP_DTYPES[flat.dtype], device=self.device)
        return DeviceArray(data, self, array.shape, array.dtype)

    def empty(self, shape, dtype) -> DeviceArray:
        dtype = np.dtype(dtype)
        size = int(np.prod(shape, dtype=np.int64))
        data = wp.empty(max(size, 1), dtype=_WARP_DTYPES[dtype], device=self.device)
        return DeviceArray(data, self, shape, dtype)

    def to_host(self, array: DeviceArray) -> np.ndarray:
        # sync: .numpy() waits for the device. On the CPU it is a view of the device array
        # itself: copy, so that a later kernel writing that array cannot change the result.
        host = array.data.numpy()[: array.size].reshape(array.shape)
        return host.copy() if self.device.is_cpu else host

    def synchronize(self) -> None:
        wp.synchronize_device(self.device)

    def _dummy(self, dtype) -> wp.array:
        """A one-element array standing in for an unused optional input."""
        dtype = np.dtype(dtype)
        if dtype not in self._dummies:
            self._dummies[dtype] = self.empty((1,), dtype)
        return self._dummies[dtype].data

    def _launch(self, kernel, dim, inputs) -> None:
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device)

    # -- kernels --------------------------------------------------------------------
    def ssd_dense(self, candidates, queries, weights, n, d, b, out) -> None:
        w = weights.data if weights is not None else self._dummy(out.dtype)
        self._launch(
            ssd_kernels.ssd_dense_kernel,
            (b, n),
            [candidates.data, queries.data, w, int(weights is not None), n, d, b, out.data],
        )

    def ssd_gather(self, grid, bases, lattice, steps, base0, offsets, values, weights, kc, threshold, out,
                   run: int = 0) -> None:
        nx, ny, nz = lattice  # run: one kernel serves every layout here
        b = bases.data if bases is not None else self._dummy(np.int32)
        w = weights.data if weights is not None else self._dummy(out.dtype)
        self._launch(
            ssd_kernels.ssd_gather_kernel,
            (nz, ny, nx),
            [grid.data, b, int(bases is not None), nx, ny, nz, *steps, base0,
             offsets.data, values.data, w, int(weights is not None), kc,
             threshold.data if threshold is not None else self._dummy(out.dtype), int(threshold is not None), out.data],
        )

    def argmin_partials(self, scores, n, part_val, part_idx) -> None:
        self._launch(ssd_kernels.argmin_partials_kernel, part_idx.size, [scores.data, n, part_val.data, part_idx.data, part_idx.size])

    def count_selected(self, scores, n, chunk, thr, mode, counts) -> None:
        self._launch(ssd_kernels.count_selected_kernel, counts.size, [scores.data, n, chunk, thr.data, mode, counts.data, counts.size])

    def compact_selected(self, scores, n, chunk, thr, mode, starts, out_idx) -> None:
        self._launch(
            ssd_kernels.compact_selected_kernel,
            starts.size,
            [scores.data, n, chunk, thr.data, mode, starts.data, out_idx.data, starts.size],
        )
