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
// band <= 0 means no band. Points are processed `run` at a time per work-item, each
// search seeded with the previous point's closest triangle (an exact upper bound).
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

// out[(k * ny + j) * nx + i] <- distance at origin + spacing * (i, j, k); work-item
// (g, j, k) handles run samples of row (j, k) from i = g * run.
__kernel void mesh_distance_grid(
    float ox, float oy, float oz, float sx, float sy, float sz, int nx, int ny, int nz, int run,
    const __global float* bbox, const __global int* child, const __global float* tris,
    const __global float* dipole, int is_signed, float band,
    __global float* out)
{
    const int g = get_global_id(0);
    const int j = get_global_id(1);
    const int k = get_global_id(2);
    const int start = g * run;
    if (start >= nx || j >= ny || k >= nz)
        return;
    const int stop = MIN_INT(start + run, nx);
    const float py = oy + sy * (float)j;
    const float pz = oz + sz * (float)k;
    const int row = (k * ny + j) * nx;
    int seed = -1;
    for (int i = start; i < stop; ++i) {
        out[row + i] = mesh_distance_at(bbox, child, tris, dipole, is_signed, band,
                                        ox + sx * (float)i, py, pz, &seed);
    }
}
