"""M1: volumetric geometry synthesis by block matching on distance fields. Lagae, Dumont and
Dutré, "Geometry Synthesis" (Report CW 381, K.U. Leuven, 2004): the block pyramid and search
tree (Sec. 4-5), with Kwatra et al.'s texture optimization (2005) and graph-cut pasting (2003),
tiled on Dask beyond one process.

- synthesis.py    which larger field looks like the exemplar? synthesize_volume(), synthesize_geometry()
- options.py      which settings does an M1 synthesis take, and are they valid? VolumeOptions, TileOptions
- tiled.py        how does a volume beyond one process grow on Dask? synthesize_volume_tiled()
- tiles.py        how is a volume split into tiles and scheduled so every seam is consistent?
- examples.py     which example inputs run with no input file? exemplar_mesh(), exemplar_field()
- pyramid.py      what are a block's coarser levels, and how far apart are two blocks at a level?
- blocks.py       where are a field's blocks, and what are the sums of its cubes?
- tree.py         which source block is nearest to a query, by the paper's search tree? BlockSearch
- cascade.py      which source block is nearest, by lower bounds over every block? CascadeSearch
- optimize.py     how does texture optimization refine a level? lattice matches, IRLS vote
- graphcut.py     where should a pasted block's overlap be cut? scipy max flow
- features.py     how large are a field's features? element_features(), compare_features()
- quality.py      how close is a synthesized field to its exemplar, and does it keep its structure?
- reference.py    what must the block pyramid and the block searches return? plain NumPy oracles

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
