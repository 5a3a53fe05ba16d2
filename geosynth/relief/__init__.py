"""Relief and colour grown from an example over any mesh (issue 34): ``geosynth relief``.

The public entry point is :func:`geosynth.grow_relief` (defined in
:mod:`geosynth.relief.grow`). Modules, each named by the question it answers:

- :mod:`~geosynth.relief.examples`: what does the example look like, as one height grid in
  world units (a grey image, a captured patch over its fitted plane, or a built-in)?
- :mod:`~geosynth.relief.refine`: where does the mesh need more samples (an isotropic remesh of
  slivers and coarse meshes, bisection), along which normals, and how far may each vertex move
  (thickness limit, mask)?
- :mod:`~geosynth.relief.orient`: which way is "along" on the surface (the tangent field)?
- :mod:`~geosynth.relief.project`: the baseline, triplanar projection.
- :mod:`~geosynth.relief.synth`: the synthesis on the surface, M4's growth and FindMatches
  kernels (Breckon and Fisher, Appendix A) with the example as the capture.
- :mod:`~geosynth.relief.transfer`: how does the finer output mesh read the example at the
  places the synthesis chose on a coarser one?
- :mod:`~geosynth.relief.quality`: how close is the result to the example (amplitude and
  period per region, seams), and the picture.
- :mod:`~geosynth.relief.write`: STL, PLY, OBJ, GLB and 3MF, atomically.
- :mod:`~geosynth.relief.grow`: :func:`grow_relief`, all of the above in order.

Nothing is imported here: ``import geosynth.relief`` costs nothing.
"""
