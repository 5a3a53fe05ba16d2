// Candidate SSD scoring and score selection: OpenCL kernels.
//
// The twin of ssd.py. Each kernel there has its meaning here, with the same arguments
// in the same order; where several OpenCL kernels compute one Warp kernel's result
// (ssd_dense_rows and ssd_dense_tile <-> ssd_dense_kernel; ssd_gather and
// ssd_gather_x16 <-> ssd_gather_kernel), they differ only in how work is split, which
// the backend picks by shape. Arrays are flat; sizes are explicit. Types come from
// common.h (GS_U8 or float). Register tiles are unrolled with the REP macros: PoCL keeps
// scalar-named accumulators in registers but spills loop-indexed private arrays.
#include "common.h"

// ---------------------------------------------------------------------------------
// Dense: out[q, i] = sum_k w[k] * (candidates[i, k] - queries[q, k])^2

// DENSE_ROWS candidate rows per work-item, rows g, g+m, ..., g+(DENSE_ROWS-1)m
// (m = ceil(n/DENSE_ROWS)): several memory streams per work-item keep the prefetchers
// busy; one query at a time. float builds use 2 rows (measured on PoCL: 8 rows of
// float16 lanes read 35-60 GB/s, 2 rows 57-75 GB/s), uchar builds 8.
// Range: round_up(ceil(n/DENSE_ROWS), local), local 16 or 32 (the backend's choice);
// DENSE_ROWS (2, 4 or 8) is a build option the backend sets.
#ifndef DENSE_ROWS
#error "DENSE_ROWS must be defined by the build options"
#endif
#if DENSE_ROWS == 2
#define REP_ROWS REP2
#elif DENSE_ROWS == 4
#define REP_ROWS REP4
#else
#define REP_ROWS REP8
#endif
__kernel void ssd_dense_rows(__global const T* candidates, __global const T* queries,
                             __global const W* weights, const int use_weights,
                             const int n, const int d, const int b, __global S* out)
{
    const int g = get_global_id(0);
    const int m = (n + DENSE_ROWS - 1) / DENSE_ROWS;
    if (g >= m) return;
#define ROW_PTR(r) const int row##r = g + r * m; \
    const __global T* x##r = candidates + (size_t)(row##r < n ? row##r : n - 1) * d;
    REP_ROWS(ROW_PTR)
    const int d16 = d & ~15;
    for (int qi = 0; qi < b; ++qi) {
        const __global T* q = queries + (size_t)qi * d;
#define ROW_INIT(r) S16 acc##r = (S16)(0); S tail##r = 0;
        REP_ROWS(ROW_INIT)
        if (use_weights) {
            for (int k = 0; k < d16; k += 16) {
                const S16 w = LOADW16(weights + k);
                const E16 qv = LOAD16(q + k);
#define ROW_STEP_W(r) { const E16 e = LOAD16(x##r + k) - qv; acc##r += w * SQ16(e); }
                REP_ROWS(ROW_STEP_W)
            }
            for (int k = d16; k < d; ++k) {
                const W wk = weights[k];
#define ROW_TAIL_W(r) tail##r += wk * SQ1(x##r[k], q[k]);
                REP_ROWS(ROW_TAIL_W)
            }
        } else {
            for (int k = 0; k < d16; k += 16) {
                const E16 qv = LOAD16(q + k);
#define ROW_STEP(r) { const E16 e = LOAD16(x##r + k) - qv; acc##r += SQ16(e); }
                REP_ROWS(ROW_STEP)
            }
            for (int k = d16; k < d; ++k) {
#define ROW_TAIL(r) tail##r += SQ1(x##r[k], q[k]);
                REP_ROWS(ROW_TAIL)
            }
        }
#define ROW_STORE(r) if (row##r < n) out[(size_t)qi * n + row##r] = hsum16(acc##r) + tail##r;
        REP_ROWS(ROW_STORE)
    }
}

// A register tile of 4 consecutive candidate rows x 6 queries per work-item: each
// 16-wide chunk of a row is loaded once for 6 queries (24 accumulators), which makes
// batches compute-bound instead of load-bound. Past the last row or query the tile
// repeats it and does not store. Unweighted sums run in float lanes (exact for uchar,
// see below); weighted uchar sums stay in integers. Range: round_up(ceil(n/4), 16),
// local 16.
__kernel void ssd_dense_tile(__global const T* candidates, __global const T* queries,
                             __global const W* weights, const int use_weights,
                             const int n, const int d, const int b, __global S* out)
{
    const int g = get_global_id(0);
    if (g * 4 >= n) return;
#define TILE_ROW_PTR(r) const int row##r = g * 4 + r; \
    const __global T* x##r = candidates + (size_t)(row##r < n ? row##r : n - 1) * d;
    REP4(TILE_ROW_PTR)
    const int d16 = d & ~15;
    for (int qb = 0; qb < b; qb += 6) {
#define TILE_Q_PTR(t) const __global T* q##t = queries + (size_t)(qb + t < b ? qb + t : b - 1) * d;
        REP6(TILE_Q_PTR)
#define TILE_INIT1(r, t) S16 acc##r##_##t = (S16)(0); S tail##r##_##t = 0;
#define TILE_INIT(r) REP6_R(TILE_INIT1, r)
        REP4(TILE_INIT)
        if (use_weights) {
            for (int k = 0; k < d16; k += 16) {
                const S16 w = LOADW16(weights + k);
#define TILE_QLOAD(t) const E16 qv##t = LOAD16(q##t + k);
                REP6(TILE_QLOAD)
#define TILE_STEP_W1(r, t) { const E16 e = xv - qv##t; acc##r##_##t += w * SQ16(e); }
#define TILE_STEP_W(r) { const E16 xv = LOAD16(x##r + k); REP6_R(TILE_STEP_W1, r) }
                REP4(TILE_STEP_W)
            }
            for (int k = d16; k < d; ++k) {
                const W wk = weights[k];
#define TILE_TAIL_W1(r, t) tail##r##_##t += wk * SQ1(x##r[k], q##t[k]);
#define TILE_TAIL_W(r) REP6_R(TILE_TAIL_W1, r)
                REP4(TILE_TAIL_W)
            }
        } else {
            // Float lanes, flushed into the scalar sums every 256 chunks: for uchar data a
            // lane then sums at most 256 squares (256 * 255^2 < 2^24), so float is exact
            // (and lanes are summed as integers), and its multiply-add is much faster here
            // than 32-bit integer multiplies. Scalar sums keep the registers for the tile.
            for (int k0 = 0; k0 < d16; k0 += 16 * 256) {
                const int k1 = MIN_INT(k0 + 16 * 256, d16);
#define TILE_F_INIT1(r, t) float16 facc##r##_##t = (float16)(0);
#define TILE_F_INIT(r) REP6_R(TILE_F_INIT1, r)
                REP4(TILE_F_INIT)
                for (int k = k0; k < k1; k += 16) {
#define TILE_FQLOAD(t) const float16 qv##t = LOADF16(q##t + k);
                    REP6(TILE_FQLOAD)
#define TILE_FSTEP1(r, t) { const float16 e = xv - qv##t; facc##r##_##t += e * e; }
#define TILE_FSTEP(r) { const float16 xv = LOADF16(x##r + k); REP6_R(TILE_FSTEP1, r) }
                    REP4(TILE_FSTEP)
                }
#define TILE_FLUSH1(r, t) tail##r##_##t += hsum16(F16_TO_S16(facc##r##_##t));
#define TILE_FLUSH(r) REP6_R(TILE_FLUSH1, r)
                REP4(TILE_FLUSH)
            }
            for (int k = d16; k < d; ++k) {
#define TILE_TAIL1(r, t) tail##r##_##t += SQ1(x##r[k], q##t[k]);
#define TILE_TAIL(r) REP6_R(TILE_TAIL1, r)
                REP4(TILE_TAIL)
            }
        }
#define TILE_STORE1(r, t) \
    if (row##r < n && qb + t < b) out[(size_t)(qb + t) * n + row##r] = hsum16(acc##r##_##t) + tail##r##_##t;
#define TILE_STORE(r) REP6_R(TILE_STORE1, r)
        REP4(TILE_STORE)
    }
}

// ---------------------------------------------------------------------------------
// Gather: out[c] = sum_j w[j] * (grid[base(c) + offsets[j]] - values[j])^2.
// Lattice mode (use_bases == 0): candidate (z, y, x) has base
// base0 + z*step_z + y*step_y + x*step_x. Explicit mode: range (n, 1, 1), base = bases[c].

// Early exit (use_threshold): a candidate whose partial sum passes threshold[0] stops
// there and reports that partial sum, any value above the threshold being as good for
// the caller (an argmin with a threshold at or above the minimum stays exact). Checked
// every GATHER_CHUNK entries.
#define GATHER_CHUNK 256

// One candidate per work-item; any lattice or explicit bases.
// Range: (round_up(nx, 16), ny, nz), local (16, 1, 1).
__kernel void ssd_gather(__global const T* grid, __global const int* bases, const int use_bases,
                         const int nx, const int ny, const int nz,
                         const int step_x, const int step_y, const int step_z, const int base0,
                         __global const int* offsets, __global const T* values,
                         __global const W* weights, const int use_weights, const int kc,
                         __global const S* threshold, const int use_threshold, __global S* out)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= nx || y >= ny || z >= nz) return;
    const int cand = (z * ny + y) * nx + x;
    const int base = use_bases ? bases[cand] : base0 + z * step_z + y * step_y + x * step_x;
    const S thr = threshold[0];
    S acc = 0;
    for (int j0 = 0; j0 < kc; j0 += GATHER_CHUNK) {
        const int j1 = MIN_INT(j0 + GATHER_CHUNK, kc);
        if (use_weights) {
            for (int j = j0; j < j1; ++j) acc += weights[j] * SQ1(grid[base + offsets[j]], values[j]);
        } else {
            for (int j = j0; j < j1; ++j) acc += SQ1(grid[base + offsets[j]], values[j]);
        }
        if (use_threshold && acc > thr) break;  // only "above threshold" matters now
    }
    out[cand] = acc;
}

// Explicit bases whose offsets come in runs of `run` consecutive grid elements (run a
// multiple of 16 dividing GATHER_CHUNK: the x rows of a block of side >= 16), unweighted:
// one candidate per work-item, 16 lanes per load of the grid and of the query values.
// Same results as ssd_gather on those inputs. Range: round_up(n, 16), local 16.
__kernel void ssd_gather_runs(__global const T* grid, __global const int* bases, const int n,
                              __global const int* offsets, __global const T* values, const int kc,
                              const int run, __global const S* threshold, const int use_threshold,
                              __global S* out)
{
    const int c = get_global_id(0);
    if (c >= n) return;
    const __global T* g = grid + bases[c];
    const S thr = threshold[0];
    S16 acc = (S16)(0);
    for (int j0 = 0; j0 < kc; j0 += GATHER_CHUNK) {
        const int j1 = MIN_INT(j0 + GATHER_CHUNK, kc);
        for (int j = j0; j < j1; j += run) {
            const __global T* p = g + offsets[j];
            const __global T* v = values + j;
            for (int l = 0; l < run; l += 16) { const E16 e = LOAD16(p + l) - LOAD16(v + l); acc += SQ16(e); }
        }
        if (use_threshold && hsum16(acc) > thr) break;  // only "above threshold" matters now
    }
    out[c] = hsum16(acc);
}

// Lattices with step_x == 1 (one channel, unit x stride): each work-item scores 64
// neighbouring candidates along x as 4 vectors of 16, so one offset/value fetch serves
// 4 vector loads. A vector that would run past nx is moved back to start at nx - 16
// (overlapping its neighbour; it stores only its own lanes), so with nx >= 16 nothing
// is read past the last window; with nx < 16 the grid needs 15 spare elements (the
// backend allocates 64 bytes more than every buffer).
// Range: (ceil(nx/64), round_up(ny, 7), nz), local (1, 7, 1).
#ifndef GATHER_NV
#define GATHER_NV 4  // vectors of 16 candidates per work-item (build option)
#endif
__kernel void ssd_gather_x16(__global const T* grid, __global const int* bases, const int use_bases,
                             const int nx, const int ny, const int nz,
                             const int step_x, const int step_y, const int step_z, const int base0,
                             __global const int* offsets, __global const T* values,
                             __global const W* weights, const int use_weights, const int kc,
                             __global const S* threshold, const int use_threshold, __global S* out)
{
    const int x0 = get_global_id(0) * (16 * GATHER_NV), y = get_global_id(1), z = get_global_id(2);
    if (x0 >= nx || y >= ny || z >= nz) return;
    const int last = nx - 16 > 0 ? nx - 16 : 0;
    int xs[GATHER_NV];
    S16 acc[GATHER_NV];
#pragma unroll
    for (int v = 0; v < GATHER_NV; ++v) {
        const int a = x0 + 16 * v;
        xs[v] = a < last ? a : last;
        acc[v] = (S16)(0);
    }
    const __global T* row = grid + base0 + z * step_z + y * step_y;
    const S16 thr = (S16)(threshold[0]);
    for (int j0 = 0; j0 < kc; j0 += GATHER_CHUNK) {
        const int j1 = MIN_INT(j0 + GATHER_CHUNK, kc);
        if (use_weights) {
            for (int j = j0; j < j1; ++j) {
                const __global T* p = row + offsets[j];
                const E16 val = SPLAT16(values[j]);
                const S16 w = (S16)(weights[j]);
#pragma unroll
                for (int v = 0; v < GATHER_NV; ++v) { const E16 e = LOAD16(p + xs[v]) - val; acc[v] += w * SQ16(e); }
            }
        } else {
            for (int j = j0; j < j1; ++j) {
                const __global T* p = row + offsets[j];
                const E16 val = SPLAT16(values[j]);
#pragma unroll
                for (int v = 0; v < GATHER_NV; ++v) { const E16 e = LOAD16(p + xs[v]) - val; acc[v] += SQ16(e); }
            }
        }
        if (use_threshold) {  // stop once all 64 candidates are above the threshold
            int16 alive = (int16)(0);
#pragma unroll
            for (int v = 0; v < GATHER_NV; ++v) alive |= acc[v] <= thr;
            if (!any16(alive)) break;
        }
    }
    __global S* orow = out + (z * ny + y) * nx;
#pragma unroll
    for (int v = 0; v < GATHER_NV; ++v) {
        const int a = x0 + 16 * v;  // the first candidate this vector owns
        if (a >= nx) break;
        if (a == xs[v] && a + 16 <= nx) {
            *(__global Sx16u*)(orow + a) = acc[v];
        } else {
            S lanes[16];
            *(Sx16u*)lanes = acc[v];
            const int hi = a + 16 < nx ? a + 16 : nx;
            for (int c = a; c < hi; ++c) orow[c] = lanes[c - xs[v]];
        }
    }
}

// ---------------------------------------------------------------------------------
// Selection. Ranges: round_up(g, 64), local 64; work-items t >= g do nothing.

// Work-item t scans t, t+g, t+2g, ... ascending, so a strict < keeps the lowest index.
// A share holding a NaN or inf score reports index -2 (the host refuses such scores).
#ifdef GS_U8
#define SCORE_OK(s) 1
#define SCORE_OK16(v) ((int16)(-1))
#else
#define SCORE_OK(s) ((s) <= FLT_MAX)  // false for NaN and +inf
#define SCORE_OK16(v) ((v) <= (S16)(FLT_MAX))
#endif
// The same partial minima over contiguous chunks, 16 lanes at a time: work-item t owns
// [t*chunk, (t+1)*chunk) (chunk a multiple of 16). Each lane keeps its first minimum
// (strict <), the lanes' minimum with the lowest index among equals is the chunk's.
// For CPU devices, where a strided share reads a new cache line per element.
__kernel void argmin_chunks(__global const S* scores, const int n, const int chunk,
                            __global S* part_val, __global int* part_idx, const int g)
{
    const int t = get_global_id(0);
    if (t >= g) return;
    const int lo = t * chunk, hi = MIN_INT(lo + chunk, n);
    if (lo >= hi) { part_val[t] = 0; part_idx[t] = -1; return; }
    const int hi16 = lo + ((hi - lo) & ~15);
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    S best = scores[lo];
    int best_idx = lo;
    int ok = 1;
    if (hi16 > lo) {
        S16 vbest = LOADS16(scores + lo);
        int16 vidx = lane + lo;
        int16 vok = SCORE_OK16(vbest);
        for (int i = lo + 16; i < hi16; i += 16) {
            const S16 v = LOADS16(scores + i);
            const int16 less = v < vbest;
            vok &= SCORE_OK16(v);
            vbest = less ? v : vbest;
            vidx = less ? lane + i : vidx;
        }
        ok = all16(vok);
        S lv[16];
        int li[16];
        *(__private Sx16u*)lv = vbest;  // not vstore16: see common.h's note on 16-wide builtins
        *(__private i32x16u*)li = vidx;
        best = lv[0];
        best_idx = li[0];
        for (int l = 1; l < 16; ++l) {
            if (lv[l] < best || (lv[l] == best && li[l] < best_idx)) { best = lv[l]; best_idx = li[l]; }
        }
    }
    for (int i = hi16; i < hi; ++i) {
        const S s = scores[i];
        ok &= SCORE_OK(s);
        if (s < best) { best = s; best_idx = i; }
    }
    part_val[t] = best;
    part_idx[t] = ok ? best_idx : -2;
}

__kernel void argmin_partials(__global const S* scores, const int n,
                              __global S* part_val, __global int* part_idx, const int g)
{
    const int t = get_global_id(0);
    if (t >= g) return;
    int best_idx = -1;
    S best = 0;
    int ok = 1;
    for (int i = t; i < n; i += g) {
        const S s = scores[i];
        ok &= SCORE_OK(s);
        if (best_idx < 0 || s < best) { best = s; best_idx = i; }
    }
    part_val[t] = best;
    part_idx[t] = ok ? best_idx : -2;
}

// Work-item t owns [t*chunk, (t+1)*chunk) and counts the scores the threshold selects.
__kernel void count_selected(__global const S* scores, const int n, const int chunk,
                             __global const S* thr, const int mode, __global int* counts, const int g)
{
    const int t = get_global_id(0);
    if (t >= g) return;
    const int lo = t * chunk, hi = MIN_INT(lo + chunk, n);
    const S th = thr[0];
    int c = 0;
    for (int i = lo; i < hi; ++i) c += is_selected(scores[i], th, mode);
    counts[t] = c;
}

// Writes the selected indices of each chunk at starts[t] (exclusive prefix of counts),
// so the output is in ascending index order.
__kernel void compact_selected(__global const S* scores, const int n, const int chunk,
                               __global const S* thr, const int mode,
                               __global const int* starts, __global int* out_idx, const int g)
{
    const int t = get_global_id(0);
    if (t >= g) return;
    const int lo = t * chunk, hi = MIN_INT(lo + chunk, n);
    const S th = thr[0];
    int w = starts[t];
    for (int i = lo; i < hi; ++i)
        if (is_selected(scores[i], th, mode)) out_idx[w++] = i;
}
