"""Which texel best matches each of many neighbourhoods? Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 4 (eq. 5).

M3 texel search, batched: eq. 5 of many irregular neighbourhoods against every texel
of a supersampled texture in one launch, then the best texel of each. Warp kernels.

The twin of ``texel.cl`` (same kernel names without ``_kernel``, same arguments in the
same order). uint8 data only: scores are uint32 sums of squared integer differences,
exact and identical on every device. Arrays are flat; sizes are explicit.

- ``texel_scores_kernel`` (one thread per query and strip of 4 texels of a row, launched
  over (B, height * ceil(width / 4))): for query b and candidate texel c = ty * width + tx, whose
  window starts at ``base0 + ty * row_step + tx * col_step`` in the flat grid,
  ``out[b * n + c] = sum_{j in [qstart[b], qstart[b + 1])} (grid[base + offsets[j]] - values[j])^2``
  (one entry per channel; offsets are flat element offsets, already clipped to the grid).
- ``texel_argmin_kernel``: the lowest index of the minimum of each query's row, and that score.

Host wrappers live in ``geosynth._backends.warp_texel``; nothing here validates.
"""

import warp as wp


@wp.kernel
def texel_scores_kernel(
    grid: wp.array(dtype=wp.uint8),  # flat padded supersampled texture (Z, Y, X, C)
    n: int,  # candidates per query (texels)
    width: int,  # texels per row
    row_step: int,  # flat step between texel rows (m grid rows)
    col_step: int,  # flat step between texel columns (m grid columns)
    base0: int,  # flat index of texel (0, 0)
    qstart: wp.array(dtype=wp.int32),  # (B + 1,) first entry of each query
    offsets: wp.array(dtype=wp.int32),  # (E,) flat element offsets
    values: wp.array(dtype=wp.uint8),  # (E,) query values
    out: wp.array(dtype=wp.uint32),  # (B * n,) scores
):
    """Thread (b, s): query b, a strip of 4 texels (tx = 4 * (s % strips) + 0..3) of row
    s / strips; each entry's offset and value are read once for the strip."""
    b, s = wp.tid()
    strips = (width + 3) / 4
    ty = s / strips
    tx = (s - ty * strips) * 4
    base = base0 + ty * row_step + tx * col_step
    # past the row's end a strip re-reads its last valid texel and does not store it
    c1 = wp.min(1, width - 1 - tx) * col_step
    c2 = wp.min(2, width - 1 - tx) * col_step
    c3 = wp.min(3, width - 1 - tx) * col_step
    a0 = wp.uint32(0)
    a1 = wp.uint32(0)
    a2 = wp.uint32(0)
    a3 = wp.uint32(0)
    for j in range(qstart[b], qstart[b + 1]):
        p = base + offsets[j]
        v = wp.int32(values[j])
        d0 = wp.int32(grid[p]) - v
        d1 = wp.int32(grid[p + c1]) - v
        d2 = wp.int32(grid[p + c2]) - v
        d3 = wp.int32(grid[p + c3]) - v
        a0 += wp.uint32(d0 * d0)
        a1 += wp.uint32(d1 * d1)
        a2 += wp.uint32(d2 * d2)
        a3 += wp.uint32(d3 * d3)
    row = b * n + ty * width + tx
    out[row] = a0
    if tx + 1 < width:
        out[row + 1] = a1
    if tx + 2 < width:
        out[row + 2] = a2
    if tx + 3 < width:
        out[row + 3] = a3


@wp.kernel
def texel_argmin_kernel(
    scores: wp.array(dtype=wp.uint32),  # (B * n,)
    n: int,
    best_idx: wp.array(dtype=wp.int32),  # (B,) lowest index of the minimum
    best_score: wp.array(dtype=wp.uint32),  # (B,)
):
    b = wp.tid()
    row = b * n
    best = scores[row]
    bi = int(0)
    for i in range(1, n):
        s = scores[row + i]
        if s < best:
            best = s
            bi = i
    best_idx[b] = bi
    best_score[b] = best
