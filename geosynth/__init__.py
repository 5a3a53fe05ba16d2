"""geosynth: example-based geometry synthesis on Warp and OpenCL kernels.

The public API; everything else is private. Every operation takes ``device=``
(see :mod:`geosynth.backend`).

- Devices and arrays: :func:`devices`, :func:`get_backend`, :func:`to_device`, :class:`DeviceArray`.
- Block scoring and selection: :func:`score_dense`, :func:`score_gather`, :func:`candidate_origins`,
  :func:`lattice_shape`, :func:`argmin`, :func:`within_tolerance`, :func:`best_fraction`, :func:`random_pick`.
- M1, volumes and geometry: :func:`synthesize_volume` (:class:`VolumeResult`),
  :func:`synthesize_geometry` (:class:`GeometryResult`).
- M2, distance fields: :func:`mesh_distance`, :func:`pointset_distance` (:class:`Field`).
- M2, point-set geometry textures: :func:`synthesize_point_texture` (:class:`PointTextureReport`) from a
  :class:`PointTexture` (:func:`point_texture_example` for the built-ins).
- M3, textured point sets: :func:`texture_points` (:class:`TextureReport`) on a :class:`PointSet`.
- M4, relief and colour completion: :func:`complete_surface` (:class:`CompletionReport`).
- Relief grown from an example over any mesh (issue 34): :func:`grow_relief`.
- Files: :func:`read_point_set`, :func:`write_point_set`, :func:`read_geometry`, :func:`load_mesh`,
  :func:`save_mesh`, :func:`read_texture`, :func:`write_texture`, :func:`write_image`,
  ``Field.load`` / ``Field.save``.
- Built-in inputs: :func:`point_model`, :func:`load_point_model`, :func:`texture_example`,
  :func:`exemplar_mesh`, :func:`exemplar_field`.
- :class:`MemoryBudgetError`: an operation's memory estimate exceeds what is available.

``import geosynth`` imports nothing else: every name's module is imported on first use
(PEP 562 ``__getattr__``). Importing them all up front took ~0.17 s of CPU, NumPy alone
~0.07 s; and the command line (:mod:`geosynth._launch`) catches Ctrl-C from its first
instant, which needs a package whose import does no work.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# Public name -> the module that defines it, imported when the name is first read.
_LAZY = {
    "DeviceArray": "geosynth.arrays",
    "to_device": "geosynth.backend",
    "devices": "geosynth.backend",
    "get_backend": "geosynth.backend",
    "candidate_origins": "geosynth.scoring",
    "lattice_shape": "geosynth.scoring",
    "score_dense": "geosynth.scoring",
    "score_gather": "geosynth.scoring",
    "argmin": "geosynth.selection",
    "best_fraction": "geosynth.selection",
    "random_pick": "geosynth.selection",
    "within_tolerance": "geosynth.selection",
    "synthesize_volume": "geosynth.volume",
    "synthesize_geometry": "geosynth.volume",
    "VolumeResult": "geosynth.volume",
    "GeometryResult": "geosynth.volume",
    "texture_points": "geosynth.texturing",
    "TextureReport": "geosynth.texturing",
    "mesh_distance": "geosynth.meshes",
    "load_mesh": "geosynth.meshes",
    "pointset_distance": "geosynth.pointsets",
    "PointSet": "geosynth.pointsets",
    "read_point_set": "geosynth.pointsets",
    "write_point_set": "geosynth.pointsets",
    "read_geometry": "geosynth.pointsets",
    "Field": "geosynth.field",
    "save_mesh": "geosynth.surface",
    "read_texture": "geosynth.textures",
    "write_texture": "geosynth.textures",
    "texture_example": "geosynth.textures",
    "write_image": "geosynth.files",
    "point_model": "geosynth.pointmodels",
    "load_point_model": "geosynth.pointmodels",
    "exemplar_mesh": "geosynth.examples",
    "exemplar_field": "geosynth.examples",
    "MemoryBudgetError": "geosynth.memory",
    # M2: point-set geometry textures
    "synthesize_point_texture": "geosynth.geometry_texture",
    "PointTextureReport": "geosynth.geometry_texture",
    "PointTexture": "geosynth.point_textures",
    "point_texture_example": "geosynth.point_examples",
    "complete_surface": "geosynth.completion",
    "CompletionReport": "geosynth.completion",
    "synthesize_volume_tiled": "geosynth.tiled",
    "exemplar_source": "geosynth.tiled",
    # issue 34: relief grown from an example over any mesh
    "grow_relief": "geosynth.relief.grow",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    """Import a lazily exported name's module on first use and keep the name here."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'geosynth' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
