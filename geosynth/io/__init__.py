"""Files and pictures: which paths may be read or written and how safely, what geometry a file
holds, and what a result looks like. Implements no paper section.

Below it: ``geosynth.core`` only.

- files.py        may this path be read or written, and how safely? check_input(), check_output(),
                  atomic_write(), write_image(), staged_outputs()
- readers.py      what geometry does this file hold? PLY (plyfile), OBJ/STL/OFF/GLB (trimesh)
- pictures.py     what does a result look like? field slices, shaded meshes and point pictures

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
