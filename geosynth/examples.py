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
