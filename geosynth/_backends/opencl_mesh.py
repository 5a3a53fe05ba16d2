"""How does an OpenCL device launch the mesh distance kernels? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 3.

OpenCL backend methods for mesh distance fields (mixed into OpenCLBackend).

Implements geosynth._backends.interfaces.MeshOps (the docstrings are there) with the
kernels of ``kernels/sdf_mesh.cl``. Methods may use the host OpenCLBackend's helpers: self.queue, self.context, self._kernel("sdf_mesh", name, np.float32)
(built once per context, with kernels/ on the include path for common.h),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import numpy as np

from geosynth._backends.interfaces import MeshArrays, MeshOps
from geosynth.core.arrays import DeviceArray

# Work-group shapes: small groups, so that PoCL spreads the work over every core
# (the cost per point varies a lot with its distance to the mesh).
# The grid kernel's tile of samples per work-item (TILE_X, TILE_Y, TILE_Z in sdf_mesh.cl);
# the points kernel takes 16 consecutive points per work-item.
_TILE = (4, 2, 2)
_LOCAL_TILES = (1, 4, 1)
_POINT_TILE = 16
_LOCAL_POINT_TILES = 4


def _round_up(value: int, multiple: int) -> int:
    return -(-value // multiple) * multiple


class OpenCLMeshOps(MeshOps):
    """Mixin: the mesh distance-field kernels on an OpenCL device."""

    def mesh_distance_points(self, mesh: MeshArrays, points: DeviceArray, n: int, signed: bool, band: float,
                             out: DeviceArray) -> None:
        kernel = self._kernel("sdf_mesh", "mesh_distance_points", np.float32)
        g = -(-n // _POINT_TILE)
        kernel(
            self.queue, (_round_up(g, _LOCAL_POINT_TILES),), (_LOCAL_POINT_TILES,),
            points.data, np.int32(n), *mesh.buffers(), np.int32(bool(signed)), np.float32(band), out.data,
        )

    def mesh_distance_grid(self, mesh: MeshArrays, origin: np.ndarray, spacing: np.ndarray,
                           shape: tuple[int, int, int], signed: bool, band: float, out: DeviceArray) -> None:
        nx, ny, nz = shape
        kernel = self._kernel("sdf_mesh", "mesh_distance_grid", np.float32)
        tiles = [-(-n // t) for n, t in zip(shape, _TILE)]
        gsize = tuple(_round_up(t, l) for t, l in zip(tiles, _LOCAL_TILES))
        kernel(
            self.queue, gsize, _LOCAL_TILES,
            *(np.float32(v) for v in origin), *(np.float32(v) for v in spacing),
            np.int32(nx), np.int32(ny), np.int32(nz),
            *mesh.buffers(), np.int32(bool(signed)), np.float32(band), out.data,
        )
