"""Distance fields: sampling the signed distance of meshes and oriented point sets.

The public face of the distance-field kernel family (kernels/sdf_mesh.*,
kernels/sdf_points.*). Grids are :class:`geosynth.field.Field` objects.
"""

from __future__ import annotations

from geosynth.field import Field as Field
from geosynth.field import cubic_grid as cubic_grid
