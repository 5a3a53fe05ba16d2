"""How far is each point from a mesh, and on which side? Lagae, Dumont and Dutré, "Geometry
Synthesis", Sec. 3 (the source field).

Distance-field kernels (mesh): Warp. The twin of sdf_mesh.cl.

Both kernels compute, per query point p, the exact distance to the mesh and, when
``is_signed``, its sign from the fast generalized winding number (Barill et al.
2018): negative where the winding number exceeds 1/2. Same kernel names (with the
``_kernel`` suffix) as sdf_mesh.cl; both traverse the BVH arrays of
geosynth.geometry.meshes.MeshBVH (``sbox``, ``child``, ``tri_lanes``, ``tris``, ``dipole``).

One result on every device: the distance is the minimum over all triangles
of ``tri_min_dist2``, the operations of sdf_mesh.cl's ``tri_min_dist2_v`` in the same
order, found by a search that prunes a node only when its (grown) search box is
farther than PRUNE_REL times the best so far: a margin beyond any rounding, so the
minimum of the same floats comes out whatever the visiting order (sdf_mesh.cl visits
for 16 lanes at once). The winding number adds the same terms in the same order as
sdf_mesh.cl, with the same atan2 polynomial. The module is compiled without FMA
contraction (``fuse_fp`` off); Warp's division and sqrt are correctly rounded on CPU
and CUDA.

``band`` > 0 clamps the result to [-band, band] and limits the search to it; <= 0
means no band. Points are processed ``run`` at a time per thread, each search bounded
by the previous point's closest triangle (the result is unchanged, only faster).
Host wrappers live in ``geosynth._backends.warp_mesh``; nothing here validates.
"""

import warp as wp

wp.set_module_options({"fuse_fp": False})

STACK_SIZE = 64
vec64i = wp.types.vector(length=STACK_SIZE, dtype=wp.int32)
vec64f = wp.types.vector(length=STACK_SIZE, dtype=wp.float32)
INV_4PI = wp.constant(0.0795774715459476678)
PRUNE_REL = wp.constant(1.0009765625)
TRI_LANES = wp.constant(32)


@wp.func
def fmax2(a: float, b: float) -> float:
    """a > b ? a : b (VMAX of sdf_mesh.cl)."""
    if a > b:
        return a
    return b


@wp.func
def fmin2(a: float, b: float) -> float:
    """a < b ? a : b (VMIN of sdf_mesh.cl)."""
    if a < b:
        return a
    return b


@wp.func
def tri_min_dist2(tl: wp.array(dtype=wp.float32), i: int, p: wp.vec3, best: float) -> float:
    """min(best, squared distance from p to triangle i), lane layout (tri_min_dist2_v)."""
    o = TRI_LANES * i
    apx = p[0] - tl[o]
    apy = p[1] - tl[o + 1]
    apz = p[2] - tl[o + 2]
    # edge ab
    s = (apx * tl[o + 3] + apy * tl[o + 4] + apz * tl[o + 5]) * tl[o + 21]
    s = fmin2(fmax2(s, 0.0), 1.0)
    ex = apx - s * tl[o + 3]
    ey = apy - s * tl[o + 4]
    ez = apz - s * tl[o + 5]
    d = ex * ex + ey * ey + ez * ez
    # edge ac
    s = (apx * tl[o + 6] + apy * tl[o + 7] + apz * tl[o + 8]) * tl[o + 22]
    s = fmin2(fmax2(s, 0.0), 1.0)
    ex = apx - s * tl[o + 6]
    ey = apy - s * tl[o + 7]
    ez = apz - s * tl[o + 8]
    e = ex * ex + ey * ey + ez * ez
    d = fmin2(d, e)
    # edge bc, from b
    bpx = apx - tl[o + 3]
    bpy = apy - tl[o + 4]
    bpz = apz - tl[o + 5]
    s = (bpx * tl[o + 12] + bpy * tl[o + 13] + bpz * tl[o + 14]) * tl[o + 23]
    s = fmin2(fmax2(s, 0.0), 1.0)
    ex = bpx - s * tl[o + 12]
    ey = bpy - s * tl[o + 13]
    ez = bpz - s * tl[o + 14]
    e = ex * ex + ey * ey + ez * ez
    d = fmin2(d, e)
    # face: the projection is inside when it is on the inner side of every edge
    thr = tl[o + 28]
    if (apx * tl[o + 15] + apy * tl[o + 16] + apz * tl[o + 17]) >= thr:
        if (bpx * tl[o + 18] + bpy * tl[o + 19] + bpz * tl[o + 20]) >= thr:
            if (apx * tl[o + 24] + apy * tl[o + 25] + apz * tl[o + 26]) >= thr:
                h = apx * tl[o + 9] + apy * tl[o + 10] + apz * tl[o + 11]
                d = h * h * tl[o + 27]
    return fmin2(d, best)


@wp.func
def box_dist2(sbox: wp.array(dtype=wp.float32), k: int, p: wp.vec3) -> float:
    """Squared distance from p to search box k (0 inside), as box_dist2_v."""
    o = 8 * k
    dx = fmax2(fmax2(sbox[o] - p[0], p[0] - sbox[o + 4]), 0.0)
    dy = fmax2(fmax2(sbox[o + 1] - p[1], p[1] - sbox[o + 5]), 0.0)
    dz = fmax2(fmax2(sbox[o + 2] - p[2], p[2] - sbox[o + 6]), 0.0)
    return dx * dx + dy * dy + dz * dz


@wp.func
def atan2_poly(y: float, x: float) -> float:
    """atan2(y, x): the polynomial of atan2_v in sdf_mesh.cl, operation for operation."""
    ax = fmax2(x, -x)
    ay = fmax2(y, -y)
    num = ay
    den = ax
    swap = ay > ax
    if swap:
        num = ax
        den = ay
    s = float(0.0)
    if den > 0.0:
        s = num / den
    t = s * s
    u = float(0.00282363896258175373077393)
    u = u * t - 0.0159569028764963150024414
    u = u * t + 0.0425049886107444763183594
    u = u * t - 0.0748900920152664184570312
    u = u * t + 0.106347933411598205566406
    u = u * t - 0.142027363181114196777344
    u = u * t + 0.199926957488059997558594
    u = u * t - 0.333331018686294555664062
    r = s + s * t * u
    if swap:
        r = 1.57079632679489661923 - r
    if x < 0.0:
        r = 3.14159265358979323846 - r
    if y < 0.0:
        r = -r
    return r


@wp.func
def tri_solid_angle(tris: wp.array(dtype=wp.float32), i: int, p: wp.vec3) -> float:
    """Solid angle of triangle i seen from p (van Oosterom-Strackee), as tri_solid_angle_v."""
    o = 12 * i
    ax = tris[o] - p[0]
    ay = tris[o + 1] - p[1]
    az = tris[o + 2] - p[2]
    bx = ax + tris[o + 3]
    by = ay + tris[o + 4]
    bz = az + tris[o + 5]
    cx = ax + tris[o + 6]
    cy = ay + tris[o + 7]
    cz = az + tris[o + 8]
    la = wp.sqrt(ax * ax + ay * ay + az * az)
    lb = wp.sqrt(bx * bx + by * by + bz * bz)
    lc = wp.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la
    return 2.0 * atan2_poly(det, den)


@wp.func
def winding_number(
    dipole: wp.array(dtype=wp.float32), child: wp.array(dtype=wp.int32), tris: wp.array(dtype=wp.float32), p: wp.vec3
) -> float:
    """Fast generalized winding number at p: dipoles for far nodes, exact near leaves."""
    stack = vec64i()
    sp = int(0)
    node = int(1)
    acc = float(0.0)
    while True:
        o = 8 * node
        dx = dipole[o] - p[0]
        dy = dipole[o + 1] - p[1]
        dz = dipole[o + 2] - p[2]
        d2 = dx * dx + dy * dy + dz * dz
        nxt = int(-1)
        if d2 > dipole[o + 3]:
            acc += (dipole[o + 4] * dx + dipole[o + 5] * dy + dipole[o + 6] * dz) / (d2 * wp.sqrt(d2))
        else:
            a = child[2 * node]
            cnt = child[2 * node + 1]
            if cnt > 0:
                for i in range(a, a + cnt):
                    acc += tri_solid_angle(tris, i, p)
            else:
                stack[sp] = a + 1
                sp += 1
                nxt = a
        if nxt >= 0:
            node = nxt
        elif sp > 0:
            sp -= 1
            node = stack[sp]
        else:
            break
    return acc * INV_4PI


@wp.func
def mesh_distance_at(
    sbox: wp.array(dtype=wp.float32),
    child: wp.array(dtype=wp.int32),
    tri_lanes: wp.array(dtype=wp.float32),
    tris: wp.array(dtype=wp.float32),
    dipole: wp.array(dtype=wp.float32),
    is_signed: int,
    band: float,
    p: wp.vec3,
    seed: int,
    out: wp.array(dtype=wp.float32),
    idx: int,
) -> int:
    """out[idx] <- distance at p, the search bounded by triangle ``seed`` (or -1);
    returns p's closest triangle (or -1 when none is within the band)."""
    init = float(wp.inf)
    if band > 0.0:
        init = band * band
    best = float(init)
    best_tri = int(-1)
    if seed >= 0:
        d = tri_min_dist2(tri_lanes, seed, p, init)
        if d < best:
            best = d
            best_tri = seed
    bound = float(best * PRUNE_REL)
    stack = vec64i()
    stack_d = vec64f()
    sp = int(0)
    node = int(1)
    go = int(0)
    if box_dist2(sbox, 1, p) < bound:
        go = int(1)
    while go != 0:
        a = child[2 * node]
        cnt = child[2 * node + 1]
        descend = int(0)
        if cnt > 0:
            for i in range(a, a + cnt):
                d = tri_min_dist2(tri_lanes, i, p, best)
                if d < best:
                    best = d
                    best_tri = i
            bound = best * PRUNE_REL
        else:
            d0 = box_dist2(sbox, a, p)
            d1 = box_dist2(sbox, a + 1, p)
            near = a
            far = a + 1
            dn = d0
            df = d1
            if d1 < d0:
                near = a + 1
                far = a
                dn = d1
                df = d0
            if dn < bound:
                if df < bound:
                    stack[sp] = far
                    stack_d[sp] = df
                    sp += 1
                node = near
                descend = int(1)
        if descend == 0:
            go = int(0)
            while sp > 0:
                sp -= 1
                if stack_d[sp] < bound:
                    node = stack[sp]
                    go = int(1)
                    break
    dist = float(band)
    if best < init:
        dist = wp.sqrt(best)
    if band > 0.0:
        dist = fmin2(dist, band)
    if is_signed != 0:
        if winding_number(dipole, child, tris, p) > 0.5:
            dist = -dist
    out[idx] = dist
    return best_tri


@wp.kernel
def mesh_distance_points_kernel(
    points: wp.array(dtype=wp.float32),  # (n * 3,) xyz
    n: int,
    run: int,
    sbox: wp.array(dtype=wp.float32),
    child: wp.array(dtype=wp.int32),
    tri_lanes: wp.array(dtype=wp.float32),
    tris: wp.array(dtype=wp.float32),
    dipole: wp.array(dtype=wp.float32),
    is_signed: int,
    band: float,
    out: wp.array(dtype=wp.float32),  # (n,)
):
    """out[i] <- distance at points[i]; thread g handles run points from g * run."""
    g = wp.tid()
    start = g * run
    stop = wp.min(start + run, n)
    seed = int(-1)
    for i in range(start, stop):
        p = wp.vec3(points[3 * i], points[3 * i + 1], points[3 * i + 2])
        seed = mesh_distance_at(sbox, child, tri_lanes, tris, dipole, is_signed, band, p, seed, out, i)


@wp.kernel
def mesh_distance_grid_kernel(
    ox: float,
    oy: float,
    oz: float,
    sx: float,
    sy: float,
    sz: float,
    nx: int,
    ny: int,
    nz: int,
    run: int,
    sbox: wp.array(dtype=wp.float32),
    child: wp.array(dtype=wp.int32),
    tri_lanes: wp.array(dtype=wp.float32),
    tris: wp.array(dtype=wp.float32),
    dipole: wp.array(dtype=wp.float32),
    is_signed: int,
    band: float,
    out: wp.array(dtype=wp.float32),  # (nz * ny * nx,)
):
    """out[(k * ny + j) * nx + i] <- distance at origin + spacing * (i, j, k); thread
    (k, j, g) handles run samples of row (j, k) from i = g * run."""
    k, j, g = wp.tid()
    start = g * run
    stop = wp.min(start + run, nx)
    py = oy + sy * float(j)
    pz = oz + sz * float(k)
    row = (k * ny + j) * nx
    seed = int(-1)
    for i in range(start, stop):
        p = wp.vec3(ox + sx * float(i), py, pz)
        seed = mesh_distance_at(sbox, child, tri_lanes, tris, dipole, is_signed, band, p, seed, out, row + i)
