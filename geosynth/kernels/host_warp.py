"""Compiled host steps of the warp (Sec. 5.2): Warp kernels in float64, launched on Warp's
``"cpu"`` device for every run through :mod:`geosynth.compute.host_steps` (whatever ``device=``
says, so the warped points are the same bits on every device).

Each kernel has a NumPy twin in :mod:`geosynth.pointtexture.warping` (its oracle; tests/test_warping.py
compares them). Arrays are flat float64 (``(m, 3)`` arrays as ``3 m`` entries, row-major).
Nothing here validates.
"""

import warp as wp


@wp.func
def _store_normal(out: wp.array(dtype=wp.float64), i: int, ju: wp.vec3d, jv: wp.vec3d, n: wp.vec3d):
    """out[3 i : 3 i + 3] = (J u x J v) / |J u x J v|, or n where that length is below 1e-12
    (the Jacobian collapses the tangents)."""
    c = wp.cross(ju, jv)
    length = wp.sqrt(wp.dot(c, c))
    if length < wp.float64(1.0e-12):
        c = n
    else:
        c = c / length
    out[3 * i] = c[0]
    out[3 * i + 1] = c[1]
    out[3 * i + 2] = c[2]


@wp.kernel
def jacobian_normals_kernel(
    jac: wp.array(dtype=wp.float64),  # (m * 9,) J[k, j] = dW_k/dx_j, row-major per point
    normals: wp.array(dtype=wp.float64),  # (m * 3,) unit normals n
    out: wp.array(dtype=wp.float64),  # (m * 3,) out: the warped unit normals
):
    """The normals of a warp from its Jacobian (Sec. 5.2), as warping's NumPy
    ``_jacobian_normals_numpy``: ``(J u x J v) / |J u x J v|`` for the orthonormal tangents
    u = normalize(h x n), v = n x u (h = e_x, or e_y where |n_x| >= 0.9), so that the result
    keeps n's side; n itself where |J u x J v| < 1e-12 (the Jacobian collapses the tangents)."""
    i = wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    n = wp.vec3d(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2])
    h = wp.vec3d(one, zero, zero)
    if not (wp.abs(n[0]) < wp.float64(0.9)):
        h = wp.vec3d(zero, one, zero)
    u = wp.cross(h, n)
    u = u / wp.sqrt(wp.dot(u, u))
    v = wp.cross(n, u)
    o = 9 * i
    ju = wp.vec3d(jac[o] * u[0] + jac[o + 1] * u[1] + jac[o + 2] * u[2],
                  jac[o + 3] * u[0] + jac[o + 4] * u[1] + jac[o + 5] * u[2],
                  jac[o + 6] * u[0] + jac[o + 7] * u[1] + jac[o + 8] * u[2])
    jv = wp.vec3d(jac[o] * v[0] + jac[o + 1] * v[1] + jac[o + 2] * v[2],
                  jac[o + 3] * v[0] + jac[o + 4] * v[1] + jac[o + 5] * v[2],
                  jac[o + 6] * v[0] + jac[o + 7] * v[1] + jac[o + 8] * v[2])
    _store_normal(out, i, ju, jv, n)


# ------------------------------------------------------------------------ adaptive clustering


@wp.func
def _sym3_top_axis(a00: wp.float64, a11: wp.float64, a22: wp.float64,
                   a01: wp.float64, a02: wp.float64, a12: wp.float64, top: wp.float64):
    """A unit eigenvector of the symmetric 3x3 matrix for its eigenvalue ``top`` (the
    largest): the longest cross product of two rows of A - top I; a vector across the
    one non-zero row when the eigenvalue is double; (0, 0, 1) when A = top I (as LAPACK's
    identity eigenvectors give)."""
    r00 = a00 - top
    r11 = a11 - top
    r22 = a22 - top
    # rows (r00, a01, a02), (a01, r11, a12), (a02, a12, r22)
    c0 = wp.vec3d(a01 * a12 - a02 * r11, a02 * a01 - r00 * a12, r00 * r11 - a01 * a01)  # row0 x row1
    c1 = wp.vec3d(a01 * r22 - a02 * a12, a02 * a02 - r00 * r22, r00 * a12 - a01 * a02)  # row0 x row2
    c2 = wp.vec3d(r11 * r22 - a12 * a12, a12 * a02 - a01 * r22, a01 * a12 - r11 * a02)  # row1 x row2
    n0 = wp.dot(c0, c0)
    n1 = wp.dot(c1, c1)
    n2 = wp.dot(c2, c2)
    best = c0
    nb = n0
    if n1 > nb:
        best = c1
        nb = n1
    if n2 > nb:
        best = c2
        nb = n2
    scale = wp.abs(r00) + wp.abs(r11) + wp.abs(r22) + wp.abs(a01) + wp.abs(a02) + wp.abs(a12)
    if nb > wp.float64(1.0e-24) * scale * scale * scale * scale and nb > wp.float64(0.0):
        return best / wp.sqrt(nb)
    # rank <= 1: any unit vector across the longest row
    row = wp.vec3d(r00, a01, a02)
    if wp.dot(wp.vec3d(a01, r11, a12), wp.vec3d(a01, r11, a12)) > wp.dot(row, row):
        row = wp.vec3d(a01, r11, a12)
    if wp.dot(wp.vec3d(a02, a12, r22), wp.vec3d(a02, a12, r22)) > wp.dot(row, row):
        row = wp.vec3d(a02, a12, r22)
    if wp.dot(row, row) > wp.float64(0.0):
        helper = wp.vec3d(wp.float64(1.0), wp.float64(0.0), wp.float64(0.0))
        if wp.abs(row[0]) > wp.abs(row[1]):
            helper = wp.vec3d(wp.float64(0.0), wp.float64(1.0), wp.float64(0.0))
        v = wp.cross(row, helper)
        return v / wp.length(v)
    return wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(1.0))


@wp.func
def _sym3_extremes(a00: wp.float64, a11: wp.float64, a22: wp.float64,
                   a01: wp.float64, a02: wp.float64, a12: wp.float64):
    """(smallest, largest) eigenvalue of a symmetric 3x3 matrix, by the closed form of
    Smith (1961) as warping._variation_of."""
    q = (a00 + a11 + a22) / wp.float64(3.0)
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b0 = a00 - q
    b1 = a11 - q
    b2 = a22 - q
    p2 = b0 * b0 + b1 * b1 + b2 * b2 + wp.float64(2.0) * p1
    pp = wp.sqrt(p2 / wp.float64(6.0))
    if not (pp > wp.float64(0.0)):
        return q, q
    b0 = b0 / pp
    b1 = b1 / pp
    b2 = b2 / pp
    c01 = a01 / pp
    c02 = a02 / pp
    c12 = a12 / pp
    det = b0 * (b1 * b2 - c12 * c12) - c01 * (c01 * b2 - c12 * c02) + c02 * (c01 * c12 - b1 * c02)
    r = wp.clamp(det / wp.float64(2.0), wp.float64(-1.0), wp.float64(1.0))
    phi = wp.acos(r) / wp.float64(3.0)
    third = wp.float64(2.0943951023931954923)  # 2 pi / 3
    return q + wp.float64(2.0) * pp * wp.cos(phi + third), q + wp.float64(2.0) * pp * wp.cos(phi)


@wp.func
def _moments(p: wp.array(dtype=wp.float64), index: wp.array(dtype=wp.int32), first: int, last: int):
    """The mean (x, y, z) and the scatter matrix (a00, a11, a22, a01, a02, a12: sums of
    products of the offsets from the mean) of the points ``p[index[first:last]]`` (last >
    first), summed in index order: two passes, as the NumPy twins."""
    zero = wp.float64(0.0)
    sx = zero
    sy = zero
    sz = zero
    for e in range(first, last):
        q = index[e]
        sx += p[3 * q]
        sy += p[3 * q + 1]
        sz += p[3 * q + 2]
    fm = wp.float64(last - first)
    mx = sx / fm
    my = sy / fm
    mz = sz / fm
    a00 = zero
    a11 = zero
    a22 = zero
    a01 = zero
    a02 = zero
    a12 = zero
    for e in range(first, last):
        q = index[e]
        dx = p[3 * q] - mx
        dy = p[3 * q + 1] - my
        dz = p[3 * q + 2] - mz
        a00 += dx * dx
        a11 += dy * dy
        a22 += dz * dz
        a01 += dx * dy
        a02 += dx * dz
        a12 += dy * dz
    return mx, my, mz, a00, a11, a22, a01, a02, a12


@wp.kernel
def adaptive_clusters_kernel(
    p: wp.array(dtype=wp.float64),  # (n * 3,) points
    n: int,
    max_size: int,  # split while a cluster holds more points than this ...
    max_variation: wp.float64,  # ... or its surface variation exceeds this (and it holds > 2)
    limit: int,  # give up (count -1) once there are more clusters than this; < 0: no limit
    perm: wp.array(dtype=wp.int32),  # (n,) scratch: the points, each cluster a contiguous range
    stack: wp.array(dtype=wp.int32),  # (2 n + 4,) scratch: pending ranges (lo, hi)
    reps: wp.array(dtype=wp.int32),  # (n,) out: each cluster's representative, in no order
    count: wp.array(dtype=wp.int32),  # (1,) out: the number of clusters, or -1 over the limit
):
    """Hierarchical clustering of Pauly et al. 2002 (warping._adaptive_clusters_numpy),
    one thread, depth first: a range of ``perm`` is split in place through its centroid
    across its principal axis (points with (p - centroid) . axis > 0 to one side) until
    it is small and flat enough or cannot be split (all its points on one side); each
    final cluster's representative is its member nearest the centroid, the lowest index
    on ties."""
    zero = wp.float64(0.0)
    for i in range(n):
        perm[i] = i
    stack[0] = 0
    stack[1] = n
    top = int(1)
    clusters = int(1)
    n_reps = int(0)
    while top > 0:
        top -= 1
        lo = stack[2 * top]
        hi = stack[2 * top + 1]
        m = hi - lo
        mx, my, mz, a00, a11, a22, a01, a02, a12 = _moments(p, perm, lo, hi)
        total = a00 + a11 + a22
        small, large = _sym3_extremes(a00, a11, a22, a01, a02, a12)
        var = zero
        if total > zero:
            var = wp.max(small, zero) / total
        split = int(0)
        if m > max_size:
            split = 1
        if var > max_variation and m > 2:
            split = 1
        n_pos = int(0)
        if split != 0:
            axis = _sym3_top_axis(a00, a11, a22, a01, a02, a12, large)
            i = lo
            j = hi - 1
            while i <= j:
                q = perm[i]
                d = (p[3 * q] - mx) * axis[0] + (p[3 * q + 1] - my) * axis[1] + (p[3 * q + 2] - mz) * axis[2]
                if d > zero:
                    perm[i] = perm[j]
                    perm[j] = q
                    j -= 1
                else:
                    i += 1
            n_pos = hi - i
        if n_pos > 0 and n_pos < m:
            mid = hi - n_pos
            stack[2 * top] = lo
            stack[2 * top + 1] = mid
            stack[2 * top + 2] = mid
            stack[2 * top + 3] = hi
            top += 2
            clusters += 1
            if limit >= 0 and clusters > limit:
                count[0] = -1
                return
        else:
            best = int(-1)
            best_d = zero
            for k in range(lo, hi):
                j = perm[k]
                dx = p[3 * j] - mx
                dy = p[3 * j + 1] - my
                dz = p[3 * j + 2] - mz
                d = wp.sqrt(dx * dx + dy * dy + dz * dz)
                if best < 0 or d < best_d or (d == best_d and j < best):
                    best = j
                    best_d = d
            reps[n_reps] = best
            n_reps += 1
    count[0] = n_reps


# ------------------------------------------------------------------------ greedy pairing


@wp.func
def _sort_edges(key: wp.array(dtype=wp.float64), by_tie: wp.array(dtype=wp.int32),
                order: wp.array(dtype=wp.int32), tmp: wp.array(dtype=wp.int32), n: int):
    """order <- the edges 0..n-1 sorted by (key, tie rank), as np.lexsort((tie, key)): a
    stable bottom-up merge sort by key alone of the edges in tie-rank order (``by_tie``:
    the edge of each rank), so that equal keys keep their tie order."""
    for i in range(n):
        order[i] = by_tie[i]
    width = int(1)
    while width < n:
        lo = int(0)
        while lo < n:
            mid = wp.min(lo + width, n)
            hi = wp.min(lo + 2 * width, n)
            i = lo
            j = mid
            k = lo
            while k < hi:
                # the left run's edge unless the right run's is strictly smaller (stability)
                take_left = int(0)
                if i < mid:
                    if j >= hi:
                        take_left = 1
                    elif key[order[j]] >= key[order[i]]:
                        take_left = 1
                if take_left != 0:
                    tmp[k] = order[i]
                    i += 1
                else:
                    tmp[k] = order[j]
                    j += 1
                k += 1
            lo += 2 * width
        for m in range(n):
            order[m] = tmp[m]
        width *= 2


@wp.func
def _greedy_scan(eq: wp.array(dtype=wp.int32), es: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32),
                 n: int, used_q: wp.array(dtype=wp.int32), used_s: wp.array(dtype=wp.int32),
                 taken: wp.array(dtype=wp.int32), n_q: int):
    """The sequential greedy over ``order``: the taken edges into ``taken`` (scan order),
    their number returned; leaves used_q / used_s cleared."""
    n_taken = int(0)
    for k in range(n):
        e = order[k]
        if used_q[eq[e]] == 0 and used_s[es[e]] == 0:
            used_q[eq[e]] = 1
            used_s[es[e]] = 1
            taken[n_taken] = e
            n_taken += 1
    for k in range(n_taken):  # clear for the next scan (only the touched entries)
        used_q[eq[taken[k]]] = 0
        used_s[es[taken[k]]] = 0
    return n_taken


@wp.func
def _edge_coherence(e: int, eq: wp.array(dtype=wp.int32), es: wp.array(dtype=wp.int32),
                    ps: wp.array(dtype=wp.float64), q_to_r: wp.array(dtype=wp.float64),
                    q_to_r_len: wp.array(dtype=wp.float64), kr: int,
                    slot_t: wp.array(dtype=wp.int32), slot_f: wp.array(dtype=wp.float64),
                    length_weight: wp.float64, direction_weight: wp.float64):
    """The coherence term g(s, q, pi) of Sec. 5.2 of edge e (warping's NumPy
    ``coherence_numpy``): over q's neighbours r whose partner t exists,
    g = w_l / unit sum f | |p_s - p_t| - |p_q - p_r| | + w_d / 2 sum f (1 - cos(p_s - p_t, p_q - p_r))
    (cos taken as 0 where either length is 0), f(q, r) = phi / sum phi over those.
    Per (q, r) slot: ``q_to_r`` ((|Q| kr) * 3) p_q - p_r, ``q_to_r_len`` its length,
    ``slot_t`` the partner t (-1: none) and ``slot_f`` f (see _coherence_pass)."""
    q = eq[e]
    s = es[e]
    zero = wp.float64(0.0)
    sx = ps[3 * s]
    sy = ps[3 * s + 1]
    sz = ps[3 * s + 2]
    lsum = zero
    dsum = zero
    for k in range(kr):
        t = slot_t[q * kr + k]
        if t >= 0:
            f = slot_f[q * kr + k]
            ax = sx - ps[3 * t]
            ay = sy - ps[3 * t + 1]
            az = sz - ps[3 * t + 2]
            o = 3 * (q * kr + k)
            la = wp.sqrt(ax * ax + ay * ay + az * az)
            lb = q_to_r_len[q * kr + k]
            lab = la * lb
            cos = zero
            if lab > zero:
                cos = (ax * q_to_r[o] + ay * q_to_r[o + 1] + az * q_to_r[o + 2]) / lab
            lsum += f * wp.abs(la - lb)
            dsum += f * (wp.float64(1.0) - cos)
    return length_weight * lsum + direction_weight * dsum


@wp.func
def _coherence_pass(n_edges: int, eq: wp.array(dtype=wp.int32), es: wp.array(dtype=wp.int32),
                    ps: wp.array(dtype=wp.float64), q_to_r: wp.array(dtype=wp.float64),
                    q_to_r_len: wp.array(dtype=wp.float64), rn: wp.array(dtype=wp.int32),
                    phi: wp.array(dtype=wp.float64), kr: int, n_q: int,
                    partner: wp.array(dtype=wp.int32), old_partner: wp.array(dtype=wp.int32),
                    old_g: wp.array(dtype=wp.float64), have_old: int, dirty: wp.array(dtype=wp.int32),
                    slot_t: wp.array(dtype=wp.int32), slot_f: wp.array(dtype=wp.float64),
                    length_weight: wp.float64, direction_weight: wp.float64, g: wp.array(dtype=wp.float64)):
    """g of every edge for ``partner``. First per q (shared by its edges): the partner t
    of each neighbour r and f(q, r) = phi / sum phi over the r with a partner (0 for the
    others and where none has one). With ``have_old``, g of an edge whose q has no
    neighbour r with a changed partner is copied from ``old_g`` (computed for
    ``old_partner``: the same inputs, so the same value); only the others are recomputed."""
    zero = wp.float64(0.0)
    for q in range(n_q):
        d = int(1)
        if have_old != 0:
            d = int(0)
            for k in range(kr):
                r = rn[q * kr + k]
                if partner[r] != old_partner[r]:
                    d = int(1)
        dirty[q] = d
        if d != 0:
            tot = zero
            for k in range(kr):
                t = partner[rn[q * kr + k]]
                slot_t[q * kr + k] = t
                if t >= 0:
                    tot += phi[q * kr + k]
            for k in range(kr):
                fk = zero
                if tot > zero and slot_t[q * kr + k] >= 0:
                    fk = phi[q * kr + k] / tot
                slot_f[q * kr + k] = fk
    for i in range(n_edges):
        if dirty[eq[i]] != 0:
            g[i] = _edge_coherence(i, eq, es, ps, q_to_r, q_to_r_len, kr, slot_t, slot_f,
                                   length_weight, direction_weight)
        else:
            g[i] = old_g[i]


@wp.kernel
def greedy_pairing_kernel(
    eq: wp.array(dtype=wp.int32),  # (E,) target q of each allowed edge
    es: wp.array(dtype=wp.int32),  # (E,) source s of each allowed edge
    cost: wp.array(dtype=wp.float64),  # (E,) the pair cost c(s, q) (eq. 2)
    by_tie: wp.array(dtype=wp.int32),  # (E,) the edge of each seeded tie rank (equal costs go by rank)
    n_edges: int,
    ps: wp.array(dtype=wp.float64),  # (S * 3,) source positions
    n_q: int,
    rn: wp.array(dtype=wp.int32),  # (|Q| * kr,) the neighbours r of each q in Q
    phi: wp.array(dtype=wp.float64),  # (|Q| * kr,) their Gaussian weights
    q_to_r: wp.array(dtype=wp.float64),  # (|Q| * kr * 3,) p_q - p_r
    q_to_r_len: wp.array(dtype=wp.float64),  # (|Q| * kr,) |p_q - p_r|
    kr: int,
    length_weight: wp.float64,  # w_l / unit
    direction_weight: wp.float64,  # w_d / 2
    miss: wp.float64,  # the cost of an unpaired q
    iterations: int,
    key: wp.array(dtype=wp.float64),  # (E,) scratch
    g: wp.array(dtype=wp.float64),  # (E,) scratch: g of the kept pairing
    new_g: wp.array(dtype=wp.float64),  # (E,) scratch
    order: wp.array(dtype=wp.int32),  # (E,) scratch
    tmp: wp.array(dtype=wp.int32),  # (E,) scratch
    partner: wp.array(dtype=wp.int32),  # (|Q|,) scratch, -1 on entry
    new_partner: wp.array(dtype=wp.int32),  # (|Q|,) scratch, -1 on entry
    dirty: wp.array(dtype=wp.int32),  # (|Q|,) scratch
    slot_t: wp.array(dtype=wp.int32),  # (|Q| * kr,) scratch
    slot_f: wp.array(dtype=wp.float64),  # (|Q| * kr,) scratch
    used_q: wp.array(dtype=wp.int32),  # (|Q|,) zeros on entry
    used_s: wp.array(dtype=wp.int32),  # (S,) zeros on entry
    new_sel: wp.array(dtype=wp.int32),  # (E,) scratch
    sel: wp.array(dtype=wp.int32),  # (E,) out: the kept pairing's edges, in scan order
    costs: wp.array(dtype=wp.float64),  # (iterations + 1,) out: C after each kept pass
    counts: wp.array(dtype=wp.int32),  # (2,) out: [edges in sel, entries in costs]
):
    """The iterated greedy pairing of Sec. 5.2 (warping._greedy_pairing with
    ``numpy_oracle``), one thread, every pass in one launch: the first pass scans the
    edges by increasing c, each later one by c + g of the kept pairing; a pass that gives
    the same pairing ends the iteration, one that costs more is discarded and ends it.
    C = sum over the pairs of c + g (in scan order) + miss per unpaired q."""
    for i in range(n_edges):
        key[i] = cost[i]
    _sort_edges(key, by_tie, order, tmp, n_edges)
    n_sel = _greedy_scan(eq, es, order, n_edges, used_q, used_s, sel, n_q)
    for k in range(n_sel):
        partner[eq[sel[k]]] = es[sel[k]]
    _coherence_pass(n_edges, eq, es, ps, q_to_r, q_to_r_len, rn, phi, kr, n_q, partner, partner, g, 0, dirty,
                    slot_t, slot_f, length_weight, direction_weight, g)
    c_sum = wp.float64(0.0)
    for k in range(n_sel):
        c_sum += cost[sel[k]] + g[sel[k]]
    last = c_sum + miss * wp.float64(n_q - n_sel)
    costs[0] = last
    n_costs = int(1)
    for it in range(iterations):
        for i in range(n_edges):
            key[i] = cost[i] + g[i]
        _sort_edges(key, by_tie, order, tmp, n_edges)
        n_new = _greedy_scan(eq, es, order, n_edges, used_q, used_s, new_sel, n_q)
        same = int(0)
        if n_new == n_sel:
            same = int(1)
            for k in range(n_new):
                if new_sel[k] != sel[k]:
                    same = 0
        if same != 0:
            break
        for q in range(n_q):
            new_partner[q] = -1
        for k in range(n_new):
            new_partner[eq[new_sel[k]]] = es[new_sel[k]]
        _coherence_pass(n_edges, eq, es, ps, q_to_r, q_to_r_len, rn, phi, kr, n_q, new_partner, partner, g, 1,
                        dirty, slot_t, slot_f, length_weight, direction_weight, new_g)
        c_new = wp.float64(0.0)
        for k in range(n_new):
            c_new += cost[new_sel[k]] + new_g[new_sel[k]]
        total = c_new + miss * wp.float64(n_q - n_new)
        if total > last:
            break
        for k in range(n_new):
            sel[k] = new_sel[k]
        n_sel = n_new
        for q in range(n_q):
            partner[q] = new_partner[q]
        for i in range(n_edges):
            g[i] = new_g[i]
        costs[n_costs] = total
        n_costs += 1
        last = total
    counts[0] = n_sel
    counts[1] = n_costs


# ------------------------------------------------------------------------ neighbourhood statistics


@wp.kernel
def outskirts_kernel(
    p: wp.array(dtype=wp.float64),  # (n * 3,) points
    dist: wp.array(dtype=wp.float64),  # (n * k,) distances to each point's k nearest (itself first)
    idx: wp.array(dtype=wp.int32),  # (n * k,) their indices
    k: int,
    lopsided: wp.float64,  # the outskirt threshold, x the mean neighbour distance
    out: wp.array(dtype=wp.int32),  # (n,) out: 1 where the point is an outskirt
):
    """warping._outskirts_numpy's test, one thread per point: the centroid of its k
    neighbours (summed in neighbour order) lies farther from it than ``lopsided`` times
    the mean distance to its k - 1 nearest others."""
    i = wp.tid()
    zero = wp.float64(0.0)
    sx = zero
    sy = zero
    sz = zero
    for j in range(k):
        q = idx[i * k + j]
        sx += p[3 * q]
        sy += p[3 * q + 1]
        sz += p[3 * q + 2]
    fk = wp.float64(k)
    dx = sx / fk - p[3 * i]
    dy = sy / fk - p[3 * i + 1]
    dz = sz / fk - p[3 * i + 2]
    offset = wp.sqrt(dx * dx + dy * dy + dz * dz)
    mean_d = zero
    if k > 1:
        for j in range(1, k):
            mean_d += dist[i * k + j]
        mean_d = mean_d / wp.float64(k - 1)
    flag = int(0)
    if offset > lopsided * mean_d:
        flag = 1
    out[i] = flag


@wp.kernel
def variation_kernel(
    p: wp.array(dtype=wp.float64),  # (n * 3,) points
    idx: wp.array(dtype=wp.int32),  # (m * k,) each row's neighbour indices
    k: int,
    out: wp.array(dtype=wp.float64),  # (m,) out: surface variation
):
    """Surface variation of the neighbourhood ``p[idx[r]]`` (warping._variation_of_numpy):
    the smallest eigenvalue of its covariance over the trace, in [0, 1/3] (0 where the
    trace is 0), by the closed form of Smith (1961)."""
    r = wp.tid()
    zero = wp.float64(0.0)
    mx, my, mz, a00, a11, a22, a01, a02, a12 = _moments(p, idx, r * k, r * k + k)
    trace = a00 + a11 + a22
    v = zero
    if trace > zero:
        small, large = _sym3_extremes(a00, a11, a22, a01, a02, a12)
        v = wp.clamp(small / trace, zero, wp.float64(1.0) / wp.float64(3.0))
    out[r] = v


# ------------------------------------------------------------------------ spline normals


@wp.kernel
def spline_normals_kernel(
    u: wp.array(dtype=wp.float64),  # (m * 3,) evaluation points in the spline's normalized coordinates
    sums: wp.array(dtype=wp.float32),  # (m * 12,) sum_i psi_i w_ik (k < 3), then sum_i psi_i w_ik c_ij at 3 + 3 k + j
    affine: wp.array(dtype=wp.float64),  # (12,) rows a_0, then A's rows for x, y, z
    normals: wp.array(dtype=wp.float64),  # (m * 3,) unit normals n
    out: wp.array(dtype=wp.float64),  # (m * 3,) out: the warped unit normals
):
    """The warped normals of a thin-plate spline from its kernel sums (warping's
    ThinPlateSpline evaluation, float32 kernel matrices): the Jacobian
    J[k, j] = delta_kj + A[j, k] + u_j sum_i psi_i w_ik - sum_i psi_i w_ik c_ij, then the
    normals of jacobian_normals_kernel. One thread per point."""
    i = wp.tid()
    o = 12 * i
    u0 = u[3 * i]
    u1 = u[3 * i + 1]
    u2 = u[3 * i + 2]
    s0 = wp.float64(sums[o])
    s1 = wp.float64(sums[o + 1])
    s2 = wp.float64(sums[o + 2])
    one = wp.float64(1.0)
    j00 = u0 * s0 - wp.float64(sums[o + 3]) + affine[3] + one
    j01 = u1 * s0 - wp.float64(sums[o + 4]) + affine[6]
    j02 = u2 * s0 - wp.float64(sums[o + 5]) + affine[9]
    j10 = u0 * s1 - wp.float64(sums[o + 6]) + affine[4]
    j11 = u1 * s1 - wp.float64(sums[o + 7]) + affine[7] + one
    j12 = u2 * s1 - wp.float64(sums[o + 8]) + affine[10]
    j20 = u0 * s2 - wp.float64(sums[o + 9]) + affine[5]
    j21 = u1 * s2 - wp.float64(sums[o + 10]) + affine[8]
    j22 = u2 * s2 - wp.float64(sums[o + 11]) + affine[11] + one
    zero = wp.float64(0.0)
    n = wp.vec3d(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2])
    h = wp.vec3d(one, zero, zero)
    if not (wp.abs(n[0]) < wp.float64(0.9)):
        h = wp.vec3d(zero, one, zero)
    a = wp.cross(h, n)
    a = a / wp.sqrt(wp.dot(a, a))
    b = wp.cross(n, a)
    ja = wp.vec3d(j00 * a[0] + j01 * a[1] + j02 * a[2], j10 * a[0] + j11 * a[1] + j12 * a[2],
                  j20 * a[0] + j21 * a[1] + j22 * a[2])
    jb = wp.vec3d(j00 * b[0] + j01 * b[1] + j02 * b[2], j10 * b[0] + j11 * b[1] + j12 * b[2],
                  j20 * b[0] + j21 * b[1] + j22 * b[2])
    _store_normal(out, i, ja, jb, n)
