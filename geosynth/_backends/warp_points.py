"""How does a Warp device launch the point-set distance kernels? "Geometry texture synthesis
with point-set surfaces", Sec. 5.1.

Warp backend methods for points distance fields (mixed into WarpBackend).

Launches the kernels of ``geosynth.kernels.sdf_points``. Methods may use the host
WarpBackend's helpers: self.device, self._launch(kernel, dim, inputs),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import numpy as np

from geosynth.kernels import sdf_points as points_kernels


class WarpPointsOps:
    """Mixin: the points distance-field kernels on a Warp device."""

    def mls_project(
        self, pn, cell_start, grid_origin, inv_cell, grid_dims, inv_h2, reach, tol, max_iter,
        queries, lattice, m, dist, grad, proj,
    ) -> None:
        """MLS signed distance, gradient and (optionally) projection of m query points.

        Args:
            pn: (n * 8,) float32 DeviceArray, sorted points interleaved with normals.
            cell_start: (nx * ny * nz + 1,) int32 DeviceArray, first point of each cell.
            grid_origin: (x, y, z) of the cell grid; inv_cell: 1 / cell size;
            grid_dims: (nx, ny, nz) cell counts.
            inv_h2: 1 / h^2; reach: the weights' cut-off; tol: |f| to stop at;
            max_iter: most projection steps.
            queries: (m * 3,) float32 DeviceArray, or None for the lattice.
            lattice: ((ox, oy, oz), (sx, sy, sz), (qx, qy)) when queries is None.
            m: query count; dist (m,), grad (m * 3,), proj (m * 3,) or None: outputs.
        """
        if queries is None:
            (qo, qs, qn) = lattice
        else:
            qo, qs, qn = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1, 1)
        q = queries.data if queries is not None else self._dummy(np.float32)
        pr = proj.data if proj is not None else self._dummy(np.float32)
        self._launch(
            points_kernels.mls_project_kernel,
            m,
            [
                pn.data, cell_start.data, *(float(v) for v in grid_origin), float(inv_cell),
                *(int(v) for v in grid_dims), float(inv_h2), float(reach), float(tol), int(max_iter),
                q, int(queries is not None), *(float(v) for v in qo), *(float(v) for v in qs),
                *(int(v) for v in qn), int(m), dist.data, grad.data, pr, int(proj is not None),
            ],
        )
