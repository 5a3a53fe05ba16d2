"""A zoo of exemplars nobody tuned for (issue #32): procedural, seeded, drawn from families
with randomized parameters, written to files the way users' tools write them.

Every method (M1 ``volume``, M2 ``pointtexture``, M4 ``complete``) gets members from several
families; member ``i`` of a method takes family ``i % len(families)`` and its own seed, so
the first 12 members cover every family at least twice. Parameters are drawn, never picked:
a member's :attr:`Member.params` records them (with what a person would measure, e.g. the
relief's period and direction, so a metric can be checked against the truth).

    >>> from zoo import zoo
    >>> members = zoo("volume", 12, seed=0)
    >>> path = members[0].write("zoo_files")        # the file a user would give

Families
- volume (meshes, trimesh PLY / OBJ / STL): ``bumps`` (a plate with half-sunk spheres of two
  size classes), ``washers`` (one layer of separate flat rings), ``knit`` (tori tilted
  alternately, interlinked or separate), ``tubes`` (a woodpile of wavy rods, layers apart),
  ``cobbles`` (squashed ellipsoids on a plate), ``terrain`` (large hills plus small-scale
  roughness, a closed slab).
- pointtexture (point sets with normals, plyfile ASCII / binary PLY, or an OBJ mesh):
  ``bumps``, ``ridges`` (one period and direction), ``cobbles`` (Worley domes), ``noise``
  (band-limited isotropic), ``rings`` (separate tori lying on a plane).
- complete (captured part of a surface as a vertex-grid mesh, with or without colour; a plane
  misses a band across its middle, a cylinder or a sphere one side):
  relief ``ridges`` (horizontal, vertical or diagonal), ``bumps`` (isotropic) or ``knurl``
  on a ``plane``, ``cylinder`` or ``sphere``; written by trimesh (binary PLY, RGBA uchar),
  plyfile (ASCII PLY, float or ushort colours) or as OBJ with vertex colours.
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

METHODS = ("volume", "pointtexture", "complete")
VOLUME_FAMILIES = ("bumps", "washers", "knit", "tubes", "cobbles", "terrain")
POINT_FAMILIES = ("bumps", "ridges", "cobbles", "noise", "rings", "ridges-diagonal")
SURFACES = ("plane", "cylinder", "sphere")
RELIEFS = ("ridges", "bumps", "knurl")


@dataclass(frozen=True)
class Member:
    """One zoo exemplar: which method it is for, its family, its seed and drawn parameters.

    Attributes:
        method: "volume", "pointtexture" or "complete".
        family: the family (see the module docstring).
        index: its place in the method's list.
        seed: the seed of its random draws.
        params: the drawn parameters (JSON-able), including the writer and, where known,
            the truth a metric should find (``period``, ``angle_deg``, ``amplitude``,
            ``element_diameter``, ``thickness``, ...).
    """

    method: str
    family: str
    index: int
    seed: int
    params: dict = field(hash=False)

    @property
    def name(self) -> str:
        return f"{self.method}-{self.index:02d}-{self.family}"

    @property
    def suffix(self) -> str:
        return {"trimesh-ply": ".ply", "plyfile-ascii": ".ply", "plyfile-binary": ".ply", "obj": ".obj",
                "stl": ".stl"}[self.params["writer"]]

    def write(self, folder: str | Path) -> Path:
        """Write the member's file into ``folder`` (created) and return its path."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{self.name}{self.suffix}"
        _WRITERS[self.method](self, path)
        return path


def zoo(method: str, count: int = 12, seed: int = 0) -> list[Member]:
    """The first ``count`` members of ``method``'s zoo, drawn with ``seed``.

    Args:
        method: "volume", "pointtexture" or "complete".
        count: members, >= 1.
        seed: the zoo's seed; member i draws its parameters with seed ``1000 * seed + i``.

    Returns:
        list of :class:`Member`, families in turn.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; the zoo has {', '.join(METHODS)}.")
    families = {"volume": VOLUME_FAMILIES, "pointtexture": POINT_FAMILIES, "complete": None}[method]
    out = []
    for i in range(count):
        s = 1000 * seed + i
        rng = np.random.default_rng(s)
        if method == "complete":
            surface = SURFACES[i % len(SURFACES)]
            relief = RELIEFS[(i // len(SURFACES)) % len(RELIEFS)]
            family = f"{relief}-{surface}"
            params = _draw_complete(rng, surface, relief, i)
        else:
            family = families[i % len(families)]
            params = (_draw_volume if method == "volume" else _draw_points)(rng, family, i)
        out.append(Member(method, family, i, s, params))
    return out


# ------------------------------------------------------------------ M1: meshes


def _draw_volume(rng, family: str, i: int) -> dict:
    writer = ("trimesh-ply", "obj", "stl")[i % 3]
    p: dict = {"writer": writer}
    if family == "bumps":
        s = float(rng.uniform(0.6, 1.0))
        r0 = float(rng.uniform(0.12, 0.2)) * s / 0.8
        p.update(size=float(rng.uniform(3.0, 5.0)), thickness=float(rng.uniform(0.2, 0.4)), spacing=s,
                 radius=(r0, r0 * float(rng.uniform(1.2, 1.8))), jitter=float(rng.uniform(0.05, 0.15)) * s)
    elif family == "washers":
        s = float(rng.uniform(0.5, 0.9))
        outer = s * float(rng.uniform(0.3, 0.42))
        p.update(cells=int(rng.integers(4, 6)), spacing=s, outer=outer, inner=outer * float(rng.uniform(0.4, 0.65)),
                 height=float(rng.uniform(0.06, 0.15)), jitter=float(rng.uniform(0.0, 0.05)) * s)
    elif family == "knit":
        major = float(rng.uniform(0.35, 0.5))
        linked = bool(rng.integers(0, 2))
        p.update(cells=4, major=major, minor=major * float(rng.uniform(0.15, 0.25)),
                 tilt=float(rng.uniform(0.3, 0.7)), linked=linked,
                 spacing=(major * float(rng.uniform(1.4, 1.7) if linked else rng.uniform(2.3, 2.7)),
                          major * float(rng.uniform(1.1, 1.4) if linked else rng.uniform(2.3, 2.7))))
    elif family == "tubes":
        r = float(rng.uniform(0.05, 0.12))
        p.update(radius=r, spacing=r * float(rng.uniform(3.0, 5.0)), layers=int(rng.integers(2, 4)),
                 gap=r * float(rng.uniform(0.5, 1.0)), wave=r * float(rng.uniform(0.0, 1.5)), size=float(rng.uniform(2, 3)))
    elif family == "cobbles":
        s = float(rng.uniform(0.5, 0.8))
        p.update(size=float(rng.uniform(3.0, 4.5)), spacing=s, radius=s * float(rng.uniform(0.38, 0.46)),
                 flatness=float(rng.uniform(0.35, 0.7)), thickness=float(rng.uniform(0.1, 0.25)),
                 jitter=float(rng.uniform(0.0, 0.08)) * s)
    elif family == "terrain":
        p.update(hills=int(rng.integers(2, 5)), hill_height=float(rng.uniform(0.15, 0.35)),
                 roughness=float(rng.uniform(0.02, 0.08)), hurst=float(rng.uniform(0.5, 0.85)),
                 base=float(rng.uniform(0.08, 0.15)))
    p["build_seed"] = int(rng.integers(0, 2**31))
    return p


def volume_mesh(member: Member):
    """The ``trimesh.Trimesh`` of a volume member (parts concatenated, not unioned, as a user's
    modelling script would leave them)."""
    import trimesh

    from geosynth.volume.examples import heightfield_slab, torus_mesh, tube_mesh

    p, rng = member.params, np.random.default_rng(member.params["build_seed"])
    f = member.family
    if f == "bumps":
        n = max(2, round(p["size"] / p["spacing"]))
        parts = [trimesh.creation.box([p["size"]] * 2 + [p["thickness"]])]
        parts[0].apply_translation([0, 0, -p["thickness"] / 2])
        for a in range(n):
            for b in range(n):
                c = (np.array([a, b]) + 0.5) * p["size"] / n - p["size"] / 2 + rng.uniform(-1, 1, 2) * p["jitter"]
                sphere = trimesh.creation.icosphere(3, radius=float(rng.uniform(*p["radius"])))
                sphere.apply_translation([c[0], c[1], 0.0])
                parts.append(sphere)
        return trimesh.util.concatenate(parts)
    if f == "washers":
        parts = []
        for a in range(p["cells"]):
            for b in range(p["cells"]):
                ring = trimesh.creation.annulus(p["inner"], p["outer"], p["height"], sections=48)
                c = np.array([a, b]) * p["spacing"] + rng.uniform(-1, 1, 2) * p["jitter"]
                ring.apply_translation([c[0], c[1], p["height"] / 2])
                parts.append(ring)
        return trimesh.util.concatenate(parts)
    if f == "knit":
        parts = []
        for a in range(p["cells"]):
            for b in range(p["cells"]):
                ring = torus_mesh(p["major"], p["minor"], 64, 16)
                tilt = p["tilt"] * (1 if (a + b) % 2 else -1)
                ring.apply_transform(trimesh.transformations.rotation_matrix(tilt, [1, 0, 0]))
                ring.apply_translation([a * p["spacing"][0], b * p["spacing"][1], 0.0])
                parts.append(ring)
        return trimesh.util.concatenate(parts)
    if f == "tubes":
        parts, r, s = [], p["radius"], p["spacing"]
        n = max(2, int(p["size"] / s))
        t = np.linspace(0, p["size"], 96)
        for layer in range(p["layers"]):
            z = layer * (2 * r + p["gap"])
            for k in range(n):
                phase = rng.uniform(0, 2 * np.pi)
                wob = p["wave"] * np.sin(2 * np.pi * t / p["size"] * 2 + phase)
                line = np.column_stack([t, np.full_like(t, (k + 0.5) * s) + wob, np.full_like(t, z)])
                if layer % 2:
                    line = line[:, [1, 0, 2]]
                parts.append(tube_mesh(line, r, sections=16))
        return trimesh.util.concatenate(parts)
    if f == "cobbles":
        n = max(2, round(p["size"] / p["spacing"]))
        base = trimesh.creation.box([n * p["spacing"]] * 2 + [p["thickness"]])
        base.apply_translation([n * p["spacing"] / 2, n * p["spacing"] / 2, -p["thickness"] / 2])
        parts = [base]
        for a in range(n):
            for b in range(n):
                stone = trimesh.creation.icosphere(3, radius=1.0)
                rx = p["radius"] * rng.uniform(0.85, 1.0)
                ry = p["radius"] * rng.uniform(0.85, 1.0)
                stone.apply_scale([rx, ry, p["radius"] * p["flatness"]])
                c = (np.array([a + 0.5, b + 0.5 + 0.5 * (a % 2) - 0.25])) * p["spacing"] + rng.uniform(-1, 1, 2) * p["jitter"]
                stone.apply_translation([c[0], c[1], 0.0])
                parts.append(stone)
        return trimesh.util.concatenate(parts)
    if f == "terrain":
        size = 96
        g = np.arange(size) / size
        x, y = np.meshgrid(g, g, indexing="ij")
        h = np.zeros((size, size))
        for _ in range(p["hills"] ** 2):  # periodic Gaussian hills about 1 / hills apart
            cx, cy = rng.uniform(0, 1, 2)
            w = rng.uniform(0.35, 0.6) / p["hills"]
            dx, dy = (x - cx + 0.5) % 1 - 0.5, (y - cy + 0.5) % 1 - 0.5
            h += rng.uniform(0.5, 1.0) * np.exp(-(dx * dx + dy * dy) / (2 * w * w))
        from geosynth.volume.examples import terrain_heights

        h = p["hill_height"] * h / max(h.max(), 1e-9) + p["roughness"] * terrain_heights(size, p["build_seed"] % 2**31,
                                                                                         p["hurst"])
        return heightfield_slab((h - h.min()) / np.ptp(h), p["base"], float(np.ptp(h)))
    raise ValueError(f"unknown volume family {f!r}")


def _write_volume(member: Member, path: Path) -> None:
    mesh = volume_mesh(member)
    mesh.export(str(path))  # trimesh's own PLY (binary), OBJ or STL writer


# ------------------------------------------------------------------ M2: point sets


def _draw_points(rng, family: str, i: int) -> dict:
    writer = ("plyfile-ascii", "plyfile-binary", "obj")[i % 3]
    p: dict = {"writer": writer, "count": int(rng.integers(25_000, 40_000)), "width": 1.5}
    if family == "bumps":
        p.update(spacing=float(rng.uniform(0.12, 0.25)), relief=float(rng.uniform(0.03, 0.08)),
                 sizes=float(rng.uniform(1.2, 2.0)))
        p["element_diameter"] = p["spacing"] * 0.7
    elif family in ("ridges", "ridges-diagonal"):
        period = float(rng.uniform(0.1, 0.3))
        angle = float(rng.choice([0.0, 90.0])) if family == "ridges" else float(rng.uniform(25, 65))
        p.update(period=period, angle_deg=angle, relief=float(rng.uniform(0.02, 0.06)), sharpness=float(rng.uniform(0, 1)))
    elif family == "cobbles":
        p.update(cells=float(rng.uniform(5, 12)), relief=float(rng.uniform(0.04, 0.1)))
        p["element_diameter"] = p["width"] / p["cells"]
    elif family == "noise":
        p.update(scale=float(rng.uniform(0.06, 0.2)), relief=float(rng.uniform(0.03, 0.08)))
    elif family == "rings":
        p.update(spacing=float(rng.uniform(0.2, 0.35)), relief=0.0)
        p.update(major=p["spacing"] * float(rng.uniform(0.25, 0.38)))
        p.update(minor=p["major"] * float(rng.uniform(0.2, 0.35)))
    p["build_seed"] = int(rng.integers(0, 2**31))
    return p


def _heights(member: Member, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The relief of a height-field point member at (x, y) (both (N,) in [0, width])."""
    p, rng = member.params, np.random.default_rng(member.params["build_seed"])
    f = member.family
    if f == "bumps":
        n = int(p["width"] / p["spacing"]) + 2
        h = np.zeros_like(x)
        for a in range(n):
            for b in range(n):
                cx, cy = (np.array([a, b]) + rng.uniform(0.2, 0.8, 2)) * p["spacing"]
                r = p["spacing"] * 0.35 * (p["sizes"] if rng.uniform() < 0.3 else 1.0) * rng.uniform(0.8, 1.0)
                d2 = (x - cx) ** 2 + (y - cy) ** 2
                h = np.maximum(h, np.sqrt(np.clip(1 - d2 / (r * r), 0, None)) * r / (p["spacing"] * 0.35))
        return p["relief"] * h
    if f in ("ridges", "ridges-diagonal"):
        a = math.radians(p["angle_deg"])
        phase = 2 * np.pi * (x * math.cos(a) + y * math.sin(a)) / p["period"]
        s = np.sin(phase)
        return p["relief"] * ((1 - p["sharpness"]) * s + p["sharpness"] * (2 * np.abs(np.sin(phase / 2)) - 1))
    if f == "cobbles":
        from scipy.spatial import cKDTree

        c = p["cells"] / p["width"]
        g = int(p["cells"]) + 3
        centres = (np.stack(np.meshgrid(np.arange(-1, g), np.arange(-1, g)), -1).reshape(-1, 2)
                   + rng.uniform(0.15, 0.85, ((g + 1) ** 2, 2))) / c
        d, _ = cKDTree(centres).query(np.column_stack([x, y]), k=2)
        edge = (d[:, 1] - d[:, 0]) * c
        return p["relief"] * np.sqrt(np.clip(edge / 0.55, 0, 1))
    if f == "noise":
        k = 64
        centres = rng.uniform(-0.2, p["width"] + 0.2, (int(k * (p["width"] / p["scale"]) ** 2 / 16) + 8, 2))
        amp = rng.normal(0, 1, len(centres))
        from scipy.spatial import cKDTree

        tree = cKDTree(centres)
        h = np.zeros_like(x)
        for j, nb in enumerate(tree.query_ball_point(np.column_stack([x, y]), 3 * p["scale"])):
            if nb:
                d2 = ((centres[nb] - [x[j], y[j]]) ** 2).sum(1)
                h[j] = (amp[nb] * np.exp(-d2 / (2 * p["scale"] ** 2))).sum()
        return p["relief"] * h / max(np.abs(h).max(), 1e-9)
    raise ValueError(f"{f!r} is not a height-field family")


def point_set(member: Member) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 3), unit normals (N, 3)) float64 of a point-texture member, spread by area
    (up to the jitter of random sampling) over its [0, width]^2 footprint."""
    import trimesh

    mesh = point_mesh(member)
    pts, face = trimesh.sample.sample_surface(mesh, member.params["count"], seed=member.params["build_seed"])
    return np.asarray(pts, np.float64), np.asarray(mesh.face_normals[face], np.float64)


def point_mesh(member: Member):
    """The surface a point member samples, as a ``trimesh.Trimesh`` (a fine height-field grid,
    or a plate with rings lying on it)."""
    import trimesh

    p = member.params
    if member.family == "rings":
        from geosynth.volume.examples import torus_mesh

        rng = np.random.default_rng(p["build_seed"])
        n = int(p["width"] / p["spacing"])
        plane = trimesh.creation.box([p["width"], p["width"], 0.02])
        plane.apply_translation([p["width"] / 2, p["width"] / 2, -0.01])
        parts = [plane]
        for a in range(n):
            for b in range(n):
                ring = torus_mesh(p["major"], p["minor"], 48, 12)
                c = (np.array([a, b]) + 0.5) * p["width"] / n + rng.uniform(-0.05, 0.05, 2) * p["spacing"]
                ring.apply_translation([c[0], c[1], p["minor"]])
                parts.append(ring)
        return trimesh.util.concatenate(parts)
    res = 200
    t = np.linspace(0, p["width"], res + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    z = _heights(member, x.ravel(), y.ravel())
    idx = np.arange((res + 1) ** 2).reshape(res + 1, res + 1)
    v00, v10, v01, v11 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    faces = np.concatenate([np.stack([v00, v10, v11], -1).reshape(-1, 3), np.stack([v00, v11, v01], -1).reshape(-1, 3)])
    return trimesh.Trimesh(np.column_stack([x.ravel(), y.ravel(), z]), faces, process=False)


def _write_points(member: Member, path: Path) -> None:
    writer = member.params["writer"]
    if writer == "obj":
        point_mesh(member).export(str(path))
        return
    import plyfile

    pts, nrm = point_set(member)
    data = np.empty(len(pts), [(k, "f4") for k in ("x", "y", "z", "nx", "ny", "nz")])
    for k, col in zip(("x", "y", "z"), pts.T):
        data[k] = col
    for k, col in zip(("nx", "ny", "nz"), nrm.T):
        data[k] = col
    plyfile.PlyData([plyfile.PlyElement.describe(data, "vertex")], text=writer == "plyfile-ascii").write(str(path))


# ------------------------------------------------------------------ M4: captures


def _draw_complete(rng, surface: str, relief: str, i: int) -> dict:
    writer = ("trimesh-ply", "plyfile-ascii", "obj", "plyfile-binary")[i % 4]
    coloured = bool(i % 5 != 4)
    # a scale of the surface: plane 3 x 2, cylinder radius 1 height 2, sphere radius 1
    period = float(rng.uniform(0.25, 0.5))
    angle = {"ridges": float(rng.choice([0.0, 90.0, float(rng.uniform(30, 60))])), "bumps": 0.0, "knurl": 0.0}[relief]
    p = {"writer": writer, "surface": surface, "relief": relief, "coloured": coloured,
         "colour_type": ("float", "ushort", "uchar")[i % 3] if writer.startswith("plyfile") else "uchar",
         "period": period, "angle_deg": angle, "amplitude": period * float(rng.uniform(0.08, 0.18)),
         "fraction": float(rng.uniform(0.45, 0.6)), "spacing": period / float(rng.uniform(6, 9)),
         "palette": rng.integers(20, 235, (2, 3)).tolist(), "build_seed": int(rng.integers(0, 2**31))}
    return p


def _dome(dist: np.ndarray, period: float) -> np.ndarray:
    """A bump's profile in [-1, 1] at ``dist`` from its centre (radius 0.35 periods)."""
    return np.clip(1 - (dist / (0.35 * period)) ** 2, 0, None) ** 0.5 * 2 - 1


def _sphere_relief(p: dict, u: np.ndarray, v: np.ndarray, k: float, a: float, rng) -> np.ndarray:
    """A relief in [-1, 1] on the unit sphere at azimuth ``u`` and polar angle ``v``, of
    wavenumber ``k`` (arc length), the same size everywhere rather than sheared: ridges of
    a whole number of turns around the axis (at angle ``a`` from the meridians at the
    equator: spirals; along the latitudes at 90 degrees); a knurl whose bands between the
    latitude ridges' zeros each take the whole number of cycles closest to their own
    circumference (continuous: it changes where the bands' factor is zero); bumps around
    centres drawn uniformly on the sphere, at their arc distance."""
    if p["relief"] == "ridges":
        return np.sin(round(k * math.cos(a)) * u + k * math.sin(a) * v)
    if p["relief"] == "knurl":
        band = np.floor(v * k / np.pi)
        cycles = np.maximum(1, np.rint(k * np.sin((band + 0.5) * np.pi / k)))
        return np.sin(k * v) * np.sin(cycles * u)
    count = int(4 * np.pi / p["period"] ** 2 * 1.5) + 4
    c = rng.normal(size=(count, 3))
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    from scipy.spatial import cKDTree

    x = np.stack([np.sin(v) * np.cos(u), np.sin(v) * np.sin(u), np.cos(v)], -1).reshape(-1, 3)
    chord, _ = cKDTree(c).query(x)
    return _dome(2 * np.arcsin(np.clip(chord / 2, 0, 1)).reshape(u.shape), p["period"])


def capture_surface(member: Member, whole: bool = False):
    """(vertices (N, 3) float64, faces (F, 3) int64, colours (N, 3) uint8 or None, uv (N, 2)) of a
    complete member's captured part (``whole``: the entire surface, the ground truth)."""
    p = member.params
    rng = np.random.default_rng(p["build_seed"])
    d = p["spacing"]
    if p["surface"] == "plane":
        nu, nv = int(3.0 / d) + 1, int(2.0 / d) + 1
        u, v = np.meshgrid(np.linspace(0, 3, nu), np.linspace(0, 2, nv), indexing="ij")
    elif p["surface"] == "cylinder":
        nu, nv = int(2 * np.pi / d) + 1, int(2.0 / d) + 1
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, nu), np.linspace(0, 2, nv), indexing="ij")  # u = arc length
        keep_u = 2 * np.pi * p["fraction"]
    else:
        nu, nv = int(2 * np.pi / d) + 1, int(np.pi / d) + 1
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, nu), np.linspace(0.15, np.pi - 0.15, nv), indexing="ij")
        keep_u = 2 * np.pi * p["fraction"]
    a = math.radians(p["angle_deg"])
    k = 2 * np.pi / p["period"]
    if p["surface"] == "sphere":
        h = _sphere_relief(p, u, v, k, a, rng)
    else:  # u and v are arc lengths; around a cylinder (radius 1) a whole number of cycles, so that it closes
        ku = k * math.cos(a) if p["surface"] == "plane" else round(k * math.cos(a))
        if p["relief"] == "ridges":
            h = np.sin(ku * u + k * math.sin(a) * v)
        elif p["relief"] == "knurl":
            h = np.sin(ku * u) * np.sin(k * v)
        else:
            c = rng.uniform(0, [u.max() + 0.01, v.max() + 0.01], (int(u.max() * v.max() / p["period"] ** 2 * 1.5) + 4, 2))
            from scipy.spatial import cKDTree

            # around a cylinder the bumps' distances wrap (u in [0, 2 pi])
            box = None if p["surface"] == "plane" else [2 * np.pi, 4 * (v.max() + 1)]
            if box is not None:
                c[:, 0] = np.mod(c[:, 0], 2 * np.pi)
            dist, _ = cKDTree(c, boxsize=box).query(np.column_stack([np.mod(u.ravel(), 2 * np.pi) if box else
                                                                     u.ravel(), v.ravel()]))
            h = _dome(dist.reshape(u.shape), p["period"])
    h = p["amplitude"] * h
    if p["surface"] == "plane":
        pos = np.stack([u, v, h], -1)
    elif p["surface"] == "cylinder":
        r = 1.0 + h
        pos = np.stack([r * np.cos(u), r * np.sin(u), v], -1)
    else:
        r = 1.0 + h
        pos = np.stack([r * np.sin(v) * np.cos(u), r * np.sin(v) * np.sin(u), r * np.cos(v)], -1)
    colours = None
    if p["coloured"]:
        t = (h / p["amplitude"] + 1) / 2
        pal = np.asarray(p["palette"], float)
        c = (1 - t[..., None]) * pal[0] + t[..., None] * pal[1] + rng.normal(0, 4, h.shape + (3,))
        colours = np.clip(np.round(c), 0, 255).astype(np.uint8)
    rows = np.ones(nu, bool)
    if not whole:  # the plane: a band across the middle missing (its box is the region to fill); else one side
        rows = (np.abs(u[:, 0] - 1.5) >= 1.5 * (1.0 - p["fraction"])) if p["surface"] == "plane" else u[:, 0] < keep_u
    elif p["surface"] != "plane":
        rows[-1] = False  # the seam column repeats the first
    keep = np.repeat(rows, nv)
    idx = np.arange(nu * nv).reshape(nu, nv)
    v00, v10, v01, v11 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    faces = np.concatenate([np.stack([v00, v10, v11], -1).reshape(-1, 3), np.stack([v00, v11, v01], -1).reshape(-1, 3)])
    faces = faces[keep[faces].all(1)]
    new_index = np.cumsum(keep) - 1
    verts = pos.reshape(-1, 3)[keep]
    uv = np.column_stack([u.ravel(), v.ravel()])[keep]
    cols = None if colours is None else colours.reshape(-1, 3)[keep]
    return verts, new_index[faces].astype(np.int64), cols, uv


def _write_complete(member: Member, path: Path) -> None:
    verts, faces, colours, _ = capture_surface(member)
    writer = member.params["writer"]
    if writer in ("trimesh-ply", "obj"):
        import trimesh

        mesh = trimesh.Trimesh(verts, faces, process=False)
        if colours is not None:
            mesh.visual.vertex_colors = np.column_stack([colours, np.full(len(colours), 255, np.uint8)])
        mesh.export(str(path))
        return
    import plyfile

    fields = [(k, "f4") for k in ("x", "y", "z")]
    kind = member.params["colour_type"]
    if colours is not None:
        fields += [(k, {"float": "f4", "ushort": "u2", "uchar": "u1"}[kind]) for k in ("red", "green", "blue")]
    data = np.empty(len(verts), fields)
    for k, col in zip(("x", "y", "z"), verts.T):
        data[k] = col
    if colours is not None:
        scale = {"float": 1 / 255, "ushort": 257, "uchar": 1}[kind]
        for k, col in zip(("red", "green", "blue"), colours.T):
            data[k] = col.astype(np.float64) * scale
    face = np.empty(len(faces), [("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = faces
    plyfile.PlyData([plyfile.PlyElement.describe(data, "vertex"), plyfile.PlyElement.describe(face, "face")],
                    text=writer == "plyfile-ascii").write(str(path))


_WRITERS = {"volume": _write_volume, "pointtexture": _write_points, "complete": _write_complete}


if __name__ == "__main__":  # write every member's file: python bench/zoo.py [FOLDER] [COUNT]
    import sys

    if any(a.startswith("-") for a in sys.argv[1:]):  # not a folder named "--help"
        sys.exit("usage: python bench/zoo.py [FOLDER] [COUNT]: every member's file in FOLDER (bench/out/zoo)")
    folder = Path(sys.argv[1] if len(sys.argv) > 1 else "bench/out/zoo")
    count = int(sys.argv[2]) if len(sys.argv) > 2 else 12
    for m in METHODS:
        for member in zoo(m, count):
            print(member.write(folder), {k: v for k, v in member.params.items() if k not in ("palette",)})
