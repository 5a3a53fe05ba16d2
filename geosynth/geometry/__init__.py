"""Geometry every method shares: grids in the world, meshes, oriented point sets, level-set
surfaces and their distance fields: the source fields of Lagae, Dumont and Dutré, "Geometry
Synthesis", and the MLS distance of "Geometry texture synthesis with point-set surfaces".

Below it: ``geosynth.core``, ``geosynth.compute`` and ``geosynth.io``.

- field.py        where in the world is each sample of a grid? Field; .npz save/load
- meshes.py       is this mesh usable, and how far is each point from it? BVH, winding numbers, mesh_distance()
- pointsets.py    how is an oriented point set read, written and given a distance field? PointSet, MLS
- distance.py     what is the signed distance of a mesh or point set on a grid? (both entry points in one place)
- surface.py      what mesh does a field's level set make? marching cubes, smoothing, mesh files
- reference.py    what must the distance kernels return? plain NumPy oracles the tests compare against

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
