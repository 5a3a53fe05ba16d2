"""geosynth: example-based geometry synthesis on Warp and OpenCL kernels.

The public API; everything else is private. Every operation takes ``device=``
(see :mod:`geosynth.backend`).
"""

from geosynth.arrays import DeviceArray as DeviceArray
from geosynth.arrays import to_device as to_device
from geosynth.backend import devices as devices
from geosynth.backend import get_backend as get_backend
from geosynth.scoring import candidate_origins as candidate_origins
from geosynth.scoring import lattice_shape as lattice_shape
from geosynth.scoring import score_dense as score_dense
from geosynth.scoring import score_gather as score_gather
from geosynth.selection import argmin as argmin
from geosynth.selection import best_fraction as best_fraction
from geosynth.selection import random_pick as random_pick
from geosynth.selection import within_tolerance as within_tolerance

__version__ = "0.1.0"

__all__ = [
    "DeviceArray",
    "argmin",
    "best_fraction",
    "candidate_origins",
    "devices",
    "get_backend",
    "lattice_shape",
    "random_pick",
    "score_dense",
    "score_gather",
    "to_device",
    "within_tolerance",
]
