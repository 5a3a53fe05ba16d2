"""How does a Warp device launch the point-set distance kernels? "Geometry texture synthesis
with point-set surfaces", Sec. 5.1.

Warp backend methods for points distance fields (mixed into WarpBackend).

Implements geosynth._backends.interfaces.PointsOps (the docstrings are there) with the
kernels of ``geosynth.kernels.sdf_points``. Methods may use the host
WarpBackend's helpers: self.device, self._launch(kernel, dim, inputs),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import numpy as np

from geosynth._backends.interfaces import PointsOps
from geosynth.core.arrays import DeviceArray
from geosynth.kernels import sdf_points as points_kernels


class WarpPointsOps(PointsOps):
    """Mixin: the points distance-field kernels on a Warp device."""

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
        q = queries.data if queries is not None else self._dummy(np.float32)
        pr = proj.data if proj is not None else self._dummy(np.float32)
        res = residual.data if residual is not None else self._dummy(np.float32)
        self._launch(
            points_kernels.mls_project_kernel,
            m,
            [
                pn.data, cell_start.data, *(float(v) for v in grid_origin), float(inv_cell),
                *(int(v) for v in grid_dims), float(inv_h2), float(reach), float(tol), int(max_iter),
                q, int(queries is not None), *(float(v) for v in qo), *(float(v) for v in qs),
                *(int(v) for v in qn), int(m), dist.data, grad.data, pr, int(proj is not None),
                res, int(residual is not None),
            ],
        )
