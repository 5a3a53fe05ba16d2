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
