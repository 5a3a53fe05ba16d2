// M4 FindMatches (Breckon and Fisher, "3D Surface Relief and Colour Completion", Sec. 3, 6
// and Appendix A): every target neighbourhood of a batch against every candidate sample at
// every rotation, one work-item per (query, candidate, rotation). The twin of relief.py
// (same kernels, same arguments in the same order; see there for the definitions).
// Integer arithmetic; the only floating-point operations are single IEEE double
// multiplications and divisions of exact integers (correctly rounded in OpenCL C),
// truncated, so the codes are the same bits on every device.
#include "common.h"

#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#pragma OPENCL FP_CONTRACT OFF

#define R_CLAMP ((long)1 << 13)
#define R_MAX_WALK 256
#define R_CODE_CAP ((long)1 << 31)
#define R_OVER ((long)0xFFFFFFFEu)
#define R_INVALID ((long)0xFFFFFFFFu)
#define R_INLINE __attribute__((always_inline)) inline

typedef struct { long x, y, z; } l3;

R_INLINE l3 l3_at(__global const int* a, int i)
{
    l3 r = {(long)a[3 * i], (long)a[3 * i + 1], (long)a[3 * i + 2]};
    return r;
}
R_INLINE l3 l3_sub(l3 a, l3 b) { l3 r = {a.x - b.x, a.y - b.y, a.z - b.z}; return r; }
R_INLINE l3 l3_add(l3 a, l3 b) { l3 r = {a.x + b.x, a.y + b.y, a.z + b.z}; return r; }
R_INLINE long l3_dot(l3 a, l3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
R_INLINE l3 l3_cross(l3 a, l3 b)
{
    l3 r = {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
    return r;
}
R_INLINE long clampl(long v) { return v < -R_CLAMP ? -R_CLAMP : (v > R_CLAMP ? R_CLAMP : v); }

// sum_k c_k * frame row k, rounded: (x + 2^13) >> 14 (arithmetic shift)
R_INLINE l3 to_world(long c0, long c1, long c2, l3 fu, l3 fv, l3 fn)
{
    const long h = (long)1 << 13;
    l3 r = {(fu.x * c0 + fv.x * c1 + fn.x * c2 + h) >> 14, (fu.y * c0 + fv.y * c1 + fn.y * c2 + h) >> 14,
            (fu.z * c0 + fv.z * c1 + fn.z * c2 + h) >> 14};
    return r;
}

R_INLINE double edge_d2(l3 e, l3 p)
{
    const long ee = l3_dot(e, e), pp = l3_dot(p, p);
    if (ee <= 0) return (double)pp;
    const long pe = l3_dot(p, e);
    return (double)(pp * ee - pe * pe) / (double)ee;
}

// Squared distance from a point to a triangle, corner a at the origin (Ericson's regions:
// exact integer tests, then one double division of exact integers).
R_INLINE double tri_d2(l3 ap, l3 ab, l3 ac)
{
    const l3 bp = l3_sub(ap, ab), cp = l3_sub(ap, ac);
    const long d1 = l3_dot(ab, ap), d2 = l3_dot(ac, ap);
    if (d1 <= 0 && d2 <= 0) return (double)l3_dot(ap, ap);
    const long d3 = l3_dot(ab, bp), d4 = l3_dot(ac, bp);
    if (d3 >= 0 && d4 <= d3) return (double)l3_dot(bp, bp);
    const long vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return edge_d2(ab, ap);
    const long d5 = l3_dot(ab, cp), d6 = l3_dot(ac, cp);
    if (d6 >= 0 && d5 <= d6) return (double)l3_dot(cp, cp);
    const long vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return edge_d2(ac, ap);
    const long va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return edge_d2(l3_sub(ac, ab), bp);
    const l3 n = l3_cross(ab, ac);
    const long nn = l3_dot(n, n);
    if (nn <= 0) return (double)l3_dot(ap, ap);
    const double na = (double)l3_dot(n, ap);
    return na * na / (double)nn;
}

R_INLINE long code_of(long acc_s, long acc_c, double ks, double kc)
{
    const double cap = (double)R_CODE_CAP;
    double xs = (double)acc_s * ks, xc = (double)acc_c * kc;
    xs = xs < cap ? xs : cap;
    xc = xc < cap ? xc : cap;
    const long c = (long)xs + (long)xc;
    return c < R_CODE_CAP ? c : R_CODE_CAP;
}

// Range: (round_up(n_cand * rotations, 64), n_query), local (64, 1); work-item
// (r * n_cand + c, q): neighbouring work-items share the rotation, so they read the same
// query entries and neighbouring stencil entries.
__kernel void relief_scores(
    __global const int* base,       // (V * 3,) base positions, quanta
    __global const int* frame,      // (V * 9,) frame rows u, v, n, FRAME_ONE scale
    __global const int* pos,        // (V * 3,) full positions, quanta
    __global const int* colour,     // (V * 3,) RGB 0..255
    __global const int* usable,     // (V,) 0/1: may be a partner or closest-triangle corner
    __global const int* adj_start,  // (V + 1,) first neighbour of each vertex
    __global const int* adj,        // (A,) neighbour ids
    __global const int* fan_start,  // (V + 1,) first fan triangle of each vertex
    __global const int* fan,        // (F * 2,) other two corners of each fan triangle
    __global const int* samples,    // (S,) vertex id of each sample
    __global const int* stencil,    // (n_cells * S,) walk starts, cell-major
    __global const int* qstart,     // (Q + 1,) first entry of each query
    __global const int* rel,        // (E * R * 6,) moved-base and displacement coefficients
    __global const int* chain,      // (E,) 1: walk from the previous partner
    __global const int* cell,       // (E * R,) stencil cell of the walk's start, -1: none
    __global const int* qcolour,    // (E * 3,) entry colours 0..255
    __global const int* qweight,    // (E,) entry weights
    __global const double* ks,      // (Q,) shape coefficient of the code
    __global const double* kc,      // (Q,) colour coefficient of the code
    __global const long* limit,     // (Q,) running codes above it stop as OVER
    __global const int* cand,       // (n_cand,) or (Q * n_cand,) candidate sample slots, -1: none (OVER)
    const int n_cand,               // candidates (of each query)
    const int cand_stride,          // 0: one candidate list for every query; n_cand: a row per query
    const int n_query,              // queries
    const int rotations,            // R
    const int n_samples,            // S (the stencil's row length)
    __global uint* out)             // (Q * n_cand * R,) codes
{
    const int g = get_global_id(0), q = get_global_id(1);
    if (g >= n_cand * rotations || q >= n_query) return;
    const int r = g / n_cand, c = g - r * n_cand;
    const int slot = cand[(size_t)q * cand_stride + c];
    if (slot < 0) { out[((size_t)q * n_cand + c) * rotations + r] = (uint)R_OVER; return; }
    const int s = samples[slot];
    const l3 fu = l3_at(frame, 3 * s), fv = l3_at(frame, 3 * s + 1), fn = l3_at(frame, 3 * s + 2);
    const l3 bs = l3_at(base, s);
    const double ksq = ks[q], kcq = kc[q];
    const long lim = limit[q];
    long acc_s = 0, acc_c = 0, result = -1;
    int prev = s;
    const int j1 = qstart[q + 1];
    for (int j = qstart[q]; j < j1; ++j) {
        const __global int* o = rel + (size_t)(j * rotations + r) * 6;
        const l3 m = l3_add(bs, to_world(o[0], o[1], o[2], fu, fv, fn));
        const l3 p = l3_add(m, to_world(o[3], o[4], o[5], fu, fv, fn));
        const int k0 = cell[j * rotations + r];
        int cur = k0 >= 0 ? stencil[(size_t)k0 * n_samples + slot] : (chain[j] ? prev : s);
        const l3 dc = l3_sub(l3_at(base, cur), m);
        long bd = l3_dot(dc, dc);  // the current vertex's distance, carried between steps
        for (int steps = 0; steps < R_MAX_WALK; ++steps) {
            int best = cur;
            const int k1 = adj_start[cur + 1];
            for (int k = adj_start[cur]; k < k1; ++k) {
                const int u = adj[k];
                const l3 d = l3_sub(l3_at(base, u), m);
                const long du = l3_dot(d, d);
                if (du < bd || (du == bd && u < best)) { best = u; bd = du; }
            }
            if (best == cur) break;
            cur = best;
        }
        const int partner = cur;
        prev = partner;
        if (!usable[partner]) { result = R_INVALID; break; }
        const long w = qweight[j];
        const long e0 = qcolour[3 * j] - colour[3 * partner], e1 = qcolour[3 * j + 1] - colour[3 * partner + 1],
                   e2 = qcolour[3 * j + 2] - colour[3 * partner + 2];
        acc_c += w * (e0 * e0 + e1 * e1 + e2 * e2);
        if (code_of(acc_s, acc_c, ksq, kcq) > lim) { result = R_OVER; break; }
        const l3 pa = l3_at(pos, partner);
        const l3 dp = l3_sub(p, pa);
        const l3 ap = {clampl(dp.x), clampl(dp.y), clampl(dp.z)};
        double bestd = 0.0;
        int bestk = -1;
        const int f1 = fan_start[partner + 1];
        for (int k = fan_start[partner]; k < f1; ++k) {
            const double d = tri_d2(ap, l3_sub(l3_at(pos, fan[2 * k]), pa), l3_sub(l3_at(pos, fan[2 * k + 1]), pa));
            if (bestk < 0 || d < bestd) { bestd = d; bestk = k; }
        }
        if (bestk < 0 || !usable[fan[2 * bestk]] || !usable[fan[2 * bestk + 1]]) { result = R_INVALID; break; }
        acc_s += w * (long)bestd;
        if (code_of(acc_s, acc_c, ksq, kcq) > lim) { result = R_OVER; break; }
    }
    if (result < 0) result = code_of(acc_s, acc_c, ksq, kcq);
    out[((size_t)q * n_cand + c) * rotations + r] = (uint)result;
}

// Range: round_up(n, 64), local 64.
__kernel void relief_update(
    __global const int* ids,         // (n,) vertex ids
    __global const int* new_pos,     // (n * 3,) full positions, quanta
    __global const int* new_colour,  // (n * 3,) RGB 0..255
    const int n,                     // updates
    const int mark,                  // 1: the vertices become usable partners
    __global int* pos,               // (V * 3,) written
    __global int* colour,            // (V * 3,) written
    __global int* usable)            // (V,) written when mark
{
    const int i = get_global_id(0);
    if (i >= n) return;
    const int v = ids[i];
    for (int k = 0; k < 3; ++k) {
        pos[3 * v + k] = new_pos[3 * i + k];
        colour[3 * v + k] = new_colour[3 * i + k];
    }
    if (mark) usable[v] = 1;
}
