"""How does a Warp device launch the batched texel search? Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 4 (eq. 5).

Warp backend methods for the batched M3 texel search (mixed into WarpBackend).

Implements geosynth._backends.interfaces.TexelOps (the docstrings are there) with the
kernels of ``geosynth.kernels.texel``.
"""

from __future__ import annotations

from geosynth._backends.interfaces import TexelOps
from geosynth.core.arrays import DeviceArray
from geosynth.kernels import texel as texel_kernels


class WarpTexelOps(TexelOps):
    """Mixin: the batched texel search on a Warp device."""

    def texel_search(self, grid: DeviceArray, n: int, width: int, row_step: int, col_step: int, base0: int,
                     qstart: DeviceArray, offsets: DeviceArray, values: DeviceArray, nq: int,
                     scores: DeviceArray, best_idx: DeviceArray, best_score: DeviceArray) -> None:
        strips = (n // width) * (-(-width // 4))
        self._launch(texel_kernels.texel_scores_kernel, (nq, strips),
                     [grid.data, n, width, row_step, col_step, base0, qstart.data, offsets.data, values.data,
                      scores.data])
        self._launch(texel_kernels.texel_argmin_kernel, nq, [scores.data, n, best_idx.data, best_score.data])
