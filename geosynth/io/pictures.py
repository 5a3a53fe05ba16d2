"""What does a result look like? Implements no paper section: pictures of the methods'
outputs.

Pictures of results, rendered in NumPy and written as PNG or JPEG by Pillow.

- :func:`write_png`: an atomic PNG or JPEG writer (Pillow).
- :func:`render_mesh`: a shaded picture of a triangle mesh, by a z-buffer rasterizer
  in NumPy (no OpenGL, no display): perspective camera framing the object from a 3/4
  view, Lambert shading with a little ambient and a soft highlight under a light fixed
  to the camera, supersampled for smooth edges.
- :func:`render_points`: the same camera and light for point sets, each point a
  screen-space disk (splat) in the z-buffer.
- :func:`side_by_side`: pictures in a row, with optional labels drawn by Pillow.
- :func:`render_mesh_png`, :func:`render_points_png`: render and write in one step.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geosynth.core.interpolate import lerp_axis, linear_taps
from geosynth.io.files import write_image

__all__ = [
    "View", "field_slices_image", "render_mesh", "render_mesh_png", "render_points", "render_points_png",
    "side_by_side", "text_image", "write_png",
]


def write_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an 8-bit grey (H, W) or RGB (H, W, 3) image, atomically, as PNG or JPEG
    by the suffix (:func:`geosynth.io.files.write_image`); returns the path."""
    return write_image(path, image)


def _bilinear(image: np.ndarray, factor: int) -> np.ndarray:
    """Upsample a 2D array by an integer factor, bilinear (cell centres aligned, clamped at the edges)."""
    h, w = image.shape
    y, x = ((np.arange(n * factor) + 0.5) / factor - 0.5 for n in (h, w))
    return lerp_axis(lerp_axis(image, 1, linear_taps(x, w, False)), 0, linear_taps(y, h, False))


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


# ------------------------------------------------------------------ camera

BACKGROUND = (255, 255, 255)
MESH_COLOR = (172, 186, 212)  # a light steel blue
BACK_COLOR = (214, 150, 120)  # the inner side of an open surface
POINT_COLOR = (172, 186, 212)
# light direction in camera coordinates (x right, y up, z into the picture): upper left, toward the viewer
LIGHT = np.array([-0.45, 0.65, -0.62]) / np.linalg.norm([-0.45, 0.65, -0.62])
# a weaker fill light from the lower right, so faces turned away from the key light keep their shape
FILL = np.array([0.6, -0.25, -0.5]) / np.linalg.norm([0.6, -0.25, -0.5])
AMBIENT, DIFFUSE, FILL_DIFFUSE = 0.18, 0.72, 0.22
CREASE_DEGREES = 40.0  # smooth shading never blends normals across a sharper edge than this
FRAGMENT_CHUNK = 1 << 21  # candidate pixels evaluated at once (memory per chunk: ~100 bytes each)


@dataclass(frozen=True)
class View:
    """Where the camera stands, looking at the centre of the object's bounding box.

    Attributes:
        azimuth: degrees around the z axis (up), from +x toward +y; -60 looks from the
            front right.
        elevation: degrees above the xy plane, in [-90, 90].
        fov: vertical field of view in degrees, in (0, 120); 0 for an orthographic view.
        zoom: > 1 magnifies, < 1 shrinks; 1 fits the object in the picture with a margin.
    """

    azimuth: float = -60.0
    elevation: float = 30.0
    fov: float = 30.0
    zoom: float = 1.0

    def __post_init__(self):
        for name in ("azimuth", "elevation", "fov", "zoom"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"View.{name} must be finite, got {getattr(self, name)!r}.")
        if not -90 <= self.elevation <= 90:
            raise ValueError(f"View.elevation must be in [-90, 90] degrees, got {self.elevation}.")
        if not 0 <= self.fov < 120:
            raise ValueError(f"View.fov must be in [0, 120) degrees (0: orthographic), got {self.fov}.")
        if not self.zoom > 0:
            raise ValueError(f"View.zoom must be > 0, got {self.zoom}.")


def _as_view(view) -> View:
    if view is None:
        return View()
    if isinstance(view, View):
        return view
    if isinstance(view, dict):
        return View(**view)
    if isinstance(view, (tuple, list)) and len(view) == 2:
        return View(float(view[0]), float(view[1]))
    raise TypeError(f"view must be None, a View, a dict of View fields or (azimuth, elevation), got {view!r}.")


def _as_size(size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size)
        ok = all(float(v) == int(v) for v in size)
    except (TypeError, ValueError):
        ok = False
    if not ok or not (8 <= w <= 8192 and 8 <= h <= 8192):
        raise ValueError(f"size must be (width, height), integers in [8, 8192], got {size!r}.")
    return w, h


class _Camera:
    """Camera frame and projection fitted to a set of points: the eye looks at the centre of
    their bounding box from outside its sphere, and the focal length makes their
    projection fill the picture up to ``margin``. Two points are read as a box's corners."""

    def __init__(self, points: np.ndarray, view: View, width: int, height: int, margin: float = 0.06):
        lo, hi = points.min(0), points.max(0)
        centre = (lo + hi) / 2
        radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-12)
        az, el = np.radians(view.azimuth), np.radians(view.elevation)
        towards_eye = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        forward = -towards_eye
        up = np.array([0.0, 0.0, 1.0]) if abs(towards_eye[2]) < 0.999 else np.array([0.0, 1.0, 0.0])
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        self.rotation = np.stack([right, np.cross(right, forward), forward])  # rows: camera x, y, z
        self.perspective = view.fov > 0
        distance = radius / np.sin(np.radians(view.fov) / 2) if self.perspective else 2 * radius
        self.eye = centre + towards_eye * distance
        # fit: the projected extent of the points (every vertex, or the given box's
        # corners), centred, with a margin
        if len(points) == 2:
            points = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        a, b, _ = self._plane(points)
        span_a, span_b = max(a.max() - a.min(), 1e-12), max(b.max() - b.min(), 1e-12)
        self.focal = min(width * (1 - 2 * margin) / span_a, height * (1 - 2 * margin) / span_b) * view.zoom
        self.cx = width / 2 - self.focal * (a.max() + a.min()) / 2
        self.cy = height / 2 + self.focal * (b.max() + b.min()) / 2
        self.near = 1e-6 * distance

    def camera(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) camera coordinates (x right, y up, z depth)."""
        return (points - self.eye) @ self.rotation.T

    def _plane(self, points):
        c = self.camera(points)
        z = c[:, 2]
        if self.perspective:
            zs = np.maximum(z, 1e-12)
            return c[:, 0] / zs, c[:, 1] / zs, z
        return c[:, 0], c[:, 1], z

    def project(self, points: np.ndarray):
        """Pixel coordinates u (right), v (down), and depth z of (n, 3) world points."""
        a, b, z = self._plane(points)
        return self.cx + self.focal * a, self.cy - self.focal * b, z


def _check_quality(supersample, specular) -> None:
    if supersample not in (1, 2, 3, 4):
        raise ValueError(f"supersample must be 1, 2, 3 or 4, got {supersample!r}.")
    if not 0 <= specular <= 1:
        raise ValueError(f"specular must be in [0, 1], got {specular!r}.")


def _framing_camera(points: np.ndarray, bounds, view: View, width: int, height: int) -> _Camera:
    """The camera framing ``points``, or the (2, 3) box ``bounds`` when given."""
    frame = points if bounds is None else np.asarray(bounds, np.float64)
    if frame.ndim != 2 or frame.shape[1] != 3 or not np.isfinite(frame).all():
        raise ValueError(f"bounds must be a finite (2, 3) box, got {np.shape(bounds)}.")
    return _Camera(frame, view, width, height)


def _expand(counts: np.ndarray):
    """For counts c_k, the owner k and the rank 0..c_k-1 of each of the sum(c) items."""
    owner = np.repeat(np.arange(len(counts)), counts)
    start = np.cumsum(counts) - counts
    return owner, np.arange(len(owner)) - start[owner]


def _rasterize(u, v, z, faces, width, height, perspective):
    """Z-buffer the triangles: per pixel the nearest face and its screen barycentrics.

    Scanline rasterization, vectorized: every triangle is cut into the pixel rows its
    box spans, each row's exact span of covered pixel centres comes from the three edge
    functions, and only covered pixels become fragments (long thin triangles cost
    their pixels, not their bounding box). The depth test keeps the nearest fragment
    (perspective: the largest 1/z, which is linear on the screen); ties go to the
    later one. Triangles are processed in chunks of about ``FRAGMENT_CHUNK`` rows and
    fragments.

    Returns:
        (face id per pixel, -1 where empty; (H*W, 2) float32 barycentrics of vertices 0, 1).
    """
    npix = width * height
    zbuf = np.full(npix, np.inf)
    fid = np.full(npix, -1, np.int64)
    bary = np.zeros((npix, 2), np.float32)
    x, y, d = u[faces], v[faces], z[faces]  # (F, 3) each
    x0, x1, x2 = x[:, 0], x[:, 1], x[:, 2]
    y0, y1, y2 = y[:, 0], y[:, 1], y[:, 2]
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    ymin = np.clip(np.ceil(y.min(1) - 0.5), 0, height).astype(np.int64)
    ymax = np.clip(np.floor(y.max(1) - 0.5), -1, height - 1).astype(np.int64)
    keep = (d > 0).all(1) & (np.abs(area) > 1e-12) & (ymax >= ymin) & (x.max(1) >= 0) & (x.min(1) <= width)
    ids = np.nonzero(keep)[0]
    inv_area = 1.0 / area[ids]
    # barycentrics of vertices 0, 1, 2 as linear functions A px + B py + C of the pixel centre
    coef = np.empty((len(ids), 3, 3))
    xi, yi = (x0[ids], x1[ids], x2[ids]), (y0[ids], y1[ids], y2[ids])
    for k in range(3):
        a, b = (k + 1) % 3, (k + 2) % 3
        coef[:, k, 0] = (yi[a] - yi[b]) * inv_area
        coef[:, k, 1] = (xi[b] - xi[a]) * inv_area
        coef[:, k, 2] = (xi[a] * yi[b] - xi[b] * yi[a]) * inv_area
    key_v = (-1.0 / d if perspective else d)[ids]  # smaller is nearer; linear on the screen
    rows = ymax[ids] - ymin[ids] + 1
    ends = np.cumsum(rows)
    c0 = 0
    while c0 < len(ids):  # chunks of triangles with about FRAGMENT_CHUNK rows in all
        c1 = max(c0 + 1, int(np.searchsorted(ends, ends[c0] - rows[c0] + FRAGMENT_CHUNK, "right")))
        owner, rank = _expand(rows[c0:c1])
        t = owner + c0
        py = ymin[ids[t]] + rank
        cy = py + 0.5
        cf = coef[t]  # (R, 3 edges, 3)
        const = cf[:, :, 1] * cy[:, None] + cf[:, :, 2]  # lambda_k = A_k x + const_k >= 0
        A = cf[:, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = -const / A
        eps = 1e-9
        lo = np.where(A > 0, bound, -np.inf).max(1) - eps
        hi = np.where(A < 0, bound, np.inf).min(1) + eps
        empty = ((A == 0) & (const < -eps)).any(1)
        xl = np.clip(np.ceil(lo - 0.5), 0, width).astype(np.int64)
        xr = np.clip(np.floor(hi - 0.5), -1, width - 1).astype(np.int64)
        span = np.where(empty, 0, np.maximum(xr - xl + 1, 0))
        span_ends = np.cumsum(span)
        s0 = 0
        while s0 < len(span):  # chunks of rows with about FRAGMENT_CHUNK pixels in all
            s1 = max(s0 + 1, int(np.searchsorted(span_ends, span_ends[s0] - span[s0] + FRAGMENT_CHUNK, "right")))
            r, k = _expand(span[s0:s1])
            r += s0
            px = xl[r] + k
            tt = t[r]
            lam = A[r] * (px + 0.5)[:, None] + const[r]  # (P, 3)
            key = (lam * key_v[tt]).sum(1)
            pix = py[r] * width + px
            np.minimum.at(zbuf, pix, key)
            win = key <= zbuf[pix]
            fid[pix[win]] = ids[tt[win]]
            bary[pix[win]] = lam[win, :2]
            s0 = s1
        c0 = c1
    return fid, bary


def _downsample(image: np.ndarray, factor: int) -> np.ndarray:
    if factor == 1:
        return image
    h, w, c = image.shape
    return image.reshape(h // factor, factor, w // factor, factor, c).mean((1, 3))


def _as_rgb(name: str, value, count: int | None = None) -> np.ndarray:
    """Colours as float64 in [0, 255]: one (3,) colour, or (count, 3) when count is given."""
    c = np.asarray(value)
    shape = (3,) if count is None else (count, 3)
    if c.shape != shape or c.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be {'an (r, g, b)' if count is None else f'a ({count}, 3)'} array of numbers "
                         f"in [0, 255], got shape {c.shape} dtype {c.dtype}.")
    c = c.astype(np.float64)
    if not np.isfinite(c).all() or c.min() < 0 or c.max() > 255:
        raise ValueError(f"{name} values must be finite and in [0, 255].")
    return c


def _light(normal_cam: np.ndarray, view_dir: np.ndarray, specular: float) -> tuple[np.ndarray, np.ndarray]:
    """Lambert + ambient, and a Blinn-Phong highlight, for unit normals facing the viewer."""
    diffuse = AMBIENT + DIFFUSE * np.clip(normal_cam @ LIGHT, 0, None) + FILL_DIFFUSE * np.clip(normal_cam @ FILL, 0, None)
    if specular <= 0:
        return diffuse, np.zeros_like(diffuse)
    half = LIGHT[None, :] + view_dir
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    return diffuse, specular * np.clip((normal_cam * half).sum(1), 0, None) ** 40


def _as_mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    try:
        import trimesh

        if isinstance(mesh, trimesh.Trimesh):
            vertices, faces = mesh.vertices, mesh.faces
        elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
            vertices, faces = mesh
        else:
            raise TypeError(f"mesh must be a trimesh.Trimesh or a (vertices, faces) pair, got {type(mesh).__name__}.")
    except ImportError:  # pragma: no cover - trimesh is a dependency
        vertices, faces = mesh
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError(f"mesh vertices must be a non-empty (n, 3) array, got shape {v.shape}.")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.dtype.kind not in "iu":
        raise ValueError(f"mesh faces must be a non-empty (m, 3) integer array, got shape {f.shape} dtype {f.dtype}.")
    if not np.isfinite(v).all():
        raise ValueError(f"mesh has {int((~np.isfinite(v)).any(1).sum())} vertices with NaN or inf coordinates.")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"mesh faces index vertices out of range [0, {len(v)}): min {f.min()}, max {f.max()}.")
    return v, f.astype(np.int64)


def render_mesh(mesh, size=(800, 600), view=None, color=MESH_COLOR, face_colors=None, vertex_colors=None,
                smooth: bool = True, background=BACKGROUND, back_color=BACK_COLOR, specular: float = 0.12,
                supersample: int = 2, bounds=None) -> np.ndarray:
    """A shaded picture of a triangle mesh, made on the CPU with no display.

    A perspective camera (see :class:`View`; default: 30 degrees above the ground, from
    the front right, z up) looks at the centre of the mesh's bounding box and is framed
    so the mesh fills the picture up to a small margin. Triangles are z-buffered at
    ``supersample`` times the resolution and averaged down. Each pixel is lit by one
    directional light fixed to the camera (upper left): Lambert with a little ambient,
    plus a soft highlight. Normals are interpolated from the vertices (``smooth``) or
    taken per face, and always turned toward the viewer; pixels seeing the back of a
    face (the inside of an open surface) get ``back_color``.

    Args:
        mesh: a ``trimesh.Trimesh`` or a (vertices (n, 3), faces (m, 3)) pair.
        size: (width, height) of the picture in pixels, each in [8, 8192].
        view: None (the default :class:`View`), a View, a dict of its fields, or
            (azimuth, elevation) in degrees.
        color: (r, g, b) in [0, 255], the colour where no per-face or per-vertex one is given.
        face_colors: optional (m, 3) colours per face.
        vertex_colors: optional (n, 3) colours per vertex, interpolated.
        smooth: interpolate vertex normals (True) or shade each face flat.
        background: (r, g, b) of the empty pixels.
        back_color: (r, g, b) of back faces, or None to colour them like the front.
        specular: highlight strength in [0, 1] (0: pure Lambert).
        supersample: pixels per picture pixel along each axis, 1 to 4.
        bounds: optional (2, 3) box to frame instead of the mesh's own (to show two
            meshes at the same scale).

    Returns:
        (height, width, 3) uint8 RGB picture. The same input gives the same picture.

    Raises:
        TypeError: ``mesh`` or ``view`` of the wrong kind.
        ValueError: empty, NaN or out-of-range mesh arrays, a bad size, colours of the
            wrong shape or range, both face and vertex colours, a bad view or
            supersample factor.

    Example:
        >>> import trimesh
        >>> render_mesh(trimesh.creation.icosphere(), size=(64, 48)).shape
        (48, 64, 3)
    """
    vertices, faces = _as_mesh_arrays(mesh)
    width, height = _as_size(size)
    cam_view = _as_view(view)
    _check_quality(supersample, specular)
    if face_colors is not None and vertex_colors is not None:
        raise ValueError("give face_colors or vertex_colors, not both.")
    base = _as_rgb("color", color)
    bg = _as_rgb("background", background)
    back = None if back_color is None else _as_rgb("back_color", back_color)
    fcol = None if face_colors is None else _as_rgb("face_colors", face_colors, len(faces))
    vcol = None if vertex_colors is None else _as_rgb("vertex_colors", vertex_colors, len(vertices))
    ss = supersample
    W, H = width * ss, height * ss
    camera = _framing_camera(vertices, bounds, cam_view, W, H)
    u, v, z = camera.project(vertices)
    z = np.where(z > camera.near, z, -1.0)  # vertices behind the camera drop their triangles
    fid, bary = _rasterize(u, v, z, faces, W, H, camera.perspective)

    image = np.empty((H * W, 3))
    image[:] = bg
    hit = np.nonzero(fid >= 0)[0]
    if len(hit):
        f = fid[hit]
        tri = faces[f]
        lam = np.empty((len(hit), 3))
        lam[:, :2] = bary[hit]
        lam[:, 2] = 1 - lam[:, 0] - lam[:, 1]
        if camera.perspective:  # perspective-correct weights
            lam /= z[tri]
            lam /= lam.sum(1, keepdims=True)
        cam_pts = camera.camera(vertices)
        position = (lam[:, :, None] * cam_pts[tri]).sum(1)
        view_dir = -position / np.linalg.norm(position, axis=1, keepdims=True) if camera.perspective else \
            np.broadcast_to(np.array([0.0, 0.0, -1.0]), position.shape)
        fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
        if smooth:
            vn = np.zeros_like(vertices)
            for k in range(3):  # area-weighted vertex normals
                np.add.at(vn, faces[:, k], fn)
            corner = vn[tri]  # (P, 3 corners, 3)
            # keep creases sharp: a corner whose vertex normal is more than CREASE_DEGREES
            # from its face's normal uses the face normal (slab edges, cut borders)
            fu = fn[f] / np.maximum(np.linalg.norm(fn[f], axis=1, keepdims=True), 1e-300)
            cos = (corner * fu[:, None, :]).sum(2) / np.maximum(np.linalg.norm(corner, axis=2), 1e-300)
            sharp = cos < np.cos(np.radians(CREASE_DEGREES))
            corner[sharp] = np.broadcast_to(fu[:, None, :], corner.shape)[sharp]
            normal = (lam[:, :, None] * corner).sum(1)
            # where the interpolated normal vanishes (a crease), fall back to the face normal
            weak = np.linalg.norm(normal, axis=1) < 1e-12
            normal[weak] = fn[f[weak]]
        else:
            normal = fn[f]
        normal = normal @ camera.rotation.T
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        # which side of the face is seen comes from the face normal, not the interpolated one
        facing = ((fn[f] @ camera.rotation.T) * view_dir).sum(1) >= 0
        flip = (normal * view_dir).sum(1) < 0
        normal[flip] *= -1
        if vcol is not None:
            albedo = (lam[:, :, None] * vcol[tri]).sum(1)
        elif fcol is not None:
            albedo = fcol[f]
        else:
            albedo = np.broadcast_to(base, (len(hit), 3)).copy()
        if back is not None:
            albedo[~facing] = back
        diffuse, highlight = _light(normal, view_dir, specular)
        image[hit] = albedo * diffuse[:, None] + 255.0 * highlight[:, None]
    image = _downsample(image.reshape(H, W, 3), ss)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def render_points(points, normals=None, colors=None, size=(800, 600), view=None, radius: float | None = None,
                  color=POINT_COLOR, background=BACKGROUND, shading: bool = True, specular: float = 0.12,
                  supersample: int = 2, bounds=None) -> np.ndarray:
    """A picture of a point set: each point a disk (splat) of ``radius`` in the z-buffer.

    The camera, framing and light are those of :func:`render_mesh`. A point with a
    normal is lit like a surface; without normals every splat is shaded as a small
    sphere (so clouds still show their shape). With ``shading`` off the colours are
    shown as they are (e.g. to judge a texture's colours).

    Args:
        points: (n, 3) positions, n >= 1, finite.
        normals: optional (n, 3) normals (need not be unit length; turned toward the viewer).
        colors: optional (n, 3) colours in [0, 255]; else ``color`` for all.
        size: (width, height) in pixels.
        view: as in :func:`render_mesh`.
        radius: splat radius in world units; default 0.75 times the median distance
            from a point to its 6th nearest neighbour (a closed look for surface samples).
        color: (r, g, b) used when ``colors`` is None.
        background: (r, g, b) of the empty pixels.
        shading: light the points (True) or show the colours flat.
        specular: highlight strength in [0, 1].
        supersample: 1 to 4, as in :func:`render_mesh`.
        bounds: optional (2, 3) box to frame instead of the points' own.

    Returns:
        (height, width, 3) uint8 RGB picture.

    Raises:
        ValueError: empty or non-finite points, arrays of the wrong shape, a radius that
            is not > 0, a bad size, view or colour.

    Example:
        >>> pts = np.random.default_rng(0).normal(size=(500, 3))
        >>> render_points(pts, size=(64, 48)).shape
        (48, 64, 3)
    """
    p = np.asarray(points, np.float64) if np.asarray(points).dtype.kind in "iuf" else None
    if p is None or p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"points must be a non-empty (n, 3) array of numbers, got shape {np.shape(points)}.")
    if not np.isfinite(p).all():
        raise ValueError("points contain NaN or inf.")
    n = len(p)
    nrm = None
    if normals is not None:
        nrm = np.asarray(normals, np.float64)
        if nrm.shape != (n, 3) or not np.isfinite(nrm).all():
            raise ValueError(f"normals must be a finite ({n}, 3) array, got shape {nrm.shape}.")
    col = _as_rgb("colors", colors, n) if colors is not None else None
    base = _as_rgb("color", color)
    bg = _as_rgb("background", background)
    width, height = _as_size(size)
    cam_view = _as_view(view)
    _check_quality(supersample, specular)
    if radius is None:
        radius = _default_splat_radius(p)
    elif not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be > 0, got {radius!r}.")
    ss = supersample
    W, H = width * ss, height * ss
    camera = _framing_camera(p, bounds, cam_view, W, H)
    u, v, z = camera.project(p)
    rpix = radius * camera.focal / np.maximum(z, 1e-300) if camera.perspective else np.full(n, radius * camera.focal)
    rpix = np.clip(rpix, 0.5, 64.0)
    keep = (z > camera.near) & (u + rpix >= 0) & (u - rpix <= W) & (v + rpix >= 0) & (v - rpix <= H)
    zbuf = np.full(W * H, np.inf)
    pid = np.full(W * H, -1, np.int64)
    offset = np.zeros((W * H, 2), np.float32)
    half = np.ceil(rpix).astype(np.int64)
    ids = np.nonzero(keep)[0]
    ids = ids[np.argsort(half[ids], kind="stable")]
    bounds_h = np.r_[0, np.nonzero(np.diff(half[ids]))[0] + 1, len(ids)]
    for g0, g1 in zip(bounds_h[:-1], bounds_h[1:]):
        k = int(half[ids[g0]])
        dy, dx = np.divmod(np.arange((2 * k + 1) ** 2), 2 * k + 1)
        dx, dy = dx - k, dy - k
        step = max(1, FRAGMENT_CHUNK // len(dx))
        for c0 in range(g0, g1, step):
            t = ids[c0:c0 + step]
            px = np.floor(u[t])[:, None].astype(np.int64) + dx[None, :]
            py = np.floor(v[t])[:, None].astype(np.int64) + dy[None, :]
            ox = (px + 0.5 - u[t, None]) / rpix[t, None]
            oy = (py + 0.5 - v[t, None]) / rpix[t, None]
            ok = (ox * ox + oy * oy <= 1) & (px >= 0) & (px < W) & (py >= 0) & (py < H)
            ti, ki = np.nonzero(ok)
            f = t[ti]
            pix = py[ti, ki] * W + px[ti, ki]
            ox, oy = ox[ti, ki], oy[ti, ki]
            # depth of a small sphere at the point: the splats of a surface interlock smoothly
            key = z[f] - radius * np.sqrt(np.clip(1 - ox * ox - oy * oy, 0, 1))
            np.minimum.at(zbuf, pix, key)
            win = key <= zbuf[pix]
            pid[pix[win]] = f[win]
            offset[pix[win]] = np.stack([ox[win], oy[win]], 1)

    image = np.empty((H * W, 3))
    image[:] = bg
    hit = np.nonzero(pid >= 0)[0]
    if len(hit):
        f = pid[hit]
        albedo = col[f] if col is not None else np.broadcast_to(base, (len(hit), 3))
        if shading:
            position = camera.camera(p[f])
            view_dir = -position / np.linalg.norm(position, axis=1, keepdims=True) if camera.perspective else \
                np.broadcast_to(np.array([0.0, 0.0, -1.0]), position.shape)
            if nrm is not None:
                normal = nrm[f] @ camera.rotation.T
                normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
                normal[(normal * view_dir).sum(1) < 0] *= -1
            else:  # a sphere impostor: the normal from the offset within the disk
                ox, oy = offset[hit, 0].astype(np.float64), offset[hit, 1].astype(np.float64)
                normal = np.stack([ox, -oy, -np.sqrt(np.clip(1 - ox * ox - oy * oy, 0, 1))], 1)
            diffuse, highlight = _light(normal, view_dir, specular)
            image[hit] = albedo * diffuse[:, None] + 255.0 * highlight[:, None]
        else:
            image[hit] = albedo
    image = _downsample(image.reshape(H, W, 3), ss)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def _default_splat_radius(points: np.ndarray) -> float:
    """0.75 x the median distance to the 6th nearest neighbour (over up to 20,000 evenly
    picked points): about 1.1 / sqrt(density) for surface samples, enough to close the
    surface even for random samples (their nearest neighbours clump)."""
    from geosynth.core.neighbours import nearest

    k = min(6, len(points) - 1)
    if k < 1:
        return 0.05
    pick = points[np.linspace(0, len(points) - 1, min(len(points), 20_000)).astype(np.int64)]
    d, _ = nearest(points, pick, k + 1)
    nn = d[:, k][d[:, k] > 0]
    if len(nn) == 0:
        return 1e-3
    return 0.75 * float(np.median(nn))


def render_mesh_png(mesh, path: str | os.PathLike, size=(800, 600), view=None, **options) -> Path:
    """Render a mesh (:func:`render_mesh`, same options) and write the PNG atomically; returns the path."""
    return write_png(path, render_mesh(mesh, size=size, view=view, **options))


def render_points_png(points, path: str | os.PathLike, normals=None, colors=None, size=(800, 600), view=None,
                      **options) -> Path:
    """Render a point set (:func:`render_points`, same options) and write the PNG atomically; returns the path."""
    return write_png(path, render_points(points, normals, colors, size=size, view=view, **options))


# ------------------------------------------------------------------ pictures in a row, with labels

CAPTION_PIXELS = 10  # font size (em height in pixels) of a caption at scale 1


@functools.lru_cache(maxsize=8)
def _font(pixels: int):
    """Pillow's built-in font (no font file from the system) at ``pixels``; where Pillow
    has no FreeType, its small bitmap font (returned with the integer zoom it needs)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=pixels), 1
    except (ImportError, OSError, TypeError):  # no FreeType, or Pillow < 10.1
        return ImageFont.load_default(), max(1, round(pixels / 11))


def text_image(text: str, scale: int = 2, color=(40, 40, 40), background=BACKGROUND) -> np.ndarray:
    """A line of text drawn by Pillow (ImageDraw) in Pillow's built-in font, anti-aliased.

    Args:
        text: the line (one line: newlines are shown as spaces).
        scale: size factor, >= 1: the font is ``CAPTION_PIXELS * scale`` pixels.
        color, background: (r, g, b) of the letters and around them.

    Returns:
        (H, W, 3) uint8 RGB; H depends only on ``scale`` (the font's ascent + descent),
        W on the text (at least one column).
    """
    from PIL import Image, ImageDraw

    if not isinstance(scale, (int, np.integer)) or scale < 1:
        raise ValueError(f"scale must be an integer >= 1, got {scale!r}.")
    line = " ".join(str(text).splitlines())
    font, zoom = _font(CAPTION_PIXELS * int(scale))
    height = sum(font.getmetrics()) if hasattr(font, "getmetrics") else font.getbbox("Ag|")[3] + 1
    width = max(1, int(np.ceil(font.getlength(line))))
    canvas = Image.new("RGB", (width, height), tuple(int(c) for c in background))
    ImageDraw.Draw(canvas).text((0, 0), line, fill=tuple(int(c) for c in color), font=font)
    out = np.asarray(canvas, np.uint8)
    return out.repeat(zoom, 0).repeat(zoom, 1) if zoom > 1 else out.copy()


def side_by_side(images, labels=None, gap: int = 8, background=BACKGROUND, scale: int = 2) -> np.ndarray:
    """Pictures in a row, centred vertically, ``gap`` pixels apart, each with an optional label above.

    Args:
        images: a non-empty sequence of (H, W, 3) or (H, W) uint8 pictures (heights may differ).
        labels: None, or one string per picture (drawn centred above it by
            :func:`text_image`, clipped to the picture's width).
        gap: pixels between pictures and around the labels, >= 0.
        background: (r, g, b) of the gaps and padding.
        scale: size factor of the labels (see :func:`text_image`).

    Returns:
        (H', W', 3) uint8 RGB picture.

    Raises:
        ValueError: no pictures, a picture that is not uint8 (H, W[, 3]), or a label
            count that differs from the picture count.
    """
    pics = []
    for k, img in enumerate(images):
        a = np.asarray(img)
        if a.dtype != np.uint8 or a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
            raise ValueError(f"images[{k}] must be an (H, W) or (H, W, 3) uint8 picture, got {a.shape} {a.dtype}.")
        pics.append(np.repeat(a[:, :, None], 3, 2) if a.ndim == 2 else a)
    if not pics:
        raise ValueError("side_by_side needs at least one picture.")
    if labels is not None:
        labels = list(labels)
        if len(labels) != len(pics):
            raise ValueError(f"got {len(labels)} labels for {len(pics)} pictures.")
    if gap < 0:
        raise ValueError(f"gap must be >= 0, got {gap}.")
    bg = np.asarray(background, np.uint8)
    tops = []
    for k, pic in enumerate(pics):
        if labels is not None:
            text = text_image(str(labels[k]), scale, background=background)[:, :pic.shape[1]]
            band = np.empty((text.shape[0] + 2 * gap, pic.shape[1], 3), np.uint8)
            band[:] = bg
            left = (pic.shape[1] - text.shape[1]) // 2
            band[gap:gap + text.shape[0], left:left + text.shape[1]] = text
            pic = np.concatenate([band, pic], 0)
        tops.append(pic)
    height = max(p.shape[0] for p in tops)
    row = []
    for k, pic in enumerate(tops):
        col = np.empty((height, pic.shape[1], 3), np.uint8)
        col[:] = bg
        if labels is not None:  # labels in one line: align the tops
            col[:pic.shape[0]] = pic
        else:
            top = (height - pic.shape[0]) // 2
            col[top:top + pic.shape[0]] = pic
        if k:
            spacer = np.empty((height, gap, 3), np.uint8)
            spacer[:] = bg
            row.append(spacer)
        row.append(col)
    return np.concatenate(row, 1)
