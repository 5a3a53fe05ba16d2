"""How does a Warp device launch the mesh distance kernels? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 3.

Warp backend methods for mesh distance fields (mixed into WarpBackend).

Launches the kernels of ``geosynth.kernels.sdf_mesh``. Methods may use the host
WarpBackend's helpers: self.device, self._launch(kernel, dim, inputs),
self.to_device(ndarray), self.empty(shape, dtype), self.to_host(array).
"""

from __future__ import annotations

import warp as wp

from geosynth.kernels import sdf_mesh as sdf_kernels


class WarpMeshHandle:
    """A mesh on a Warp device: the BVH arrays of geosynth.meshes.MeshBVH."""

    def __init__(self, bvh, device):
        self.sbox = wp.array(bvh.sbox.reshape(-1), dtype=wp.float32, device=device)
        self.child = wp.array(bvh.child.reshape(-1), dtype=wp.int32, device=device)
        self.tri_lanes = wp.array(bvh.tri_lanes.reshape(-1), dtype=wp.float32, device=device)
        self.tris = wp.array(bvh.tris.reshape(-1), dtype=wp.float32, device=device)
        self.dipole = wp.array(bvh.dipole.reshape(-1), dtype=wp.float32, device=device)

    def arrays(self) -> list:
        return [self.sbox, self.child, self.tri_lanes, self.tris, self.dipole]


class WarpMeshOps:
    """Mixin: the mesh distance-field kernels on a Warp device."""

    def mesh_handle(self, bvh) -> WarpMeshHandle:
        """The device structures of a prepared mesh, made once per mesh and device."""
        handle = bvh.device_cache.get(self.name)
        if handle is None:
            handle = bvh.device_cache[self.name] = WarpMeshHandle(bvh, self.device)
        return handle

    def mesh_distance_points(self, mesh, points, n, signed, band, out, run: int = 8) -> None:
        """out (n,) <- distance at points (n, 3), run points per thread (pass them in a
        spatial order: each search starts from the previous point's closest triangle);
        see kernels/sdf_mesh.py."""
        self._launch(
            sdf_kernels.mesh_distance_points_kernel,
            -(-n // run),
            [points.data, n, run, *mesh.arrays(), int(signed), float(band), out.data],
        )

    def mesh_distance_grid(self, mesh, origin, spacing, shape, signed, band, out, run: int = 8) -> None:
        """out (nz * ny * nx,) <- distance at origin + spacing * (i, j, k) for shape (nx, ny, nz)."""
        nx, ny, nz = shape
        self._launch(
            sdf_kernels.mesh_distance_grid_kernel,
            (nz, ny, -(-nx // run)),
            [*(float(v) for v in origin), *(float(v) for v in spacing), nx, ny, nz, run,
             *mesh.arrays(), int(signed), float(band), out.data],
        )
