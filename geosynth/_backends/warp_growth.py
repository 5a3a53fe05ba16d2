"""How does a Warp device launch the M3 growth kernel? Zhang, Qiu and Kaufman, "Fast Hybrid
Approach for Texturing Point Models", Sec. 3.2-3.4 and 4.2.

Warp backend methods for the M3 patch growth (mixed into WarpBackend).

Implements geosynth._backends.interfaces.GrowthOps (the docstrings are there) with the
kernels of ``geosynth.kernels.growth``; the array groups become launch arguments through
their ``buffers()`` (field order = kernel order).
"""

from __future__ import annotations

import warp as wp

from geosynth._backends.interfaces import (
    BlendInputs, BlendOutputs, BlendScratch, GrowthInputs, GrowthOps, GrowthOutputs, GrowthScratch, MatchInputs,
    MatchScratch, MatchState, PatchFrames,
)
from geosynth.core.arrays import DeviceArray
from geosynth.kernels import growth as growth_kernels


class WarpGrowthOps(GrowthOps):
    """Mixin: the sequential patch growth on a Warp device."""

    def grow_patches(self, n: int, k: int, inputs: GrowthInputs, dir_step: int, unit: float,
                     weights: tuple[float, float, float, float], threshold: float, max_patch: float,
                     n_buckets: int, outputs: GrowthOutputs, scratch: GrowthScratch) -> None:
        f64 = wp.float64
        self._launch(growth_kernels.grow_patches_kernel, 1,
                     [n, k, *inputs.buffers(), dir_step, f64(unit), *(f64(w) for w in weights), f64(threshold),
                      f64(max_patch), n_buckets, *outputs.buffers(), *scratch.buffers()])

    def blend_gaps(self, n: int, k: int, inputs: BlendInputs, unit: float, tex: DeviceArray, h: int, w: int,
                   wrap: int, offsets: DeviceArray, n_buckets: int, frames: PatchFrames, outputs: BlendOutputs,
                   scratch: BlendScratch) -> None:
        self._launch(growth_kernels.blend_gaps_kernel, 1,
                     [n, k, *inputs.buffers(), wp.float64(unit), tex.data, h, w, wrap, offsets.data,
                      n_buckets, *frames.buffers(), *outputs.buffers(), *scratch.buffers()])

    def match_coherent(self, n: int, k: int, inputs: MatchInputs, unit: float, grid: DeviceArray, xp: int, pad: int,
                       m: int, h: int, w: int, tileable: int, subtexel: int, shifts1: DeviceArray, n_shift1: int,
                       ring: int, order: DeviceArray, rand_texel: DeviceArray, n_buckets: int, state: MatchState,
                       scratch: MatchScratch) -> None:
        self._launch(growth_kernels.match_coherent_kernel, 1,
                     [n, k, *inputs.buffers(), wp.float64(unit), grid.data, xp, pad, m, h, w, tileable,
                      subtexel, shifts1.data, n_shift1, ring, order.data, rand_texel.data, n_buckets,
                      *state.buffers(), *scratch.buffers()])
