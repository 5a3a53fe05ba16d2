"""M4: relief and colour completion. Breckon and Fisher, "Plausible 3D colour surface completion
using non-parametric techniques": the underlying surface and frames, the samples and targets,
FindMatches and the growth of the missing part.

- synthesis.py    how is the missing part grown? GrowSurface, quality numbers; complete_surface()
- examples.py     which partly captured surfaces complete with no input file?
- fit.py          which smooth surface underlies a capture? plane, sphere, cylinder fits; the frames
- prep.py         which samples and targets, in which triangulation? displacements, oversampling, W-rings
- matching.py     which captured sample's neighbourhood best matches a target's? ReliefIndex, find_matches()
- spectrum.py     what are a gridded relief's amplitude, period and direction? relief_spectrum()
- reference.py    what must the relief kernels return? plain NumPy oracles the tests compare against

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
