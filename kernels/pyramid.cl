// Block pyramids (M1): OpenCL kernels.
//
// The twin of pyramid.py: every kernel there has its meaning here, with the same
// arguments in the same order (pyramid_compare_kernel <-> pyramid_compare). Arrays are
// flat; sizes are explicit; every kernel is 1D and checks its own range (the backend
// rounds the global size up to the explicit local size). See pyramid.py for the slab
// layout, the node codes and the hashes. Plain operators only (see common.h).
#include "common.h"

__kernel void pyramid_init(__global const uchar* field, __global uint* sums, const int total)
{
    const int p = get_global_id(0);
    if (p < total) sums[p] = (uint)field[p];
}

__kernel void pyramid_double(__global uint* sums, const int src_off, const int dst_off, const int c,
                             const int nz, const int ny, const int nx)
{
    const int p = get_global_id(0);
    if (p >= nz * ny * nx) return;
    const int yx = ny * nx;
    const int z = p / yx, y = (p / nx) % ny, x = p % nx;
    uint acc = 0;
    if (z + 2 * c <= nz && y + 2 * c <= ny && x + 2 * c <= nx) {
        const __global uint* b = sums + src_off + p;
        const int dz = c * yx, dy = c * nx;
        acc = b[0] + b[c] + b[dy] + b[dy + c] + b[dz] + b[dz + c] + b[dz + dy] + b[dz + dy + c];
    }
    sums[dst_off + p] = acc;
}

__kernel void pyramid_quantize(__global const uint* sums, const int off, const int lc, const int total,
                               __global uchar* out)
{
    const int p = get_global_id(0);
    if (p >= total) return;
    const int sh = 3 * lc;
    const uint hc = sh > 0 ? (1u << (sh - 1)) : 0u;
    out[p] = (uchar)((sums[off + p] + hc) >> sh);
}

__kernel void pyramid_compare(__global const uint* sums, const int total, const int ny, const int nx,
                              const int log_block, __global const int* node_base,
                              __global const int* node_code, __global const int* ids, const int first,
                              const int count, __global const int* query, __global const int* query_off,
                              __global long* out)
{
    const int t = get_global_id(0);
    if (t >= count) return;
    const int node = ids[first + t];
    const int code = node_code[node];
    const int lev = code >> 1, kind = code & 1;
    const int lc = log_block - (lev - 1);
    const int c = 1 << lc, n = 1 << (lev - 1);
    const int yx = ny * nx;
    const __global uint* base = sums + (size_t)lc * total + node_base[node];
    const __global int* qb = query + query_off[lev - 1];
    const int sh = 3 * lc;
    const long c3 = (long)1 << sh, hc = c3 >> 1, cap = 255 * c3;
    long acc = 0;
    if (kind == 0) {
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j) {
                const __global uint* row = base + c * (i * yx + j * nx);
                const __global int* qrow = qb + (i * n + j) * n;
                if (c == 1) {
                    for (int k = 0; k < n; ++k) {
                        const int d = qrow[k] - (int)row[k];
                        acc += (long)(d * d);  // |d| <= 255 at cell size 1
                    }
                } else {
                    for (int k = 0; k < n; ++k) {
                        const long d = (long)qrow[k] - (long)row[c * k];
                        acc += d * d;
                    }
                }
            }
    } else {
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j) {
                const __global uint* row = base + c * (i * yx + j * nx);
                const __global int* qrow = qb + (i * n + j) * n;
                for (int k = 0; k < n; ++k) {
                    const long s = (long)row[c * k], q = (long)qrow[k];
                    const long m = (s + hc) >> sh;
                    long lo = m * c3 - hc, hi = m * c3 + hc - 1;
                    lo = lo < 0 ? 0 : lo;
                    hi = hi > cap ? cap : hi;
                    const long d = q < lo ? lo - q : (q > hi ? q - hi : 0);
                    acc += d * d;
                }
            }
    }
    out[t] = acc;
}

__kernel void pyramid_hash_init(__global const uint* sums, const int off, const int lc, const int quantized,
                                const int total, __global ulong* out)
{
    const int p = get_global_id(0);
    if (p >= total) return;
    uint s = sums[off + p];
    if (quantized) {
        const int sh = 3 * lc;
        const uint hc = sh > 0 ? (1u << (sh - 1)) : 0u;
        s = (s + hc) >> sh;
    }
    out[p] = (ulong)s + 1;
}

__kernel void pyramid_hash_step(__global const ulong* src, __global ulong* dst, const int total,
                                const int stride, const ulong mult)
{
    const int p = get_global_id(0);
    if (p >= total) return;
    dst[p] = p + stride < total ? src[p] + mult * src[p + stride] : 0;
}

__kernel void pyramid_pair_equal(__global const uint* sums, const int total, const int ny, const int nx,
                                 const int lc, const int n, const int quantized,
                                 __global const int* base_a, __global const int* base_b, const int count,
                                 __global int* out)
{
    const int t = get_global_id(0);
    if (t >= count) return;
    const int c = 1 << lc, yx = ny * nx, sh = 3 * lc;
    const uint hc = sh > 0 ? (1u << (sh - 1)) : 0u;
    const __global uint* a = sums + (size_t)lc * total + base_a[t];
    const __global uint* b = sums + (size_t)lc * total + base_b[t];
    int same = 1;
    for (int i = 0; i < n && same; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k) {
                const int o = c * (i * yx + j * nx + k);
                uint va = a[o], vb = b[o];
                if (quantized) {
                    va = (va + hc) >> sh;
                    vb = (vb + hc) >> sh;
                }
                same &= va == vb;
            }
    out[t] = same;
}

// ---------------------------------------------------------------------------------
// M1's cascade search in one launch (geosynth.search.CascadeSearch, fused). Lower
// bounds of a block's SSD, per cell of m samples with sums S_q, S_b and centred norms
// C_q, C_b (the norm of the samples minus their mean): SSD_cell = (S_q - S_b)^2 / m +
// |q~ - b~|^2 >= (S_q - S_b)^2 / m + (C_q - C_b)^2. The 8 coarse cells (side n/2) use
// both terms, their 8 fine cells each (side n/4) the sums only; any mix of coarse and
// fine cells bounds the SSD. A block goes on only while its bound is <= the limit of
// t, the best SSD found by any work-item (shared through best_shared by atomic_min):
// coarse cells first, then each coarse cell's term replaced by its fine cells' terms,
// then the exact SSD. Every block whose SSD could be the minimum is scored exactly, so
// the smallest (SSD, index) over the work-items' results is the linear search's answer.
//
// coarse, coarse_norm, fine: float sums (centred norms) of the c^3 cube at every field
// position (flat, strides sy, sz; 0 where the cube leaves the field). offsets: 8 coarse
// then 64 fine flat offsets, the fine ones grouped by coarse cell in the coarse order;
// query_terms: the query's 8 coarse sums, 8 coarse centred norms, 64 fine sums in that
// order. inv_c, inv_f: 1 / cell samples (powers of two). Limit: t * margin + slack,
// slack covering the float32 rounding of the norms. n: a multiple of 8 (8-byte rows),
// SSDs < 2^31 (n <= 32).
// Work-item t scans lattice rows [t*rows, (t+1)*rows) (row r = z*ly + y), 16 blocks
// along x at a time; out[3t..3t+2] = its best SSD, that block's lattice index (-1 if it
// scored none below what others had found) and how many blocks it scored exactly.
// Range: the number of work-items, local 1 on CPUs (each a work-group of its own).
#define CASCADE_COARSE 8

typedef uchar u8x8u __attribute__((ext_vector_type(8), aligned(1)));
#define CASCADE_SUMS16(p) (*(const __global f32x16u*)(p))

// Exact SSD of the block at flat position base; stops (returning > limit) once above limit.
inline uint cascade_block_ssd(__global const uchar* field, const int base, const int n, const int sy, const int sz,
                              __global const uchar* query, const uint limit)
{
    uint acc = 0;
    for (int dz = 0; dz < n; ++dz) {
        int8 a8 = (int8)(0);
        for (int dy = 0; dy < n; ++dy) {
            const __global uchar* p = field + base + dz * sz + dy * sy;
            const __global uchar* q = query + (dz * n + dy) * n;
            for (int dx = 0; dx < n; dx += 8) {
                const int8 e = __builtin_convertvector(*(const __global u8x8u*)(p + dx), int8)
                             - __builtin_convertvector(*(const __global u8x8u*)(q + dx), int8);
                a8 += e * e;
            }
        }
        const int4 b = a8.lo + a8.hi;
        const int2 c = b.lo + b.hi;
        acc += (uint)(c.x + c.y);
        if (acc > limit) break;
    }
    return acc;
}

__kernel void cascade_search(__global const uchar* field, __global const float* coarse,
                             __global const float* coarse_norm, __global const float* fine,
                             const int lx, const int ly, const int lz, const int sy, const int sz, const int n,
                             __global const int* offsets, __global const float* query_terms, const float inv_c,
                             const float inv_f, __global const uchar* query, const int rows, const float margin,
                             const float slack, volatile __global int* best_shared, __global int* out)
{
    const int item = get_global_id(0);
    const int r0 = item * rows;
    const int r1 = MIN_INT(r0 + rows, ly * lz);
    if (r0 >= ly * lz) return;
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    __global const float* q_sum = query_terms;
    __global const float* q_norm = query_terms + CASCADE_COARSE;
    __global const float* q_fine = query_terms + CASCADE_COARSE;  // fine slot i (8..71) at query_terms[i + 8]
    int best = INT_MAX, best_i = -1, scored = 0;
    for (int r = r0; r < r1; ++r) {
        const int z = r / ly;
        const int row = z * sz + (r - z * ly) * sy;
        for (int x0 = 0; x0 < lx; x0 += 16) {  // lanes past lx read spare elements and are masked
            const int shared = *best_shared;
            int t = shared < best ? shared : best;
            const float16 lim = (float16)((float)t * margin + slack);
            float16 term[CASCADE_COARSE];
            float16 bound = (float16)(0.0f);
            for (int j = 0; j < CASCADE_COARSE; ++j) {
                const int o = row + offsets[j] + x0;
                const float16 e = CASCADE_SUMS16(coarse + o) - (float16)(q_sum[j]);
                const float16 d = CASCADE_SUMS16(coarse_norm + o) - (float16)(q_norm[j]);
                term[j] = e * e * (float16)(inv_c) + d * d;
                bound += term[j];
            }
            int16 alive = (bound <= lim) & ((lane + x0) < lx);
            if (!any16(alive)) continue;
            for (int j = 0; j < CASCADE_COARSE; ++j) {
                float16 acc = (float16)(0.0f);
                for (int i = CASCADE_COARSE * (j + 1); i < CASCADE_COARSE * (j + 2); ++i) {
                    const float16 e = CASCADE_SUMS16(fine + row + offsets[i] + x0) - (float16)(q_fine[i]);
                    acc += e * e;
                }
                bound += acc * (float16)(inv_f) - term[j];
                alive &= bound <= lim;
                if (!any16(alive)) break;
            }
            if (!any16(alive)) continue;
            int live[16];
            *(int16*)live = alive;
            for (int l = 0; l < 16; ++l) {
                if (!live[l]) continue;
                const uint s = cascade_block_ssd(field, row + x0 + l, n, sy, sz, query, (uint)t);
                ++scored;
                if (s <= (uint)t && s < (uint)best) {  // exact (it ran to the end); a later index never wins a tie
                    best = (int)s;
                    best_i = r * lx + x0 + l;
                    if (best < t) {
                        t = best;
                        atomic_min(best_shared, best);
                    }
                }
            }
        }
    }
    out[3 * item] = best;
    out[3 * item + 1] = best_i;
    out[3 * item + 2] = scored;
}
