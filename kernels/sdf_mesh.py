"""Distance-field kernels (mesh): Warp. The twin of sdf_mesh.cl."""
