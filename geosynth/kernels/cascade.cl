// The fused cascade search (M1): OpenCL kernels.
//
// The twin of cascade.py, with the same arguments in the same order
// (cascade_search_kernel <-> cascade_search). The bound is eq. 2 of Lagae, Dumont and
// Dutre, "Geometry Synthesis", Sec. 4.2, over every block of the source. Plain
// operators only (see common.h).
#include "common.h"

// M1's cascade search in one launch (geosynth.volume.cascade.CascadeSearch, fused). Lower
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
// query_terms: per query, its 8 coarse sums, 8 coarse centred norms, 64 fine sums in that
// order. inv_c, inv_f: 1 / cell samples (powers of two). Limit: t * margin + slack,
// slack covering the float32 rounding of the norms. n: a multiple of 8 (8-byte rows),
// SSDs < 2^31 (n <= 32).
// A batch of n_queries queries, items work-items each: work-item g serves query
// q = g / items (its terms at query_terms[80 q], its samples at query[n^3 q], its shared
// best at best_shared[q]) and scans lattice rows [t*rows, (t+1)*rows) (t = g - q*items,
// row r = z*ly + y), 16 blocks along x at a time; out[3g..3g+2] = its best SSD, that
// block's lattice index (-1 if it scored none below what others had found) and how many
// blocks it scored exactly. The answer does not depend on items: every block whose SSD
// could be the minimum is scored by one item or another.
// Range: items * n_queries work-items (padded), local 1 on CPUs (each a work-group of its own).
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
                             const float inv_f, __global const uchar* queries, const int rows, const int items,
                             const int n_queries, const float margin, const float slack,
                             volatile __global int* best_all, __global int* out)
{
    const int gid = get_global_id(0);
    const int qi = gid / items;
    if (qi >= n_queries) return;
    const int r0 = (gid - qi * items) * rows;
    const int r1 = MIN_INT(r0 + rows, ly * lz);
    if (r0 >= ly * lz) {
        out[3 * gid] = INT_MAX;
        out[3 * gid + 1] = -1;
        out[3 * gid + 2] = 0;
        return;
    }
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    __global const float* q_sum = query_terms + qi * (10 * CASCADE_COARSE);
    __global const float* q_norm = q_sum + CASCADE_COARSE;
    __global const float* q_fine = q_sum + CASCADE_COARSE;  // fine slot i (8..71) at the query's terms[i + 8]
    __global const uchar* query = queries + qi * n * n * n;
    volatile __global int* best_shared = best_all + qi;
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
    out[3 * gid] = best;
    out[3 * gid + 1] = best_i;
    out[3 * gid + 2] = scored;
}
