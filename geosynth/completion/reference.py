"""What must M4's relief kernels return? A NumPy oracle of FindMatches (Breckon and Fisher,
"Plausible 3D colour surface completion using non-parametric techniques", Sec. 3 and Appendix A),
by the kernels' integer arithmetic.

These oracles are slow, obvious and never on a production path. Each takes the same arguments
as the operation it checks and returns the same result; float sums are accumulated in float64,
uint8 sums in exact integers.
"""

from __future__ import annotations

import numpy as np


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
