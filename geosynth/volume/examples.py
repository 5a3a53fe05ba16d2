"""Which example inputs run with no input file? Implements no paper section: exemplars for
the methods' inputs.

Built-in example data, generated procedurally so that everything runs with no input file."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = [
    "EXEMPLARS", "Exemplar", "balls_mesh", "chainmail_exemplar", "chainmail_mesh", "exemplar_field", "exemplar_mesh",
    "fibers_mesh", "grid_mesh", "resolve_exemplar_mesh", "settle_spheres", "spheres_field", "terrain_heights",
    "terrain_mesh", "torus_mesh", "tube_mesh",
    "domes_mesh", "heightfield_slab", "ring_layer_mesh",
]


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


def torus_mesh(major_radius: float = 1.0, minor_radius: float = 0.35, major_sections: int = 128,
               minor_sections: int = 64):
    """A torus around the z axis as a watertight trimesh.Trimesh.

    Faces: 2 * major_sections * minor_sections (the defaults give 16,384).
    """
    import trimesh

    return trimesh.creation.torus(major_radius=major_radius, minor_radius=minor_radius,
                                  major_sections=major_sections, minor_sections=minor_sections)


def chainmail_mesh(rings: int = 3, major_radius: float = 1.0, minor_radius: float = 0.15, spacing: float = 1.3,
                   major_sections: int = 32, minor_sections: int = 16):
    """Chainmail of linked tori (one watertight mesh, rings not intersecting).

    Horizontal rings (in the xy plane) sit on a ``rings`` x ``rings`` lattice of step
    2 * spacing; every pair of lattice neighbours is linked by a vertical ring (in the
    xz plane between x-neighbours, in the yz plane between y-neighbours) centred half
    way. With the defaults each vertical ring passes 0.3 inside the holes of the two
    rings it links and rings stay 0.12 apart at their closest.

    Args:
        rings: horizontal rings per side, >= 1.
        major_radius, minor_radius: ring radius and wire radius.
        spacing: distance between a horizontal ring's centre and a linking ring's centre.
        major_sections, minor_sections: tessellation of each torus.

    Returns:
        trimesh.Trimesh with 2 * major_sections * minor_sections faces per ring
        (rings^2 + 2 * rings * (rings - 1) rings: 21 rings, 21,504 faces by default).
    """
    import trimesh

    if rings < 1:
        raise ValueError(f"rings must be >= 1, got {rings}.")
    base = torus_mesh(major_radius, minor_radius, major_sections, minor_sections)
    to_xz = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])  # ring plane xy -> xz
    to_yz = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])  # ring plane xy -> yz
    parts = []
    step = 2 * spacing
    for i in range(rings):
        for j in range(rings):
            parts.append(base.copy().apply_translation([i * step, j * step, 0]))
            if i + 1 < rings:
                ring = base.copy().apply_transform(to_xz)
                parts.append(ring.apply_translation([i * step + spacing, j * step, 0]))
            if j + 1 < rings:
                ring = base.copy().apply_transform(to_yz)
                parts.append(ring.apply_translation([i * step, j * step + spacing, 0]))
    return trimesh.util.concatenate(parts)


# ------------------------------------------------------------------ exemplars
#
# Units: every exemplar is built in the box [0, 1] x [0, 1] x [0, H]: one unit is the
# side of its square footprint, z is up (balls settle along -z, the terrain's height
# is z), and H <= 1 is given per exemplar. All randomness comes from
# ``numpy.random.default_rng(seed)``; the same seed gives the same mesh, bit for bit.


def _fit_footprint(mesh):
    """Scale and move a mesh so that its bounding box starts at 0 and its larger
    horizontal (x or y) extent is 1."""
    lo, hi = mesh.bounds
    mesh.apply_translation(-lo)
    mesh.apply_scale(1.0 / max(hi[0] - lo[0], hi[1] - lo[1]))
    return mesh


def chainmail_exemplar(seed: int = 0, rings: int = 3, minor_radius: float = 0.25, spacing: float = 1.42,
                       jitter: float = 0.02, major_sections: int = 32, minor_sections: int = 16):
    """The "chainmail" exemplar: :func:`chainmail_mesh` with thicker wire, fitted to the unit footprint.

    3 x 3 horizontal rings linked by 12 vertical ones (21 rings). In ring units (ring
    radius 1) the wire radius is 0.25 and neighbouring centres are 1.42 apart, which
    leaves 0.08 between the wires of any two rings; the seed moves every ring by up to
    ``jitter`` (0.02) along each axis, so rings never touch. The result is scaled so
    the footprint is 1 x 1 (about 0.3 high): the wire is then about 0.06 thick, 3
    samples of a 64^3 source field.

    Args:
        seed: seed of the ring jitter.
        rings, minor_radius, spacing, major_sections, minor_sections: as in
            :func:`chainmail_mesh` (ring radius 1).
        jitter: largest ring displacement per axis, in ring units.

    Returns:
        watertight ``trimesh.Trimesh``, 2 * major_sections * minor_sections faces per
        ring (21,504 by default), in [0, 1] x [0, 1] x [0, ~0.3].
    """
    mesh = chainmail_mesh(rings, 1.0, minor_radius, spacing, major_sections, minor_sections)
    per_ring = major_sections * minor_sections  # chainmail_mesh concatenates equal tori in order
    count = len(mesh.vertices) // per_ring
    shift = np.random.default_rng(seed).uniform(-jitter, jitter, (count, 1, 3))
    vertices = (mesh.vertices.reshape(count, per_ring, 3) + shift).reshape(-1, 3)
    import trimesh

    return _fit_footprint(trimesh.Trimesh(vertices, mesh.faces, process=False))


def settle_spheres(radii, seed: int = 0, candidates: int = 48, gap: float = 0.005) -> np.ndarray:
    """Drop spheres one by one into the box [0, 1]^2 x [0, inf): a sequential settling.

    Each sphere (in the given order) is tried above a ``candidates`` x ``candidates``
    grid of xy positions covering the footprint (kept ``radius`` from the walls, each
    position moved randomly within its grid cell) and falls straight down at each until
    it rests on the floor or on earlier spheres (keeping ``gap`` between surfaces); the
    lowest resting place wins (ties: the first). A crude model of spheres poured into a
    box, where each rolls into the deepest hollow: the pile is dense, and no two
    spheres overlap.

    Args:
        radii: (n,) sphere radii, each in (0, 0.5).
        seed: seed of the candidate positions.
        candidates: candidate positions per side of the grid, >= 1.
        gap: smallest distance kept between two sphere surfaces, >= 0.

    Returns:
        (n, 3) float64 centres; sphere i rests at z >= radii[i].
    """
    r = np.asarray(radii, np.float64)
    if r.ndim != 1 or not ((r > 0) & (r < 0.5)).all():
        raise ValueError(f"radii must be a 1D array of values in (0, 0.5), got {radii!r}.")
    if candidates < 1 or gap < 0:
        raise ValueError(f"candidates must be >= 1 and gap >= 0, got {candidates}, {gap}.")
    rng = np.random.default_rng(seed)
    cell = np.stack(np.meshgrid(np.arange(candidates), np.arange(candidates), indexing="ij"), -1).reshape(-1, 2)
    centres = np.zeros((len(r), 3))
    for i, ri in enumerate(r):
        xy = ri + (cell + rng.random(cell.shape)) / candidates * (1 - 2 * ri)
        z = np.full(len(xy), ri)
        if i:
            d2 = ((xy[:, None, :] - centres[None, :i, :2]) ** 2).sum(-1)  # (candidates^2, i)
            reach2 = (ri + r[:i] + gap) ** 2
            rest = np.where(d2 < reach2, centres[None, :i, 2] + np.sqrt(np.maximum(reach2 - d2, 0)), -np.inf)
            z = np.maximum(z, rest.max(1))
        best = int(np.argmin(z))
        centres[i] = (xy[best, 0], xy[best, 1], z[best])
    return centres


def _balls_layout(seed: int, count: int = 40, radius=(0.07, 0.12), candidates: int = 48, gap: float = 0.005):
    rng = np.random.default_rng(seed)
    radii = rng.uniform(radius[0], radius[1], count)
    return settle_spheres(radii, seed=int(rng.integers(2**31)), candidates=candidates, gap=gap), radii


def balls_mesh(seed: int = 0, count: int = 40, radius: tuple[float, float] = (0.07, 0.12), candidates: int = 48,
               gap: float = 0.005, subdivisions: int = 2):
    """The "balls" exemplar: ``count`` spheres settled in a box (:func:`settle_spheres`).

    Radii uniform in ``radius``; the spheres never overlap (``gap`` apart at least), so
    the mesh (one icosphere each) is a clean union. The pile is about 0.4 to 0.5 high.

    Args:
        seed: seed of the radii and the drop positions.
        count: number of spheres.
        radius: (min, max) radius in units of the footprint.
        candidates, gap: see :func:`settle_spheres`.
        subdivisions: icosphere subdivisions (2: 320 faces a sphere).

    Returns:
        watertight ``trimesh.Trimesh`` (12,800 faces by default) in [0, 1]^2 x [0, ~0.5].
    """
    import trimesh

    centres, radii = _balls_layout(seed, count, radius, candidates, gap)
    unit = trimesh.creation.icosphere(subdivisions=subdivisions)
    parts = [trimesh.Trimesh(unit.vertices * r + c, unit.faces, process=False) for c, r in zip(centres, radii)]
    return trimesh.util.concatenate(parts)


def balls_field(resolution: int = 64, seed: int = 0, padding: float = 0.1, **params):
    """The exact signed distance of the "balls" exemplar (true spheres, not icospheres).

    The minimum over the spheres of ``|p - c| - r``: exact everywhere, inside too, as
    the spheres do not overlap. The grid is the one :func:`geosynth.geometry.meshes.mesh_distance`
    uses for ``balls_mesh(seed)`` with the same ``resolution`` and ``padding``.

    Returns:
        float32 :class:`~geosynth.geometry.field.Field`, negative inside.
    """
    from geosynth.geometry.field import cubic_grid

    centres, radii = _balls_layout(seed, **{k: v for k, v in params.items() if k != "subdivisions"})
    grid = cubic_grid(balls_mesh(seed, **params).bounds, resolution, padding)
    (nz, ny, nx), o, h = grid.shape, grid.origin, grid.spacing
    x, y, z = (o[a] + h[a] * np.arange(n) for a, n in enumerate((nx, ny, nz)))
    out = np.full((nz, ny, nx), np.inf)
    for c, r in zip(centres, radii):
        d = np.sqrt((z[:, None, None] - c[2]) ** 2 + (y[None, :, None] - c[1]) ** 2 + (x[None, None, :] - c[0]) ** 2)
        np.minimum(out, d - r, out=out)
    grid.values = out.astype(np.float32)
    return grid


def tube_mesh(path, radius, sections: int = 12, caps: bool = True):
    """A tube of circular section swept along a polyline, closed with flat caps.

    The section is carried along the path by parallel transport (rotation-minimizing
    frames), so the tube does not twist.

    Args:
        path: (n, 3) centre line, n >= 2, consecutive points distinct.
        radius: the tube radius, a number or (n,) per path point.
        sections: vertices around the section, >= 3.
        caps: close both ends (a watertight tube), else leave them open.

    Returns:
        ``trimesh.Trimesh`` with 2 * sections * (n - 1) faces (+ 2 * sections for the
        caps), faces outward.
    """
    import trimesh

    p = np.asarray(path, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
        raise ValueError(f"path must be (n, 3) with n >= 2, got shape {p.shape}.")
    if sections < 3:
        raise ValueError(f"sections must be >= 3, got {sections}.")
    n = len(p)
    r = np.broadcast_to(np.asarray(radius, np.float64), (n,))
    tangent = np.gradient(p, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.empty_like(p)
    seed_axis = np.eye(3)[int(np.argmin(np.abs(tangent[0])))]
    v = seed_axis - tangent[0] * (seed_axis @ tangent[0])
    for i in range(n):  # parallel transport of the normal
        v = v - tangent[i] * (v @ tangent[i])
        v /= np.linalg.norm(v)
        normal[i] = v
    binormal = np.cross(tangent, normal)
    a = 2 * np.pi * np.arange(sections) / sections
    ring = np.cos(a)[None, :, None] * normal[:, None, :] + np.sin(a)[None, :, None] * binormal[:, None, :]
    vertices = (p[:, None, :] + r[:, None, None] * ring).reshape(-1, 3)
    i, k = np.meshgrid(np.arange(n - 1), np.arange(sections), indexing="ij")
    v00, v01 = i * sections + k, i * sections + (k + 1) % sections
    v10, v11 = v00 + sections, v01 + sections
    faces = [np.stack([v00, v11, v10], -1).reshape(-1, 3), np.stack([v00, v01, v11], -1).reshape(-1, 3)]
    if caps:
        c0, c1 = n * sections, n * sections + 1
        vertices = np.vstack([vertices, p[0], p[-1]])
        k = np.arange(sections)
        faces.append(np.stack([np.full(sections, c0), (k + 1) % sections, k], -1))
        last = (n - 1) * sections
        faces.append(np.stack([np.full(sections, c1), last + k, last + (k + 1) % sections], -1))
    return trimesh.Trimesh(vertices, np.concatenate(faces), process=False)


def _smooth_noise(rng, t, amplitude: float, waves: int = 3, frequency=(0.7, 2.5)):
    """A sum of ``waves`` random sinusoids of t with peak at most ``amplitude``."""
    f = rng.uniform(frequency[0], frequency[1], waves)
    phase = rng.uniform(0, 2 * np.pi, waves)
    weight = rng.uniform(0.5, 1.0, waves)
    weight *= amplitude / weight.sum()
    return (weight[:, None] * np.sin(2 * np.pi * f[:, None] * t[None, :] + phase[:, None])).sum(0)


def fibers_mesh(seed: int = 0, count: int = 14, radius: float = 0.03, height: float = 0.4, wave: float = 0.04,
                gap: float = 0.015, step: float = 0.0125, sections: int = 12, tries: int = 200):
    """The "fibers" exemplar: wavy tubes crossing the box in random horizontal directions.

    Each fiber's centre line runs across the unit footprint along a random direction
    through a random point, at a random height, and wanders sideways (by up to
    ``wave``) and up and down (by up to wave / 3) as sums of three random sinusoids.
    It is cut where it leaves the footprint and swept as a capped tube
    (:func:`tube_mesh`). A fiber whose centre line comes closer than 2 * radius + gap to
    an earlier one is drawn again (up to ``tries`` times, then left out), so fibers
    never touch and the mesh is a clean union.

    Args:
        seed: seed of every random choice.
        count: number of fibers wanted.
        radius: tube radius.
        height: the box height; fibers stay inside [0, height].
        wave: sideways waviness amplitude.
        gap: smallest distance kept between two fibers' surfaces.
        step: centre-line sample spacing.
        sections: vertices around a tube.
        tries: draws per fiber before giving up on it.

    Returns:
        watertight ``trimesh.Trimesh`` (about 10 of the 14 fibers fit: 15,000 to 35,000
        faces with the defaults) in about [0, 1]^2 x [0, height] (the tube ends stick out
        of the footprint by up to a radius).
    """
    import trimesh

    from geosynth.core.neighbours import nearest

    rng = np.random.default_rng(seed)
    placed: list[np.ndarray] = []
    tubes = []
    lift = wave / 3
    for _ in range(count):
        for _ in range(tries):
            theta = rng.uniform(0, np.pi)
            d = np.array([np.cos(theta), np.sin(theta)])
            side = np.array([-d[1], d[0]])
            p = rng.uniform(0.2, 0.8, 2)
            z0 = rng.uniform(radius + lift, height - radius - lift)
            with np.errstate(divide="ignore"):  # the chord of the unit square along d through p
                t_lo = np.where(d != 0, (np.where(d > 0, 0, 1) - p) / d, -np.inf).max()
                t_hi = np.where(d != 0, (np.where(d > 0, 1, 0) - p) / d, np.inf).min()
            t = np.linspace(t_lo, t_hi, max(8, int(np.ceil((t_hi - t_lo) / step)) + 1))
            xy = p + t[:, None] * d + _smooth_noise(rng, t, wave)[:, None] * side
            z = z0 + _smooth_noise(rng, t, lift)
            inside = ((xy >= 0) & (xy <= 1)).all(1)
            first, last = np.argmax(inside), len(inside) - np.argmax(inside[::-1])  # trim the wandering ends
            centre = np.column_stack([xy, z])[first:last]
            if len(centre) < 8:
                continue
            if placed and nearest(np.vstack(placed), centre, 1, upper=2 * radius + gap)[0].min() < np.inf:
                continue
            placed.append(centre)
            tubes.append(tube_mesh(centre, radius, sections))
            break
    return trimesh.util.concatenate(tubes)


def _segment_distance_into(out, a, b, radius, origin, spacing, margin):
    """out = min(out, distance to the capsule (a, b, radius)) on the samples near it."""
    lo = np.minimum(a, b) - radius - margin
    hi = np.maximum(a, b) + radius + margin
    n = np.array(out.shape[::-1])
    i0 = np.clip(np.floor((lo - origin) / spacing).astype(int), 0, n)
    i1 = np.clip(np.ceil((hi - origin) / spacing).astype(int) + 1, 0, n)
    if (i1 <= i0).any():
        return
    x, y, z = (origin[k] + spacing[k] * np.arange(i0[k], i1[k]) for k in range(3))
    pts = np.stack(np.meshgrid(z, y, x, indexing="ij")[::-1], -1)  # (nz, ny, nx, 3) as (x, y, z)
    ab = b - a
    t = np.clip(((pts - a) @ ab) / max(ab @ ab, 1e-300), 0, 1)
    d = np.linalg.norm(pts - a - t[..., None] * ab, axis=-1) - radius
    view = out[i0[2]:i1[2], i0[1]:i1[1], i0[0]:i1[0]]
    np.minimum(view, d, out=view)


def grid_mesh(seed: int = 0, cells: tuple[int, int, int] = (3, 3, 2), jitter: float = 0.04,
              rod_radius: tuple[float, float] = (0.03, 0.042), ball_radius: float = 0.075, resolution: int = 72,
              smooth: int = 10):
    """The "grid" exemplar: a perturbed lattice of crossing rods with a ball at every crossing.

    Nodes sit at the cell centres of ``cells`` (x, y, z) cubes of side 1/3 (so the box
    is 1 x 1 x 2/3 by default), each moved by up to ``jitter`` per axis. Through every
    row of nodes along x, y and z runs a rod, a cubic spline through the moved nodes
    cut flat at the box's faces, of a radius drawn uniformly from ``rod_radius``; a
    ball of ``ball_radius`` sits on every node. Rods and balls overlap, so the mesh is
    made as their union: the distance to the union of capsules and spheres, cut by the
    box, sampled at ``resolution`` samples across the footprint and meshed by marching
    cubes (:func:`geosynth.geometry.surface.field_to_mesh`), which gives one clean closed surface,
    then smoothed by ``smooth`` Taubin steps (the staircase of the sampling goes away).

    Args:
        seed: seed of the node moves and the rod radii.
        cells: nodes along x, y, z.
        jitter: largest node move per axis.
        rod_radius: (min, max) rod radius.
        ball_radius: radius of the balls at the nodes.
        resolution: marching-cubes samples across the footprint (the mesh's detail).
        smooth: Taubin smoothing iterations after marching cubes.

    Returns:
        watertight ``trimesh.Trimesh`` (35,000 to 60,000 faces with the defaults) in
        [0, 1] x [0, 1] x [0, cells[2] / 3].
    """
    from scipy.interpolate import CubicSpline

    from geosynth.geometry.field import Field
    from geosynth.geometry.surface import field_to_mesh

    rng = np.random.default_rng(seed)
    cells = np.asarray(cells, int)
    size = cells / 3.0  # box extent (x, y, z); the footprint is 1 x 1 by default
    axes = [(np.arange(c) + 0.5) / 3.0 for c in cells]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1)  # (cx, cy, cz, 3)
    nodes = nodes + rng.uniform(-jitter, jitter, nodes.shape)
    spacing = 1.0 / (resolution - 1)
    pad = 2 * spacing
    origin = np.full(3, -pad)
    shape = np.ceil((size + 2 * pad) / spacing).astype(int) + 1  # (x, y, z) counts
    margin = 2 * spacing  # exact distances within this of a part; farther only the sign matters
    dist = np.full(shape[::-1], margin + max(rod_radius[1], ball_radius), np.float64)
    for axis in range(3):
        rows = np.moveaxis(nodes, axis, -2).reshape(-1, cells[axis], 3)  # every row of nodes along axis
        for row in rows:
            radius = rng.uniform(*rod_radius)
            other = [k for k in range(3) if k != axis]
            if len(row) > 1:
                spline = CubicSpline(row[:, axis], row[:, other], bc_type="natural")
            else:
                spline = lambda s, c=row[0, other]: np.broadcast_to(c, (np.size(s), 2))  # noqa: E731
            s = np.linspace(-radius, size[axis] + radius, max(8, int(size[axis] / 0.03)))
            centre = np.empty((len(s), 3))
            centre[:, axis], centre[:, other] = s, spline(s)
            for a, b in zip(centre[:-1], centre[1:]):
                _segment_distance_into(dist, a, b, radius, origin, np.full(3, spacing), margin)
    for c in nodes.reshape(-1, 3):
        _segment_distance_into(dist, c, c, ball_radius, origin, np.full(3, spacing), margin)
    # cut by the box [0, size]: the intersection is the larger of the two distances
    coords = [origin[k] + spacing * np.arange(shape[k]) for k in range(3)]
    box = [np.maximum(-c, c - size[k]) for k, c in enumerate(coords)]  # per-axis outside distance
    box_d = np.maximum(np.maximum(box[2][:, None, None], box[1][None, :, None]), box[0][None, None, :])
    field = Field(np.maximum(dist, box_d).astype(np.float32), origin, spacing)
    return field_to_mesh(field, smooth=smooth)


def terrain_heights(size: int = 96, seed: int = 0, hurst: float = 0.7, cutoff: float = 0.2) -> np.ndarray:
    """A periodic fractal height field by spectral synthesis (fractional Brownian surface).

    White noise shaped in the Fourier domain by the amplitude ``f ** -(hurst + 1)``
    (power spectrum ``f ** -(2 hurst + 2)``), rolled off smoothly above ``cutoff``
    (times ``exp(-(f / cutoff)^2)``, so the finest detail spans a few samples rather
    than zigzagging from sample to sample), mean removed, scaled to [0, 1]. Being a
    Fourier series it wraps: the field tiles without seams.

    Args:
        size: samples per side, >= 4.
        seed: seed of the noise.
        hurst: the Hurst exponent in (0, 1): low is rough, high is smooth.
        cutoff: roll-off frequency in cycles per sample, > 0.

    Returns:
        (size, size) float64 heights in [0, 1], indexed [i, j] for x = i / size, y = j / size.
    """
    if size < 4 or not 0 < hurst < 1 or not cutoff > 0:
        raise ValueError(f"size must be >= 4, hurst in (0, 1) and cutoff > 0, got size={size}, hurst={hurst}, "
                         f"cutoff={cutoff}.")
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    freq = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2)
    freq[0, 0] = 1.0
    amplitude = freq ** -(hurst + 1) * np.exp(-((freq / cutoff) ** 2))
    amplitude[0, 0] = 0.0
    h = np.fft.ifft2(np.fft.fft2(rng.standard_normal((size, size))) * amplitude).real
    return (h - h.min()) / (h.max() - h.min())


def terrain_mesh(seed: int = 0, size: int = 96, base: float = 0.1, relief: float = 0.3, hurst: float = 0.7):
    """The "terrain" exemplar: a fractal height field (:func:`terrain_heights`) as a closed slab.

    The top is the height surface ``z = base + relief * h(x, y)`` on a (size + 1)^2
    vertex grid over the unit footprint (the heights wrap, so the slab's opposite walls
    match), the bottom is flat at z = 0 (a fan around its centre), and four walls join
    them: a watertight solid.

    Args:
        seed: seed of the height field.
        size: height samples per side.
        base: the lowest top height (the slab's thinnest part).
        relief: height difference between the lowest and highest points of the top.
        hurst: roughness, see :func:`terrain_heights`.

    Returns:
        watertight ``trimesh.Trimesh`` (2 size^2 + 12 size faces: 19,584 by default) in
        [0, 1]^2 x [0, base + relief].
    """
    return heightfield_slab(terrain_heights(size, seed, hurst), base, relief)


# ------------------------------------------------------------------ slab exemplars
#
# Exemplars much thinner along z than across (geosynth.volume.synthesis.is_slab): the synthesis
# grows them across only, with blocks that span their full thickness.


def heightfield_slab(heights: np.ndarray, base: float, relief: float):
    """A closed slab over the unit footprint whose top is ``z = base + relief * h``.

    Args:
        heights: (S, S) heights in [0, 1] on a periodic S x S grid (row i at x = i / S).
        base: the lowest top height (the slab's thinnest part), > 0.
        relief: the height of h = 1 above the base.

    Returns:
        watertight ``trimesh.Trimesh`` (2 S^2 + 12 S faces), flat bottom at z = 0,
        in [0, 1]^2 x [0, base + relief].
    """
    import trimesh

    size = heights.shape[0]
    n = size + 1
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    top = np.column_stack([i.ravel() / size, j.ravel() / size, base + relief * heights[i % size, j % size].ravel()])
    idx = i * n + j
    v00, v10, v01, v11 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    faces = [np.stack([v00, v10, v11], -1).reshape(-1, 3), np.stack([v00, v11, v01], -1).reshape(-1, 3)]
    loop = np.concatenate([idx[:-1, 0], idx[-1, :-1], idx[:0:-1, -1], idx[0, :0:-1]])  # counter-clockwise
    m = len(loop)
    bottom = np.column_stack([top[loop, :2], np.zeros(m)])
    b = n * n + np.arange(m)
    centre = n * n + m
    ta, tb = loop, np.roll(loop, -1)
    ba, bb = b, np.roll(b, -1)
    faces += [np.stack([ba, bb, tb], -1), np.stack([ba, tb, ta], -1), np.stack([np.full(m, centre), bb, ba], -1)]
    vertices = np.vstack([top, bottom, [[0.5, 0.5, 0.0]]])
    return trimesh.Trimesh(vertices, np.concatenate(faces), process=False)


def domes_mesh(seed: int = 0, size: int = 128, cells: int = 5, radius: tuple[float, float] = (0.06, 0.085),
               jitter: float = 0.02, base: float = 0.05, relief: float = 0.07):
    """The "domes" slab exemplar: a thin plate with round domes on a jittered lattice.

    ``cells`` x ``cells`` domes (half-ellipsoids of footprint radius drawn from
    ``radius`` and height ``relief``) on a plate ``base`` thick; centres on the lattice
    of spacing 1 / cells, moved by up to ``jitter`` per axis; the heights wrap, so the
    footprint tiles. About 12 samples thick (margins included) of a 64-sample source.

    Returns:
        watertight ``trimesh.Trimesh`` (2 size^2 + 12 size faces: 34,304 by default) in
        [0, 1]^2 x [0, base + relief].
    """
    rng = np.random.default_rng(seed)
    t = np.arange(size) / size
    x, y = np.meshgrid(t, t, indexing="ij")
    h = np.zeros((size, size))
    for a in range(cells):
        for b in range(cells):
            cx, cy = (np.array([a, b]) + 0.5) / cells + rng.uniform(-jitter, jitter, 2)
            r = rng.uniform(*radius)
            dx = (x - cx + 0.5) % 1.0 - 0.5  # periodic offsets
            dy = (y - cy + 0.5) % 1.0 - 0.5
            h = np.maximum(h, np.sqrt(np.clip(1.0 - (dx * dx + dy * dy) / (r * r), 0.0, None)))
    return heightfield_slab(h, base, relief)


def ring_layer_mesh(seed: int = 0, cells: int = 4, major_radius: float = 0.08, minor_radius: float = 0.025,
                    jitter: float = 0.01, major_sections: int = 32, minor_sections: int = 12):
    """The "rings" slab exemplar: one layer of separate flat rings (tori around z).

    ``cells`` x ``cells`` rings on a lattice of spacing 1 / cells, each moved by up to
    ``jitter`` per axis (neighbouring wires stay >= 0.02 apart: separate pieces), fitted
    to the unit footprint: a layer about 0.05 thick, 8 samples with margins of a
    64-sample source; a ring is about 14 samples across there.

    Returns:
        watertight ``trimesh.Trimesh`` (2 major_sections minor_sections faces per ring:
        12,288 by default) in [0, 1]^2 x [0, ~0.05].
    """
    import trimesh

    rng = np.random.default_rng(seed)
    ring = torus_mesh(major_radius, minor_radius, major_sections, minor_sections)
    parts = []
    for a in range(cells):
        for b in range(cells):
            c = (np.array([a, b]) + 0.5) / cells + rng.uniform(-jitter, jitter, 2)
            part = ring.copy()
            part.apply_translation([c[0], c[1], minor_radius])
            parts.append(part)
    return _fit_footprint(trimesh.util.concatenate(parts))


@dataclass(frozen=True)
class Exemplar:
    """A built-in exemplar: how to build it and what to expect of it.

    Attributes:
        name: its registry name.
        build: ``build(seed=0, **params) -> trimesh.Trimesh``.
        summary: one line for help texts.
        faces: (min, max) face count of the default build, any seed.
        field: None, or ``field(resolution, seed, padding) -> Field``: an exact signed
            distance made without the mesh (see :func:`exemplar_field`).
    """

    name: str
    build: Callable
    summary: str
    faces: tuple[int, int]
    field: Callable | None = None

    def __call__(self, seed: int = 0, **params):
        return self.build(seed=seed, **params)


EXEMPLARS: dict[str, Exemplar] = {
    "chainmail": Exemplar("chainmail", chainmail_exemplar,
                          "21 linked tori on a 3 x 3 lattice, 1 x 1 x 0.3", (21_504, 21_504)),
    "balls": Exemplar("balls", balls_mesh, "40 spheres settled in a box, 1 x 1 x ~0.5", (12_800, 12_800), balls_field),
    "grid": Exemplar("grid", grid_mesh, "perturbed crossing rods with balls at the crossings, 1 x 1 x 0.67",
                     (35_000, 60_000)),
    "fibers": Exemplar("fibers", fibers_mesh, "wavy tubes crossing the box in random directions, 1 x 1 x 0.4",
                       (15_000, 35_000)),
    "terrain": Exemplar("terrain", terrain_mesh, "a fractal height field as a closed slab, 1 x 1 x 0.4",
                        (19_584, 19_584)),
    # slab exemplars (grown across only, blocks through their full thickness)
    "domes": Exemplar("domes", domes_mesh, "slab: round domes on a thin plate, 1 x 1 x 0.12", (34_304, 34_304)),
    "rings": Exemplar("rings", ring_layer_mesh, "slab: one layer of 16 separate flat rings, 1 x 1 x 0.05",
                      (12_288, 12_288)),
}


def _exemplar(name: str) -> Exemplar:
    if name not in EXEMPLARS:
        raise ValueError(f"unknown exemplar {name!r}; the built-in exemplars are: {', '.join(EXEMPLARS)}.")
    return EXEMPLARS[name]


def exemplar_mesh(name: str, seed: int = 0):
    """A built-in exemplar as a mesh (units: see the section comment above; z is up).

    Args:
        name: one of ``EXEMPLARS``: chainmail, balls, grid, fibers, terrain.
        seed: seed of its random choices; the same seed gives the same mesh.

    Returns:
        a watertight ``trimesh.Trimesh`` in about [0, 1]^2 x [0, 1].

    Raises:
        ValueError: an unknown name (the message lists the known ones).

    Example:
        >>> len(exemplar_mesh("terrain").faces)
        19584
    """
    return _exemplar(name)(seed=seed)


def exemplar_field(name: str, resolution: int = 64, seed: int = 0, padding: float = 0.1, device: str | None = None):
    """A built-in exemplar's signed distance field on a grid, negative inside.

    The grid is :func:`geosynth.geometry.field.cubic_grid` around the mesh's bounds (``resolution``
    samples along the longest axis, ``padding`` times it added on every side), the
    same grid as ``mesh_distance(exemplar_mesh(name, seed), resolution=resolution,
    padding=padding)``. Exemplars with an exact analytic distance (balls: true spheres)
    use it; the others are computed from the mesh by :func:`geosynth.geometry.meshes.mesh_distance`
    on ``device``.

    Args:
        name: one of ``EXEMPLARS``.
        resolution: samples along the longest axis, >= 2.
        seed: the exemplar's seed.
        padding: fraction of the largest extent added on each side.
        device: the device of ``mesh_distance`` (None: "auto").

    Returns:
        float32 :class:`~geosynth.geometry.field.Field`.

    Raises:
        ValueError: an unknown name, resolution < 2.
    """
    ex = _exemplar(name)
    if ex.field is not None:
        return ex.field(resolution=resolution, seed=seed, padding=padding)
    from geosynth.geometry.meshes import mesh_distance

    return mesh_distance(ex(seed=seed), resolution=resolution, padding=padding, device=device)


def resolve_exemplar_mesh(exemplar, seed: int | None = 0):
    """The mesh an ``exemplar`` argument names (as :func:`geosynth.synthesize_geometry` takes it).

    Args:
        exemplar: a ``trimesh.Trimesh`` (returned as is), a built-in exemplar name (one
            of ``EXEMPLARS``) or a mesh file path (read by :func:`geosynth.geometry.meshes.load_mesh`).
        seed: the built-in exemplar's seed (None: 0).

    Returns:
        a ``trimesh.Trimesh``.

    Raises:
        ValueError: a string without a suffix that is neither a built-in name nor a file;
            a file that cannot be read as a mesh (see ``load_mesh``).
    """
    import trimesh

    if isinstance(exemplar, trimesh.Trimesh):
        return exemplar
    if isinstance(exemplar, str) and exemplar in EXEMPLARS:
        return exemplar_mesh(exemplar, seed=0 if seed is None else seed)
    from pathlib import Path

    if isinstance(exemplar, str) and not Path(exemplar).suffix and not Path(exemplar).exists():
        raise ValueError(f"exemplar {exemplar!r} is neither a built-in exemplar ({', '.join(EXEMPLARS)}) "
                         "nor a mesh file.")
    from geosynth.geometry.meshes import load_mesh

    return load_mesh(exemplar)
