"""Distance-field kernels (mesh): Warp. The twin of sdf_mesh.cl.

Both kernels compute, per query point p, the exact distance to the mesh and, when
``is_signed``, its sign from the fast generalized winding number (Barill et al.
2018): negative where the winding number exceeds 1/2. Same kernel names (with the
``_kernel`` suffix) and arguments in the same order as sdf_mesh.cl, except that the
closest-point search runs on a ``wp.Mesh`` (its id stands where sdf_mesh.cl takes the
BVH boxes ``bbox``); the winding number traverses the same BVH arrays as sdf_mesh.cl
(geosynth.meshes.MeshBVH: ``child``, ``tris``, ``dipole``) in the same order, so the
two backends agree on the sign. The wp.Mesh is built over the triangles in the same
(leaf) order as ``tris``, so its face indices are ``tris`` rows.

``band`` > 0 clamps the result to [-band, band] and limits the search to it; <= 0
means no band. Points are processed ``run`` at a time per thread, each search bounded
by the distance to the previous point's closest triangle (exact, only faster). The
OpenCL grid kernel differs in its launch: it takes tiles of 16 samples as SIMD lanes
(no ``run``; the lane triangles ``tri_lanes`` before ``tris``), with per lane the same
closest distance and the same winding-number terms in the same order as here.
Host wrappers live in ``geosynth._backends.warp_mesh``; nothing here validates.
"""

import warp as wp

STACK_SIZE = 64
vec64i = wp.types.vector(length=STACK_SIZE, dtype=wp.int32)
INV_4PI = wp.constant(0.0795774715459476678)
BIG = wp.constant(1.0e30)


@wp.func
def tri_dist2(tris: wp.array(dtype=wp.float32), i: int, p: wp.vec3) -> float:
    """Squared distance from p to triangle i (Ericson 5.1.5, as tri_dist2 in sdf_mesh.cl)."""
    o = 12 * i
    apx = p[0] - tris[o]
    apy = p[1] - tris[o + 1]
    apz = p[2] - tris[o + 2]
    abx = tris[o + 3]
    aby = tris[o + 4]
    abz = tris[o + 5]
    acx = tris[o + 6]
    acy = tris[o + 7]
    acz = tris[o + 8]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    s = float(0.0)
    w = float(0.0)
    if d1 <= 0.0 and d2 <= 0.0:
        s = 0.0
    else:
        d3 = d1 - tris[o + 9]
        d4 = d2 - tris[o + 11]
        d5 = d1 - tris[o + 11]
        d6 = d2 - tris[o + 10]
        if d3 >= 0.0 and d4 <= d3:
            s = 1.0
        elif d6 >= 0.0 and d5 <= d6:
            w = 1.0
        else:
            vc = d1 * d4 - d3 * d2
            vb = d5 * d2 - d1 * d6
            va = d3 * d6 - d5 * d4
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                s = d1 / (d1 - d3)
            elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                w = d2 / (d2 - d6)
            elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                s = 1.0 - w
            else:
                inv = 1.0 / (va + vb + vc)
                s = vb * inv
                w = vc * inv
    ex = apx - abx * s - acx * w
    ey = apy - aby * s - acy * w
    ez = apz - abz * s - acz * w
    return ex * ex + ey * ey + ez * ez


@wp.func
def tri_solid_angle(tris: wp.array(dtype=wp.float32), i: int, p: wp.vec3) -> float:
    """Solid angle of triangle i seen from p (van Oosterom-Strackee), as in sdf_mesh.cl."""
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
    return 2.0 * wp.atan2(det, den)


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
    mesh: wp.uint64,
    child: wp.array(dtype=wp.int32),
    tris: wp.array(dtype=wp.float32),
    dipole: wp.array(dtype=wp.float32),
    is_signed: int,
    band: float,
    p: wp.vec3,
    seed: int,
    out: wp.array(dtype=wp.float32),
    idx: int,
) -> int:
    """out[idx] <- distance at p, the search bounded by triangle ``seed``; returns the
    closest triangle (or -1 when none is within the band)."""
    best = BIG
    if band > 0.0:
        best = band
    best_tri = int(-1)
    if seed >= 0:
        d = wp.sqrt(tri_dist2(tris, seed, p))
        if d < best:
            best = d
            best_tri = seed
    q = wp.mesh_query_point_no_sign(mesh, p, best)
    if q.result:
        c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        d = wp.length(c - p)
        if d < best or best_tri < 0:
            best = d
            best_tri = q.face
    dist = best
    if best_tri < 0 or (band > 0.0 and dist > band):
        dist = band
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
    mesh: wp.uint64,
    child: wp.array(dtype=wp.int32),
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
        seed = mesh_distance_at(mesh, child, tris, dipole, is_signed, band, p, seed, out, i)


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
    mesh: wp.uint64,
    child: wp.array(dtype=wp.int32),
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
        seed = mesh_distance_at(mesh, child, tris, dipole, is_signed, band, p, seed, out, row + i)
