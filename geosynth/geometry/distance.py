"""What is the signed distance of a mesh or point set on a grid? The source field of Lagae,
Dumont and Dutré, "Geometry Synthesis", Sec. 3 (system overview), and the MLS distance of
"Geometry texture synthesis with point-set surfaces", Sec. 5.1.

Distance fields: sampling the signed distance of meshes and oriented point sets.

The public face of the distance-field kernel family (kernels/sdf_mesh.*,
kernels/sdf_points.*). Grids are :class:`geosynth.geometry.field.Field` objects.
"""

from __future__ import annotations

from geosynth.geometry.field import Field as Field
from geosynth.geometry.field import cubic_grid as cubic_grid
from geosynth.geometry.meshes import load_mesh as load_mesh
from geosynth.geometry.meshes import mesh_distance as mesh_distance
from geosynth.geometry.pointsets import pointset_distance as pointset_distance
