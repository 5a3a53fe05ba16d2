"""M3 point parameterization (Zhang, Qiu and Kaufman, Sec. 3.2-3.3 and Appendix A): the
sequential region growing of distortion-bounded patches, in one thread. Warp kernels.

The twin of ``growth.cl`` (same kernel name without ``_kernel``, same arguments in the
same order, the same float64 arithmetic in the same order). Definitions are those of
``geosynth/parameterize.py``; the order of growth is fixed here:

- Patches start at the first free point of ``order`` (a seeded permutation), in the
  seed frame ``(seed_s, seed_t)`` of that point, at q = (0, 0).
- Priority queue: one FIFO list per priority ``min(key, n_buckets - 1)``, ``key`` the
  number of points of the current patch that have the point among their k neighbours.
  When a point joins, each free point of its k-neighbourhood (in table order) gets +1
  and moves to the end of its new priority's list. The next candidate is the first of
  the highest non-empty list. A candidate with no usable patch neighbour stays free
  (out of the lists until another neighbour joins).
- A candidate's usable neighbours are the points of its k-neighbourhood in the current
  patch with n_P . n_F > 0 that Appendix A accepts (F not on P and not along P's normal).
  Their weights, averages and the distortion (eqs. 2-4) are summed in table order.
- Bounded patches (``max_patch > 0``): an accepted point that would grow the patch's
  bounding box of q past ``max_patch`` texels becomes a gap point.

Arrays are flat; sizes are explicit; nothing here validates. Host wrappers live in
``geosynth._backends.warp_growth``.
"""

import warp as wp

G_FREE = wp.constant(0)
G_PATCH = wp.constant(1)
G_GAP = wp.constant(2)
PARALLEL_LIMIT = wp.constant(wp.float64(1.0 - 1e-9))
TINY = wp.constant(wp.float64(1e-300))


@wp.func
def _at(a: wp.array(dtype=wp.float64), i: int):
    return wp.vec3d(a[3 * i], a[3 * i + 1], a[3 * i + 2])


@wp.func
def _put(a: wp.array(dtype=wp.float64), i: int, v: wp.vec3d):
    a[3 * i] = v[0]
    a[3 * i + 1] = v[1]
    a[3 * i + 2] = v[2]


@wp.func
def _dot(a: wp.vec3d, b: wp.vec3d):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@wp.func
def _cross(a: wp.vec3d, b: wp.vec3d):
    return wp.vec3d(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@wp.func
def _div(a: wp.vec3d, s: wp.float64):
    return wp.vec3d(a[0] / s, a[1] / s, a[2] / s)


@wp.func
def _unlink(nxt: wp.array(dtype=wp.int32), prv: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32),
            head: wp.array(dtype=wp.int32), tail: wp.array(dtype=wp.int32), i: int):
    b = slot[i]
    p = prv[i]
    q = nxt[i]
    if p >= 0:
        nxt[p] = q
    else:
        head[b] = q
    if q >= 0:
        prv[q] = p
    else:
        tail[b] = p
    slot[i] = -1


@wp.func
def _append(nxt: wp.array(dtype=wp.int32), prv: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32),
            head: wp.array(dtype=wp.int32), tail: wp.array(dtype=wp.int32), i: int, b: int):
    t = tail[b]
    prv[i] = t
    nxt[i] = -1
    if t >= 0:
        nxt[t] = i
    else:
        head[b] = i
    tail[b] = i
    slot[i] = b


@wp.kernel
def grow_patches_kernel(
    n: int,  # points
    k: int,  # neighbours per point
    pos: wp.array(dtype=wp.float64),  # (n * 3,) positions
    nrm: wp.array(dtype=wp.float64),  # (n * 3,) unit normals
    nb: wp.array(dtype=wp.int32),  # (n * k,) k-neighbour table, self excluded
    order: wp.array(dtype=wp.int32),  # (n,) seed order
    seed_s: wp.array(dtype=wp.float64),  # (n * 3,) seed frame S of each point
    seed_t: wp.array(dtype=wp.float64),  # (n * 3,) seed frame T of each point
    unit: wp.float64,  # world length of a texel
    w1: wp.float64,
    w2: wp.float64,
    w3: wp.float64,
    w4: wp.float64,
    threshold: wp.float64,
    max_patch: wp.float64,  # largest patch extent in texels; <= 0: unbounded
    n_buckets: int,  # priority levels
    state: wp.array(dtype=wp.int32),  # (n,) out: PATCH or GAP
    patch: wp.array(dtype=wp.int32),  # (n,) out: patch index, -1 for gap points
    uv: wp.array(dtype=wp.float64),  # (n * 2,) out: patch coordinates (NaN for gap points)
    fn: wp.array(dtype=wp.float64),  # (n * 3,) out: propagated frames (NaN for gap points)
    fs: wp.array(dtype=wp.float64),
    ft: wp.array(dtype=wp.float64),
    distortion: wp.array(dtype=wp.float64),  # (n,) out: D when evaluated (0 for seeds, NaN if never)
    seeds: wp.array(dtype=wp.int32),  # (n,) out: seed of each patch, the first counts[0] used
    counts: wp.array(dtype=wp.int32),  # (1,) out: patches
    key: wp.array(dtype=wp.int32),  # (n,) scratch
    slot: wp.array(dtype=wp.int32),  # (n,) scratch: list of each point, -1 for none
    nxt: wp.array(dtype=wp.int32),  # (n,) scratch
    prv: wp.array(dtype=wp.int32),  # (n,) scratch
    touched: wp.array(dtype=wp.int32),  # (n,) scratch
    head: wp.array(dtype=wp.int32),  # (n_buckets,) scratch
    tail: wp.array(dtype=wp.int32),  # (n_buckets,) scratch
    terms: wp.array(dtype=wp.float64),  # (k * 12,) scratch
):
    """One thread grows every patch (launch dim 1)."""
    nan_value = wp.float64(wp.nan)
    zero = wp.float64(0.0)
    for i in range(n):
        state[i] = G_FREE
        patch[i] = -1
        key[i] = 0
        slot[i] = -1
        uv[2 * i] = nan_value
        uv[2 * i + 1] = nan_value
        distortion[i] = nan_value
        for r in range(3):
            fn[3 * i + r] = nan_value
            fs[3 * i + r] = nan_value
            ft[3 * i + r] = nan_value
    for b in range(n_buckets):
        head[b] = -1
        tail[b] = -1
    n_patches = int(0)
    next_seed = int(0)
    while True:
        while next_seed < n and state[order[next_seed]] != G_FREE:
            next_seed += 1
        if next_seed == n:
            break
        sd = order[next_seed]
        pid = n_patches
        n_patches += 1
        seeds[pid] = sd
        state[sd] = G_PATCH
        patch[sd] = pid
        uv[2 * sd] = zero
        uv[2 * sd + 1] = zero
        distortion[sd] = zero
        _put(fn, sd, _at(nrm, sd))
        _put(fs, sd, _at(seed_s, sd))
        _put(ft, sd, _at(seed_t, sd))
        lo_x = zero
        lo_y = zero
        hi_x = zero
        hi_y = zero
        n_touched = int(0)
        top = int(0)
        joined = sd
        while True:
            if joined >= 0:
                for j in range(k):
                    q = nb[joined * k + j]
                    if state[q] == G_FREE:
                        if key[q] == 0:
                            touched[n_touched] = q
                            n_touched += 1
                        key[q] = key[q] + 1
                        b = wp.min(key[q], n_buckets - 1)
                        if slot[q] != b:
                            if slot[q] >= 0:
                                _unlink(nxt, prv, slot, head, tail, q)
                            _append(nxt, prv, slot, head, tail, q, b)
                            top = wp.max(top, b)
                joined = -1
            while top > 0 and head[top] < 0:
                top -= 1
            if top == 0:
                break
            f = head[top]
            _unlink(nxt, prv, slot, head, tail, f)
            pf = _at(pos, f)
            nf = _at(nrm, f)
            used = int(0)
            wsum = zero
            su = zero
            sv = zero
            sn = wp.vec3d(zero, zero, zero)
            st = wp.vec3d(zero, zero, zero)
            for j in range(k):
                l = nb[f * k + j]
                if state[l] != G_PATCH or patch[l] != pid:
                    continue
                pn = _at(fn, l)
                if not (_dot(_at(nrm, l), nf) > zero):
                    continue
                pp = _at(pos, l)
                ps = _at(fs, l)
                pt = _at(ft, l)
                v = wp.vec3d(pf[0] - pp[0], pf[1] - pp[1], pf[2] - pp[2])
                dist = wp.sqrt(_dot(v, v))
                v0 = _div(v, wp.max(dist, TINY))
                along = _dot(v0, pn)
                if not (dist > zero and wp.abs(along) < PARALLEL_LIMIT):
                    continue
                a = _dot(v, ps)
                bb = _dot(v, pt)
                plane = wp.sqrt(a * a + bb * bb)
                scale = dist / wp.max(plane, TINY) / unit
                lu = uv[2 * l] + a * scale
                lv = uv[2 * l + 1] + bb * scale
                nn = wp.vec3d(pn[0] - along * v0[0], pn[1] - along * v0[1], pn[2] - along * v0[2])
                nn = _div(nn, wp.max(wp.sqrt(_dot(nn, nn)), TINY))
                vt = _dot(v0, pt)
                vs = _dot(v0, ps)
                cv = _cross(nn, v0)
                tt = wp.vec3d(vt * v0[0] + vs * cv[0], vt * v0[1] + vs * cv[1], vt * v0[2] + vs * cv[2])
                ss = _cross(tt, nn)
                w = unit / wp.max(dist, TINY)
                base = 12 * used
                terms[base] = w
                terms[base + 1] = lu
                terms[base + 2] = lv
                terms[base + 3] = ss[0]
                terms[base + 4] = ss[1]
                terms[base + 5] = ss[2]
                terms[base + 6] = tt[0]
                terms[base + 7] = tt[1]
                terms[base + 8] = tt[2]
                wsum += w
                su += w * lu
                sv += w * lv
                sn = wp.vec3d(sn[0] + w * nn[0], sn[1] + w * nn[1], sn[2] + w * nn[2])
                st = wp.vec3d(st[0] + w * tt[0], st[1] + w * tt[1], st[2] + w * tt[2])
                used += 1
            if used == 0:
                continue
            inv = wp.float64(1.0) / wsum
            qu = su * inv
            qv = sv * inv
            n_f = _div(sn, wp.max(wp.sqrt(_dot(sn, sn)), TINY))
            tn = _dot(st, n_f)
            t_f = wp.vec3d(st[0] - tn * n_f[0], st[1] - tn * n_f[1], st[2] - tn * n_f[2])
            t_f = _div(t_f, wp.max(wp.sqrt(_dot(t_f, t_f)), TINY))
            s_f = _cross(t_f, n_f)
            pos_sum = zero
            pos_max = zero
            ori_sum = zero
            ori_max = zero
            for j in range(used):
                base = 12 * j
                w = terms[base]
                du = terms[base + 1] - qu
                dv = terms[base + 2] - qv
                dp = w * wp.sqrt(du * du + dv * dv)
                ss = wp.vec3d(terms[base + 3], terms[base + 4], terms[base + 5])
                tt = wp.vec3d(terms[base + 6], terms[base + 7], terms[base + 8])
                dor = w * (wp.float64(2.0) - _dot(ss, s_f) - _dot(tt, t_f))
                pos_sum += dp
                ori_sum += dor
                pos_max = wp.max(pos_max, dp)
                ori_max = wp.max(ori_max, dor)
            d_pos = w1 * pos_sum * inv + pos_max
            d_ori = w2 * ori_sum * inv + ori_max
            d = w3 * d_ori + w4 * d_pos
            distortion[f] = d
            accept = d <= threshold
            if accept and max_patch > zero:
                nlx = wp.min(lo_x, qu)
                nly = wp.min(lo_y, qv)
                nhx = wp.max(hi_x, qu)
                nhy = wp.max(hi_y, qv)
                if wp.max(nhx - nlx, nhy - nly) > max_patch:
                    accept = False
                else:
                    lo_x = nlx
                    lo_y = nly
                    hi_x = nhx
                    hi_y = nhy
            if not accept:
                state[f] = G_GAP
                continue
            state[f] = G_PATCH
            patch[f] = pid
            uv[2 * f] = qu
            uv[2 * f + 1] = qv
            _put(fn, f, n_f)
            _put(fs, f, s_f)
            _put(ft, f, t_f)
            joined = f
        for i in range(n_touched):
            key[touched[i]] = 0
    counts[0] = n_patches
