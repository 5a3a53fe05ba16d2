"""Built-in example data, generated procedurally so that everything runs with no input file."""

from __future__ import annotations

import numpy as np

__all__ = ["quantize_distance", "spheres_field"]


def quantize_distance(distance: np.ndarray, band: float) -> np.ndarray:
    """Map signed distances to uint8: -band -> 0, 0 -> 128 (about), +band -> 255.

    Args:
        distance: any-shape float array of signed distances (negative inside).
        band: half-width of the clamped band, in the same units, > 0.

    Returns:
        uint8 array of the same shape.
    """
    if not band > 0:
        raise ValueError(f"band must be > 0, got {band!r}.")
    t = (np.clip(distance, -band, band) + band) / (2 * band)
    return np.round(t * 255).astype(np.uint8)


def spheres_field(size: int = 64, count: int = 40, radius: tuple[float, float] = (3.0, 7.0), seed: int = 0) -> np.ndarray:
    """Signed distance to a periodic set of random spheres on a size^3 grid.

    Sphere centres are uniform in the cube and radii uniform in ``radius`` (in grid
    samples); the distance is taken with periodic wrap, so the field tiles.

    Args:
        size: samples per side, >= 4.
        count: number of spheres, >= 1.
        radius: (min, max) radius in samples.
        seed: seed of the numpy Generator that places them.

    Returns:
        (size, size, size) float32 signed distance in samples, negative inside.
    """
    if size < 4 or count < 1:
        raise ValueError(f"size must be >= 4 and count >= 1, got size={size}, count={count}.")
    rng = np.random.default_rng(seed)
    centres = rng.random((count, 3)) * size
    radii = rng.uniform(radius[0], radius[1], count)
    axis = np.arange(size, dtype=np.float32)
    field = np.full((size, size, size), np.inf, np.float32)
    for c, r in zip(centres, radii):
        # periodic per-axis distance to the centre
        d = [np.minimum(np.abs(axis - ci), size - np.abs(axis - ci)) for ci in c]
        dist = np.sqrt(d[0][:, None, None] ** 2 + d[1][None, :, None] ** 2 + d[2][None, None, :] ** 2) - r
        np.minimum(field, dist, out=field)
    return field
