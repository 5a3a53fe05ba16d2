"""How does a Warp device launch the mesh distance kernels? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 3.

Warp backend methods for mesh distance fields (mixed into WarpBackend).

Implements geosynth._backends.interfaces.MeshOps (the docstrings are there) with the
kernels of ``geosynth.kernels.sdf_mesh``. Methods may use the host WarpBackend's helpers: self.device, self._launch(kernel, dim, inputs),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import numpy as np

from geosynth._backends.interfaces import MeshArrays, MeshOps
from geosynth.core.arrays import DeviceArray
from geosynth.kernels import sdf_mesh as sdf_kernels

# Points (and grid samples along x) per thread: each search starts from the previous
# point's closest triangle.
_RUN = 8


class WarpMeshOps(MeshOps):
    """Mixin: the mesh distance-field kernels on a Warp device."""

    def mesh_distance_points(self, mesh: MeshArrays, points: DeviceArray, n: int, signed: bool, band: float,
                             out: DeviceArray) -> None:
        self._launch(
            sdf_kernels.mesh_distance_points_kernel,
            -(-n // _RUN),
            [points.data, n, _RUN, *mesh.buffers(), int(signed), float(band), out.data],
        )

    def mesh_distance_grid(self, mesh: MeshArrays, origin: np.ndarray, spacing: np.ndarray,
                           shape: tuple[int, int, int], signed: bool, band: float, out: DeviceArray) -> None:
        nx, ny, nz = shape
        self._launch(
            sdf_kernels.mesh_distance_grid_kernel,
            (nz, ny, -(-nx // _RUN)),
            [*(float(v) for v in origin), *(float(v) for v in spacing), nx, ny, nz, _RUN,
             *mesh.buffers(), int(signed), float(band), out.data],
        )
