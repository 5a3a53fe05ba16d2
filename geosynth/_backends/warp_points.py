"""Warp backend methods for points distance fields (mixed into WarpBackend).

Launches the kernels of ``geosynth.kernels.sdf_points``. Methods may use the host
WarpBackend's helpers: self.device, self._launch(kernel, dim, inputs),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations


class WarpPointsOps:
    """Mixin: the points distance-field kernels on a Warp device."""
