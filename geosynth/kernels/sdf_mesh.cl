// Distance-field kernels (mesh): OpenCL. The twin of sdf_mesh.py.
//
// Both kernels compute, per query point p, the exact distance to the mesh (closest
// point over all triangles, by a BVH traversal with a stack) and, when `is_signed`,
// its sign from the fast generalized winding number (Barill et al. 2018) on the same
// BVH: negative where the winding number exceeds 1/2. They take tiles of 16 points as
// the lanes of SIMD vectors (below): mesh_distance_grid 4 x 2 x 2 grid samples,
// mesh_distance_points 16 consecutive points (the host sorts them in Morton order).
//
// One result on every device: each lane's distance is the minimum over ALL
// triangles of one per-triangle float expression (tri_min_dist2_v; sdf_mesh.py has the
// same operations in the same order), found by a search whose pruning keeps a safety
// margin larger than any rounding (search boxes grown on the host, and a node is left
// out only when its box is farther than PRUNE_REL times the best so far). The minimum
// of the same floats does not depend on the visiting order, so the tile shape, the
// traversal and the device do not change the result. The winding number adds the same
// terms in the same order as the per-point traversal of sdf_mesh.py, with the same
// atan2 polynomial. No contraction into FMAs (pragma below; Warp: fuse_fp off) and
// correctly rounded division and sqrt (-cl-fp32-correctly-rounded-divide-sqrt).
//
// BVH layout (geosynth.geometry.meshes.MeshBVH; node 0 unused, root = node 1):
//   sbox   (N * 8) float: search box min xyz, 0, max xyz, 0 (grown by geosynth.geometry.meshes.BOX_SLACK);
//          the two children of a node are adjacent
//   child  (N * 2) int:   internal (first child, 0) | leaf (first triangle, count > 0)
//   dipole (N * 8) float: centroid xyz, (beta r)^2, area-weighted normal sum xyz, 0
//   tris   (F * 12) float: a, b - a, c - a, |b-a|^2, |c-a|^2, (b-a).(c-a)
// `band` > 0 clamps the result to [-band, band] and prunes the search beyond it;
// band <= 0 means no band.
//
// PoCL note (common.h): builtins are calls there, so the hot paths use plain operators
// and clang's sqrt builtins (one instruction each).
#pragma OPENCL FP_CONTRACT OFF
#include "common.h"

#define STACK_SIZE 64
#define INV_4PI 0.0795774715459476678f
// A node is searched while its box is nearer than PRUNE_REL * best (squared): slack
// for the rounding of the box and triangle distances of far points (near ones are
// covered by the grown boxes).
#define PRUNE_REL 1.0009765625f

// ------------------------------------------------------------------ tiles
//
// The grid kernel below evaluates TILE_X x TILE_Y x TILE_Z = 16 neighbouring grid
// samples per work-item as the 16 lanes of float16 vectors (one AVX-512 register):
// one BVH traversal per tile, each lane keeping its own best distance (a node is
// entered when it may hold a closer triangle for ANY lane), and every triangle of a
// visited leaf tested against the 16 lanes at once with branch-free code. Per lane
// the result is exactly the per-point one: the closest triangle over the whole mesh.
// The winding number traverses the same way with a mask of the lanes that still
// descend: each lane adds exactly the terms (dipoles of its far nodes, exact solid
// angles of its near leaves) in exactly the order of the per-point traversal above,
// so the sign is the per-point algorithm's, lane by lane.
//
// Lane triangles `tri_lanes` (F * 32) float, in leaf order (geosynth.geometry.meshes.MeshBVH):
//   0 a, 3 ab = b - a, 6 ac = c - a, 9 n = ab x ac, 12 bc = c - b,
//   15 n x ab, 18 n x bc, 21 1/|ab|^2, 22 1/|ac|^2, 23 1/|bc|^2, 24 ac x n,
//   27 1/|n|^2, 28 inside threshold (0; +inf for a needle whose normal underflows)
#define TILE_X 4
#define TILE_Y 2
#define TILE_Z 2
#define TRI_LANES 32

typedef float16 vf;
typedef int16 vm;

#ifdef __AVX512F__
#define VSQRT(v) __builtin_ia32_sqrtps512((v), 4)
#else
// sqrt of each half: PoCL 3.0 aborts generating code for its 16-wide sqrt on CPUs whose
// AVX-512 its LLVM does not know (Zen 4: "Cannot select ... fsqrt", _cl_sqrtDv16_f). The
// same correctly rounded square root per lane.
#define VSQRT(v) ((vf)(sqrt((v).lo), sqrt((v).hi)))
#endif
#define VMIN(a, b) ((a) < (b) ? (a) : (b))
#define VMAX(a, b) ((a) > (b) ? (a) : (b))
#define ANY(m) (__builtin_reduce_or(m) != 0)

// Per lane: min(best, squared distance from the point to the triangle at t (lane
// layout above)): the plane distance where the projection falls inside, else the
// nearest of the edges.
inline vf tri_min_dist2_v(const __global float* t, vf px, vf py, vf pz, vf best)
{
    const vf zero = (vf)0.0f, one = (vf)1.0f;
    const vf apx = px - t[0], apy = py - t[1], apz = pz - t[2];
    // edge ab
    vf s = (apx * t[3] + apy * t[4] + apz * t[5]) * t[21];
    s = VMIN(VMAX(s, zero), one);
    vf ex = apx - s * t[3], ey = apy - s * t[4], ez = apz - s * t[5];
    vf d = ex * ex + ey * ey + ez * ez;
    // edge ac
    s = (apx * t[6] + apy * t[7] + apz * t[8]) * t[22];
    s = VMIN(VMAX(s, zero), one);
    ex = apx - s * t[6]; ey = apy - s * t[7]; ez = apz - s * t[8];
    vf e = ex * ex + ey * ey + ez * ez;
    d = VMIN(d, e);
    // edge bc, from b
    const vf bpx = apx - t[3], bpy = apy - t[4], bpz = apz - t[5];
    s = (bpx * t[12] + bpy * t[13] + bpz * t[14]) * t[23];
    s = VMIN(VMAX(s, zero), one);
    ex = bpx - s * t[12]; ey = bpy - s * t[13]; ez = bpz - s * t[14];
    e = ex * ex + ey * ey + ez * ez;
    d = VMIN(d, e);
    // face: the projection is inside when it is on the inner side of every edge
    const float thr = t[28];
    const vm in = ((apx * t[15] + apy * t[16] + apz * t[17]) >= thr)
        & ((bpx * t[18] + bpy * t[19] + bpz * t[20]) >= thr)
        & ((apx * t[24] + apy * t[25] + apz * t[26]) >= thr);
    const vf h = apx * t[9] + apy * t[10] + apz * t[11];
    d = in ? h * h * t[27] : d;
    return VMIN(d, best);
}

inline vf box_dist2_v(const __global float* b, vf px, vf py, vf pz)
{
    const vf zero = (vf)0.0f;
    vf dx = VMAX(b[0] - px, px - b[4]);
    vf dy = VMAX(b[1] - py, py - b[5]);
    vf dz = VMAX(b[2] - pz, pz - b[6]);
    dx = VMAX(dx, zero); dy = VMAX(dy, zero); dz = VMAX(dz, zero);
    return dx * dx + dy * dy + dz * dz;
}

// Per lane: the smallest squared distance below best (else best): the minimum of
// tri_min_dist2_v over every triangle whose distance can be below it. A node is
// entered while its search box is nearer than PRUNE_REL * best for ANY lane.
inline vf closest_dist2_v(
    const __global float* sbox, const __global int* child, const __global float* tl,
    vf px, vf py, vf pz, vf best)
{
    int stack[STACK_SIZE];
    int sp = 0;
    int node = 1;
    vf bound = best * PRUNE_REL;
    if (!ANY(box_dist2_v(sbox + 8, px, py, pz) < bound))
        return best;
    for (;;) {
        const int a = child[2 * node];
        const int cnt = child[2 * node + 1];
        if (cnt > 0) {
            for (int i = a; i < a + cnt; ++i) {
                best = tri_min_dist2_v(tl + TRI_LANES * i, px, py, pz, best);
            }
            bound = best * PRUNE_REL;
        } else {
            const vf d0 = box_dist2_v(sbox + 8 * a, px, py, pz);
            const vf d1 = box_dist2_v(sbox + 8 * (a + 1), px, py, pz);
            const int h0 = ANY(d0 < bound), h1 = ANY(d1 < bound);
            if (h0 && h1) {
                const int near_first = __builtin_reduce_min(d0) <= __builtin_reduce_min(d1);
                stack[sp++] = near_first ? a + 1 : a;
                node = near_first ? a : a + 1;
                continue;
            }
            if (h0 | h1) {
                node = h0 ? a : a + 1;
                continue;
            }
        }
        int found = 0;
        while (sp > 0) {
            const int n = stack[--sp];
            if (ANY(box_dist2_v(sbox + 8 * n, px, py, pz) < bound)) { node = n; found = 1; break; }
        }
        if (!found)
            return best;
    }
}

// atan2(y, x) per lane, inline (PoCL calls its builtin; and one polynomial on every
// device): reduction to [0, 1] and the minimax polynomial of SLEEF's atanf (about 3
// ulp). sdf_mesh.py's atan2_poly is the same, operation for operation.
inline vf atan2_v(vf y, vf x)
{
    const vf ax = VMAX(x, -x), ay = VMAX(y, -y);
    const vm swap = ay > ax;
    const vf num = swap ? ax : ay, den = swap ? ay : ax;
    const vf s = den > 0.0f ? num / den : (vf)0.0f;
    const vf t = s * s;
    vf u = (vf)0.00282363896258175373077393f;
    u = u * t - 0.0159569028764963150024414f;
    u = u * t + 0.0425049886107444763183594f;
    u = u * t - 0.0748900920152664184570312f;
    u = u * t + 0.106347933411598205566406f;
    u = u * t - 0.142027363181114196777344f;
    u = u * t + 0.199926957488059997558594f;
    u = u * t - 0.333331018686294555664062f;
    vf r = s + s * t * u;
    r = swap ? 1.57079632679489661923f - r : r;
    r = x < 0.0f ? 3.14159265358979323846f - r : r;
    return y < 0.0f ? -r : r;
}

// Solid angles of triangle t (tris layout) seen from 16 points (van Oosterom-Strackee),
// positive when p is on the side its normal points away from; as tri_solid_angle in sdf_mesh.py.
inline vf tri_solid_angle_v(const __global float* t, vf px, vf py, vf pz)
{
    const vf ax = t[0] - px, ay = t[1] - py, az = t[2] - pz;
    const vf bx = ax + t[3], by = ay + t[4], bz = az + t[5];
    const vf cx = ax + t[6], cy = ay + t[7], cz = az + t[8];
    const vf la = VSQRT(ax * ax + ay * ay + az * az);
    const vf lb = VSQRT(bx * bx + by * by + bz * bz);
    const vf lc = VSQRT(cx * cx + cy * cy + cz * cz);
    const vf det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx);
    const vf den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc
        + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la;
    return 2.0f * atan2_v(det, den);
}

// Per lane: the fast winding number (dipoles for far nodes, exact near leaves) of
// winding_number() in sdf_mesh.py, lanes as a descent mask.
inline vf winding_number_v(
    const __global float* dipole, const __global int* child, const __global float* tris,
    vf px, vf py, vf pz)
{
    int stack[STACK_SIZE];
    vm stack_m[STACK_SIZE];
    int sp = 0;
    int node = 1;
    vm act = (vm)(-1);
    vf acc = (vf)0.0f;
    for (;;) {
        const __global float* q = dipole + 8 * node;
        const vf dx = q[0] - px, dy = q[1] - py, dz = q[2] - pz;
        const vf d2 = dx * dx + dy * dy + dz * dz;
        const vm far = d2 > q[3];
        const vm take = far & act;
        if (ANY(take)) {
            const vf term = (q[4] * dx + q[5] * dy + q[6] * dz) / (d2 * VSQRT(d2));
            acc = take ? acc + term : acc;
        }
        const vm near = act & ~far;
        int next = -1;
        if (ANY(near)) {
            const int a = child[2 * node];
            const int cnt = child[2 * node + 1];
            if (cnt > 0) {
                for (int i = a; i < a + cnt; ++i) {
                    const vf sa = tri_solid_angle_v(tris + 12 * i, px, py, pz);
                    acc = near ? acc + sa : acc;
                }
            } else {
                stack[sp] = a + 1;
                stack_m[sp] = near;
                ++sp;
                next = a;
                act = near;
            }
        }
        if (next >= 0) {
            node = next;
        } else if (sp > 0) {
            --sp;
            node = stack[sp];
            act = stack_m[sp];
        } else {
            break;
        }
    }
    return acc * INV_4PI;
}

// Per lane: the signed / unsigned, banded distance at (px, py, pz).
inline vf mesh_distance_v(
    const __global float* sbox, const __global int* child, const __global float* tri_lanes,
    const __global float* tris, const __global float* dipole, int is_signed, float band,
    vf px, vf py, vf pz)
{
    const vf init = (vf)(band > 0.0f ? band * band : INFINITY);
    const vf best = closest_dist2_v(sbox, child, tri_lanes, px, py, pz, init);
    vf dist = best < init ? VSQRT(best) : (vf)band;
    if (band > 0.0f)
        dist = VMIN(dist, (vf)band);
    if (is_signed) {
        const vf w = winding_number_v(dipole, child, tris, px, py, pz);
        dist = w > 0.5f ? -dist : dist;
    }
    return dist;
}

// out[(k * ny + j) * nx + i] <- distance at origin + spacing * (i, j, k); work-item
// (ti, tj, tk) handles the tile of samples i = TILE_X ti ..., j = TILE_Y tj ...,
// k = TILE_Z tk ... (lanes past the grid's end repeat its last sample, unwritten).
__kernel void mesh_distance_grid(
    float ox, float oy, float oz, float sx, float sy, float sz, int nx, int ny, int nz,
    const __global float* sbox, const __global int* child, const __global float* tri_lanes,
    const __global float* tris, const __global float* dipole, int is_signed, float band,
    __global float* out)
{
    const int i0 = get_global_id(0) * TILE_X;
    const int j0 = get_global_id(1) * TILE_Y;
    const int k0 = get_global_id(2) * TILE_Z;
    if (i0 >= nx || j0 >= ny || k0 >= nz)
        return;
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const int16 li = lane % TILE_X, lj = (lane / TILE_X) % TILE_Y, lk = lane / (TILE_X * TILE_Y);
    int16 ii = i0 + li, jj = j0 + lj, kk = k0 + lk;
    ii = VMIN(ii, (int16)(nx - 1));
    jj = VMIN(jj, (int16)(ny - 1));
    kk = VMIN(kk, (int16)(nz - 1));
    const vf px = ox + sx * __builtin_convertvector(ii, vf);
    const vf py = oy + sy * __builtin_convertvector(jj, vf);
    const vf pz = oz + sz * __builtin_convertvector(kk, vf);
    const vf dist = mesh_distance_v(sbox, child, tri_lanes, tris, dipole, is_signed, band, px, py, pz);
    float res[16];
    *(f32x16u*)res = dist;
    const int mi = MIN_INT(TILE_X, nx - i0), mj = MIN_INT(TILE_Y, ny - j0), mk = MIN_INT(TILE_Z, nz - k0);
    for (int c = 0; c < mk; ++c)
        for (int b = 0; b < mj; ++b) {
            const int row = ((k0 + c) * ny + (j0 + b)) * nx + i0;
            for (int a = 0; a < mi; ++a)
                out[row + a] = res[(c * TILE_Y + b) * TILE_X + a];
        }
}

// out[i] <- distance at points[i] (xyz), for i < n; work-item g handles the 16 points
// from 16 g as one tile (lanes past n repeat the last point, unwritten). Nearby points
// in consecutive slots make tight tiles: the host passes them in Morton order.
__kernel void mesh_distance_points(
    const __global float* points, int n,
    const __global float* sbox, const __global int* child, const __global float* tri_lanes,
    const __global float* tris, const __global float* dipole, int is_signed, float band,
    __global float* out)
{
    const int i0 = get_global_id(0) * 16;
    if (i0 >= n)
        return;
    float xs[16], ys[16], zs[16];
    for (int l = 0; l < 16; ++l) {
        const int i = MIN_INT(i0 + l, n - 1);
        xs[l] = points[3 * i];
        ys[l] = points[3 * i + 1];
        zs[l] = points[3 * i + 2];
    }
    const vf px = *(f32x16u*)xs, py = *(f32x16u*)ys, pz = *(f32x16u*)zs;
    const vf dist = mesh_distance_v(sbox, child, tri_lanes, tris, dipole, is_signed, band, px, py, pz);
    float res[16];
    *(f32x16u*)res = dist;
    const int m = MIN_INT(16, n - i0);
    for (int l = 0; l < m; ++l)
        out[i0 + l] = res[l];
}
