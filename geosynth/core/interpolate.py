"""Linear interpolation on regular grids: the one resampler of the project.

Textures (:mod:`geosynth.texturing.textures`), volume upsampling (:mod:`geosynth.volume.synthesis`) and
picture slices (:mod:`geosynth.io.pictures`) all resample with these two steps, so their
values agree bit for bit with each other and with the kernels that repeat
:func:`geosynth.texturing.textures.sample_bilinear` operation for operation:

- :func:`linear_taps`: along one axis, the two samples around a coordinate and the
  weight of the second (wrapped, or the coordinate clamped to the grid first);
- :func:`lerp_axis`: blend along one axis with those taps, ``a * (1 - t) + b * t``
  (:func:`geosynth.texturing.textures.sample_bilinear`, whose lookups are scattered, writes the
  same blend out for its four texels).

scipy.ndimage.map_coordinates / zoom (order=1) compute the same blend in float64 with
other roundings: that would change the float32 volume results and the texture values
the kernels reproduce, hence this small module. (The elements metric's grid
refinement, geosynth.volume.quality._refine, stays on scipy.ndimage.zoom: it differs from
this module by up to 1 float32 ulp, so moving it would change metric figures.)
"""

from __future__ import annotations

import numpy as np

__all__ = ["lerp_axis", "linear_taps"]


def linear_taps(coord, size: int, wrap: bool, dtype=np.float64,
                clamp: str = "coordinate") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two samples of a linear lookup along one axis and the weight of the second.

    Args:
        coord: array of coordinates in samples (sample centres at integers).
        size: number of samples along the axis, >= 1.
        wrap: periodic axis; otherwise clamped to the edge as ``clamp`` says.
        dtype: dtype of the returned weight (the fraction is computed in float64).
        clamp: "coordinate" (textures, pictures): the coordinate is clamped to
            [0, size - 1] first, so an edge lookup is the edge sample exactly;
            "taps" (volume upsampling): the fraction comes from the unclamped
            coordinate and the two indices are clamped, so beyond the edge the
            edge sample is blended with itself (kept: it is what the volume
            results were computed with, and float32 rounds the two differently).

    Returns:
        (i0, i1) int64 sample indices and the weight ``t`` of ``i1`` (``dtype``), all of
        coord's shape.
    """
    if clamp not in ("coordinate", "taps"):
        raise ValueError(f"clamp must be 'coordinate' or 'taps', got {clamp!r}.")
    c = np.asarray(coord, np.float64)
    if not wrap and clamp == "coordinate":
        c = np.clip(c, 0, size - 1)
    c0 = np.floor(c)
    frac = (c - c0).astype(dtype, copy=False)
    i0 = c0.astype(np.int64)
    if wrap:
        i0 = np.mod(i0, size)
        return i0, np.mod(i0 + 1, size), frac
    if clamp == "taps":
        return np.clip(i0, 0, size - 1), np.clip(i0 + 1, 0, size - 1), frac
    return i0, np.minimum(i0 + 1, size - 1), frac


def lerp_axis(values: np.ndarray, axis: int, taps: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Resample ``values`` along ``axis`` at the 1D taps of :func:`linear_taps`.

    Args:
        values: any-shape array (float); axis: the axis to resample.
        taps: (i0, i1, t), 1D arrays of the new length n along ``axis``.

    Returns:
        values' shape with n samples along ``axis``.
    """
    i0, i1, t = taps
    shape = [1] * values.ndim
    shape[axis] = len(t)
    t = t.reshape(shape)
    # one expression: each gathered copy is freed as soon as it is weighted (peak memory)
    return np.take(values, i0, axis=axis) * (1 - t) + np.take(values, i1, axis=axis) * t
