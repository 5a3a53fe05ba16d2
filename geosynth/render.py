"""Pictures of results, written as PNG with no imaging dependency."""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from geosynth._atomic import atomic_write

__all__ = ["write_png"]


def write_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an 8-bit grey (H, W) or RGB (H, W, 3) image as PNG, atomically.

    The file is written beside the target and renamed into place, so a failure never
    leaves a half-written file.

    Args:
        path: the output file.
        image: (H, W) or (H, W, 3) uint8 array.

    Returns:
        The path written.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"image must be (H, W) or (H, W, 3) uint8, got {img.shape} {img.dtype}.")
    h, w = img.shape[:2]
    colour_type = 0 if img.ndim == 2 else 2
    rows = np.ascontiguousarray(img).reshape(h, -1)
    raw = b"".join(b"\x00" + rows[i].tobytes() for i in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(png)

    return atomic_write(path, write)


def _bilinear(image: np.ndarray, factor: int) -> np.ndarray:
    """Upsample a 2D array by an integer factor with bilinear interpolation."""
    h, w = image.shape
    y = np.clip((np.arange(h * factor) + 0.5) / factor - 0.5, 0, h - 1)
    x = np.clip((np.arange(w * factor) + 0.5) / factor - 0.5, 0, w - 1)
    y0, x0 = np.minimum(y.astype(int), h - 2 if h > 1 else 0), np.minimum(x.astype(int), w - 2 if w > 1 else 0)
    y1, x1 = np.minimum(y0 + 1, h - 1), np.minimum(x0 + 1, w - 1)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    top = image[y0][:, x0] * (1 - fx) + image[y0][:, x1] * fx
    bottom = image[y1][:, x0] * (1 - fx) + image[y1][:, x1] * fx
    return top * (1 - fy) + bottom * fy


def distance_colours(distance: np.ndarray, scale: float, spacing: float) -> np.ndarray:
    """Colour a 2D slice of signed distances: blue inside, orange outside, darker
    bands every ``spacing`` (iso-distance lines), the zero level in black.

    Args:
        distance: (H, W) float signed distances.
        scale: the distance mapped to full saturation (> 0).
        spacing: distance between the bands (> 0).

    Returns:
        (H, W, 3) uint8 RGB.
    """
    d = np.asarray(distance, np.float64)
    t = np.clip(np.abs(d) / scale, 0, 1)[..., None]
    inside = np.array([40, 90, 200.0])
    outside = np.array([235, 140, 40.0])
    white = np.array([250, 250, 250.0])
    rgb = np.where(d[..., None] < 0, white + (inside - white) * t, white + (outside - white) * t)
    band = 0.93 + 0.07 * np.cos(2 * np.pi * d / spacing)[..., None]
    rgb = rgb * band
    neg = d < 0
    zero = np.zeros_like(neg)  # the zero level: inside pixels with an outside 4-neighbour
    zero[:-1] |= neg[:-1] & ~neg[1:]
    zero[1:] |= neg[1:] & ~neg[:-1]
    zero[:, :-1] |= neg[:, :-1] & ~neg[:, 1:]
    zero[:, 1:] |= neg[:, 1:] & ~neg[:, :-1]
    rgb[zero] = 0
    return np.clip(rgb, 0, 255).astype(np.uint8)


def field_slices_image(values: np.ndarray, count: int = 3, axis: int = 0, size: int = 256) -> np.ndarray:
    """Side-by-side slices of a (Z, Y, X) signed-distance volume, zero level in black.

    Slices are taken at evenly spaced positions inside the volume along ``axis``
    (0: z, 1: y, 2: x), each scaled up by an integer factor to about ``size`` pixels,
    separated by a white gap.

    Args:
        values: (Z, Y, X) float distances (uint8 fields are shown as value - 127.5).
        count: number of slices, >= 1.
        axis: the axis across which to cut.
        size: target slice size in pixels.

    Returns:
        (H, W, 3) uint8 RGB image.
    """
    vol = np.asarray(values)
    if vol.ndim != 3:
        raise ValueError(f"values must be a (Z, Y, X) volume, got shape {vol.shape}.")
    vol = vol.astype(np.float64) - (127.5 if vol.dtype == np.uint8 else 0.0)
    n = vol.shape[axis]
    positions = [int(round((i + 1) * (n - 1) / (count + 1))) for i in range(count)]
    finite = np.abs(vol[np.isfinite(vol)])
    scale = float(np.percentile(finite, 95)) if finite.size else 1.0
    scale = scale if scale > 0 else 1.0
    slices = [np.take(vol, p, axis=axis) for p in positions]
    factor = max(1, size // max(slices[0].shape))
    tiles = [distance_colours(_bilinear(s[::-1], factor), scale, scale / 4) for s in slices]  # y up
    gap = np.full((tiles[0].shape[0], 8, 3), 255, np.uint8)
    row = [tiles[0]]
    for t in tiles[1:]:
        row += [gap, t]
    return np.concatenate(row, axis=1)
