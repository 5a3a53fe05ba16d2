"""How does an OpenCL device launch the M3 growth kernel? Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 3.2-3.4 and 4.2.

OpenCL backend methods for the M3 patch growth (mixed into OpenCLBackend).

Launches the kernel of ``kernels/growth.cl``; see kernels/growth.py for the definitions.
"""

from __future__ import annotations

import numpy as np


class OpenCLGrowthOps:
    """Mixin: the sequential patch growth on an OpenCL device."""

    def grow_patches(self, n, k, inputs, dir_step, unit, weights, threshold, max_patch, n_buckets, outputs, scratch) -> None:
        """Same arguments as WarpGrowthOps.grow_patches."""
        kernel = self._kernel("growth", "grow_patches", np.float64)
        kernel(self.queue, (1,), (1,), n, k, *(a.data for a in inputs), dir_step, unit, *weights, threshold, max_patch,
               n_buckets, *(a.data for a in outputs), *(a.data for a in scratch))

    def blend_gaps(self, n, k, inputs, unit, tex, h, w, wrap, offsets, n_buckets, in_out, outputs, scratch) -> None:
        """Same arguments as WarpGrowthOps.blend_gaps."""
        kernel = self._kernel("growth", "blend_gaps", np.float64)
        kernel(self.queue, (1,), (1,), n, k, *(a.data for a in inputs), unit, tex.data, h, w, wrap, offsets.data,
               n_buckets, *(a.data for a in in_out), *(a.data for a in outputs), *(a.data for a in scratch))

    def match_coherent(self, n, k, inputs, unit, grid, xp, pad, m, h, w, tileable, subtexel, shifts1, n_shift1, ring,
                       order, rand_texel, n_buckets, in_out, scratch) -> None:
        """Same arguments as WarpGrowthOps.match_coherent."""
        kernel = self._kernel("growth", "match_coherent", np.float64)
        kernel(self.queue, (1,), (1,), n, k, *(a.data for a in inputs), unit, grid.data, xp, pad, m, h, w, tileable,
               subtexel, shifts1.data, n_shift1, ring, order.data, rand_texel.data, n_buckets,
               *(a.data for a in in_out), *(a.data for a in scratch))
