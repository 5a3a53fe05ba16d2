// Distance-field kernels (points): OpenCL. The twin of sdf_points.py.
//
// The MLS surface of an oriented point set (Adamson and Alexa): with Gaussian weights
// w_i(y) = exp(-|p_i - y|^2 / h^2), cut off beyond `reach`,
//   a(y) = sum w_i p_i / sum w_i,   n(y) = normalize(sum w_i n_i),   f(y) = n(y) . (y - a(y)).
// mls_project iterates the quasi-orthogonal projection y <- y - f(y) n(y) from each query
// point x and writes the signed distance sign(f(x)) |x - proj(x)| (clamped to +-reach),
// the MLS normal at the projection (the gradient) and, when asked, the projection and the
// residual f(proj) (how far one more step would move it; +reach where no point is within
// reach of proj; where it stopped at |f| <= tol, that last step's f). A query with no
// point within reach gets distance +reach, gradient 0, proj = x. A projection that reaches a fixed point (a step that leaves y's bits unchanged)
// stops there: the later steps would repeat it exactly, so the result is the same as with
// all max_iter steps, sooner.
//
// Neighbours come from a cell-sorted grid built on the host (geosynth.geometry.pointsets): the
// points sorted by linear cell index (cz * ny + cy) * nx + cx, cell_start[c] the first
// point of cell c (nx*ny*nz + 1 entries, the last = n). The cells of one (cz, cy) row are
// consecutive, so a row of cells is one contiguous range of points.
// Points are interleaved as float8 (x, y, z, 0, nx, ny, nz, 0): one 32-byte read each.
//
// Performance (PoCL 3 on the CPU, measured): exp() is a library call there and dominated
// the inner loop; gauss_weight() below is a plain-arithmetic exp(-t) (relative error
// < 2e-7 on the range used), several times faster. Only sqrt (once per iteration) stays.
#include "common.h"

// exp(-t) for 0 <= t (t <= 9 here: the reach is 3h). 2^x with x = -t log2(e) split into
// an integer k and a fraction in (-0.5, 0.5]; 2^frac by a degree-6 Taylor polynomial of
// e^g, |g| <= 0.347 (truncation error < 1.3e-7 relative).
inline float gauss_weight(const float t)
{
    const float x = -t * 1.44269504f;
    if (x < -125.0f)
        return 0.0f;
    const int k = (int)(x - 0.5f);  // x - 0.5 < 0: truncation rounds up, k in [x - 0.5, x + 0.5)
    const float g = (x - (float)k) * 0.693147181f;
    const float p = 1.0f + g * (1.0f + g * (0.5f + g * (0.166666667f + g * (0.0416666667f
                  + g * (0.00833333333f + g * 0.00138888889f)))));
    return p * as_float((k + 127) << 23);
}

// One axis of the cell range a box [c - reach, c + reach] touches; empty when lo > hi.
#define CELL_RANGE(c, g, n, lo, hi)                                       \
    {                                                                     \
        const float flo = ((c) - reach - (g)) * inv_cell;                 \
        const float fhi = ((c) + reach - (g)) * inv_cell;                 \
        lo = flo < 0.0f ? 0 : (flo >= (float)(n) ? (n) : (int)flo);       \
        hi = fhi < 0.0f ? -1 : (fhi >= (float)(n) ? (n) - 1 : (int)fhi);  \
    }

// Gaussian-weighted sums at y over the points within reach:
// returns sum w; s = sum w (p - y); m = sum w n.
inline float mls_sums(__global const float8* pn, __global const int* cell_start,
                      const float gx, const float gy, const float gz, const float inv_cell,
                      const int nx, const int ny, const int nz,
                      const float inv_h2, const float reach,
                      const float yx, const float yy, const float yz,
                      float* sx, float* sy, float* sz, float* mx, float* my, float* mz)
{
    const float reach2 = reach * reach;
    const float cell = 1.0f / inv_cell;
    int x0, x1, y0, y1, z0, z1;
    CELL_RANGE(yx, gx, nx, x0, x1);
    CELL_RANGE(yy, gy, ny, y0, y1);
    CELL_RANGE(yz, gz, nz, z0, z1);
    float ws = 0.0f, ax = 0.0f, ay = 0.0f, az = 0.0f, bx = 0.0f, by = 0.0f, bz = 0.0f;
    if (x0 <= x1) {
        for (int cz = z0; cz <= z1; ++cz) {
            // distance from y to the slab of cell layer cz (0 inside it)
            const float zlo = gz + (float)cz * cell;
            const float dz = yz < zlo ? zlo - yz : (yz > zlo + cell ? yz - zlo - cell : 0.0f);
            for (int cy = y0; cy <= y1; ++cy) {
                const float ylo = gy + (float)cy * cell;
                const float dy = yy < ylo ? ylo - yy : (yy > ylo + cell ? yy - ylo - cell : 0.0f);
                if (dz * dz + dy * dy > reach2)
                    continue;  // the whole row is out of reach
                const int row = (cz * ny + cy) * nx;
                const int end = cell_start[row + x1 + 1];
                for (int i = cell_start[row + x0]; i < end; ++i) {
                    const float8 q = pn[i];
                    const float ex = q.s0 - yx, ey = q.s1 - yy, ez = q.s2 - yz;
                    const float d2 = ex * ex + ey * ey + ez * ez;
                    if (d2 < reach2) {
                        const float w = gauss_weight(d2 * inv_h2);
                        ws += w;
                        ax += w * ex;
                        ay += w * ey;
                        az += w * ez;
                        bx += w * q.s4;
                        by += w * q.s5;
                        bz += w * q.s6;
                    }
                }
            }
        }
    }
    *sx = ax; *sy = ay; *sz = az;
    *mx = bx; *my = by; *mz = bz;
    return ws;
}

// One work-item per query. Queries are read from `queries` (m x 3) when use_queries != 0,
// else generated on a lattice: query i = (ix, iy, iz) in raster order (x fastest) sits at
// (qox + ix qsx, qoy + iy qsy, qoz + iz qsz). Outputs: dist (m), grad (m x 3), and
// proj (m x 3) when write_proj != 0, resid (m) when write_resid != 0. Range: round_up(m, 64),
// local 64.
__kernel void mls_project(__global const float8* pn, __global const int* cell_start,
                          const float gx, const float gy, const float gz, const float inv_cell,
                          const int nx, const int ny, const int nz,
                          const float inv_h2, const float reach, const float tol, const int max_iter,
                          __global const float* queries, const int use_queries,
                          const float qox, const float qoy, const float qoz,
                          const float qsx, const float qsy, const float qsz,
                          const int qnx, const int qny,
                          const int m, __global float* dist, __global float* grad,
                          __global float* proj, const int write_proj,
                          __global float* resid, const int write_resid)
{
    const int i = get_global_id(0);
    if (i >= m)
        return;
    float xx, xy, xz;
    if (use_queries != 0) {
        xx = queries[3 * i];
        xy = queries[3 * i + 1];
        xz = queries[3 * i + 2];
    } else {
        const int ix = i % qnx;
        const int iy = (i / qnx) % qny;
        const int iz = i / (qnx * qny);
        xx = qox + (float)ix * qsx;
        xy = qoy + (float)iy * qsy;
        xz = qoz + (float)iz * qsz;
    }
    float yx = xx, yy = xy, yz = xz;           // the current iterate
    float px = xx, py = xy, pz = xz;           // the projection so far
    float nx_ = 0.0f, ny_ = 0.0f, nz_ = 0.0f;  // the MLS normal at the last iterate
    float f0 = 0.0f, f_last = 0.0f;
    int found = 0, settled = 0, lost = 0;
    for (int it = 0; it < max_iter; ++it) {
        float sx, sy, sz, mx, my, mz;
        const float ws = mls_sums(pn, cell_start, gx, gy, gz, inv_cell, nx, ny, nz, inv_h2, reach,
                                  yx, yy, yz, &sx, &sy, &sz, &mx, &my, &mz);
        const float mm = mx * mx + my * my + mz * mz;
        if (!(ws > 0.0f) || !(mm > 0.0f)) {
            lost = 1;  // no point within reach of y == p (or normals cancel): keep the last projection
            break;
        }
        const float inv = 1.0f / sqrt(mm);
        const float ux = mx * inv, uy = my * inv, uz = mz * inv;
        const float f = -(ux * sx + uy * sy + uz * sz) / ws;  // n . (y - a)
        if (it == 0) {
            f0 = f;
            found = 1;
        }
        nx_ = ux; ny_ = uy; nz_ = uz;
        f_last = f;
        px = yx - f * ux; py = yy - f * uy; pz = yz - f * uz;
        if ((f < 0.0f ? -f : f) <= tol) {
            settled = 1;  // converged: the last step's f stands for f at the projection
            break;
        }
        if (px == yx && py == yy && pz == yz) {
            settled = 1;  // a fixed point: every later step would repeat this one bit for bit
            break;
        }
        yx = px; yy = py; yz = pz;
    }
    float d = reach;
    if (found) {
        const float ex = xx - px, ey = xy - py, ez = xz - pz;
        d = sqrt(ex * ex + ey * ey + ez * ez);
        d = d > reach ? reach : d;
        d = f0 < 0.0f ? -d : d;
    }
    dist[i] = d;
    grad[3 * i] = nx_;
    grad[3 * i + 1] = ny_;
    grad[3 * i + 2] = nz_;
    if (write_proj != 0) {
        proj[3 * i] = px;
        proj[3 * i + 1] = py;
        proj[3 * i + 2] = pz;
    }
    if (write_resid != 0) {
        // f at the projection (reach where no point is within reach of it): one more step's
        // size; at a fixed point the last step's f, which is f there; at the tolerance the
        // last step's f (|f| <= tol: the projection has converged). A projection that lost
        // its support stopped at p, where the sums just came out empty: reach, not recomputed.
        float r = reach;
        if (settled) {
            r = f_last;
        } else if (!lost) {
            float sx, sy, sz, mx, my, mz;
            const float ws = mls_sums(pn, cell_start, gx, gy, gz, inv_cell, nx, ny, nz, inv_h2, reach,
                                      px, py, pz, &sx, &sy, &sz, &mx, &my, &mz);
            const float mm = mx * mx + my * my + mz * mz;
            if (ws > 0.0f && mm > 0.0f) {
                const float inv = 1.0f / sqrt(mm);
                r = -(mx * inv * sx + my * inv * sy + mz * inv * sz) / ws;
            }
        }
        resid[i] = r;
    }
}
