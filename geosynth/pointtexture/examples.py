"""Which point-set geometry textures run with no input file? The four kinds of exemplar of
"Geometry texture synthesis with point-set surfaces", Sec. 6 and Table 1: a height field
made from a grey image, chainmail with small bumps, a weave of interlaced threads, and
flowers (small disconnected shapes on a plane), each with the paper's warping weights.

Each is point-sampled (uniformly by area, up to the jitter of random sampling) over its
box B = [0, 1] x [0, 1] in x and y plus a padding of 0.25 on each side (B holds about
44% of the points, the paper's "about 40%"), with analytic normals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geosynth.core.exact import times3x3
from geosynth.pointtexture.texture import PointTexture, texture_from_image

__all__ = ["POINT_EXAMPLES", "PointExample", "point_texture_example", "stones_image"]

PAD = 0.25  # geometry beyond B on each side, in units of B's side


@dataclass(frozen=True)
class PointExample:
    """A built-in exemplar: its maker, the paper's input point count (Table 1) and the key of
    its warping weights in :data:`geosynth.pointtexture.warping.WARP_PRESETS`. No patch size: a built-in's
    is measured like a file's (:func:`geosynth.pointtexture.synthesis.choose_patch`, issue 32)."""

    make: object
    count: int
    preset: str
    description: str


def _rng(seed):
    return np.random.default_rng(seed)


def stones_image(size: int = 256, cells: float = 9.0, seed: int = 0) -> np.ndarray:
    """A grey picture of rounded cobblestones (size x size float64 in [0, 1]): the
    Worley F2 - F1 distance of jittered cell centres, shaped into domes, each stone its own height."""
    from geosynth.core.neighbours import nearest

    rng = _rng(seed)
    g = int(np.ceil(cells)) + 2
    cx, cy = np.meshgrid(np.arange(-1, g - 1), np.arange(-1, g - 1))
    centres = (np.stack([cx.ravel(), cy.ravel()], 1) + rng.uniform(0.15, 0.85, (cx.size, 2))) / cells
    heights = rng.uniform(0.6, 1.0, len(centres))
    u = (np.arange(size) + 0.5) / size
    px, py = np.meshgrid(u, u)
    d, i = nearest(centres, np.stack([px.ravel(), py.ravel()], 1), 2)
    edge = (d[:, 1] - d[:, 0]) * cells  # 0 on the cell border
    dome = np.sqrt(np.clip(edge / 0.55, 0, 1))
    img = (dome * heights[i[:, 0]]).reshape(size, size)
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(img, size / 256)
    return (img - img.min()) / (img.max() - img.min())


def heightfield(count: int = 33_194, seed: int = 0) -> PointTexture:
    """Cobblestones as a height field from a grey image (:func:`stones_image`)."""
    width = 1.0 + 2 * PAD
    img = stones_image(320, cells=9.0 * width / 1.5, seed=seed)
    t = texture_from_image(img, width=width, relief=0.08, count=count, padding=PAD / width, seed=seed,
                           name="heightfield")
    return _shifted(t, -PAD)


def _shifted(t: PointTexture, dx: float) -> PointTexture:
    shift = np.array([dx, dx, 0.0])
    return PointTexture(t.points + shift, t.normals, t.box_min + shift, t.box_max + shift, name=t.name)


# ------------------------------------------------------------------ analytic surfaces, sampled


def _torus(rng, count, centre, axis, big, small):
    """``count`` points by area on a torus (centre, unit axis, radii), with outward normals."""
    u = rng.uniform(0, 2 * np.pi, 4 * count + 16)
    v = rng.uniform(0, 2 * np.pi, 4 * count + 16)
    keep = rng.uniform(0, big + small, u.size) < big + small * np.cos(v)  # area element
    u, v = u[keep][:count], v[keep][:count]
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    e1 = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    radial = np.cos(u)[:, None] * e1 + np.sin(u)[:, None] * e2
    n = np.cos(v)[:, None] * radial + np.sin(v)[:, None] * a
    p = np.asarray(centre) + big * radial + small * n
    return p, n


def _sphere(rng, count, centre, radius, scale=(1.0, 1.0, 1.0), rotation=None):
    """Points on a (scaled) sphere, normals from the ellipsoid's gradient."""
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s = np.asarray(scale, np.float64)
    p = d * radius * s
    n = d / s
    if rotation is not None:  # p @ rotation.T in a fixed order (BLAS rounds by the CPU)
        p, n = times3x3(p, rotation.T), times3x3(n, rotation.T)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return p + np.asarray(centre), n


def _torus_area(big, small):
    return 4 * np.pi ** 2 * big * small


def _region(p, n):
    keep = ((p[:, :2] >= -PAD) & (p[:, :2] <= 1 + PAD)).all(axis=1)
    return p[keep], n[keep]


def _finish(parts, name, zlo, zhi):
    p = np.concatenate([a for a, _ in parts])
    n = np.concatenate([b for _, b in parts])
    p, n = _region(p, n)
    return PointTexture(p, n, np.array([0.0, 0.0, zlo]), np.array([1.0, 1.0, zhi]), name=name)


def chainmail(count: int = 71_454, seed: int = 0) -> PointTexture:
    """Chainmail with small bumps: flat rings on a square lattice linked by upright rings
    at the midpoints of the lattice's edges, and a small sphere in each flat ring's hole."""
    rng = _rng(seed)
    a = 1.0 / 3.0
    big, small, conn, bump = 0.42 * a, 0.06 * a, 0.30 * a, 0.14 * a
    lo, hi = -PAD - a, 1 + PAD + a
    ij = np.arange(int(np.floor(lo / a)), int(np.ceil(hi / a)) + 1)
    shapes = []
    for i in ij:
        for j in ij:
            c = np.array([i * a, j * a, 0.0])
            shapes.append(("torus", c, (0, 0, 1), big, small))
            shapes.append(("torus", c + [a / 2, 0, 0], (0, 1, 0), conn, small))
            shapes.append(("torus", c + [0, a / 2, 0], (1, 0, 0), conn, small))
            shapes.append(("sphere", c, bump))
    areas = np.array([_torus_area(s[3], s[4]) if s[0] == "torus" else 4 * np.pi * s[2] ** 2 for s in shapes])
    region_share = ((1 + 2 * PAD) / (hi - lo)) ** 2
    density = count / (areas.sum() * region_share)
    parts = []
    for s, ar in zip(shapes, areas):
        k = rng.poisson(density * ar)
        parts.append(_torus(rng, k, s[1], s[2], s[3], s[4]) if s[0] == "torus" else _sphere(rng, k, s[1], s[2]))
    return _finish(parts, "chainmail", -(conn + small), conn + small)


def _tube(rng, density, centre_fn, t0, t1, radius, steps=2048):
    """Points on a tube of ``radius`` around the curve centre_fn(t), t in [t0, t1], by area."""
    t = np.linspace(t0, t1, steps)
    c = centre_fn(t)
    seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
    length = seg.sum()
    k = rng.poisson(density * 2 * np.pi * radius * length)
    s = rng.uniform(0, length, k)
    cum = np.r_[0, np.cumsum(seg)]
    tt = np.interp(s, cum, t)
    eps = (t1 - t0) / steps
    p0 = centre_fn(tt)
    tan = centre_fn(tt + eps) - centre_fn(tt - eps)
    tan /= np.linalg.norm(tan, axis=1, keepdims=True)
    up = np.broadcast_to([0.0, 0.0, 1.0], tan.shape)
    e1 = np.cross(tan, up)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(e1, tan)
    phi = rng.uniform(0, 2 * np.pi, k)
    n = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    return p0 + radius * n, n


def weave(count: int = 43_592, seed: int = 0) -> PointTexture:
    """A plain weave: threads along x and along y passing over and under each other."""
    rng = _rng(seed)
    d = 0.2  # thread pitch
    r = 0.042  # thread radius
    amp = 1.15 * r  # the centrelines' wave: crossings are 2 * amp apart
    lo, hi = -PAD - d, 1 + PAD + d
    rows = np.arange(int(np.floor(lo / d)), int(np.ceil(hi / d)) + 1)
    length = (hi - lo) * 1.05
    area = 2 * len(rows) * 2 * np.pi * r * length
    density = count / (area * ((1 + 2 * PAD) / (hi - lo)) ** 2)
    parts = []
    for j in rows:
        yj = (j + 0.5) * d
        fx = (lambda t, yj=yj, j=j: np.stack([t, np.full_like(t, yj), amp * np.sin(np.pi * t / d + j * np.pi)], 1))
        parts.append(_tube(rng, density, fx, lo, hi, r))
        xi = (j + 0.5) * d
        fy = (lambda t, xi=xi, j=j: np.stack([np.full_like(t, xi), t, -amp * np.sin(np.pi * t / d + j * np.pi)], 1))
        parts.append(_tube(rng, density, fy, lo, hi, r))
    return _finish(parts, "weave", -(amp + r), amp + r)


def flowers(count: int = 37_473, seed: int = 0) -> PointTexture:
    """Flowers: a ground plane and, above it, small disconnected flowers (a round heart and
    five flat petals each), scattered at random with a minimum distance."""
    rng = _rng(seed)
    lo, hi = -PAD - 0.1, 1 + PAD + 0.1
    # dart throwing for the flowers' centres
    centres = []
    tries = 0
    while tries < 4000:
        c = rng.uniform(lo, hi, 2)
        tries += 1
        if all(np.hypot(*(c - o)) > 0.2 for o in centres):
            centres.append(c)
    heart, petal_len, petal_w, lift = 0.022, 0.045, 0.022, 0.05
    plane_area = (1 + 2 * PAD) ** 2
    flower_area = 4 * np.pi * heart ** 2 + 5 * 4 * np.pi * (petal_len * petal_w + petal_len * 0.008 + petal_w * 0.008) / 3
    n_flowers = len(centres) * ((1 + 2 * PAD) / (hi - lo)) ** 2
    density = count / (plane_area + n_flowers * flower_area)
    k = rng.poisson(density * plane_area)
    xy = rng.uniform(-PAD, 1 + PAD, (k, 2))
    parts = [(np.c_[xy, np.zeros(k)], np.tile([0.0, 0.0, 1.0], (k, 1)))]
    for c in centres:
        z = lift + rng.uniform(-0.01, 0.01)
        base = np.array([c[0], c[1], z])
        parts.append(_sphere(rng, rng.poisson(density * 4 * np.pi * heart ** 2), base, heart))
        turn = rng.uniform(0, 2 * np.pi)
        for m in range(5):
            ang = turn + 2 * np.pi * m / 5
            rot = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1.0]])
            tilt = 0.35  # petals rise outward
            ct, st = np.cos(tilt), np.sin(tilt)
            rot = times3x3(rot, np.array([[ct, 0, -st], [0, 1, 0], [st, 0, ct]]))
            centre = base + times3x3(np.array([[heart + petal_len * 0.8, 0, 0]]), rot.T)[0]
            ar = 4 * np.pi * (petal_len * petal_w + petal_len * 0.008 + petal_w * 0.008) / 3
            parts.append(_sphere(rng, rng.poisson(density * ar), centre, 1.0, (petal_len, petal_w, 0.008), rot))
    return _finish(parts, "flowers", 0.0, lift + 0.04)


POINT_EXAMPLES: dict[str, PointExample] = {
    "heightfield": PointExample(heightfield, 33_194, "heightfield", "cobblestones, a height field from a grey image"),
    "chainmail": PointExample(chainmail, 71_454, "chainmail", "linked rings with small spheres"),
    "weave": PointExample(weave, 43_592, "weave", "interlaced threads"),
    "flowers": PointExample(flowers, 37_473, "flowers", "small disconnected flowers on a plane"),
}


def point_texture_example(name: str, count: int | None = None, seed: int = 0) -> PointTexture:
    """A built-in point texture.

    Args:
        name: one of :data:`POINT_EXAMPLES` (heightfield, chainmail, weave, flowers).
        count: about this many points in all (padding included); default the paper's
            Table 1 input size for that kind.
        seed: seed of the sampling (and of the random layout: stones, flowers).

    Returns:
        The :class:`PointTexture` (B = [0, 1]^2 in x and y).
    """
    if name not in POINT_EXAMPLES:
        raise ValueError(f"unknown point texture example {name!r}; choose one of {', '.join(POINT_EXAMPLES)}.")
    ex = POINT_EXAMPLES[name]
    c = ex.count if count is None else count
    if not isinstance(c, (int, np.integer)) or c < 1000:
        raise ValueError(f"count must be an integer >= 1000, got {count!r}.")
    t = ex.make(int(c), seed)
    if abs(len(t) - c) > 0.01 * c:  # the cropped lattice's share of the points is known only after sampling
        t = ex.make(int(round(c * c / len(t))), seed)
    return t
