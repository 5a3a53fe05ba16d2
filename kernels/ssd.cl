// Candidate SSD scoring and score selection: OpenCL kernels.
//
// The twin of ssd.py: every kernel here has a namesake there (ssd_dense <->
// ssd_dense_kernel) with the same arguments in the same order and the same meaning.
// Arrays are flat; sizes are explicit. Types come from common.h (GS_U8 or float).
// Build options: GS_TB = queries per work-item in ssd_dense (a register tile).
#include "common.h"

#ifndef GS_TB
#define GS_TB 1
#endif

// out[q, i] = sum_k w[k] * (candidates[i, k] - queries[q, k])^2.
// One work-item per candidate row; it scores GS_TB queries at a time so that each
// candidate chunk is loaded once per tile, 16 lanes wide.
__kernel void ssd_dense(__global const T* candidates, __global const T* queries,
                        __global const W* weights, const int use_weights,
                        const int n, const int d, const int b, __global S* out)
{
    const int i = get_global_id(0);
    if (i >= n) return;
    const __global T* row = candidates + (size_t)i * d;
    const int d16 = d & ~15;
    for (int q0 = 0; q0 < b; q0 += GS_TB) {
        S16 acc[GS_TB];
        S tail[GS_TB];
        const __global T* qrow[GS_TB];
        for (int t = 0; t < GS_TB; ++t) {
            acc[t] = (S16)(0);
            tail[t] = 0;
            // Past the last query the tile repeats it; those results are not stored.
            qrow[t] = queries + (size_t)min(q0 + t, b - 1) * d;
        }
        if (use_weights) {
            for (int k = 0; k < d16; k += 16) {
                const T16 x = vload16(0, row + k);
                const W16 w = vload16(0, weights + k);
                for (int t = 0; t < GS_TB; ++t) acc[t] += w * sq_diff16(x, vload16(0, qrow[t] + k));
            }
            for (int k = d16; k < d; ++k)
                for (int t = 0; t < GS_TB; ++t) tail[t] += weights[k] * sq_diff(row[k], qrow[t][k]);
        } else {
            for (int k = 0; k < d16; k += 16) {
                const T16 x = vload16(0, row + k);
                for (int t = 0; t < GS_TB; ++t) acc[t] += sq_diff16(x, vload16(0, qrow[t] + k));
            }
            for (int k = d16; k < d; ++k)
                for (int t = 0; t < GS_TB; ++t) tail[t] += sq_diff(row[k], qrow[t][k]);
        }
        for (int t = 0; t < GS_TB; ++t)
            if (q0 + t < b) out[(size_t)(q0 + t) * n + i] = hsum16(acc[t]) + tail[t];
    }
}

// out[c] = sum_j w[j] * (grid[base(c) + offsets[j]] - values[j])^2.
// Lattice mode (use_bases == 0): work-item (x, y, z) is candidate (z, y, x) with base
// base0 + z*step_z + y*step_y + x*step_x. Explicit mode: range (n, 1, 1), base = bases[c].
__kernel void ssd_gather(__global const T* grid, __global const int* bases, const int use_bases,
                         const int nx, const int ny, const int nz,
                         const int step_x, const int step_y, const int step_z, const int base0,
                         __global const int* offsets, __global const T* values,
                         __global const W* weights, const int use_weights, const int kc,
                         __global S* out)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= nx || y >= ny || z >= nz) return;
    const int cand = (z * ny + y) * nx + x;
    const int base = use_bases ? bases[cand] : base0 + z * step_z + y * step_y + x * step_x;
    S acc = 0;
    if (use_weights) {
        for (int j = 0; j < kc; ++j) acc += weights[j] * sq_diff(grid[base + offsets[j]], values[j]);
    } else {
        for (int j = 0; j < kc; ++j) acc += sq_diff(grid[base + offsets[j]], values[j]);
    }
    out[cand] = acc;
}

// ssd_gather for lattices with step_x == 1 and use_bases == 0: each work-item scores
// 16 neighbouring candidates along x with one unaligned 16-wide load per query entry.
// The grid buffer must have 16 spare elements past its end (the backend allocates them).
__kernel void ssd_gather_x16(__global const T* grid, __global const int* bases, const int use_bases,
                             const int nx, const int ny, const int nz,
                             const int step_x, const int step_y, const int step_z, const int base0,
                             __global const int* offsets, __global const T* values,
                             __global const W* weights, const int use_weights, const int kc,
                             __global S* out)
{
    const int x0 = get_global_id(0) * 16, y = get_global_id(1), z = get_global_id(2);
    if (x0 >= nx || y >= ny || z >= nz) return;
    const __global T* origin = grid + base0 + z * step_z + y * step_y + x0;
    S16 acc = (S16)(0);
    if (use_weights) {
        for (int j = 0; j < kc; ++j)
            acc += (S16)(weights[j]) * sq_diff16(vload16(0, origin + offsets[j]), (T16)(values[j]));
    } else {
        for (int j = 0; j < kc; ++j) acc += sq_diff16(vload16(0, origin + offsets[j]), (T16)(values[j]));
    }
    const int cand0 = (z * ny + y) * nx + x0;
    if (x0 + 16 <= nx) {
        vstore16(acc, 0, out + cand0);
    } else {
        S lanes[16];
        vstore16(acc, 0, lanes);
        for (int l = 0; l < nx - x0; ++l) out[cand0 + l] = lanes[l];
    }
}

// Work-item t scans t, t+g, t+2g, ... ascending, so a strict < keeps the lowest index.
__kernel void argmin_partials(__global const S* scores, const int n,
                              __global S* part_val, __global int* part_idx)
{
    const int t = get_global_id(0), g = get_global_size(0);
    int best_idx = -1;
    S best = 0;
    for (int i = t; i < n; i += g) {
        const S s = scores[i];
        if (best_idx < 0 || s < best) { best = s; best_idx = i; }
    }
    part_val[t] = best;
    part_idx[t] = best_idx;
}

// Work-item t owns [t*chunk, (t+1)*chunk) and counts the scores the threshold selects.
__kernel void count_selected(__global const S* scores, const int n, const int chunk,
                             __global const S* thr, const int mode, __global int* counts)
{
    const int t = get_global_id(0);
    const int lo = t * chunk, hi = min(lo + chunk, n);
    const S th = thr[0];
    int c = 0;
    for (int i = lo; i < hi; ++i) c += is_selected(scores[i], th, mode);
    counts[t] = c;
}

// Writes the selected indices of each chunk at starts[t] (exclusive prefix of counts),
// so the output is in ascending index order.
__kernel void compact_selected(__global const S* scores, const int n, const int chunk,
                               __global const S* thr, const int mode,
                               __global const int* starts, __global int* out_idx)
{
    const int t = get_global_id(0);
    const int lo = t * chunk, hi = min(lo + chunk, n);
    const S th = thr[0];
    int w = starts[t];
    for (int i = lo; i < hi; ++i)
        if (is_selected(scores[i], th, mode)) out_idx[w++] = i;
}
