"""Which points join which patch, in the paper's sequential order? Zhang, Qiu and Kaufman,
"Fast Hybrid Approach for Texturing Point Models", Sec. 3.2-3.4 and 4.2.

M3's sequential orders, each in one thread: the point parameterization's region growing
(Zhang, Qiu and Kaufman, Sec. 3.2-3.3 and Appendix A), the texture mapping and gap
blending (Sec. 3.4) and the coherent neighbourhood matching of one level (Sec. 4). Warp
kernels.

The twin of ``growth.cl`` (same kernel names without ``_kernel``, same arguments in the
same order, the same float64 arithmetic in the same order, exact integer scores);
``geosynth.texturing.reference`` has plain-Python twins (``parameterize_reference``,
``colour_parameterization_reference``, ``match_coherent_reference``) that give the same
bits. Definitions are those of ``geosynth/texturing/parameterize.py`` and ``geosynth/texturing/matching.py``;
the orders are fixed here:

- ``grow_patches_kernel``: patches start at the first free point of ``order`` (a seeded
  permutation), at q = (0, 0), in the frame that the point's normal and its direction
  (``dirs``: the up vector, or a random one per point) give (``_seed_frame``).
- Priority queue (all three kernels): one FIFO list per priority ``min(key, n_buckets -
  1)``, ``key`` the number of points of the current patch (or coloured points) that have
  the point among their k neighbours. When a point joins, each free (uncoloured) point of
  its k-neighbourhood, in table order, gets +1 and moves to the end of its new priority's
  list. The next candidate is the first of the highest non-empty list. A growth candidate
  with no usable patch neighbour stays free (out of the lists until another neighbour
  joins).
- A growth candidate's usable neighbours are the points of its k-neighbourhood in the
  current patch with n_P . n_F > 0 that Appendix A accepts (F not on P and not along P's
  normal). Their weights, averages and the distortion (eqs. 2-4) are summed in table order.
- Bounded patches (``max_patch > 0``): an accepted point that would grow the patch's
  bounding box of q past ``max_patch`` texels becomes a gap point.
- ``blend_gaps_kernel`` and ``match_coherent_kernel``: see their rules in ``growth.cl``.

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
    r = wp.float64(1.0) / s  # one division
    return wp.vec3d(a[0] * r, a[1] * r, a[2] * r)


@wp.func
def _appendix_a(pf: wp.vec3d, pp: wp.vec3d, pu: wp.float64, pv: wp.float64, pn: wp.vec3d, ps: wp.vec3d,
                pt: wp.vec3d, unit: wp.float64):
    """Appendix A: F (at pf) seen from patch point P: (ok, qu, qv, normal, T, S, |F - P|);
    ok is False where F coincides with P or lies along P's normal (the rest is then 0)."""
    zero = wp.float64(0.0)
    v = wp.vec3d(pf[0] - pp[0], pf[1] - pp[1], pf[2] - pp[2])
    d = wp.sqrt(_dot(v, v))
    v0 = _div(v, wp.max(d, TINY))
    along = _dot(v0, pn)
    qu = zero
    qv = zero
    m = wp.vec3d(zero, zero, zero)
    t = wp.vec3d(zero, zero, zero)
    s = wp.vec3d(zero, zero, zero)
    ok = d > zero and wp.abs(along) < PARALLEL_LIMIT
    if ok:
        a = _dot(v, ps)
        b = _dot(v, pt)
        plane = wp.sqrt(a * a + b * b)
        scale = d / wp.max(plane, TINY) / unit
        qu = pu + a * scale
        qv = pv + b * scale
        m = wp.vec3d(pn[0] - along * v0[0], pn[1] - along * v0[1], pn[2] - along * v0[2])
        m = _div(m, wp.max(wp.sqrt(_dot(m, m)), TINY))
        vt = _dot(v0, pt)
        vs = _dot(v0, ps)
        c = _cross(m, v0)
        t = wp.vec3d(vt * v0[0] + vs * c[0], vt * v0[1] + vs * c[1], vt * v0[2] + vs * c[2])
        s = _cross(t, m)
    return ok, qu, qv, m, t, s, d


@wp.func
def _average_frame(sn: wp.vec3d, st: wp.vec3d):
    """The frame of weighted sums: (N, S, T), N = sn normalized, T = st minus its N part
    normalized, S = T x N."""
    n = _div(sn, wp.max(wp.sqrt(_dot(sn, sn)), TINY))
    tn = _dot(st, n)
    t = wp.vec3d(st[0] - tn * n[0], st[1] - tn * n[1], st[2] - tn * n[2])
    t = _div(t, wp.max(wp.sqrt(_dot(t, t)), TINY))
    return n, _cross(t, n), t


@wp.func
def _seed_frame(n: wp.vec3d, u: wp.vec3d):
    """The frame (S, T) a patch seeded at a point of unit normal n starts with, from the
    direction u (see growth.cl's seed_frame)."""
    u = _div(u, wp.sqrt(_dot(u, u)))
    un = _dot(u, n)
    t = wp.vec3d(u[0] - un * n[0], u[1] - un * n[1], u[2] - un * n[2])
    if wp.sqrt(_dot(t, t)) < wp.float64(1e-3):
        alt = wp.vec3d(wp.float64(0.0), wp.float64(1.0), wp.float64(0.0))
        if wp.abs(u[0]) < wp.float64(0.9):
            alt = wp.vec3d(wp.float64(1.0), wp.float64(0.0), wp.float64(0.0))
        an = _dot(alt, n)
        t = wp.vec3d(alt[0] - an * n[0], alt[1] - an * n[1], alt[2] - an * n[2])
    tn = _dot(t, n)
    t = wp.vec3d(t[0] - tn * n[0], t[1] - tn * n[1], t[2] - tn * n[2])
    t = _div(t, wp.max(wp.sqrt(_dot(t, t)), TINY))
    return _cross(t, n), t


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


@wp.func
def _pop(nxt: wp.array(dtype=wp.int32), prv: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32),
         head: wp.array(dtype=wp.int32), tail: wp.array(dtype=wp.int32), top: int):
    """The first point of the highest non-empty list, taken out: (point or -1, new top)."""
    t = top
    while t > 0 and head[t] < 0:
        t -= 1
    f = int(-1)
    if t > 0:
        f = head[t]
        _unlink(nxt, prv, slot, head, tail, f)
    return f, t


@wp.func
def _requeue(q: int, key: wp.array(dtype=wp.int32), n_buckets: int, nxt: wp.array(dtype=wp.int32),
             prv: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32), head: wp.array(dtype=wp.int32),
             tail: wp.array(dtype=wp.int32), top: int):
    """key[q] + 1, q to the end of its new priority's list; returns the new top priority."""
    key[q] = key[q] + 1
    b = wp.min(key[q], n_buckets - 1)
    new_top = top
    if slot[q] != b:
        if slot[q] >= 0:
            _unlink(nxt, prv, slot, head, tail, q)
        _append(nxt, prv, slot, head, tail, q, b)
        new_top = wp.max(top, b)
    return new_top


@wp.func
def _queue_from_coloured(n: int, k: int, nb: wp.array(dtype=wp.int32), coloured: wp.array(dtype=wp.int32),
                         key: wp.array(dtype=wp.int32), nxt: wp.array(dtype=wp.int32),
                         prv: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32),
                         head: wp.array(dtype=wp.int32), tail: wp.array(dtype=wp.int32), n_buckets: int):
    """The queue of the uncoloured points, in index order (key = the coloured points that
    have the point among their k neighbours); returns the top priority (0: empty)."""
    for i in range(n):
        key[i] = 0
        slot[i] = -1
    for b in range(n_buckets):
        head[b] = -1
        tail[b] = -1
    for i in range(n):
        if coloured[i] != 0:
            for j in range(k):
                q = nb[i * k + j]
                key[q] = key[q] + 1
    top = int(0)
    for i in range(n):
        if coloured[i] == 0 and key[i] > 0:
            b = wp.min(key[i], n_buckets - 1)
            _append(nxt, prv, slot, head, tail, i, b)
            top = wp.max(top, b)
    return top


@wp.kernel
def grow_patches_kernel(
    n: int,  # points
    k: int,  # neighbours per point
    pos: wp.array(dtype=wp.float64),  # (n * 3,) positions
    nrm: wp.array(dtype=wp.float64),  # (n * 3,) unit normals
    nb: wp.array(dtype=wp.int32),  # (n * k,) k-neighbour table, self excluded
    order: wp.array(dtype=wp.int32),  # (n,) seed order
    dirs: wp.array(dtype=wp.float64),  # seed frame directions: (3,) for all or (n * 3,) per point
    dir_step: int,  # 0: one direction for all, 1: one per point
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
        s0, t0 = _seed_frame(_at(nrm, sd), _at(dirs, dir_step * sd))
        _put(fs, sd, s0)
        _put(ft, sd, t0)
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
                        top = _requeue(q, key, n_buckets, nxt, prv, slot, head, tail, top)
                joined = -1
            f, top = _pop(nxt, prv, slot, head, tail, top)
            if f < 0:
                break
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
                if patch[l] != pid:  # (only patch points have a patch)
                    continue
                pn = _at(fn, l)
                if not (_dot(_at(nrm, l), nf) > zero):
                    continue
                ok, lu, lv, nn, tt, ss, dist = _appendix_a(pf, _at(pos, l), uv[2 * l], uv[2 * l + 1], pn, _at(fs, l),
                                                           _at(ft, l), unit)
                if not ok:
                    continue
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
            n_f, s_f, t_f = _average_frame(sn, st)
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


@wp.func
def _wrap(i: int, size: int):
    """i modulo size, in [0, size)."""
    r = i % size
    if r < 0:
        r += size
    return r


@wp.func
def _bilinear(tex: wp.array(dtype=wp.uint8), h: int, w: int, wrap: int, x: wp.float64, y: wp.float64):
    """Bilinear texture lookup at texel coordinates (x, y), as
    geosynth.texturing.textures.sample_bilinear: wrapped (wrap != 0) or clamped to the edge."""
    one = wp.float64(1.0)
    if wrap == 0:
        y = wp.min(wp.max(y, wp.float64(0.0)), wp.float64(h - 1))
        x = wp.min(wp.max(x, wp.float64(0.0)), wp.float64(w - 1))
    yf = wp.floor(y)
    xf = wp.floor(x)
    fy = y - yf
    fx = x - xf
    y0 = int(yf)
    x0 = int(xf)
    y1 = int(0)
    x1 = int(0)
    if wrap != 0:
        y0 = _wrap(y0, h)
        x0 = _wrap(x0, w)
        y1 = (y0 + 1) % h
        x1 = (x0 + 1) % w
    else:
        y1 = wp.min(y0 + 1, h - 1)
        x1 = wp.min(x0 + 1, w - 1)
    out = wp.vec3d()
    for c in range(3):
        t00 = wp.float64(tex[(y0 * w + x0) * 3 + c])
        t01 = wp.float64(tex[(y0 * w + x1) * 3 + c])
        t10 = wp.float64(tex[(y1 * w + x0) * 3 + c])
        t11 = wp.float64(tex[(y1 * w + x1) * 3 + c])
        top = t00 * (one - fx) + t01 * fx
        bottom = t10 * (one - fx) + t11 * fx
        out[c] = top * (one - fy) + bottom * fy
    return out


@wp.kernel
def blend_gaps_kernel(
    n: int,
    k: int,
    pos: wp.array(dtype=wp.float64),  # (n * 3,)
    nrm: wp.array(dtype=wp.float64),  # (n * 3,)
    nb: wp.array(dtype=wp.int32),  # (n * k,)
    state: wp.array(dtype=wp.int32),  # (n,) PATCH or GAP
    unit: wp.float64,
    tex: wp.array(dtype=wp.uint8),  # (h * w * 3,) RGB texture
    h: int,
    w: int,
    wrap: int,  # 1: tileable (wrapped lookups), 0: clamped
    offsets: wp.array(dtype=wp.float64),  # (patches * 2,) texel offset (x, y) of each patch
    n_buckets: int,
    patch: wp.array(dtype=wp.int32),  # (n,) in/out: joined gap points get a patch
    uv: wp.array(dtype=wp.float64),  # (n * 2,) in/out
    fn: wp.array(dtype=wp.float64),  # (n * 3,) in/out
    fs: wp.array(dtype=wp.float64),
    ft: wp.array(dtype=wp.float64),
    colours: wp.array(dtype=wp.float64),  # (n * 3,) out
    coloured: wp.array(dtype=wp.int32),  # (n,) out
    key: wp.array(dtype=wp.int32),  # (n,) scratch
    slot: wp.array(dtype=wp.int32),
    nxt: wp.array(dtype=wp.int32),
    prv: wp.array(dtype=wp.int32),
    head: wp.array(dtype=wp.int32),  # (n_buckets,) scratch
    tail: wp.array(dtype=wp.int32),
    terms: wp.array(dtype=wp.float64),  # (k * 16,) scratch
):
    """One thread colours the patch points, then blends the gap points (see growth.cl's
    blend_gaps for the rules; launch dim 1)."""
    zero = wp.float64(0.0)
    for i in range(n):
        col = wp.vec3d(zero, zero, zero)
        if state[i] == G_PATCH:
            coloured[i] = 1
            p = patch[i]
            col = _bilinear(tex, h, w, wrap, uv[2 * i] + offsets[2 * p], uv[2 * i + 1] + offsets[2 * p + 1])
        else:
            coloured[i] = 0
        for c in range(3):
            colours[3 * i + c] = col[c]
    top = _queue_from_coloured(n, k, nb, coloured, key, nxt, prv, slot, head, tail, n_buckets)
    while True:
        f, top = _pop(nxt, prv, slot, head, tail, top)
        if f < 0:
            break
        pf = _at(pos, f)
        nf = _at(nrm, f)
        used = int(0)
        n_coloured = int(0)
        wsum = zero
        plain = wp.vec3d(zero, zero, zero)
        blend = wp.vec3d(zero, zero, zero)
        for j in range(k):
            l = nb[f * k + j]
            if coloured[l] == 0:
                continue
            n_coloured += 1
            plain = wp.vec3d(plain[0] + colours[3 * l], plain[1] + colours[3 * l + 1], plain[2] + colours[3 * l + 2])
            pl = patch[l]
            if pl < 0 or not (_dot(_at(nrm, l), nf) > zero):
                continue
            ok, lu, lv, nn, tt, ss, dist = _appendix_a(pf, _at(pos, l), uv[2 * l], uv[2 * l + 1], _at(fn, l),
                                                       _at(fs, l), _at(ft, l), unit)
            if not ok:
                continue
            wl = wp.float64(1.0) / wp.max(dist, TINY)
            col = _bilinear(tex, h, w, wrap, lu + offsets[2 * pl], lv + offsets[2 * pl + 1])
            base = 16 * used
            terms[base] = wl
            terms[base + 1] = wp.float64(pl)
            terms[base + 2] = lu
            terms[base + 3] = lv
            for r in range(3):
                terms[base + 4 + r] = nn[r]
                terms[base + 7 + r] = tt[r]
            wsum += wl
            blend = wp.vec3d(blend[0] + wl * col[0], blend[1] + wl * col[1], blend[2] + wl * col[2])
            used += 1
        if n_coloured == 0:
            continue
        coloured[f] = 1
        if used == 0:
            for c in range(3):
                colours[3 * f + c] = plain[c] / wp.float64(n_coloured)
        else:
            for c in range(3):
                colours[3 * f + c] = blend[c] / wsum
            best = int(-1)
            best_total = zero
            for j in range(used):
                pj = int(terms[16 * j + 1])
                total = zero
                for i in range(used):
                    if int(terms[16 * i + 1]) == pj:
                        total += terms[16 * i]
                if best < 0 or total > best_total or (total == best_total and pj < best):
                    best = pj
                    best_total = total
            su = zero
            sv = zero
            sw = zero
            sn = wp.vec3d(zero, zero, zero)
            st = wp.vec3d(zero, zero, zero)
            for j in range(used):
                base = 16 * j
                if int(terms[base + 1]) != best:
                    continue
                wl = terms[base]
                sw += wl
                su += wl * terms[base + 2]
                sv += wl * terms[base + 3]
                sn = wp.vec3d(sn[0] + wl * terms[base + 4], sn[1] + wl * terms[base + 5], sn[2] + wl * terms[base + 6])
                st = wp.vec3d(st[0] + wl * terms[base + 7], st[1] + wl * terms[base + 8], st[2] + wl * terms[base + 9])
            n_f, s_f, t_f = _average_frame(sn, st)
            patch[f] = best
            uv[2 * f] = su / sw
            uv[2 * f + 1] = sv / sw
            _put(fn, f, n_f)
            _put(fs, f, s_f)
            _put(ft, f, t_f)
        for j in range(k):
            q = nb[f * k + j]
            if coloured[q] == 0:
                top = _requeue(q, key, n_buckets, nxt, prv, slot, head, tail, top)


@wp.func
def _window_error(grid: wp.array(dtype=wp.uint8), centre: int, rel: wp.array(dtype=wp.int32),
                  vals: wp.array(dtype=wp.uint8), count: int, bound: int):
    """Eq. 5 of one candidate: the entries' colours against the supersampled pixels at
    their offsets from the candidate's centre pixel (exact integers); the sum stops once
    it exceeds bound."""
    err = int(0)
    for e in range(count):
        if err > bound:
            break
        px = 3 * (centre + rel[e])
        for c in range(3):
            d = int(grid[px + c]) - int(vals[3 * e + c])
            err += d * d
    return err


@wp.func
def _centre(t: int, w: int, m: int, pad: int, xp: int):
    """Flat pixel index of texel t's centre in the padded supersampled grid."""
    return (pad + m * (t / w)) * xp + pad + m * (t % w)


@wp.kernel
def match_coherent_kernel(
    n: int,
    k: int,
    pos: wp.array(dtype=wp.float64),  # (n * 3,)
    nrm: wp.array(dtype=wp.float64),  # (n * 3,) unit normals
    s_axis: wp.array(dtype=wp.float64),  # (n * 3,) texture x direction
    t_axis: wp.array(dtype=wp.float64),  # (n * 3,) texture y direction
    nb: wp.array(dtype=wp.int32),  # (n * k,)
    unit: wp.float64,
    grid: wp.array(dtype=wp.uint8),  # (rows * xp * 3,) padded supersampled texture
    xp: int,  # pixels per grid row
    pad: int,  # padding in pixels (offsets are clipped to it)
    m: int,  # supersampling factor
    h: int,  # texels
    w: int,
    tileable: int,
    subtexel: int,
    shifts1: wp.array(dtype=wp.int32),  # (n_shift1 * 2,) first refinement shifts (dy, dx), in order
    n_shift1: int,
    ring: int,  # 1: refine again over the 3 x 3 pixels around the best shift
    order: wp.array(dtype=wp.int32),  # (n,) order of the points taken when none is queued
    rand_texel: wp.array(dtype=wp.int32),  # (n,) the texel a point with no coloured neighbour takes
    n_buckets: int,
    coloured: wp.array(dtype=wp.int32),  # (n,) in/out
    colours: wp.array(dtype=wp.uint8),  # (n * 3,) in/out
    source: wp.array(dtype=wp.int32),  # (n,) in/out: texel each coloured point came from (-1: none)
    key: wp.array(dtype=wp.int32),  # (n,) scratch
    slot: wp.array(dtype=wp.int32),
    nxt: wp.array(dtype=wp.int32),
    prv: wp.array(dtype=wp.int32),
    head: wp.array(dtype=wp.int32),  # (n_buckets,) scratch
    tail: wp.array(dtype=wp.int32),
    rel: wp.array(dtype=wp.int32),  # (k,) scratch: entry pixel offsets
    vals: wp.array(dtype=wp.uint8),  # (k * 3,) scratch: entry colours
    cand: wp.array(dtype=wp.int32),  # (k,) scratch: suggested texels
):
    """One thread colours every uncoloured point of a level (see growth.cl's
    match_coherent for the rules; launch dim 1)."""
    zero = wp.float64(0.0)
    top = _queue_from_coloured(n, k, nb, coloured, key, nxt, prv, slot, head, tail, n_buckets)
    half = m / 2
    big = int(2147483647)
    next_order = int(0)
    while True:
        f, top = _pop(nxt, prv, slot, head, tail, top)
        if f < 0:
            while next_order < n and coloured[order[next_order]] != 0:
                next_order += 1
            if next_order == n:
                break
            f = order[next_order]
        pf = _at(pos, f)
        nf = _at(nrm, f)
        sf = _at(s_axis, f)
        tf = _at(t_axis, f)
        count = int(0)
        n_cand = int(0)
        for j in range(k):
            l = nb[f * k + j]
            if coloured[l] == 0:
                continue
            pl = _at(pos, l)
            v = wp.vec3d(pl[0] - pf[0], pl[1] - pf[1], pl[2] - pf[2])
            dist = wp.sqrt(_dot(v, v))
            v0 = _div(v, wp.max(dist, TINY))
            along = _dot(v0, nf)
            a = _dot(v, sf)
            bb = _dot(v, tf)
            ox = a / unit
            oy = bb / unit
            if dist > zero and wp.abs(along) < PARALLEL_LIMIT:
                scale = dist / wp.max(wp.sqrt(a * a + bb * bb), TINY) / unit
                ox = a * scale
                oy = bb * scale
            dy = int(wp.rint(oy * wp.float64(m)))
            dx = int(wp.rint(ox * wp.float64(m)))
            rel[count] = wp.clamp(dy, -pad, pad) * xp + wp.clamp(dx, -pad, pad)
            for c in range(3):
                vals[3 * count + c] = colours[3 * l + c]
            count += 1
            src = source[l]
            if src < 0:
                continue
            cy = src / w - int(wp.rint(wp.float64(dy) / wp.float64(m)))
            cx = src % w - int(wp.rint(wp.float64(dx) / wp.float64(m)))
            if tileable != 0:
                cy = _wrap(cy, h)
                cx = _wrap(cx, w)
            elif cy < 0 or cy >= h or cx < 0 or cx >= w:
                continue
            t = cy * w + cx
            seen = int(0)  # neighbours that agree suggest the same texel: score it once
            for i in range(n_cand):
                if cand[i] == t:
                    seen = 1
            if seen == 0:
                cand[n_cand] = t
                n_cand += 1
        texel = wp.int32(-1)
        if count == 0:
            texel = rand_texel[f]
            at = 3 * _centre(texel, w, m, pad, xp)
            for ch in range(3):
                colours[3 * f + ch] = grid[at + ch]
        else:
            best = big
            n_search = h * w
            if n_cand > 0:
                n_search = n_cand
            for i in range(n_search):
                t = i
                if n_cand > 0:
                    t = cand[i]
                err = _window_error(grid, _centre(t, w, m, pad, xp), rel, vals, count, best)
                if err < best or (err == best and t < texel):
                    best = err
                    texel = t
            cy0 = pad + m * (texel / w)
            cx0 = pad + m * (texel % w)
            by = int(0)
            bx = int(0)
            if subtexel != 0:
                # the texel centre comes first when it is a shift: its error is the search's
                first = int(0)
                if shifts1[0] == 0 and shifts1[1] == 0:
                    first = 1
                else:
                    best = big
                for i in range(first, n_shift1):
                    sy = shifts1[2 * i]
                    sx = shifts1[2 * i + 1]
                    err = _window_error(grid, (cy0 + sy) * xp + cx0 + sx, rel, vals, count, best)
                    if err < best:
                        best = err
                        by = sy
                        bx = sx
                if ring != 0:
                    oy0 = by  # best is its error: the ring's (0, 0)
                    ox0 = bx
                    for r in range(1, 9):
                        q = r  # ring cell q = 3 (dy + 1) + (dx + 1); the centre, 4, is done
                        if r <= 4:
                            q = r - 1
                        sy = wp.clamp(oy0 + q / 3 - 1, -half, m - half - 1)
                        sx = wp.clamp(ox0 + q % 3 - 1, -half, m - half - 1)
                        err = _window_error(grid, (cy0 + sy) * xp + cx0 + sx, rel, vals, count, best)
                        if err < best:
                            best = err
                            by = sy
                            bx = sx
            at = 3 * ((cy0 + by) * xp + cx0 + bx)
            for ch in range(3):
                colours[3 * f + ch] = grid[at + ch]
        source[f] = texel
        coloured[f] = 1
        for j in range(k):
            q = nb[f * k + j]
            if coloured[q] == 0:
                top = _requeue(q, key, n_buckets, nxt, prv, slot, head, tail, top)
