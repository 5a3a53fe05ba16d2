"""The device layer every method calls: which backend runs a device string, the input checks,
block scoring and selection, the compiled host steps, and their oracles. Scoring is the linear
search of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 4.3 (and eq. 5 of Zhang, Qiu and
Kaufman); the rest implements no paper section.

Below it: ``geosynth.core``, ``geosynth._backends`` and ``geosynth.kernels``.

- backend.py      which backend runs a device string? devices(), resolve_device(), get_backend(), to_device()
- checks.py       is this argument acceptable? the input checks every public operation shares
- scoring.py      how far is every candidate from a query? score_dense(), score_gather()
- selection.py    which candidate wins? argmin(), within_tolerance(), best_fraction(), random_pick()
- host_steps.py   where do the compiled host steps run? host_array(), host_launch() on Warp's cpu device
- reference.py    what must scoring and selection return? plain NumPy oracles the tests compare against

The modules are imported on first use, never by this package (``import geosynth`` stays cheap).
"""
