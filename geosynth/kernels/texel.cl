// M3 texel search, batched: eq. 5 of many irregular neighbourhoods against every texel
// of a supersampled texture in one launch, then the best texel of each. The twin of
// texel.py (same kernels, same arguments in the same order); uchar data, uint scores,
// exact. See texel.py for the definitions.
#include "common.h"

// Work-item (s, b): query b, a strip of 16 texels (tx = 16 * (s % strips) + 0..15) of row
// s / strips; each entry's offset and value are read once for the strip. With col_step
// 1 (a channel-planar layout: neighbouring texels in neighbouring bytes) the 16 texels are
// one 16-byte load (lanes past the row's end read padding and are not stored); else 16
// scalar reads, the last valid texel repeated past the row's end.
// Range: (round_up(height * ceil(width / 16), 64), B), local (64, 1).
__kernel void texel_scores(__global const uchar* grid, const int n, const int width,
                           const int row_step, const int col_step, const int base0,
                           __global const int* qstart, __global const int* offsets,
                           __global const uchar* values, __global uint* out)
{
    const int s = get_global_id(0), b = get_global_id(1);
    const int strips = (width + 15) / 16;
    const int height = n / width;
    if (s >= height * strips) return;
    const int ty = s / strips, tx = (s - ty * strips) * 16;
    const int base = base0 + ty * row_step + tx * col_step;
    const int j0 = qstart[b], j1 = qstart[b + 1];
    uint16 acc = (uint16)(0);
    if (col_step == 1) {
        for (int j = j0; j < j1; ++j) {
            const int16 d = LOAD16(grid + base + offsets[j]) - (int16)((int)values[j]);
            acc += SQ16(d);
        }
    } else {
        int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        const int16 last = (int16)(width - 1 - tx);
        lane = lane > last ? last : lane;  // not select(): PoCL 3.0 aborts on 16-wide builtins on Zen 4
        const int16 cols = lane * (int16)(col_step);
        for (int j = j0; j < j1; ++j) {
            const int p = base + offsets[j];
            const int v = (int)values[j];
            int16 g;
            g.s0 = grid[p + cols.s0]; g.s1 = grid[p + cols.s1]; g.s2 = grid[p + cols.s2]; g.s3 = grid[p + cols.s3];
            g.s4 = grid[p + cols.s4]; g.s5 = grid[p + cols.s5]; g.s6 = grid[p + cols.s6]; g.s7 = grid[p + cols.s7];
            g.s8 = grid[p + cols.s8]; g.s9 = grid[p + cols.s9]; g.sa = grid[p + cols.sa]; g.sb = grid[p + cols.sb];
            g.sc = grid[p + cols.sc]; g.sd = grid[p + cols.sd]; g.se = grid[p + cols.se]; g.sf = grid[p + cols.sf];
            const int16 d = g - (int16)(v);
            acc += SQ16(d);
        }
    }
    __global uint* row = out + (size_t)b * n + ty * width + tx;
    const int valid = MIN_INT(16, width - tx);
    uint lanes[16];
    *(uint16*)lanes = acc;
    for (int r = 0; r < valid; ++r) row[r] = lanes[r];
}

// Range: round_up(B, 64), local 64; one work-item per query scans its row.
__kernel void texel_argmin(__global const uint* scores, const int n, __global int* best_idx,
                           __global uint* best_score, const int nq)
{
    const int b = get_global_id(0);
    if (b >= nq) return;
    const __global uint* row = scores + (size_t)b * n;
    uint best = row[0];
    int bi = 0;
    for (int i = 1; i < n; ++i) {
        const uint s = row[i];
        if (s < best) { best = s; bi = i; }
    }
    best_idx[b] = bi;
    best_score[b] = best;
}
