"""What mesh does a field's level set make? It stands in for the geometry reconstruction of
Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 5.3 (marching cubes on the synthesized
field).

Geometry out: a field's level set as a triangle mesh, smoothing, and mesh files.

:func:`field_to_mesh` runs marching cubes (scikit-image's Lewiner variant) on a
:class:`~geosynth.geometry.field.Field`, puts the vertices where the field's samples are in
the world, and orients the faces outward (the field is negative inside, as every
signed distance in geosynth is). :func:`smooth_mesh` applies Taubin (or
volume-preserving Laplacian) smoothing, and :func:`save_mesh` writes PLY, OBJ or
STL atomically, refusing to overwrite an input file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from geosynth.geometry.field import Field
from geosynth.io.files import atomic_write, check_finite_output

__all__ = ["MESH_SUFFIXES", "field_to_mesh", "save_mesh", "smooth_mesh"]

MESH_SUFFIXES = {".ply": "ply", ".obj": "obj", ".stl": "stl"}
SMOOTHING_METHODS = ("taubin", "laplacian")
UINT8_LEVEL = 127.5  # quantize_field maps distance 0 to 127.5: half way between two codes


def field_to_mesh(field: Field, level: float | None = None, smooth: int = 0, method: str = "taubin",
                  close: bool = False):
    """The surface where a field crosses ``level``, as a triangle mesh in world coordinates.

    Marching cubes (``skimage.measure.marching_cubes``, Lewiner) on ``field.values``
    in their (Z, Y, X) order; a vertex found at fractional index (k, j, i) is placed at
    ``field.origin + field.spacing * (i, j, k)``, the world position of that point of
    the grid (the same rule as :meth:`Field.world_position`).

    - Sign convention: values below ``level`` are inside (a signed distance is
      negative inside). Faces are wound counter-clockwise seen from outside, so face
      normals point outward and a closed result has a positive volume.
    - ``level`` defaults to 0.0 for float fields and to 127.5 for uint8 fields (the
      zero distance of :func:`geosynth.volume.synthesis.quantize_field`, between codes 127
      and 128, so the surface never passes exactly through a sample).
    - Where the inside touches the border of the grid the surface is open there,
      unless ``close`` is set: then the volume is padded with one layer of outside
      values, which caps the cut at most one sample beyond the border.

    Args:
        field: a scalar :class:`~geosynth.geometry.field.Field` (values (Z, Y, X), float32 or
            uint8), at least 2 samples per axis, no NaN.
        level: the iso-value; None for the default above.
        smooth: smoothing iterations after meshing (0: none); see :func:`smooth_mesh`.
        method: "taubin" (default) or "laplacian", used when ``smooth`` > 0.
        close: cap the surface at the border of the grid (a watertight result).

    Returns:
        ``trimesh.Trimesh`` with float64 vertices (world units) and outward faces.

    Raises:
        TypeError: ``field`` is not a Field.
        ValueError: a field with channels, fewer than 2 samples on an axis, NaN values,
            a level that is not finite or outside the range of the values (no
            surface), an unknown smoothing method or negative iterations.

    Example:
        >>> import numpy as np
        >>> from geosynth.geometry.field import Field
        >>> z, y, x = np.mgrid[:16, :16, :16]
        >>> f = Field(np.sqrt((x - 7.5) ** 2 + (y - 7.5) ** 2 + (z - 7.5) ** 2) - 5, (0, 0, 0), 1.0)
        >>> mesh = field_to_mesh(f)
        >>> bool(mesh.is_watertight and mesh.volume > 0)
        True
    """
    import trimesh
    from skimage import measure

    if not isinstance(field, Field):
        raise TypeError(f"field must be a geosynth.geometry.field.Field, got {type(field).__name__}.")
    values = field.values
    if values.ndim != 3:
        raise ValueError(f"field must be scalar (Z, Y, X) to mesh, got values of shape {values.shape}.")
    if min(values.shape) < 2:
        raise ValueError(f"field needs at least 2 samples on every axis to mesh, got shape {values.shape}.")
    _check_smoothing(smooth, method)
    if level is None:
        level = UINT8_LEVEL if values.dtype == np.uint8 else 0.0
    level = float(level)
    if not np.isfinite(level):
        raise ValueError(f"level must be a finite number, got {level!r}.")
    vol = values.astype(np.float32) if values.dtype == np.uint8 else values
    if np.isnan(vol).any():
        raise ValueError(f"field has {int(np.isnan(vol).sum())} NaN values; marching cubes needs numbers everywhere.")
    lo, hi = float(np.min(vol)), float(np.max(vol))
    if not lo < level < hi:
        raise ValueError(f"no surface: level {level} is not strictly inside the range of the values "
                         f"[{lo}, {hi}] (the field is all inside or all outside).")
    offset = np.zeros(3)
    if close:
        # one layer of outside values all round: the cut surface is capped
        outside = max(hi, level + 1.0) if values.dtype != np.uint8 else 255.0
        vol = np.pad(vol, 1, mode="constant", constant_values=outside)
        offset = -field.spacing  # index 0 of the padded grid is index -1 of the field
    spacing_zyx = tuple(float(s) for s in field.spacing[::-1])
    # "ascent": the inside has the smaller values (scikit-image's default assumes larger)
    verts, faces, _, _ = measure.marching_cubes(np.ascontiguousarray(vol), level, spacing=spacing_zyx,
                                                gradient_direction="ascent", allow_degenerate=False)
    if len(faces) == 0:
        raise ValueError(f"no surface at level {level}: marching cubes found no triangle.")
    vertices = field.origin + offset + verts[:, ::-1].astype(np.float64)  # (z, y, x) -> (x, y, z)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces.astype(np.int64), process=False)
    if smooth:
        mesh = smooth_mesh(mesh, smooth, method)
    return mesh


def _check_smoothing(iterations, method) -> None:
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 0:
        raise ValueError(f"smoothing iterations must be an integer >= 0, got {iterations!r}.")
    if method not in SMOOTHING_METHODS:
        raise ValueError(f"unknown smoothing method {method!r}; choose one of {', '.join(SMOOTHING_METHODS)}.")


def smooth_mesh(mesh, iterations: int = 10, method: str = "taubin"):
    """Smooth a mesh in place (and return it), keeping its volume about the same.

    - "taubin": Taubin's lambda|mu filter (lambda 0.5, mu -0.53), a low-pass filter that
      removes the staircase of marching cubes without the shrinking of plain Laplacian
      smoothing (``trimesh.smoothing.filter_taubin``).
    - "laplacian": Laplacian steps with the volume restored after each
      (``trimesh.smoothing.filter_laplacian(volume_constraint=True)``); stronger, for
      closed meshes.

    Args:
        mesh: a ``trimesh.Trimesh``; its vertices are moved, its faces kept.
        iterations: number of smoothing steps, >= 0.
        method: "taubin" or "laplacian".

    Returns:
        The same mesh.

    Raises:
        ValueError: an unknown method or negative iterations.
    """
    from trimesh import smoothing

    _check_smoothing(iterations, method)
    if iterations == 0:
        return mesh
    if method == "taubin":
        return smoothing.filter_taubin(mesh, lamb=0.5, nu=0.53, iterations=int(iterations))
    return smoothing.filter_laplacian(mesh, lamb=0.5, iterations=int(iterations), volume_constraint=True)


def save_mesh(mesh, path: str | os.PathLike, inputs=None) -> Path:
    """Write a mesh as PLY (binary), OBJ or STL (binary), chosen by the suffix, atomically.

    The file is written to a temporary file in the same folder and renamed into place,
    so an error never leaves a partial file (nor destroys an older one at ``path``).

    Args:
        mesh: a ``trimesh.Trimesh``.
        path: the output file; its suffix (.ply, .obj, .stl, any case) picks the format.
        inputs: paths this run read (e.g. the exemplar mesh); writing over one of them
            is refused.

    Returns:
        The path written.

    Raises:
        TypeError: ``mesh`` is not a trimesh.Trimesh.
        ValueError: an unknown suffix, an empty mesh, a vertex with NaN or inf
            coordinates (before any file is created), or ``path`` is one of ``inputs``.

    Example:
        >>> import tempfile, trimesh
        >>> p = save_mesh(trimesh.creation.box(), tempfile.mkdtemp() + "/box.ply")
        >>> p.suffix
        '.ply'
    """
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh):
        raise TypeError(f"mesh must be a trimesh.Trimesh, got {type(mesh).__name__}.")
    out = Path(path)
    file_type = MESH_SUFFIXES.get(out.suffix.lower())
    if file_type is None:
        raise ValueError(f"cannot write {str(out)!r}: unknown mesh suffix {out.suffix!r}; "
                         f"use one of {', '.join(MESH_SUFFIXES)}.")
    if len(mesh.faces) == 0:
        raise ValueError("refusing to write an empty mesh (no faces).")
    check_finite_output(out, "vertex", vertex=np.asarray(mesh.vertices))
    data = mesh.export(file_type=file_type)
    if isinstance(data, str):
        data = data.encode("utf-8")
    return atomic_write(out, lambda tmp: Path(tmp).write_bytes(data), inputs=tuple(inputs or ()))
