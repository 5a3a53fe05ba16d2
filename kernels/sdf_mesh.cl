// Distance-field kernels (mesh): OpenCL. The twin of sdf_mesh.py.
#include "common.h"
