"""What must M3's growth and texel kernels return? Plain-Python oracles of the
parameterization (Zhang, Qiu and Kaufman, "Fast Hybrid Approach for Texturing Point Models",
Sec. 3 and Appendix A), of its colouring, and of the coherent texel matching.

These oracles are slow, obvious and never on a production path. Each takes the same arguments
as the operation it checks and returns the same result; float sums are accumulated in float64,
uint8 sums in exact integers.
"""

from __future__ import annotations

import math

import numpy as np


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
