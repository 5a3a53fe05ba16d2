"""OpenCL backend methods for mesh distance fields (mixed into OpenCLBackend).

Launches the kernels of ``kernels/sdf_mesh.cl``. Methods may use the host
OpenCLBackend's helpers: self.queue, self.context, self._kernel("sdf_mesh", name, np.float32)
(built once per context, with kernels/ on the include path for common.h),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations


class OpenCLMeshOps:
    """Mixin: the mesh distance-field kernels on an OpenCL device."""
