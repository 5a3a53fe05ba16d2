"""How is an oriented point set read, written, and given a distance field? The MLS distance
of "Geometry texture synthesis with point-set surfaces", Sec. 5.1 (finding a similar patch).

Oriented point sets: PLY input/output (and :func:`read_geometry`, which reads a mesh
or a point set), normal estimation, and the MLS distance field.

The distance field of a point set is the one of method M2 ("Geometry texture synthesis
with point-set surfaces", Sec. 5.1, finding a similar patch): grid points are projected onto the MLS point-set surface of
Adamson and Alexa with their quasi-orthogonal projection, and the field holds the
signed distance to the projection plus a gradient field.

Definitions (the kernels are ``kernels/sdf_points.py`` and ``kernels/sdf_points.cl``):

- Weights: a Gaussian ``w_i(x) = exp(-|x - p_i|^2 / h^2)`` of kernel width ``h``
  (``radius=``), cut off to 0 beyond ``reach = MLS_REACH * h`` (3h: the weight there
  is exp(-9) ~ 1.2e-4 of the peak).
- ``a(x) = sum w_i p_i / sum w_i`` and ``n(x) = normalize(sum w_i n_i)``, with the
  input normals normalized first; the implicit function ``f(x) = n(x) . (x - a(x))``
  (Adamson and Alexa), positive on the side the normals point to.
- Projection: ``y <- y - f(y) n(y)`` from ``y = x``, until ``|f(y)| <= MLS_TOL * h``
  or ``MLS_MAX_ITER`` steps.
- Field value: the *signed distance* ``sign(f(x)) * |x - proj(x)|``, not ``f(x)``:
  the M2 paper (Sec. 5.1) computes D(S) "by projecting points of a regular grid on the
  surface(s) of S using the quasi-orthogonal projection operator of Adamson and Alexa"
  and asks for "signed distance fields together with a gradient field"; the sign comes
  from the explicit normals ("to determine the distance sign, the operator should always
  yield consistent normals, and therefore we require explicit normals"). ``f(x)`` alone
  is only a distance near the surface. Values are clamped to ``[-reach, reach]``.
- Gradient: the MLS normal ``n(proj(x))`` at the projection, a unit vector: the
  gradient of an exact signed distance field is the surface normal at the closest point,
  and unlike ``(x - proj(x)) / |x - proj(x)|`` it stays defined on the surface.
- Far value (``far="nearest"``, the default): a query with no input point within reach
  gets the signed distance to the projection of its nearest input point,
  ``sign(n . (x - y)) |x - y|`` with ``y = proj(p_nearest)`` and ``n`` the MLS normal
  there, and that normal as its gradient: a signed distance everywhere, exact in the
  limit of dense sampling (the nearest sample's projection lies within about one
  sample spacing of the true closest point) and with the sign of the closest surface
  side. ``far="reach"`` skips that pass (faster) and gives such queries ``+reach``
  and gradient ``(0, 0, 0)`` instead. No NaN is ever returned.
- Default width: ``h = MLS_WIDTH_FACTOR * mean nearest-neighbour distance`` (2x), so
  that about a dozen points of a uniformly sampled surface lie within h of a surface
  point; see :func:`default_radius`.

Neighbours come from a cell-sorted grid (cell size reach/2) built here on the host
(points sorted by cell with NumPy) and read by both backends; its rows of cells are
contiguous ranges of points. The Warp path reads the same grid instead of wp.HashGrid,
so both backends visit the same points in the same order and agree to a few ulps.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.core.memory import require
from geosynth.geometry.field import Field, cubic_grid, cubic_grid_geometry
from geosynth.io import readers as _readers
from geosynth.io.files import atomic_write, check_finite_output, check_input

__all__ = [
    "MLS_MAX_ITER",
    "MLS_REACH",
    "MLS_TOL",
    "MLS_WIDTH_FACTOR",
    "PointSet",
    "default_radius",
    "estimate_normals",
    "pointset_distance",
    "project_points",
    "read_geometry",
    "read_point_set",
    "write_point_set",
]

MLS_REACH = 3.0  # support radius in units of h: weights beyond 3h (< 1.2e-4 of the peak) are 0
MLS_WIDTH_FACTOR = 2.0  # default h = 2 x the mean nearest-neighbour distance
MLS_TOL = 1e-4  # projection stops when |f| <= MLS_TOL * h (float32 keeps ~1e-6 relative)
MLS_MAX_ITER = 20  # projection steps at most; near the surface 2-5 suffice
_MAX_CELLS_PER_POINT = 8  # the cell grid is coarsened beyond max(8 n, 2^20) cells
_MIN_CELL_CAP = 1 << 20


# ------------------------------------------------------------------------- the data


@dataclass
class PointSet:
    """An oriented point set.

    Attributes:
        positions: (N, 3) float32 positions.
        normals: (N, 3) float32 normals, or None.
        colors: (N, 3) uint8 RGB colours, or None.
        source: the file it was read from (set by :func:`read_point_set`), which
            :func:`write_point_set` refuses to overwrite; None otherwise.
        alpha: (N,) uint8 alpha of the colours when the file gave one, or None (opaque);
            only with ``colors``.
    """

    positions: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    source: Path | None = dc_field(default=None, compare=False)
    alpha: np.ndarray | None = None

    def __post_init__(self):
        self.positions = _as_points("positions", self.positions)
        n = len(self.positions)
        if self.normals is not None:
            self.normals = _as_points("normals", self.normals)
            if self.normals.shape != (n, 3):
                raise ValueError(f"normals must have shape ({n}, 3) to match positions, got {self.normals.shape}.")
        if self.colors is not None:
            c = np.asarray(self.colors)
            if c.shape != (n, 3):
                raise ValueError(f"colors must have shape ({n}, 3) (RGB) to match positions, got {c.shape}.")
            if c.dtype != np.uint8:
                if c.dtype.kind not in "iu" or c.min(initial=0) < 0 or c.max(initial=0) > 255:
                    raise TypeError(f"colors must be uint8 (0..255), got dtype {c.dtype}.")
                c = c.astype(np.uint8)
            self.colors = np.ascontiguousarray(c)
        if self.alpha is not None:
            a = np.asarray(self.alpha)
            if self.colors is None or a.shape != (n,) or a.dtype != np.uint8:
                raise ValueError(f"alpha must be ({n},) uint8 beside colors, got {a.shape} {a.dtype}"
                                 + ("" if self.colors is not None else " without colors") + ".")
            self.alpha = np.ascontiguousarray(a)

    def __len__(self) -> int:
        return len(self.positions)


def _as_points(name: str, array) -> np.ndarray:
    """(N, 3) float32 points, checked (:func:`geosynth.compute.checks.as_points3`; non-finite ones are
    reported by the caller)."""
    return _checks.as_points3(name, array, dtype=np.float32, finite=False)


def read_point_set(path: str | os.PathLike) -> PointSet:
    """Read a point set from a PLY file (ASCII or binary, either byte order, through plyfile).

    Reads the vertex element: x, y, z; nx, ny, nz (or normal_x, ...) when present; red,
    green, blue and optional alpha (or r, g, b, a, or diffuse_red, ...) when present:
    integer colours 0..255 as they are, 16-bit ones scaled, float colours in [0, 1] times
    255 (whole-number floats up to 255 as they are; other floats beyond [0, 1], NaN, half a
    colour group are refused); face colours only: each vertex the mean of its faces'.
    Other properties and faces are ignored. The file is noted as an
    input (:func:`geosynth.io.files.note_input`): no writer of this process replaces it.

    Args:
        path: the .ply file.

    Returns:
        The PointSet ((N, 3) float32 positions, (N, 3) float32 normals or None, (N, 3)
        uint8 colours or None), with ``source`` set to the path.

    Raises:
        FileNotFoundError: ``"point set file 'X' does not exist."``
        ValueError: one line naming the file: a folder, an empty file, not .ply, not a
            readable PLY file (``"'X' is not a readable PLY file: <reason>; give ..."``),
            no vertices, or NaN/inf positions or normals (their count and the first index).
    """
    p = check_input(path, "point set")
    if p.suffix.lower() != ".ply":
        raise ValueError(f"point sets are read from PLY files; {str(p)!r} is not .ply (read meshes and other "
                         "formats with geosynth.geometry.pointsets.read_geometry).")
    return _point_set(p, _readers.read_ply(p, faces=False))


def _point_set(p: Path, g) -> PointSet:
    positions, normals = _readers.checked_points(p, g)
    return PointSet(positions, normals, g.colors, source=p, alpha=g.alpha)


def read_geometry(path: str | os.PathLike):
    """Read a mesh or a point set: a mesh when the file has faces, else a point set.

    PLY files (ASCII or binary, with or without faces) are read through plyfile as
    :func:`read_point_set` reads them; OBJ, STL, OFF, GLB and GLTF through trimesh,
    without processing (nothing is merged or dropped). Meshes are checked: every vertex
    finite, face indices in range. The file is noted as an input.

    Args:
        path: a .ply, .obj, .stl, .off, .glb or .gltf file.

    Returns:
        A ``trimesh.Trimesh`` (float64 vertices, int64 triangle faces; PLY polygons are
        split into triangle fans) when the file has faces, its colours as
        ``visual.vertex_colors`` (RGBA; ``metadata["alpha_given"]`` says whether the file
        gave the alpha), else a :class:`PointSet` (positions; normals from PLY files;
        colours and alpha from any format). Colours: PLY vertex or face colours, OBJ
        ``v x y z r g b``, GLB COLOR_0, a texture sampled at the vertices' UVs; colours
        that cannot be used are refused in one line (see :func:`read_point_set`).

    Raises:
        FileNotFoundError: ``"mesh or point-set file 'X' does not exist."``
        ValueError: one line naming the file: a folder, an empty file, another extension,
            an unreadable file (``"'X' is not a readable PLY file: <reason>; ..."``,
            ``"'X' is not a readable OBJ file: <reason>; ..."``), NaN/inf vertices
            (``"'X' has 1 vertex with NaN or inf coordinates (the first: index 5,
            counting from 0); ..."``), face indices out of range.
    """
    p = check_input(path, "mesh or point-set")
    g = _readers.read_any(p)
    if g.faces is not None and len(g.faces):
        return _readers.checked_mesh(p, g)
    return _point_set(p, g)


def write_point_set(path: str | os.PathLike, ps: PointSet) -> Path:
    """Write a point set as binary little-endian PLY (through plyfile), atomically.

    The vertex element holds x, y, z (float32), then nx, ny, nz (float32) when the set
    has normals and red, green, blue (uchar) when it has colours (and alpha when it has
    one). The file is written to
    a temporary name beside ``path`` and then renamed over it, so a reader never sees a
    partial file (:func:`geosynth.io.files.atomic_write`).

    Args:
        path: the .ply file to write.
        ps: the PointSet (or anything with positions / normals / colors).

    Returns:
        The path written.

    Raises:
        ValueError: ``path`` is not .ply, or is the file ``ps`` was read from or another
            input of this process (inputs are never overwritten), or a position or normal
            is NaN or inf (``"refusing to write 'X': 4 of its 900 position coordinates are
            NaN or inf, in 2 points (the first: point 7, counting from 0); ..."``, before any file is
            created).
    """
    from plyfile import PlyData, PlyElement

    out = Path(path)
    if out.suffix.lower() != ".ply":
        raise ValueError(f"point sets are written as .ply; got {str(out)!r}.")
    if not isinstance(ps, PointSet):
        ps = PointSet(ps.positions, getattr(ps, "normals", None), getattr(ps, "colors", None))
    check_finite_output(out, "point", position=ps.positions, normal=ps.normals)
    src = ps.source
    if src is not None and out.exists() and Path(src).exists() and os.path.samefile(out, src):
        raise ValueError(f"refusing to overwrite the input {str(src)!r}; write the point set to another path.")
    layout = [(c, "<f4") for c in "xyz"]
    if ps.normals is not None:
        layout += [(c, "<f4") for c in ("nx", "ny", "nz")]
    alpha = getattr(ps, "alpha", None) if ps.colors is not None else None
    if ps.colors is not None:
        layout += [(c, "u1") for c in ("red", "green", "blue")] + ([("alpha", "u1")] if alpha is not None else [])
    vertex = np.empty(len(ps), dtype=layout)
    for i, c in enumerate("xyz"):
        vertex[c] = ps.positions[:, i]
    if ps.normals is not None:
        for i, c in enumerate(("nx", "ny", "nz")):
            vertex[c] = ps.normals[:, i]
    if ps.colors is not None:
        for i, c in enumerate(("red", "green", "blue")):
            vertex[c] = ps.colors[:, i]
        if alpha is not None:
            vertex["alpha"] = alpha
    data = PlyData([PlyElement.describe(vertex, "vertex")], text=False, byte_order="<")

    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            data.write(fh)

    return atomic_write(out, write, inputs=(src,))


# ------------------------------------------------------------------------- normals


def _kdtree(points: np.ndarray):
    from geosynth.core.neighbours import NeighbourIndex

    return NeighbourIndex(points)


# eigh's second eigenvalue below this fraction of the largest: rank < 2, to rounding.
_PLANE_TOLERANCE = 1e-12


def estimate_normals(points, k: int = 16) -> np.ndarray:
    """Unit normals of a point set: PCA over k nearest neighbours, oriented consistently.

    1. For each point, the covariance of its k nearest neighbours (itself included);
       the normal is the eigenvector of the smallest eigenvalue.
    2. Orientation (Hoppe et al. 1992): on the symmetric k-nearest-neighbour graph with
       edge cost ``1 - |n_i . n_j|``, take a minimum spanning tree of each connected
       component and propagate the sign from a root along it, flipping a child whose
       normal points against its parent's.
    3. Root of each component: for the directions +z, +y, +x, -z, -y, -x in that order,
       the component's extreme point along d; the first direction whose extreme point's
       normal is most nearly parallel to d (within 0.05 of the best) wins, and that
       normal is oriented along d. On a closed surface the extreme point along d has
       outward normal d, so normals point outward; an open sheet such as a height field
       gets normals towards +z (else +y, +x).

    Args:
        points: (N, 3) float positions (N >= 3), or a PointSet.
        k: neighbours per point (itself included), >= 3; clipped to N.

    Returns:
        (N, 3) float32 unit normals.

    Raises:
        ValueError: wrong shape, fewer than 3 points, NaN/inf, k < 3, points whose k
            nearest neighbours do not span a plane (coincident or collinear: the message
            says how many).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

    if isinstance(points, PointSet):
        points = points.positions
    p = _as_points("points", points).astype(np.float64)
    n = len(p)
    if n < 3:
        raise ValueError(f"points must hold at least 3 points to estimate normals, got {n}.")
    _checks.check_finite("points", p)
    if not isinstance(k, (int, np.integer)) or k < 3:
        raise ValueError(f"k must be an integer >= 3, got {k!r}.")
    k = int(min(k, n))

    # 1. PCA over the k nearest neighbours.
    _, idx = _kdtree(p).query(p, k)
    nb = p[idx]  # (N, k, 3)
    centred = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    vals, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]  # smallest eigenvalue first
    # A neighbourhood that does not span a plane (all its points coincide, or lie on one
    # line) has no normal: the eigenvector would be arbitrary.
    flat = np.flatnonzero(vals[:, 1] <= _PLANE_TOLERANCE * vals[:, 2])
    if flat.size:
        if flat.size == n and not (p.max(axis=0) - p.min(axis=0)).any():
            raise ValueError(f"points: all {n} points coincide, so no point has a defined normal.")
        raise ValueError(
            f"points: {flat.size} of {n} points have no defined normal (first at index {int(flat[0])}): "
            f"their k={k} nearest neighbours (itself included) coincide or lie on one line, fewer than 3 "
            "distinct points spanning a plane; remove duplicate points or raise k."
        )

    # 2. Minimum spanning tree of the Riemannian graph.
    rows = np.repeat(np.arange(n), k - 1)
    cols = idx[:, 1:].reshape(-1)
    keep = rows != cols
    rows, cols = rows[keep], cols[keep]
    cost = 1.0 - np.abs(np.einsum("ij,ij->i", normals[rows], normals[cols])) + 1e-6  # > 0: zeros are dropped
    graph = coo_matrix((cost, (rows, cols)), shape=(n, n)).tocsr()
    graph = graph.maximum(graph.T)
    tree = minimum_spanning_tree(graph)
    tree = tree + tree.T
    n_comp, labels = connected_components(tree, directed=False)

    # 3. Per component: choose the root, propagate signs in breadth-first order.
    dirs = np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, -1], [0, -1, 0], [-1, 0, 0]], np.float64)
    sign = np.zeros(n, np.float64)
    order_all = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order_all], np.arange(n_comp + 1))
    for c in range(n_comp):
        members = order_all[bounds[c]:bounds[c + 1]]
        proj = p[members] @ dirs.T  # (m, 6)
        ext = members[np.argmax(proj, axis=0)]  # extreme point per direction
        score = np.abs(np.einsum("ij,ij->i", normals[ext], dirs))
        d = int(np.flatnonzero(score >= score.max() - 0.05)[0])
        root = int(ext[d])
        sign[root] = 1.0 if normals[root] @ dirs[d] >= 0 else -1.0
        if len(members) == 1:
            continue
        order, pred = breadth_first_order(tree, root, directed=False, return_predecessors=True)
        child = order[1:]
        parent = pred[child]
        agree = np.where(np.einsum("ij,ij->i", normals[child], normals[parent]) >= 0, 1.0, -1.0)
        s = sign.tolist()
        for v, u, a in zip(child.tolist(), parent.tolist(), agree.tolist()):
            s[v] = s[u] * a
        sign = np.asarray(s)
    return (normals * sign[:, None]).astype(np.float32)


def default_radius(points) -> float:
    """The default MLS kernel width h: MLS_WIDTH_FACTOR (2) x the mean distance from
    each point to its nearest neighbour (over an even subsample of at most ~20k points).

    Args:
        points: (N, 3) positions (N >= 2) or a PointSet.

    Raises:
        ValueError: fewer than 2 distinct points (pass ``radius=`` instead).
    """
    if isinstance(points, PointSet):
        points = points.positions
    p = _as_points("points", points)
    if len(p) < 2:
        raise ValueError("the default radius needs at least 2 points; pass radius= (the kernel width h).")
    # The mean over an even subsample of at most ~20k points: the same estimate, cheaper.
    sample = p[:: max(1, len(p) // 20_000)]
    dist, _ = _kdtree(p).query(sample, 2)
    h = MLS_WIDTH_FACTOR * float(np.mean(dist[:, 1]))
    if not h > 0:
        raise ValueError("all points coincide, so the point spacing is 0; pass radius= (the kernel width h).")
    return h


# ------------------------------------------------------------------------- MLS distance


def _prepare(points, normals) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert positions and normals; normals come back unit length."""
    if isinstance(points, PointSet):
        if normals is None:
            normals = points.normals
        points = points.positions
    p = _as_points("points", points)
    if len(p) == 0:
        raise ValueError("points is empty: the point set must hold at least one point.")
    _checks.check_finite("points", p)
    if normals is None:
        raise ValueError(
            "normals are required: the MLS distance takes its sign from the normals; estimate them "
            "with geosynth.geometry.pointsets.estimate_normals(points)."
        )
    nrm = _as_points("normals", normals)
    if nrm.shape != p.shape:
        raise ValueError(f"normals must have shape {p.shape} to match points, got {nrm.shape}.")
    _checks.check_finite("normals", nrm)
    length = np.linalg.norm(nrm.astype(np.float64), axis=1)
    zero = np.flatnonzero(length < 1e-12)
    if zero.size:
        raise ValueError(
            f"normals has {zero.size} zero-length normal(s), first at index {int(zero[0])}; every normal must "
            "have a direction (drop those points or re-estimate with estimate_normals)."
        )
    return p, (nrm / length[:, None]).astype(np.float32)


# The kernels hold coordinates relative to the points' box centre in float32, which
# resolves about extent * 2^-24; a kernel width below extent * 2^-16 (256 times that) is
# lost in rounding, and its cell grid would need more cells than int64 counts.
_RADIUS_RESOLUTION = 2.0**-16


def smallest_radius(points: np.ndarray) -> float:
    """The smallest kernel width h that :func:`pointset_distance` accepts for these
    points: their largest box extent times 2^-16 (0 for a single point)."""
    p = np.asarray(points, np.float64)
    return float((p.max(axis=0) - p.min(axis=0)).max()) * _RADIUS_RESOLUTION if len(p) else 0.0


def _as_radius(radius, points: np.ndarray) -> float:
    if radius is None:
        return default_radius(points)
    if isinstance(radius, bool) or not isinstance(radius, (int, float, np.integer, np.floating)):
        raise TypeError(f"radius must be a number (the kernel width h), got {type(radius).__name__}.")
    h = float(radius)
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"radius must be a finite number > 0 (the kernel width h), got {radius!r}.")
    smallest = smallest_radius(points)
    if h < smallest:
        raise ValueError(
            f"radius {radius!r} is too small for points spanning {smallest / _RADIUS_RESOLUTION:.6g}: float32 "
            f"coordinates cannot resolve it; the smallest radius that works is {smallest:.6g} (omit radius= "
            "for the default, twice the mean point spacing)."
        )
    return h


class _CellGrid:
    """Points sorted by cell of a regular grid, with each cell's first point.

    Coordinates are relative to ``shift`` (the centre of the points' box), which keeps
    float32 precise for data far from the origin.
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, reach: float):
        rel, order, start, self.shift, self.origin, self.cell, self.dims = cell_sort(points, reach)
        self.order = order  # (n,) int64: sorted position -> input index
        pn = np.zeros((len(points), 8), np.float32)
        pn[:, 0:3] = rel[order]
        pn[:, 4:7] = normals[order]
        self.pn = pn.reshape(-1)
        self.cell_start = start


def cell_sort(points: np.ndarray, reach: float):
    """The layout of :class:`CellGrid` (also the search's float64 host grid): cells of
    reach / 2 (coarser where they would exceed max(8 n, 2^20)) over the points' box, in
    coordinates relative to its centre.

    Args:
        points: (n, 3) float positions, n >= 1; reach: the MLS support radius (> 0).

    Returns:
        (rel, order, cell_start, shift, origin, cell, dims): (n, 3) float64 positions
        relative to ``shift`` ((3,) float64, the box centre), (n,) int64 stable order by
        linear cell index ``(cz * ny + cy) * nx + cx``, (nx*ny*nz + 1,) int32 first sorted
        point of each cell, (3,) float64 grid origin (relative), the float cell size,
        (3,) int64 dims (nx, ny, nz).
    """
    p64 = points.astype(np.float64)
    columns = np.ascontiguousarray(p64.T)  # min / max along contiguous rows: ~15x faster than axis=0
    lo, hi = columns.min(axis=1), columns.max(axis=1)
    shift = (lo + hi) / 2
    rel = p64 - shift
    lo = lo - shift - 1e-6 * max(reach, float((hi - lo).max()))
    cell = reach / 2  # a query's box spans 5 cells per axis: 25 contiguous rows
    cap = max(_MAX_CELLS_PER_POINT * len(points), _MIN_CELL_CAP)
    while True:
        dims = np.floor((hi - shift - lo) / cell).astype(np.int64) + 1
        if math.prod(int(v) for v in dims) <= cap:  # Python ints: no int64 overflow
            break
        cell *= 1.25
    keys3 = np.minimum(np.floor((rel - lo) / cell).astype(np.int64), dims - 1)
    keys = (keys3[:, 2] * dims[1] + keys3[:, 1]) * dims[0] + keys3[:, 0]
    order = np.argsort(keys, kind="stable")
    start = np.zeros(int(np.prod(dims)) + 1, np.int32)
    np.cumsum(np.bincount(keys, minlength=len(start) - 1), out=start[1:])
    return rel, order, start, shift, lo, cell, dims


# Public for callers that launch PointsOps.mls_project themselves (geosynth.pointtexture.patch_search, M2's
# fixed-step projections): the points sorted by cell, as the kernels read them.
CellGrid = _CellGrid


def _run_mls(p, nrm, h, device, queries=None, lattice=None, want_proj=False, grid=None):
    """Project the queries ((M, 3) float32) or the lattice ((origin, spacing, shape ZYX));
    ``grid``: the points' _CellGrid for this reach, when already built."""
    reach = MLS_REACH * h
    if grid is None:
        grid = _CellGrid(p, nrm, reach)
    backend = _checks.resolve_backend(device)
    if queries is not None:
        m = len(queries)
        q_dev = backend.to_device(np.ascontiguousarray((queries.astype(np.float64) - grid.shift).astype(np.float32)).reshape(-1))
        lat = None
    else:
        origin, spacing, shape = lattice
        m = int(np.prod(shape))
        q_dev = None
        lat = (tuple(np.asarray(origin, np.float64) - grid.shift), tuple(spacing), (int(shape[2]), int(shape[1])))
    if m > 2**31 // 3 - 1024:
        raise ValueError(f"{m} query points exceed the int32 indexing of the kernels; split the call.")
    dist = backend.empty((m,), np.float32)
    grad = backend.empty((m * 3,), np.float32)
    proj = backend.empty((m * 3,), np.float32) if want_proj else None
    backend.mls_project(
        backend.to_device(grid.pn), backend.to_device(grid.cell_start),
        tuple(grid.origin), 1.0 / grid.cell, tuple(int(d) for d in grid.dims),
        1.0 / (h * h), reach, MLS_TOL * h, MLS_MAX_ITER,
        q_dev, lat, m, dist, grad, proj,
    )
    # sync: the results are returned to the caller as host arrays.
    out_d, out_g = dist.numpy(), grad.numpy().reshape(m, 3)
    out_p = None
    if want_proj:
        out_p = (proj.numpy().reshape(m, 3).astype(np.float64) + grid.shift).astype(np.float32)
    return out_d, out_g, out_p


_FAR_CHUNK = 1 << 16  # far queries filled per pass: bounds that pass's memory (~160 B each, 10 MiB)


def _fill_far(p, nrm, h, device, coords, d, g) -> None:
    """Give the queries that had no input point within reach (gradient 0) the signed
    distance to the projection of their nearest input point, in place.

    ``coords(indices)`` gives the (c, 3) float32 positions of the queries ``indices``;
    they are made and filled _FAR_CHUNK at a time (the same values as all at once)."""
    far = np.flatnonzero(~g.any(axis=1))
    if far.size == 0:
        return
    tree = _kdtree(p)
    cells = _CellGrid(p, nrm, MLS_REACH * h)  # built once for every pass
    for start in range(0, far.size, _FAR_CHUNK):
        idx = far[start:start + _FAR_CHUNK]
        x = coords(idx)
        nearest = tree.query(x, 1)[1][:, 0]
        used, inverse = np.unique(nearest, return_inverse=True)  # many queries share a point
        _, normal, proj = _run_mls(p, nrm, h, device, queries=p[used], want_proj=True, grid=cells)
        y, n = proj[inverse].astype(np.float64), normal[inverse].astype(np.float64)
        v = x.astype(np.float64) - y
        side = np.where(np.einsum("ij,ij->i", v, n) < 0, -1.0, 1.0)
        d[idx] = side * np.linalg.norm(v, axis=1)
        g[idx] = n


def _lattice_coords(origin, spacing, shape):
    """``coords`` for :func:`_fill_far` on a grid: the world positions of flat sample
    indices, as :func:`geosynth.geometry.field.grid_points` computes them (float64, then float32)."""
    nz, ny, nx = (int(v) for v in shape)
    origin, spacing = np.asarray(origin, np.float64), np.asarray(spacing, np.float64)

    def coords(idx: np.ndarray) -> np.ndarray:
        ijk = np.stack([idx % nx, idx // nx % ny, idx // (nx * ny)], -1).astype(np.float64)
        return (origin + spacing * ijk).astype(np.float32)

    return coords


def grid_mls_bytes(n_samples: int, points: np.ndarray, h: float) -> int:
    """Estimated peak bytes of :func:`pointset_distance` on a grid of ``n_samples`` for
    the (N, 3) input ``points`` and kernel width ``h``.

    Counts, per sample: distance and gradient on the device (16 B; host memory on Warp
    CPU and PoCL) and their host copies (16 B); or, in the far pass, the copies, its
    masks and far indices (26 B) plus 160 B per query of one pass (_FAR_CHUNK at most:
    positions, kd-tree answers, projections, float64 differences). Per input point
    200 B (the sorted cell grid, host and device, twice; the kd-tree) and 16 B per
    cell of the cell grid. Measured on a 2,000-point sphere (tracemalloc, far
    "reach"): 20.1 B/sample (+16 device); the far pass 156-165 B per query of a pass.
    """
    n, m = int(n_samples), len(points)
    reach = MLS_REACH * h
    extent = np.ptp(np.asarray(points, np.float64), axis=0) if m else np.zeros(3)
    dims = np.floor(extent / (reach / 2)).astype(np.float64) + 2
    cells = min(float(np.prod(dims)), max(_MAX_CELLS_PER_POINT * m, _MIN_CELL_CAP))
    return max(32 * n, 26 * n + 160 * min(n, _FAR_CHUNK)) + 200 * m + 16 * int(cells)


def _as_query(query) -> np.ndarray:
    q = _as_points("query", query)
    if len(q) == 0:
        raise ValueError("query is empty: pass at least one query point.")
    _checks.check_finite("query", q)
    return q


def pointset_distance(
    points,
    normals=None,
    query=None,
    *,
    field: Field | None = None,
    bounds=None,
    resolution=None,
    padding: float = 0.1,
    radius: float | None = None,
    far: str = "nearest",
    device: str | None = None,
):
    """Signed distance and gradient of the MLS surface of an oriented point set.

    The definitions (Gaussian width h, reach 3h, quasi-orthogonal projection, signed
    distance ``sign(f(x)) |x - proj(x)|``, gradient = MLS normal at the projection, far
    value) are in the module docstring.

    Where to sample, one of:

    - ``query``: (M, 3) points -> returns two arrays;
    - ``field``: a :class:`Field` whose geometry (origin, spacing, shape) is used;
    - ``resolution`` (and optionally ``bounds``, default the points' bounding box):
      the cubic grid of :func:`geosynth.geometry.field.cubic_grid` (``padding`` around it).

    Args:
        points: (N, 3) float positions, or a PointSet (its normals are used unless
            ``normals`` is given).
        normals: (N, 3) float normals, oriented (outward for closed shapes); they are
            normalized. Required: see :func:`estimate_normals` for inputs without.
        query: (M, 3) float query points.
        field: a Field giving the sample grid (its values are ignored).
        bounds: (2, 3) box for the cubic grid, default the points' bounds.
        resolution: samples along the box's longest axis, >= 2.
        padding: fraction of the largest extent added around ``bounds``.
        radius: the Gaussian kernel width h (> 0); default :func:`default_radius`.
        far: what queries beyond reach (3h) of every input point get: ``"nearest"``
            (the signed distance to the nearest input point's projection) or
            ``"reach"`` (``+reach``, gradient 0); see the module docstring.
        device: a device string (see :mod:`geosynth.compute.backend`); None means ``"auto"``.

    Returns:
        With ``query``: ``(distance, gradient)``, (M,) and (M, 3) float32 arrays.
        Otherwise: ``(distance, gradient)`` Fields on the same grid, values (Z, Y, X)
        and (Z, Y, X, 3) float32, the gradient's components in (x, y, z) order.

    Raises:
        TypeError: non-numeric arrays, a radius that is not a number, a field that is not a Field.
        ValueError: no normals, zero-length normals, NaN/inf, mismatched shapes, an empty
            point set or query, no sampling given (or more than one), resolution < 2,
            bounds with zero extent, radius <= 0 or below :func:`smallest_radius` (the
            points' extent times 2^-16, which float32 coordinates cannot resolve).
        RuntimeError: the device is absent.
        MemoryBudgetError: a grid's estimate (:func:`grid_mls_bytes`) exceeds the memory
            available, before allocating (option ``"resolution"``, or ``"field"``).

    Example:
        >>> import numpy as np
        >>> from geosynth.geometry.pointsets import pointset_distance
        >>> g = np.stack(np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1, 1, 21)), -1).reshape(-1, 2)
        >>> pts = np.c_[g, np.zeros(len(g))]
        >>> d, grad = pointset_distance(pts, np.tile([0, 0, 1.0], (len(g), 1)), [[0.0, 0.0, 0.05]], device="cpu")
        >>> bool(np.isclose(d[0], 0.05, atol=1e-4)), bool(np.allclose(grad[0], [0, 0, 1], atol=1e-4))
        (True, True)
    """
    p, nrm = _prepare(points, normals)
    modes = [name for name, v in (("query", query), ("field", field), ("resolution", resolution)) if v is not None]
    if len(modes) != 1:
        raise ValueError(
            "give exactly one of query=, field= or resolution= (with optional bounds=) to say where to sample"
            + (f"; got {', '.join(modes)}." if modes else ".")
        )
    if bounds is not None and resolution is None:
        raise ValueError("bounds= needs resolution= (the cubic grid's samples along its longest axis).")
    h = _as_radius(radius, p)
    if far not in ("nearest", "reach"):
        raise ValueError(f"far must be 'nearest' or 'reach', got {far!r}.")
    if query is not None:
        q = _as_query(query)
        d, g, _ = _run_mls(p, nrm, h, device, queries=q)
        if far == "nearest":
            _fill_far(p, nrm, h, device, lambda idx: q[idx], d, g)
        return d, g
    if field is not None:
        if not isinstance(field, Field):
            raise TypeError(f"field must be a geosynth.geometry.field.Field, got {type(field).__name__}.")
        shape = field.shape
        require(grid_mls_bytes(int(np.prod(shape, dtype=object)), p, h), option="field", value=shape,
                what=f"the MLS distance field of a {shape[2]} x {shape[1]} x {shape[0]} grid")
        grid = Field(np.zeros(field.shape, np.float32), field.origin, field.spacing)
    else:
        box = np.stack([p.min(axis=0), p.max(axis=0)]).astype(np.float64) if bounds is None else bounds
        _, _, shape = cubic_grid_geometry(box, resolution, padding)

        def estimate(r):
            return grid_mls_bytes(int(np.prod(cubic_grid_geometry(box, r, padding)[2], dtype=object)), p, h)

        require(estimate(resolution), option="resolution", value=resolution, largest_fn=estimate, smallest=2,
                what=f"resolution {int(resolution):,} (a {shape[2]:,} x {shape[1]:,} x {shape[0]:,} grid)")
        grid = cubic_grid(box, resolution, padding)
    d, g, _ = _run_mls(p, nrm, h, device, lattice=(grid.origin, grid.spacing, grid.shape))
    if far == "nearest":
        _fill_far(p, nrm, h, device, _lattice_coords(grid.origin, grid.spacing, grid.shape), d, g)
    shape = grid.shape
    return (
        Field(d.reshape(shape), grid.origin, grid.spacing),
        Field(g.reshape(shape + (3,)), grid.origin, grid.spacing),
    )


def project_points(points, normals=None, query=None, *, radius: float | None = None, device: str | None = None):
    """Project query points onto the MLS surface (Adamson and Alexa's quasi-orthogonal
    projection, as in :func:`pointset_distance`).

    Args:
        points, normals, radius, device: as in :func:`pointset_distance`.
        query: (M, 3) float points to project.

    Returns:
        (M, 3) float32 projections; a query with no input point within reach (3h) is
        returned unchanged.

    Raises:
        As :func:`pointset_distance`; a missing ``query`` is a ValueError.
    """
    p, nrm = _prepare(points, normals)
    if query is None:
        raise ValueError("query is required: the (M, 3) points to project.")
    q = _as_query(query)
    h = _as_radius(radius, p)
    _, _, proj = _run_mls(p, nrm, h, device, queries=q, want_proj=True)
    return proj
