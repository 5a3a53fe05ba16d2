"""Which captured sample's neighbourhood best matches a target's? Breckon and Fisher,
"3D Surface Relief and Colour Completion", Sec. 3, 6 and Appendix A (FindMatches).

M4 FindMatches: every target neighbourhood of a batch against every candidate sample at
every rotation, one thread per (query, candidate, rotation). Warp kernels.

The twin of ``relief.cl`` (same kernel names without ``_kernel``, same arguments in the
same order). Integer arithmetic throughout (positions in quanta, frames scaled by
FRAME_ONE = 2^14, colours 0..255, integer weights); the only floating-point operations
are single IEEE double multiplications and divisions of exact integers, truncated, so
every device returns the same bits (geosynth.completion.matching defines the codes and
geosynth.completion.reference.relief_scores_reference is the NumPy twin).

- ``relief_scores_kernel`` (launched over (Q, R, n_cand): neighbouring threads share the
  rotation, as the OpenCL work-items): for query q, candidate s = samples[slot], slot =
  cand[q * cand_stride + c] (cand_stride 0: one list for every query; a slot -1: OVER),
  rotation r, each entry j of q in order: the moved base m = base[s] + the
  entry's first three coefficients on s's frame rows (rounded: (x + 2^13) >> 14), the
  moved point p = m + the last three; the partner = a greedy walk over adj from
  stencil[slot, cell[j, r]] (else from the previous entry's partner when chain[j], else s) to the vertex of smallest (squared
  distance of its base to m, id); INVALID if the partner is not usable (a sample, or textured: ReliefIndex.build's partners); add the colour
  term w * |c_j - colour[partner]|^2, stop as OVER if the code passes limit[q]; add
  w * trunc(min over the partner's fan of the squared distance from p to the triangle),
  INVALID if the closest triangle has a corner not usable, OVER test again. The code is
  min(floor(acc_shape * ks) + floor(acc_colour * kc), CODE_CAP), each floor clamped at
  CODE_CAP first.
- ``relief_update_kernel`` (launched over n): scattered writes of texturing.

Host wrappers live in ``geosynth._backends.warp_relief``; nothing here validates.
"""

import warp as wp

vec3l = wp.types.vector(length=3, dtype=wp.int64)

CLAMP = wp.constant(wp.int64(1 << 13))  # |p - partner| components clamp here (quanta)
MAX_WALK = wp.constant(256)  # most steps of one partner walk
CODE_CAP = wp.constant(wp.int64(1 << 31))  # (a literal 1 << 31 in a kernel is an int32 shift)
CAP_F = wp.constant(wp.float64(1 << 31))
HALF = wp.constant(wp.int64(1 << 13))  # rounding of the frame products
OVER = wp.constant(wp.int64(0xFFFFFFFE))
INVALID = wp.constant(wp.int64(0xFFFFFFFF))


@wp.func
def _at3(a: wp.array(dtype=wp.int32), i: int) -> vec3l:
    return vec3l(wp.int64(a[3 * i]), wp.int64(a[3 * i + 1]), wp.int64(a[3 * i + 2]))


@wp.func
def _to_world(c0: wp.int64, c1: wp.int64, c2: wp.int64, fu: vec3l, fv: vec3l, fn: vec3l) -> vec3l:
    x = fu * c0 + fv * c1 + fn * c2
    h = HALF
    return vec3l((x[0] + h) >> wp.int64(14), (x[1] + h) >> wp.int64(14), (x[2] + h) >> wp.int64(14))


@wp.func
def _len2(a: vec3l) -> wp.int64:
    return wp.dot(a, a)


@wp.func
def _edge_d2(e: vec3l, p: vec3l) -> wp.float64:
    ee = wp.dot(e, e)
    pp = wp.dot(p, p)
    if ee <= wp.int64(0):
        return wp.float64(pp)
    pe = wp.dot(p, e)
    return wp.float64(pp * ee - pe * pe) / wp.float64(ee)


@wp.func
def _tri_d2(ap: vec3l, ab: vec3l, ac: vec3l) -> wp.float64:
    """Squared distance from a point to a triangle, corner a at the origin (Ericson's
    regions: exact integer tests, then one double division of exact integers)."""
    bp = ap - ab
    cp = ap - ac
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= wp.int64(0) and d2 <= wp.int64(0):
        return wp.float64(_len2(ap))
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= wp.int64(0) and d4 <= d3:
        return wp.float64(_len2(bp))
    vc = d1 * d4 - d3 * d2
    if vc <= wp.int64(0) and d1 >= wp.int64(0) and d3 <= wp.int64(0):
        return _edge_d2(ab, ap)
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= wp.int64(0) and d5 <= d6:
        return wp.float64(_len2(cp))
    vb = d5 * d2 - d1 * d6
    if vb <= wp.int64(0) and d2 >= wp.int64(0) and d6 <= wp.int64(0):
        return _edge_d2(ac, ap)
    va = d3 * d6 - d5 * d4
    if va <= wp.int64(0) and (d4 - d3) >= wp.int64(0) and (d5 - d6) >= wp.int64(0):
        return _edge_d2(ac - ab, bp)
    n = wp.cross(ab, ac)
    nn = wp.dot(n, n)
    if nn <= wp.int64(0):
        return wp.float64(_len2(ap))
    na = wp.float64(wp.dot(n, ap))
    return na * na / wp.float64(nn)


@wp.func
def _code(acc_s: wp.int64, acc_c: wp.int64, ks: wp.float64, kc: wp.float64) -> wp.int64:
    cap = CAP_F
    xs = wp.min(wp.float64(acc_s) * ks, cap)
    xc = wp.min(wp.float64(acc_c) * kc, cap)
    return wp.min(wp.int64(xs) + wp.int64(xc), CODE_CAP)


@wp.kernel
def relief_scores_kernel(
    base: wp.array(dtype=wp.int32),  # (V * 3,) base positions, quanta
    frame: wp.array(dtype=wp.int32),  # (V * 9,) frame rows u, v, n, FRAME_ONE scale
    pos: wp.array(dtype=wp.int32),  # (V * 3,) full positions, quanta
    colour: wp.array(dtype=wp.int32),  # (V * 3,) RGB 0..255
    usable: wp.array(dtype=wp.int32),  # (V,) 0/1: may be a partner or closest-triangle corner
    adj_start: wp.array(dtype=wp.int32),  # (V + 1,) first neighbour of each vertex
    adj: wp.array(dtype=wp.int32),  # (A,) neighbour ids
    fan_start: wp.array(dtype=wp.int32),  # (V + 1,) first fan triangle of each vertex
    fan: wp.array(dtype=wp.int32),  # (F * 2,) other two corners of each fan triangle
    samples: wp.array(dtype=wp.int32),  # (S,) vertex id of each sample
    stencil: wp.array(dtype=wp.int32),  # (n_cells * S,) walk starts, cell-major
    qstart: wp.array(dtype=wp.int32),  # (Q + 1,) first entry of each query
    rel: wp.array(dtype=wp.int32),  # (E * R * 6,) moved-base and displacement coefficients
    chain: wp.array(dtype=wp.int32),  # (E,) 1: walk from the previous partner
    cell: wp.array(dtype=wp.int32),  # (E * R,) stencil cell of the walk's start, -1: none
    qcolour: wp.array(dtype=wp.int32),  # (E * 3,) entry colours 0..255
    qweight: wp.array(dtype=wp.int32),  # (E,) entry weights
    ks: wp.array(dtype=wp.float64),  # (Q,) shape coefficient of the code
    kc: wp.array(dtype=wp.float64),  # (Q,) colour coefficient of the code
    limit: wp.array(dtype=wp.int64),  # (Q,) running codes above it stop as OVER
    cand: wp.array(dtype=wp.int32),  # (n_cand,) or (Q * n_cand,) candidate sample slots, -1: none (OVER)
    n_cand: int,  # candidates (of each query)
    cand_stride: int,  # 0: one candidate list for every query; n_cand: a row per query
    n_query: int,  # queries
    rotations: int,  # R
    n_samples: int,  # S (the stencil's row length)
    out: wp.array(dtype=wp.uint32),  # (Q * n_cand * R,) codes
):
    q, r, c = wp.tid()
    slot = cand[q * cand_stride + c]
    if slot < 0:
        out[(q * n_cand + c) * rotations + r] = wp.uint32(OVER)
        return
    s = samples[slot]
    fu = _at3(frame, 3 * s)
    fv = _at3(frame, 3 * s + 1)
    fn = _at3(frame, 3 * s + 2)
    bs = _at3(base, s)
    ksq = ks[q]
    kcq = kc[q]
    lim = limit[q]
    acc_s = wp.int64(0)
    acc_c = wp.int64(0)
    prev = s
    result = wp.int64(-1)
    for j in range(qstart[q], qstart[q + 1]):
        o = (j * rotations + r) * 6
        m = bs + _to_world(wp.int64(rel[o]), wp.int64(rel[o + 1]), wp.int64(rel[o + 2]), fu, fv, fn)
        p = m + _to_world(wp.int64(rel[o + 3]), wp.int64(rel[o + 4]), wp.int64(rel[o + 5]), fu, fv, fn)
        cur = s
        k0 = cell[j * rotations + r]
        if k0 >= 0:
            cur = stencil[k0 * n_samples + slot]
        elif chain[j] != 0:
            cur = prev
        steps = int(0)
        bd = _len2(_at3(base, cur) - m)
        while steps < MAX_WALK:
            best = cur
            for k in range(adj_start[cur], adj_start[cur + 1]):
                u = adj[k]
                du = _len2(_at3(base, u) - m)
                if du < bd or (du == bd and u < best):
                    best = u
                    bd = du
            steps += 1
            if best == cur:
                steps = MAX_WALK  # converged
            cur = best
        partner = cur
        prev = partner
        if usable[partner] == 0:
            result = INVALID
            break
        w = wp.int64(qweight[j])
        e0 = wp.int64(qcolour[3 * j] - colour[3 * partner])
        e1 = wp.int64(qcolour[3 * j + 1] - colour[3 * partner + 1])
        e2 = wp.int64(qcolour[3 * j + 2] - colour[3 * partner + 2])
        acc_c += w * (e0 * e0 + e1 * e1 + e2 * e2)
        if _code(acc_s, acc_c, ksq, kcq) > lim:
            result = OVER
            break
        pa = _at3(pos, partner)
        dp = p - pa
        ap = vec3l(wp.clamp(dp[0], -CLAMP, CLAMP), wp.clamp(dp[1], -CLAMP, CLAMP), wp.clamp(dp[2], -CLAMP, CLAMP))
        bestd = wp.float64(0.0)
        bestk = int(-1)
        for k in range(fan_start[partner], fan_start[partner + 1]):
            d = _tri_d2(ap, _at3(pos, fan[2 * k]) - pa, _at3(pos, fan[2 * k + 1]) - pa)
            if bestk < 0 or d < bestd:
                bestd = d
                bestk = k
        if bestk < 0:
            result = INVALID
            break
        if usable[fan[2 * bestk]] == 0 or usable[fan[2 * bestk + 1]] == 0:
            result = INVALID
            break
        acc_s += w * wp.int64(bestd)
        if _code(acc_s, acc_c, ksq, kcq) > lim:
            result = OVER
            break
    if result < wp.int64(0):
        result = _code(acc_s, acc_c, ksq, kcq)
    out[(q * n_cand + c) * rotations + r] = wp.uint32(result)


@wp.kernel
def relief_update_kernel(
    ids: wp.array(dtype=wp.int32),  # (n,) vertex ids
    new_pos: wp.array(dtype=wp.int32),  # (n * 3,) full positions, quanta
    new_colour: wp.array(dtype=wp.int32),  # (n * 3,) RGB 0..255
    n: int,  # updates
    mark: int,  # 1: the vertices become usable partners
    pos: wp.array(dtype=wp.int32),  # (V * 3,) written
    colour: wp.array(dtype=wp.int32),  # (V * 3,) written
    usable: wp.array(dtype=wp.int32),  # (V,) written when mark
):
    i = wp.tid()
    v = ids[i]
    for k in range(3):
        pos[3 * v + k] = new_pos[3 * i + k]
        colour[3 * v + k] = new_colour[3 * i + k]
    if mark != 0:
        usable[v] = 1
