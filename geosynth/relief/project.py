"""The baseline (issue 34, item 4): triplanar projection of the example, what projection tools
(BumpMesh / stlTexturizer) do. Each vertex reads the example (repeated as tiles) at its position
projected along x, along y and along z, and blends the three by the normal's |n_x|^4, |n_y|^4,
|n_z|^4 (normalized). Where one axis dominates the example is undistorted; where the weights
blend, two or three unrelated copies are averaged (the relief flattens, features double): the
seams the quality numbers look for (:func:`blend_share` marks them)."""

from __future__ import annotations

import numpy as np

from geosynth.relief.examples import ReliefExample

__all__ = ["BLEND_POWER", "blend_share", "project"]

BLEND_POWER = 4.0  # |n|^4: the usual triplanar sharpness (a narrower blend, more visible cuts)


def _weights(normals: np.ndarray) -> np.ndarray:
    w = np.abs(np.asarray(normals, np.float64)) ** BLEND_POWER
    return w / w.sum(1, keepdims=True)


def blend_share(normals: np.ndarray) -> np.ndarray:
    """(V,) float64 in [0, 2/3]: 1 - the largest projection weight: 0 where one projection alone
    lays the relief, larger on the blends (the projection's seams)."""
    return 1.0 - _weights(normals).max(1)


def _sample(example: ReliefExample, a: np.ndarray, b: np.ndarray):
    """Bilinear heights (and nearest colours) at world coordinates (a along x/columns, b along
    y/rows), the example repeated as tiles."""
    h, w = example.shape
    x = a / example.spacing
    y = b / example.spacing
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    g = example.heights
    # a non-tiling example repeats too (as projection tools do); its tile borders are seams as well
    x0m, x1m, y0m, y1m = x0 % w, (x0 + 1) % w, y0 % h, (y0 + 1) % h
    z = (g[y0m, x0m] * (1 - fx) * (1 - fy) + g[y0m, x1m] * fx * (1 - fy)
         + g[y1m, x0m] * (1 - fx) * fy + g[y1m, x1m] * fx * fy)
    col = None
    if example.colours is not None:
        col = example.colours[np.rint(y).astype(np.int64) % h, np.rint(x).astype(np.int64) % w].astype(np.float64)
    return z, col


def project(example: ReliefExample, vertices: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Triplanar projection.

    Args:
        example: the relief (world units, its own spacing: no resampling needed).
        vertices: (V, 3) float64 positions (world units); normals: (V, 3) unit float64.

    Returns:
        ((V,) float64 heights, world units; (V, 3) uint8 colours or None).
    """
    v = np.asarray(vertices, np.float64)
    w = _weights(normals)
    heights = np.zeros(len(v))
    colours = None if example.colours is None else np.zeros((len(v), 3))
    for axis, (i, j) in enumerate(((1, 2), (0, 2), (0, 1))):  # along x: (y, z); along y: (x, z); along z: (x, y)
        z, col = _sample(example, v[:, i], v[:, j])
        heights += w[:, axis] * z
        if colours is not None:
            colours += w[:, axis, None] * col
    return heights, None if colours is None else np.clip(np.rint(colours), 0, 255).astype(np.uint8)
