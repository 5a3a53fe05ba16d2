"""Which block is nearest, by bounds refined cell by cell? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.2 (eq. 2).

The fused cascade search (M1): Warp kernels.

The twin of ``cascade.cl``, with the same arguments in the same order
(``cascade_search_kernel`` <-> ``cascade_search``); cascade.cl says what the bounds
are and why the answer is exact. It serves :class:`geosynth.volume.cascade.CascadeSearch`
(the lower bound of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 4.2, eq. 2,
over every block of the source). Arrays are flat; nothing here validates.
"""

import warp as wp

CASCADE_COARSE = 8  # coarse cells per block (side n/2), each split into 8 fine cells (side n/4)


@wp.func
def _cascade_block_ssd(
    field: wp.array(dtype=wp.uint8), base: int, n: int, sy: int, sz: int, query: wp.array(dtype=wp.uint8),
    q0: int, limit: int
) -> int:
    """Exact SSD of the block at flat position base against the query at query[q0:];
    stops (returning > limit) once above limit."""
    acc = int(0)
    for dz in range(n):
        for dy in range(n):
            p = base + dz * sz + dy * sy
            q = q0 + (dz * n + dy) * n
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
    query_terms: wp.array(dtype=wp.float32),  # per query: 8 coarse sums, 8 coarse norms, 64 fine sums
    inv_c: float,  # 1 / (n/2)^3
    inv_f: float,  # 1 / (n/4)^3
    queries: wp.array(dtype=wp.uint8),  # (n_queries * n^3,)
    rows: int,
    items: int,  # threads per query
    n_queries: int,
    margin: float,
    slack: float,
    best_all: wp.array(dtype=wp.int32),  # (n_queries,) per query the best SSD found so far by any of its threads
    out: wp.array(dtype=wp.int32),  # (3 * items * n_queries,) best SSD, its lattice index (-1: none), blocks scored
):
    """The fused cascade search of a batch of queries: thread g serves query q = g / items
    and scans lattice rows [t*rows, (t+1)*rows), t = g - q*items, block by block (see
    ``cascade_search`` in cascade.cl for the bounds and why the answer is exact)."""
    gid = wp.tid()
    qi = gid / items
    r0 = (gid - qi * items) * rows
    r1 = wp.min(r0 + rows, ly * lz)
    t0 = qi * 10 * CASCADE_COARSE  # the query's terms
    q0 = qi * n * n * n  # the query's samples
    best = int(2147483647)
    best_i = int(-1)
    scored = int(0)
    for r in range(r0, r1):
        z = r / ly
        row = z * sz + (r - z * ly) * sy
        for x in range(lx):
            t = wp.min(best, best_all[qi])
            lim = float(t) * margin + slack
            p = row + x
            bound = float(0.0)
            for j in range(CASCADE_COARSE):
                o = p + offsets[j]
                e = coarse[o] - query_terms[t0 + j]
                d = coarse_norm[o] - query_terms[t0 + CASCADE_COARSE + j]
                bound += e * e * inv_c + d * d
            alive = bound <= lim
            j = int(0)
            while alive and j < CASCADE_COARSE:
                o = p + offsets[j]
                e = coarse[o] - query_terms[t0 + j]
                d = coarse_norm[o] - query_terms[t0 + CASCADE_COARSE + j]
                acc = float(0.0)
                for i in range(CASCADE_COARSE):
                    k = CASCADE_COARSE * (j + 1) + i
                    f = fine[p + offsets[k]] - query_terms[t0 + CASCADE_COARSE + k]
                    acc += f * f
                bound += acc * inv_f - (e * e * inv_c + d * d)
                alive = bound <= lim
                j += 1
            if alive:
                s = _cascade_block_ssd(field, p, n, sy, sz, queries, q0, t)
                scored += 1
                if s <= t and s < best:  # exact (it ran to the end); a later index never wins a tie
                    best = s
                    best_i = r * lx + x
                    wp.atomic_min(best_all, qi, s)
    out[3 * gid] = best
    out[3 * gid + 1] = best_i
    out[3 * gid + 2] = scored
