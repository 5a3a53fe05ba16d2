"""Warp backend methods for mesh distance fields (mixed into WarpBackend).

Launches the kernels of ``geosynth.kernels.sdf_mesh``. Methods may use the host
WarpBackend's helpers: self.device, self._launch(kernel, dim, inputs),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations


class WarpMeshOps:
    """Mixin: the mesh distance-field kernels on a Warp device."""
