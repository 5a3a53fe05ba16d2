"""What are the block pyramid's cell sums, and which nodes does a query expand? Lagae,
Dumont and Dutré, "Geometry Synthesis", Sec. 4.1-4.3.

Block pyramids (M1): Warp kernels.

The twin of ``pyramid.cl``: every kernel here has its meaning there, with the same
arguments in the same order (``pyramid_compare_kernel`` <-> ``pyramid_compare``). All
arrays are flat (1D); sizes are passed explicitly; nothing here validates.

Layout of the global pyramid (``sums``, uint32): one slab of ``total = Z*Y*X`` entries
per cell size c = 2^k, k = 0 .. log2(N), slab k starting at ``k * total``. Entry p of
slab k is the exact integer sum of the field over the c^3 cube whose lowest corner is
p (flat (z, y, x) raster index); positions whose cube leaves the field hold 0. Block
level l (1 = one cell of size N, L = log2(N) + 1 = the full block) has cell size
c = N / 2^(l-1) and samples slab log2(c) at origin + c * (i, j, k).

Node codes (``node_code``): ``level * 2 + kind``; kind 0 compares exact cell sums,
kind 1 compares against the interval of sums that the node's uint8-rounded means
allow (a parent node grouping children with equal rounded means; see
``geosynth.volume.tree``).

Hashes are linear polynomial hashes modulo 2^64, built by doubling (``pyramid_hash_step``);
they only propose groups, which are then verified exactly (``pyramid_pair_equal``).
"""

import warp as wp


@wp.kernel
def pyramid_init_kernel(
    field: wp.array(dtype=wp.uint8),  # (total,) the quantized source
    sums: wp.array(dtype=wp.uint32),  # slab 0 written: the field widened
    total: int,
):
    """sums[p] = field[p] (the cell size 1 slab)."""
    p = wp.tid()
    if p < total:
        sums[p] = wp.uint32(field[p])


@wp.kernel
def pyramid_double_kernel(
    sums: wp.array(dtype=wp.uint32),
    src_off: int,  # first entry of the cell size c slab
    dst_off: int,  # first entry of the cell size 2c slab
    c: int,  # source cell size
    nz: int,
    ny: int,
    nx: int,
):
    """S_2c[p] = sum over o in {0, c}^3 of S_c[p + o], 0 where the 2c cube leaves the field."""
    p = wp.tid()
    if p >= nz * ny * nx:
        return
    yx = ny * nx
    z = p / yx
    y = (p / nx) % ny
    x = p % nx
    acc = wp.uint32(0)
    if z + 2 * c <= nz and y + 2 * c <= ny and x + 2 * c <= nx:
        b = src_off + p
        dz = c * yx
        dy = c * nx
        acc = (sums[b] + sums[b + c] + sums[b + dy] + sums[b + dy + c]
               + sums[b + dz] + sums[b + dz + c] + sums[b + dz + dy] + sums[b + dz + dy + c])
    sums[dst_off + p] = acc


@wp.kernel
def pyramid_quantize_kernel(
    sums: wp.array(dtype=wp.uint32),
    off: int,  # first entry of the slab
    lc: int,  # log2 of its cell size
    total: int,
    out: wp.array(dtype=wp.uint8),  # (total,) rounded means
):
    """out[p] = floor((S + c^3/2) / c^3): the mean rounded half up (exact for c = 1)."""
    p = wp.tid()
    if p < total:
        sh = 3 * lc
        half = wp.uint32(0)
        if sh > 0:
            half = wp.uint32(1 << (sh - 1))
        out[p] = wp.uint8((sums[off + p] + half) >> wp.uint32(sh))


@wp.kernel
def pyramid_compare_kernel(
    sums: wp.array(dtype=wp.uint32),  # the global pyramid, log2(N) + 1 slabs
    total: int,  # entries per slab, Z * Y * X
    ny: int,
    nx: int,
    log_block: int,  # log2(N)
    node_base: wp.array(dtype=wp.int32),  # flat origin of each node's representative block
    node_code: wp.array(dtype=wp.int32),  # level * 2 + kind
    ids: wp.array(dtype=wp.int32),  # node ids to compare, from ids[first]
    first: int,
    count: int,
    query: wp.array(dtype=wp.int32),  # the query's cell sums, level after level
    query_off: wp.array(dtype=wp.int32),  # (L + 1,) start of level l at query_off[l - 1]
    out: wp.array(dtype=wp.int64),  # (count,) D per node
):
    """out[t] = sum over the n^3 cells of node ids[first + t]'s level of d^2, in integers.

    kind 0: d = Q - S (query and candidate cell sums); kind 1: d = the distance of Q
    to the interval of sums [lo, hi] that rounds to the candidate's uint8 mean.
    """
    t = wp.tid()
    if t >= count:
        return
    node = ids[first + t]
    code = node_code[node]
    lev = code >> 1
    kind = code & 1
    lc = log_block - (lev - 1)
    c = 1 << lc
    n = 1 << (lev - 1)
    yx = ny * nx
    base = lc * total + node_base[node]
    qb = query_off[lev - 1]
    sh = 3 * lc
    c3 = wp.int64(1) << wp.int64(sh)
    half = c3 >> wp.int64(1)
    cap = wp.int64(255) * c3
    acc = wp.int64(0)
    for i in range(n):
        for j in range(n):
            row = base + c * (i * yx + j * nx)
            qrow = qb + (i * n + j) * n
            for k in range(n):
                s = wp.int64(sums[row + c * k])
                q = wp.int64(query[qrow + k])
                d = q - s
                if kind != 0:
                    m = (s + half) >> wp.int64(sh)
                    lo = m * c3 - half
                    hi = m * c3 + half - wp.int64(1)
                    if lo < wp.int64(0):
                        lo = wp.int64(0)
                    if hi > cap:
                        hi = cap
                    d = wp.int64(0)
                    if q < lo:
                        d = lo - q
                    if q > hi:
                        d = q - hi
                acc += d * d
    out[t] = acc


@wp.kernel
def pyramid_hash_init_kernel(
    sums: wp.array(dtype=wp.uint32),
    off: int,  # first entry of the slab
    lc: int,  # log2 of its cell size
    quantized: int,  # 1: hash the rounded means, 0: the exact sums
    total: int,
    out: wp.array(dtype=wp.uint64),  # (total,)
):
    """out[p] = the value a level's hash is built from at position p."""
    p = wp.tid()
    if p < total:
        s = sums[off + p]
        if quantized != 0:
            sh = 3 * lc
            half = wp.uint32(0)
            if sh > 0:
                half = wp.uint32(1 << (sh - 1))
            s = (s + half) >> wp.uint32(sh)
        out[p] = wp.uint64(s) + wp.uint64(1)


@wp.kernel
def pyramid_hash_step_kernel(
    src: wp.array(dtype=wp.uint64),
    dst: wp.array(dtype=wp.uint64),
    total: int,
    stride: int,  # flat distance to the second half of the doubled window
    mult: wp.uint64,  # the hash weight of that half
):
    """dst[p] = src[p] + mult * src[p + stride] (mod 2^64); 0 past the end."""
    p = wp.tid()
    if p < total:
        v = wp.uint64(0)
        if p + stride < total:
            v = src[p] + mult * src[p + stride]
        dst[p] = v


@wp.kernel
def pyramid_pair_equal_kernel(
    sums: wp.array(dtype=wp.uint32),
    total: int,
    ny: int,
    nx: int,
    lc: int,  # log2 of the level's cell size
    n: int,  # cells per side at that level
    quantized: int,  # compare rounded means instead of exact sums
    base_a: wp.array(dtype=wp.int32),
    base_b: wp.array(dtype=wp.int32),
    count: int,
    out: wp.array(dtype=wp.int32),  # (count,) 1 where the two levels are identical
):
    """out[t] = 1 if the level of the blocks at base_a[t] and base_b[t] is identical."""
    t = wp.tid()
    if t >= count:
        return
    c = 1 << lc
    yx = ny * nx
    sh = 3 * lc
    half = wp.uint32(0)
    if sh > 0:
        half = wp.uint32(1 << (sh - 1))
    a = lc * total + base_a[t]
    b = lc * total + base_b[t]
    same = int(1)
    for i in range(n):
        for j in range(n):
            for k in range(n):
                o = c * (i * yx + j * nx + k)
                va = sums[a + o]
                vb = sums[b + o]
                if quantized != 0:
                    va = (va + half) >> wp.uint32(sh)
                    vb = (vb + half) >> wp.uint32(sh)
                if va != vb:
                    same = 0
    out[t] = same
