// M3's sequential orders, each in one work-item: the point parameterization's region
// growing (Zhang, Qiu and Kaufman, Sec. 3.2-3.3 and Appendix A: grow_patches), the texture
// mapping and gap blending (Sec. 3.4: blend_gaps) and the coherent neighbourhood matching
// of one level (Sec. 4: match_coherent). The twin of growth.py (same kernels, same
// arguments in the same order, float64 without contraction in the same order, exact
// integer scores); see there and geosynth/texturing/parameterize.py, geosynth/texturing/matching.py for the
// definitions.
#include "common.h"

#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#pragma OPENCL FP_CONTRACT OFF

#define G_FREE 0
#define G_PATCH 1
#define G_GAP 2
#define PARALLEL_LIMIT (1.0 - 1e-9)
#define TINY 1e-300
// PoCL does not inline helpers that write through pointers on its own (measured: the
// growth ran 1.3x slower with appendix_a called)
#define GS_INLINE __attribute__((always_inline)) inline

// Builtins through clang's own (PoCL calls its OpenCL builtins instead of inlining them,
// see common.h); the same IEEE results: sqrt is correctly rounded, and no value here is NaN.
#define SQRT(x) __builtin_sqrt(x)
#define FMAX(a, b) __builtin_fmax(a, b)
#define FMIN(a, b) __builtin_fmin(a, b)
#define FABS(x) __builtin_fabs(x)
#define FLOOR(x) __builtin_floor(x)

typedef struct { double x, y, z; } d3;

GS_INLINE d3 d3_at(__global const double* a, int i) { d3 r = {a[3 * i], a[3 * i + 1], a[3 * i + 2]}; return r; }
GS_INLINE void d3_put(__global double* a, int i, d3 v) { a[3 * i] = v.x; a[3 * i + 1] = v.y; a[3 * i + 2] = v.z; }
GS_INLINE double d3_dot(d3 a, d3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
GS_INLINE d3 d3_cross(d3 a, d3 b)
{
    d3 r = {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
    return r;
}
GS_INLINE d3 d3_scale(d3 a, double s) { d3 r = {a.x * s, a.y * s, a.z * s}; return r; }
GS_INLINE d3 d3_div(d3 a, double s) { const double r = 1.0 / s; d3 q = {a.x * r, a.y * r, a.z * r}; return q; }  // one division

// Appendix A: F (at pf) seen from patch point P (at pp, patch position (pu, pv), frame
// pn, ps, pt): F's patch position (*qu, *qv) in texels, normal *nn, axes *tt, *ss and
// the distance |F - P|. Returns 0 where F coincides with P or lies along P's normal.
GS_INLINE int appendix_a(d3 pf, d3 pp, double pu, double pv, d3 pn, d3 ps, d3 pt, double unit, double* qu,
                      double* qv, d3* nn, d3* tt, d3* ss, double* dist)
{
    const d3 v = {pf.x - pp.x, pf.y - pp.y, pf.z - pp.z};
    const double d = SQRT(d3_dot(v, v));
    *dist = d;
    const d3 v0 = d3_div(v, FMAX(d, TINY));
    const double along = d3_dot(v0, pn);
    if (!(d > 0.0 && FABS(along) < PARALLEL_LIMIT)) return 0;
    const double a = d3_dot(v, ps), b = d3_dot(v, pt);
    const double plane = SQRT(a * a + b * b);
    const double scale = d / FMAX(plane, TINY) / unit;
    *qu = pu + a * scale;
    *qv = pv + b * scale;
    d3 m = {pn.x - along * v0.x, pn.y - along * v0.y, pn.z - along * v0.z};
    m = d3_div(m, FMAX(SQRT(d3_dot(m, m)), TINY));
    const double vt = d3_dot(v0, pt), vs = d3_dot(v0, ps);
    const d3 c = d3_cross(m, v0);
    const d3 t = {vt * v0.x + vs * c.x, vt * v0.y + vs * c.y, vt * v0.z + vs * c.z};
    *nn = m;
    *tt = t;
    *ss = d3_cross(t, m);
    return 1;
}

// The frame of weighted sums sn (normals) and st (T axes): N = sn normalized, T = st
// minus its N part, normalized, S = T x N.
GS_INLINE void average_frame(d3 sn, d3 st, d3* n_f, d3* s_f, d3* t_f)
{
    const d3 n = d3_div(sn, FMAX(SQRT(d3_dot(sn, sn)), TINY));
    const double tn = d3_dot(st, n);
    d3 t = {st.x - tn * n.x, st.y - tn * n.y, st.z - tn * n.z};
    t = d3_div(t, FMAX(SQRT(d3_dot(t, t)), TINY));
    *n_f = n;
    *t_f = t;
    *s_f = d3_cross(t, n);
}

// The frame a patch seeded at a point of unit normal n starts with, from the direction
// u (normalized here): T = u minus its n part (where that is shorter than 1e-3, the x
// axis, or y when u is near x, instead), normalized; S = T x N.
GS_INLINE void seed_frame(d3 n, d3 u, d3* s_f, d3* t_f)
{
    u = d3_div(u, SQRT(d3_dot(u, u)));
    const double un = d3_dot(u, n);
    d3 t = {u.x - un * n.x, u.y - un * n.y, u.z - un * n.z};
    if (SQRT(d3_dot(t, t)) < 1e-3) {
        const d3 alt = {FABS(u.x) < 0.9 ? 1.0 : 0.0, FABS(u.x) < 0.9 ? 0.0 : 1.0, 0.0};
        const double an = d3_dot(alt, n);
        t.x = alt.x - an * n.x; t.y = alt.y - an * n.y; t.z = alt.z - an * n.z;
    }
    const double tn = d3_dot(t, n);
    t.x -= tn * n.x; t.y -= tn * n.y; t.z -= tn * n.z;
    t = d3_div(t, FMAX(SQRT(d3_dot(t, t)), TINY));
    *t_f = t;
    *s_f = d3_cross(t, n);
}

// Priority queue of frontier points: one FIFO list per priority min(key, n_buckets - 1)
// (key: patch points that have the point among their k neighbours), linked through
// next/prev (-1 ends a list); a point is in at most one list (slot[i]: its bucket, -1
// when in none). The next candidate is the head of the highest non-empty list.
GS_INLINE void queue_unlink(__global int* next, __global int* prev, __global int* slot, __global int* head,
                         __global int* tail, int i)
{
    const int b = slot[i], p = prev[i], q = next[i];
    if (p >= 0) next[p] = q; else head[b] = q;
    if (q >= 0) prev[q] = p; else tail[b] = p;
    slot[i] = -1;
}

GS_INLINE void queue_append(__global int* next, __global int* prev, __global int* slot, __global int* head,
                         __global int* tail, int i, int b)
{
    const int t = tail[b];
    prev[i] = t; next[i] = -1;
    if (t >= 0) next[t] = i; else head[b] = i;
    tail[b] = i;
    slot[i] = b;
}

// The first point of the highest non-empty list, taken out (-1 when all are empty);
// *top follows the highest non-empty list down.
GS_INLINE int queue_pop(__global int* next, __global int* prev, __global int* slot, __global int* head,
                        __global int* tail, int* top)
{
    while (*top > 0 && head[*top] < 0) --*top;
    if (*top == 0) return -1;
    const int f = head[*top];
    queue_unlink(next, prev, slot, head, tail, f);
    return f;
}

// key[q] + 1, and q to the end of its new priority's list; returns the new top priority.
GS_INLINE int queue_raise(__global int* key, __global int* next, __global int* prev, __global int* slot,
                          __global int* head, __global int* tail, int n_buckets, int q, int top)
{
    key[q] += 1;
    const int b = min(key[q], n_buckets - 1);
    if (slot[q] == b) return top;
    if (slot[q] >= 0) queue_unlink(next, prev, slot, head, tail, q);
    queue_append(next, prev, slot, head, tail, q, b);
    return max(top, b);
}

// The queue of the uncoloured points, in index order: key = the coloured points that have
// the point among their k neighbours; returns the top priority (0: empty).
GS_INLINE int queue_from_coloured(int n, int k, __global const int* nb, __global const int* coloured,
                                  __global int* key, __global int* next, __global int* prev, __global int* slot,
                                  __global int* head, __global int* tail, int n_buckets)
{
    for (int i = 0; i < n; ++i) { key[i] = 0; slot[i] = -1; }
    for (int b = 0; b < n_buckets; ++b) { head[b] = -1; tail[b] = -1; }
    for (int i = 0; i < n; ++i)
        if (coloured[i])
            for (int j = 0; j < k; ++j) key[nb[i * k + j]] += 1;
    int top = 0;
    for (int i = 0; i < n; ++i)
        if (!coloured[i] && key[i] > 0) {
            const int b = min(key[i], n_buckets - 1);
            queue_append(next, prev, slot, head, tail, i, b);
            top = max(top, b);
        }
    return top;
}

// One work-item (range (1,), local (1,)) grows every patch.
// Inputs: n points, k neighbours each (nb: n*k int, self excluded); pos, nrm: n*3 double
// (unit normals); order: n int, the seed order; dirs: the seed frames' directions (see
// seed_frame), dir_step 0: one (3 double) for every point, 1: one per point (n*3); unit: world length of a texel; w1..w4, threshold: eqs. 2-4; max_patch: the
// largest patch extent in texels, <= 0 for unbounded; n_buckets: priority levels.
// Outputs: state, patch (n int); uv (n*2), fn, fs, ft (n*3), distortion (n) double;
// seeds (n int, the first counts[0] used); counts: (1,) int: patches.
// Scratch: key, slot, next, prev, touched (n int), head, tail (n_buckets int), terms (k * 12 double).
__kernel void grow_patches(const int n, const int k, __global const double* pos, __global const double* nrm,
                           __global const int* nb, __global const int* order, __global const double* dirs,
                           const int dir_step, const double unit, const double w1, const double w2,
                           const double w3, const double w4, const double threshold, const double max_patch,
                           const int n_buckets, __global int* state, __global int* patch, __global double* uv,
                           __global double* fn, __global double* fs, __global double* ft,
                           __global double* distortion, __global int* seeds, __global int* counts,
                           __global int* key, __global int* slot, __global int* next, __global int* prev,
                           __global int* touched, __global int* head, __global int* tail, __global double* terms)
{
    if (get_global_id(0) != 0) return;
    const double nan_value = NAN;
    for (int i = 0; i < n; ++i) {
        state[i] = G_FREE; patch[i] = -1; key[i] = 0; slot[i] = -1;
        uv[2 * i] = nan_value; uv[2 * i + 1] = nan_value; distortion[i] = nan_value;
        for (int c = 0; c < 3; ++c) { fn[3 * i + c] = nan_value; fs[3 * i + c] = nan_value; ft[3 * i + c] = nan_value; }
    }
    for (int b = 0; b < n_buckets; ++b) { head[b] = -1; tail[b] = -1; }
    int n_patches = 0, next_seed = 0;
    while (1) {
        while (next_seed < n && state[order[next_seed]] != G_FREE) ++next_seed;
        if (next_seed == n) break;
        const int sd = order[next_seed];
        const int pid = n_patches++;
        seeds[pid] = sd;
        state[sd] = G_PATCH; patch[sd] = pid;
        uv[2 * sd] = 0.0; uv[2 * sd + 1] = 0.0; distortion[sd] = 0.0;
        d3 s0, t0;
        seed_frame(d3_at(nrm, sd), d3_at(dirs, dir_step * sd), &s0, &t0);
        d3_put(fn, sd, d3_at(nrm, sd)); d3_put(fs, sd, s0); d3_put(ft, sd, t0);
        double lo_x = 0.0, lo_y = 0.0, hi_x = 0.0, hi_y = 0.0;
        int n_touched = 0, top = 0;
        int joined = sd;  // the point whose free neighbours get +1 next
        while (1) {
            if (joined >= 0) {
                for (int j = 0; j < k; ++j) {
                    const int q = nb[joined * k + j];
                    if (state[q] != G_FREE) continue;
                    if (key[q] == 0) touched[n_touched++] = q;
                    top = queue_raise(key, next, prev, slot, head, tail, n_buckets, q, top);
                }
                joined = -1;
            }
            const int f = queue_pop(next, prev, slot, head, tail, &top);  // highest priority, first in
            if (f < 0) break;
            // Appendix A from every usable patch neighbour P
            const d3 pf = d3_at(pos, f), nf = d3_at(nrm, f);
            int used = 0;
            double wsum = 0.0, su = 0.0, sv = 0.0;
            d3 sn = {0.0, 0.0, 0.0}, st = {0.0, 0.0, 0.0};
            for (int j = 0; j < k; ++j) {
                const int l = nb[f * k + j];
                if (patch[l] != pid) continue;  // (only patch points have a patch)
                const d3 pn = d3_at(fn, l);
                if (!(d3_dot(d3_at(nrm, l), nf) > 0.0)) continue;
                double lu, lv, dist;
                d3 nn, tt, ss;
                if (!appendix_a(pf, d3_at(pos, l), uv[2 * l], uv[2 * l + 1], pn, d3_at(fs, l), d3_at(ft, l), unit,
                                &lu, &lv, &nn, &tt, &ss, &dist)) continue;
                const double w = unit / FMAX(dist, TINY);
                __global double* term = terms + 12 * used;
                term[0] = w; term[1] = lu; term[2] = lv;
                term[3] = ss.x; term[4] = ss.y; term[5] = ss.z; term[6] = tt.x; term[7] = tt.y; term[8] = tt.z;
                wsum += w; su += w * lu; sv += w * lv;
                sn.x += w * nn.x; sn.y += w * nn.y; sn.z += w * nn.z;
                st.x += w * tt.x; st.y += w * tt.y; st.z += w * tt.z;
                ++used;
            }
            if (used == 0) continue;  // no usable neighbour: F stays free for a later patch
            // weighted averages, re-orthonormalized frame, distortion (eqs. 2-4)
            const double inv = 1.0 / wsum;
            const double qu = su * inv, qv = sv * inv;
            d3 n_f, s_f, t_f;
            average_frame(sn, st, &n_f, &s_f, &t_f);
            double pos_sum = 0.0, pos_max = 0.0, ori_sum = 0.0, ori_max = 0.0;
            for (int j = 0; j < used; ++j) {
                __global const double* term = terms + 12 * j;
                const double w = term[0], du = term[1] - qu, dv = term[2] - qv;
                const double dp = w * SQRT(du * du + dv * dv);
                const d3 ss = {term[3], term[4], term[5]}, tt = {term[6], term[7], term[8]};
                const double dor = w * (2.0 - d3_dot(ss, s_f) - d3_dot(tt, t_f));
                pos_sum += dp; ori_sum += dor;
                pos_max = FMAX(pos_max, dp); ori_max = FMAX(ori_max, dor);
            }
            const double d_pos = w1 * pos_sum * inv + pos_max;
            const double d_ori = w2 * ori_sum * inv + ori_max;
            const double d = w3 * d_ori + w4 * d_pos;
            distortion[f] = d;
            int accept = d <= threshold;
            if (accept && max_patch > 0.0) {  // the patch's bounding box may not outgrow max_patch
                const double nlx = FMIN(lo_x, qu), nly = FMIN(lo_y, qv), nhx = FMAX(hi_x, qu), nhy = FMAX(hi_y, qv);
                if (FMAX(nhx - nlx, nhy - nly) > max_patch) accept = 0;
                else { lo_x = nlx; lo_y = nly; hi_x = nhx; hi_y = nhy; }
            }
            if (!accept) { state[f] = G_GAP; continue; }
            state[f] = G_PATCH; patch[f] = pid;
            uv[2 * f] = qu; uv[2 * f + 1] = qv;
            d3_put(fn, f, n_f); d3_put(fs, f, s_f); d3_put(ft, f, t_f);
            joined = f;
        }
        for (int i = 0; i < n_touched; ++i) key[touched[i]] = 0;  // keys count the current patch only
    }
    counts[0] = n_patches;
}

// i modulo size, in [0, size).
GS_INLINE long wrap_index(long i, long size)
{
    const long r = i % size;
    return r < 0 ? r + size : r;
}

// Bilinear texture lookup at texel coordinates (x, y) (texel centres at integers), as
// geosynth.texturing.textures.sample_bilinear: wrapped (wrap != 0) or clamped to the edge.
GS_INLINE void bilinear(__global const uchar* tex, int h, int w, int wrap, double x, double y, double* out)
{
    if (!wrap) { y = FMIN(FMAX(y, 0.0), (double)(h - 1)); x = FMIN(FMAX(x, 0.0), (double)(w - 1)); }
    const double yf = FLOOR(y), xf = FLOOR(x);
    const double fy = y - yf, fx = x - xf;
    long y0 = (long)yf, x0 = (long)xf, y1, x1;
    if (wrap) {
        y0 = wrap_index(y0, h);
        x0 = wrap_index(x0, w);
        y1 = (y0 + 1) % h; x1 = (x0 + 1) % w;
    } else {
        y1 = min(y0 + 1, (long)(h - 1)); x1 = min(x0 + 1, (long)(w - 1));
    }
    for (int c = 0; c < 3; ++c) {
        const double t00 = tex[(y0 * w + x0) * 3 + c], t01 = tex[(y0 * w + x1) * 3 + c];
        const double t10 = tex[(y1 * w + x0) * 3 + c], t11 = tex[(y1 * w + x1) * 3 + c];
        const double top = t00 * (1.0 - fx) + t01 * fx;
        const double bottom = t10 * (1.0 - fx) + t11 * fx;
        out[c] = top * (1.0 - fy) + bottom * fy;
    }
}


// One work-item colours the patch points (the texture at their patch position plus their
// patch's offset) and then the gap points, most coloured neighbours first (the same FIFO
// bucket queue as grow_patches, key = coloured points that have the point among their k
// neighbours): the 1/distance-weighted blend of the colours that the usable coloured
// neighbours' patches map it to (Appendix A from each; usable: in a patch, n_P . n_F > 0);
// it then joins the patch of the largest total weight (lowest index on ties) with the
// weighted position and frame that patch's neighbours give it. With coloured neighbours
// but none usable it takes their plain mean colour and joins no patch; with no coloured
// neighbour of its own it waits (and stays uncoloured if none comes).
// In: state (n int), tex (h*w*3 uchar), offsets (patches*2 double: x, y). In/out: patch
// (n int), uv (n*2), fn, fs, ft (n*3 double). Out: colours (n*3 double), coloured (n int).
// Scratch: key, slot, next, prev (n int), head, tail (n_buckets int), terms (k * 16 double).
__kernel void blend_gaps(const int n, const int k, __global const double* pos, __global const double* nrm,
                         __global const int* nb, __global const int* state, const double unit,
                         __global const uchar* tex, const int h, const int w, const int wrap,
                         __global const double* offsets, const int n_buckets, __global int* patch,
                         __global double* uv, __global double* fn, __global double* fs, __global double* ft,
                         __global double* colours, __global int* coloured, __global int* key, __global int* slot,
                         __global int* next, __global int* prev, __global int* head, __global int* tail,
                         __global double* terms)
{
    if (get_global_id(0) != 0) return;
    double col[3];
    for (int i = 0; i < n; ++i) {
        coloured[i] = state[i] == G_PATCH;
        col[0] = 0.0; col[1] = 0.0; col[2] = 0.0;
        if (coloured[i]) {
            const int p = patch[i];
            bilinear(tex, h, w, wrap, uv[2 * i] + offsets[2 * p], uv[2 * i + 1] + offsets[2 * p + 1], col);
        }
        for (int c = 0; c < 3; ++c) colours[3 * i + c] = col[c];
    }
    int top = queue_from_coloured(n, k, nb, coloured, key, next, prev, slot, head, tail, n_buckets);
    while (1) {
        const int f = queue_pop(next, prev, slot, head, tail, &top);
        if (f < 0) break;
        const d3 pf = d3_at(pos, f), nf = d3_at(nrm, f);
        int used = 0, n_coloured = 0;
        double wsum = 0.0, plain[3] = {0.0, 0.0, 0.0}, blend[3] = {0.0, 0.0, 0.0};
        for (int j = 0; j < k; ++j) {
            const int l = nb[f * k + j];
            if (!coloured[l]) continue;
            ++n_coloured;
            for (int c = 0; c < 3; ++c) plain[c] += colours[3 * l + c];
            const int pl = patch[l];
            if (pl < 0 || !(d3_dot(d3_at(nrm, l), nf) > 0.0)) continue;
            double lu, lv, dist;
            d3 nn, tt, ss;
            if (!appendix_a(pf, d3_at(pos, l), uv[2 * l], uv[2 * l + 1], d3_at(fn, l), d3_at(fs, l), d3_at(ft, l),
                            unit, &lu, &lv, &nn, &tt, &ss, &dist)) continue;
            const double wl = 1.0 / FMAX(dist, TINY);
            bilinear(tex, h, w, wrap, lu + offsets[2 * pl], lv + offsets[2 * pl + 1], col);
            __global double* term = terms + 16 * used;
            term[0] = wl; term[1] = (double)pl; term[2] = lu; term[3] = lv;
            term[4] = nn.x; term[5] = nn.y; term[6] = nn.z; term[7] = tt.x; term[8] = tt.y; term[9] = tt.z;
            wsum += wl;
            for (int c = 0; c < 3; ++c) blend[c] += wl * col[c];
            ++used;
        }
        if (n_coloured == 0) continue;  // waits for a coloured neighbour
        coloured[f] = 1;
        if (used == 0) {
            for (int c = 0; c < 3; ++c) colours[3 * f + c] = plain[c] / (double)n_coloured;
        } else {
            for (int c = 0; c < 3; ++c) colours[3 * f + c] = blend[c] / wsum;
            // the patch with the largest total weight, the lowest index on ties
            int best = -1;
            double best_total = 0.0;
            for (int j = 0; j < used; ++j) {
                const int pj = (int)terms[16 * j + 1];
                double total = 0.0;
                for (int i = 0; i < used; ++i)
                    if ((int)terms[16 * i + 1] == pj) total += terms[16 * i];
                if (best < 0 || total > best_total || (total == best_total && pj < best)) { best = pj; best_total = total; }
            }
            double su = 0.0, sv = 0.0, sw = 0.0;
            d3 sn = {0.0, 0.0, 0.0}, st = {0.0, 0.0, 0.0};
            for (int j = 0; j < used; ++j) {
                __global const double* term = terms + 16 * j;
                if ((int)term[1] != best) continue;
                const double wl = term[0];
                sw += wl; su += wl * term[2]; sv += wl * term[3];
                sn.x += wl * term[4]; sn.y += wl * term[5]; sn.z += wl * term[6];
                st.x += wl * term[7]; st.y += wl * term[8]; st.z += wl * term[9];
            }
            d3 n_f, s_f, t_f;
            average_frame(sn, st, &n_f, &s_f, &t_f);
            patch[f] = best;
            uv[2 * f] = su / sw; uv[2 * f + 1] = sv / sw;
            d3_put(fn, f, n_f); d3_put(fs, f, s_f); d3_put(ft, f, t_f);
        }
        for (int j = 0; j < k; ++j) {  // its uncoloured neighbours: one coloured point more
            const int q = nb[f * k + j];
            if (!coloured[q]) top = queue_raise(key, next, prev, slot, head, tail, n_buckets, q, top);
        }
    }
}

// Eq. 5 of one candidate texel t = (ty, tx): the squared differences of the entries'
// colours against the supersampled pixels at their offsets from t's centre pixel. The sum
// stops once it exceeds bound (then only "more than bound" is meaningful).
GS_INLINE uint window_error(__global const uchar* grid, int centre, __global const int* rel,
                            __global const uchar* vals, int count, uint bound)
{
    uint err = 0;
    for (int e = 0; e < count && err <= bound; ++e) {
        __global const uchar* px = grid + 3 * (centre + rel[e]);
        for (int c = 0; c < 3; ++c) {
            const int d = (int)px[c] - (int)vals[3 * e + c];
            err += (uint)(d * d);
        }
    }
    return err;
}

// Coherent neighbourhood matching of one level (paper Sec. 4; no coarser level), one
// work-item, the points in the paper's sequential order: most coloured neighbours first
// (the FIFO bucket queue of grow_patches; key = coloured points that have the point among
// their k neighbours); with none queued, the next uncoloured point of `order` takes the
// random texel rand_texel[i]. A point's entries are its coloured neighbours at their
// tangent-plane offsets (Appendix A from the point, in texels x along S and y along T;
// the plain projection where Appendix A fails), as supersampled pixel offsets
// (rint(m * y), rint(m * x)) clipped to [-pad, pad]. Each entry j suggests the texel
// source_j - rint(offset_j / m) (wrapped when tileable, else dropped outside); the
// suggestion of least eq. 5 error wins (lowest texel on ties); with none, every texel is
// searched. Sub-texel refinement (subtexel != 0): the supersampled pixel around the
// texel, first over shifts1 (n_shift1 (dy, dx), in order), then (ring != 0) over the 3 x 3
// ring around the best (clipped to [-m/2, m - m/2 - 1]), first minimum winning, gives the
// colour; else the texel's own colour (grid pixel at its centre).
// grid: (rows, xp, 3) uchar, the padded supersampled texture (texel (ty, tx) centred at
// pixel (pad + m ty, pad + m tx)). In/out: coloured (n int), colours (n*3 uchar), source
// (n int). Scratch: key, slot, next, prev (n int), head, tail (n_buckets int), rel (k int),
// vals (k*3 uchar), cand (k int). Pixel indices are int: grids below 2^31 / 3 bytes.
__kernel void match_coherent(const int n, const int k, __global const double* pos, __global const double* nrm,
                             __global const double* s_axis, __global const double* t_axis, __global const int* nb,
                             const double unit, __global const uchar* grid, const int xp, const int pad,
                             const int m, const int h, const int w, const int tileable, const int subtexel,
                             __global const int* shifts1, const int n_shift1, const int ring, __global const int* order,
                             __global const int* rand_texel, const int n_buckets, __global int* coloured,
                             __global uchar* colours, __global int* source, __global int* key, __global int* slot,
                             __global int* next, __global int* prev, __global int* head, __global int* tail,
                             __global int* rel, __global uchar* vals, __global int* cand)
{
    if (get_global_id(0) != 0) return;
    int top = queue_from_coloured(n, k, nb, coloured, key, next, prev, slot, head, tail, n_buckets);
    const int half_m = m / 2;
    int next_order = 0;
    while (1) {
        int f = queue_pop(next, prev, slot, head, tail, &top);
        if (f < 0) {
            while (next_order < n && coloured[order[next_order]]) ++next_order;
            if (next_order == n) break;
            f = order[next_order];
        }
        const d3 pf = d3_at(pos, f), nf = d3_at(nrm, f), sf = d3_at(s_axis, f), tf = d3_at(t_axis, f);
        int count = 0, n_cand = 0;
        for (int j = 0; j < k; ++j) {
            const int l = nb[f * k + j];
            if (!coloured[l]) continue;
            const d3 pl = d3_at(pos, l);
            const d3 v = {pl.x - pf.x, pl.y - pf.y, pl.z - pf.z};
            const double dist = SQRT(d3_dot(v, v));
            const d3 v0 = d3_div(v, FMAX(dist, TINY));
            const double along = d3_dot(v0, nf);
            const double a = d3_dot(v, sf), b = d3_dot(v, tf);
            double ox, oy;
            if (dist > 0.0 && FABS(along) < PARALLEL_LIMIT) {
                const double scale = dist / FMAX(SQRT(a * a + b * b), TINY) / unit;
                ox = a * scale; oy = b * scale;
            } else {
                ox = a / unit; oy = b / unit;
            }
            const int dy = (int)__builtin_rint(oy * m), dx = (int)__builtin_rint(ox * m);
            rel[count] = min(max(dy, -pad), pad) * xp + min(max(dx, -pad), pad);
            for (int c = 0; c < 3; ++c) vals[3 * count + c] = colours[3 * l + c];
            ++count;
            const int src = source[l];
            if (src < 0) continue;
            int cy = src / w - (int)__builtin_rint((double)dy / m), cx = src % w - (int)__builtin_rint((double)dx / m);
            if (tileable) {
                cy = (int)wrap_index(cy, h);
                cx = (int)wrap_index(cx, w);
            } else if (cy < 0 || cy >= h || cx < 0 || cx >= w) {
                continue;
            }
            const int t = cy * w + cx;
            int seen = 0;  // neighbours that agree suggest the same texel: score it once
            for (int i = 0; i < n_cand && !seen; ++i) seen = cand[i] == t;
            if (!seen) cand[n_cand++] = t;
        }
        int texel;
        if (count == 0) {
            texel = rand_texel[f];
            const int centre = (pad + m * (texel / w)) * xp + pad + m * (texel % w);
            for (int c = 0; c < 3; ++c) colours[3 * f + c] = grid[3 * centre + c];
        } else {
            uint best = 0xffffffffu;
            texel = -1;
            const int n_search = n_cand > 0 ? n_cand : h * w;  // no suggestion: every texel
            for (int i = 0; i < n_search; ++i) {
                const int t = n_cand > 0 ? cand[i] : i;
                const int centre = (pad + m * (t / w)) * xp + pad + m * (t % w);
                const uint err = window_error(grid, centre, rel, vals, count, best);
                if (err < best || (err == best && t < texel)) { best = err; texel = t; }
            }
            const int cy = pad + m * (texel / w), cx = pad + m * (texel % w);
            int by = 0, bx = 0;
            if (subtexel) {
                // the texel centre comes first when it is a shift: its error is the search's
                int first = 0;
                if (shifts1[0] == 0 && shifts1[1] == 0) first = 1;
                else best = 0xffffffffu;
                for (int i = first; i < n_shift1; ++i) {
                    const int sy = shifts1[2 * i], sx = shifts1[2 * i + 1];
                    const uint err = window_error(grid, (cy + sy) * xp + cx + sx, rel, vals, count, best);
                    if (err < best) { best = err; by = sy; bx = sx; }
                }
                if (ring) {
                    const int oy = by, ox = bx;  // best is its error: the ring's (0, 0)
                    for (int r = 1; r < 9; ++r) {  // (0, 0) first (done), then row by row
                        const int q = r <= 4 ? r - 1 : r;  // ring cell 3 (dy + 1) + (dx + 1); 4 is done
                        const int sy = min(max(oy + q / 3 - 1, -half_m), m - half_m - 1);
                        const int sx = min(max(ox + q % 3 - 1, -half_m), m - half_m - 1);
                        const uint err = window_error(grid, (cy + sy) * xp + cx + sx, rel, vals, count, best);
                        if (err < best) { best = err; by = sy; bx = sx; }
                    }
                }
            }
            const int px = (cy + by) * xp + cx + bx;
            for (int c = 0; c < 3; ++c) colours[3 * f + c] = grid[3 * px + c];
        }
        source[f] = texel;
        coloured[f] = 1;
        for (int j = 0; j < k; ++j) {
            const int q = nb[f * k + j];
            if (!coloured[q]) top = queue_raise(key, next, prev, slot, head, tail, n_buckets, q, top);
        }
    }
}
