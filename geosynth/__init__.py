"""geosynth: example-based geometry synthesis on Warp and OpenCL kernels.

The public API; everything else is private. Every operation takes ``device=``
(see :mod:`geosynth.compute.backend`).

- Devices and arrays: :func:`devices`, :func:`get_backend`, :func:`to_device`, :class:`DeviceArray`.
- Block scoring and selection: :func:`score_dense`, :func:`score_gather`, :func:`candidate_origins`,
  :func:`lattice_shape`, :func:`argmin`, :func:`within_tolerance`, :func:`best_fraction`, :func:`random_pick`.
- M1, volumes and geometry: :func:`synthesize_volume` (:class:`VolumeResult`),
  :func:`synthesize_geometry` (:class:`GeometryResult`), :func:`synthesize_volume_tiled`; their settings in one
  :class:`VolumeOptions` (a tiled run's in its :class:`TileOptions`).
- M2, distance fields: :func:`mesh_distance`, :func:`pointset_distance` (:class:`Field`).
- M2, point-set geometry textures: :func:`synthesize_point_texture` (:class:`PointTextureReport`; its settings
  in one :class:`PointTextureOptions`) from a :class:`PointTexture` (:func:`point_texture_example` for the
  built-ins).
- M3, textured point sets: :func:`texture_points` (:class:`TextureReport`; its settings in one
  :class:`TexturingOptions`) on a :class:`PointSet`.
- M4, relief and colour completion: :func:`complete_surface` (:class:`CompletionReport`; its settings in one
  :class:`CompletionOptions`).
- Relief grown from an example over any mesh (issue 34): :func:`grow_relief`.
- Files: :func:`read_point_set`, :func:`write_point_set`, :func:`read_geometry`, :func:`load_mesh`,
  :func:`save_mesh`, :func:`read_texture`, :func:`write_texture`, :func:`write_image`,
  :func:`write_viewer` (a self-contained HTML page to turn two models in 3D), ``Field.load`` / ``Field.save``.
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

from geosynth.core.config import numpy_same_on_every_cpu as _numpy_same_on_every_cpu

_numpy_same_on_every_cpu()  # before NumPy loads: the same bits on an AVX-512 CPU as on any other

__version__ = "0.1.0"

# Public name -> the module that defines it, imported when the name is first read.
_LAZY = {
    "DeviceArray": "geosynth.core.arrays",
    "to_device": "geosynth.compute.backend",
    "devices": "geosynth.compute.backend",
    "get_backend": "geosynth.compute.backend",
    "candidate_origins": "geosynth.compute.scoring",
    "lattice_shape": "geosynth.compute.scoring",
    "score_dense": "geosynth.compute.scoring",
    "score_gather": "geosynth.compute.scoring",
    "argmin": "geosynth.compute.selection",
    "best_fraction": "geosynth.compute.selection",
    "random_pick": "geosynth.compute.selection",
    "within_tolerance": "geosynth.compute.selection",
    "synthesize_volume": "geosynth.volume.synthesis",
    "synthesize_geometry": "geosynth.volume.synthesis",
    "VolumeResult": "geosynth.volume.synthesis",
    "GeometryResult": "geosynth.volume.synthesis",
    "texture_points": "geosynth.texturing.synthesis",
    "TextureReport": "geosynth.texturing.synthesis",
    "TexturingOptions": "geosynth.texturing.synthesis",
    "mesh_distance": "geosynth.geometry.meshes",
    "load_mesh": "geosynth.geometry.meshes",
    "pointset_distance": "geosynth.geometry.pointsets",
    "PointSet": "geosynth.geometry.pointsets",
    "read_point_set": "geosynth.geometry.pointsets",
    "write_point_set": "geosynth.geometry.pointsets",
    "read_geometry": "geosynth.geometry.pointsets",
    "Field": "geosynth.geometry.field",
    "save_mesh": "geosynth.geometry.surface",
    "read_texture": "geosynth.texturing.textures",
    "write_texture": "geosynth.texturing.textures",
    "texture_example": "geosynth.texturing.textures",
    "write_image": "geosynth.io.files",
    "write_viewer": "geosynth.io.viewer",
    "point_model": "geosynth.texturing.models",
    "load_point_model": "geosynth.texturing.models",
    "exemplar_mesh": "geosynth.volume.examples",
    "exemplar_field": "geosynth.volume.examples",
    "MemoryBudgetError": "geosynth.core.memory",
    # M2: point-set geometry textures
    "synthesize_point_texture": "geosynth.pointtexture.synthesis",
    "PointTextureReport": "geosynth.pointtexture.synthesis",
    "PointTextureOptions": "geosynth.pointtexture.synthesis",
    "PointTexture": "geosynth.pointtexture.texture",
    "point_texture_example": "geosynth.pointtexture.examples",
    "complete_surface": "geosynth.completion.synthesis",
    "CompletionReport": "geosynth.completion.synthesis",
    "CompletionOptions": "geosynth.completion.synthesis",
    "synthesize_volume_tiled": "geosynth.volume.tiled",
    "VolumeOptions": "geosynth.volume.options",
    "TileOptions": "geosynth.volume.options",
    "exemplar_source": "geosynth.volume.tiled",
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
