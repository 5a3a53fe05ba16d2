"""How does a Warp device launch the batched texel search? Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 4 (eq. 5).

Warp backend methods for the batched M3 texel search (mixed into WarpBackend).

Launches the kernels of ``geosynth.kernels.texel``; see there for the definitions.
"""

from __future__ import annotations

from geosynth.kernels import texel as texel_kernels


class WarpTexelOps:
    """Mixin: the batched texel search on a Warp device."""

    def texel_search(self, grid, n, width, row_step, col_step, base0, qstart, offsets, values, nq,
                     scores, best_idx, best_score) -> None:
        """Eq. 5 of ``nq`` queries against every texel, then each query's best texel.

        Args:
            grid: flat uint8 DeviceArray (the padded supersampled texture).
            n, width: texel count and texels per row; row_step, col_step, base0: flat
                index arithmetic of the texel centres (see kernels/texel.py).
            qstart: (nq + 1,) int32 DeviceArray; offsets (E,) int32 and values (E,)
                uint8 DeviceArrays: the queries' entries.
            scores: (nq * n,) uint32 scratch; best_idx (nq,) int32, best_score (nq,) uint32: outputs.
        """
        strips = (n // width) * (-(-width // 4))
        self._launch(texel_kernels.texel_scores_kernel, (nq, strips),
                     [grid.data, n, width, row_step, col_step, base0, qstart.data, offsets.data, values.data,
                      scores.data])
        self._launch(texel_kernels.texel_argmin_kernel, nq, [scores.data, n, best_idx.data, best_score.data])
