"""What does the example look like? One internal form for the three kinds of relief example
(issue 34, item 1): a height grid in world units with its spacing, and an optional RGB grid.

- a grey height-map image (Pillow; white high), optionally with a colour image of the same
  size: its width spans a quarter of the mesh's size times ``scale``, its heights ``depth``
  from black to white;
- a captured patch (a mesh or a PLY point set, with or without colour): its relief measured
  over its least-squares plane as M4 measures a capture (Breckon and Fisher, Sec. 3:
  displacements over the fit; :func:`geosynth.completion.prep.as_capture`,
  :func:`geosynth.completion.fit.fit_surface` with ``"plane"``,
  :func:`geosynth.completion.fit.relief_frame`), gridded with
  :func:`geosynth.completion.spectrum.heights_on_grid`; it keeps its own world size (times ``scale``);
- a built-in by name (:data:`BUILTINS`): procedural, seeded, periodic (so that a projection
  can tile it), treated as a 128 x 128 height image; :func:`builtin_image` writes one as a grey image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

__all__ = ["BUILTINS", "IMAGE_WIDTH_SHARE", "DEFAULT_DEPTH_SHARE", "ReliefExample", "builtin_heights",
           "builtin_image", "load_example"]

BUILTINS = ("knurl", "bark", "hammered", "cobbles", "scales", "weave")
BUILTIN_SIZE = 128  # pixels a side of a built-in (every built-in's period divides it: they tile)
IMAGE_WIDTH_SHARE = 0.25  # an image spans this share of the mesh's size (largest bounding-box side), x scale
DEFAULT_DEPTH_SHARE = 0.01  # default --depth of an image or built-in: this share of the mesh's size
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class ReliefExample:
    """An example relief as one regular grid.

    Attributes:
        heights: (H, W) float64 heights in world units (lowest 0), rows along y, columns along x.
        spacing: world length of one cell (square cells), > 0.
        colours: (H, W, 3) uint8 RGB, or None.
        name: how the output line names it.
        note: how it was sized (the output line prints it).
        periodic: True when the grid tiles (a built-in): a projection may repeat it seamlessly and
            the synthesis may wrap its border.
    """

    heights: np.ndarray
    spacing: float
    colours: np.ndarray | None
    name: str
    note: str
    periodic: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape

    @property
    def depth(self) -> float:
        """The relief's full height range, world units."""
        return float(self.heights.max() - self.heights.min())

    def resampled(self, spacing: float) -> "ReliefExample":
        """The same relief on a grid of ``spacing`` (world units): bilinear heights, nearest colours;
        wrapped at the border when periodic. The world size is kept (the cell count changes)."""
        from scipy import ndimage

        if abs(spacing - self.spacing) <= 1e-9 * self.spacing:
            return self
        h, w = self.shape
        edge = 0 if self.periodic else 1  # a tiling grid spans its cells, another its cell centres
        span_y, span_x = (h - edge) * self.spacing, (w - edge) * self.spacing
        ny = max(4, int(round(span_y / spacing)) + (0 if self.periodic else 1))
        nx = max(4, int(round(span_x / spacing)) + (0 if self.periodic else 1))
        # cell centres of the new grid in old cell units (the new spacing exact along each axis, rounded to fit)
        sy = span_y / (ny - (0 if self.periodic else 1)) / self.spacing
        sx = span_x / (nx - (0 if self.periodic else 1)) / self.spacing
        yy, xx = np.meshgrid(np.arange(ny) * sy, np.arange(nx) * sx, indexing="ij")
        mode = "grid-wrap" if self.periodic else "nearest"
        heights = ndimage.map_coordinates(self.heights, [yy, xx], order=1, mode=mode)
        colours = None
        if self.colours is not None:
            iy = np.rint(yy).astype(np.int64) % h if self.periodic else np.clip(np.rint(yy).astype(np.int64), 0, h - 1)
            ix = np.rint(xx).astype(np.int64) % w if self.periodic else np.clip(np.rint(xx).astype(np.int64), 0, w - 1)
            colours = self.colours[iy, ix]
        return replace(self, heights=heights, spacing=float(self.spacing * sx), colours=colours)

    def scaled(self, scale: float) -> "ReliefExample":
        """The relief with its lateral size times ``scale`` (heights kept)."""
        return replace(self, spacing=self.spacing * float(scale))

    def with_depth(self, depth: float) -> "ReliefExample":
        """The relief with its height range set to ``depth`` world units (lowest 0)."""
        h = self.heights - self.heights.min()
        top = float(h.max())
        return replace(self, heights=h * (depth / top) if top > 0 else h)


# ---------------------------------------------------------------------- built-ins


def _tri(t: np.ndarray) -> np.ndarray:
    """A triangle wave of period 1 in [0, 1], 1 at integers."""
    return np.abs(1.0 - 2.0 * (t - np.floor(t)))


def _periodic_noise(n: int, rng: np.random.Generator, cutoff: float, slope: float = 1.5) -> np.ndarray:
    """(n, n) float64 periodic noise in [0, 1]: random phases at integer frequencies up to ``cutoff``
    cycles across the grid, amplitudes falling as |f|^-slope."""
    f = np.fft.fftfreq(n) * n
    fy, fx = np.meshgrid(f, f, indexing="ij")
    r = np.hypot(fx, fy)
    amp = np.where((r > 0) & (r <= cutoff), np.maximum(r, 1) ** -slope, 0.0)
    spec = amp * np.exp(2j * np.pi * rng.random((n, n)))
    z = np.fft.ifft2(spec).real
    z -= z.min()
    return z / max(float(z.max()), 1e-300)


def _voronoi(n: int, rng: np.random.Generator, cell: int):
    """(F1, F2, index) distances (pixels) to the nearest and second nearest of jittered grid points
    (one per ``cell`` x ``cell`` square, so that the features are evenly sized) on the n x n torus,
    and the nearest one's index."""
    from scipy.spatial import cKDTree

    k = n // cell
    count = k * k
    gy, gx = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    pts = (np.stack([gy.ravel(), gx.ravel()], 1) + 0.15 + 0.7 * rng.random((count, 2))) * (n / k)
    shifts = np.array([(a, b) for a in (-n, 0, n) for b in (-n, 0, n)], np.float64)
    tiled = (pts[None, :, :] + shifts[:, None, :]).reshape(-1, 2)
    yy, xx = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5, indexing="ij")
    d, i = cKDTree(tiled).query(np.stack([yy.ravel(), xx.ravel()], 1), k=2)
    return d[:, 0].reshape(n, n), d[:, 1].reshape(n, n), (i[:, 0] % count).reshape(n, n)


def _norm01(h: np.ndarray) -> np.ndarray:
    h = h - h.min()
    return h / max(float(h.max()), 1e-300)


def builtin_heights(name: str, seed: int = 0, size: int = BUILTIN_SIZE) -> tuple[np.ndarray, np.ndarray | None]:
    """A built-in relief: ((size, size) float64 heights in [0, 1], (size, size, 3) uint8 colours or None).

    Every one tiles (periodic on the size x size torus; its period divides the size, 128 by default):
    knurl: a diamond knurl, square pyramids between two crossing sets of grooves at +-45 degrees,
    period 16 px along x and y; bark: vertical ridges wandering with low-frequency noise, brown;
    hammered: parabolic dimples around random points meeting in ridges; cobbles: rounded stones
    (Voronoi cells) in mortar grooves, each stone its own grey-brown; scales: overlapping rows of
    round scales (fish, dragon); weave: a plain weave of strands 8 px wide.
    The seed moves the random parts (and the knurl's phase).

    Raises:
        ValueError: an unknown name (lists the built-ins).
    """
    if name not in BUILTINS:
        raise ValueError(f"unknown built-in example {name!r}; the built-ins are {', '.join(BUILTINS)}.")
    rng = np.random.default_rng([int(seed), BUILTINS.index(name)])
    n = int(size)
    yy, xx = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64), indexing="ij")
    colours = None
    if name == "knurl":
        p = 16.0
        oy, ox = rng.integers(0, int(p), 2)
        u, v = (xx + ox + yy + oy) / p, (xx + ox - yy - oy) / p
        h = np.minimum(_tri(u + 0.5), _tri(v + 0.5))  # pyramids between the two groove sets
        h = h + 0.02 * _periodic_noise(n, rng, n / 4)
    elif name == "bark":
        warp = (_periodic_noise(n, rng, 3, 1.0) - 0.5) * 20.0
        p = 16.0
        ridge = _tri((xx + warp) / p)
        h = ridge ** 0.6 * 0.8 + 0.2 * _periodic_noise(n, rng, n / 6, 1.0)
        c = np.stack([0.36 + 0.2 * h, 0.24 + 0.14 * h, 0.15 + 0.08 * h], -1)
        colours = np.clip(np.rint(c * 255), 0, 255).astype(np.uint8)
    elif name == "hammered":
        f1, _, _ = _voronoi(n, rng, 11)
        h = np.clip((f1 / 7.0) ** 2, 0, 1) + 0.03 * _periodic_noise(n, rng, n / 4)
    elif name == "cobbles":
        f1, f2, cell = _voronoi(n, rng, 16)
        edge = np.clip((f2 - f1) / 6.0, 0, 1)
        h = np.sqrt(edge) * (1.0 - 0.3 * np.clip(f1 / 12.0, 0, 1) ** 2)  # rounded stones, mortar grooves
        tint = rng.random((int(cell.max()) + 1, 3)) * np.array([0.25, 0.2, 0.15]) + np.array([0.45, 0.42, 0.38])
        c = np.where((edge > 0.25)[..., None], tint[cell], np.array([0.3, 0.28, 0.25]))
        colours = np.clip(np.rint(c * 255), 0, 255).astype(np.uint8)
    elif name == "scales":
        p, dy = 16.0, 8.0
        r = 0.75 * p
        h = np.full((n, n), np.nan)
        j0 = np.floor(yy / dy)
        # the visible scale is the lowest row's (its centre at or above the pixel) whose disc holds it
        for back in range(3):
            j = j0 - back
            shift = np.mod(j, 2) * p / 2
            cx = np.round((xx - shift) / p) * p + shift
            d = np.hypot(xx - cx, yy - j * dy)
            h = np.where(np.isnan(h) & (d < r), 0.25 + 0.75 * d / r, h)  # raised toward its free rim
        h = np.nan_to_num(h, nan=0.0) + 0.02 * _periodic_noise(n, rng, n / 4)
    else:  # weave
        b = 8.0
        k, l = np.floor(yy / b), np.floor(xx / b)
        across_y = np.sqrt(np.clip(1 - (2 * ((yy % b) + 0.5) / b - 1) ** 2, 0, 1))
        across_x = np.sqrt(np.clip(1 - (2 * ((xx % b) + 0.5) / b - 1) ** 2, 0, 1))
        hx = (0.5 + 0.4 * np.cos(np.pi * ((xx + 0.5) / b - 0.5 + k))) * across_y
        hy = (0.5 + 0.4 * np.cos(np.pi * ((yy + 0.5) / b - 0.5 + l + 1))) * across_x
        h = np.maximum(hx, hy) + 0.02 * _periodic_noise(n, rng, n / 4)
    return _norm01(h), colours


def builtin_image(name: str, seed: int = 0) -> np.ndarray:
    """A built-in as an 8-bit grey height image ((128, 128) uint8, white high), to write with
    :func:`geosynth.io.files.write_image` and use as an image example."""
    h, _ = builtin_heights(name, seed)
    return np.clip(np.rint(h * 255), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------- files


def _read_grey(path: Path, what: str) -> np.ndarray:
    """(H, W) float64 in [0, 1] from an image file, white high."""
    from PIL import Image, UnidentifiedImageError

    from geosynth.io.files import check_input

    check_input(path, what)
    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float64)
                top = 65535.0 if a.max() > 255 else 255.0
                return np.clip(a / top, 0, 1)
            if mode not in ("1", "L", "LA", "P", "RGB", "RGBA", "F"):
                raise ValueError(f"{what} {str(path)!r} has pixel mode {mode}, which has no grey value; "
                                 "give an 8- or 16-bit grey or RGB image.")
            if mode == "F":
                a = np.asarray(im, dtype=np.float64)
                a = a - np.nanmin(a)
                return a / max(float(np.nanmax(a)), 1e-300)
            return np.asarray(im.convert("L"), dtype=np.float64) / 255.0
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"{what} {str(path)!r} is not a readable image ({type(exc).__name__}); give a PNG, JPEG, "
                         "BMP or TIFF height map.") from None


def _read_rgb(path: Path, shape: tuple[int, int]) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    from geosynth.io.files import check_input

    check_input(path, "colour image")
    try:
        with Image.open(path) as im:
            rgb = np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"colour image {str(path)!r} is not a readable image ({type(exc).__name__}).") from None
    if rgb.shape[:2] != shape:
        raise ValueError(f"colour image {str(path)!r} is {rgb.shape[1]} x {rgb.shape[0]} pixels, the height image "
                         f"{shape[1]} x {shape[0]}; give a colour image of the same size.")
    return np.ascontiguousarray(rgb)


def _trim_to_valid(grid: np.ndarray, mask: np.ndarray) -> tuple[slice, slice]:
    """Rows and columns of the largest-looking all-valid rectangle: border rows/columns with a
    missing cell are dropped, the side with the most missing first."""
    r0, r1, c0, c1 = 0, mask.shape[0], 0, mask.shape[1]
    while r1 - r0 >= 4 and c1 - c0 >= 4:
        m = mask[r0:r1, c0:c1]
        miss = [(~m[0]).sum(), (~m[-1]).sum(), (~m[:, 0]).sum(), (~m[:, -1]).sum()]
        if max(miss) == 0:
            break
        k = int(np.argmax(miss))
        if k == 0:
            r0 += 1
        elif k == 1:
            r1 -= 1
        elif k == 2:
            c0 += 1
        else:
            c1 -= 1
    return slice(r0, r1), slice(c0, c1)


def _from_capture(path: Path, name: str) -> ReliefExample:
    """A captured patch's relief over its fitted plane (M4's measurement), on a grid at its median
    sample spacing; colours by the nearest sample."""
    from scipy.spatial import cKDTree

    from geosynth.geometry.pointsets import read_geometry
    from geosynth.completion.prep import as_capture
    from geosynth.completion.spectrum import heights_on_grid
    from geosynth.completion.fit import fit_surface, relief_frame

    cap = as_capture(read_geometry(path))
    if len(cap) < 16:
        raise ValueError(f"example {str(path)!r} has {len(cap)} points; a captured patch needs at least 16.")
    fit = fit_surface(cap.positions, "plane", normals=cap.normals)
    uv, h, _ = relief_frame(fit, cap.positions)
    nn = cKDTree(uv).query(uv, k=2)[0][:, 1]
    spacing = float(np.median(nn))
    if not spacing > 0:
        raise ValueError(f"example {str(path)!r}: its points do not spread over a plane.")
    grid, mask = heights_on_grid(uv, h, spacing)
    rows, cols = _trim_to_valid(grid, mask)
    grid, mask = grid[rows, cols], mask[rows, cols]
    if min(grid.shape) < 8 or not mask.all():
        raise ValueError(f"example {str(path)!r}: its relief covers no 8 x 8 rectangle of its plane at spacing "
                         f"{spacing:.4g}; give a denser or squarer patch.")
    colours = None
    if cap.colors is not None:
        lo = uv.min(0)
        yy, xx = np.meshgrid(np.arange(grid.shape[0]) + rows.start, np.arange(grid.shape[1]) + cols.start,
                             indexing="ij")
        cells = np.stack([lo[0] + xx.ravel() * spacing, lo[1] + yy.ravel() * spacing], 1)
        colours = cap.colors[cKDTree(uv).query(cells)[1]].reshape(grid.shape + (3,))
    heights = grid - grid.min()
    return ReliefExample(heights, spacing, colours, name,
                         f"captured patch, {len(cap):,} points over its plane, {grid.shape[1]} x {grid.shape[0]} "
                         f"cells of {spacing:.4g}, depth {float(heights.max()):.4g} as captured")


def load_example(example, *, size: float, depth: float | None = None, colour=None, seed: int = 0) -> ReliefExample:
    """Turn an example into a :class:`ReliefExample`.

    Args:
        example: a built-in's name (:data:`BUILTINS`), an image file (.png, .jpg, .jpeg, .bmp,
            .tif, .tiff: a grey height map, white high), or a mesh / PLY point set of a captured
            patch; or a ReliefExample (returned with ``depth`` applied).
        size: the mesh's size (its largest bounding-box side, world units): an image or a built-in
            spans ``IMAGE_WIDTH_SHARE`` of it across its width.
        depth: the relief's height range in world units (images and built-ins: black to white,
            default ``DEFAULT_DEPTH_SHARE`` x size; a captured patch: rescaled to it, default as
            captured). >= 0.
        colour: None or an RGB image file of the same size as the height image (images only).
        seed: a built-in's seed.

    Returns:
        The example in world units (before ``scale``: :meth:`ReliefExample.scaled`).

    Raises:
        FileNotFoundError: a missing file (one line). ValueError: an unknown name, an image that is
        not grey-convertible, a negative depth, a colour image of another size or with a built-in.
    """
    if depth is not None and not (math.isfinite(depth) and depth >= 0):
        raise ValueError(f"depth must be a length >= 0 (mesh units), got {depth!r}.")
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"the mesh's size must be > 0, got {size!r}.")
    if isinstance(example, ReliefExample):
        return example if depth is None else example.with_depth(depth)
    text = str(example)
    path = Path(text)
    if text in BUILTINS and not path.exists():
        if colour is not None:
            raise ValueError(f"--colour goes with an image example; the built-in {text!r} has its own colours.")
        h, col = builtin_heights(text, seed)
        d = DEFAULT_DEPTH_SHARE * size if depth is None else depth
        spacing = IMAGE_WIDTH_SHARE * size / h.shape[1]
        return ReliefExample(h * d, spacing, col, text, f"built-in {text} (seed {seed}), {h.shape[1]} x {h.shape[0]} "
                             f"px across {IMAGE_WIDTH_SHARE * size:.4g} (a quarter of the mesh's size), depth {d:.4g}"
                             f"{' (1% of the mesh size)' if depth is None else ''}", periodic=True)
    if path.suffix.lower() in _IMAGE_SUFFIXES:
        grey = _read_grey(path, "example image")
        if min(grey.shape) < 8:
            raise ValueError(f"example image {text!r} is {grey.shape[1]} x {grey.shape[0]} pixels; give at least "
                             "8 x 8.")
        col = None if colour is None else _read_rgb(Path(colour), grey.shape)
        d = DEFAULT_DEPTH_SHARE * size if depth is None else depth
        spacing = IMAGE_WIDTH_SHARE * size / grey.shape[1]
        return ReliefExample(grey * d, spacing, col, path.name,
                             f"height image {grey.shape[1]} x {grey.shape[0]} px across {IMAGE_WIDTH_SHARE * size:.4g} "
                             f"(a quarter of the mesh's size), depth {d:.4g}"
                             f"{' (1% of the mesh size)' if depth is None else ''}")
    if not path.exists():
        raise FileNotFoundError(f"example {text!r} is neither a built-in ({', '.join(BUILTINS)}) nor an existing file.")
    if colour is not None:
        raise ValueError("--colour goes with an image example; a captured patch carries its own colours.")
    ex = _from_capture(path, path.name)
    return ex if depth is None else ex.with_depth(depth)
