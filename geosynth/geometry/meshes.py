"""Is this mesh usable, and how far is each grid point from it? The source distance field of
Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 3 (system overview).

Meshes: loading, checking, orienting, and the signed distance of a mesh.

The host half of the mesh distance-field family (kernels/sdf_mesh.*): the input
checks, a consistent face orientation, and the bounding volume hierarchy (BVH) that
both backends traverse, built once per mesh in NumPy and cached. The public function
is :func:`mesh_distance` (re-exported by :mod:`geosynth.geometry.distance`).
"""

from __future__ import annotations

import hashlib
import math
import os
from collections import OrderedDict
from dataclasses import dataclass, field as dc_field

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.core.memory import require
from geosynth.geometry.field import Field, cubic_grid_geometry
from geosynth.io import readers as _readers
from geosynth.io.files import check_input

__all__ = ["MeshBVH", "build_bvh", "check_mesh", "load_mesh", "mesh_distance", "orient_faces"]

# Far-field criterion of the fast winding number: a node whose dipole centre is more
# than BETA times its radius away is summed as one dipole (Barill et al. use 2).
BETA = 2.0
LEAF_SIZE = 4  # triangles per BVH leaf, at most
STACK_SIZE = 64  # traversal stack of the kernels (kernels/sdf_mesh.*); the build keeps depth below it
# Grid points processed in a row by one work-item; each seeds its search with the
# previous point's closest triangle (an upper bound: the result stays exact).
GRID_RUN = 8
# A face is degenerate when twice its area is below this fraction of the squared
# bounding-box diagonal (zero-area faces, collinear or repeated corners).
_DEGENERATE_REL = 1e-12
# The closest-point searches of every kernel use boxes grown by this fraction of the
# mesh's bounding-box diagonal (MeshBVH.sbox): far beyond the rounding of the float32
# box and triangle distances, so no node that holds the minimum is ever pruned and the
# result is the same minimum on every device, whatever the visiting order.
BOX_SLACK = 2.0**-12
# mesh_distance works in units where the mesh's bounding-box diagonal lies in [1/2, 1):
# every coordinate is scaled by a power of two (exact in floating point), so that only
# the ratio of sizes matters: the same float32 bits, scaled back, at any scale, where
# tiny or huge meshes underflowed or overflowed float32 (a plate of 4e-6 had the
# squared plane distances of its small faces flush to 0, which erased their sign).
# Queries farther than FAR_LIMIT diagonals from the mesh are refused: their squared
# distance leaves float32.
FAR_LIMIT = 2.0**60


# ------------------------------------------------------------------ input


def load_mesh(path: str | os.PathLike):
    """Read a triangle mesh: PLY through plyfile, OBJ, STL, OFF, GLB and GLTF through
    trimesh without processing (nothing merged or dropped before the checks here).

    Scenes with several meshes are concatenated (their transforms applied); PLY polygons
    are split into triangle fans. The file is noted as an input
    (:func:`geosynth.io.files.note_input`): no writer of this process replaces it.

    Args:
        path: the file.

    Returns:
        A ``trimesh.Trimesh`` (float64 vertices, int64 faces), vertices as the file has them.

    Raises:
        FileNotFoundError: ``"mesh file 'X' does not exist."``
        ValueError: one line naming the file: a folder, an empty file, another
            extension, an unreadable file (``"'X' is not a readable OBJ file: <reason>;
            ..."``), no faces, NaN/inf vertices (``"'X' has 1 vertex with NaN or inf
            coordinates (the first: index 5, counting from 0); ..."``), face indices out
            of range.
    """
    p = check_input(path, "mesh")
    return _readers.checked_mesh(p, _readers.read_any(p))


def _as_trimesh(mesh, name: str):
    import trimesh

    if isinstance(mesh, (str, os.PathLike)):
        return load_mesh(mesh)
    if isinstance(mesh, trimesh.Trimesh):
        return mesh
    raise TypeError(f"{name} must be a trimesh.Trimesh or a path to a mesh file, got {type(mesh).__name__}.")


def check_mesh(mesh, name: str = "mesh", *, drop_degenerate: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Check a triangle mesh and return its arrays.

    Args:
        mesh: a ``trimesh.Trimesh`` (or a path, read with :func:`load_mesh`).
        name: the argument name used in error messages.
        drop_degenerate: remove zero-area faces instead of refusing them.

    Returns:
        ``(vertices, faces)``: (V, 3) float32 and (F, 3) int32.

    Raises:
        TypeError: not a mesh.
        ValueError: no faces, NaN/inf vertices, face indices out of range, or
            degenerate (zero-area) faces when ``drop_degenerate`` is False.
    """
    v, f = _checked_arrays(mesh, name, drop_degenerate)
    return v.astype(np.float32), f


def _checked_arrays(mesh, name: str, drop_degenerate: bool) -> tuple[np.ndarray, np.ndarray]:
    """:func:`check_mesh`'s checks; (V, 3) float64 vertices and (F, 3) int32 faces."""
    m = _as_trimesh(mesh, name)
    v = np.asarray(m.vertices, dtype=np.float64)
    f = np.asarray(m.faces)
    if f.ndim != 2 or f.shape[0] == 0 or f.shape[1] != 3:
        raise ValueError(f"{name} is empty: it has no triangle faces (faces shape {f.shape}).")
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise ValueError(f"{name} vertices must have shape (V, 3), got {v.shape}.")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise ValueError(f"{name} has {int(bad.sum())} vertices with NaN or inf coordinates; every vertex must be finite.")
    if f.dtype.kind not in "iu":
        raise TypeError(f"{name} faces must be integer indices, got dtype {f.dtype}.")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ValueError(
            f"{name} has face indices out of range [0, {v.shape[0]}): min {int(f.min())}, max {int(f.max())}."
        )
    if v.shape[0] >= 2**31 or f.shape[0] >= 2**27:
        raise ValueError(f"{name} is too large ({v.shape[0]} vertices, {f.shape[0]} faces); split it.")
    tri = v[f]
    twice_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    diag2 = float(((v.max(0) - v.min(0)) ** 2).sum())
    degenerate = twice_area <= _DEGENERATE_REL * diag2
    if degenerate.any():
        if not drop_degenerate:
            raise ValueError(
                f"{name} has {int(degenerate.sum())} degenerate (zero-area) face(s) of {f.shape[0]}; "
                "remove them (e.g. mesh.update_faces(mesh.nondegenerate_faces())) or pass drop_degenerate=True."
            )
        f = f[~degenerate]
        if f.shape[0] == 0:
            raise ValueError(f"{name} is empty: every one of its faces is degenerate (zero area).")
    return v, np.ascontiguousarray(f, dtype=np.int32)


# ------------------------------------------------------------------ orientation


def orient_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces with a consistent orientation, outward on closed parts.

    Faces that share an edge (vertices merged by exact position) must traverse it in
    opposite directions. Within each edge-connected patch the orientation held by
    the majority of its faces (by area) wins, so a patch with a few flipped faces is
    repaired and an open sheet keeps the orientation it was given. A patch whose
    signed volume is clearly negative (an inside-out closed part) is then flipped.
    Non-manifold edges (shared by more than two faces) do not propagate orientation.

    Args:
        vertices: (V, 3) float array.
        faces: (F, 3) int array.

    Returns:
        (F, 3) int32 faces, some with their winding reversed.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    n_f = f.shape[0]
    # merge vertices by exact position so that split seams still connect
    _, vid = np.unique(v, axis=0, return_inverse=True)
    fv = vid.reshape(-1)[f]
    a = fv.reshape(-1)
    b = fv[:, [1, 2, 0]].reshape(-1)
    fid = np.repeat(np.arange(n_f), 3)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    same_dir = a < b  # direction of the face's edge relative to (lo, hi)
    key = lo * (int(vid.max()) + 1) + hi
    order = np.argsort(key, kind="stable")
    key_s = key[order]
    starts = np.flatnonzero(np.r_[True, key_s[1:] != key_s[:-1]])
    counts = np.diff(np.r_[starts, key_s.size])
    pair = starts[counts == 2]  # manifold interior edges
    e0, e1 = order[pair], order[pair + 1]
    f0, f1 = fid[e0], fid[e1]
    # consistent neighbours traverse the shared edge in opposite directions
    must_flip_rel = same_dir[e0] == same_dir[e1]  # True: one of the two is flipped relative to the other
    flip = np.zeros(n_f, bool)
    if not must_flip_rel.any():
        comp = _components(n_f, f0, f1)
    else:
        comp, flip = _propagate(n_f, f0, f1, must_flip_rel)
        tri = v[f]
        area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        # majority by area within each patch: flip the propagated labels if most area disagrees
        flipped_area = np.bincount(comp, weights=area * flip)
        total_area = np.bincount(comp, weights=area)
        invert = flipped_area > 0.5 * total_area
        flip ^= invert[comp]
    out = f.copy()
    out[flip] = out[flip][:, ::-1]
    # inside-out closed parts: signed volume about the patch centroid
    tri = v[out]
    n_c = int(comp.max()) + 1
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    wsum = np.maximum(np.bincount(comp, weights=area2, minlength=n_c), 1e-300)
    centre = np.stack([np.bincount(comp, weights=area2 * tri[:, :, k].mean(1), minlength=n_c) for k in range(3)], 1) / wsum[:, None]
    rel = tri - centre[comp][:, None, :]
    vol = np.bincount(comp, weights=np.einsum("ij,ij->i", rel[:, 0], np.cross(rel[:, 1], rel[:, 2])) / 6.0, minlength=n_c)
    # open sheets have a volume near zero about their centroid: compare with area^1.5
    inside_out = vol < -1e-3 * wsum**1.5
    if inside_out.any():
        sel = inside_out[comp]
        out[sel] = out[sel][:, ::-1]
    return out.astype(np.int32)


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected-component labels (int64) of n nodes joined by edges (a, b), numbered
    in the order of each component's smallest node (scipy.sparse.csgraph)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _propagate(n: int, a: np.ndarray, b: np.ndarray, rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Breadth-first 2-colouring: flip[j] = flip[i] ^ rel for each edge (i, j).

    Returns (component labels, flip flags relative to each component's first face).
    Conflicting cycles (non-orientable parts) keep the first label that reached them.

    Kept by hand: scipy.sparse.csgraph finds components and BFS trees but carries no
    parity along the edges, and its sparse matrices sum the rel flags of two edges
    joining the same two faces; this loop keeps the first edge that reaches a face.
    """
    from collections import deque

    adj_src = np.concatenate([a, b])
    adj_dst = np.concatenate([b, a])
    adj_rel = np.concatenate([rel, rel])
    order = np.argsort(adj_src, kind="stable")
    adj_dst, adj_rel = adj_dst[order].tolist(), adj_rel[order].tolist()
    ptr = np.searchsorted(adj_src[order], np.arange(n + 1)).tolist()
    comp = [-1] * n
    flip = [False] * n
    c = 0
    for s in range(n):
        if comp[s] >= 0:
            continue
        comp[s] = c
        queue = deque([s])
        while queue:
            i = queue.popleft()
            fi = flip[i]
            for k in range(ptr[i], ptr[i + 1]):
                j = adj_dst[k]
                if comp[j] < 0:
                    comp[j] = c
                    flip[j] = fi ^ adj_rel[k]
                    queue.append(j)
        c += 1
    return np.array(comp, np.int64), np.array(flip, bool)


# ------------------------------------------------------------------ BVH


@dataclass
class MeshBVH:
    """A mesh prepared for the distance kernels: checked, oriented, and a BVH.

    Node 0 is unused; the root is node 1; the two children of an internal node are
    adjacent (``first``, ``first + 1``, ``first`` even) so that one fetch reads both
    boxes. Triangles are stored in leaf order.

    Attributes:
        vertices: (V, 3) float32, as checked.
        faces: (F, 3) int32, oriented (:func:`orient_faces`) and in leaf order.
        bbox: (N, 8) float32 per node: min x, y, z, 0, max x, y, z, 0.
        sbox: (N, 8) float32: the search boxes of the kernels, ``bbox`` grown by
            ``BOX_SLACK`` times the root box's diagonal on every side.
        child: (N, 2) int32 per node: (first child, 0) for an internal node,
            (first triangle, count) for a leaf.
        dipole: (N, 8) float32 per node for the fast winding number: area-weighted
            centroid c (3), (BETA * r)^2 with r the radius of the node about c, then
            the area-weighted normal sum (3), 0.
        tris: (F, 12) float32 per triangle: a (3), b - a (3), c - a (3),
            |b - a|^2, |c - a|^2, (b - a).(c - a).
        tri_lanes: (F, 32) float32 per triangle, for the branch-free distance of the
            OpenCL grid kernel (layout in kernels/sdf_mesh.cl): a, ab, ac, n = ab x ac,
            bc, n x ab, n x bc, 1/|ab|^2, 1/|ac|^2, 1/|bc|^2, ac x n, 1/|n|^2, the
            inside threshold (0, or +inf where the normal is too small), 0 padding.
        depth: the deepest node's depth (the root is depth 1).
        scale: the power of two the mesh's coordinates were multiplied by before the
            build (1.0 unless built with ``normalize``): the BVH's units are world
            units times ``scale``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    bbox: np.ndarray
    child: np.ndarray
    dipole: np.ndarray
    tris: np.ndarray
    depth: int
    tri_lanes: np.ndarray
    sbox: np.ndarray
    scale: float = 1.0
    device_cache: dict = dc_field(default_factory=dict, repr=False)

    @property
    def bounds(self) -> np.ndarray:
        return self.bbox[1].reshape(2, 4)[:, :3].astype(np.float64)


def _morton63(q: np.ndarray) -> np.ndarray:
    """Interleave three 21-bit integer coordinates (n, 3) into 63-bit Morton codes."""

    def spread(x):
        x = x.astype(np.uint64) & np.uint64(0x1FFFFF)
        x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
        x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
        x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
        x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
        x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
        return x

    return spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)) | (spread(q[:, 2]) << np.uint64(2))


def _highest_bit(x: np.ndarray) -> np.ndarray:
    """Index of the highest set bit of each nonzero uint64 (vectorized binary search)."""
    x = x.copy()
    pos = np.zeros(x.shape, np.uint64)
    for shift in (32, 16, 8, 4, 2, 1):
        s = np.uint64(shift)
        big = (x >> s) != 0
        pos[big] += s
        x[big] >>= s
    return pos


def _range_reduce(ufunc, values: np.ndarray, s: np.ndarray, e: np.ndarray) -> np.ndarray:
    """ufunc-reduce of values[s_i:e_i] for disjoint, non-empty ranges."""
    order = np.argsort(s, kind="stable")
    idx = np.stack([s[order], e[order]], 1).reshape(-1)
    padded = np.concatenate([values, values[:1]])
    red = ufunc.reduceat(padded, idx, axis=0)[::2]
    out = np.empty_like(red)
    out[order] = red
    return out


def build_bvh(vertices: np.ndarray, faces: np.ndarray, leaf_size: int = LEAF_SIZE, beta: float = BETA) -> MeshBVH:
    """A linear BVH (Morton-sorted triangle centroids, split at the highest differing bit).

    Built top-down, one level at a time in NumPy: every node covers a contiguous
    range of the Morton-sorted triangles, split where the highest bit that differs
    across the range changes (a spatial median on alternating axes); ranges of equal
    codes, and every range below depth 32, split at their middle, which keeps the depth
    under STACK_SIZE. Boxes are exact over each node's triangles; the dipole terms of
    the fast winding number come from prefix sums over the sorted triangles.

    Args:
        vertices: (V, 3) float array.
        faces: (F, 3) int array (already checked and oriented).
        leaf_size: most triangles per leaf.
        beta: far-field ratio of the fast winding number.

    Returns:
        The :class:`MeshBVH`.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    n_f = f.shape[0]
    tri = v[f]  # (F, 3, 3)
    cent = tri.mean(axis=1)
    lo_c, hi_c = cent.min(0), cent.max(0)
    scale = np.where(hi_c > lo_c, hi_c - lo_c, 1.0)
    q = np.clip(((cent - lo_c) / scale * (2**21 - 1)).astype(np.int64), 0, 2**21 - 1)
    codes = _morton63(q)
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    tri = tri[order]
    f = f[order]

    max_nodes = 2 * n_f + 2
    child = np.zeros((max_nodes, 2), np.int64)
    node_s = np.zeros(max_nodes, np.int64)
    node_e = np.zeros(max_nodes, np.int64)
    idx, s, e = np.array([1]), np.array([0]), np.array([n_f])
    next_free = 2
    depth = 0
    while idx.size:
        depth += 1
        node_s[idx], node_e[idx] = s, e
        n = e - s
        leaf = n <= leaf_size
        child[idx[leaf], 0] = s[leaf]
        child[idx[leaf], 1] = n[leaf]
        inner = ~leaf
        idx, s, e = idx[inner], s[inner], e[inner]
        if not idx.size:
            break
        cs, ce = codes[s], codes[e - 1]
        diff = cs ^ ce
        mid = (s + e) // 2
        use_bits = (diff != 0) & (depth < 32)
        if use_bits.any():
            hb = _highest_bit(diff[use_bits])
            split_val = ((cs[use_bits] >> hb) | np.uint64(1)) << hb
            m = np.searchsorted(codes, split_val, side="left")
            mid[use_bits] = np.clip(m, s[use_bits] + 1, e[use_bits] - 1)
        first = next_free + 2 * np.arange(idx.size)
        next_free += 2 * idx.size
        child[idx, 0] = first
        child[idx, 1] = 0
        idx = np.concatenate([first, first + 1])
        s, e = np.concatenate([s, mid]), np.concatenate([mid, e])
    n_nodes = next_free
    if depth > STACK_SIZE - 2:
        raise RuntimeError(f"BVH depth {depth} exceeds the kernels' stack ({STACK_SIZE}).")
    ns, ne = node_s[1:n_nodes], node_e[1:n_nodes]

    # boxes: exact over each node's triangle range
    tlo, thi = tri.min(axis=1), tri.max(axis=1)
    bbox = np.zeros((n_nodes, 8), np.float64)
    bbox[1:, 0:3] = _range_reduce(np.minimum, tlo, ns, ne)
    bbox[1:, 4:7] = _range_reduce(np.maximum, thi, ns, ne)

    # dipoles: area-weighted centroid and normal sums through prefix sums
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # 2 * area * unit normal
    area = 0.5 * np.linalg.norm(cross, axis=1)
    pre_a = np.concatenate([[0.0], np.cumsum(area)])
    pre_ac = np.concatenate([np.zeros((1, 3)), np.cumsum(area[:, None] * tri.mean(axis=1), axis=0)])
    pre_n = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * cross, axis=0)])
    a_node = np.maximum(pre_a[ne] - pre_a[ns], 1e-300)
    c_node = (pre_ac[ne] - pre_ac[ns]) / a_node[:, None]
    n_node = pre_n[ne] - pre_n[ns]
    far = np.maximum(np.abs(bbox[1:, 0:3] - c_node), np.abs(bbox[1:, 4:7] - c_node))
    r2 = (far**2).sum(axis=1)
    dipole = np.zeros((n_nodes, 8), np.float64)
    dipole[1:, 0:3] = c_node
    dipole[1:, 3] = beta * beta * r2
    dipole[1:, 4:7] = n_node

    ab, ac = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    tris = np.concatenate(
        [tri[:, 0], ab, ac, (ab * ab).sum(1, keepdims=True), (ac * ac).sum(1, keepdims=True), (ab * ac).sum(1, keepdims=True)],
        axis=1,
    )
    return MeshBVH(
        tri_lanes=tri_lanes_layout(tri),
        sbox=_search_boxes(bbox),
        vertices=v.astype(np.float32),
        faces=np.ascontiguousarray(f, dtype=np.int32),
        bbox=np.ascontiguousarray(bbox, dtype=np.float32),
        child=np.ascontiguousarray(child[:n_nodes], dtype=np.int32),
        dipole=np.ascontiguousarray(dipole, dtype=np.float32),
        tris=np.ascontiguousarray(tris, dtype=np.float32),
        depth=depth,
    )


def _search_boxes(bbox: np.ndarray) -> np.ndarray:
    """(N, 8) float32 boxes grown by BOX_SLACK times the root's diagonal, rounded outward."""
    slack = BOX_SLACK * float(np.linalg.norm(bbox[1, 4:7] - bbox[1, 0:3]))
    out = np.zeros(bbox.shape, np.float32)
    lo, hi = bbox[:, 0:3] - slack, bbox[:, 4:7] + slack
    out[:, 0:3] = np.nextafter(lo.astype(np.float32), np.float32(-np.inf))
    out[:, 4:7] = np.nextafter(hi.astype(np.float32), np.float32(np.inf))
    out[0] = 0.0
    return np.ascontiguousarray(out)


def tri_lanes_layout(tri: np.ndarray) -> np.ndarray:
    """(F, 32) float32 lane layout of (F, 3, 3) float64 triangles (see MeshBVH.tri_lanes)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, bc = b - a, c - a, c - b
    n = np.cross(ab, ac)
    out = np.zeros((tri.shape[0], 32), np.float64)
    out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:12], out[:, 12:15] = a, ab, ac, n, bc
    out[:, 15:18], out[:, 18:21], out[:, 24:27] = np.cross(n, ab), np.cross(n, bc), np.cross(ac, n)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        for col, e in ((21, ab), (22, ac), (23, bc)):
            out[:, col] = 1.0 / np.einsum("ij,ij->i", e, e)
        n2 = np.einsum("ij,ij->i", n, n)
        out[:, 27] = 1.0 / n2
        lanes = out.astype(np.float32)
    # a needle whose normal or edge terms leave float32: never "inside", and its edges
    # as segments of zero length at worst (a finite 1/|e|^2 of 0 clamps to the corner)
    bad = ~np.isfinite(lanes[:, 27]) | (n2 == 0) | ~np.isfinite(lanes[:, 15:27]).all(axis=1)
    lanes[bad, 27] = 0.0
    lanes[bad, 28] = np.inf
    for col in (21, 22, 23):
        lanes[~np.isfinite(lanes[:, col]), col] = 0.0
    lanes[:, 15:21][~np.isfinite(lanes[:, 15:21])] = 0.0
    lanes[:, 24:27][~np.isfinite(lanes[:, 24:27])] = 0.0
    return np.ascontiguousarray(lanes)


_BVH_CACHE: OrderedDict[tuple, MeshBVH] = OrderedDict()
_BVH_CACHE_SIZE = 8


def mesh_scale(vertices: np.ndarray) -> float:
    """The power of two that brings the bounding-box diagonal of (V, 3) float64
    ``vertices`` into [1/2, 1) (1.0 for a single point)."""
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    if not diag > 0:
        return 1.0
    return math.ldexp(1.0, -math.frexp(diag)[1])


def prepare_mesh(mesh, name: str = "mesh", *, drop_degenerate: bool = False, normalize: bool = False) -> MeshBVH:
    """Check, orient and build the BVH of a mesh, cached by content (8 most recent meshes).

    With ``normalize``, the coordinates are first multiplied by :func:`mesh_scale` (a
    power of two, exact), recorded as the BVH's ``scale``: what :func:`mesh_distance`
    traverses, whatever the mesh's units. In float64 before float32 is taken, so that
    meshes beyond float32's range of exponents are read whole."""
    v64, faces = _checked_arrays(mesh, name, drop_degenerate)
    scale = mesh_scale(v64) if normalize else 1.0
    vertices = (v64 * scale).astype(np.float32)
    h = hashlib.blake2b(vertices.tobytes(), digest_size=16)
    h.update(faces.tobytes())
    key = (h.hexdigest(), vertices.shape, faces.shape, scale)
    bvh = _BVH_CACHE.get(key)
    if bvh is None:
        bvh = build_bvh(vertices, orient_faces(vertices, faces))
        bvh.scale = scale
        _BVH_CACHE[key] = bvh
        while len(_BVH_CACHE) > _BVH_CACHE_SIZE:
            _BVH_CACHE.popitem(last=False)
    else:
        _BVH_CACHE.move_to_end(key)
    return bvh


def _check_reach(bvh: MeshBVH, lo: np.ndarray, hi: np.ndarray, what: str) -> None:
    """Refuse queries (their box lo..hi, in the BVH's units) farther from the mesh than
    FAR_LIMIT times its size: their squared distances would leave float32."""
    box = bvh.bbox[1].reshape(2, 4)[:, :3].astype(np.float64)
    reach = float(np.max(np.maximum(box[0] - lo, hi - box[1])))
    if not reach <= FAR_LIMIT:  # NaN (an overflow) included
        diag = float(np.linalg.norm(box[1] - box[0])) / bvh.scale
        raise ValueError(f"{what} lie up to {reach / bvh.scale:.3g} beyond the mesh's bounding box, more than 2^60 "
                         f"({FAR_LIMIT:.3g}) times its size (diagonal {diag:.3g}): their squared distances would "
                         "leave float32; query points nearer the mesh.")


# bit b of a 10-bit integer moved to bit 3 b (the Morton interleave, by table)
_SPREAD10 = np.zeros(1024, np.uint64)
for _b in range(10):
    _SPREAD10 |= ((np.arange(1024, dtype=np.uint64) >> np.uint64(_b)) & np.uint64(1)) << np.uint64(3 * _b)


def _query_order(points: np.ndarray) -> np.ndarray:
    """(M,) permutation putting (M, 3) query points in Morton order (1024 cells per side
    over their bounding box, ties by index): consecutive points are near each other, so
    the kernels' SIMD tiles and seeded searches stay tight. Results do not depend on it."""
    columns = np.ascontiguousarray(points.T, dtype=np.float64)  # NumPy reduces (M, 3) along axis 0 slowly
    lo, hi = columns.min(axis=1), columns.max(axis=1)
    scale = 1023.0 / np.where(hi > lo, hi - lo, 1.0)
    q = np.clip(((columns - lo[:, None]) * scale[:, None]).astype(np.int64), 0, 1023)
    code = _SPREAD10[q[0]] | (_SPREAD10[q[1]] << np.uint64(1)) | (_SPREAD10[q[2]] << np.uint64(2))
    index_bits = max(1, int(len(points) - 1).bit_length())
    return np.argsort((code << np.uint64(index_bits)) | np.arange(len(points), dtype=np.uint64))  # unique keys


# ------------------------------------------------------------------ public API


def grid_distance_bytes(shape) -> int:
    """Estimated peak bytes of :func:`mesh_distance` on a grid of ``shape`` (Z, Y, X),
    beyond the mesh's BVH: 4 B/sample of the device output (host memory on Warp CPU and
    PoCL) and 4 of its host copy, which becomes the Field's values; 256 KiB for the launch. Measured (RSS high-water delta and
    tracemalloc, icosphere, 64^3 and 128^3 grids): 8.0 B/sample."""
    n = int(np.prod([int(v) for v in shape], dtype=object))
    return 8 * n + (256 << 10)


def mesh_distance(
    mesh,
    points=None,
    *,
    field: Field | None = None,
    bounds=None,
    resolution=None,
    padding: float = 0.1,
    signed: bool = True,
    band: float | None = None,
    drop_degenerate: bool = False,
    device: str | None = None,
):
    """Distance from points, or from every sample of a grid, to a triangle mesh.

    The distance is exact: the closest point over all triangles, found by a traversal
    of a Morton-ordered bounding volume hierarchy (BVH) built once on the host and
    cached. On OpenCL, queries go in tiles of 16 (grids: 4 x 2 x 2 samples; points: 16
    consecutive points after sorting them in Morton order) that share one traversal as
    the lanes of SIMD vectors: a node is entered while it may hold a closer triangle for
    any lane, and triangles are tested against all lanes at once (branch-free). On Warp,
    a few nearby queries go per thread, each search starting from the previous one's
    closest triangle as an upper bound. Every path returns the same float32 bits on
    every device: each distance is the minimum over all triangles of one float
    expression, computed with the same operations in the same order (no FMA
    contraction), and the search prunes with a margin beyond any rounding, so neither
    the tiles, nor the visiting order, nor the device change a result; point queries
    at grid positions equal the grid's values.

    The sign is negative inside. Inside means a generalized winding number above 1/2
    (Jacobson et al. 2013), computed with the fast approximation of Barill et al. 2018
    on the same BVH on every backend: nodes farther than 2 radii are summed as dipoles
    (area-weighted normal sums), nearer leaves exactly (van Oosterom-Strackee solid
    angles). Unlike ray parity or closest-normal tests, the winding number degrades
    gracefully on meshes that are not watertight: holes, gaps and self-intersections
    only change it near the defect, so the sign stays right away from them. Before the
    build, face orientation is made consistent across shared edges (majority per
    connected patch, closed patches turned outward; :func:`orient_faces`), so a few
    flipped faces do not disturb the sign either. Both backends run the same winding
    traversal on the same BVH, so they agree on the sign (the OpenCL grid tiles run it
    with a mask of the lanes still descending: per sample the same terms in the same
    order).

    Units do not matter: the mesh, the queries and ``band`` are multiplied by the power
    of two that brings the mesh's bounding-box diagonal into [1/2, 1) (exact in
    floating point; :func:`mesh_scale`) and the distances divided by it, so a mesh and
    its queries scaled by any factor give the same signs, and a power of two the same
    bits scaled (meshes from about 1e-30 to 1e30 wide; tested at 1e-6, 1 and 1e6).
    Queries more than 2^60 times the mesh's size beyond its box are refused.

    Degenerate (zero-area) faces are refused, or removed with ``drop_degenerate``:
    they carry no area and no normal.

    Args:
        mesh: a ``trimesh.Trimesh`` or a path to a mesh file (any format trimesh reads).
        points: (M, 3) query positions; if given, the result is an (M,) array.
        field: a :class:`~geosynth.geometry.field.Field` whose geometry (origin, spacing, shape)
            gives the grid; its values are not used or changed.
        bounds: (2, 3) (x, y, z) min and max corners of the grid box (default
            ``mesh.bounds``), used with ``resolution`` through
            :func:`~geosynth.geometry.field.cubic_grid`.
        resolution: samples along the longest axis (>= 2), when ``field`` is None.
        padding: fraction of the largest extent added around ``bounds``.
        signed: negative inside (True) or the unsigned distance (False).
        band: if given (> 0), distances are clamped to [-band, band] (faster too:
            nothing beyond the band is searched).
        drop_degenerate: remove zero-area faces instead of raising.
        device: a device string (see :mod:`geosynth.compute.backend`); None means "auto".

    Returns:
        (M,) float32 distances when ``points`` is given, else a new float32
        :class:`~geosynth.geometry.field.Field` on the requested grid.

    Raises:
        TypeError: ``mesh`` is not a mesh or path; ``field`` is not a Field; ``signed``
            or ``drop_degenerate`` not a bool; ``band`` not a number.
        ValueError: an empty mesh, NaN/inf vertices, out-of-range or degenerate
            faces, points not (M, 3) or not finite, resolution < 2, bounds of zero
            extent, a band that is not > 0, points together with a grid, or queries
            more than 2^60 times the mesh's size beyond its bounding box.
        RuntimeError: the device is not present.
        MemoryBudgetError: the grid's estimate (:func:`grid_distance_bytes`) exceeds the
            memory available, before allocating (option ``"resolution"``, or ``"field"``).
    """
    _checks.check_bool("signed", signed)
    _checks.check_bool("drop_degenerate", drop_degenerate)
    numeric = isinstance(band, (int, float, np.integer, np.floating)) and not isinstance(band, (bool, np.bool_))
    if band is not None and not numeric:
        raise TypeError(f"band must be a number (the distance to clamp at) or None, got {band!r}.")
    bvh = prepare_mesh(mesh, "mesh", drop_degenerate=drop_degenerate, normalize=True)
    scale = bvh.scale  # a power of two: world units -> the BVH's (exact both ways)
    if band is not None:
        band = float(band)
        if not (np.isfinite(band) and band > 0):
            raise ValueError(f"band must be a finite number > 0 (or None), got {band!r}.")
    band_arg = -1.0 if band is None else band * scale

    if points is not None:
        if field is not None or bounds is not None or resolution is not None:
            raise ValueError("pass either points or a grid (field=, or bounds=/resolution=), not both.")
        pts = _checks.as_points3("points", points, dtype=np.float32, finite=False)
        _checks.check_finite("points", pts)
        backend = _checks.resolve_backend(device)
        m = pts.shape[0]
        if m == 0:
            return np.zeros(0, np.float32)
        with np.errstate(over="ignore"):
            pts = pts * np.float32(scale)  # a new array: the caller's is left alone
        _check_reach(bvh, pts.min(axis=0).astype(np.float64), pts.max(axis=0).astype(np.float64), "points")
        order = _query_order(pts)  # tiles of nearby points; each result is order-free
        out = backend.empty((m,), np.float32)
        backend.mesh_distance_points(backend.mesh_handle(bvh), backend.to_device(pts[order]), m, bool(signed),
                                     band_arg, out)
        result = np.empty(m, np.float32)
        result[order] = backend.to_host(out)  # sync: the distances are the answer
        if scale != 1.0:
            result *= np.float32(1.0 / scale)
        return result

    if field is not None:
        if not isinstance(field, Field):
            raise TypeError(f"field must be a geosynth.geometry.field.Field, got {type(field).__name__}.")
        if bounds is not None or resolution is not None:
            raise ValueError("pass either field= or bounds=/resolution=, not both.")
        shape = field.shape
        require(grid_distance_bytes(shape), option="field", value=shape,
                what=f"the distance field of a {shape[2]} x {shape[1]} x {shape[0]} grid")
        origin, spacing = field.origin.copy(), field.spacing.copy()
    else:
        if resolution is None:
            raise ValueError("resolution is required for a grid (or pass field= or points).")
        b = bvh.bounds / scale if bounds is None else bounds
        _, _, shape = cubic_grid_geometry(b, resolution, padding)
        require(grid_distance_bytes(shape), option="resolution", value=resolution,
                largest_fn=lambda r: grid_distance_bytes(cubic_grid_geometry(b, r, padding)[2]), smallest=2,
                what=f"resolution {int(resolution):,} (a {shape[2]:,} x {shape[1]:,} x {shape[0]:,} grid)")
        origin, spacing, _ = cubic_grid_geometry(b, resolution, padding)
        spacing = np.full(3, spacing, np.float64)
    backend = _checks.resolve_backend(device)
    nz, ny, nx = shape
    o32 = (np.asarray(origin, np.float64) * scale).astype(np.float32)
    s32 = (np.asarray(spacing, np.float64) * scale).astype(np.float32)
    last = o32.astype(np.float64) + s32.astype(np.float64) * (np.array([nx, ny, nz], np.float64) - 1)
    _check_reach(bvh, np.minimum(o32, last), np.maximum(o32, last), "the grid's samples")
    out = backend.empty((nz * ny * nx,), np.float32)
    backend.mesh_distance_grid(backend.mesh_handle(bvh), o32, s32, (nx, ny, nz), bool(signed), band_arg, out)
    # sync: the field comes back; the Field is made around it (no zeroed grid first)
    values = backend.to_host(out).reshape(nz, ny, nx)
    if scale != 1.0:
        values *= np.float32(1.0 / scale)
    return Field(values, origin, spacing)
