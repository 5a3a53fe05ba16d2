"""How does an OpenCL device launch the batched texel search? Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 4 (eq. 5).

OpenCL backend methods for the batched M3 texel search (mixed into OpenCLBackend).

Implements geosynth._backends.interfaces.TexelOps (the docstrings are there) with the
kernels of ``kernels/texel.cl``.
"""

from __future__ import annotations

import numpy as np

from geosynth._backends.interfaces import TexelOps
from geosynth.core.arrays import DeviceArray

_LOCAL = 64  # work-items per group; always explicit (see opencl_backend._LOCAL_1D)


class OpenCLTexelOps(TexelOps):
    """Mixin: the batched texel search on an OpenCL device."""

    def texel_search(self, grid: DeviceArray, n: int, width: int, row_step: int, col_step: int, base0: int,
                     qstart: DeviceArray, offsets: DeviceArray, values: DeviceArray, nq: int,
                     scores: DeviceArray, best_idx: DeviceArray, best_score: DeviceArray) -> None:
        i32 = np.int32
        k = self._kernel("texel", "texel_scores", np.uint8)
        strips = (n // width) * (-(-width // 16))
        k(self.queue, (-(-strips // _LOCAL) * _LOCAL, nq), (_LOCAL, 1), grid.data, i32(n), i32(width), i32(row_step),
          i32(col_step), i32(base0), qstart.data, offsets.data, values.data, scores.data)
        k = self._kernel("texel", "texel_argmin", np.uint8)
        k(self.queue, (-(-nq // _LOCAL) * _LOCAL,), (_LOCAL,), scores.data, i32(n), best_idx.data, best_score.data,
          i32(nq))
