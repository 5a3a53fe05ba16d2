"""Which point models can be textured, and which are each point's k nearest neighbours? The
inputs and neighbourhoods of Zhang, Qiu and Kaufman, "Fast Hybrid Approach for Texturing
Point Models", Sec. 4 and 6.

Point models for M3: built-in shapes sampled as oriented point sets, points sampled
from any mesh, loading from files, and k-nearest-neighbour tables.

Built-ins (any count; the paper's models have 16k-76k points):

- ``sphere``: the unit sphere.
- ``torus``: major radius 1, minor radius 0.4, around the z axis.
- ``blob``: a closed star-shaped surface ``r(u) = 1 + sum a_i exp((u . c_i - 1) / s_i^2)``
  over directions u, with bumps (a_i > 0) and dents (a_i < 0: concave parts).

Points are drawn with density proportional to area, then spread by a few rounds of
repulsion from their nearest neighbours and put back on the surface, so that the
spacing is nearly even (as in the scanned models of the paper). Normals are exact.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

from geosynth.core.config import passive_openmp_threads
from geosynth.core.memory import available_memory, require
from geosynth.geometry.pointsets import PointSet, estimate_normals, read_geometry

__all__ = [
    "POINT_MODELS", "PointModelExample", "knn_table", "load_point_model", "passive_openmp_threads", "point_model",
    "sample_mesh_points", "spatial_order",
]

RELAX_ROUNDS = 4  # repulsion rounds: enough to remove the clumps of random sampling
RELAX_NEIGHBOURS = 6


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


# ------------------------------------------------------------------ shapes: sample, project, normal


class _Sphere:
    def sample(self, rng, n):
        return _unit(rng.standard_normal((n, 3)))

    def project(self, p):
        return _unit(p)

    def normal(self, p):
        return _unit(p)


class _Torus:
    def __init__(self, major: float = 1.0, minor: float = 0.4):
        self.R, self.r = major, minor

    def sample(self, rng, n):
        out = []
        while sum(len(o) for o in out) < n:  # area element ~ (R + r cos phi): rejection
            theta = rng.uniform(0, 2 * np.pi, 2 * n)
            phi = rng.uniform(0, 2 * np.pi, 2 * n)
            keep = rng.uniform(0, self.R + self.r, 2 * n) < self.R + self.r * np.cos(phi)
            out.append(self._point(theta[keep], phi[keep]))
        return np.concatenate(out)[:n]

    def _point(self, theta, phi):
        ring = self.R + self.r * np.cos(phi)
        return np.stack([ring * np.cos(theta), ring * np.sin(theta), self.r * np.sin(phi)], 1)

    def _centre(self, p):
        d = p[:, :2]
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        return np.c_[self.R * d, np.zeros(len(p))]

    def project(self, p):
        c = self._centre(p)
        return c + self.r * _unit(p - c)

    def normal(self, p):
        return _unit(p - self._centre(p))


class _Blob:
    """Star-shaped: x = r(u) u for unit directions u."""

    def __init__(self, seed: int = 7, bumps: int = 14):
        rng = np.random.default_rng(seed)
        self.c = _unit(rng.standard_normal((bumps, 3)))
        self.a = rng.uniform(0.15, 0.35, bumps) * np.where(np.arange(bumps) % 2 == 0, -1.0, 1.0)  # every other a dent
        self.s = rng.uniform(0.35, 0.6, bumps)

    def radius(self, u):
        return 1.0 + np.exp((u @ self.c.T - 1.0) / self.s**2) @ self.a

    def sample(self, rng, n):
        out = []
        while sum(len(o) for o in out) < n:  # density ~ area element r^2 / cos(normal, radial): rejection
            u = _unit(rng.standard_normal((3 * n, 3)))
            x = self.radius(u)[:, None] * u
            cos = np.abs(np.einsum("ij,ij->i", self.normal(x), u))
            area = self.radius(u) ** 2 / np.maximum(cos, 0.2)
            keep = rng.uniform(0, 1, len(u)) * 3.0 < area
            out.append(x[keep])
        return np.concatenate(out)[:n]

    def project(self, p):
        u = _unit(p)
        return self.radius(u)[:, None] * u

    def normal(self, p):
        # gradient of F(x) = |x| - r(x / |x|), by central differences
        h = 1e-5
        g = np.empty_like(p)
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            fp = np.linalg.norm(p + e, axis=1) - self.radius(_unit(p + e))
            fm = np.linalg.norm(p - e, axis=1) - self.radius(_unit(p - e))
            g[:, i] = (fp - fm) / (2 * h)
        return _unit(g)


def _relax(shape, p: np.ndarray, rounds: int = RELAX_ROUNDS) -> np.ndarray:
    """Spread points by repulsion from their nearest neighbours, projected back each round."""
    from geosynth.core.neighbours import nearest

    for _ in range(rounds):
        d, idx = nearest(p, k=RELAX_NEIGHBOURS)
        h = 1.5 * float(np.mean(d[:, 0]))  # repulsion reach
        away = p[:, None, :] - p[idx]
        w = np.clip(1 - d / h, 0, None) ** 2
        step = (away / np.maximum(d, 1e-12)[..., None] * w[..., None]).sum(1)
        p = shape.project(p + 0.25 * h * step)
    return p


@dataclass(frozen=True)
class PointModelExample:
    """A built-in point model: its name, a one-line summary and its shape."""

    name: str
    summary: str
    shape: Callable[[], object]
    bytes_per_point: int = 1200  # peak bytes per point of point_model (see POINT_MODELS)


# bytes_per_point: the peak RSS high-water delta per point measured at 50k and 200k points
# (sphere 896, torus 873-875, blob 1158-1160; tracemalloc sees 640 / 640 / 1033 of it, the
# rest is scipy's cKDTree): the relaxation's (n, 6, 3) float64 neighbour differences and
# their weighted sums, the kNN answers, the tree, and the blob's finite-difference normals.
POINT_MODELS: dict[str, PointModelExample] = {
    "sphere": PointModelExample("sphere", "the unit sphere", _Sphere, 900),
    "torus": PointModelExample("torus", "a torus, radii 1 and 0.4", _Torus, 900),
    "blob": PointModelExample("blob", "a bumpy closed blob with dents (concave parts), radius about 1", _Blob, 1160),
}
_MESH_SAMPLE_BYTES = 190  # peak bytes per point of sample_mesh_points (RSS, 50k and 200k points: 188-189)
_MESH_FACE_BYTES = 64  # and per face (trimesh's area weights, their cumulative sum, the face choice)


def point_model(name: str, count: int = 20_000, seed: int = 0) -> PointSet:
    """A built-in point model: ``count`` nearly evenly spaced points with exact unit normals.

    Args:
        name: ``sphere``, ``torus`` or ``blob``.
        count: number of points, >= 16.
        seed: seed of the sampling.

    Returns:
        PointSet with positions and normals (no colours).

    Raises:
        ValueError: an unknown name or count < 16.
        MemoryBudgetError: ``count`` points would not fit in memory (option ``"count"``),
            refused before sampling.

    Example:
        >>> len(point_model("sphere", 1000))
        1000
    """
    if name not in POINT_MODELS:
        raise ValueError(f"unknown point model {name!r}; the built-in models are: {', '.join(POINT_MODELS)}.")
    if not isinstance(count, (int, np.integer)) or count < 16:
        raise ValueError(f"count must be an integer >= 16, got {count!r}.")
    per_point = POINT_MODELS[name].bytes_per_point
    avail = available_memory()
    require(per_point * int(count), option="count", value=count, available=avail,
            largest=avail // per_point if avail >= 16 * per_point else None,
            what=f"{int(count):,} points of the {name} model")
    shape = POINT_MODELS[name].shape()
    rng = np.random.default_rng(seed)
    p = _relax(shape, shape.sample(rng, int(count)))
    return PointSet(p.astype(np.float32), shape.normal(p).astype(np.float32))


def sample_mesh_points(mesh, count: int, seed: int = 0) -> PointSet:
    """Points sampled uniformly by area on a mesh, with the normals of their faces.

    Args:
        mesh: a ``trimesh.Trimesh`` (or a mesh file, read with
            :func:`geosynth.geometry.meshes.load_mesh`).
        count: number of points, >= 16.
        seed: seed of the sampling.

    Returns:
        PointSet with (count, 3) float32 positions and unit normals.

    Raises:
        ValueError: no faces, faces of zero total area, count < 16.
        MemoryBudgetError: ``count`` points would not fit in memory (option ``"count"``).
    """
    import trimesh

    if isinstance(mesh, (str, os.PathLike)):
        from geosynth.geometry.meshes import load_mesh

        mesh = load_mesh(mesh)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("mesh must be a trimesh.Trimesh with faces (or a mesh file).")
    if not isinstance(count, (int, np.integer)) or count < 16:
        raise ValueError(f"count must be an integer >= 16, got {count!r}.")
    if not float(mesh.area) > 0:
        raise ValueError(f"the mesh's {len(mesh.faces)} faces have zero total area: there is no surface to sample.")
    faces_part = _MESH_FACE_BYTES * len(mesh.faces)
    avail = available_memory()
    fits = (avail - faces_part) // _MESH_SAMPLE_BYTES
    require(_MESH_SAMPLE_BYTES * int(count) + faces_part, option="count", value=count, available=avail,
            largest=fits if fits >= 16 else None,
            what=f"{int(count):,} points sampled from a {len(mesh.faces):,}-face mesh")
    points, face = trimesh.sample.sample_surface(mesh, int(count), seed=seed)
    return PointSet(np.asarray(points, np.float32), np.asarray(mesh.face_normals[face], np.float32))


def load_point_model(path: str | os.PathLike, count: int = 30_000, seed: int = 0, k_normals: int = 16) -> PointSet:
    """A point model from a file: a point set as it is, or points sampled from a mesh.

    The file is read with :func:`geosynth.geometry.pointsets.read_geometry`: one with faces is a
    mesh and is sampled (``count`` points), one without is a point set. Missing normals
    are estimated (PCA over ``k_normals`` neighbours, oriented consistently).

    Returns:
        PointSet with positions and normals (and the file's colours, if any).

    Raises:
        FileNotFoundError, ValueError: see :func:`~geosynth.geometry.pointsets.read_geometry`;
            also too few points to estimate normals from.
        MemoryBudgetError: sampling ``count`` points from a mesh would not fit in memory
            (option ``"count"``; see :func:`sample_mesh_points`).
    """
    geom = read_geometry(path)
    if not isinstance(geom, PointSet):
        return sample_mesh_points(geom, count, seed)
    ps = geom
    if ps.normals is None:
        if len(ps) < max(3, k_normals):
            raise ValueError(f"{str(path)!r} has no normals and only {len(ps)} points: estimating normals needs at "
                             f"least {max(3, k_normals)} neighbours; give normals in the file or more points.")
        ps.normals = estimate_normals(ps.positions, k=k_normals)
    return ps


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """uint64 values below 2^21 with two zero bits inserted after every bit."""
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    return (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)


def spatial_order(positions: np.ndarray) -> np.ndarray:
    """A permutation that puts nearby points near each other in memory: the Morton (Z)
    order of the points on a grid of up to 2^14 cells per side over their bounding box,
    ties by index.

    The sequential kernels and the kNN query read every point's neighbours; in this order
    those reads mostly hit the cache (measured on the M3 models: kNN 1.2-1.35x, the growth
    1.05-1.15x faster than in the models' random sampling order).

    Args:
        positions: (N, 3) finite positions.

    Returns:
        (N,) int64 permutation.
    """
    p = np.asarray(positions, np.float64)
    index_bits = max(1, int(len(p) - 1).bit_length())
    bits = min(14, (64 - index_bits) // 3)  # the code and the index share one uint64: unique keys
    columns = np.ascontiguousarray(p.T)  # (3, N): NumPy reduces (N, 3) along axis 0 5x slower
    lo, hi = columns.min(1), columns.max(1)
    q = ((p - lo) * ((2**bits - 1) / np.maximum(hi - lo, 1e-300))).astype(np.uint64)
    code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << np.uint64(1)) | (_spread_bits(q[:, 2]) << np.uint64(2))
    key = (code << np.uint64(index_bits)) | np.arange(len(p), dtype=np.uint64)
    return np.argsort(key)  # unique keys: any sort algorithm gives this order


def knn_table(positions: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest neighbours of every point (itself excluded;
    :func:`geosynth.core.neighbours.nearest`).

    Args:
        positions: (N, 3) float positions, N > k.
        k: neighbours per point.

    Returns:
        (distances (N, k) float64 (possibly a view), indices (N, k) int32 (the kernels'
        index type; N < 2^31)), nearest first, ties by lower index.
    """
    from geosynth.core.neighbours import nearest

    d, idx = nearest(positions, k=k)
    return d, idx.astype(np.int32)
