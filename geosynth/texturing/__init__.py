"""M3: texturing point models. Zhang, Qiu and Kaufman, "Fast Hybrid Approach for Texturing Point
Models": patches and texture coordinates (Sec. 3, Appendix A), the hierarchy and texel matching
(Sec. 4-5, eq. 5), the models and neighbourhoods (Sec. 4, 6).

- synthesis.py    how are a point model's points coloured, and how well? texture_points()
- textures.py     which texture, at which resolution? Pillow I/O, procedural textures, pyramid
- models.py       which point models, and which are each point's k nearest neighbours?
- parameterize.py which patch and texture coordinate does each point get? (Sec. 3, Appendix A)
- hierarchy.py    which coarser point does each point belong to? build_hierarchy()
- texel_search.py which texel best matches a point neighbourhood? TexelSearch (eq. 5)
- matching.py     which texel colours each point of one hierarchy level? match_level()
- reference.py    what must the growth and the texel kernels return? plain NumPy/Python oracles

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
