"""How does an OpenCL device launch the M3 growth kernel? Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 3.2-3.4 and 4.2.

OpenCL backend methods for the M3 patch growth (mixed into OpenCLBackend).

Implements geosynth._backends.interfaces.GrowthOps (the docstrings are there) with the
kernels of ``kernels/growth.cl`` (kernels/growth.py defines them); the array groups
become launch arguments through their ``buffers()`` (field order = kernel order).
"""

from __future__ import annotations

import numpy as np

from geosynth._backends.interfaces import (
    BlendInputs, BlendOutputs, BlendScratch, GrowthInputs, GrowthOps, GrowthOutputs, GrowthScratch, MatchInputs,
    MatchScratch, MatchState, PatchFrames,
)
from geosynth.core.arrays import DeviceArray


class OpenCLGrowthOps(GrowthOps):
    """Mixin: the sequential patch growth on an OpenCL device."""

    def grow_patches(self, n: int, k: int, inputs: GrowthInputs, dir_step: int, unit: float,
                     weights: tuple[float, float, float, float], threshold: float, max_patch: float,
                     n_buckets: int, outputs: GrowthOutputs, scratch: GrowthScratch) -> None:
        kernel = self._kernel("growth", "grow_patches", np.float64)
        kernel(self.queue, (1,), (1,), n, k, *inputs.buffers(), dir_step, unit, *weights, threshold, max_patch,
               n_buckets, *outputs.buffers(), *scratch.buffers())

    def blend_gaps(self, n: int, k: int, inputs: BlendInputs, unit: float, tex: DeviceArray, h: int, w: int,
                   wrap: int, offsets: DeviceArray, n_buckets: int, frames: PatchFrames, outputs: BlendOutputs,
                   scratch: BlendScratch) -> None:
        kernel = self._kernel("growth", "blend_gaps", np.float64)
        kernel(self.queue, (1,), (1,), n, k, *inputs.buffers(), unit, tex.data, h, w, wrap, offsets.data,
               n_buckets, *frames.buffers(), *outputs.buffers(), *scratch.buffers())

    def match_coherent(self, n: int, k: int, inputs: MatchInputs, unit: float, grid: DeviceArray, xp: int, pad: int,
                       m: int, h: int, w: int, tileable: int, subtexel: int, shifts1: DeviceArray, n_shift1: int,
                       ring: int, order: DeviceArray, rand_texel: DeviceArray, n_buckets: int, state: MatchState,
                       scratch: MatchScratch) -> None:
        kernel = self._kernel("growth", "match_coherent", np.float64)
        kernel(self.queue, (1,), (1,), n, k, *inputs.buffers(), unit, grid.data, xp, pad, m, h, w, tileable,
               subtexel, shifts1.data, n_shift1, ring, order.data, rand_texel.data, n_buckets,
               *state.buffers(), *scratch.buffers())
