"""Distance-field kernels (points): Warp. The twin of sdf_points.cl."""
