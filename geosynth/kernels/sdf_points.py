"""How far is each point from a point set's MLS surface? "Geometry texture synthesis with
point-set surfaces", Sec. 5.1.

Distance-field kernels (points): Warp. The twin of sdf_points.cl.

The MLS surface of an oriented point set (Adamson and Alexa): with Gaussian weights
``w_i(y) = exp(-|p_i - y|^2 / h^2)``, cut off beyond ``reach``,
``a(y) = sum w_i p_i / sum w_i``, ``n(y) = normalize(sum w_i n_i)`` and
``f(y) = n(y) . (y - a(y))``. ``mls_project_kernel`` (<-> ``mls_project``) iterates the
quasi-orthogonal projection ``y <- y - f(y) n(y)`` from each query point x and writes
the signed distance ``sign(f(x)) |x - proj(x)|`` (clamped to +-reach), the MLS normal at
the projection (the gradient) and, when asked, the projection and the residual f(proj)
(+reach where no point is within reach of proj; where it stopped at |f| <= tol, that last
step's f). A query with no point within reach gets distance +reach, gradient 0, proj = x. A projection that reaches a fixed point (a step
that leaves y's bits unchanged) stops there: the later steps would repeat it exactly.

Neighbours come from the same host-built cell-sorted grid as in sdf_points.cl: points
sorted by linear cell index ``(cz * ny + cy) * nx + cx``, ``cell_start[c]`` the first
point of cell c (``nx*ny*nz + 1`` entries); a (cz, cy) row of cells is one contiguous
range. Points are interleaved, 8 floats each: (x, y, z, 0, nx, ny, nz, 0).
Sums run in the same order as in OpenCL; only exp differs (wp.exp here, a polynomial
there), by a few float32 ulps.

Host wrappers live in ``geosynth._backends.warp_points``; nothing here validates.
"""

import warp as wp


@wp.func
def cell_lo(c: float, g: float, reach: float, inv_cell: float, n: int) -> int:
    f = (c - reach - g) * inv_cell
    if f < 0.0:
        return 0
    if f >= float(n):
        return n
    return int(f)


@wp.func
def cell_hi(c: float, g: float, reach: float, inv_cell: float, n: int) -> int:
    f = (c + reach - g) * inv_cell
    if f < 0.0:
        return -1
    if f >= float(n):
        return n - 1
    return int(f)


@wp.func
def slab_distance(y: float, lo: float, cell: float) -> float:
    """Distance from y to the interval [lo, lo + cell] (0 inside)."""
    if y < lo:
        return lo - y
    if y > lo + cell:
        return y - lo - cell
    return 0.0


@wp.func
def mls_sums(
    pn: wp.array(dtype=wp.float32),
    cell_start: wp.array(dtype=wp.int32),
    gx: float,
    gy: float,
    gz: float,
    inv_cell: float,
    nx: int,
    ny: int,
    nz: int,
    inv_h2: float,
    reach: float,
    y: wp.vec3,
):
    """(sum w, sum w (p - y), sum w n) over the points within reach of y."""
    reach2 = reach * reach
    cell = 1.0 / inv_cell
    x0 = cell_lo(y[0], gx, reach, inv_cell, nx)
    x1 = cell_hi(y[0], gx, reach, inv_cell, nx)
    y0 = cell_lo(y[1], gy, reach, inv_cell, ny)
    y1 = cell_hi(y[1], gy, reach, inv_cell, ny)
    z0 = cell_lo(y[2], gz, reach, inv_cell, nz)
    z1 = cell_hi(y[2], gz, reach, inv_cell, nz)
    ws = float(0.0)
    s = wp.vec3(0.0, 0.0, 0.0)
    m = wp.vec3(0.0, 0.0, 0.0)
    if x0 <= x1:
        for cz in range(z0, z1 + 1):
            dz = slab_distance(y[2], gz + float(cz) * cell, cell)
            for cy in range(y0, y1 + 1):
                dy = slab_distance(y[1], gy + float(cy) * cell, cell)
                if dz * dz + dy * dy <= reach2:
                    row = (cz * ny + cy) * nx
                    for i in range(cell_start[row + x0], cell_start[row + x1 + 1]):
                        e = wp.vec3(pn[8 * i] - y[0], pn[8 * i + 1] - y[1], pn[8 * i + 2] - y[2])
                        d2 = wp.dot(e, e)
                        if d2 < reach2:
                            w = wp.exp(-d2 * inv_h2)
                            ws += w
                            s += w * e
                            m += w * wp.vec3(pn[8 * i + 4], pn[8 * i + 5], pn[8 * i + 6])
    return ws, s, m


@wp.kernel
def mls_project_kernel(
    pn: wp.array(dtype=wp.float32),  # (n * 8,) sorted points, interleaved with normals
    cell_start: wp.array(dtype=wp.int32),  # (nx * ny * nz + 1,)
    gx: float,  # cell grid origin
    gy: float,
    gz: float,
    inv_cell: float,  # 1 / cell size
    nx: int,
    ny: int,
    nz: int,
    inv_h2: float,  # 1 / h^2
    reach: float,  # weights beyond it are 0
    tol: float,  # stop when |f| <= tol
    max_iter: int,
    queries: wp.array(dtype=wp.float32),  # (m * 3,) or a dummy when use_queries == 0
    use_queries: int,
    qox: float,  # lattice origin and spacing (use_queries == 0)
    qoy: float,
    qoz: float,
    qsx: float,
    qsy: float,
    qsz: float,
    qnx: int,  # lattice counts along x and y (x fastest)
    qny: int,
    m: int,
    dist: wp.array(dtype=wp.float32),  # (m,)
    grad: wp.array(dtype=wp.float32),  # (m * 3,)
    proj: wp.array(dtype=wp.float32),  # (m * 3,) or a dummy when write_proj == 0
    write_proj: int,
    resid: wp.array(dtype=wp.float32),  # (m,) f at the projection, or a dummy when write_resid == 0
    write_resid: int,
):
    i = wp.tid()
    if i >= m:
        return
    x = wp.vec3(0.0, 0.0, 0.0)
    if use_queries != 0:
        x = wp.vec3(queries[3 * i], queries[3 * i + 1], queries[3 * i + 2])
    else:
        ix = i % qnx
        iy = (i / qnx) % qny
        iz = i / (qnx * qny)
        x = wp.vec3(qox + float(ix) * qsx, qoy + float(iy) * qsy, qoz + float(iz) * qsz)
    y = x
    p = x
    n = wp.vec3(0.0, 0.0, 0.0)
    f0 = float(0.0)
    f_last = float(0.0)
    found = int(0)
    settled = int(0)
    lost = int(0)
    for it in range(max_iter):
        ws, s, msum = mls_sums(pn, cell_start, gx, gy, gz, inv_cell, nx, ny, nz, inv_h2, reach, y)
        mm = wp.dot(msum, msum)
        if not (ws > 0.0) or not (mm > 0.0):
            lost = 1  # no point within reach of y == p (or normals cancel): keep the last projection
            break
        u = msum * (1.0 / wp.sqrt(mm))
        f = -wp.dot(u, s) / ws  # n . (y - a)
        if it == 0:
            f0 = f
            found = 1
        n = u
        f_last = f
        p = y - f * u
        if wp.abs(f) <= tol:
            settled = 1  # converged: the last step's f stands for f at the projection
            break
        if p[0] == y[0] and p[1] == y[1] and p[2] == y[2]:
            settled = 1  # a fixed point: every later step would repeat this one bit for bit
            break
        y = p
    d = reach
    if found != 0:
        d = wp.min(wp.length(x - p), reach)
        if f0 < 0.0:
            d = -d
    dist[i] = d
    grad[3 * i] = n[0]
    grad[3 * i + 1] = n[1]
    grad[3 * i + 2] = n[2]
    if write_proj != 0:
        proj[3 * i] = p[0]
        proj[3 * i + 1] = p[1]
        proj[3 * i + 2] = p[2]
    if write_resid != 0:
        # f at the projection (reach where no point is within reach of it): one more step's
        # size; at a fixed point the last step's f, which is f there; at the tolerance the
        # last step's f (|f| <= tol: the projection has converged). A projection that lost
        # its support stopped at p, where the sums just came out empty: reach, not recomputed.
        r = reach
        if settled != 0:
            r = f_last
        elif lost == 0:
            ws2, s2, m2 = mls_sums(pn, cell_start, gx, gy, gz, inv_cell, nx, ny, nz, inv_h2, reach, p)
            mm2 = wp.dot(m2, m2)
            if ws2 > 0.0 and mm2 > 0.0:
                r = -wp.dot(m2 * (1.0 / wp.sqrt(mm2)), s2) / ws2
        resid[i] = r
