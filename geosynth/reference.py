"""What must each kernel return? Implements no paper section: plain oracles of the kernels
the methods use.

Plain NumPy oracles, one per kernel: slow, obvious, never on a production path.

Each takes the same arguments as the operation it checks and returns the same
result; float sums are accumulated in float64, uint8 sums in exact integers.
"""

from __future__ import annotations

import math

import numpy as np

from geosynth.compute.selection import tolerance_threshold


def score_dense_naive(candidates: np.ndarray, queries: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Same arguments and result as :func:`geosynth.score_dense` (float64 or int64 here)."""
    exact = candidates.dtype == np.uint8
    acc = np.int64 if exact else np.float64
    x = candidates.astype(acc)
    q = np.atleast_2d(queries).astype(acc)
    w = np.ones(x.shape[1], acc) if weights is None else np.asarray(weights).astype(acc)
    out = np.empty((q.shape[0], x.shape[0]), acc)
    for b in range(q.shape[0]):
        out[b] = (((x - q[b]) ** 2) * w).sum(axis=1)
    return out[0] if np.ndim(queries) == 1 else out


def score_gather_naive(
    grid: np.ndarray,
    offsets: np.ndarray,
    values: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    origins: np.ndarray | None = None,
    stride=1,
    wrap: bool = False,
) -> np.ndarray:
    """Same arguments and result as :func:`geosynth.score_gather`, one candidate at a time."""
    from geosynth.compute.scoring import candidate_origins

    off = np.asarray(offsets, np.int64)
    k, nd = off.shape
    exact = grid.dtype == np.uint8
    acc = np.int64 if exact else np.float64
    g = grid.astype(acc)
    if g.ndim == nd:
        g = g[..., None]
    dims = np.array(g.shape[:nd])
    vals = np.asarray(values).astype(acc).reshape(k, -1)
    w = np.ones(k, acc) if weights is None else np.asarray(weights).astype(acc)
    if origins is None:
        origins = candidate_origins(grid.shape[:nd], off, stride, wrap)
    out = np.empty(len(origins), acc)
    for i, o in enumerate(np.asarray(origins, np.int64)):
        pos = o + off
        if wrap:
            pos = np.mod(pos, dims)
        window = g[tuple(pos.T)]  # (K, C)
        out[i] = (((window - vals) ** 2).sum(axis=1) * w).sum()
    return out


def argmin_naive(scores: np.ndarray) -> int:
    """Same as :func:`geosynth.argmin`: np.argmin already returns the first minimum."""
    return int(np.argmin(np.ravel(scores)))


def within_tolerance_naive(scores: np.ndarray, eps: float) -> np.ndarray:
    """Same as :func:`geosynth.within_tolerance`."""
    s = np.ravel(scores)
    return np.flatnonzero(s <= tolerance_threshold(s.min(), eps, s.dtype)).astype(np.int64)


def best_fraction_naive(scores: np.ndarray, fraction: float) -> np.ndarray:
    """Same as :func:`geosynth.best_fraction`: sort by (score, index), keep the first k."""
    s = np.ravel(scores)
    k = max(1, math.ceil(fraction * s.size))
    order = np.lexsort((np.arange(s.size), s))
    return np.sort(order[:k]).astype(np.int64)


# ------------------------------------------------------------------ mesh distance oracles


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


# ------------------------------------------------------------------ block pyramid oracles


def box_sums_naive(field: np.ndarray, cell: int) -> np.ndarray:
    """Same result as :meth:`geosynth.volume.pyramid.BlockPyramid.cell_sums`: the exact sum of
    every cell^3 cube of ``field``, (Z - c + 1, Y - c + 1, X - c + 1) int64."""
    from numpy.lib.stride_tricks import sliding_window_view

    return sliding_window_view(field.astype(np.int64), (cell,) * 3).sum(axis=(-3, -2, -1))


def box_means_naive(field: np.ndarray, cell: int) -> np.ndarray:
    """Same result as :meth:`geosynth.volume.pyramid.BlockPyramid.means`: the cube means
    rounded half up, computed in float64 then floor(mean + 1/2), as uint8."""
    return np.floor(box_sums_naive(field, cell) / float(cell) ** 3 + 0.5).astype(np.uint8)


def compare_level_naive(field: np.ndarray, query: np.ndarray, origins: np.ndarray, level: int,
                        rounded: bool = False) -> np.ndarray:
    """Same arguments and result as :func:`geosynth.volume.pyramid.compare_level` (without the
    pyramid): the level's cell sums by reshaping each block, then the integer D."""
    n_block = query.shape[0]
    n = 1 << (level - 1)
    c = n_block // n
    c3 = c ** 3

    def cells(b):
        return np.asarray(b, np.int64).reshape(n, c, n, c, n, c).sum(axis=(1, 3, 5))

    q = cells(query)
    out = []
    for z, y, x in np.asarray(origins, np.int64):
        s = cells(field[z:z + n_block, y:y + n_block, x:x + n_block])
        if rounded:
            m = np.floor(s / c3 + 0.5).astype(np.int64)
            lo = np.maximum(m * c3 - c3 // 2, 0)
            hi = np.minimum(m * c3 + c3 // 2 - 1, 255 * c3)
            d = np.where(q < lo, lo - q, np.where(q > hi, q - hi, 0))
        else:
            d = q - s
        out.append(int((d * d).sum()))
    return np.asarray(out, np.int64)


def nearest_block_naive(field: np.ndarray, query: np.ndarray) -> tuple[tuple[int, int, int], int]:
    """Same result as :meth:`geosynth.volume.tree.BlockSearch.nearest`: the SSD of the query
    against every block, the smallest, the lowest raster index on ties."""
    from numpy.lib.stride_tricks import sliding_window_view

    win = sliding_window_view(field.astype(np.int64), query.shape)  # a cube or a (bz, by, bx) box
    ssd = ((win - query.astype(np.int64)) ** 2).sum(axis=(-3, -2, -1))
    i = int(np.argmin(ssd.reshape(-1)))  # argmin returns the first minimum
    z, y, x = np.unravel_index(i, ssd.shape)
    return (int(z), int(y), int(x)), int(ssd.reshape(-1)[i])


def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross3(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _div3(a, s):  # one division, as the kernels
    r = 1.0 / s
    return [a[0] * r, a[1] * r, a[2] * r]


def _appendix_a(pf, pp, pu, pv, pn, ps, pt, unit):
    """The kernels' appendix_a on Python floats: (ok, qu, qv, normal, T, S, |F - P|)."""
    from geosynth.texturing.parameterize import PARALLEL_LIMIT

    tiny = 1e-300
    v = [pf[0] - pp[0], pf[1] - pp[1], pf[2] - pp[2]]
    dist = math.sqrt(_dot3(v, v))
    v0 = _div3(v, max(dist, tiny))
    along = _dot3(v0, pn)
    if not (dist > 0.0 and abs(along) < PARALLEL_LIMIT):
        return False, 0.0, 0.0, None, None, None, dist
    a, b = _dot3(v, ps), _dot3(v, pt)
    scale = dist / max(math.sqrt(a * a + b * b), tiny) / unit
    m = [pn[i] - along * v0[i] for i in range(3)]
    nn = _div3(m, max(math.sqrt(_dot3(m, m)), tiny))
    vt, vs = _dot3(v0, pt), _dot3(v0, ps)
    c = _cross3(nn, v0)
    tt = [vt * v0[i] + vs * c[i] for i in range(3)]
    return True, pu + a * scale, pv + b * scale, nn, tt, _cross3(tt, nn), dist


def _average_frame(sn, st):
    """The kernels' average_frame: (N, S, T) of weighted sums of normals and T axes."""
    tiny = 1e-300
    n = _div3(sn, max(math.sqrt(_dot3(sn, sn)), tiny))
    tn = _dot3(st, n)
    t = [st[i] - tn * n[i] for i in range(3)]
    t = _div3(t, max(math.sqrt(_dot3(t, t)), tiny))
    return n, _cross3(t, n), t


class _FifoQueue:
    """The kernels' priority queue (kernels/growth.py): one FIFO list per priority
    min(key, n_buckets - 1); ``pop`` gives the first of the highest non-empty list."""

    def __init__(self, n: int, n_buckets: int):
        self.key, self.slot = [0] * n, [-1] * n
        self.lists: list[dict] = [dict() for _ in range(n_buckets)]  # insertion-ordered
        self.top = 0

    @classmethod
    def from_coloured(cls, nb: list, coloured, n_buckets: int) -> "_FifoQueue":
        """Key = coloured points that have the point among their neighbours; the
        uncoloured points with a key queued in index order."""
        queue = cls(len(nb), n_buckets)
        for i, done in enumerate(coloured):
            if done:
                for q in nb[i]:
                    queue.key[q] += 1
        for i, done in enumerate(coloured):
            if not done and queue.key[i] > 0:
                queue.key[i] -= 1
                queue.raise_key(i)
        return queue

    def raise_key(self, q: int) -> None:
        self.key[q] += 1
        b = min(self.key[q], len(self.lists) - 1)
        if self.slot[q] != b:
            if self.slot[q] >= 0:
                del self.lists[self.slot[q]][q]
            self.lists[b][q] = None
            self.slot[q] = b
            self.top = max(self.top, b)

    def pop(self) -> int:
        """The next point, or -1 when every list is empty."""
        while self.top > 0 and not self.lists[self.top]:
            self.top -= 1
        if self.top == 0:
            return -1
        f = next(iter(self.lists[self.top]))
        del self.lists[self.top][f]
        self.slot[f] = -1
        return f


def parameterize_reference(points, k: int = 25, *, unit_scale: float = 1.0, up=(0.0, 1.0, 0.0), weights=None,
                           threshold: float | None = None, max_patch: float | None = None, seed=0, neighbours=None):
    """Same arguments (less ``device``) and result as :func:`geosynth.texturing.parameterize.parameterize_points`:
    the growth of ``kernels/growth.py`` as a plain-Python loop, the same float64
    arithmetic in the same order (so normally the same bits)."""
    from geosynth.texturing.parameterize import (
        DEFAULT_THRESHOLD, DEFAULT_WEIGHTS, FREE, GAP, PATCH, Parameterization, growth_buckets,
        growth_inputs,
    )

    w1, w2, w3, w4 = (float(x) for x in (DEFAULT_WEIGHTS if weights is None else weights))
    threshold = DEFAULT_THRESHOLD if threshold is None else float(threshold)
    g = growth_inputs(points, k, unit_scale=unit_scale, up=up, seed=seed, neighbours=neighbours)
    n, k = g["nb"].shape
    unit, n_buckets, tiny = g["unit"], growth_buckets(k), 1e-300
    pos, nrm, nb = g["pos"].tolist(), g["nrm"].tolist(), g["nb"].tolist()
    state, patch = [FREE] * n, [-1] * n
    queue = _FifoQueue(n, n_buckets)
    key = queue.key
    nan = float("nan")
    uv = [[nan, nan] for _ in range(n)]
    fn, fs, ft = ([[nan] * 3 for _ in range(n)] for _ in range(3))
    distortion = [nan] * n
    seeds = []

    dot, cross, div = _dot3, _cross3, _div3
    for sd in g["order"].tolist():
        if state[sd] != FREE:
            continue
        pid = len(seeds)
        seeds.append(sd)
        state[sd], patch[sd], uv[sd], distortion[sd] = PATCH, pid, [0.0, 0.0], 0.0
        n0 = nrm[sd]
        u = g["dirs"][sd if len(g["dirs"]) > 1 else 0].tolist()
        u = div(u, math.sqrt(dot(u, u)))
        un = dot(u, n0)
        t0 = [u[i] - un * n0[i] for i in range(3)]
        if math.sqrt(dot(t0, t0)) < 1e-3:
            alt = [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0]
            an = dot(alt, n0)
            t0 = [alt[i] - an * n0[i] for i in range(3)]
        tn = dot(t0, n0)
        t0 = [t0[i] - tn * n0[i] for i in range(3)]
        t0 = div(t0, max(math.sqrt(dot(t0, t0)), tiny))
        fn[sd], fs[sd], ft[sd] = list(n0), cross(t0, n0), t0
        lo, hi = [0.0, 0.0], [0.0, 0.0]
        touched, joined = [], sd
        while True:
            if joined >= 0:
                for q in nb[joined]:
                    if state[q] != FREE:
                        continue
                    if key[q] == 0:
                        touched.append(q)
                    queue.raise_key(q)
                joined = -1
            f = queue.pop()
            if f < 0:
                break
            pf, nf = pos[f], nrm[f]
            terms = []
            wsum = su = sv = 0.0
            sn, st = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
            for l in nb[f]:
                if state[l] != PATCH or patch[l] != pid or not dot(nrm[l], nf) > 0.0:
                    continue
                ok, lu, lv, nn, tt, ss, dist = _appendix_a(pf, pos[l], uv[l][0], uv[l][1], fn[l], fs[l], ft[l], unit)
                if not ok:
                    continue
                w = unit / max(dist, tiny)
                terms.append((w, lu, lv, ss, tt))
                wsum += w
                su += w * lu
                sv += w * lv
                sn = [sn[i] + w * nn[i] for i in range(3)]
                st = [st[i] + w * tt[i] for i in range(3)]
            if not terms:
                continue
            inv = 1.0 / wsum
            qu, qv = su * inv, sv * inv
            n_f, s_f, t_f = _average_frame(sn, st)
            pos_sum = pos_max = ori_sum = ori_max = 0.0
            for w, lu, lv, ss, tt in terms:
                du, dv = lu - qu, lv - qv
                dp = w * math.sqrt(du * du + dv * dv)
                dor = w * (2.0 - dot(ss, s_f) - dot(tt, t_f))
                pos_sum += dp
                ori_sum += dor
                pos_max, ori_max = max(pos_max, dp), max(ori_max, dor)
            d = w3 * (w2 * ori_sum * inv + ori_max) + w4 * (w1 * pos_sum * inv + pos_max)
            distortion[f] = d
            accept = d <= threshold
            if accept and max_patch is not None:
                nlo, nhi = [min(lo[0], qu), min(lo[1], qv)], [max(hi[0], qu), max(hi[1], qv)]
                if max(nhi[0] - nlo[0], nhi[1] - nlo[1]) > max_patch:
                    accept = False
                else:
                    lo, hi = nlo, nhi
            if not accept:
                state[f] = GAP
                continue
            state[f], patch[f], uv[f] = PATCH, pid, [qu, qv]
            fn[f], fs[f], ft[f] = n_f, s_f, t_f
            joined = f
        for q in touched:
            key[q] = 0
    return Parameterization(np.asarray(state, np.int8), np.asarray(patch, np.int32), np.asarray(uv), np.asarray(fn),
                            np.asarray(fs), np.asarray(ft), unit, np.asarray(seeds, np.int64),
                            np.asarray(distortion), g["nb"], g["dist"])


def colour_parameterization_reference(points, param, texture, *, tileable: bool = True, seed=0):
    """Same arguments (less ``blend_gaps`` and ``device``) and result as
    :func:`geosynth.texturing.parameterize.colour_parameterization`: the blending of
    ``kernels/growth.py`` (``blend_gaps``) as a plain-Python loop, same arithmetic in the
    same order."""
    from geosynth.texturing.parameterize import PATCH, as_model, growth_buckets, patch_offsets
    from geosynth.texturing.textures import as_texture, sample_bilinear

    p, nrm = as_model(points)
    tex = as_texture(texture)
    h, w = tex.shape[:2]
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    offsets = patch_offsets(param, (h, w), tileable, rng).tolist()
    n, k = param.neighbours.shape
    n_buckets, tiny, unit = growth_buckets(k), 1e-300, param.unit
    pos, nrm_l, nb = p.tolist(), nrm.tolist(), param.neighbours.tolist()
    patch, uv = param.patch.tolist(), param.uv.tolist()
    fn, fs, ft = param.normal.tolist(), param.s_axis.tolist(), param.t_axis.tolist()

    dot = _dot3

    def bilinear(x, y):  # the kernels' lookup is sample_bilinear's, operation for operation
        return sample_bilinear(tex, y, x, tileable).tolist()

    coloured = [s == PATCH for s in param.state.tolist()]
    colours = [bilinear(uv[i][0] + offsets[patch[i]][0], uv[i][1] + offsets[patch[i]][1]) if coloured[i]
               else [0.0, 0.0, 0.0] for i in range(n)]
    queue = _FifoQueue.from_coloured(nb, coloured, n_buckets)
    while True:
        f = queue.pop()
        if f < 0:
            break
        pf, nf = pos[f], nrm_l[f]
        terms, n_coloured, wsum = [], 0, 0.0
        plain, blend = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        for l in nb[f]:
            if not coloured[l]:
                continue
            n_coloured += 1
            plain = [plain[c] + colours[l][c] for c in range(3)]
            pl = patch[l]
            if pl < 0 or not dot(nrm_l[l], nf) > 0.0:
                continue
            ok, lu, lv, nn, tt, _, dist = _appendix_a(pf, pos[l], uv[l][0], uv[l][1], fn[l], fs[l], ft[l], unit)
            if not ok:
                continue
            wl = 1.0 / max(dist, tiny)
            col = bilinear(lu + offsets[pl][0], lv + offsets[pl][1])
            terms.append((wl, pl, lu, lv, nn, tt))
            wsum += wl
            blend = [blend[c] + wl * col[c] for c in range(3)]
        if n_coloured == 0:
            continue
        coloured[f] = True
        if not terms:
            colours[f] = [plain[c] / float(n_coloured) for c in range(3)]
        else:
            colours[f] = [blend[c] / wsum for c in range(3)]
            best, best_total = -1, 0.0
            for _, pj, *_rest in terms:
                total = 0.0
                for t in terms:
                    if t[1] == pj:
                        total += t[0]
                if best < 0 or total > best_total or (total == best_total and pj < best):
                    best, best_total = pj, total
            su = sv = sw = 0.0
            sn, st = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
            for wl, pj, lu, lv, nn, tt in terms:
                if pj != best:
                    continue
                sw += wl
                su += wl * lu
                sv += wl * lv
                sn = [sn[i] + wl * nn[i] for i in range(3)]
                st = [st[i] + wl * tt[i] for i in range(3)]
            n_f, s_f, t_f = _average_frame(sn, st)
            patch[f], uv[f] = best, [su / sw, sv / sw]
            fn[f], fs[f], ft[f] = n_f, s_f, t_f
        for q in nb[f]:
            if not coloured[q]:
                queue.raise_key(q)
    colours_f = np.asarray(colours)
    done = np.asarray(coloured)
    rest = np.flatnonzero(~done)
    if len(rest):
        colours_f[rest] = tex.reshape(-1, 3)[rng.integers(0, h * w, len(rest))]
        done[rest] = True
    return np.clip(np.rint(colours_f), 0, 255).astype(np.uint8), done, np.asarray(offsets)


def match_coherent_reference(level, search, colours, coloured, source, rng, subtexel: bool = True):
    """The coherent matching of ``kernels/growth.py`` (``match_coherent``) as a plain-Python
    loop: same arguments as ``geosynth.texturing.matching.match_coherent_level`` (level, TexelSearch,
    colours (n, 3) uint8, coloured (n,) bool, source (n,) int64, Generator, subtexel), the
    same random draws, the same arithmetic; returns new (colours, coloured, source)."""
    from geosynth.texturing.parameterize import PARALLEL_LIMIT, growth_buckets
    from geosynth.texturing.texel_search import refine_shifts

    n, k = level.neighbours.shape
    order = rng.permutation(n).tolist()
    rand_texel = rng.integers(0, search.h * search.w, n).tolist()
    dy1, dx1, ring = refine_shifts(search.m)
    shifts1 = list(zip(dy1.tolist(), dx1.tolist()))
    m, h, w, pad, tiny = search.m, search.h, search.w, search.pad, 1e-300
    grid = search.host.astype(np.int64)  # (rows, xp, 3)
    xp = grid.shape[1]
    flat = grid.reshape(-1, 3)
    unit, n_buckets = level.unit, growth_buckets(k)
    pos, nrm, s_ax, t_ax = (a.tolist() for a in (level.positions, level.normals, level.s_axis, level.t_axis))
    nb = level.neighbours.tolist()
    colours, coloured, source = colours.copy(), coloured.copy(), source.copy()
    queue = _FifoQueue.from_coloured(nb, coloured.tolist(), n_buckets)

    dot = _dot3

    def error(centre, rel, vals):
        return int(((flat[centre + rel] - vals) ** 2).sum())

    next_order = 0
    while True:
        f = queue.pop()
        if f < 0:
            while next_order < n and coloured[order[next_order]]:
                next_order += 1
            if next_order == n:
                break
            f = order[next_order]
        pf, nf, sf, tf = pos[f], nrm[f], s_ax[f], t_ax[f]
        rel, vals, cand = [], [], []
        for l in nb[f]:
            if not coloured[l]:
                continue
            v = [pos[l][i] - pf[i] for i in range(3)]
            dist = math.sqrt(dot(v, v))
            r = 1.0 / max(dist, tiny)
            along = dot([x * r for x in v], nf)
            a, b = dot(v, sf), dot(v, tf)
            if dist > 0.0 and abs(along) < PARALLEL_LIMIT:
                scale = dist / max(math.sqrt(a * a + b * b), tiny) / unit
                ox, oy = a * scale, b * scale
            else:
                ox, oy = a / unit, b / unit
            dy, dx = int(np.rint(oy * m)), int(np.rint(ox * m))
            rel.append(min(max(dy, -pad), pad) * xp + min(max(dx, -pad), pad))
            vals.append(colours[l].astype(np.int64))
            src = int(source[l])
            if src < 0:
                continue
            cy, cx = src // w - int(np.rint(dy / m)), src % w - int(np.rint(dx / m))
            if search.tileable:
                cy, cx = cy % h, cx % w
            elif not (0 <= cy < h and 0 <= cx < w):
                continue
            if cy * w + cx not in cand:
                cand.append(cy * w + cx)
        if not rel:
            texel = rand_texel[f]
            colours[f] = grid[pad + m * (texel // w), pad + m * (texel % w)]
        else:
            rel_a, vals_a = np.asarray(rel), np.asarray(vals)
            texel, best = -1, None
            for t in cand if cand else range(h * w):
                err = error((pad + m * (t // w)) * xp + pad + m * (t % w), rel_a, vals_a)
                if best is None or err < best or (err == best and t < texel):
                    best, texel = err, t
            cy, cx = pad + m * (texel // w), pad + m * (texel % w)
            by = bx = 0
            if subtexel:
                best = None
                for sy, sx in shifts1:
                    err = error((cy + sy) * xp + cx + sx, rel_a, vals_a)
                    if best is None or err < best:
                        best, by, bx = err, sy, sx
                if ring:
                    oy, ox, best = by, bx, None
                    for a, b in [(0, 0)] + [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)]:
                        sy = min(max(oy + a, -(m // 2)), m - m // 2 - 1)
                        sx = min(max(ox + b, -(m // 2)), m - m // 2 - 1)
                        err = error((cy + sy) * xp + cx + sx, rel_a, vals_a)
                        if best is None or err < best:
                            best, by, bx = err, sy, sx
            colours[f] = grid[cy + by, cx + bx]
        source[f] = texel
        coloured[f] = True
        for q in nb[f]:
            if not coloured[q]:
                queue.raise_key(q)
    return colours, coloured, source


# ------------------------------------------------------------------ M4 FindMatches (kernels/relief.*)


def _relief_tri_d2(ap, ab, ac):
    """Squared distances (n,) float64 from points to triangles, all int64 (n, 3) relative
    to corner a, as the relief kernels compute them (Ericson's regions, exact integer
    tests, one double division of exact integers)."""
    dot = lambda x, y: (x * y).sum(1)  # noqa: E731
    bp, cp = ap - ab, ap - ac
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    vc, vb, va = d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4
    bc = ac - ab
    nrm = np.cross(ab, ac)
    nn = dot(nrm, nrm)
    na = dot(nrm, ap).astype(np.float64)

    def edge(e, p):
        ee = dot(e, e)
        num = dot(p, p) * ee - dot(p, e) ** 2
        return np.where(ee > 0, num.astype(np.float64) / np.maximum(ee, 1).astype(np.float64), dot(p, p).astype(np.float64))

    face = np.where(nn > 0, na * na / np.maximum(nn, 1).astype(np.float64), dot(ap, ap).astype(np.float64))
    out = face
    out = np.where((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), edge(bc, bp), out)
    out = np.where((vb <= 0) & (d2 >= 0) & (d6 <= 0), edge(ac, ap), out)
    out = np.where((d6 >= 0) & (d5 <= d6), dot(cp, cp).astype(np.float64), out)
    out = np.where((vc <= 0) & (d1 >= 0) & (d3 <= 0), edge(ab, ap), out)
    out = np.where((d3 >= 0) & (d4 <= d3), dot(bp, bp).astype(np.float64), out)
    out = np.where((d1 <= 0) & (d2 <= 0), dot(ap, ap).astype(np.float64), out)
    return out


def relief_scores_reference(index, queries, limits=None, slots=None) -> np.ndarray:
    """Same result as :func:`geosynth.completion.matching.score` (``.codes``), by the same integer
    arithmetic in NumPy: (Q, k, R) uint32 codes for the samples ``index.samples[slots]``
    (slots: None = every sample, (k,) for every query, or (Q, k) a row per query where -1
    is no candidate: OVER). Breckon and Fisher, Sec. 3 and Appendix A (FindMatches)."""
    from geosynth.completion import matching as rm

    lim = (np.full(queries.n_queries, rm.CODE_CAP, np.int64) if limits is None
           else np.clip(np.asarray(limits).astype(np.int64), -1, rm.CODE_CAP))
    slots = np.arange(len(index.samples)) if slots is None else np.asarray(slots, np.int64)
    h = index.host
    v = len(h.base)
    deg = np.diff(h.adj_start)
    adj = np.full((v, max(int(deg.max()), 1)), -1, np.int64)  # (V, max degree) neighbours, -1 padded
    for i in range(v):
        adj[i, :deg[i]] = h.adj[h.adj_start[i]:h.adj_start[i + 1]]
    nfan = np.diff(h.fan_start)
    fan = np.full((v, max(int(nfan.max()), 1), 2), -1, np.int64)  # (V, max fan, 2) fan corners, -1 padded
    for i in range(v):
        fan[i, :nfan[i]] = h.fan[h.fan_start[i]:h.fan_start[i + 1]]
    if slots.ndim == 2:
        out = np.full((queries.n_queries, slots.shape[1], queries.rotations), rm.OVER, np.uint32)
        for qi, row in enumerate(slots):
            some = row >= 0
            if some.any():
                out[qi, some] = _relief_one_list(index, queries, lim[qi], row[some], qi, adj, fan)
        return out
    return np.stack([_relief_one_list(index, queries, lim[qi], slots, qi, adj, fan)
                     for qi in range(queries.n_queries)])


def _relief_one_list(index, queries, lim: int, slots: np.ndarray, qi: int, adj: np.ndarray,
                     fan: np.ndarray) -> np.ndarray:
    """(k, R) uint32 codes of query qi (its limit ``lim``) against the samples
    index.samples[slots]; adj, fan: the index's CSR lists padded with -1."""
    from geosynth.completion import matching as rm

    h = index.host
    cand = index.samples[slots].astype(np.int64)
    nr = queries.rotations
    s = np.repeat(cand, nr)
    slot_of = np.repeat(slots, nr)
    r = np.tile(np.arange(nr), len(cand))
    frame = h.frame[s]  # (L, 3, 3) rows u, v, n
    half = rm.FRAME_ONE // 2

    def to_world(c):  # (L, 3) coefficients -> (L, 3) quanta: sum_k c_k * frame_k, rounded
        return (np.einsum("lk,lkx->lx", c, frame) + half) >> 14

    def code_of(acc_s, acc_c, ks, kc):
        xs = np.minimum(acc_s.astype(np.float64) * ks, float(rm.CODE_CAP)).astype(np.int64)
        xc = np.minimum(acc_c.astype(np.float64) * kc, float(rm.CODE_CAP)).astype(np.int64)
        return np.minimum(xs + xc, rm.CODE_CAP)

    lanes = len(s)
    result = np.zeros(lanes, np.int64)
    alive = np.ones(lanes, bool)
    acc_s = np.zeros(lanes, np.int64)
    acc_c = np.zeros(lanes, np.int64)
    prev = s.copy()
    ks, kc = queries.ks[qi], queries.kc[qi]
    for j in range(queries.qstart[qi], queries.qstart[qi + 1]):
        rel = queries.rel[j, r].astype(np.int64)  # (L, 6)
        m = h.base[s] + to_world(rel[:, :3])
        p = m + to_world(rel[:, 3:])
        cur = prev.copy() if queries.chain[j] else s.copy()
        k0 = queries.cell[j, r]
        cur = np.where(k0 >= 0, h.stencil[slot_of, np.maximum(k0, 0)], cur)
        moving = alive.copy()
        for _ in range(rm.MAX_WALK):
            if not moving.any():
                break
            li = np.nonzero(moving)[0]
            c = cur[li]
            best = c.copy()
            bd = ((h.base[c] - m[li]) ** 2).sum(1)
            for k in range(adj.shape[1]):
                u = adj[c, k]
                ok = u >= 0
                du = ((h.base[np.maximum(u, 0)] - m[li]) ** 2).sum(1)
                better = ok & ((du < bd) | ((du == bd) & (u < best)))
                best = np.where(better, u, best)
                bd = np.where(better, du, bd)
            moved = best != c
            cur[li] = best
            moving[li[~moved]] = False
        partner = cur
        prev = np.where(alive, partner, prev)
        bad = alive & ~h.usable[partner]
        result[bad] = rm.INVALID
        alive &= ~bad
        dc = (queries.colour[j].astype(np.int64) - h.colour[partner]) ** 2
        acc_c = np.where(alive, acc_c + int(queries.weight[j]) * dc.sum(1), acc_c)
        code = code_of(acc_s, acc_c, ks, kc)
        over = alive & (code > lim)
        result[over] = rm.OVER
        alive &= ~over
        ap = np.clip(p - h.pos[partner], -rm.CLAMP, rm.CLAMP)
        best_d = np.full(lanes, np.inf)
        best_k = np.full(lanes, -1)
        for k in range(fan.shape[1]):
            b_, c_ = fan[partner, k, 0], fan[partner, k, 1]
            ok = b_ >= 0
            d2 = _relief_tri_d2(ap, h.pos[np.maximum(b_, 0)] - h.pos[partner], h.pos[np.maximum(c_, 0)] - h.pos[partner])
            better = ok & (d2 < best_d)
            best_d = np.where(better, d2, best_d)
            best_k = np.where(better, k, best_k)
        kk = np.maximum(best_k, 0)
        corners_ok = (best_k >= 0) & h.usable[np.maximum(fan[partner, kk, 0], 0)] & \
            h.usable[np.maximum(fan[partner, kk, 1], 0)]
        bad = alive & ~corners_ok
        result[bad] = rm.INVALID
        alive &= ~bad
        d2i = np.where(np.isfinite(best_d), best_d, 0).astype(np.int64)
        acc_s = np.where(alive, acc_s + int(queries.weight[j]) * d2i, acc_s)
        code = code_of(acc_s, acc_c, ks, kc)
        over = alive & (code > lim)
        result[over] = rm.OVER
        alive &= ~over
    result[alive] = code_of(acc_s, acc_c, ks, kc)[alive]
    return result.reshape(len(cand), nr).astype(np.uint32)
