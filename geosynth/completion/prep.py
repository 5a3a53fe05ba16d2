"""Which samples and targets, in which triangulation? Breckon and Fisher, "Plausible 3D
colour surface completion using non-parametric techniques", Sec. 3 (displacement vectors,
targets, the combined triangulation, W-ring neighbourhoods), Sec. 4 (target spacing at the
minimum edge length; the capture oversampled once by 1-to-4 subdivision) and Sec. 6 (new
samples coloured by a Gaussian-weighted sum of their k nearest neighbours).

:func:`prepare_relief` turns a capture and its :class:`~geosynth.completion.fit.SurfaceFit`
into a :class:`ReliefSurface`: every vertex (samples first, then targets) with its base
position on the fit, the fit's normal there (the corrected normal), the paper's tangent
frame, its displacement ``D = position - base`` (zero for targets), colour, and one
triangulation of samples and targets over the fit's parameter domain:

- plane: ``scipy.spatial.Delaunay`` of the (u, v) parameters;
- cylinder: Delaunay of (R * angle, height); over a full circle the vertices near the seam
  are copied one period to either side, and a triangle is kept once, by the copy whose
  first corner lies in the period;
- sphere: the convex hull of the unit directions (``scipy.spatial.ConvexHull``), which
  is the spherical Delaunay triangulation and has no seam.

Triangles with an edge longer than 3x the target spacing (across a concave border of
the capture or of the region) are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geosynth.completion.fit import SurfaceFit, tangent_frames
from geosynth.compute.checks import as_points3
from geosynth.core.exact import exp_fixed, norm3

__all__ = ["TARGET_SPACINGS", "Capture", "ReliefSurface", "as_capture", "capture_depth", "check_spacing_rule",
           "prepare_relief", "ring_neighbourhoods", "target_spacing"]

TARGET_SPACINGS = ("minimum", "median")  # prepare_relief(spacing=): the paper's minimum edge, or the median on the fit

_LONG_EDGE = 3.0  # triangles with an edge over 3x the spacing are dropped
_MISSING = 0.6  # a target lies in the missing part when its nearest sample is over 0.6x the spacing away
_KNN = 8  # neighbours of the Gaussian-weighted kNN colour of a new sample
_FLOOR = 0.5  # the spacing is never below 0.5x the captured part's median edge length


@dataclass
class Capture:
    """A captured surface part: (N, 3) float64 positions, optional (N, 3) uint8 colours,
    optional (F, 3) int64 triangles, optional (N, 3) normals, optional (N,) uint8 alpha of
    the colours (the file gave one: it is copied with the colours and written back)."""

    positions: np.ndarray
    colors: np.ndarray | None = None
    faces: np.ndarray | None = None
    normals: np.ndarray | None = None
    alpha: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.positions)


def as_capture(capture) -> Capture:
    """A :class:`Capture` from a Capture, a ``trimesh.Trimesh`` (its vertex colours when it
    has them), a :class:`geosynth.geometry.pointsets.PointSet`, or an (N, 3) array; checked.

    Raises:
        ValueError: NaN/inf positions (how many, the first index), duplicated positions (how
            many, the first), colours or normals of the wrong shape, face indices out of range.
    """
    alpha = None
    if isinstance(capture, Capture):
        pos, col, faces, nrm = capture.positions, capture.colors, capture.faces, capture.normals
        alpha = capture.alpha
    elif hasattr(capture, "vertices") and hasattr(capture, "faces"):
        pos, faces, nrm = np.asarray(capture.vertices), np.asarray(capture.faces), None
        col = None
        visual = getattr(capture, "visual", None)
        if visual is not None and getattr(visual, "kind", None) in ("vertex", "face"):  # face colours: per vertex
            rgba = np.asarray(visual.vertex_colors)
            col = rgba[:, :3]
            # the alpha when the file gave one (geosynth's readers say so) or when it is not opaque
            given = getattr(capture, "metadata", {}).get("alpha_given")
            if rgba.shape[1:] == (4,) and (given or (given is None and (rgba[:, 3] != 255).any())):
                alpha = rgba[:, 3]
    elif hasattr(capture, "positions"):
        pos, col, faces, nrm = capture.positions, getattr(capture, "colors", None), None, getattr(capture, "normals", None)
        alpha = getattr(capture, "alpha", None)
    else:
        pos, col, faces, nrm = capture, None, None, None
    pos = as_points3("the capture's positions", pos, finite=False)  # bad rows are reported below, by index
    bad = ~np.isfinite(pos).all(1)
    if bad.any():
        raise ValueError(f"the capture has {int(bad.sum())} position(s) with NaN or inf coordinates (the first: "
                         f"index {int(np.argmax(bad))}); remove those points.")
    n = len(pos)
    _, first, inverse = np.unique(pos, axis=0, return_index=True, return_inverse=True)
    if len(first) < n:  # coincident points: one position, two samples (their triangulation has no room for both)
        copies = np.flatnonzero(first[inverse.ravel()] != np.arange(n))
        raise ValueError(f"the capture has {len(copies)} duplicated point(s) (the first: index {int(copies[0])}, at "
                         f"the position of index {int(first[inverse.ravel()[copies[0]]])}); remove the duplicates.")
    if col is not None:
        c = np.asarray(col)
        if c.shape != (n, 3):
            raise ValueError(f"the capture's colours must have shape ({n}, 3) (RGB, one per position), got {c.shape}.")
        if c.dtype != np.uint8:
            if c.dtype.kind == "f" and np.isfinite(c).all() and c.min() >= 0 and c.max() <= 1:
                c = np.round(c * 255)
            if not np.isfinite(c).all() or c.min() < 0 or c.max() > 255:
                raise ValueError("the capture's colours must be 0..255 (uint8) or 0..1 (float).")
            c = c.astype(np.uint8)
        col = np.ascontiguousarray(c)
    if alpha is not None:
        a = np.asarray(alpha)
        if col is None or a.shape != (n,) or a.dtype != np.uint8:
            raise ValueError(f"the capture's alpha must be ({n},) uint8 beside its colours, got {a.shape} {a.dtype}"
                             + ("" if col is not None else " without colours") + ".")
        alpha = np.ascontiguousarray(a)
    if faces is not None:
        faces = np.asarray(faces, dtype=np.int64)
        if faces.size == 0:
            faces = None
        elif faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= n:
            raise ValueError(f"the capture's faces must be (F, 3) vertex indices in 0..{n - 1}.")
    if nrm is not None:
        nrm = np.asarray(nrm, dtype=np.float64)
        if nrm.shape != (n, 3):
            raise ValueError(f"the capture's normals must have shape ({n}, 3), got {nrm.shape}.")
    return Capture(pos, col, faces, nrm, alpha)


@dataclass
class ReliefSurface:
    """Samples and targets in one triangulation (Sec. 3). Vertices ``0..n_samples-1`` are
    samples (the first ``n_original`` the captured vertices, then the oversampling's new
    ones), the rest targets.

    Attributes:
        fit: the :class:`SurfaceFit`.
        base: (V, 3) float64 projections on the fit (``s - D(s)``).
        normals: (V, 3) float64 unit normals of the fit at ``base`` (the corrected normals).
        frame_u, frame_v: (V, 3) float64 the paper's tangent frames at ``base``.
        displacement: (V, 3) float64 ``D``; zero for targets until they are textured.
        colors: (V, 3) uint8 (zero for targets until they are textured); None without colour.
        alpha: (V,) uint8 alpha of the colours, as ``colors`` (None when the capture gave none).
        faces: (F, 3) int32 triangles of samples and targets.
        param: (V, 2) float64 parameters on the fit (:meth:`SurfaceFit.to_param`).
        n_samples, n_original: counts (see above).
        spacing: the target spacing (the captured part's minimum edge length, Sec. 4, or
            the median length of its edges on the fit: ``prepare_relief(spacing=)``).
        adjacency: (indptr, indices) int64 CSR of the triangulation's edges.
    """

    fit: SurfaceFit
    base: np.ndarray
    normals: np.ndarray
    frame_u: np.ndarray
    frame_v: np.ndarray
    displacement: np.ndarray
    colors: np.ndarray | None
    faces: np.ndarray
    param: np.ndarray
    n_samples: int
    n_original: int
    spacing: float
    adjacency: tuple[np.ndarray, np.ndarray]
    alpha: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return len(self.base)

    @property
    def n_targets(self) -> int:
        return self.n_vertices - self.n_samples

    @property
    def positions(self) -> np.ndarray:
        """(V, 3) float64 current positions ``base + D``."""
        return self.base + self.displacement


# ---------------------------------------------------------------------- triangulation


def _plane_coords(fit: SurfaceFit, param: np.ndarray) -> np.ndarray:
    if fit.kind == "cylinder":
        return np.stack([param[:, 0] * fit.radius, param[:, 1]], 1)
    return param


def _triangulate(fit: SurfaceFit, base: np.ndarray, param: np.ndarray) -> np.ndarray:
    """(F, 3) int64 triangles of the vertices' base positions over the parameter domain."""
    from scipy.spatial import ConvexHull, Delaunay

    if fit.kind == "sphere":
        d = base - fit.center
        d /= norm3(d)[:, None]
        hull = ConvexHull(d)
        faces = hull.simplices.astype(np.int64)
        if len(np.unique(faces)) < len(d):
            raise ValueError("the sphere triangulation lost vertices (points too close together on the sphere).")
        return faces
    q = _plane_coords(fit, param)
    if fit.kind == "cylinder":  # always across the seam; triangles over a gap are dropped as long
        period = 2 * math.pi * fit.radius
        width = period / 8
        lo, hi = q[:, 0] < width, q[:, 0] > period - width
        ids = np.concatenate([np.arange(len(q)), np.flatnonzero(lo), np.flatnonzero(hi)])
        qq = np.concatenate([q, q[lo] + [period, 0], q[hi] - [period, 0]])
        tri = Delaunay(qq).simplices
        # keep a triangle once: the copy whose lowest-x corner lies in [0, period)
        xs = qq[tri, 0]
        first = xs.min(1)
        keep = (first >= 0) & (first < period)
        faces = ids[tri[keep]]
        faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
        return faces.astype(np.int64)
    return Delaunay(q).simplices.astype(np.int64)


def _drop_long(faces: np.ndarray, points: np.ndarray, limit: float) -> np.ndarray:
    e = np.stack([norm3(points[faces[:, i]] - points[faces[:, (i + 1) % 3]]) for i in range(3)], 1)
    return faces[e.max(1) <= limit]


def _orient(faces: np.ndarray, base: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Triangles wound counter-clockwise seen from the fit's outside."""
    a, b, c = (base[faces[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    flip = (n * normals[faces].mean(1)).sum(1) < 0
    out = faces.copy()
    out[flip, 1], out[flip, 2] = faces[flip, 2], faces[flip, 1]
    return out


def _edges(faces: np.ndarray) -> np.ndarray:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0)


def _csr(faces: np.ndarray, n: int):
    from scipy import sparse

    e = _edges(faces)
    rows = np.concatenate([e[:, 0], e[:, 1]])
    cols = np.concatenate([e[:, 1], e[:, 0]])
    a = sparse.csr_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n))
    a.sum_duplicates()
    a.sort_indices()
    return a


def ring_neighbourhoods(adjacency: tuple[np.ndarray, np.ndarray], rows: np.ndarray, window: int):
    """The W-ring neighbourhoods N(v) (Sec. 3, Fig. 4): the vertices within ``window`` edge
    connections of each vertex of ``rows``, by powers of the CSR adjacency.

    Args:
        adjacency: (indptr, indices) CSR of the triangulation's edges (V vertices).
        rows: (M,) vertex indices.
        window: W >= 1.

    Returns:
        (indptr (M+1,) int64, indices (K,) int64, ring (K,) int8): for row i, the vertices
        ``indices[indptr[i]:indptr[i+1]]`` (sorted, the vertex itself excluded) and their ring
        distance 1..W.
    """
    from scipy import sparse

    indptr, indices = adjacency
    n = len(indptr) - 1
    a = sparse.csr_matrix((np.ones(len(indices), dtype=np.int32), indices, indptr), shape=(n, n))
    a = (a + sparse.identity(n, dtype=np.int32, format="csr")).tocsr()
    rows = np.asarray(rows, dtype=np.int64)
    reach = a[rows]
    count = (reach > 0).astype(np.int32)
    for _ in range(window - 1):
        reach = (reach @ a)
        reach.data[:] = 1
        count = count + reach
    count = count.tocsr()
    count.sort_indices()
    ring = (window + 1 - count.data).astype(np.int8)
    # drop the vertex itself (ring 0)
    own = np.repeat(rows, np.diff(count.indptr)) == count.indices
    keep = ~own
    counts = np.add.reduceat(keep.astype(np.int64), count.indptr[:-1]) if len(rows) else np.zeros(0, np.int64)
    counts[np.diff(count.indptr) == 0] = 0
    out_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return out_ptr, count.indices[keep].astype(np.int64), ring[keep]


def capture_depth(rs: "ReliefSurface") -> np.ndarray:
    """(n_original,) float64: how far (world units, between base positions on the fit) each
    of the capture's own vertices lies from the captured part's border: the distance to the
    nearest target or vertex of a border edge (an edge of one triangle). A target's W-ring
    neighbourhood reaches about W target spacings, so a candidate whose depth is below
    ``W * rs.spacing`` is matched partly against the border's samples, not against captured
    relief (:func:`geosynth.completion.synthesis.complete_surface` counts and checks them)."""
    from geosynth.core.neighbours import nearest

    f = np.sort(rs.faces.astype(np.int64), axis=1)
    edges, count = np.unique(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [0, 2]]]), axis=0, return_counts=True)
    sources = np.union1d(np.arange(rs.n_samples, rs.n_vertices), edges[count == 1].ravel())
    if len(sources) == 0:
        return np.full(rs.n_original, np.inf)
    return nearest(rs.base[sources], rs.base[: rs.n_original])[0][:, 0]


# ---------------------------------------------------------------------- targets


def _lattice(fit: SurfaceFit, region, delta: float, periodic: bool) -> np.ndarray:
    """(T, 2) parameters of a hexagonal lattice of spacing ``delta`` (lengths on the fit) over the region."""
    (a0, a1), (b0, b1) = region
    if fit.kind == "plane":
        dy = delta * math.sqrt(3) / 2
        ny = max(1, int(math.floor((b1 - b0) / dy)) + 1)
        nx = max(1, int(math.floor((a1 - a0) / delta)) + 1)
        j, i = np.mgrid[0:ny, 0:nx]
        u = a0 + (i + 0.5 * (j % 2)) * delta
        v = b0 + j * dy
        q = np.stack([u.ravel(), v.ravel()], 1)
        return q[(q[:, 0] <= a1 + 1e-9)]
    if fit.kind == "cylinder":
        r = fit.radius
        span = a1 - a0
        dy = delta * math.sqrt(3) / 2
        ny = max(1, int(math.floor((b1 - b0) / dy)) + 1)
        nx = max(1, int(math.ceil(span * r / delta))) if periodic else max(1, int(math.floor(span * r / delta)) + 1)
        step = span / nx if periodic else delta / r
        j, i = np.mgrid[0:ny, 0:nx]
        ang = a0 + (i + 0.5 * (j % 2)) * step
        q = np.stack([np.mod(ang.ravel(), 2 * math.pi) if periodic else ang.ravel(), (b0 + j * dy).ravel()], 1)
        return q if periodic else q[q[:, 0] <= a1 + 1e-9]
    # sphere: a Fibonacci lattice over the whole sphere at the spacing, restricted to the region
    r = fit.radius
    count = int(math.ceil(4 * math.pi * r * r / (delta * delta * math.sqrt(3) / 2)))
    k = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * k / count)
    az = np.mod(math.pi * (1 + math.sqrt(5)) * k, 2 * math.pi)
    inside = (polar >= b0 - 1e-12) & (polar <= b1 + 1e-12)
    if not (a0 <= 0 and a1 >= 2 * math.pi):
        inside &= (az >= a0) & (az <= a1)
    return np.stack([az[inside], polar[inside]], 1)


def _check_region(fit: SurfaceFit, region) -> tuple[tuple[float, float], tuple[float, float]]:
    try:
        (a0, a1), (b0, b1) = region
        a0, a1, b0, b1 = (float(x) for x in (a0, a1, b0, b1))
    except (TypeError, ValueError):
        raise ValueError(f"region must be two (low, high) ranges of the {fit.kind}'s parameters, got {region!r}.") from None
    if not all(math.isfinite(x) for x in (a0, a1, b0, b1)) or a1 <= a0 or b1 <= b0:
        raise ValueError(f"region {region!r} is empty: each range must be finite with low < high.")
    if fit.kind == "sphere" and (b0 < 0 or b1 > math.pi):
        raise ValueError(f"region {region!r}: a sphere's polar range lies within [0, pi].")
    if fit.kind != "plane" and a1 - a0 > 2 * math.pi + 1e-9:
        raise ValueError(f"region {region!r}: the angle range spans more than 2 pi.")
    return (a0, a1), (b0, b1)


# ---------------------------------------------------------------------- preparation


def _capture_faces(cap: Capture, fit: SurfaceFit, base: np.ndarray, param: np.ndarray) -> np.ndarray:
    if cap.faces is not None:
        return cap.faces
    return _triangulate(fit, base, param)


def _gaussian_knn_colours(points: np.ndarray, colors: np.ndarray, queries: np.ndarray, sigma: float) -> np.ndarray:
    from geosynth.core.neighbours import nearest

    k = min(_KNN, len(points))
    d, i = nearest(points, queries, k)
    w = exp_fixed(-(d / sigma) ** 2)  # not np.exp: AVX-512's rounds otherwise (issue 40)
    w /= w.sum(1, keepdims=True)
    return np.clip(np.round((w[:, :, None] * colors[i].astype(np.float64)).sum(1)), 0, 255).astype(np.uint8)


def _edge_points(points: np.ndarray, faces: np.ndarray, edges: np.ndarray, fit: SurfaceFit) -> np.ndarray:
    """(E, 3) new vertices of the 1-to-4 subdivision: on the fit below each edge's midpoint,
    at the height (signed distance to the fit) of the interpolating butterfly rule of Dyn,
    Levin and Gregory (1/2 the edge's ends, 1/8 the two opposite vertices, -1/16 the four
    wing vertices); the chord midpoint where the stencil is incomplete (the border)."""
    h = fit.distance(points)
    opposite: dict[tuple[int, int], list[int]] = {}
    for a, b, c in faces.tolist():
        for x, y, z in ((a, b, c), (b, c, a), (c, a, b)):
            opposite.setdefault((min(x, y), max(x, y)), []).append(z)

    def other(x: int, y: int, not_z: int):
        o = [z for z in opposite.get((min(x, y), max(x, y)), ()) if z != not_z]
        return o[0] if len(o) == 1 else None

    out = 0.5 * (points[edges[:, 0]] + points[edges[:, 1]])
    base = fit.project(out)
    normal = fit.normal(out)
    for i, (a, b) in enumerate(edges.tolist()):
        opp = opposite.get((a, b), ())
        if len(opp) != 2:
            continue
        c, d = opp
        wings = [other(a, c, b), other(b, c, a), other(a, d, b), other(b, d, a)]
        if any(w is None for w in wings):
            continue
        hh = 0.5 * (h[a] + h[b]) + 0.125 * (h[c] + h[d]) - 0.0625 * sum(h[w] for w in wings)
        out[i] = base[i] + hh * normal[i]
    return out


def check_spacing_rule(spacing) -> str:
    """``spacing`` if it is one of TARGET_SPACINGS or a positive finite length (world units,
    an explicit target spacing; issue 32's automatic choice), else a one-line ValueError."""
    if isinstance(spacing, (float, int, np.floating, np.integer)) and not isinstance(spacing, (bool, np.bool_)):
        if math.isfinite(float(spacing)) and float(spacing) > 0:
            return spacing
    if not isinstance(spacing, str) or spacing not in TARGET_SPACINGS:
        raise ValueError(f"spacing must be one of {', '.join(map(repr, TARGET_SPACINGS))} or a length > 0, "
                         f"got {spacing!r}.")
    return spacing


def _sampling(capture: Capture, fit: SurfaceFit, spacing: str | float):
    """(base, param, faces, edges, median, delta): the capture's positions on the fit, their
    parameters, its triangles (over-long ones dropped), their edges, the median 3-D edge
    length (over every triangle) and the target spacing the rule ``spacing`` gives."""
    base0 = fit.project(capture.positions)
    param0 = fit.to_param(capture.positions)
    faces0 = _capture_faces(capture, fit, base0, param0)
    e = _edges(faces0)
    lengths = norm3(capture.positions[e[:, 0]] - capture.positions[e[:, 1]])
    if len(lengths) == 0:
        raise ValueError("the capture has no triangle to measure its sampling; give more points.")
    med = float(np.median(lengths))
    faces0 = _drop_long(faces0, capture.positions, _LONG_EDGE * med)
    e = _edges(faces0)
    lengths = norm3(capture.positions[e[:, 0]] - capture.positions[e[:, 1]])
    if not isinstance(spacing, str):
        delta = max(float(spacing), _FLOOR * med)
    elif spacing == "minimum":
        delta = max(float(lengths.min()), _FLOOR * med)  # Sec. 4: targets at the minimum edge length
    else:
        # as dense as the capture's own sampling where the targets lie: its edges on the fit (the
        # 3-D lengths grow with the relief's slope and would space the targets wider than the capture)
        delta = float(np.median(norm3(base0[e[:, 0]] - base0[e[:, 1]])))
    return base0, param0, faces0, e, med, delta


def target_spacing(capture: Capture, fit: SurfaceFit, spacing: str | float = "minimum") -> float:
    """The target spacing :func:`prepare_relief` gives a capture under the rule ``spacing``
    ("minimum", "median" or a length; see there), before any target is made: what the
    automatic settings weigh the relief's period against (the targets' count, and so the
    cost, goes with the inverse square of it).

    Raises:
        ValueError: a bad rule; the capture has no triangle.
    """
    check_spacing_rule(spacing)
    return _sampling(as_capture(capture), fit, spacing)[-1]


def prepare_relief(capture: Capture, fit: SurfaceFit, region=None, max_targets: int | None = None,
                   oversample: str = "butterfly", spacing: str | float = "minimum") -> ReliefSurface:
    """Samples, targets and their triangulation for a capture over its fit (Sec. 3, 4, 6).

    Args:
        capture: the captured part (:func:`as_capture`).
        fit: its :class:`SurfaceFit`.
        region: ((low, high), (low, high)) parameter ranges to complete (plane: u, v
            lengths; sphere: azimuth, polar angle; cylinder: angle, height), or None for
            :meth:`SurfaceFit.default_region`.
        max_targets: refuse more targets than this (None: no limit).
        oversample: "butterfly" (default): each new vertex at the butterfly rule's height
            over the fit (an interpolating subdivision: it adds no detail, but the paper's
            coplanar midpoints lie on chords and lowered the mean relief height of the
            samples by 2-11% on the built-ins, a bias every copy inherits); "midpoint":
            the paper's coplanar midpoints; "none": no oversampling (a capture already
            much denser than the targets has the phases the oversampling is for).
        spacing: a length (world units on the fit): the targets' spacing as given (the
            automatic choice of :func:`geosynth.completion.synthesis.complete_surface` for a capture
            much denser than its relief needs; not below 0.5x the capture's median edge). Or the
            target lattice's spacing. "minimum" (default, the paper's Sec. 4):
            the capture's minimum edge length (at least 0.5x its median), so that the
            targets are at least as dense as the capture everywhere. "median" (our option):
            the median length of the capture's edges on the fit (between their base
            positions, where the targets lie; the 3-D lengths grow with the relief's slope:
            the wave's median 3-D edge is 0.0547 on a 0.05 lattice), so that the targets are
            as dense as the capture's own sampling. Why: a coherent completion copies a
            feature at the capture's sampling limit (one sample row thick) sample for
            sample, so on a lattice denser than the capture it covers a smaller share of the
            targets than of the capture's vertices, and the Table 1 volume integral (a mean
            over vertices) comes out low by about the density ratio. The tower: minimum edge
            0.0522 (in the arch recesses, 5% inside the wall) against the median 0.0548 on
            the fit; 40 target rows over the height against the capture's 38, its one-row
            ledges 4 rows in both (10.0% of the targets, 10.5% of the capture); the relief
            itself sampled at those targets has a mean |h| 1.08% below the capture's
            (m4spacing in `git log -p bench/RESULTS.md`).

    Returns:
        The :class:`ReliefSurface`.

    Raises:
        ValueError: the region is malformed or holds no missing part; the capture has no
            triangle; too many targets.
    """
    from geosynth.core.neighbours import nearest

    if oversample not in ("butterfly", "midpoint", "none"):
        raise ValueError(f"oversample must be 'butterfly', 'midpoint' or 'none', got {oversample!r}.")
    check_spacing_rule(spacing)
    base0, param0, faces0, e, med, delta = _sampling(capture, fit, spacing)

    # Sec. 4: oversample the capture once, 1-to-4 (a new vertex at each edge's midpoint).
    n0 = len(capture.positions)
    if oversample == "none":
        mid = np.zeros((0, 3))
    elif oversample == "butterfly":
        mid = _edge_points(capture.positions, faces0, e, fit)
    else:
        mid = 0.5 * (capture.positions[e[:, 0]] + capture.positions[e[:, 1]])
    sample_pos = np.concatenate([capture.positions, mid])
    colors = None
    if capture.colors is not None:
        new = _gaussian_knn_colours(capture.positions, capture.colors, mid, sigma=0.5 * med)
        colors = np.concatenate([capture.colors, new])
    alpha = None
    if capture.alpha is not None:  # the alpha as a fourth channel of the same interpolation
        new = _gaussian_knn_colours(capture.positions, capture.alpha[:, None], mid, sigma=0.5 * med)
        alpha = np.concatenate([capture.alpha, new[:, 0]])
    sample_base = fit.project(sample_pos)
    n_samples = len(sample_pos)

    # Targets on the missing part of the region.
    region = fit.default_region(param0) if region is None else _check_region(fit, region)
    periodic = fit.kind == "cylinder" and region[0][1] - region[0][0] >= 2 * math.pi - 1e-9
    tq = _lattice(fit, region, delta, periodic)
    tbase = fit.from_param(tq)
    if len(tbase):
        dist = nearest(sample_base, tbase)[0][:, 0]
        tbase, tq = tbase[dist > _MISSING * delta], tq[dist > _MISSING * delta]
    if len(tbase) == 0:
        raise ValueError(f"the region to complete {tuple(region)} is empty: the capture already covers it (or it "
                         f"holds no target at spacing {delta:.4g}); give a larger region.")
    if max_targets is not None and len(tbase) > max_targets:
        raise ValueError(f"the completion has {len(tbase):,} targets (spacing {delta:.4g}), over the limit of "
                         f"{max_targets:,}; give a smaller region or a coarser capture.")

    base = np.concatenate([sample_base, tbase])
    param = np.concatenate([fit.to_param(sample_pos), tq])
    normals = fit.normal(base)
    displacement = np.concatenate([sample_pos - sample_base, np.zeros_like(tbase)])
    if colors is not None:
        colors = np.concatenate([colors, np.zeros((len(tbase), 3), np.uint8)])
    if alpha is not None:
        alpha = np.concatenate([alpha, np.zeros(len(tbase), np.uint8)])
    faces = _triangulate(fit, base, param)
    faces = _drop_long(faces, base, _LONG_EDGE * delta)
    faces = _orient(faces, base, normals)
    a = _csr(faces, len(base))
    u, v = tangent_frames(normals)
    return ReliefSurface(fit=fit, base=base, normals=normals, frame_u=u, frame_v=v, displacement=displacement,
                         colors=colors, faces=faces.astype(np.int32), param=param, n_samples=n_samples,
                         n_original=n0, spacing=delta,
                         adjacency=(a.indptr.astype(np.int64), a.indices.astype(np.int64)), alpha=alpha)
