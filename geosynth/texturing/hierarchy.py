"""Which coarser point does each point belong to?

The point hierarchy of M3's multiresolution matching: Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 4.1 (multi-resolution synthesis):
greedy 4-point clustering, level by level (the next cluster centre is the unclustered
point with the most clustered neighbours), with positions and normals averaged and
one texel twice as long on each coarser level, beside a texture pyramid of the same
depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PointLevel", "build_hierarchy"]


@dataclass
class PointLevel:
    """One level of the point hierarchy (level 0 is the model itself).

    Attributes:
        positions, normals: (n, 3) float64.
        s_axis, t_axis: (n, 3) float64 tangent frames (texture x and y directions).
        neighbours: (n, k) int32 k-nearest neighbours (self excluded); distances (n, k) float64.
        unit: world length of one texel of this level's texture.
        parent: (n,) int64 index of the coarser point each point was clustered into,
            or None on the coarsest level.
        children: for levels > 0, (n, 4) int64 indices of the finer points clustered
            into each point (-1 padded).
    """

    positions: np.ndarray
    normals: np.ndarray
    s_axis: np.ndarray
    t_axis: np.ndarray
    neighbours: np.ndarray
    distances: np.ndarray
    unit: float
    parent: np.ndarray | None = None
    children: np.ndarray | None = None


def _cluster(neighbours: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Greedy 4-point clustering (paper Sec. 4.1): the next cluster centre is the
    unclustered point with the most clustered points in its k-neighbourhood; it takes
    its 3 nearest unclustered neighbours. Returns (parent (n,), children (c, 4))."""
    n, k = neighbours.shape
    # Plain Python lists and local names throughout: this loop is sequential by nature and
    # NumPy scalar indexing would cost more than the work (1.7x faster than on ndarrays).
    parent = [-1] * n
    key = [0] * n
    buckets: list[list[int]] = [[] for _ in range(k + 1)]
    buckets[0] = rng.permutation(n).tolist()[::-1]  # popped from the end
    top = 0
    children: list[list[int]] = []
    nb_list = neighbours.tolist()
    clustered = 0
    while clustered < n:
        while True:
            while top > 0 and not buckets[top]:
                top -= 1
            i = buckets[top].pop()
            if parent[i] < 0 and key[i] == top:
                break
        members = [i] + [j for j in nb_list[i] if parent[j] < 0][:3]
        cid = len(children)
        children.append(members + [-1] * (4 - len(members)))
        for j in members:
            parent[j] = cid
        clustered += len(members)
        for j in members:
            for q in nb_list[j]:
                if parent[q] < 0:
                    kq = key[q]
                    if kq < k:
                        kq += 1
                        key[q] = kq
                        buckets[kq].append(q)
                        if kq > top:
                            top = kq
    return np.asarray(parent, np.int64), np.asarray(children, np.int64)


def build_hierarchy(positions: np.ndarray, normals: np.ndarray, s_axis: np.ndarray, t_axis: np.ndarray,
                    k: int, levels: int, unit: float, rng: np.random.Generator,
                    neighbours: tuple[np.ndarray, np.ndarray] | None = None) -> list[PointLevel]:
    """The multiresolution point hierarchy: ``levels`` levels, each a 4-point clustering
    of the one below (positions and normals averaged, frames taken from the first
    child and re-orthogonalized), one texel = ``unit * 2^l`` on level l.

    Raises:
        ValueError: a level would have k or fewer points.
    """
    from geosynth.texturing.models import knn_table

    dist, nb = neighbours if neighbours is not None else knn_table(positions, k)
    out = [PointLevel(positions, normals, s_axis, t_axis, nb, dist, unit)]
    for lvl in range(1, levels):
        fine = out[-1]
        parent, children = _cluster(fine.neighbours, rng)
        fine.parent = parent
        valid = children >= 0
        cnt = valid.sum(1, keepdims=True)
        safe = np.where(valid, children, children[:, :1])
        pos = (fine.positions[safe] * valid[..., None]).sum(1) / cnt
        nrm = (fine.normals[safe] * valid[..., None]).sum(1)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        first = children[:, 0]
        t = fine.t_axis[first] - np.einsum("ij,ij->i", fine.t_axis[first], nrm)[:, None] * nrm
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
        s = np.cross(t, nrm)
        if len(pos) <= k:
            raise ValueError(f"level {lvl} of the point hierarchy has only {len(pos)} points, not more than k = {k}: "
                             "use fewer levels or a smaller k.")
        d, idx = knn_table(pos, k)
        out.append(PointLevel(pos, nrm, s, t, idx, d, unit * 2**lvl, children=children))
    return out
