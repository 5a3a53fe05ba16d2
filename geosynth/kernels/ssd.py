"""How far is every candidate from a query, and which is nearest? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.3 (linear search), and Zhang, Qiu and Kaufman, "Fast Hybrid
Approach for Texturing Point Models", Sec. 4 (eq. 5).

Candidate SSD scoring and score selection: Warp kernels.

The twin of ``ssd.cl``: every kernel here has its meaning there, with the same
arguments in the same order (``argmin_partials_kernel`` <-> ``argmin_partials``). Where
ssd.cl splits one kernel's work in several ways for PoCL (``ssd_dense_kernel`` <->
``ssd_dense_rows`` / ``ssd_dense_tile``; ``ssd_gather_kernel`` <-> ``ssd_gather`` /
``ssd_gather_x16``), each variant computes the same result.
All arrays are flat (1D); sizes are passed explicitly. Kernels are generic over the
data type:

- float32 data -> float32 scores, weights float32;
- uint8 data -> uint32 scores, weights uint32, computed in integer arithmetic
  (exact; the caller guarantees the sum cannot overflow 32 bits).

Host wrappers live in ``geosynth._backends.warp_backend``; nothing here validates.
"""

from typing import Any

import warp as wp

# Selection modes shared with ssd.cl: which scores a threshold selects.
SELECT_LEQ = wp.constant(0)  # score <= thr
SELECT_LT = wp.constant(1)  # score <  thr
SELECT_EQ = wp.constant(2)  # score == thr
GATHER_CHUNK = wp.constant(256)  # entries between early-exit checks in ssd_gather (as in ssd.cl)


@wp.func
def sq_diff(a: wp.float32, b: wp.float32) -> wp.float32:
    d = a - b
    return d * d


@wp.func
def sq_diff(a: wp.uint8, b: wp.uint8) -> wp.uint32:  # noqa: F811 (overload by type)
    d = wp.int32(a) - wp.int32(b)
    return wp.uint32(d * d)


@wp.kernel
def ssd_dense_kernel(
    candidates: wp.array(dtype=Any),  # (n * d,) row-major (n, d)
    queries: wp.array(dtype=Any),  # (b * d,) row-major (b, d)
    weights: wp.array(dtype=Any),  # (d,) or a dummy when use_weights == 0
    use_weights: int,
    n: int,
    d: int,
    b: int,
    out: wp.array(dtype=Any),  # (b * n,) row-major (b, n)
):
    """out[q, i] = sum_k w[k] * (candidates[i, k] - queries[q, k])^2; one thread per (q, i)."""
    q, i = wp.tid()
    row = i * d
    qrow = q * d
    acc = out.dtype(0)
    if use_weights != 0:
        for k in range(d):
            acc += weights[k] * sq_diff(candidates[row + k], queries[qrow + k])
    else:
        for k in range(d):
            acc += sq_diff(candidates[row + k], queries[qrow + k])
    out[q * n + i] = acc


@wp.kernel
def ssd_gather_kernel(
    grid: wp.array(dtype=Any),  # the source grid, flat (z, y, x, c)
    bases: wp.array(dtype=wp.int32),  # explicit candidate base indices, or a dummy
    use_bases: int,
    nx: int,
    ny: int,
    nz: int,
    step_x: int,  # flat-index step between neighbouring lattice candidates along x
    step_y: int,
    step_z: int,
    base0: int,  # flat index of the first lattice candidate's origin
    offsets: wp.array(dtype=wp.int32),  # (kc,) flat offsets of the query entries
    values: wp.array(dtype=Any),  # (kc,) query values
    weights: wp.array(dtype=Any),  # (kc,) or a dummy when use_weights == 0
    use_weights: int,
    kc: int,
    threshold: wp.array(dtype=Any),  # (1,) same dtype as out
    use_threshold: int,
    out: wp.array(dtype=Any),  # (nz * ny * nx,) one score per candidate
):
    """out[c] = sum_j w[j] * (grid[base(c) + offsets[j]] - values[j])^2.

    Lattice mode (use_bases == 0): candidate (z, y, x) has base
    base0 + z*step_z + y*step_y + x*step_x. Explicit mode: launched as (1, 1, n)
    and base(c) = bases[c]. With use_threshold, a candidate whose partial sum passes
    threshold[0] (checked every GATHER_CHUNK entries) stops and reports it.
    """
    z, y, x = wp.tid()
    cand = (z * ny + y) * nx + x
    base = base0 + z * step_z + y * step_y + x * step_x
    if use_bases != 0:
        base = bases[cand]
    thr = threshold[0]
    acc = out.dtype(0)
    j0 = int(0)
    while j0 < kc:
        j1 = wp.min(j0 + GATHER_CHUNK, kc)
        if use_weights != 0:
            for j in range(j0, j1):
                acc += weights[j] * sq_diff(grid[base + offsets[j]], values[j])
        else:
            for j in range(j0, j1):
                acc += sq_diff(grid[base + offsets[j]], values[j])
        j0 = j1
        if use_threshold != 0 and acc > thr:
            j0 = kc
    out[cand] = acc


@wp.func
def score_ok(s: wp.float32) -> bool:
    return wp.isfinite(s)


@wp.func
def score_ok(s: wp.uint32) -> bool:  # noqa: F811 (overload by type)
    return True


@wp.kernel
def argmin_partials_kernel(
    scores: wp.array(dtype=Any),  # (n,)
    n: int,
    part_val: wp.array(dtype=Any),  # (g,) per-thread minimum
    part_idx: wp.array(dtype=wp.int32),  # (g,) lowest index reaching it, -1 if none, -2 if NaN/inf seen
    g: int,  # threads launched
):
    """Thread t scans t, t+g, t+2g, ... ascending, so a strict < keeps the lowest index."""
    t = wp.tid()
    best_idx = int(-1)
    best = part_val.dtype(0)
    ok = bool(True)
    i = t
    while i < n:
        s = scores[i]
        if not score_ok(s):
            ok = False
        if best_idx < 0 or s < best:
            best = s
            best_idx = i
        i += g
    part_val[t] = best
    if ok:
        part_idx[t] = best_idx
    else:
        part_idx[t] = -2


@wp.func
def is_selected(s: Any, thr: Any, mode: int) -> bool:
    if mode == SELECT_LEQ:
        return s <= thr
    if mode == SELECT_LT:
        return s < thr
    return s == thr


@wp.kernel
def count_selected_kernel(
    scores: wp.array(dtype=Any),  # (n,)
    n: int,
    chunk: int,  # thread t owns [t*chunk, (t+1)*chunk)
    thr: wp.array(dtype=Any),  # (1,) threshold, same dtype as scores
    mode: int,  # SELECT_LEQ, SELECT_LT or SELECT_EQ
    counts: wp.array(dtype=wp.int32),  # (g,)
    g: int,
):
    t = wp.tid()
    lo = t * chunk
    hi = wp.min(lo + chunk, n)
    th = thr[0]
    c = int(0)
    for i in range(lo, hi):
        if is_selected(scores[i], th, mode):
            c += 1
    counts[t] = c


@wp.kernel
def compact_selected_kernel(
    scores: wp.array(dtype=Any),
    n: int,
    chunk: int,
    thr: wp.array(dtype=Any),
    mode: int,
    starts: wp.array(dtype=wp.int32),  # (g,) exclusive prefix sum of counts
    out_idx: wp.array(dtype=wp.int32),  # (total,) selected indices, ascending
    g: int,
):
    t = wp.tid()
    lo = t * chunk
    hi = wp.min(lo + chunk, n)
    th = thr[0]
    w = starts[t]
    for i in range(lo, hi):
        if is_selected(scores[i], th, mode):
            out_idx[w] = i
            w += 1
