"""Which meshes does ``geosynth relief`` take by name? Implements no paper section: a body of
revolution and a genus-1 tube, the two shapes issue 34's targets name (a vase, a torus knot),
so that the command, the gallery and bench/bm_relief.py run with no input file.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SHAPES", "shape_mesh", "torus_knot", "vase"]


def vase():
    """A closed vase, 100 units tall: a profile revolved about z (64 sections)."""
    import trimesh

    z = np.linspace(0, 100, 60)
    r = 22 + 10 * np.sin(np.pi * z / 70) - 6 * np.exp(-((z - 85) / 8) ** 2)
    profile = np.concatenate([[[0.0, 0.0]], np.stack([r, z], 1), [[0.0, 100.0]]])
    mesh = trimesh.creation.revolve(profile, sections=64)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def torus_knot(p: int = 2, q: int = 3, radius: float = 30.0, tube: float = 6.0, n: int = 400, ring: int = 24):
    """A closed (p, q) torus knot tube: a circle of ``ring`` points swept along ``n`` curve points with
    parallel-transported frames, the twist left at the end spread over the loop so that it closes."""
    import trimesh

    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rr = radius * (1 + 0.4 * np.cos(q * t))
    c = np.stack([rr * np.cos(p * t), rr * np.sin(p * t), radius * 0.4 * np.sin(q * t)], 1)
    tan = np.roll(c, -1, 0) - np.roll(c, 1, 0)
    tan /= np.linalg.norm(tan, axis=1)[:, None]
    normal = np.zeros_like(c)
    a = np.cross(tan[0], [0.0, 0.0, 1.0])
    normal[0] = a / np.linalg.norm(a)
    for i in range(1, n):  # parallel transport
        m = normal[i - 1] - (normal[i - 1] @ tan[i]) * tan[i]
        normal[i] = m / np.linalg.norm(m)
    end = normal[-1] - (normal[-1] @ tan[0]) * tan[0]
    twist = math.atan2(np.cross(end, normal[0]) @ tan[0], end @ normal[0])
    binormal = np.cross(tan, normal)
    angle = twist * np.arange(n) / n
    nn = np.cos(angle)[:, None] * normal + np.sin(angle)[:, None] * binormal
    bb = np.cross(tan, nn)
    phi = 2 * np.pi * np.arange(ring) / ring
    verts = (c[:, None, :] + tube * (np.cos(phi)[None, :, None] * nn[:, None, :]
                                     + np.sin(phi)[None, :, None] * bb[:, None, :])).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(ring), indexing="ij")
    a0 = (i * ring + j).ravel()
    a1 = (((i + 1) % n) * ring + j).ravel()
    b0 = (i * ring + (j + 1) % ring).ravel()
    b1 = (((i + 1) % n) * ring + (j + 1) % ring).ravel()
    faces = np.concatenate([np.stack([a0, a1, b1], 1), np.stack([a0, b1, b0], 1)])
    mesh = trimesh.Trimesh(verts, faces, process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


SHAPES = {"vase": vase, "knot": torus_knot}


def shape_mesh(name: str):
    """The built-in mesh ``name`` (one of :data:`SHAPES`), a closed ``trimesh.Trimesh``, outward."""
    if name not in SHAPES:
        raise ValueError(f"no built-in mesh {name!r}; the built-ins: {', '.join(SHAPES)}.")
    return SHAPES[name]()
