"""OpenCL backend methods for the M3 patch growth (mixed into OpenCLBackend).

Launches the kernel of ``kernels/growth.cl``; see kernels/growth.py for the definitions.
"""

from __future__ import annotations

import numpy as np


class OpenCLGrowthOps:
    """Mixin: the sequential patch growth on an OpenCL device."""

    def grow_patches(self, n, k, inputs, unit, weights, threshold, max_patch, n_buckets, outputs, scratch) -> None:
        """Same arguments as WarpGrowthOps.grow_patches."""
        kernel = self._kernel("growth", "grow_patches", np.float64)
        kernel(self.queue, (1,), (1,), n, k, *(a.data for a in inputs), unit, *weights, threshold, max_patch,
               n_buckets, *(a.data for a in outputs), *(a.data for a in scratch))
