"""Which way is "along" on the surface? The tangent field the example's rows follow (issue 34,
item 2: orientation from a tangent field, so that a ridged example wraps a cylinder as a knurl would).

- ``"axis"``: a body of revolution (found by :func:`revolution_axis`): the example's y runs along
  the meridians (the axis projected onto the tangent plane), its x around the axis; on caps facing
  along the axis, a fixed direction across it.
- ``"principal"``: anything else: the direction of least absolute normal curvature (along a tube,
  along a ridge) from a quadric fitted to each vertex's edge neighbours, smoothed as a line field
  (neighbours' directions flipped to agree before averaging) over 12 passes weighted by how
  anisotropic the curvature is, so that umbilic regions (a sphere) take their neighbours' direction.
  The sign is not consistent (a line field): the synthesis tries 2 rotations (0 and 180 degrees).

:func:`tangent_frames` returns (V, 3, 3) rows u (example x), v (example y), n, with v = n x u as the
M4 kernels' frames (:func:`geosynth.completion.matching.paper_frames`) have them.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FIELDS", "revolution_axis", "tangent_frames"]

FIELDS = ("auto", "axis", "principal")
_REVOLUTION_SPREAD = 0.03  # median relative spread of the radius in height slices: a body of revolution


def _pca(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = v.mean(0)
    w, vec = np.linalg.eigh(np.cov((v - c).T))
    return c, vec.T[::-1]  # rows: largest variance first


def revolution_axis(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(centre (3,), unit axis (3,), spread) when the vertices lie on a body of revolution about one of
    their principal axes (in 32 slices along the axis, the median over slices of std(radius) /
    mean(radius) is under 3%), else None. The axis with the smallest spread wins; its sign makes
    its largest component positive."""
    v = np.asarray(vertices, np.float64)
    c, axes = _pca(v)
    best = None
    for a in axes:
        z = (v - c) @ a
        r = np.linalg.norm((v - c) - np.outer(z, a), axis=1)
        edges = np.linspace(z.min(), z.max(), 33)
        k = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, 31)
        spreads = []
        for s in range(32):
            rr = r[k == s]
            if len(rr) >= 8 and rr.mean() > 0:
                spreads.append(rr.std() / rr.mean())
        if len(spreads) < 8:
            continue
        spread = float(np.median(spreads))
        if best is None or spread < best[2]:
            best = (c, a * (1 if a[np.argmax(np.abs(a))] > 0 else -1), spread)
    return best if best is not None and best[2] < _REVOLUTION_SPREAD else None


def _least_curvature(v: np.ndarray, n: np.ndarray, adj) -> tuple[np.ndarray, np.ndarray]:
    """((V, 3) unit tangent of least |normal curvature|, (V,) anisotropy | |k1| - |k2| | / (|k1| + |k2|))
    from a least-squares quadric z = a x^2 + 2 b x y + c y^2 over each vertex's edge neighbours."""
    from geosynth.completion.matching import paper_frames

    indptr, indices = adj
    own = np.repeat(np.arange(len(v)), np.diff(indptr))
    f = paper_frames(n)
    d = v[indices] - v[own]
    x = np.einsum("ij,ij->i", d, f[own, 0])
    y = np.einsum("ij,ij->i", d, f[own, 1])
    z = np.einsum("ij,ij->i", d, f[own, 2])
    rows = np.stack([x * x, 2 * x * y, y * y], 1)
    ata = np.zeros((len(v), 3, 3))
    atb = np.zeros((len(v), 3))
    np.add.at(ata, own, rows[:, :, None] * rows[:, None, :])
    np.add.at(atb, own, rows * z[:, None])
    ata += np.eye(3) * 1e-12 * np.trace(ata, axis1=1, axis2=2)[:, None, None].clip(1e-300)
    coef = np.linalg.solve(ata, atb[:, :, None])[:, :, 0]
    a, b, c = coef[:, 0], coef[:, 1], coef[:, 2]
    # eigenvectors of [[a, b], [b, c]]: angles theta and theta + 90 degrees
    theta = 0.5 * np.arctan2(2 * b, a - c)
    k1 = a * np.cos(theta) ** 2 + 2 * b * np.sin(theta) * np.cos(theta) + c * np.sin(theta) ** 2
    k2 = a + c - k1
    least = np.where(np.abs(k1) <= np.abs(k2), theta, theta + np.pi / 2)
    t = np.cos(least)[:, None] * f[:, 0] + np.sin(least)[:, None] * f[:, 1]
    aniso = np.abs(np.abs(k1) - np.abs(k2)) / np.maximum(np.abs(k1) + np.abs(k2), 1e-300)
    return t, aniso


def _project_unit(t: np.ndarray, n: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    t = t - np.einsum("ij,ij->i", t, n)[:, None] * n
    length = np.linalg.norm(t, axis=1)
    bad = length < 1e-9
    t[bad] = fallback[bad]
    length[bad] = 1.0
    return t / length[:, None]


def tangent_frames(vertices: np.ndarray, normals: np.ndarray, adj, field: str = "auto"
                   ) -> tuple[np.ndarray, str, int]:
    """The frames the example is laid along.

    Args:
        vertices: (V, 3) float64; normals: (V, 3) unit float64 (the smoothed normals);
        adj: the CSR (indptr, indices) of the mesh's edges.
        field: "auto" (the axis of a body of revolution when :func:`revolution_axis` finds one,
            else principal directions), "axis" or "principal".

    Returns:
        ((V, 3, 3) float64 frames, rows u, v, n; a one-line description; the rotations the
        synthesis should try: 1 for the axis field, 2 for the principal line field).

    Raises:
        ValueError: an unknown field; "axis" on a mesh that is no body of revolution.
    """
    from geosynth.completion.matching import paper_frames

    if field not in FIELDS:
        raise ValueError(f"field must be one of {', '.join(FIELDS)}, got {field!r}.")
    v = np.asarray(vertices, np.float64)
    n = np.asarray(normals, np.float64)
    fallback = paper_frames(n)[:, 0]
    rev = revolution_axis(v) if field in ("auto", "axis") else None
    if field == "axis" and rev is None:
        raise ValueError("field 'axis' needs a body of revolution (its radius a function of the height along "
                         "a principal axis, within 3%); this mesh is not one: use 'principal' or 'auto'.")
    if rev is not None:
        centre, axis, spread = rev
        # across the axis on the caps: the principal axis of largest spread perpendicular to it
        across = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        along = np.where((np.abs(n @ axis) > 0.95)[:, None], across[None, :], axis[None, :])
        vdir = _project_unit(np.broadcast_to(along, n.shape).copy(), n, fallback)
        u = np.cross(vdir, n)  # so that n x u = v
        how = (f"tangent field: the axis of a body of revolution (through {np.round(centre, 4).tolist()}, direction "
               f"{np.round(axis, 4).tolist()}, radius spread {100 * spread:.1f}%): example y along the meridians, "
               f"x around")
        return np.stack([u, vdir, n], 1), how, 1
    from scipy import sparse

    t, aniso = _least_curvature(v, n, adj)
    indptr, indices = adj
    a = sparse.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(len(v), len(v)))
    own = np.repeat(np.arange(len(v)), np.diff(indptr))
    w = aniso.copy()
    for _ in range(12):
        # line field: each neighbour's direction flipped to agree with the vertex's own
        sign = np.sign(np.einsum("ij,ij->i", t[indices], t[own]))
        sign[sign == 0] = 1.0
        contrib = (sign * w[indices])[:, None] * t[indices]
        acc = np.zeros_like(t)
        np.add.at(acc, own, contrib)
        acc += w[:, None] * t
        t = _project_unit(acc, n, t)
        w = np.maximum(w, 0.5 * (a @ w) / np.maximum(np.diff(indptr), 1))  # confidence spreads to umbilic parts
    u = t
    vdir = np.cross(n, u)
    how = ("tangent field: smoothed principal directions (least |curvature|, 12 line-field passes): example x "
           "along the least curved direction, tried at 0 and 180 degrees")
    return np.stack([u, vdir, n], 1), how, 2
