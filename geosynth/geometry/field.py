"""Where in the world is each sample of a grid? Implements no paper section: the grid type
of every distance field.

The Field type: values sampled on a regular grid, with the grid's place in the world."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geosynth.io.files import atomic_write, check_finite_output, check_input

__all__ = ["Field", "cubic_grid", "cubic_grid_geometry", "grid_points", "grid_resolution"]


def _as_xyz(name: str, value, *, positive: bool = False) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.ndim == 0:
        v = np.full(3, float(v))
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"{name} must be a finite number or 3 finite numbers (x, y, z), got {value!r}.")
    if positive and (v <= 0).any():
        raise ValueError(f"{name} must be > 0 on every axis, got {tuple(v)}.")
    return v


@dataclass
class Field:
    """Samples on a regular grid.

    Attributes:
        values: (Z, Y, X) or (Z, Y, X, C) float32 or uint8 array; index order z, y, x.
        origin: (3,) float64 world position (x, y, z) of sample [0, 0, 0].
        spacing: (3,) float64 distance between neighbouring samples along x, y, z.

    The sample at index (k, j, i) sits at ``origin + spacing * (i, j, k)``.
    """

    values: np.ndarray
    origin: np.ndarray
    spacing: np.ndarray

    def __post_init__(self):
        v = np.asarray(self.values)
        if v.ndim not in (3, 4):
            raise ValueError(f"Field values must be (Z, Y, X) or (Z, Y, X, C), got shape {v.shape}.")
        if v.dtype not in (np.dtype(np.float32), np.dtype(np.uint8)):
            if np.issubdtype(v.dtype, np.floating):
                v = v.astype(np.float32)
            else:
                raise TypeError(f"Field values must be float32 or uint8, got {v.dtype}.")
        self.values = v
        self.origin = _as_xyz("origin", self.origin)
        self.spacing = _as_xyz("spacing", self.spacing, positive=True)

    @classmethod
    def from_bounds(cls, bounds, resolution, channels: int | None = None, dtype=np.float32) -> "Field":
        """An all-zero field covering ``bounds`` with ``resolution`` samples per axis.

        Args:
            bounds: (2, 3) array, the (x, y, z) minimum and maximum corner; samples lie
                on both corners.
            resolution: samples per axis, one int >= 2 for all or (x, y, z).
            channels: None for scalar values, else the channel count.
            dtype: float32 or uint8.

        Returns:
            The Field; its spacing is extent / (resolution - 1).
        """
        shape_xyz = grid_resolution(resolution)
        b = np.asarray(bounds, np.float64)
        if b.shape != (2, 3) or not np.isfinite(b).all():
            raise ValueError(f"bounds must be a finite (2, 3) array [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {b.shape}.")
        extent = b[1] - b[0]
        if (extent <= 0).any():
            raise ValueError(f"bounds have zero or negative extent {tuple(extent)}: every axis needs max > min.")
        shape = tuple(int(s) for s in shape_xyz[::-1]) + (() if channels is None else (int(channels),))
        return cls(np.zeros(shape, dtype), b[0], extent / (shape_xyz - 1))

    @property
    def shape(self) -> tuple[int, int, int]:
        """(Z, Y, X) sample counts."""
        return tuple(self.values.shape[:3])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) world corners (x, y, z) of the first and last samples."""
        last = np.array(self.shape[::-1], np.float64) - 1
        return np.stack([self.origin, self.origin + self.spacing * last])

    def world_position(self, index) -> np.ndarray:
        """World (x, y, z) of samples given by (..., 3) integer or fractional (k, j, i) indices."""
        idx = np.asarray(index, np.float64)
        return self.origin + self.spacing * idx[..., ::-1]

    def points(self) -> np.ndarray:
        """(Z*Y*X, 3) float32 world positions of every sample, in the values' raster order."""
        return grid_points(self.origin, self.spacing, self.shape)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the field as .npz (values, origin, spacing), atomically; returns the path.

        Raises:
            ValueError: not a .npz path, or a value is NaN or inf (before any file is
                created; the message counts them and gives the first (z, y, x) sample).
        """
        out = Path(path)
        if out.suffix != ".npz":
            raise ValueError(f"Field files are .npz; got {str(out)!r} (add the .npz suffix).")
        check_finite_output(out, "sample (z, y, x)", field=self.values)
        return atomic_write(
            out, lambda tmp: np.savez_compressed(tmp, values=self.values, origin=self.origin, spacing=self.spacing)
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Field":
        """Read a field written by :meth:`save` (a .npz with values, origin, spacing).

        The file is noted as an input (:func:`geosynth.io.files.note_input`).

        Returns:
            The Field.

        Raises:
            FileNotFoundError: ``"field file 'X' does not exist."``
            ValueError: one line naming the file: a folder, an empty file, not a readable
                .npz (``"'X' is not a readable geosynth field file: <reason>; ..."``), or
                one without values, origin and spacing of the right shapes.
        """
        p = check_input(path, "field")
        try:
            fh = open(p, "rb")  # ours to close: np.load leaks its own on a corrupt archive
        except OSError as exc:  # no read permission, ...
            raise _unreadable_field(p, exc) from exc
        with fh:
            try:
                data = np.load(fh, allow_pickle=False)
            except Exception as exc:  # ValueError (pickled or unknown data), BadZipFile, EOFError, ...
                raise _unreadable_field(p, exc) from exc
            if not isinstance(data, np.lib.npyio.NpzFile):
                raise ValueError(f"{str(p)!r} is not a geosynth field file: it holds one array, not the values, "
                                 "origin and spacing that Field.save writes.")
            with data:
                missing = {"values", "origin", "spacing"} - set(data.files)
                if missing:
                    raise ValueError(f"{str(p)!r} is not a geosynth field: it lacks {', '.join(sorted(missing))}.")
                try:
                    values, origin, spacing = data["values"], data["origin"], data["spacing"]
                except Exception as exc:  # a corrupt member: zlib.error, BadZipFile (CRC), ValueError, ...
                    raise _unreadable_field(p, exc) from exc
        try:
            return cls(values, origin, spacing)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{str(p)!r} is not a valid geosynth field: {exc}") from exc


def _unreadable_field(p: Path, exc: BaseException) -> ValueError:
    from geosynth.io.readers import reason

    return ValueError(f"{str(p)!r} is not a readable geosynth field file: {reason(exc)}; give a .npz written by "
                      "Field.save (or the field command).")


def grid_resolution(resolution) -> np.ndarray:
    """Per-axis (x, y, z) sample counts from one int or three; each must be >= 2."""
    r = np.asarray(resolution)
    if r.ndim == 0:
        r = np.full(3, r)
    if r.shape != (3,) or r.dtype.kind not in "iu" or (r < 2).any():
        raise ValueError(f"resolution must be an integer >= 2 or three of them (x, y, z), got {resolution!r}.")
    return r.astype(np.int64)


def grid_points(origin, spacing, shape) -> np.ndarray:
    """(Z*Y*X, 3) float32 world (x, y, z) positions of a grid's samples in raster order."""
    z, y, x = (np.arange(n, dtype=np.float64) for n in shape)
    zz, yy, xx = np.meshgrid(z, y, x, indexing="ij")
    idx = np.stack([xx, yy, zz], -1).reshape(-1, 3)
    return (np.asarray(origin) + np.asarray(spacing) * idx).astype(np.float32)


def cubic_grid_geometry(bounds, resolution: int, padding: float = 0.1) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """The geometry of :func:`cubic_grid` without allocating it: (origin (3,) float64
    world (x, y, z) of the first sample, spacing (world units), shape (Z, Y, X)).

    Raises:
        ValueError: as :func:`cubic_grid`.
    """
    res = int(grid_resolution(resolution)[0]) if np.ndim(resolution) == 0 else None
    if res is None:
        raise ValueError(f"resolution must be one integer >= 2 for a cubic grid, got {resolution!r}.")
    b = np.asarray(bounds, np.float64)
    if b.shape != (2, 3) or not np.isfinite(b).all():
        raise ValueError(f"bounds must be a finite (2, 3) array [[xmin, ymin, zmin], [xmax, ymax, zmax]], got shape {b.shape}.")
    if not (np.isfinite(padding) and padding >= 0):
        raise ValueError(f"padding must be >= 0, got {padding!r}.")
    extent = b[1] - b[0]
    if (extent < 0).any() or extent.max() <= 0:
        raise ValueError(f"bounds have zero extent {tuple(extent)}: the box needs max > min on some axis.")
    size = extent + 2 * padding * extent.max()
    spacing = size.max() / (res - 1)
    counts = np.maximum(2, np.ceil(size / spacing - 1e-9).astype(np.int64) + 1)
    centre = (b[0] + b[1]) / 2
    origin = centre - spacing * (counts - 1) / 2
    return origin, float(spacing), (int(counts[2]), int(counts[1]), int(counts[0]))


def cubic_grid(bounds, resolution: int, padding: float = 0.1, channels: int | None = None) -> Field:
    """An all-zero float32 Field with cubic cells around ``bounds``.

    The box is grown by ``padding`` times its largest extent on every side; its
    longest axis gets ``resolution`` samples and the others as many as the same
    spacing needs (at least 2), centred on the box.

    Args:
        bounds: (2, 3) (x, y, z) minimum and maximum corner, e.g. ``mesh.bounds``.
        resolution: samples along the longest axis, >= 2.
        padding: fraction of the largest extent added on each side, >= 0.
        channels: None for scalar values, else the channel count.

    Returns:
        The Field (values zero); fill ``values`` from ``points()``.
    """
    origin, spacing, shape = cubic_grid_geometry(bounds, resolution, padding)
    shape = shape + (() if channels is None else (int(channels),))
    return Field(np.zeros(shape, np.float32), origin, np.full(3, spacing))
