"""Compiled host steps of the blending (Sec. 5.3 of "Geometry texture synthesis with
point-set surfaces"): Warp kernels in float64, launched on Warp's ``"cpu"`` device for
every run through :mod:`geosynth.compute.host_steps` (whatever ``device=`` says, so the blended
points are the same bits on every device).

Their NumPy twins are :class:`geosynth.pointtexture.blending.MLSSurface` and the ``_numpy`` functions
beside it (the oracles; tests/test_blend_kernels.py compares them). One thread per query
does all of a query's work: its k nearest points, every iteration of the line search, the
re-gatherings, the projection fallback, and (``blend_kernel``) the patch's own surface and
the blend itself, so that a patch costs a few launches, not a NumPy pass per operation.
``pieces_kernel`` is :func:`geosynth.pointtexture.blending.pieces` (the flowers' cut, Sec. 5.3).

The MLS surface (Adamson and Alexa, as in :mod:`geosynth.geometry.pointsets`): over a query's
gathered neighbours, ``w_i(y) = exp(-|p_i - y|^2 / h^2)`` (0 beyond ``reach`` = 3h),
``n(y) = normalize(sum w_i n_i)``, ``f(y) = n(y) . (y - a(y))`` with ``a`` the weighted mean
of the points; the weights by :func:`gauss` (an inline exp).

Neighbours come from a dense cell grid (``geosynth.pointtexture.blending._CellGrid``): points
sorted by linear cell index ``(cz * ny + cy) * nx + cx`` (stably, so a cell holds its points
in input order), ``cell_start[c]`` the first point of cell c (``nx*ny*nz + 1`` entries),
points interleaved with their unit normals, 6 float64 each; ``ids[j]`` the input index of
sorted point j (``build_grid_kernel``). :func:`nearest` returns the k nearest points closer
than ``reach`` (ties by lower input index, as pykdtree's), exactly (the cell size only sets
the speed), in an order of its own: sums over them differ from NumPy's in the last bits
only, and are the same bits on every run.

Arrays are flat (``(m, 3)`` as ``3 m`` entries, row-major). Nothing here validates.
"""

import warp as wp

from geosynth.kernels.host_search import slab_gap  # the same cell-distance rule as the search's grid

RAY = wp.constant(1)
PROJECTION = wp.constant(2)


@wp.func
def _cell_of(q: wp.float64, g: wp.float64, inv_cell: wp.float64) -> int:
    """q's cell index along one axis (any int; clamped far outside, where only the sign matters)."""
    c = wp.clamp(wp.floor((q - g) * inv_cell), wp.float64(-1.0e9), wp.float64(1.0e9))
    return int(c)


@wp.func
def _before(
    ids: wp.array(dtype=wp.int32),
    nbr: wp.array(dtype=wp.int32),
    nd2: wp.array(dtype=wp.float64),
    a: int,
    d2: wp.float64,
    j: int,
) -> bool:
    """Whether list entry a sorts before the point j at squared distance d2: nearer
    first, ties by lower input index (as pykdtree returns them)."""
    da = nd2[a]
    return da < d2 or (da == d2 and ids[nbr[a]] < ids[j])


@wp.func
def _select(
    ids: wp.array(dtype=wp.int32),
    nbr: wp.array(dtype=wp.int32),
    nd2: wp.array(dtype=wp.float64),
    base: int,
    count: int,
    k: int,
):
    """Reorder the list entries base..base+count-1 (count > k) so that the first k are the
    k nearest (Hoare's FIND: entry base+k-1 is then the k-th, no entry before it sorts
    after it, none after it before it)."""
    lo = base
    hi = base + count - 1
    kth = base + k - 1
    while lo < hi:
        pd2 = nd2[kth]
        pj = nbr[kth]
        i = lo
        j = hi
        while i <= j:
            while _before(ids, nbr, nd2, i, pd2, pj):
                i += 1
            while (nd2[j] > pd2) or (nd2[j] == pd2 and ids[nbr[j]] > ids[pj]):
                j -= 1
            if i <= j:
                td2 = nd2[i]
                tj = nbr[i]
                nd2[i] = nd2[j]
                nbr[i] = nbr[j]
                nd2[j] = td2
                nbr[j] = tj
                i += 1
                j -= 1
        if j < kth:
            lo = i
        if kth < i:
            hi = j


@wp.func
def _collect(
    pn: wp.array(dtype=wp.float64),
    ids: wp.array(dtype=wp.int32),
    first: int,
    last: int,
    q: wp.vec3d,
    k: int,
    nbr: wp.array(dtype=wp.int32),
    nd2: wp.array(dtype=wp.float64),
    base: int,
    cap: int,
    count: int,
    bound2: wp.float64,
    bound_j: int,
):
    """Append the sorted points first..last-1 that sort before (bound2, bound_j) (bound_j
    -1: strictly nearer than sqrt(bound2)) to the list at base; a full list is first cut
    to its k nearest, whose k-th becomes the bound. Returns (count, bound2, bound_j)."""
    for j in range(first, last):
        e = wp.vec3d(pn[6 * j] - q[0], pn[6 * j + 1] - q[1], pn[6 * j + 2] - q[2])
        d2 = wp.dot(e, e)
        if d2 < bound2 or (d2 == bound2 and bound_j >= 0 and ids[j] < ids[bound_j]):
            if count == cap:  # full: keep the k nearest, raise the bar
                _select(ids, nbr, nd2, base, count, k)
                count = k
                bound2 = nd2[base + k - 1]
                bound_j = nbr[base + k - 1]
            if d2 < bound2 or (d2 == bound2 and bound_j >= 0 and ids[j] < ids[bound_j]):
                nd2[base + count] = d2
                nbr[base + count] = j
                count += 1
    return count, bound2, bound_j


@wp.func
def nearest(
    pn: wp.array(dtype=wp.float64),  # (K * 6,) sorted points and normals
    ids: wp.array(dtype=wp.int32),  # (K,) input index of each sorted point
    cell_start: wp.array(dtype=wp.int32),  # (nx * ny * nz + 1,)
    g: wp.vec3d,  # grid origin (the points' minimum corner)
    cell: wp.float64,  # cell side
    nx: int,
    ny: int,
    nz: int,
    q: wp.vec3d,
    k: int,
    reach: wp.float64,
    nbr: wp.array(dtype=wp.int32),  # out: sorted indices of the neighbours, from base
    nd2: wp.array(dtype=wp.float64),  # out: their squared distances, from base
    base: int,
    cap: int,  # the list's room (> k): a full list is cut to the k nearest so far
) -> int:
    """The k nearest points strictly closer than ``reach`` to q (ties by lower input index),
    in no particular order (a deterministic one); returns how many (0..k).

    Scans shells of cells around q's cell, ring by ring (rows of cells trimmed to the ball
    that may still hold a nearer point), collecting candidates unsorted; after each ring
    the k nearest so far are picked (Hoare's FIND) and the search ends once the k-th is
    nearer than every cell not scanned yet, or the scanned cells hold the whole reach."""
    zero = wp.float64(0.0)
    inf = wp.float64(1.0e300)
    reach2 = reach * reach
    inv_cell = wp.float64(1.0) / cell
    cx = _cell_of(q[0], g[0], inv_cell)
    cy = _cell_of(q[1], g[1], inv_cell)
    cz = _cell_of(q[2], g[2], inv_cell)
    # the cells within reach (empty ranges far from the grid's box)
    lz = wp.max(_cell_of(q[2] - reach, g[2], inv_cell), 0)
    hz = wp.min(_cell_of(q[2] + reach, g[2], inv_cell), nz - 1)
    ly = wp.max(_cell_of(q[1] - reach, g[1], inv_cell), 0)
    hy = wp.min(_cell_of(q[1] + reach, g[1], inv_cell), ny - 1)
    lx = wp.max(_cell_of(q[0] - reach, g[0], inv_cell), 0)
    hx = wp.min(_cell_of(q[0] + reach, g[0], inv_cell), nx - 1)
    count = int(0)
    bound2 = reach2  # a candidate must sort before (bound2, bound_j)
    bound_j = int(-1)
    r = int(0)
    done = bool(lx > hx or ly > hy or lz > hz)
    while not done:
        z0 = wp.max(cz - r, lz)
        z1 = wp.min(cz + r, hz)
        y0 = wp.max(cy - r, ly)
        y1 = wp.min(cy + r, hy)
        x0 = wp.max(cx - r, lx)
        x1 = wp.min(cx + r, hx)
        for iz in range(z0, z1 + 1):
            dz = slab_gap(q[2], g[2] + wp.float64(iz) * cell, cell)
            for iy in range(y0, y1 + 1):
                dy = slab_gap(q[1], g[1] + wp.float64(iy) * cell, cell)
                rest = bound2 - dz * dz - dy * dy
                row = (iz * ny + iy) * nx
                # (most rows of a surface's grid are empty: two loads say so)
                if rest >= zero and x0 <= x1 and cell_start[row + x0] < cell_start[row + x1 + 1]:
                    rx = wp.sqrt(rest)  # this row's cells that the ball reaches
                    a = wp.max(x0, _cell_of(q[0] - rx, g[0], inv_cell))
                    b = wp.min(x1, _cell_of(q[0] + rx, g[0], inv_cell))
                    if wp.abs(iz - cz) == r or wp.abs(iy - cy) == r:
                        if a <= b:  # a row on the shell's z or y faces: all of it is new
                            count, bound2, bound_j = _collect(pn, ids, cell_start[row + a], cell_start[row + b + 1],
                                                              q, k, nbr, nd2, base, cap, count, bound2, bound_j)
                    else:  # inside: only the shell's two x ends are new
                        if cx - r >= a and cx - r <= b:
                            c = row + cx - r
                            count, bound2, bound_j = _collect(pn, ids, cell_start[c], cell_start[c + 1], q, k,
                                                              nbr, nd2, base, cap, count, bound2, bound_j)
                        if r > 0 and cx + r >= a and cx + r <= b:
                            c = row + cx + r
                            count, bound2, bound_j = _collect(pn, ids, cell_start[c], cell_start[c + 1], q, k,
                                                              nbr, nd2, base, cap, count, bound2, bound_j)
        if count > k:
            _select(ids, nbr, nd2, base, count, k)
            count = k
            bound2 = nd2[base + k - 1]
            bound_j = nbr[base + k - 1]
        elif count == k and bound_j < 0:
            # exactly k so far: the k-th is the farthest (sorts last) of them
            worst = base
            for e in range(base + 1, base + k):
                if _before(ids, nbr, nd2, worst, nd2[e], nbr[e]):
                    worst = e
            bound2 = nd2[worst]
            bound_j = nbr[worst]
        # the ball around q that the scanned cells hold (a side with no cells beyond: all)
        covered = inf
        if cx - r > lx:
            covered = wp.min(covered, q[0] - (g[0] + wp.float64(cx - r) * cell))
        if cx + r < hx:
            covered = wp.min(covered, g[0] + wp.float64(cx + r + 1) * cell - q[0])
        if cy - r > ly:
            covered = wp.min(covered, q[1] - (g[1] + wp.float64(cy - r) * cell))
        if cy + r < hy:
            covered = wp.min(covered, g[1] + wp.float64(cy + r + 1) * cell - q[1])
        if cz - r > lz:
            covered = wp.min(covered, q[2] - (g[2] + wp.float64(cz - r) * cell))
        if cz + r < hz:
            covered = wp.min(covered, g[2] + wp.float64(cz + r + 1) * cell - q[2])
        if covered == inf or (bound_j >= 0 and bound2 < covered * covered):
            done = True
        r += 1
    return count


GAUSS_STEPS = wp.constant(8)  # gauss_table[j] = exp(-j / GAUSS_STEPS), j = 0 .. 9 GAUSS_STEPS + 1


@wp.func
def gauss(x: wp.float64, table: wp.array(dtype=wp.float64)) -> wp.float64:
    """exp(-x) for 0 <= x <= 9 (a weight within reach, 3h), inline: the table's
    exp(-j / 8) times exp(-r), r = x - j / 8 in [0, 1/8), by its Taylor series to r^10
    (error below 1e-17 relative): a few times cheaper than libm's exp, which the loop
    over the neighbours cannot overlap."""
    j = int(x * wp.float64(GAUSS_STEPS))
    t = wp.float64(j) / wp.float64(GAUSS_STEPS) - x  # -r
    p = wp.float64(2.755731922398589e-07)  # 1 / 10!
    p = wp.float64(2.7557319223985893e-06) + t * p
    p = wp.float64(2.48015873015873e-05) + t * p
    p = wp.float64(0.0001984126984126984) + t * p
    p = wp.float64(0.001388888888888889) + t * p
    p = wp.float64(0.008333333333333333) + t * p
    p = wp.float64(0.041666666666666664) + t * p
    p = wp.float64(0.16666666666666666) + t * p
    p = wp.float64(0.5) + t * p
    p = wp.float64(1.0) + t * p
    p = wp.float64(1.0) + t * p
    return table[j] * p


@wp.func
def mls_at(
    table: wp.array(dtype=wp.float64),
    pn: wp.array(dtype=wp.float64),
    nbr: wp.array(dtype=wp.int32),
    base: int,
    count: int,
    y: wp.vec3d,
    inv_h2: wp.float64,
    reach2: wp.float64,
):
    """``(f, n, support)`` of the MLS surface of the gathered neighbours at y: f(y), the
    unit MLS normal (zero without support) and whether any neighbour lies within reach
    (and their normals do not cancel)."""
    zero = wp.float64(0.0)
    wsum = zero
    sp = wp.vec3d(zero, zero, zero)  # sum w (p - y)
    sn = wp.vec3d(zero, zero, zero)  # sum w n
    for j in range(count):
        i = nbr[base + j]
        e = wp.vec3d(pn[6 * i] - y[0], pn[6 * i + 1] - y[1], pn[6 * i + 2] - y[2])
        d2 = wp.dot(e, e)
        if d2 <= reach2:
            w = gauss(d2 * inv_h2, table)
            wsum += w
            sp += w * e
            sn += w * wp.vec3d(pn[6 * i + 3], pn[6 * i + 4], pn[6 * i + 5])
    length = wp.length(sn)
    if wsum > zero and length > wp.float64(1.0e-12):
        nn = sn / length
        return -wp.dot(nn, sp) / wsum, nn, True  # n . (y - a)
    return zero, wp.vec3d(zero, zero, zero), False


@wp.func
def _settle(
    mode: int,  # RAY: the line search along d; PROJECTION: the MLS projection
    iters: int,  # steps a gathering at most
    table: wp.array(dtype=wp.float64),
    pn: wp.array(dtype=wp.float64),
    ids: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    g: wp.vec3d,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    k: int,
    cap: int,
    reach: wp.float64,
    inv_h2: wp.float64,
    reach2: wp.float64,
    tol: wp.float64,
    tmax: wp.float64,
    min_slope: wp.float64,
    h: wp.float64,
    x: wp.vec3d,  # the query p'
    d: wp.vec3d,  # its unit normal n'
    nbr: wp.array(dtype=wp.int32),
    nd2: wp.array(dtype=wp.float64),
    at_x: int,  # the list gathered at x (count_x entries)
    again: int,  # the slot of a re-gathering
    count_x: int,
):
    """One search of ``_counterpart_of`` from x with MLSSurface._iterate's re-gathering (a
    search that converged more than h from where its neighbours were gathered is gathered
    again there, at most 3 gatherings). RAY: t <- t - f(y) / (n(y) . d), y = x + t d, from
    t = 0, stopped where the line grazes the surface or |t| > tmax (t reset to 0); PROJECTION:
    y <- y - f(y) n(y), stopped beyond tmax from x. Returns (converged, y, t, last normal)."""
    zero = wp.float64(0.0)
    t = zero
    y = x
    start = x
    normal = wp.vec3d(zero, zero, zero)
    base = at_x
    count = count_x
    ok = bool(False)
    for rnd in range(3):
        converged = bool(False)
        for it in range(iters):
            f, nn, sup = mls_at(table, pn, nbr, base, count, y, inv_h2, reach2)
            normal = nn
            if not sup:
                break
            if wp.abs(f) <= tol:
                converged = True
                break
            if mode == RAY:
                slope = wp.dot(nn, d)
                if wp.abs(slope) < min_slope:
                    break  # the line grazes the surface
                t = t - f / slope
                if wp.abs(t) > tmax:
                    t = zero
                    y = x + t * d
                    break
                y = x + t * d
            else:
                y = y - f * nn
                if wp.dot(y - x, y - x) > tmax * tmax:
                    break
        if not converged:
            break
        if rnd == 2 or not (wp.length(y - start) > h):
            ok = True
            break
        start = y  # converged more than h from where its neighbours were gathered: again
        count = nearest(pn, ids, cell_start, g, cell, nx, ny, nz, start, k, reach, nbr, nd2, again, cap)
        base = again
    return ok, y, t, normal


@wp.func
def _counterpart_of(
    table: wp.array(dtype=wp.float64),  # (9 GAUSS_STEPS + 2,) gauss()'s exp(-j / GAUSS_STEPS)
    pn: wp.array(dtype=wp.float64),  # (K * 6,) N_k sorted by cell, with unit normals
    ids: wp.array(dtype=wp.int32),  # (K,)
    cell_start: wp.array(dtype=wp.int32),
    g: wp.vec3d,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    k: int,  # neighbours per evaluation: min(MLS_NEIGHBOURS, K)
    cap: int,  # room of a neighbour list (> k)
    h: wp.float64,  # MLS width
    reach: wp.float64,  # 3 h
    tol: wp.float64,  # |f| <= tol ends an iteration (_TOL * h)
    tmax: wp.float64,  # the line's reach and the farthest projection (max_ray spacings)
    min_slope: wp.float64,
    min_facing: wp.float64,
    line_iter: int,
    proj_iter: int,
    points: wp.array(dtype=wp.float64),  # (m * 3,) queries p'
    dirs: wp.array(dtype=wp.float64),  # (m * 3,) their unit normals n'
    nbr: wp.array(dtype=wp.int32),  # (workers * 2 cap,) scratch: neighbours at p', then re-gathered
    nd2: wp.array(dtype=wp.float64),  # (workers * 2 cap,) scratch
    out_p: wp.array(dtype=wp.float64),  # (m * 3,) counterpart (p' where none)
    out_n: wp.array(dtype=wp.float64),  # (m * 3,) MLS normal there (n' where none)
    how: wp.array(dtype=wp.int8),  # (m,) 0 none, RAY, PROJECTION
    i: int,  # the point
    slot: int,  # its worker's scratch slot
):
    """:func:`geosynth.pointtexture.blending.counterparts` for one query: the ray-plane iteration along
    +-n' (MLSSurface.intersect_line), else the projection (MLSSurface.project), each with
    MLSSurface._iterate's re-gathering (a query that converged more than h from where its
    neighbours were gathered is gathered again there, at most 3 gatherings: ``_settle``)."""
    inv_h2 = wp.float64(1.0) / (h * h)
    reach2 = reach * reach
    x = wp.vec3d(points[3 * i], points[3 * i + 1], points[3 * i + 2])
    d = wp.vec3d(dirs[3 * i], dirs[3 * i + 1], dirs[3 * i + 2])
    at_x = 2 * cap * slot  # neighbours gathered at p' (both searches start there)
    again = at_x + cap  # re-gathered ones
    count_x = nearest(pn, ids, cell_start, g, cell, nx, ny, nz, x, k, reach, nbr, nd2, at_x, cap)
    result = int(0)
    cp = x
    cn = d

    # --- the line x + t d: t <- t - f(y) / (n(y) . d), y = x + t d, from t = 0
    ok, y, t, normal = _settle(RAY, line_iter, table, pn, ids, cell_start, g, cell, nx, ny, nz, k, cap, reach,
                               inv_h2, reach2, tol, tmax, min_slope, h, x, d, nbr, nd2, at_x, again, count_x)
    if ok and wp.dot(normal, d) >= min_facing:
        result = RAY
        cp = x + t * d
        cn = normal
    else:
        # --- the projection y <- y - f(y) n(y), given up beyond tmax from x
        ok, y, t, normal = _settle(PROJECTION, proj_iter, table, pn, ids, cell_start, g, cell, nx, ny, nz, k, cap,
                                   reach, inv_h2, reach2, tol, tmax, min_slope, h, x, d, nbr, nd2, at_x, again,
                                   count_x)
        if ok and wp.dot(normal, d) >= min_facing and wp.length(y - x) <= tmax:
            result = PROJECTION
            cp = y
            cn = normal
    for c in range(3):
        out_p[3 * i + c] = cp[c]
        out_n[3 * i + c] = cn[c]
    how[i] = wp.int8(result)

@wp.kernel
def counterparts_kernel(
    table: wp.array(dtype=wp.float64),
    pn: wp.array(dtype=wp.float64),
    ids: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    g: wp.vec3d,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    k: int,
    cap: int,
    h: wp.float64,
    reach: wp.float64,
    tol: wp.float64,
    tmax: wp.float64,
    min_slope: wp.float64,
    min_facing: wp.float64,
    line_iter: int,
    proj_iter: int,
    points: wp.array(dtype=wp.float64),
    dirs: wp.array(dtype=wp.float64),
    nbr: wp.array(dtype=wp.int32),
    nd2: wp.array(dtype=wp.float64),
    out_p: wp.array(dtype=wp.float64),
    out_n: wp.array(dtype=wp.float64),
    how: wp.array(dtype=wp.int8),
    m: int,  # the points
    workers: int,  # launch dim: each worker does every workers-th point in one scratch slot
    part_start: int,  # the worker of thread 0 (host_steps.host_launch's split)
):
    """:func:`geosynth.pointtexture.blending.counterparts` (``_counterpart_of``) for the points w, w +
    workers, ...; the arguments as ``_counterpart_of``'s. One scratch slot per worker,
    reused from point to point (hot in the cache; a slot per point was cold memory each
    time)."""
    w = part_start + wp.tid()
    for i in range(w, m, workers):
        _counterpart_of(table, pn, ids, cell_start, g, cell, nx, ny, nz, k, cap, h, reach, tol, tmax, min_slope,
                        min_facing, line_iter, proj_iter, points, dirs, nbr, nd2, out_p, out_n, how, i, w)



@wp.func
def _blend_of(
    table: wp.array(dtype=wp.float64),  # (9 GAUSS_STEPS + 2,) gauss()'s exp(-j / GAUSS_STEPS)
    pn: wp.array(dtype=wp.float64),  # (M * 6,) the patch F'_k sorted by cell, unit normals
    ids: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    g: wp.vec3d,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    k: int,  # min(MLS_NEIGHBOURS, M)
    cap: int,  # room of a neighbour list (> k)
    h: wp.float64,
    reach: wp.float64,
    min_slope: wp.float64,
    relative: int,  # 1: move by the gap between the two surfaces; 0: onto N_k's
    points: wp.array(dtype=wp.float64),  # (s * 3,) the blended points p' (ramp > 0)
    dirs: wp.array(dtype=wp.float64),  # (s * 3,) their unit normals n'
    ramp: wp.array(dtype=wp.float64),  # (s,) r
    cp: wp.array(dtype=wp.float64),  # (s * 3,) counterparts c on N_k
    cn: wp.array(dtype=wp.float64),  # (s * 3,) MLS normals n_c there
    how: wp.array(dtype=wp.int8),  # (s,)
    nbr: wp.array(dtype=wp.int32),  # (workers * cap,) scratch
    nd2: wp.array(dtype=wp.float64),  # (workers * cap,) scratch
    out_p: wp.array(dtype=wp.float64),  # (s * 3,) p''
    out_n: wp.array(dtype=wp.float64),  # (s * 3,) n''
    i: int,  # the point
    slot: int,  # its worker's scratch slot
):
    """The blend of :func:`geosynth.pointtexture.blending.blend_patch` for one point: ``p'' = p' + r (c -
    c')``, ``n'' = normalize(n' + r (n_c - n_c'))`` with c' one ray-plane step (RAY) or one
    projection step (PROJECTION) on F'_k's own MLS surface at p' (relative), else
    ``p'' = (1 - r) p' + r c``, ``n'' = normalize((1 - r) n' + r n_c)``."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    x = wp.vec3d(points[3 * i], points[3 * i + 1], points[3 * i + 2])
    d = wp.vec3d(dirs[3 * i], dirs[3 * i + 1], dirs[3 * i + 2])
    c = wp.vec3d(cp[3 * i], cp[3 * i + 1], cp[3 * i + 2])
    nc = wp.vec3d(cn[3 * i], cn[3 * i + 1], cn[3 * i + 2])
    r = ramp[i]
    kind = int(how[i])
    own = x
    blended = (one - r) * d + r * nc
    if relative != 0:
        turn = wp.vec3d(zero, zero, zero)
        if kind != 0:  # only where N_k gave a counterpart
            count = nearest(pn, ids, cell_start, g, cell, nx, ny, nz, x, k, reach, nbr, nd2, cap * slot, cap)
            f, n_own, sup = mls_at(table, pn, nbr, cap * slot, count, x, one / (h * h), reach * reach)
            slope = wp.dot(n_own, d)
            moved = False
            if kind == RAY and sup and wp.abs(slope) >= min_slope:
                own = x - (f / slope) * d  # one ray-plane step
                moved = True
            if kind == PROJECTION and sup:
                own = x - f * n_own  # one projection step
                moved = True
            if moved:
                turn = nc - n_own
        blended = d + r * turn
    q = x + r * (c - own)
    length = wp.length(blended)
    if length > wp.float64(1.0e-9):
        blended = blended / length
    else:
        blended = d
    for a in range(3):
        out_p[3 * i + a] = q[a]
        out_n[3 * i + a] = blended[a]


@wp.kernel
def blend_kernel(
    table: wp.array(dtype=wp.float64),
    pn: wp.array(dtype=wp.float64),
    ids: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    g: wp.vec3d,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    k: int,
    cap: int,
    h: wp.float64,
    reach: wp.float64,
    min_slope: wp.float64,
    relative: int,
    points: wp.array(dtype=wp.float64),
    dirs: wp.array(dtype=wp.float64),
    ramp: wp.array(dtype=wp.float64),
    cp: wp.array(dtype=wp.float64),
    cn: wp.array(dtype=wp.float64),
    how: wp.array(dtype=wp.int8),
    nbr: wp.array(dtype=wp.int32),
    nd2: wp.array(dtype=wp.float64),
    out_p: wp.array(dtype=wp.float64),
    out_n: wp.array(dtype=wp.float64),
    m: int,  # the points
    workers: int,  # launch dim: each worker does every workers-th point in one scratch slot
    part_start: int,  # the worker of thread 0 (host_steps.host_launch's split)
):
    """The blend of :func:`geosynth.pointtexture.blending.blend_patch` (``_blend_of``) for the points w,
    w + workers, ...; the arguments as ``_blend_of``'s, one scratch slot per worker (as
    counterparts_kernel)."""
    w = part_start + wp.tid()
    for i in range(w, m, workers):
        _blend_of(table, pn, ids, cell_start, g, cell, nx, ny, nz, k, cap, h, reach, min_slope, relative, points, dirs,
                  ramp, cp, cn, how, nbr, nd2, out_p, out_n, i, w)


@wp.kernel
def build_grid_kernel(
    points: wp.array(dtype=wp.float64),  # (K * 3,) K >= 1
    normals: wp.array(dtype=wp.float64),  # (K * 3,) unit normals
    count: int,  # K
    cell0: wp.float64,  # the wanted cell side (auto_k > 0: unused)
    auto_k: int,  # > 0: cells about as wide as the k = auto_k nearest on a surface
    max_cells: int,  # the most cells: a larger box gets larger cells
    pn: wp.array(dtype=wp.float64),  # out (K * 6,) points and normals sorted by cell
    ids: wp.array(dtype=wp.int32),  # out (K,) input index of each sorted point
    cell_start: wp.array(dtype=wp.int32),  # out (max_cells + 1,); the first nx*ny*nz + 1 used
    cursor: wp.array(dtype=wp.int32),  # scratch (max_cells,)
    cell_of: wp.array(dtype=wp.int32),  # scratch (K,)
    info: wp.array(dtype=wp.float64),  # out (7,) origin x, y, z, cell, nx, ny, nz
):
    """The cell grid of ``nearest`` (one thread, a stable counting sort): the points' box
    from its minimum corner, cells of side cell0 or by auto_k (grown while the box would need more
    than max_cells), each point's cell ``floor((p - origin) / cell)`` (the arithmetic of
    ``nearest``'s queries) clamped into the grid."""
    lo = wp.vec3d(points[0], points[1], points[2])
    hi = lo
    for i in range(1, count):
        p = wp.vec3d(points[3 * i], points[3 * i + 1], points[3 * i + 2])
        lo = wp.min(lo, p)
        hi = wp.max(hi, p)
    extent = hi - lo
    cell = cell0
    if auto_k > 0:
        # a surface's spacing sqrt(area / K), area the product of the box's two longest sides
        small = wp.min(extent[0], wp.min(extent[1], extent[2]))
        area = extent[0] * extent[1] * extent[2] / wp.max(small, wp.float64(1.0e-300))
        if small <= wp.float64(0.0):
            area = wp.max(extent[0] * extent[1], wp.max(extent[0] * extent[2], extent[1] * extent[2]))
        longest = wp.max(extent[0], wp.max(extent[1], extent[2]))
        cell = wp.max(wp.float64(0.5) * wp.sqrt(area * wp.float64(auto_k) / wp.float64(count)),
                      wp.max(wp.float64(1.0e-9) * longest, wp.float64(1.0e-300)))
    nx = int(wp.min(wp.floor(extent[0] / cell), wp.float64(1.0e9))) + 1
    ny = int(wp.min(wp.floor(extent[1] / cell), wp.float64(1.0e9))) + 1
    nz = int(wp.min(wp.floor(extent[2] / cell), wp.float64(1.0e9))) + 1
    while wp.float64(nx) * wp.float64(ny) * wp.float64(nz) > wp.float64(max_cells):
        ratio = wp.float64(nx) * wp.float64(ny) * wp.float64(nz) / wp.float64(max_cells)
        cell = cell * wp.float64(1.05) * wp.pow(ratio, wp.float64(1.0) / wp.float64(3.0))
        nx = int(wp.min(wp.floor(extent[0] / cell), wp.float64(1.0e9))) + 1
        ny = int(wp.min(wp.floor(extent[1] / cell), wp.float64(1.0e9))) + 1
        nz = int(wp.min(wp.floor(extent[2] / cell), wp.float64(1.0e9))) + 1
    inv_cell = wp.float64(1.0) / cell
    cells = nx * ny * nz
    for c in range(cells + 1):
        cell_start[c] = 0
    for i in range(count):
        cx = wp.min(_cell_of(points[3 * i], lo[0], inv_cell), nx - 1)
        cy = wp.min(_cell_of(points[3 * i + 1], lo[1], inv_cell), ny - 1)
        cz = wp.min(_cell_of(points[3 * i + 2], lo[2], inv_cell), nz - 1)
        c = (cz * ny + cy) * nx + cx
        cell_of[i] = c
        cell_start[c + 1] = cell_start[c + 1] + 1
    for c in range(cells):
        cell_start[c + 1] = cell_start[c + 1] + cell_start[c]
        cursor[c] = cell_start[c]
    for i in range(count):  # in input order: stable within a cell
        c = cell_of[i]
        j = cursor[c]
        cursor[c] = j + 1
        ids[j] = i
        for a in range(3):
            pn[6 * j + a] = points[3 * i + a]
            pn[6 * j + 3 + a] = normals[3 * i + a]
    info[0] = lo[0]
    info[1] = lo[1]
    info[2] = lo[2]
    info[3] = cell
    info[4] = wp.float64(nx)
    info[5] = wp.float64(ny)
    info[6] = wp.float64(nz)


@wp.func
def _root(parent: wp.array(dtype=wp.int32), i: int) -> int:
    """The root of i's set (path halving on the way)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@wp.kernel
def pieces_kernel(
    cells: wp.array(dtype=wp.int32),  # (M * 3,) each point's cell (i, j, k), cells link / 2 wide
    count: int,  # M >= 1
    nx: int,
    ny: int,
    nz: int,
    voxel: wp.array(dtype=wp.int32),  # scratch (nx * ny * nz,) all -1: a cell's first point
    parent: wp.array(dtype=wp.int32),  # scratch (M,)
    labels: wp.array(dtype=wp.int32),  # out (M,) 0, 1, ... in the order of each piece's first point
):
    """geosynth.pointtexture.blending.pieces: occupied cells joined through faces, edges or corners
    (26-connectivity), by union-find over the points (one thread); each cell's points hang
    on its first point, whose set is joined with the first points of its occupied
    neighbour cells."""
    for i in range(count):
        v = (cells[3 * i + 2] * ny + cells[3 * i + 1]) * nx + cells[3 * i]
        if voxel[v] < 0:
            voxel[v] = i
        parent[i] = voxel[v]
    for i in range(count):
        cx = cells[3 * i]
        cy = cells[3 * i + 1]
        cz = cells[3 * i + 2]
        if voxel[(cz * ny + cy) * nx + cx] == i:
            for dz in range(-1, 2):
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        x = cx + dx
                        y = cy + dy
                        z = cz + dz
                        if x >= 0 and x < nx and y >= 0 and y < ny and z >= 0 and z < nz:
                            other = voxel[(z * ny + y) * nx + x]
                            if other >= 0:
                                a = _root(parent, i)
                                b = _root(parent, other)
                                if a < b:
                                    parent[b] = a
                                if b < a:
                                    parent[a] = b
    for i in range(count):
        labels[i] = -1
    n = int(0)
    for i in range(count):
        r = _root(parent, i)
        if labels[r] < 0:
            labels[r] = n
            n += 1
        labels[i] = labels[r]


@wp.kernel
def knn_kernel(
    pn: wp.array(dtype=wp.float64),
    ids: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    g: wp.vec3d,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    k: int,
    cap: int,
    reach: wp.float64,  # only points strictly nearer count
    count_all: int,  # the grid's points: the index of "none"
    queries: wp.array(dtype=wp.float64),  # (m * 3,)
    nbr: wp.array(dtype=wp.int32),  # scratch (workers * cap,)
    nd2: wp.array(dtype=wp.float64),  # scratch (workers * cap,)
    out_d: wp.array(dtype=wp.float64),  # (m * k,) out: distances, nearest first; inf for none
    out_i: wp.array(dtype=wp.int32),  # (m * k,) out: input indices (ties: the lower first); count_all for none
    m: int,  # the queries
    workers: int,  # launch dim: each worker does every workers-th query in one scratch slot
    part_start: int,  # the worker of thread 0 (host_steps.host_launch's split)
):
    """The k nearest points of each query in pykdtree's form (``geosynth.pointtexture.blending.nearest_k``):
    :func:`nearest`'s list, sorted nearer first, ties by lower input index (insertion sort:
    k is small), padded with (inf, count_all)."""
    w = part_start + wp.tid()
    base = w * cap
    for i in range(w, m, workers):
        q = wp.vec3d(queries[3 * i], queries[3 * i + 1], queries[3 * i + 2])
        count = nearest(pn, ids, cell_start, g, cell, nx, ny, nz, q, k, reach, nbr, nd2, base, cap)
        for a in range(base + 1, base + count):
            d2 = nd2[a]
            j = nbr[a]
            b = a - 1
            while b >= base and not _before(ids, nbr, nd2, b, d2, j):
                nd2[b + 1] = nd2[b]
                nbr[b + 1] = nbr[b]
                b -= 1
            nd2[b + 1] = d2
            nbr[b + 1] = j
        for a in range(k):
            if a < count:
                out_d[i * k + a] = wp.sqrt(nd2[base + a])
                out_i[i * k + a] = ids[nbr[base + a]]
            else:
                out_d[i * k + a] = wp.float64(1.0e308) * wp.float64(10.0)
                out_i[i * k + a] = count_all
