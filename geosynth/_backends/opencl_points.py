"""OpenCL backend methods for points distance fields (mixed into OpenCLBackend).

Launches the kernels of ``kernels/sdf_points.cl``. Methods may use the host
OpenCLBackend's helpers: self.queue, self.context, self._kernel("sdf_points", name, np.float32)
(built once per context, with kernels/ on the include path for common.h),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations


class OpenCLPointsOps:
    """Mixin: the points distance-field kernels on an OpenCL device."""
