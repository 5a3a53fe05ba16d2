"""What must the distance kernels return? Implements no paper section: plain NumPy oracles of
the mesh distance (:func:`geosynth.mesh_distance`) and of the point-set MLS distance
(:func:`geosynth.pointset_distance`).

These oracles are slow, obvious and never on a production path. Each takes the same arguments
as the operation it checks and returns the same result; float sums are accumulated in float64,
uint8 sums in exact integers.
"""

from __future__ import annotations

import numpy as np


def _closest_point_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points on triangles (a, b, c) (each (..., 3)) to points p (..., 3),
    Ericson's Voronoi-region test, vectorized; float64."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        out = a + ab * v[..., None] + ac * w[..., None]  # interior
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        t_ac = d2 / (d2 - d6)
        t_ab = d1 / (d1 - d3)
    # regions, assigned from the last to the first so that the first test wins
    cases = [
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[..., None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[..., None]),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[..., None]),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d1 <= 0) & (d2 <= 0), a),
    ]
    for mask, value in cases:
        out = np.where(mask[..., None], np.broadcast_to(value, out.shape), out)
    return out


def mesh_unsigned_distance_naive(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact distance from each point to the closest of all triangles, brute force
    (vectorized over faces), float64."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    pts = np.asarray(points, np.float64)
    out = np.empty(len(pts))
    for i, p in enumerate(pts):
        q = _closest_point_triangles(p[None, :], a, b, c)
        out[i] = np.sqrt(((q - p) ** 2).sum(-1).min())
    return out


def winding_number_naive(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact generalized winding number (Jacobson et al. 2013) at each point: the sum of
    the triangles' signed solid angles (van Oosterom-Strackee) over 4 pi, float64."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    pts = np.asarray(points, np.float64)
    out = np.empty(len(pts))
    for i, p in enumerate(pts):
        a, b, c = tri[:, 0] - p, tri[:, 1] - p, tri[:, 2] - p
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = la * lb * lc + (a * b).sum(1) * lc + (a * c).sum(1) * lb + (b * c).sum(1) * la
        out[i] = 2.0 * np.arctan2(det, den).sum() / (4.0 * np.pi)
    return out


def mesh_distance_naive(mesh, points: np.ndarray, *, signed: bool = True, band: float | None = None, sign: str = "winding") -> np.ndarray:
    """Same arguments and result as :func:`geosynth.geometry.distance.mesh_distance` with points
    (float64 here): brute-force distance; the sign from the exact winding number
    (``sign="winding"``) or from ``mesh.contains`` (``sign="contains"``, watertight meshes)."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    d = mesh_unsigned_distance_naive(v, f, points)
    if signed:
        if sign == "contains":
            inside = mesh.contains(np.asarray(points, np.float64))
        else:
            inside = winding_number_naive(v, f, points) > 0.5
        d = np.where(inside, -d, d)
    if band is not None:
        d = np.clip(d, -band, band)
    return d



# ------------------------------------------------------------- point-set (MLS) oracles


def mls_project_naive(
    points: np.ndarray, normals: np.ndarray, query: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The MLS projection of :mod:`geosynth.geometry.pointsets`, brute force over all points.

    Same definitions as :func:`geosynth.geometry.pointsets.pointset_distance` (Gaussian width
    ``radius``, cut off at MLS_REACH * radius, projection y <- y - f(y) n(y) until
    |f| <= MLS_TOL * radius or MLS_MAX_ITER steps), one query at a time, in float64.

    Returns:
        (distance (M,), gradient (M, 3), projection (M, 3)), float64.
    """
    from geosynth.geometry.pointsets import MLS_MAX_ITER, MLS_REACH, MLS_TOL

    p = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    q = np.asarray(query, np.float64).reshape(-1, 3)
    h = float(radius)
    reach = MLS_REACH * h
    dist = np.full(len(q), reach)
    grad = np.zeros((len(q), 3))
    proj = q.copy()
    for j, x in enumerate(q):
        y = x.copy()
        f0 = None
        for _ in range(MLS_MAX_ITER):
            d2 = ((p - y) ** 2).sum(axis=1)
            inside = d2 < reach * reach
            w = np.where(inside, np.exp(-d2 / (h * h)), 0.0)
            ws = w.sum()
            msum = w @ nrm
            if not ws > 0 or not msum @ msum > 0:
                break
            n = msum / np.linalg.norm(msum)
            a = w @ p / ws
            f = n @ (y - a)
            if f0 is None:
                f0 = f
            grad[j] = n
            proj[j] = y - f * n
            if abs(f) <= MLS_TOL * h:
                break
            y = proj[j].copy()
        if f0 is not None:
            d = min(np.linalg.norm(x - proj[j]), reach)
            dist[j] = -d if f0 < 0 else d
    return dist, grad, proj


def pointset_distance_naive(points: np.ndarray, normals: np.ndarray, query: np.ndarray, radius: float):
    """Same arguments (query form, explicit radius) and result as
    :func:`geosynth.geometry.pointsets.pointset_distance`, from :func:`mls_project_naive`."""
    dist, grad, _ = mls_project_naive(points, normals, query, radius)
    return dist, grad
