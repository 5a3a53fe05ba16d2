"""What is a point-set geometry texture? The input texture T_in of "Geometry texture
synthesis with point-set surfaces", Sec. 3 (texture representation).

A :class:`PointTexture` is an oriented point set (unit normals), an axis-aligned box B
whose xy extent is the texture and whose z extent is its height (the reference plane is
xy, the height axis z), with geometry that extends beyond B in x and y (the padding the
paper asks for, so that MLS projections near B's border see the surface beyond it).

Constructors: :func:`texture_from_points` (an oriented point set; normals estimated by
:func:`geosynth.geometry.pointsets.estimate_normals` when absent), :func:`read_point_texture` (a PLY
point set or any mesh trimesh reads, meshes sampled uniformly by area),
:func:`texture_from_mesh`, :func:`texture_from_image` (a grey image as a height field,
the paper's first example, Sec. 6).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from geosynth.compute.checks import as_points3

__all__ = [
    "PointTexture",
    "read_point_texture",
    "texture_from_image",
    "texture_from_mesh",
    "texture_from_points",
]

HEIGHT_AXIS = 2  # the height axis is z; the reference plane is xy
MIN_POINTS = 16  # fewer points cannot give a neighbourhood for normals or MLS


@dataclass(frozen=True)
class PointTexture:
    """An input geometry texture (Sec. 3).

    Attributes:
        points: (N, 3) float64 positions, world units.
        normals: (N, 3) float64 unit normals.
        box_min, box_max: (3,) float64 corners of the box B; B's xy extent is the
            texture, its z extent the height. Points may (and should) lie outside B in
            x and y: that is the padding.
        name: a label for reports.
        merged: how many coincident points were merged: points at exactly the same
            position as an earlier one are dropped (the first one and its normal kept),
            since a point set's spacing, and so its MLS width, must not be 0.
        colors: (N, 3) uint8 RGB colour of each point, or None; the synthesis copies each
            output point's colour from the exemplar point it was warped from.
    """

    points: np.ndarray
    normals: np.ndarray
    box_min: np.ndarray
    box_max: np.ndarray
    name: str = "texture"
    merged: int = 0
    colors: np.ndarray | None = None

    def __post_init__(self):
        p = as_points3("points", self.points, finite=False)  # bad rows are reported below, by index
        n = np.asarray(self.normals, np.float64)
        lo = np.asarray(self.box_min, np.float64).reshape(-1)
        hi = np.asarray(self.box_max, np.float64).reshape(-1)
        if n.shape != p.shape:
            raise ValueError(f"normals must have shape {p.shape} to match points, got {n.shape}.")
        bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
        if bad.size:
            raise ValueError(f"points has {bad.size} position(s) with NaN or inf, the first at index {int(bad[0])}; "
                             "drop or fix them.")
        c = None
        if self.colors is not None:
            c = np.asarray(self.colors)
            if c.shape != p.shape or c.dtype != np.uint8:
                raise ValueError(f"colors must be {p.shape} uint8 (RGB) to match points, got {c.shape} {c.dtype}.")
        keep = _first_of_each_position(p)
        if keep is not None:  # coincident points: the spacing (and the MLS width) would be 0
            object.__setattr__(self, "merged", int(self.merged) + len(p) - len(keep))
            p, n = p[keep], n[keep]
            c = None if c is None else c[keep]
        if len(p) < MIN_POINTS:
            raise ValueError(f"points holds {len(p)} distinct points; a point texture needs at least {MIN_POINTS}.")
        bad = np.flatnonzero(~np.isfinite(n).all(axis=1))
        if bad.size:
            raise ValueError(f"normals has {bad.size} normal(s) with NaN or inf, the first at index {int(bad[0])}; "
                             "re-estimate them (give no normals).")
        length = np.linalg.norm(n, axis=1)
        bad = np.flatnonzero(length < 1e-12)
        if bad.size:
            raise ValueError(f"normals has {bad.size} zero-length normal(s), the first at index {int(bad[0])}; "
                             "re-estimate them (give no normals).")
        if lo.shape != (3,) or hi.shape != (3,) or not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise ValueError(f"box_min and box_max must be finite (3,) corners, got {lo} and {hi}.")
        if not (hi[:2] > lo[:2]).all() or not hi[2] >= lo[2]:
            raise ValueError(f"the box B from {lo.tolist()} to {hi.tolist()} is empty; give box_max > box_min in x "
                             "and y (and >= in z).")
        inside = self.inside_mask(p, lo, hi)
        if inside.sum() < MIN_POINTS:
            raise ValueError(f"the box B from {lo.tolist()} to {hi.tolist()} holds {int(inside.sum())} of the "
                             f"{len(p)} points; it must hold at least {MIN_POINTS}: give a box around the geometry.")
        object.__setattr__(self, "points", np.ascontiguousarray(p))
        object.__setattr__(self, "normals", np.ascontiguousarray(n / length[:, None]))
        object.__setattr__(self, "box_min", lo.copy())
        object.__setattr__(self, "box_max", hi.copy())
        object.__setattr__(self, "colors", None if c is None else np.ascontiguousarray(c))

    @staticmethod
    def inside_mask(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(N,) bool: the points whose x and y lie in B (the height is not tested)."""
        return ((points[:, :2] >= lo[:2]) & (points[:, :2] <= hi[:2])).all(axis=1)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def extent(self) -> np.ndarray:
        """(3,) float64 size of B."""
        return self.box_max - self.box_min

    @property
    def spacing(self) -> float:
        """The mean nearest-neighbour distance of the points (world units)."""
        return float(_nearest_distances(self.points).mean())

    def padding(self) -> np.ndarray:
        """(2,) how far (x, y) the geometry extends beyond B on its narrower side, >= 0."""
        lo, hi = self.points[:, :2].min(axis=0), self.points[:, :2].max(axis=0)
        return np.maximum(0.0, np.minimum(self.box_min[:2] - lo, hi - self.box_max[:2]))


def _nearest_distances(points: np.ndarray) -> np.ndarray:
    """The nearest-neighbour distances ((k,) float64) of up to 20,000 evenly picked points."""
    from geosynth.core.neighbours import nearest

    pick = points[np.linspace(0, len(points) - 1, min(len(points), 20_000)).astype(np.int64)]
    return nearest(points, pick, 2)[0][:, 1]


def _first_of_each_position(points: np.ndarray) -> np.ndarray | None:
    """Indices (ascending) of the first point at each distinct position, or None when
    every position is distinct (positions compared exactly, as their float64 values)."""
    if len(points) < 2:
        return None
    _, first = np.unique(points, axis=0, return_index=True)
    return None if len(first) == len(points) else np.sort(first)


def _box(points: np.ndarray, box, padding: float):
    """B from ``box`` ((2, 3)), or the points' bounds shrunk in x and y by ``padding`` of
    their extent on each side (the geometry beyond is the padding)."""
    if box is not None:
        b = np.asarray(box, np.float64)
        if b.shape != (2, 3):
            raise ValueError(f"box must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], shape (2, 3), got {b.shape}.")
        return b[0], b[1]
    if not (0 <= padding < 0.5):
        raise ValueError(f"padding must be in [0, 0.5) (a fraction of the extent on each side), got {padding!r}.")
    lo, hi = points.min(axis=0), points.max(axis=0)
    ext = hi - lo
    lo2, hi2 = lo.copy(), hi.copy()
    lo2[:2] += padding * ext[:2]
    hi2[:2] -= padding * ext[:2]
    return lo2, hi2


def texture_from_points(points, normals=None, *, box=None, padding: float = 0.2, k: int = 16,
                        name: str = "texture", colors=None) -> PointTexture:
    """A point texture from an oriented point set.

    Args:
        points: (N, 3) float positions (N >= 16), or a :class:`geosynth.geometry.pointsets.PointSet`
            (its normals are used unless ``normals`` is given).
        normals: (N, 3) normals; None estimates them (PCA over ``k`` neighbours,
            oriented towards +z for a sheet: :func:`geosynth.geometry.pointsets.estimate_normals`).
        box: (2, 3) the box B; default the points' bounds, shrunk in x and y by
            ``padding`` of the extent on each side.
        padding: see ``box``, in [0, 0.5).
        k: neighbours for normal estimation, >= 3.
        name: a label for reports.
        colors: (N, 3) uint8 colours, or None (a PointSet's own are used unless given).

    Returns:
        The :class:`PointTexture`.

    Raises:
        ValueError: fewer than 16 points, NaN/inf positions, normals of the wrong shape or
            zero length, no normals and too few neighbours to estimate them (collinear or
            coincident neighbourhoods), an empty box or one holding too few points.
    """
    from geosynth.geometry.pointsets import PointSet, estimate_normals

    if isinstance(points, PointSet):
        normals = points.normals if normals is None else normals
        colors = points.colors if colors is None else colors
        points = points.positions
    p = as_points3("points", points, finite=False)
    if len(p) < MIN_POINTS:
        raise ValueError(f"points holds {len(p)} points; a point texture needs at least {MIN_POINTS}.")
    bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
    if bad.size:
        raise ValueError(f"points has {bad.size} position(s) with NaN or inf, the first at index {int(bad[0])}; "
                         "drop or fix them.")
    merged = 0
    keep = _first_of_each_position(p)
    if keep is not None:  # coincident points have no normal of their own, and no spacing
        merged = len(p) - len(keep)
        p = p[keep]
        if colors is not None:
            colors = np.asarray(colors)
            if len(colors) != merged + len(p):
                raise ValueError(f"colors must have {merged + len(p)} rows to match points, got {len(colors)}.")
            colors = colors[keep]
        if normals is not None:
            normals = np.asarray(normals)
            if normals.shape != (merged + len(p), 3):
                raise ValueError(f"normals must have shape ({merged + len(p)}, 3) to match points, got {normals.shape}.")
            normals = normals[keep]
        if len(p) < MIN_POINTS:
            raise ValueError(f"points holds {len(p)} distinct position(s) ({merged} coincident point(s) merged); a "
                             f"point texture needs at least {MIN_POINTS}.")
    centred = p - p.mean(axis=0)
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(centred.T @ centred), 0.0))  # ascending
    if spread[1] <= 1e-5 * spread[2]:  # float32 files: a line to rounding
        raise ValueError(f"the {len(p):,} distinct points lie on one line: a point texture is a surface over the xy "
                         "plane (heights along z); give points spread in x and y.")
    if box is None:
        flat = np.ptp(p[:, :2], axis=0) <= 1e-12 * max(1.0, float(np.abs(p).max()))
        if flat.any():
            raise ValueError(f"the points span no extent in {' and '.join('xy'[a] for a in np.flatnonzero(flat))}: "
                             "a point texture is a surface over the xy plane (heights along z), so its points must "
                             "spread in both x and y (they lie on a line, or in a plane upright to xy).")
    if normals is None:
        try:
            normals = estimate_normals(p, k=k)
        except ValueError as exc:
            raise ValueError(f"the points have no normals and they cannot be estimated: {exc}") from None
    lo, hi = _box(p, box, padding)
    return PointTexture(p, np.asarray(normals, np.float64), lo, hi, name=name, merged=merged, colors=colors)


def _sample_mesh(mesh, count: int, seed: int):
    """``count`` points uniformly by area on a triangle mesh, with the faces' normals and,
    when the mesh has vertex (or face) colours, the colours interpolated at the points
    ((n, 3) uint8, else None)."""
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cross = np.cross(b - a, c - a)
    area = np.linalg.norm(cross, axis=1)
    if not area.sum() > 0:
        raise ValueError("the mesh has no area (every face is degenerate); give a mesh with faces.")
    rng = np.random.default_rng(seed)
    face = rng.choice(len(f), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    u, w = 1 - s, s * r2
    pts = a[face] * u[:, None] + b[face] * (s * (1 - r2))[:, None] + c[face] * w[:, None]
    good = area[face] > 0
    nrm = cross[face] / np.where(good, area[face], 1.0)[:, None]
    col = None
    visual = getattr(mesh, "visual", None)
    if getattr(visual, "kind", None) in ("vertex", "face"):
        vc = np.asarray(visual.vertex_colors)[:, :3].astype(np.float64)
        col = vc[f[face, 0]] * u[:, None] + vc[f[face, 1]] * (s * (1 - r2))[:, None] + vc[f[face, 2]] * w[:, None]
        col = np.clip(np.rint(col[good]), 0, 255).astype(np.uint8)
    return pts[good], nrm[good], col


def texture_from_mesh(mesh, count: int = 40_000, *, box=None, padding: float = 0.2, seed: int = 0,
                      name: str = "mesh") -> PointTexture:
    """A point texture sampled uniformly by area from a triangle mesh (normals from the faces,
    as the mesh winds them).

    Args:
        mesh: a ``trimesh.Trimesh`` (or anything with ``vertices`` and ``faces``).
        count: points to sample, >= 16.
        box, padding, name: as :func:`texture_from_points`.
        seed: seed of the sampling.

    Returns:
        The :class:`PointTexture`.
    """
    if not isinstance(count, (int, np.integer)) or count < MIN_POINTS:
        raise ValueError(f"count must be an integer >= {MIN_POINTS}, got {count!r}.")
    pts, nrm, col = _sample_mesh(mesh, int(count), seed)
    lo, hi = _box(pts, box, padding)
    return PointTexture(pts, nrm, lo, hi, name=name, colors=col)


# A file's padding (the geometry beyond B that B's border needs), in mean point spacings:
# the MLS support reaches 3 h = 6 spacings (h = 2 spacings, geosynth.pointtexture.synthesis) and a
# warped patch reads points up to 4 spacings beyond its box; 8 covers both. The rest of the
# file is texture: at a fixed 20% a side, 64% of the area was cut off, and a file whose edges
# differ from its middle (the zoo's noise) lost a third of its relief.
FILE_PADDING_SPACINGS = 8.0
MAX_PADDING = 0.2


def file_padding(points: np.ndarray, count: int | None = None, area: float | None = None) -> float:
    """The padding of a file's box B, a fraction of its x/y extent a side, in [0, MAX_PADDING]:
    FILE_PADDING_SPACINGS mean point spacings over the smaller of the x and y extents. The
    spacing of a point set is measured (mean nearest-neighbour distance over up to 20,000 of
    its points); a mesh about to be sampled with ``count`` points over its ``area`` has
    0.5 sqrt(area / count), the mean nearest-neighbour distance of a uniform sample. Sums by
    ``math.fsum`` (NumPy's reductions round by the CPU's SIMD width; the box decides the output)."""
    p = np.asarray(points, np.float64)
    if count is not None and area is not None:
        spacing = 0.5 * math.sqrt(float(area) / int(count))
    else:
        d = _nearest_distances(p)
        spacing = math.fsum(d.tolist()) / len(d)
    ext = float(np.min(p[:, :2].max(axis=0) - p[:, :2].min(axis=0)))
    if not ext > 0:
        return MAX_PADDING
    return float(min(MAX_PADDING, FILE_PADDING_SPACINGS * spacing / ext))


def _area_fixed(mesh) -> float:
    """A mesh's surface area, the same bits on every CPU: each triangle's by elementwise
    arithmetic (:func:`geosynth.core.exact.norm3` of its cross product), summed by ``math.fsum``
    (trimesh's ``area`` sums with NumPy's SIMD reduction)."""
    from geosynth.core.exact import norm3

    t = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces, np.int64)]
    a, b = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    cross = np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                      a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)
    return 0.5 * math.fsum(norm3(cross).tolist())


def read_point_texture(path: str | os.PathLike, *, box=None, padding: float | None = None, count: int = 40_000,
                       seed: int = 0, before_sampling=None) -> PointTexture:
    """A point texture from a file: a PLY point set (normals estimated when absent) or a mesh
    (any format :func:`geosynth.geometry.pointsets.read_geometry` reads), sampled uniformly; the
    file's colours are kept (a mesh's interpolated at the sampled points).

    Args:
        path: the file.
        box, padding: as :func:`texture_from_points`; padding None (default): from the
            file's sampling (:func:`file_padding`: what B's border needs, the rest is texture).
        count: points sampled from a mesh.
        seed: seed of the mesh sampling.
        before_sampling: called as ``before_sampling(box_min, box_max, share)`` (B as the
            sampled points will give it, from the mesh's vertices, and B's share of the
            mesh's x/y bounds) before a mesh is sampled, e.g. to refuse a ``count`` that
            cannot fit; it may raise.

    Raises:
        FileNotFoundError, ValueError: as :func:`geosynth.geometry.pointsets.read_geometry`, and as
            :func:`texture_from_points` (each message starting with the file's name).
    """
    from geosynth.geometry.pointsets import PointSet, read_geometry

    g = read_geometry(path)
    name = os.path.basename(str(path))
    if padding is None and box is None:
        if isinstance(g, PointSet):
            padding = file_padding(g.positions)
        else:
            padding = file_padding(np.asarray(g.vertices, np.float64), count, _area_fixed(g))
    padding = MAX_PADDING if padding is None else padding
    if before_sampling is not None and not isinstance(g, PointSet):
        try:
            lo, hi = _box(np.asarray(g.vertices, np.float64), box, padding)
        except ValueError as exc:
            raise ValueError(f"{str(path)!r}: {exc}") from None
        ext = np.ptp(np.asarray(g.vertices, np.float64)[:, :2], axis=0)
        share = float(np.prod((hi - lo)[:2]) / np.prod(ext)) if (ext > 0).all() else 1.0
        before_sampling(lo, hi, min(1.0, share))  # its refusals are about the options, not the file
    try:
        if isinstance(g, PointSet):
            return texture_from_points(g.positions, g.normals, box=box, padding=padding, name=name, colors=g.colors)
        return texture_from_mesh(g, count, box=box, padding=padding, seed=seed, name=name)
    except ValueError as exc:
        raise ValueError(f"{str(path)!r}: {exc}") from None


def texture_from_image(image, *, width: float = 1.0, relief: float = 0.12, count: int = 33_000,
                       padding: float = 0.2, seed: int = 0, name: str = "heightfield") -> PointTexture:
    """A height-field point texture from a grey image (Sec. 6, the first example).

    The image spans ``width`` along x (its aspect kept along y); grey 0..1 maps to height
    0..``relief``. Points are jittered samples of the surface z = relief * grey(x, y)
    (bilinear), about ``count`` of them, with normals from the height field's gradient
    (pointing to +z). B is the image shrunk by ``padding`` on each side in x and y.

    Args:
        image: (H, W) or (H, W, 3) array (uint8 0..255 or float 0..1), H, W >= 8.
        width: the x extent of the image, world units, > 0.
        relief: the height of grey 1, > 0.
        count: about this many points, >= 64.
        padding: fraction of the image beyond B on each side, in [0, 0.5).
        seed: seed of the jitter.

    Returns:
        The :class:`PointTexture`.

    Raises:
        ValueError: a constant image (no relief to synthesize), a wrong shape, NaN, bad numbers.
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = img[:, :, :3].astype(np.float64).mean(axis=2)
    if img.ndim != 2 or min(img.shape) < 8:
        raise ValueError(f"image must be an (H, W) grey or (H, W, 3) picture with H, W >= 8, got shape {img.shape}.")
    g = img.astype(np.float64)
    if not np.isfinite(g).all():
        raise ValueError("image holds NaN or inf; give a picture of finite grey values.")
    if np.asarray(image).dtype == np.uint8 or g.max() > 1.0:
        g = g / 255.0
    if float(g.max() - g.min()) < 1e-6:
        raise ValueError("image is constant (one grey level): a flat height field has no relief to synthesize; "
                         "give a picture with some variation.")
    if not (width > 0 and relief > 0 and count >= 64):
        raise ValueError(f"width and relief must be > 0 and count >= 64, got {width!r}, {relief!r}, {count!r}.")
    h, w = g.shape
    height_extent = width * (h - 1) / (w - 1)
    area = width * height_extent
    s = np.sqrt(area / count)
    nx, ny = int(round(width / s)) + 1, int(round(height_extent / s)) + 1
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(nx) * (width / (nx - 1)), np.arange(ny) * (height_extent / (ny - 1)))
    jitter = 0.25 * s
    x = np.clip(gx.ravel() + rng.uniform(-jitter, jitter, gx.size), 0, width)
    y = np.clip(gy.ravel() + rng.uniform(-jitter, jitter, gy.size), 0, height_extent)
    # bilinear height and its gradient
    u, v = x / width * (w - 1), y / height_extent * (h - 1)
    i0, j0 = np.minimum(np.floor(u).astype(np.int64), w - 2), np.minimum(np.floor(v).astype(np.int64), h - 2)
    fu, fv = u - i0, v - j0
    z00, z10, z01, z11 = g[j0, i0], g[j0, i0 + 1], g[j0 + 1, i0], g[j0 + 1, i0 + 1]
    z = relief * ((1 - fu) * (1 - fv) * z00 + fu * (1 - fv) * z10 + (1 - fu) * fv * z01 + fu * fv * z11)
    # gradient of a smoothed copy (bilinear facets' normals are blocky)
    from scipy.ndimage import gaussian_filter, map_coordinates

    gs = gaussian_filter(g, 0.7)
    dzdu = np.gradient(gs, axis=1) * relief / (width / (w - 1))
    dzdv = np.gradient(gs, axis=0) * relief / (height_extent / (h - 1))
    dx = map_coordinates(dzdu, [v, u], order=1)
    dy = map_coordinates(dzdv, [v, u], order=1)
    nrm = np.stack([-dx, -dy, np.ones_like(dx)], axis=1)
    pts = np.stack([x, y, z], axis=1)
    lo, hi = _box(pts, None, padding)
    lo[2], hi[2] = 0.0, relief
    return PointTexture(pts, nrm, lo, hi, name=name)
