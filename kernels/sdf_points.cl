// Distance-field kernels (points): OpenCL. The twin of sdf_points.py.
#include "common.h"
