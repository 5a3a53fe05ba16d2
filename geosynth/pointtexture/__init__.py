"""M2: point-set geometry textures. "Geometry texture synthesis with point-set surfaces": the
input texture T_in and output T_out, the synthesis of Sec. 4 (steps 1 to 8) and the patch
processing of Sec. 5 (search 5.1, warping 5.2, blending 5.3).

- synthesis.py    which larger point-set texture looks like the exemplar? synthesize_point_texture()
- texture.py      what is a point-set geometry texture? PointTexture; from points, PLY, meshes, images
- examples.py     which point textures run with no input file? heightfield, chainmail, weave, flowers
- output_grid.py  which output points lie near here? PointGrid, the hashed grid of point buckets
- patch_search.py which exemplar patch best continues the output? gather SSD (Sec. 5.1)
- warping.py      how is a pasted patch bent to fit its neighbourhood? pairing + thin-plate spline (Sec. 5.2)
- blending.py     how does a warped patch meet the points already there? (Sec. 5.3)
- element_size.py how large are a point texture's elements? relief_scale()

The NumPy twins of the compiled host steps (``*_numpy`` in warping.py and blending.py) stay beside
the steps they mirror.

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
