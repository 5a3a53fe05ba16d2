// Distance-field kernels (mesh): OpenCL. The twin of sdf_mesh.py.
//
// Both kernels compute, per query point p, the exact distance to the mesh (closest
// point over all triangles, by a nearest-child-first BVH traversal with a stack) and,
// when `is_signed`, its sign from the fast generalized winding number (Barill et al.
// 2018) on the same BVH: negative where the winding number exceeds 1/2.
//
// BVH layout (geosynth.meshes.MeshBVH; node 0 unused, root = node 1):
//   bbox   (N * 8) float: min xyz, 0, max xyz, 0; the two children of a node are adjacent
//   child  (N * 2) int:   internal (first child, 0) | leaf (first triangle, count > 0)
//   dipole (N * 8) float: centroid xyz, (beta r)^2, area-weighted normal sum xyz, 0
//   tris   (F * 12) float: a, b - a, c - a, |b-a|^2, |c-a|^2, (b-a).(c-a)
// `band` > 0 clamps the result to [-band, band] and prunes the search beyond it;
// band <= 0 means no band. mesh_distance_points processes `run` points per work-item,
// each search seeded with the previous point's closest triangle (an exact upper
// bound); mesh_distance_grid processes tiles of 16 samples as SIMD lanes (below).
//
// PoCL note (common.h): builtins are calls there, so the hot paths use plain operators
// and clang's __builtin_sqrtf (one instruction); atan2 remains a call, once per exact
// solid angle.
#include "common.h"

#define STACK_SIZE 64
#define INV_4PI 0.0795774715459476678f

// Squared distance from (px, py, pz) to triangle t (Ericson, Real-Time Collision
// Detection 5.1.5, with the edge products precomputed).
inline float tri_dist2(const __global float* t, float px, float py, float pz)
{
    const float apx = px - t[0], apy = py - t[1], apz = pz - t[2];
    const float abx = t[3], aby = t[4], abz = t[5];
    const float acx = t[6], acy = t[7], acz = t[8];
    const float d1 = abx * apx + aby * apy + abz * apz;
    const float d2 = acx * apx + acy * apy + acz * apz;
    float s, w;
    if (d1 <= 0.0f && d2 <= 0.0f) {
        s = 0.0f; w = 0.0f;
    } else {
        const float d3 = d1 - t[9];
        const float d4 = d2 - t[11];
        const float d5 = d1 - t[11];
        const float d6 = d2 - t[10];
        if (d3 >= 0.0f && d4 <= d3) {
            s = 1.0f; w = 0.0f;
        } else if (d6 >= 0.0f && d5 <= d6) {
            s = 0.0f; w = 1.0f;
        } else {
            const float vc = d1 * d4 - d3 * d2;
            const float vb = d5 * d2 - d1 * d6;
            const float va = d3 * d6 - d5 * d4;
            if (vc <= 0.0f && d1 >= 0.0f && d3 <= 0.0f) {
                s = d1 / (d1 - d3); w = 0.0f;
            } else if (vb <= 0.0f && d2 >= 0.0f && d6 <= 0.0f) {
                s = 0.0f; w = d2 / (d2 - d6);
            } else if (va <= 0.0f && (d4 - d3) >= 0.0f && (d5 - d6) >= 0.0f) {
                w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
                s = 1.0f - w;
            } else {
                const float inv = 1.0f / (va + vb + vc);
                s = vb * inv; w = vc * inv;
            }
        }
    }
    const float ex = apx - abx * s - acx * w;
    const float ey = apy - aby * s - acy * w;
    const float ez = apz - abz * s - acz * w;
    return ex * ex + ey * ey + ez * ez;
}

// Squared distance from a point to box k (0 inside).
inline float box_dist2(const __global float* bbox, int k, float px, float py, float pz)
{
    const __global float* b = bbox + 8 * k;
    const float dx = px < b[0] ? b[0] - px : (px > b[4] ? px - b[4] : 0.0f);
    const float dy = py < b[1] ? b[1] - py : (py > b[5] ? py - b[5] : 0.0f);
    const float dz = pz < b[2] ? b[2] - pz : (pz > b[6] ? pz - b[6] : 0.0f);
    return dx * dx + dy * dy + dz * dz;
}

// Smallest squared distance below `best` (else `best`), its triangle in *best_tri.
inline float closest_dist2(
    const __global float* bbox, const __global int* child, const __global float* tris,
    float px, float py, float pz, float best, int* best_tri)
{
    int stack[STACK_SIZE];
    float stack_d[STACK_SIZE];
    int sp = 0;
    int node = 1;
    if (box_dist2(bbox, 1, px, py, pz) >= best)
        return best;
    for (;;) {
        const int a = child[2 * node];
        const int cnt = child[2 * node + 1];
        int descend = 0;
        if (cnt > 0) {
            for (int i = a; i < a + cnt; ++i) {
                const float d = tri_dist2(tris + 12 * i, px, py, pz);
                if (d < best) { best = d; *best_tri = i; }
            }
        } else {
            const float d0 = box_dist2(bbox, a, px, py, pz);
            const float d1 = box_dist2(bbox, a + 1, px, py, pz);
            const int near_first = d0 <= d1;
            const float dn = near_first ? d0 : d1;
            const float df = near_first ? d1 : d0;
            if (dn < best) {
                if (df < best) {
                    stack[sp] = near_first ? a + 1 : a;
                    stack_d[sp] = df;
                    ++sp;
                }
                node = near_first ? a : a + 1;
                descend = 1;
            }
        }
        if (descend)
            continue;
        // pop the next subtree still closer than the best so far
        int found = 0;
        while (sp > 0) {
            --sp;
            if (stack_d[sp] < best) { node = stack[sp]; found = 1; break; }
        }
        if (!found)
            return best;
    }
}

// Solid angle of triangle t seen from p (van Oosterom-Strackee), positive when p is
// on the side its normal points away from.
inline float tri_solid_angle(const __global float* t, float px, float py, float pz)
{
    const float ax = t[0] - px, ay = t[1] - py, az = t[2] - pz;
    const float bx = ax + t[3], by = ay + t[4], bz = az + t[5];
    const float cx = ax + t[6], cy = ay + t[7], cz = az + t[8];
    const float la = __builtin_sqrtf(ax * ax + ay * ay + az * az);
    const float lb = __builtin_sqrtf(bx * bx + by * by + bz * bz);
    const float lc = __builtin_sqrtf(cx * cx + cy * cy + cz * cz);
    const float det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx);
    const float den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc
        + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la;
    return 2.0f * atan2(det, den);
}

// Fast generalized winding number at p: dipoles for far nodes, exact near leaves.
inline float winding_number(
    const __global float* dipole, const __global int* child, const __global float* tris,
    float px, float py, float pz)
{
    int stack[STACK_SIZE];
    int sp = 0;
    int node = 1;
    float acc = 0.0f;
    for (;;) {
        const __global float* q = dipole + 8 * node;
        const float dx = q[0] - px, dy = q[1] - py, dz = q[2] - pz;
        const float d2 = dx * dx + dy * dy + dz * dz;
        int next = -1;
        if (d2 > q[3]) {
            acc += (q[4] * dx + q[5] * dy + q[6] * dz) / (d2 * __builtin_sqrtf(d2));
        } else {
            const int a = child[2 * node];
            const int cnt = child[2 * node + 1];
            if (cnt > 0) {
                for (int i = a; i < a + cnt; ++i)
                    acc += tri_solid_angle(tris + 12 * i, px, py, pz);
            } else {
                stack[sp++] = a + 1;
                next = a;
            }
        }
        if (next >= 0) {
            node = next;
        } else if (sp > 0) {
            node = stack[--sp];
        } else {
            break;
        }
    }
    return acc * INV_4PI;
}

// Signed / unsigned, banded distance at p; *seed is the previous closest triangle
// (or -1) on entry and this point's on exit.
inline float mesh_distance_at(
    const __global float* bbox, const __global int* child, const __global float* tris,
    const __global float* dipole, int is_signed, float band,
    float px, float py, float pz, int* seed)
{
    float best = band > 0.0f ? band * band : INFINITY;
    int best_tri = -1;
    if (*seed >= 0) {
        const float d = tri_dist2(tris + 12 * (*seed), px, py, pz);
        if (d < best) { best = d; best_tri = *seed; }
    }
    best = closest_dist2(bbox, child, tris, px, py, pz, best, &best_tri);
    *seed = best_tri;
    float dist = best_tri >= 0 ? __builtin_sqrtf(best) : band;
    if (band > 0.0f && dist > band)
        dist = band;
    if (is_signed && winding_number(dipole, child, tris, px, py, pz) > 0.5f)
        dist = -dist;
    return dist;
}

// out[i] <- distance at points[i] (xyz), for i < n; work-item g handles run points
// from g * run.
__kernel void mesh_distance_points(
    const __global float* points, int n, int run,
    const __global float* bbox, const __global int* child, const __global float* tris,
    const __global float* dipole, int is_signed, float band,
    __global float* out)
{
    const int g = get_global_id(0);
    const int start = g * run;
    if (start >= n)
        return;
    const int stop = MIN_INT(start + run, n);
    int seed = -1;
    for (int i = start; i < stop; ++i) {
        out[i] = mesh_distance_at(bbox, child, tris, dipole, is_signed, band,
                                  points[3 * i], points[3 * i + 1], points[3 * i + 2], &seed);
    }
}

// ------------------------------------------------------------------ grid tiles
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
// Lane triangles `tri_lanes` (F * 32) float, in leaf order (geosynth.meshes.MeshBVH):
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
#define VSQRT(v) sqrt(v)
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

// Per lane: the smallest squared distance below best (else best).
inline vf closest_dist2_v(
    const __global float* bbox, const __global int* child, const __global float* tl,
    vf px, vf py, vf pz, vf best)
{
    int stack[STACK_SIZE];
    int sp = 0;
    int node = 1;
    if (!ANY(box_dist2_v(bbox + 8, px, py, pz) < best))
        return best;
    for (;;) {
        const int a = child[2 * node];
        const int cnt = child[2 * node + 1];
        if (cnt > 0) {
            for (int i = a; i < a + cnt; ++i) {
                best = tri_min_dist2_v(tl + TRI_LANES * i, px, py, pz, best);
            }
        } else {
            const vf d0 = box_dist2_v(bbox + 8 * a, px, py, pz);
            const vf d1 = box_dist2_v(bbox + 8 * (a + 1), px, py, pz);
            const int h0 = ANY(d0 < best), h1 = ANY(d1 < best);
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
            if (ANY(box_dist2_v(bbox + 8 * n, px, py, pz) < best)) { node = n; found = 1; break; }
        }
        if (!found)
            return best;
    }
}

// atan2(y, x) per lane, inline (PoCL calls its builtin): reduction to [0, 1] and the
// minimax polynomial of SLEEF's atanf (about 3 ulp).
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

// Solid angles of triangle t (tris layout) seen from 16 points, as tri_solid_angle.
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

// Per lane: the fast winding number of winding_number(), lanes as a descent mask.
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

// out[(k * ny + j) * nx + i] <- distance at origin + spacing * (i, j, k); work-item
// (ti, tj, tk) handles the tile of samples i = TILE_X ti ..., j = TILE_Y tj ...,
// k = TILE_Z tk ... (lanes past the grid's end repeat its last sample, unwritten).
__kernel void mesh_distance_grid(
    float ox, float oy, float oz, float sx, float sy, float sz, int nx, int ny, int nz,
    const __global float* bbox, const __global int* child, const __global float* tri_lanes,
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
    const vf init = (vf)(band > 0.0f ? band * band : INFINITY);
    const vf best = closest_dist2_v(bbox, child, tri_lanes, px, py, pz, init);
    vf dist = best < init ? VSQRT(best) : (vf)band;
    if (band > 0.0f)
        dist = VMIN(dist, (vf)band);
    if (is_signed) {
        const vf w = winding_number_v(dipole, child, tris, px, py, pz);
        dist = w > 0.5f ? -dist : dist;
    }
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
