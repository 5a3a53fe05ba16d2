"""Which block is nearest, by bounds refined cell by cell? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.2 (eq. 2).

The fused cascade search (M1): Warp kernels.

The twin of ``cascade.cl``, with the same arguments in the same order
(``cascade_search_kernel`` <-> ``cascade_search``); cascade.cl says what the bounds
are and why the answer is exact. It serves :class:`geosynth.cascade_search.CascadeSearch`
(the lower bound of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 4.2, eq. 2,
over every block of the source). Arrays are flat; nothing here validates.
"""

import warp as wp

CASCADE_COARSE = 8  # coarse cells per block (side n/2), each split into 8 fine cells (side n/4)


@wp.func
def _cascade_block_ssd(
    field: wp.array(dtype=wp.uint8), base: int, n: int, sy: int, sz: int, query: wp.array(dtype=wp.uint8), limit: int
) -> int:
    """Exact SSD of the block at flat position base; stops (returning > limit) once above limit."""
    acc = int(0)
    for dz in range(n):
        for dy in range(n):
            p = base + dz * sz + dy * sy
            q = (dz * n + dy) * n
            for dx in range(n):
                e = int(field[p + dx]) - int(query[q + dx])
                acc += e * e
        if acc > limit:
            return acc
    return acc


@wp.kernel
def cascade_search_kernel(
    field: wp.array(dtype=wp.uint8),  # (Z*Y*X,) the source
    coarse: wp.array(dtype=wp.float32),  # sums of the (n/2)^3 cube at every position
    coarse_norm: wp.array(dtype=wp.float32),  # centred norms of the (n/2)^3 cube
    fine: wp.array(dtype=wp.float32),  # sums of the (n/4)^3 cube at every position
    lx: int,
    ly: int,
    lz: int,
    sy: int,
    sz: int,
    n: int,
    offsets: wp.array(dtype=wp.int32),  # 8 coarse, then 64 fine cell offsets grouped by coarse cell
    query_terms: wp.array(dtype=wp.float32),  # the query's 8 coarse sums, 8 coarse norms, 64 fine sums
    inv_c: float,  # 1 / (n/2)^3
    inv_f: float,  # 1 / (n/4)^3
    query: wp.array(dtype=wp.uint8),  # (n^3,)
    rows: int,
    margin: float,
    slack: float,
    best_shared: wp.array(dtype=wp.int32),  # (1,) best SSD found so far by any thread
    out: wp.array(dtype=wp.int32),  # (3 * threads,) best SSD, its lattice index (-1: none), blocks scored
):
    """The fused cascade search: thread t scans lattice rows [t*rows, (t+1)*rows) block by
    block (see ``cascade_search`` in cascade.cl for the bounds and why the answer is exact)."""
    item = wp.tid()
    r0 = item * rows
    r1 = wp.min(r0 + rows, ly * lz)
    best = int(2147483647)
    best_i = int(-1)
    scored = int(0)
    for r in range(r0, r1):
        z = r / ly
        row = z * sz + (r - z * ly) * sy
        for x in range(lx):
            t = wp.min(best, best_shared[0])
            lim = float(t) * margin + slack
            p = row + x
            bound = float(0.0)
            for j in range(CASCADE_COARSE):
                o = p + offsets[j]
                e = coarse[o] - query_terms[j]
                d = coarse_norm[o] - query_terms[CASCADE_COARSE + j]
                bound += e * e * inv_c + d * d
            alive = bound <= lim
            j = int(0)
            while alive and j < CASCADE_COARSE:
                o = p + offsets[j]
                e = coarse[o] - query_terms[j]
                d = coarse_norm[o] - query_terms[CASCADE_COARSE + j]
                acc = float(0.0)
                for i in range(CASCADE_COARSE):
                    k = CASCADE_COARSE * (j + 1) + i
                    f = fine[p + offsets[k]] - query_terms[CASCADE_COARSE + k]
                    acc += f * f
                bound += acc * inv_f - (e * e * inv_c + d * d)
                alive = bound <= lim
                j += 1
            if alive:
                s = _cascade_block_ssd(field, p, n, sy, sz, query, t)
                scored += 1
                if s <= t and s < best:  # exact (it ran to the end); a later index never wins a tie
                    best = s
                    best_i = r * lx + x
                    wp.atomic_min(best_shared, 0, s)
    out[3 * item] = best
    out[3 * item + 1] = best_i
    out[3 * item + 2] = scored
