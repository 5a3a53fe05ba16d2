"""The search's float64 host recomputation of flagged samples: "Geometry texture synthesis
with point-set surfaces", Sec. 5.1 (D(S), the MLS signed distance of a point set).

A compiled host step (see ``geosynth.compute.host_steps``): launched on Warp's ``"cpu"`` device for
every run, whatever device the run's other kernels use, so the recomputed samples are the
same bits on cpu, opencl and cuda. The oracle is ``geosynth.pointtexture.patch_search._iterate`` (NumPy).

The MLS surface (Adamson and Alexa), as in sdf_points.py but in float64: Gaussian weights
``w_i(y) = exp(-|p_i - y|^2 / h^2)`` cut off at ``reach`` (``d^2 < reach^2``),
``a(y) = sum w_i p_i / sum w_i``, ``n(y) = normalize(sum w_i n_i)``, ``f(y) = n . (y - a)``;
the projection iterates ``y <- y - f(y) n(y)``. One thread per query runs every step.

Neighbours come from a float64 cell grid built on the host (``patch_search._HostCells``,
the layout of the device's float32 grid, widened by ``slack`` for the rounding between them):
points sorted by linear cell index ``(cz * ny + cy) * nx + cx`` (stable: ascending index
within a cell), ``cell_start[c]`` the first point of cell c (``nx*ny*nz + 1`` entries),
interleaved 6 float64 each: (x, y, z, nx, ny, nz), coordinates relative to the grid's shift.
A query visits the cells its reach box overlaps, skipping rows of cells whose slab lies
beyond reach; the sums run in that cell order.
"""

import warp as wp


@wp.func
def cell_first(c: wp.float64, g: wp.float64, reach: wp.float64, inv_cell: wp.float64, n: int) -> int:
    """The first cell (0..n) whose slab may hold a point within reach of coordinate c."""
    f = (c - reach - g) * inv_cell
    if f < wp.float64(0.0):
        return 0
    if f >= wp.float64(n):
        return n
    return int(f)


@wp.func
def cell_last(c: wp.float64, g: wp.float64, reach: wp.float64, inv_cell: wp.float64, n: int) -> int:
    """The last cell (-1..n-1) whose slab may hold a point within reach of coordinate c."""
    f = (c + reach - g) * inv_cell
    if f < wp.float64(0.0):
        return -1
    if f >= wp.float64(n):
        return n - 1
    return int(f)


@wp.func
def cell_box(y: wp.vec3d, g: wp.vec3d, wide: wp.float64, inv_cell: wp.float64, nx: int, ny: int, nz: int):
    """The first and last cell along x, y and z (cell_first, cell_last) of the cells within
    ``wide`` of y: (x0, x1, y0, y1, z0, z1)."""
    return (cell_first(y[0], g[0], wide, inv_cell, nx), cell_last(y[0], g[0], wide, inv_cell, nx),
            cell_first(y[1], g[1], wide, inv_cell, ny), cell_last(y[1], g[1], wide, inv_cell, ny),
            cell_first(y[2], g[2], wide, inv_cell, nz), cell_last(y[2], g[2], wide, inv_cell, nz))


@wp.func
def slab_gap(y: wp.float64, lo: wp.float64, cell: wp.float64) -> wp.float64:
    """Distance from y to the interval [lo, lo + cell] (0 inside)."""
    if y < lo:
        return lo - y
    if y > lo + cell:
        return y - lo - cell
    return wp.float64(0.0)


@wp.func
def mls_sums_f64(
    pn: wp.array(dtype=wp.float64),
    cell_start: wp.array(dtype=wp.int32),
    g: wp.vec3d,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    inv_h2: wp.float64,
    reach: wp.float64,
    slack: wp.float64,
    y: wp.vec3d,
):
    """(sum w, sum w (p - y), sum w n) over the points within reach of y, float64."""
    reach2 = reach * reach
    # the cell ranges and row test widened by slack (how far a point may lie outside its
    # cell) and a hair: a point at d^2 < reach^2 is never left out by rounding of the cell
    # arithmetic (the points' own test is exact)
    wide = reach * wp.float64(1.000000001) + slack
    wide2 = wide * wide
    inv_cell = wp.float64(1.0) / cell
    x0, x1, y0, y1, z0, z1 = cell_box(y, g, wide, inv_cell, nx, ny, nz)
    ws = wp.float64(0.0)
    s = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    m = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    if x0 <= x1:
        for cz in range(z0, z1 + 1):
            dz = slab_gap(y[2], g[2] + wp.float64(cz) * cell, cell)
            for cy in range(y0, y1 + 1):
                dy = slab_gap(y[1], g[1] + wp.float64(cy) * cell, cell)
                if dz * dz + dy * dy <= wide2:
                    row = (cz * ny + cy) * nx
                    for i in range(cell_start[row + x0], cell_start[row + x1 + 1]):
                        e = wp.vec3d(pn[6 * i] - y[0], pn[6 * i + 1] - y[1], pn[6 * i + 2] - y[2])
                        d2 = wp.dot(e, e)
                        if d2 < reach2:
                            w = wp.exp(-d2 * inv_h2)
                            ws += w
                            s += w * e
                            m += w * wp.vec3d(pn[6 * i + 3], pn[6 * i + 4], pn[6 * i + 5])
    return ws, s, m


@wp.kernel
def mls_project_f64(
    pn: wp.array(dtype=wp.float64),  # (n * 6,) points sorted by cell, with their unit normals
    cell_start: wp.array(dtype=wp.int32),  # (nx * ny * nz + 1,)
    gx: wp.float64,  # cell grid origin (relative coordinates)
    gy: wp.float64,
    gz: wp.float64,
    cell: wp.float64,  # cell size
    nx: int,
    ny: int,
    nz: int,
    inv_h2: wp.float64,  # 1 / h^2
    reach: wp.float64,  # weights at d >= reach are 0
    slack: wp.float64,  # how far a point may lie outside its cell (>= 0)
    tol: wp.float64,  # a projection stops once |f| <= tol
    max_iter: int,  # and after max_iter steps at most
    queries: wp.array(dtype=wp.float64),  # (m * 3,) relative coordinates
    f0: wp.array(dtype=wp.float64),  # (m,) out: f at the query (0 where found == 0)
    found: wp.array(dtype=wp.int32),  # (m,) out: 1 where the query had support
    grad: wp.array(dtype=wp.float64),  # (m * 3,) out: the last MLS normal (0 where none)
    proj: wp.array(dtype=wp.float64),  # (m * 3,) out: the projection (relative; the query where none)
    part_start: int,  # the query of thread 0 (host_steps.host_launch's split)
):
    i = part_start + wp.tid()
    y = wp.vec3d(queries[3 * i], queries[3 * i + 1], queries[3 * i + 2])
    g = wp.vec3d(gx, gy, gz)
    n = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    first = wp.float64(0.0)
    have = int(0)
    for it in range(max_iter):
        ws, s, msum = mls_sums_f64(pn, cell_start, g, cell, nx, ny, nz, inv_h2, reach, slack, y)
        mlen = wp.length(msum)
        if not (ws > wp.float64(0.0)) or not (mlen > wp.float64(0.0)):
            break  # no point within reach (or normals cancel): keep the last projection
        u = msum / mlen
        f = -wp.dot(u, s) / ws  # n . (y - a), with s = sum w (p - y)
        if have == 0:
            first = f
            have = 1
        n = u
        p = y - f * u
        # stop at the tolerance, or at an exact fixed point (every later step would repeat it)
        still = wp.abs(f) > tol and (p[0] != y[0] or p[1] != y[1] or p[2] != y[2])
        y = p
        if not still:
            break
    f0[i] = first
    found[i] = have
    for c in range(3):
        grad[3 * i + c] = n[c]
        proj[3 * i + c] = y[c]


@wp.kernel
def nearest_point_f64(
    pn: wp.array(dtype=wp.float64),  # (n * 6,) as for mls_project_f64
    cell_start: wp.array(dtype=wp.int32),  # (nx * ny * nz + 1,)
    order: wp.array(dtype=wp.int32),  # (n,) sorted position -> the point's input index
    gx: wp.float64,
    gy: wp.float64,
    gz: wp.float64,
    cell: wp.float64,
    nx: int,
    ny: int,
    nz: int,
    slack: wp.float64,  # how far a point may lie outside its cell (>= 0)
    radius: wp.float64,  # the first search radius (> 0): queries nearer than it need one pass
    enough2: wp.float64,  # a point at d^2 < enough2 ends the search (<= radius^2; 0: never)
    queries: wp.array(dtype=wp.float64),  # (m * 3,) relative coordinates
    dist2: wp.array(dtype=wp.float64),  # (m,) out: squared distance to the nearest point
    nearest: wp.array(dtype=wp.int32),  # (m,) out: its input index (the lowest on ties)
    part_start: int,  # the query of thread 0 (host_steps.host_launch's split)
):
    """The nearest point of each query: the cells within r of it are scanned, r = radius,
    doubled while no point was met, else the distance of the nearest met so far, until a
    point within r is found (every point within r was then scanned, so it is the nearest)
    or the scan covered the whole grid. A query with a point at
    d^2 < enough2 stops at the first such point: its outputs are that point, not
    necessarily the nearest (the caller needs only to know that one lies that near)."""
    i = part_start + wp.tid()
    y = wp.vec3d(queries[3 * i], queries[3 * i + 1], queries[3 * i + 2])
    g = wp.vec3d(gx, gy, gz)
    inv_cell = wp.float64(1.0) / cell
    best = wp.float64(-1.0)  # < 0: none yet
    best_i = int(-1)
    r = radius
    done = int(0)
    last = int(0)
    while done == 0:
        wide = r * wp.float64(1.000000001) + slack
        wide2 = wide * wide
        x0, x1, y0, y1, z0, z1 = cell_box(y, g, wide, inv_cell, nx, ny, nz)
        close = int(0)  # a point at d^2 < enough2 was met
        if x0 <= x1:
            for cz in range(z0, z1 + 1):
                dz = slab_gap(y[2], g[2] + wp.float64(cz) * cell, cell)
                for cy in range(y0, y1 + 1):
                    dy = slab_gap(y[1], g[1] + wp.float64(cy) * cell, cell)
                    if close == 0 and dz * dz + dy * dy <= wide2:
                        row = (cz * ny + cy) * nx
                        for k in range(cell_start[row + x0], cell_start[row + x1 + 1]):
                            e = wp.vec3d(pn[6 * k] - y[0], pn[6 * k + 1] - y[1], pn[6 * k + 2] - y[2])
                            d2 = wp.dot(e, e)
                            if best < wp.float64(0.0) or d2 < best or (d2 == best and order[k] < best_i):
                                best = d2
                                best_i = order[k]
                            if d2 < enough2:
                                close = 1
                                break
        whole = x0 == 0 and x1 == nx - 1 and y0 == 0 and y1 == ny - 1 and z0 == 0 and z1 == nz - 1
        if close != 0 or last != 0 or (best >= wp.float64(0.0) and best <= r * r) or whole:
            done = 1
        elif best >= wp.float64(0.0):
            # the nearest lies within the best met so far: the next pass (its box a hair wider)
            # is the last, whatever the rounding of sqrt(best)^2
            r = wp.sqrt(best)
            last = 1
        else:
            r = r * wp.float64(2.0)
    dist2[i] = best
    nearest[i] = best_i
