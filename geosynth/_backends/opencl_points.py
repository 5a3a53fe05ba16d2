"""How does an OpenCL device launch the point-set distance kernels? "Geometry texture
synthesis with point-set surfaces", Sec. 5.1.

OpenCL backend methods for points distance fields (mixed into OpenCLBackend).

Implements geosynth._backends.interfaces.PointsOps (the docstrings are there) with the
kernels of ``kernels/sdf_points.cl``. Methods may use the host
OpenCLBackend's helpers: self.queue, self.context, self._kernel("sdf_points", name, np.float32)
(built once per context, with kernels/ on the include path for common.h),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import numpy as np

from geosynth._backends.interfaces import PointsOps
from geosynth.core.arrays import DeviceArray

_LOCAL = 64  # work-items per group; always explicit (see opencl_backend._LOCAL_1D)


class OpenCLPointsOps(PointsOps):
    """Mixin: the points distance-field kernels on an OpenCL device."""

    def mls_project(
        self, pn: DeviceArray, cell_start: DeviceArray, grid_origin: tuple[float, float, float], inv_cell: float,
        grid_dims: tuple[int, int, int], inv_h2: float, reach: float, tol: float, max_iter: int,
        queries: DeviceArray | None, lattice: tuple | None, m: int, dist: DeviceArray, grad: DeviceArray,
        proj: DeviceArray | None, residual: DeviceArray | None = None,
    ) -> None:
        if queries is None:
            (qo, qs, qn) = lattice
        else:
            qo, qs, qn = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1, 1)
        kernel = self._kernel("sdf_points", "mls_project", np.float32)
        f32, i32 = np.float32, np.int32
        kernel(
            self.queue, (-(-m // _LOCAL) * _LOCAL,), (_LOCAL,),
            pn.data, cell_start.data, *(f32(v) for v in grid_origin), f32(inv_cell),
            *(i32(v) for v in grid_dims), f32(inv_h2), f32(reach), f32(tol), i32(max_iter),
            queries.data if queries is not None else self._dummy(np.float32), i32(queries is not None),
            *(f32(v) for v in qo), *(f32(v) for v in qs), *(i32(v) for v in qn),
            i32(m), dist.data, grad.data,
            proj.data if proj is not None else self._dummy(np.float32), i32(proj is not None),
            residual.data if residual is not None else self._dummy(np.float32), i32(residual is not None),
        )
