"""Which texture, at which resolution, is sampled? The supersampled texture and the texture
pyramid of Zhang, Qiu and Kaufman, "Fast Hybrid Approach for Texturing Point Models", Sec. 4
and 4.1.

Sample textures for M3 (texturing point models): image input/output through Pillow,
procedural built-ins, bilinear lookups, the m-times supersampled texture of the
neighbourhood search and the texture pyramid of multiresolution matching.

A texture is an (H, W, 3) uint8 RGB array. Texel (i, j) sits at the continuous texture
coordinate (y, x) = (i, j) (texel centres at integers, texel side 1); the point
parameterization and the tangent-plane neighbourhoods are measured in these units.

Every float step here (bilinear lookups, supersampling, pyramid) runs once on the host
in float64 and is rounded to uint8, so every device scores the same integers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from geosynth.core.interpolate import lerp_axis, linear_taps
from geosynth.io.files import check_input, write_image

__all__ = [
    "TEXTURES", "TextureExample", "as_texture", "bricks_texture", "checker_texture", "noise_texture",
    "read_texture", "sample_bilinear", "supersample", "texture_example", "texture_pyramid", "write_texture",
]


# ------------------------------------------------------------------ conversion and I/O


def as_texture(image, name: str = "texture") -> np.ndarray:
    """Check and convert an image array to an (H, W, 3) uint8 RGB texture.

    - (H, W) grey and (H, W, 1) are converted to RGB by repeating the channel.
    - (H, W, 4) RGBA: an alpha that is everywhere opaque (255, or 1.0 for floats) is
      dropped; a texture with transparent texels is refused (there is no colour to
      copy there): flatten it onto a background first.
    - float data must lie in [0, 1] and is scaled to 0..255 (rounded); integer data
      must lie in 0..255.

    Args:
        image: the array.
        name: the argument's name, for error messages.

    Returns:
        (H, W, 3) uint8 C-contiguous array (a new array unless already so).

    Raises:
        TypeError: not a numeric array.
        ValueError: wrong shape, values out of range, NaN, or transparent texels.
    """
    a = np.asarray(image)
    if a.dtype.kind not in "iuf" and a.dtype != np.bool_:
        raise TypeError(f"{name} must be a numeric image array, got dtype {a.dtype}.")
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise ValueError(f"{name} must have shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got {np.shape(image)}.")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name} is empty (shape {a.shape}).")
    if a.dtype.kind == "f":
        if not np.isfinite(a).all():
            raise ValueError(f"{name} contains NaN or inf.")
        if a.min() < 0 or a.max() > 1:
            raise ValueError(f"float {name} must lie in [0, 1], got [{a.min():.3g}, {a.max():.3g}]; pass uint8 for 0..255.")
        a = np.rint(a.astype(np.float64) * 255)
    elif a.dtype != np.uint8:
        if a.min() < 0 or a.max() > 255:
            raise ValueError(f"integer {name} must lie in 0..255, got [{a.min()}, {a.max()}].")
    a = a.astype(np.uint8)
    if a.shape[2] == 4:
        transparent = int(np.count_nonzero(a[:, :, 3] < 255))
        if transparent:
            raise ValueError(
                f"{name} is RGBA with {transparent} transparent texel(s): a texture needs a colour everywhere; "
                "flatten it onto a background colour first (e.g. Pillow's Image.alpha_composite), or drop the alpha."
            )
        a = a[:, :, :3]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return np.ascontiguousarray(a)


def read_texture(path: str | os.PathLike) -> np.ndarray:
    """Read a texture image (PNG, JPEG or anything Pillow reads) as RGB.

    Grey (L, I;16, ...) and palette images are converted to RGB; an RGBA (or LA, or a
    palette with transparency) image is accepted only if fully opaque, see
    :func:`as_texture`. The file is noted as an input (:func:`geosynth.io.files.note_input`).

    Args:
        path: the image file.

    Returns:
        (H, W, 3) uint8 array.

    Raises:
        ImportError: Pillow is missing.
        FileNotFoundError: ``"texture image file 'X' does not exist."``
        ValueError: one line naming the file: a folder, an empty file, more pixels than
            Pillow's limit (``"texture image 'X' has 400,000,000 pixels (20000 x 20000),
            more than Pillow's limit of 89,478,485 ..."``), an unreadable or truncated
            image (``"'X' is not a readable image: <reason>; ..."``), or transparent texels.
    """
    import warnings

    try:
        from PIL import Image
    except ImportError as exc:  # pragma: no cover - pillow is a dependency
        raise ImportError("reading texture images needs Pillow: pip install pillow") from exc
    from geosynth.io.readers import reason

    p = check_input(path, "texture image")
    name = f"texture {p.name}"
    try:
        with warnings.catch_warnings():
            # Pillow warns beyond MAX_IMAGE_PIXELS (checked below, with the size at hand) and
            # raises beyond twice that: both are refused
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(p) as img:
                _check_pixels(p, img.size, Image.MAX_IMAGE_PIXELS)
                img.load()
                mode = img.mode
                if mode in ("RGBA", "LA", "PA") or (mode == "P" and "transparency" in img.info):
                    kind, pixels = "rgba", np.asarray(img.convert("RGBA"))
                elif mode.startswith("I;16") or mode == "I":
                    kind, pixels = "wide", np.asarray(img, dtype=np.float64)
                else:
                    kind, pixels = "rgb", np.asarray(img.convert("RGB"))
    except Image.DecompressionBombError as exc:
        _check_pixels(p, None, Image.MAX_IMAGE_PIXELS, str(exc))
        raise  # pragma: no cover - _check_pixels raised
    except ValueError as exc:
        if str(exc).startswith(f"texture image {str(p)!r}"):
            raise
        raise _unreadable_image(p, reason(exc)) from exc
    except Exception as exc:  # OSError (truncated, unidentified), SyntaxError, EOFError, zlib.error, ...
        raise _unreadable_image(p, reason(exc)) from exc
    if kind == "wide":
        top = 65535.0 if pixels.max(initial=0) > 255 else 255.0
        pixels = np.rint(pixels / top * 255).astype(np.uint8)
    return as_texture(pixels, name)


def _unreadable_image(p: Path, why: str) -> ValueError:
    return ValueError(f"{str(p)!r} is not a readable image: {why}; give a complete PNG or JPEG file "
                      "(or another format Pillow reads).")


def _check_pixels(p: Path, size, limit, message: str | None = None) -> None:
    """Refuse an image with more pixels than Pillow's limit (``PIL.Image.MAX_IMAGE_PIXELS``)."""
    import re

    if limit is None:
        return
    if size is not None:
        count, shape = int(size[0]) * int(size[1]), f" ({size[0]} x {size[1]})"
        if count <= limit:
            return
    else:  # Pillow refused it while opening: its message has the pixel count
        found = re.search(r"\((\d+) pixels\)", message or "")
        count, shape = (int(found.group(1)) if found else None), ""
    has = f"has {count:,} pixels{shape}" if count is not None else "has too many pixels"
    raise ValueError(f"texture image {str(p)!r} {has}, more than Pillow's limit of {int(limit):,} "
                     "(PIL.Image.MAX_IMAGE_PIXELS, a guard against decompression bombs); use a smaller image, or "
                     "raise that limit if you trust the file.")


def write_texture(path: str | os.PathLike, texture: np.ndarray, *, inputs=()) -> Path:
    """Write a texture as PNG or JPEG (by suffix, through Pillow), atomically.

    Args:
        path: .png, .jpg or .jpeg file.
        texture: (H, W, 3) uint8 (anything :func:`as_texture` accepts).
        inputs: files never to overwrite.

    Returns:
        The path written.
    """
    return write_image(path, as_texture(texture), inputs=inputs)


# ------------------------------------------------------------------ lookups


def sample_bilinear(texture: np.ndarray, y, x, wrap: bool) -> np.ndarray:
    """Bilinear texture lookup at continuous texel coordinates, in float64.

    Args:
        texture: (H, W, C) array.
        y, x: arrays of the same shape S: coordinates in texels (texel centres at integers).
        wrap: periodic texture (tileable); otherwise coordinates are clamped to the edge.

    Returns:
        S + (C,) float64 values.
    """
    tex = np.asarray(texture, np.float64)
    h, w = tex.shape[:2]
    y0, y1, fy = linear_taps(y, h, wrap)
    x0, x1, fx = linear_taps(x, w, wrap)
    fy, fx = fy[..., None], fx[..., None]
    top = tex[y0, x0] * (1 - fx) + tex[y0, x1] * fx  # lerp_axis's blend, at scattered texels
    bottom = tex[y1, x0] * (1 - fx) + tex[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def sample_bilinear_grid(texture: np.ndarray, y, x, wrap: bool) -> np.ndarray:
    """:func:`sample_bilinear` at every (y[i], x[j]) of a grid, the same values bit for
    bit (the same operations: rows are blended along x first, then along y), in
    O(H * len(x) + len(y) * len(x)) work instead of four lookups per sample.

    Args:
        texture: (H, W, C) array; y: (Ny,) and x: (Nx,) coordinates in texels.
        wrap: periodic texture; otherwise coordinates are clamped to the edge.

    Returns:
        (Ny, Nx, C) float64.
    """
    tex = np.asarray(texture, np.float64)
    h, w = tex.shape[:2]
    rows = lerp_axis(tex, 1, linear_taps(x, w, wrap))  # (H, Nx, C): every texture row along x
    return lerp_axis(rows, 0, linear_taps(y, h, wrap))


def supersample(texture: np.ndarray, m: int = 8, wrap: bool = True, scale: float = 1.0,
                shift: float = 0.0) -> np.ndarray:
    """The texture resampled bilinearly at 1/m texel steps (the paper's m-times supersampling).

    Pixel (Y, X) of the result holds the texture at ``((Y / m - shift) / scale,
    (X / m - shift) / scale)``; with the defaults, pixel (m i, m j) is texel (i, j)
    exactly, so a lookup rounded to the nearest pixel needs no interpolation and the
    candidates of the search are the pixels on the stride-m lattice.

    ``scale`` and ``shift`` resample a coarser pyramid level into a finer level's
    pixels (scale 2, shift 0.5 for a 2 x 2 box reduction).

    Args:
        texture: (H, W, C) uint8 (or float) texture.
        m: supersampling factor, >= 1.
        wrap: periodic texture.
        scale, shift: see above.

    Returns:
        (m * H * scale, m * W * scale, C) uint8, rounded half to even.
    """
    if not isinstance(m, (int, np.integer)) or m < 1:
        raise ValueError(f"m (the supersampling factor) must be an integer >= 1, got {m!r}.")
    tex = np.asarray(texture)
    h, w = tex.shape[:2]
    hh, ww = int(round(m * h * scale)), int(round(m * w * scale))
    yy = (np.arange(hh, dtype=np.float64) / m - shift) / scale
    xx = (np.arange(ww, dtype=np.float64) / m - shift) / scale
    return np.clip(np.rint(sample_bilinear_grid(tex, yy, xx, wrap)), 0, 255).astype(np.uint8)


def texture_pyramid(texture: np.ndarray, levels: int) -> list[np.ndarray]:
    """A texture pyramid by 2 x 2 box averaging (rounded to uint8): level 0 is the texture.

    An odd last row or column is dropped before reducing.

    Args:
        texture: (H, W, 3) uint8.
        levels: number of levels, >= 1; the coarsest must keep at least 2 x 2 texels.

    Returns:
        ``levels`` arrays, level l of size (H >> l, W >> l, 3).

    Raises:
        ValueError: levels < 1, or a texture too small for that many levels.
    """
    tex = as_texture(texture)
    if not isinstance(levels, (int, np.integer)) or levels < 1:
        raise ValueError(f"levels must be an integer >= 1, got {levels!r}.")
    h, w = tex.shape[:2]
    if min(h, w) >> (levels - 1) < 2:
        raise ValueError(f"a {w} x {h} texture is too small for {levels} pyramid levels (the coarsest needs 2 x 2 texels).")
    out = [tex]
    for _ in range(levels - 1):
        t = out[-1].astype(np.float64)
        hh, ww = t.shape[0] // 2 * 2, t.shape[1] // 2 * 2
        t = t[:hh, :ww]
        box = (t[0::2, 0::2] + t[1::2, 0::2] + t[0::2, 1::2] + t[1::2, 1::2]) / 4
        out.append(np.clip(np.rint(box), 0, 255).astype(np.uint8))
    return out


# ------------------------------------------------------------------ procedural textures


def bricks_texture(size: int = 64, seed: int = 0, brick: tuple[int, int] = (8, 16), mortar: int = 2) -> np.ndarray:
    """A tileable brick wall (a regular texture): staggered rows of bricks whose colours
    vary a little, light mortar joints, slight per-texel grain.

    Args:
        size: texels per side; a multiple of brick height, of brick width, and of 2 x
            (half a brick) so that the pattern tiles.
        seed: seed of the colour variation.
        brick: (height, width) of a brick including its mortar, in texels.
        mortar: mortar width in texels, in [1, min(brick) - 2].

    Returns:
        (size, size, 3) uint8.
    """
    bh, bw = brick
    if size < 4 or size % bh or size % bw or bw % 2 or not 1 <= mortar <= min(bh, bw) - 2:
        raise ValueError(f"size {size} must be a multiple of the brick size {brick} (even width) and "
                         f"mortar {mortar} in [1, {min(bh, bw) - 2}].")
    rng = np.random.default_rng(seed)
    rows, cols = size // bh, size // bw
    base = np.array([160.0, 62.0, 42.0])
    tint = base[None, None, :] * rng.uniform(0.8, 1.15, (rows, cols, 1)) + rng.normal(0, 6, (rows, cols, 3))
    y, x = np.mgrid[0:size, 0:size]
    row = y // bh
    xs = (x + (row % 2) * (bw // 2)) % size  # odd rows shifted by half a brick
    col = xs // bw
    img = tint[row, col] + rng.normal(0, 5, (size, size, 1))
    joint = (y % bh < mortar) | (xs % bw < mortar)
    img[joint] = np.array([205.0, 200.0, 190.0]) + rng.normal(0, 4, (int(joint.sum()), 1))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def checker_texture(size: int = 64, seed: int = 0, cells: int = 6) -> np.ndarray:
    """A tileable checker of varying cells (a regular texture): cell edges at random
    positions along each axis (an even count, so colours alternate across the seam),
    two colours.

    Args:
        size: texels per side, >= 4 * cells.
        seed: seed of the cell sizes.
        cells: cells per axis, even, >= 2.

    Returns:
        (size, size, 3) uint8.
    """
    if cells < 2 or cells % 2 or size < 4 * cells:
        raise ValueError(f"cells must be even and >= 2 with size >= 4 * cells, got cells={cells}, size={size}.")
    rng = np.random.default_rng(seed)

    def edges():
        widths = rng.uniform(0.6, 1.4, cells)
        cuts = np.rint(np.cumsum(widths) / widths.sum() * size).astype(np.int64)
        return np.searchsorted(cuts, np.arange(size), side="right")  # cell index per texel

    cy, cx = edges(), edges()
    parity = (cy[:, None] + cx[None, :]) % 2
    dark, light = np.array([40, 52, 96]), np.array([236, 214, 150])
    return np.where(parity[:, :, None] == 1, dark, light).astype(np.uint8)


def noise_texture(size: int = 64, seed: int = 0, wavelength: float = 8.0) -> np.ndarray:
    """Tileable filtered noise (a stochastic texture): white noise low-pass filtered in
    the Fourier domain (a Gaussian of the given wavelength, so it tiles) for a scalar
    field and a finer second field, mapped to a moss-and-stone colour ramp.

    Args:
        size: texels per side, >= 8.
        seed: seed of the noise.
        wavelength: feature size in texels, > 1.

    Returns:
        (size, size, 3) uint8.
    """
    if size < 8 or not wavelength > 1:
        raise ValueError(f"size must be >= 8 and wavelength > 1, got size={size}, wavelength={wavelength}.")
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    rad2 = f[:, None] ** 2 + f[None, :] ** 2

    def field(wl):
        spectrum = np.fft.fft2(rng.standard_normal((size, size))) * np.exp(-rad2 * (wl / 2.0) ** 2 * 2 * np.pi**2 / 2)
        v = np.real(np.fft.ifft2(spectrum))
        return (v - v.mean()) / (v.std() + 1e-12)

    a, b = field(wavelength), field(wavelength / 3)
    t = np.clip(0.5 + 0.22 * a + 0.08 * b, 0, 1)[:, :, None]
    low, high = np.array([46.0, 70.0, 30.0]), np.array([196.0, 186.0, 150.0])
    return np.clip(np.rint(low + (high - low) * t), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class TextureExample:
    """A built-in texture: ``build(size, seed)``, whether it tiles, and its kind."""

    name: str
    build: Callable[..., np.ndarray]
    summary: str
    regular: bool
    tileable: bool = True
    pattern_size: int = 8  # the texture's pattern size in texels at size 64 (hybrid gap widening)
    bytes_per_texel: int = 120  # peak bytes per texel of build (tracemalloc, sizes 256-1024)
    smallest: int = 8  # the smallest valid size
    size_step: int = 1  # valid sizes are multiples of it


# bytes_per_texel, measured peak (tracemalloc) at sizes 256, 512, 1024: bricks 113.2 (float64
# colours, noise and index grids), checker 35.0 (int64 parity, int64 colour choice), noise
# 80.1-81.1 (complex spectra); the estimate adds 64 KiB.
TEXTURES: dict[str, TextureExample] = {
    "bricks": TextureExample("bricks", bricks_texture, "staggered bricks (regular)", True, pattern_size=16,
                             bytes_per_texel=114, smallest=16, size_step=16),
    "checker": TextureExample("checker", checker_texture, "checker of varying cells (regular)", True, pattern_size=11,
                              bytes_per_texel=36, smallest=24),
    "noise": TextureExample("noise", noise_texture, "filtered noise, moss and stone (stochastic)", False, pattern_size=8,
                            bytes_per_texel=81, smallest=8),
}


def texture_example(name: str, size: int = 64, seed: int = 0) -> np.ndarray:
    """A built-in procedural texture by name (bricks, checker, noise), (size, size, 3) uint8.

    Raises:
        ValueError: an unknown name (the message lists the built-in ones), a size that
            is not a positive integer or does not suit the texture.
        MemoryBudgetError: the texture would not fit in memory (option ``"texture_size"``,
            the CLI's ``--texture-size``; refused before allocating).
    """
    from geosynth.core.memory import require

    if name not in TEXTURES:
        raise ValueError(f"unknown texture example {name!r}; the built-in textures are: {', '.join(TEXTURES)}.")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
        raise ValueError(f"size must be a positive integer (texels per side), got {size!r}.")
    ex = TEXTURES[name]

    def estimate(s: int) -> int:
        return ex.bytes_per_texel * int(s) ** 2 + (64 << 10)

    require(estimate(size), option="texture_size", value=size, largest_fn=estimate, smallest=ex.smallest,
            step=ex.size_step, what=f"the {size:,} x {size:,} {name} texture")
    return ex.build(size=size, seed=seed)
