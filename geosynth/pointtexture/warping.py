"""How is a pasted patch bent to fit its neighbourhood? The warping step of "Geometry
texture synthesis with point-set surfaces" (Sec. 5.2, warping).

A chosen patch F_k, translated into place, rarely fits the output's neighbourhood N_k
exactly. Its points S are paired with target points Q (cluster representatives of N_k's
points in the overlap) by an iterated greedy minimization of

    C(pi) = sum over pairs (s, q) of  c(s, q) + g(s, q, pi)                    (eq. 1)

with the pair cost (eq. 2)

    c(s, q) = w_p |p_s - p_q| + (w_n / 2)(1 - n_s . n_q) + w_v (v_s - v_q)^2

(v the surface variation of Pauly et al.: smallest PCA eigenvalue over their sum), a
pair being forbidden when a term is over its threshold, and the coherence term

    g(s, q, pi) = w_l sum_(t,r) f(q, r) | |p_s - p_t| - |p_q - p_r| |
                + (w_d / 2) sum_(t,r) f(q, r) (1 - (p_s - p_t).(p_q - p_r) / (|p_s - p_t| |p_q - p_r|))

over the pairs (t, r) of the previous pairing whose r is a neighbour of q in Q, with
``f(q, r) = phi(|p_q - p_r|) / sum_r phi(|p_q - p_r|)`` and phi a Gaussian. A thin-plate
spline through the pairs (plus fixed pairs mapping to themselves in the free corners of
the patch's box) then moves every point of F_k, and the normals follow the spline's
analytic Jacobian J: ``n' = (J u x J v) / |J u x J v|`` for tangents u, v of n.

Choices where the paper is vague (stated here once):

- Lengths in c and g are measured in units of ``length_unit`` spacings (32 by default,
  about a patch width: the paper's examples all had "about the same base dimensions",
  so its weights assume a fixed length scale). A position mismatch of one spacing then
  costs w_p / 32, a normal difference of 20 degrees w_n * 0.03.
- The greedy passes match edges in increasing order of cost (a pair is taken when it is
  the cheapest remaining for both its q and its s), not Q in an arbitrary order; equal
  costs are ordered by the seeded generator. A pass whose pairing costs more than the
  previous one is discarded and the iteration stops, so the reported cost never rises.
  An unpaired q costs ``miss_cost`` (the cost of a pair at every threshold) so that
  pairings with different numbers of pairs compare fairly.
- Q is the adaptive (hierarchical) clustering of Pauly et al. 2002: a cluster is split
  through its centroid across its principal axis while it holds more than
  ``cluster_size`` points or its surface variation exceeds 0.05; each cluster is
  represented by its point nearest the centroid. Targets whose neighbourhood is
  lopsided (the outskirts of N_k, where surface variation is unreliable) are left out.
- A corner of the box is free when no target lies within a quarter of the box's
  smaller side of it (horizontally); each free corner gets two fixed points, at the
  bottom and the top of the box.
- The spline keeps the patch's height scale (``keep_height_scale``, our change to the
  paper's spline): the pairs lie on a thin sheet of surface, where the spline's affine part
  is free to explain the two surfaces' height differences by a vertical scaling; two
  surfaces that match only approximately regress toward each other (correlation below 1),
  so the paper's spline squashes the patch's relief by about that correlation, also where
  the patch has no neighbour (zoo noise: heights 0.80 of the exemplar's). After the solve
  the affine part's z -> z term is set to 0 (heights neither squashed nor stretched); the
  rest of the spline still bends the patch toward N_k, and the blend closes what is left.
- The spline is smoothed (``smoothing`` 0.1, on the kernel's diagonal in units of the
  centres' extent; the paper interpolates): an interpolating spline pulls each paired
  point exactly onto its approximate partner and bends the patch between pairs (the
  built-ins' patch-field distances 10-40% lower smoothed, measured in bench/RESULTS.md).
- The spline is the 3D thin-plate kernel r^2 log r with an affine part; it maps
  displacements, so a degenerate set of pairs (all on one plane) is solved in the
  least-squares sense and leaves the undetermined direction unmoved.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from geosynth.compute.checks import as_points3, as_unit_vectors, check_positive
from geosynth.compute.host_steps import run_parts
from geosynth.core.exact import exp_fixed, log_fixed, round_log_f32, solve_fixed, sum_products_f32, times3x3

__all__ = [
    "WARP_PRESETS",
    "ThinPlateSpline",
    "WarpResult",
    "WarpWeights",
    "greedy_pairing",
    "surface_variation",
    "warp_patch",
]


@dataclass(frozen=True)
class WarpWeights:
    """The weights of eq. 2 and 3 and the thresholds that forbid a pair (Sec. 5.2).

    Attributes:
        w_p, w_n, w_v: position, normal and surface-variation weights of c (eq. 2).
        w_l, w_d: length and direction weights of the coherence term g.
        max_distance: a pair is forbidden when |p_s - p_q| > max_distance spacings.
        max_normal: forbidden when 1 - n_s . n_q > max_normal (1.0: more than 90 degrees apart).
        max_variation: forbidden when |v_s - v_q| > max_variation.
    """

    w_p: float = 1.0
    w_n: float = 1.0
    w_v: float = 10.0
    w_l: float = 8.0
    w_d: float = 6.0
    max_distance: float = 4.0
    max_normal: float = 1.0
    max_variation: float = 0.1

    def __post_init__(self):
        for name in ("w_p", "w_n", "w_v", "w_l", "w_d", "max_distance", "max_normal", "max_variation"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not (
                math.isfinite(float(v)) and float(v) >= 0
            ):
                raise ValueError(f"WarpWeights.{name} must be a finite number >= 0, got {v!r}.")
        if not self.max_distance > 0:
            raise ValueError(f"WarpWeights.max_distance must be > 0 (in spacings), got {self.max_distance!r}.")


# The paper's Table 1 weights (w_p = 1 throughout), as (w_p, w_n, w_v, w_l, w_d).
WARP_PRESETS: dict[str, WarpWeights] = {
    "heightfield": WarpWeights(1.0, 3.0, 30.0, 9.0, 7.0),
    "chainmail": WarpWeights(1.0, 1.0, 10.0, 8.0, 6.0),
    "weave": WarpWeights(1.0, 2.0, 15.0, 6.0, 5.0),
    "flowers": WarpWeights(1.0, 2.0, 2.0, 6.0, 6.0),
}


@dataclass(frozen=True)
class WarpResult:
    """What :func:`warp_patch` returns.

    Attributes:
        points: (S, 3) float64 warped source positions W(p_s).
        normals: (S, 3) float64 unit normals ``(J u x J v) / |J u x J v|``.
        pairs: (P, 2) int64 (source index, target index) of the final pairing.
        fixed: (F, 3) float64 fixed points (mapped to themselves) in free corners of the box.
        costs: the pairing cost C(pi) (eq. 1, unpaired q at ``miss_cost``) after the first
            greedy pass and after each kept later pass; never increasing.
        q_index: (|Q|,) int64 indices into the targets of the cluster representatives Q.
    """

    points: np.ndarray
    normals: np.ndarray
    pairs: np.ndarray
    fixed: np.ndarray
    costs: tuple[float, ...]
    q_index: np.ndarray


# ------------------------------------------------------------------------ input checks





class _KDTree:
    """k nearest neighbours in cKDTree's form: ``query(x, k, distance_upper_bound)`` ->
    ((m, k) float64 distances, (m, k) int64 indices; index len(points) and distance inf
    where fewer than k lie within the bound), nearest first, ties by lower index. By the
    compiled host step :func:`geosynth.pointtexture.blending.nearest_k` (exact in float64, split over
    the cores); on the built-ins' warp queries it gave pykdtree's indices and distances
    bit for bit (tests/test_warping.py compares them), about as fast on one thread (10,000
    points, 3,000 queries of 16: 5.3 ms against 6.0 ms with its tree), but it lets go of the
    GIL and splits over the cores."""

    def __init__(self, points: np.ndarray):
        self.points = np.ascontiguousarray(points, np.float64)
        self._grid = None  # the points' cell grid, built at the first query, kept for the next

    def query(self, x: np.ndarray, k: int = 1, distance_upper_bound: float | None = None):
        from geosynth.pointtexture.blending import knn_grid, nearest_k

        if self._grid is None and len(x):
            self._grid = knn_grid(self.points, int(k))
        return nearest_k(self.points, x, int(k), distance_upper_bound, grid=self._grid)


def _kdtree(points: np.ndarray) -> _KDTree:
    return _KDTree(points)



# ------------------------------------------------------------------------ surface variation


def surface_variation(points, k: int = 16) -> np.ndarray:
    """Surface variation of each point (Pauly et al. 2002, used by eq. 2 of Sec. 5.2):
    the smallest eigenvalue of the covariance of its k nearest neighbours (itself
    included) over the sum of the three; 0 on a plane, at most 1/3.

    Args:
        points: (N, 3) float positions.
        k: neighbours (itself included), clipped to N; >= 3.

    Returns:
        (N,) float64 in [0, 1/3] (0 where the neighbours coincide).
    """
    p = as_points3("points", points)
    if not isinstance(k, (int, np.integer)) or k < 3:
        raise ValueError(f"k must be an integer >= 3, got {k!r}.")
    if len(p) < 3:
        return np.zeros(len(p))
    k = int(min(k, len(p)))
    _, idx = _kdtree(p).query(p, k=k)
    return _variation_of(p, idx)


def _variation_of(p: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Surface variation of the neighbourhoods ``p[idx]`` ((n, 3) float64 points, (m, k)
    int indices): (m,) float64, the smallest eigenvalue of each covariance over its trace
    (Smith 1961's closed form), by the compiled host step ``host_warp.variation_kernel``;
    :func:`_variation_of_numpy` is its oracle."""
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels import host_warp

    idx = np.asarray(idx).reshape(len(idx), -1)
    out = np.empty(len(idx))
    host_launch(host_warp.variation_kernel, len(idx), [host_array(p, np.float64)[0], host_array(idx, np.int32)[0],
                                                       int(idx.shape[1]), host_array(out)[0]])
    return out


def _variation_of_numpy(p: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The NumPy form of :func:`_variation_of` (its oracle): the closed form for
    symmetric 3x3 matrices (Smith 1961), vectorized."""
    nb = p[idx]
    d = nb - nb.mean(axis=1, keepdims=True)
    a00, a11, a22 = (d[..., 0] ** 2).sum(1), (d[..., 1] ** 2).sum(1), (d[..., 2] ** 2).sum(1)
    a01, a02, a12 = (d[..., 0] * d[..., 1]).sum(1), (d[..., 0] * d[..., 2]).sum(1), (d[..., 1] * d[..., 2]).sum(1)
    trace = a00 + a11 + a22
    q = trace / 3.0
    p1 = a01 ** 2 + a02 ** 2 + a12 ** 2
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
    pp = np.sqrt(p2 / 6.0)
    safe = np.where(pp > 0, pp, 1.0)
    b00, b11, b22 = (a00 - q) / safe, (a11 - q) / safe, (a22 - q) / safe
    b01, b02, b12 = a01 / safe, a02 / safe, a12 / safe
    det = b00 * (b11 * b22 - b12 ** 2) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    smallest = np.where(pp > 0, q + 2.0 * pp * np.cos(phi + 2.0 * np.pi / 3.0), q)
    out = np.zeros(len(idx))
    ok = trace > 0
    out[ok] = np.clip(smallest[ok] / trace[ok], 0.0, 1.0 / 3.0)
    return out


# ------------------------------------------------------------------------ adaptive clustering


_CLUSTER_VARIATION = 0.05  # a cluster whose surface variation exceeds this is split
_CANDIDATES = 12  # the nearest sources considered per target of Q
_LOPSIDED = 0.6  # a target whose k-neighbour centroid is this far (x mean neighbour distance) is an outskirt


def _adaptive_clusters(p: np.ndarray, max_size: int, max_variation: float = _CLUSTER_VARIATION,
                       limit: int | None = None, fallback_size: int | None = None) -> np.ndarray | None:
    """Hierarchical clustering (Pauly et al. 2002) of (n, 3) float64 points ``p``, as
    :func:`_adaptive_clusters_numpy` (the oracle: the same arguments, the same result on
    points in general position), by the compiled host step
    ``host_warp.adaptive_clusters_kernel`` (one thread, depth first). Returns the sorted
    (m,) int64 indices of the clusters' representatives; with more than ``limit``
    clusters None, or with ``fallback_size`` the clustering by size alone (a second run
    of the kernel: it is cheap, and stops as soon as the first passes the limit).

    Where a point lies exactly on a splitting plane, or a cluster's principal axis is
    not unique (a double eigenvalue), the kernel's axis (closed-form eigenvalues, cross
    products for the vector) may differ from LAPACK's in sign or direction, and so may
    the split."""
    n = len(p)
    if n == 0:
        return np.zeros(0, np.int64)
    if fallback_size is not None and fallback_size < max_size:
        raise ValueError(f"fallback_size ({fallback_size}) must be >= max_size ({max_size}).")
    reps = _cluster_run(p, int(max_size), float(max_variation), -1 if limit is None else int(limit))
    if reps is None:
        if fallback_size is None:
            return None
        reps = _cluster_run(p, int(fallback_size), math.inf, -1)
    return np.sort(reps)


def _cluster_run(p: np.ndarray, max_size: int, max_variation: float, limit: int) -> np.ndarray | None:
    """One launch of ``adaptive_clusters_kernel``: the (m,) int64 representatives in no
    order, or None with more than ``limit >= 0`` clusters."""
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels import host_warp

    n = len(p)
    pw, _ = host_array(p, np.float64)
    perm, _perm = host_array(np.empty(n, np.int32))
    stack, _stack = host_array(np.empty(2 * n + 4, np.int32))
    reps_np = np.empty(n, np.int32)
    reps, _ = host_array(reps_np)
    count_np = np.zeros(1, np.int32)
    count, _ = host_array(count_np)
    host_launch(host_warp.adaptive_clusters_kernel, 1,
                [pw, n, max_size, max_variation, limit, perm, stack, reps, count])
    if count_np[0] < 0:
        return None
    return reps_np[:count_np[0]].astype(np.int64)


def _adaptive_clusters_numpy(p: np.ndarray, max_size: int, max_variation: float = _CLUSTER_VARIATION,
                             limit: int | None = None, fallback_size: int | None = None) -> np.ndarray | None:
    """The NumPy form of :func:`_adaptive_clusters` (its oracle). Hierarchical clustering (Pauly et al. 2002): clusters are split through their
    centroid across their principal axis while they hold more than ``max_size`` points
    or their surface variation exceeds ``max_variation`` (and they hold more than 2).
    Returns the index of each cluster's representative (its member nearest the
    centroid, the lowest index on ties), sorted.

    With more than ``limit`` clusters: None, or with ``fallback_size`` the clustering by
    size alone (split while more than ``fallback_size >= max_size`` points). Both come
    from one pass: a cluster's split depends only on its points, and every cluster the
    size-only clustering splits (more than fallback_size points) the first one splits
    too, so the fallback's clusters are nodes of the first one's split tree; the pass
    keeps a second label per point for them and, once the first clustering is over
    the limit, goes on splitting only those. The same representatives as two runs."""
    n = len(p)
    if n == 0:
        return np.zeros(0, np.int64)
    if fallback_size is not None and fallback_size < max_size:
        raise ValueError(f"fallback_size ({fallback_size}) must be >= max_size ({max_size}).")
    labels = np.zeros(n, np.int64)  # the finest clusters so far (the first clustering's while it is kept)
    fallback = np.zeros(n, np.int64) if fallback_size is not None else None  # the size-only clustering's
    frozen = np.zeros(1, bool)  # clusters whose points cannot be split (coincident along the axis)
    in_fallback = np.ones(1, bool)  # clusters (of labels) that are clusters of the fallback too
    first_kept = True  # the first clustering is within the limit so far

    # A cluster that is not split in a round keeps its points, so it is never split later:
    # each round looks only at the points of the clusters the previous round split (in
    # ascending order, so that every cluster's sums run over the same points in the same
    # order as over all points: the same bits).
    active = np.arange(n)
    cols = [np.ascontiguousarray(p[:, j]) for j in range(3)]
    while active.size:
        # ids (ascending) and each active point's rank among them: np.unique's, without a sort
        lab = labels[active]
        present = np.zeros(len(frozen), bool)
        present[lab] = True
        ids = np.flatnonzero(present)
        m = len(ids)
        local = (np.cumsum(present) - 1)[lab]
        counts = np.bincount(local, minlength=m).astype(np.float64)
        ca = [c[active] for c in cols]
        mean = [np.bincount(local, c, m) / counts for c in ca]
        dc = [c - mu[local] for c, mu in zip(ca, mean)]  # columns of p - centroid
        cov = np.empty((m, 3, 3))
        for i in range(3):
            for j in range(i, 3):
                cov[:, i, j] = cov[:, j, i] = np.bincount(local, dc[i] * dc[j], m)
        vals, vecs = np.linalg.eigh(cov)
        total = vals.sum(axis=1)
        var = np.where(total > 0, np.clip(vals[:, 0], 0, None) / np.where(total > 0, total, 1), 0.0)
        open_ = ~frozen[ids]
        split_first = open_ & ((counts > max_size) | ((var > max_variation) & (counts > 2))) if first_kept \
            else np.zeros(m, bool)
        split_fallback = open_ & in_fallback[ids] & (counts > fallback_size) if fallback is not None \
            else np.zeros(m, bool)
        split = split_first | split_fallback
        if not split.any():
            break
        positive = np.einsum("ij,ij->i", np.stack(dc, 1), vecs[:, :, 2][local]) > 0
        n_pos = np.bincount(local[positive], minlength=m)
        real = split & (n_pos > 0) & (n_pos < counts)
        frozen[ids[split & ~real]] = True
        n_new = int(real.sum())
        new_id = np.full(m, -1, np.int64)
        new_id[real] = len(frozen) + np.arange(n_new)
        move = real[local] & positive
        labels[active[move]] = new_id[local[move]]
        if fallback is not None:
            move_fb = move & split_fallback[local]
            fallback[active[move_fb]] = new_id[local[move_fb]]
        # both halves of a fallback split are fallback clusters; of a split the fallback
        # does not make, neither (the unsplit parent is)
        in_fallback[ids[real & ~split_fallback]] = False
        in_fallback = np.concatenate([in_fallback, split_fallback[real]])
        frozen = np.concatenate([frozen, np.zeros(n_new, bool)])
        if first_kept and limit is not None and len(frozen) > limit:
            if fallback is None:
                return None
            first_kept = False
        keep = real if first_kept else real & split_fallback
        active = active[keep[local]]
    return _representatives(p, labels if first_kept else fallback)


def _representatives(p: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Each cluster's member nearest its centroid (the lowest index on ties), sorted."""
    n = len(p)
    _, labels = np.unique(labels, return_inverse=True)
    n_clusters = int(labels.max()) + 1
    counts = np.bincount(labels, minlength=n_clusters).astype(np.float64)
    mean = np.stack([np.bincount(labels, p[:, j], n_clusters) for j in range(3)], 1) / counts[:, None]
    dist = np.linalg.norm(p - mean[labels], axis=1)
    order = np.lexsort((np.arange(n), dist, labels))  # by cluster, then distance, then index
    first = np.ones(n, bool)
    first[1:] = labels[order][1:] != labels[order][:-1]
    return np.sort(order[first])


# ------------------------------------------------------------------------ greedy pairing


def _greedy_match_numpy(eq: np.ndarray, es: np.ndarray, order: np.ndarray) -> np.ndarray:
    """The NumPy form of the greedy scan of ``host_warp.greedy_pairing_kernel`` (its
    oracle, used by ``_greedy_pairing(..., numpy_oracle=True)``): the indices of the edges the
    sequential greedy takes when it scans the edges in the given ``order`` (a
    permutation) and keeps each whose q and s are both unused, in scan order.

    Vectorized: an edge that is the first remaining one for its q and for its s is
    taken by the scan; remove the edges touching those, repeat."""
    eq, es = eq[order], es[order]
    alive = np.arange(len(order))
    taken = []
    if not alive.size:
        return np.zeros(0, np.int64)
    n_q, n_s = int(eq.max()) + 1, int(es.max()) + 1
    first_q, first_s = np.empty(n_q, np.int64), np.empty(n_s, np.int64)
    while alive.size:
        q, s = eq[alive], es[alive]
        rank = np.arange(alive.size)
        # the first remaining edge of each q and of each s (np.minimum.at: no sort)
        first_q.fill(alive.size)
        np.minimum.at(first_q, q, rank)
        first_s.fill(alive.size)
        np.minimum.at(first_s, s, rank)
        win = (first_q[q] == rank) & (first_s[s] == rank)
        taken.append(alive[win])
        used_q = np.zeros(n_q, bool)
        used_q[q[win]] = True
        used_s = np.zeros(n_s, bool)
        used_s[s[win]] = True
        alive = alive[~(used_q[q] | used_s[s])]
    return order[np.sort(np.concatenate(taken))] if taken else np.zeros(0, np.int64)


def _greedy_passes(eq, es, c, tie, ps, pq, rn, phi, kr: int, length_weight: float, direction_weight: float,
                   miss: float, iterations: int) -> tuple[np.ndarray, tuple[float, ...]]:
    """The passes of the greedy pairing in one launch of ``host_warp.greedy_pairing_kernel``.

    Args:
        eq, es: (E,) int target and source of each allowed edge; c: (E,) float64 its cost
            c(s, q); tie: (E,) int seeded permutation ordering equal costs.
        ps, pq: (S, 3), (|Q|, 3) float64 positions; rn, phi: (|Q|, kr) the neighbours r of
            each q in Q and their Gaussian weights.
        length_weight, direction_weight: w_l / unit and w_d / 2 of g; miss: the cost of
            an unpaired q; iterations: passes after the first.

    Returns:
        ``(sel, costs)``: (P,) int64 the kept pairing's edges in scan order, and C after
        each kept pass.
    """
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels import host_warp

    n_e, n_q = len(eq), len(pq)
    if n_e == 0:
        return np.zeros(0, np.int64), (float(miss * n_q),)
    i32 = lambda a: host_array(a, np.int32)[0]  # noqa: E731
    f64 = lambda a: host_array(a, np.float64)[0]  # noqa: E731
    q_to_r = pq[:, None, :] - pq[rn] if kr > 0 else np.zeros((n_q, 0, 3))  # (|Q|, kr, 3)
    q_to_r_len = np.sqrt(np.einsum("qkj,qkj->qk", q_to_r, q_to_r))
    sel_np = np.empty(n_e, np.int32)
    costs_np = np.empty(iterations + 1)
    counts_np = np.zeros(2, np.int32)
    by_tie = np.argsort(tie)  # the edge of each tie rank (tie is a permutation)
    args = [i32(eq), i32(es), f64(c), i32(by_tie), n_e, f64(ps), n_q, i32(rn), f64(phi), f64(q_to_r), f64(q_to_r_len),
            int(kr), float(length_weight), float(direction_weight), float(miss), int(iterations),
            f64(np.empty(n_e)), f64(np.empty(n_e)), f64(np.empty(n_e)), i32(np.empty(n_e, np.int32)),
            i32(np.empty(n_e, np.int32)), i32(np.full(n_q, -1, np.int32)), i32(np.full(n_q, -1, np.int32)),
            i32(np.empty(n_q, np.int32)), i32(np.empty(max(n_q * kr, 1), np.int32)), f64(np.empty(max(n_q * kr, 1))),
            i32(np.zeros(n_q, np.int32)),
            i32(np.zeros(len(ps), np.int32)), i32(np.empty(n_e, np.int32)),
            host_array(sel_np)[0], host_array(costs_np)[0], host_array(counts_np)[0]]
    host_launch(host_warp.greedy_pairing_kernel, 1, args)
    return sel_np[:counts_np[0]].astype(np.int64), tuple(float(v) for v in costs_np[:counts_np[1]])


def greedy_pairing(
    ps, ns, vs, pq, nq, vq, weights: WarpWeights, spacing: float, rng: np.random.Generator, *,
    iterations: int = 3, candidates: int = 12, length_unit: float = 32.0, neighbours: int = 8,
) -> tuple[np.ndarray, tuple[float, ...]]:
    """The iterated greedy pairing of Sec. 5.2 between sources S and targets Q.

    Args:
        ps, ns, vs: (S, 3) positions, (S, 3) unit normals, (S,) surface variation of S.
        pq, nq, vq: the same for Q.
        weights: the weights and thresholds (:class:`WarpWeights`).
        spacing: the point spacing (world units); thresholds are in spacings.
        rng: orders equal costs.
        iterations: greedy passes with the coherence term after the first (paper step 6).
        candidates: the nearest sources considered per q.
        length_unit: the unit of the lengths in c and g, in spacings.
        neighbours: the pairs (t, r) with r among q's nearest ``neighbours`` in Q enter g.

    Returns:
        ``(pairs, costs)``: (P, 2) int64 (source index, target index) sorted by target,
        and the cost C(pi) after each kept pass (non-increasing).
    """
    return _greedy_pairing(ps, ns, vs, pq, nq, vq, weights, spacing, rng, iterations=iterations,
                           candidates=candidates, length_unit=length_unit, neighbours=neighbours)


def _greedy_pairing(
    ps, ns, vs, pq, nq, vq, weights: WarpWeights, spacing: float, rng: np.random.Generator, *,
    iterations: int = 3, candidates: int = 12, length_unit: float = 32.0, neighbours: int = 8,
    numpy_oracle: bool = False,
) -> tuple[np.ndarray, tuple[float, ...]]:
    """:func:`greedy_pairing`. The candidate edges and their costs c are found here
    (k-d tree, NumPy); the passes (sort by cost, greedy scan, coherence term g of every
    edge, pairing cost C) run in one launch of the compiled host step
    ``host_warp.greedy_pairing_kernel`` or, with ``numpy_oracle``, in NumPy (the oracle:
    the same pairs and costs to rounding, except where rounding decides between two
    pairings of nearly equal cost)."""
    w = weights
    n_s, n_q = len(ps), len(pq)
    if n_s == 0 or n_q == 0:
        return np.zeros((0, 2), np.int64), (0.0,)
    unit = length_unit * spacing
    k = int(min(candidates, n_s))
    dist, idx = _kdtree(ps).query(pq, k=k, distance_upper_bound=w.max_distance * spacing)
    dist, idx = dist.reshape(n_q, k), idx.reshape(n_q, k)
    ok = idx < n_s
    eq = np.repeat(np.arange(n_q), k)[ok.ravel()]
    es = idx.ravel()[ok.ravel()]
    d = dist.ravel()[ok.ravel()]
    dn = 1.0 - np.einsum("ij,ij->i", ns[es], nq[eq])
    dv = np.abs(vs[es] - vq[eq])
    allowed = (dn <= w.max_normal) & (dv <= w.max_variation)
    eq, es, d, dn, dv = eq[allowed], es[allowed], d[allowed], dn[allowed], dv[allowed]
    c = w.w_p * d / unit + 0.5 * w.w_n * dn + w.w_v * dv * dv
    miss = w.w_p * w.max_distance / length_unit + 0.5 * w.w_n * w.max_normal + w.w_v * w.max_variation**2 + w.w_d
    tie = rng.permutation(len(c)) if len(c) else np.zeros(0, np.int64)

    # The neighbours r of each q in Q and their Gaussian weights.
    kr = int(min(neighbours, n_q - 1))
    if kr > 0:
        rd, rn = _kdtree(pq).query(pq, k=kr + 1)
        rd, rn = rd[:, 1:].reshape(n_q, kr), rn[:, 1:].reshape(n_q, kr)
        sigma = max(float(np.median(rd[:, 0])) * 1.5, spacing)
        phi = exp_fixed(-0.5 * (rd / sigma) ** 2)  # (not np.exp: its bits depend on the CPU)
    else:
        rn = np.zeros((n_q, 0), np.int64)
        phi = np.zeros((n_q, 0))

    # What g reads per edge and does not change between passes: q's neighbours r, p_s,
    # and p_q - p_r with its length.
    if numpy_oracle:
        rn_e = rn[eq]  # (E, kr)
        ps_e = ps[es][:, None, :]  # (E, 1, 3)
        q_to_r = pq[eq][:, None, :] - pq[rn_e] if kr > 0 else np.zeros((len(eq), 0, 3))
        q_to_r_len = np.linalg.norm(q_to_r, axis=2)

    def coherence_numpy(partner):
        """g of every edge given ``partner`` (source of each q, -1 if none), (E,)."""
        if kr == 0 or len(eq) == 0:
            return np.zeros(len(eq))
        # f(q, r) depends on q and the pairing only: computed per q, then read per edge
        t_q = partner[rn]  # (|Q|, kr)
        wgt = phi * (t_q >= 0)
        tot = wgt.sum(axis=1, keepdims=True)
        f = np.divide(wgt, tot, out=np.zeros_like(wgt), where=tot > 0)[eq]  # (E, kr)
        a = ps_e - ps[np.maximum(t_q, 0)][eq]  # p_s - p_t, (E, kr, 3)
        b, lb = q_to_r, q_to_r_len  # p_q - p_r
        sq = a * a
        la = np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])  # np.linalg.norm's sums, without its overhead
        lab = la * lb
        cos = np.divide(np.einsum("ekj,ekj->ek", a, b), lab, out=np.zeros_like(la), where=lab > 0)
        return (w.w_l * (f * np.abs(la - lb)).sum(axis=1) / unit + 0.5 * w.w_d * (f * (1.0 - cos)).sum(axis=1))

    def pairing_cost(sel, g):
        return float((c[sel] + g[sel]).sum() + miss * (n_q - len(sel)))

    def partner_of(sel):
        partner = np.full(n_q, -1, np.int64)
        partner[eq[sel]] = es[sel]
        return partner

    if numpy_oracle:
        # g of every edge is computed once per pairing: the next pass's edge costs and this
        # pairing's cost C both read it.
        sel = _greedy_match_numpy(eq, es, np.lexsort((tie, c)))
        g = coherence_numpy(partner_of(sel))
        costs = [pairing_cost(sel, g)]
        for _ in range(int(iterations)):
            new_sel = _greedy_match_numpy(eq, es, np.lexsort((tie, c + g)))
            if np.array_equal(new_sel, sel):
                break
            new_g = coherence_numpy(partner_of(new_sel))
            cost = pairing_cost(new_sel, new_g)
            if cost > costs[-1]:
                break
            sel, g = new_sel, new_g
            costs.append(cost)
    else:
        sel, costs = _greedy_passes(eq, es, c, tie, ps, pq, rn, phi, kr, w.w_l / unit, 0.5 * w.w_d, miss, int(iterations))
    pairs = np.stack([es[sel], eq[sel]], 1).astype(np.int64)
    return pairs[np.argsort(pairs[:, 1], kind="stable")], tuple(costs)


# ------------------------------------------------------------------------ thin-plate spline


class ThinPlateSpline:
    """A 3D thin-plate spline W(x) = x + sum_i w_i phi(|x - c_i|) + a_0 + A x, phi(r) = r^2 log r,
    through ``W(c_i) = y_i`` (the interpolation of Sec. 5.2; the spline's linear system
    solved by :func:`solve_fixed`), with its analytic Jacobian. With dtype float32 (the
    warp's) the result is the same bits on every CPU (see :meth:`_rows_f32`); float64 is
    the evaluation's oracle (BLAS products: its last bits depend on the CPU).

    Args:
        centres: (n, 3) float positions c_i.
        values: (n, 3) float targets y_i.
        smoothing: lambda added to the kernel's diagonal (0: interpolating).
        dtype: float type of the evaluation's kernel matrices (the solve is float64):
            np.float64, or np.float32, about 3x faster and within ~1e-6 of the patch
            size (the warp uses it: a thousandth of a spacing).
    """

    # Rows per evaluation step: 256 keeps the step's three (256, |Q|) float32 matrices
    # (~200 KB each at |Q| = 200) in the L2 cache; 1,024 rows (before) took ~20% longer.
    # (float64 evaluation: OpenBLAS's products round a row differently with other row counts.)
    _CHUNK = 256
    # r^2 (in units of the centres' extent) at or below which an evaluation point counts
    # as a centre (r = 0): above the product's rounding, below any real spacing.
    _AT_CENTRE = 1e-12

    def __init__(self, centres, values, smoothing: float = 0.0, dtype=np.float64):
        import scipy.linalg

        if np.dtype(dtype) not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise ValueError(f"dtype must be np.float32 or np.float64, got {dtype!r}.")
        self.dtype = np.dtype(dtype).type
        self.degenerate = False  # solved by least squares (see below)

        c = as_points3("centres", centres)
        y = as_points3("values", values, len(c))
        self.shift = c.mean(axis=0) if len(c) else np.zeros(3)
        extent = float(np.ptp(c, axis=0).max()) if len(c) else 0.0
        self.scale = extent if extent > 0 else 1.0
        self.centres = (c - self.shift) / self.scale
        disp = (y - c) / self.scale
        n = len(c)
        if n == 0:
            self.w = np.zeros((0, 3))
            self.affine = np.zeros((4, 3))
            return
        r2 = self._r2(self.centres, self.centres)
        kmat = 0.5 * r2 * log_fixed(np.where(r2 > 0, r2, 1.0))  # _phi, with a log of the same bits on every CPU
        system = np.zeros((n + 4, n + 4))
        system[:n, :n] = kmat + float(smoothing) * np.eye(n)
        system[:n, n] = system[n, :n] = 1.0
        system[:n, n + 1:] = self.centres
        system[n + 1:, :n] = self.centres.T
        rhs = np.zeros((n + 4, 3))
        rhs[:n] = disp
        # By elimination in fixed-order elementwise arithmetic, not LAPACK: its blocked kernels
        # round differently on every CPU (SSE4, AVX2, AVX-512), and the output must not.
        sol = solve_fixed(system, rhs)
        if sol is None:
            # Degenerate pairs (fewer than 4, or all on one plane): the least-squares
            # solution of least norm leaves the undetermined directions unmoved. (LAPACK's
            # SVD: these rare splines' bits may depend on the CPU; the built-ins meet none.)
            self.degenerate = True
            sol = scipy.linalg.lstsq(system, rhs, cond=1e-10, check_finite=False)[0]
        self.w = sol[:n]
        self.affine = sol[n:]  # row 0: a_0; rows 1-3: A (x, y, z) -> displacement

    @staticmethod
    def _r2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(len(a), len(b)) squared distances, summed x, y, z in that order (in place: one
        temporary instead of five)."""
        r2 = np.empty((len(a), len(b)), np.result_type(a, b))
        ThinPlateSpline._r2_into(a, [b[:, j] for j in range(3)], r2, np.empty_like(r2))
        return r2

    @staticmethod
    def _r2_into(a: np.ndarray, b_cols: list[np.ndarray], out: np.ndarray, tmp: np.ndarray) -> None:
        """:meth:`_r2` of a (m, 3) against the columns (x, y, z; each (n,)) of b, written into
        ``out`` ((m, n), a's dtype) with ``tmp`` (same shape) as scratch: the same sums."""
        np.subtract.outer(a[:, 0], b_cols[0], out=out)
        np.square(out, out=out)
        for j in (1, 2):
            np.subtract.outer(a[:, j], b_cols[j], out=tmp)
            np.square(tmp, out=tmp)
            out += tmp

    @staticmethod
    def _phi(r2: np.ndarray) -> np.ndarray:
        return 0.5 * r2 * np.log(np.where(r2 > 0, r2, 1.0))  # r^2 log r, 0 at r = 0

    def _eval(self, x: np.ndarray, want_jacobian: bool):
        """W(x) ((m, 3) float64) and, if wanted, the Jacobians ((m, 3, 3) float64)."""
        points, u, sums12 = self._eval_sums(x, want_jacobian)
        jac = None
        if want_jacobian:
            pp = sums12.astype(np.float64)
            jac = u[:, None, :] * pp[:, :3, None] - pp[:, 3:].reshape(len(u), 3, 3)
            jac += self.affine[1:].T[None] + np.eye(3)[None]
        return points, jac

    def _eval_sums(self, x: np.ndarray, want_sums: bool):
        """W(x) ((m, 3) float64), the normalized points u ((m, 3) float64) and, if wanted,
        the Jacobian's kernel sums ((m, 12), the evaluation's dtype): sum_i psi_i w_ik
        (k < 3), then sum_i psi_i w_ik c_ij at 3 + 3 k + j (psi = 2 log r + 1, 0 at r = 0)."""
        u = (x - self.shift) / self.scale
        if len(self.centres) == 0:
            disp = self.affine[0] + times3x3(u, self.affine[1:])
            return x + disp * self.scale, u, np.zeros((len(x), 12), self.dtype) if want_sums else None
        dt = self.dtype
        n = len(self.centres)
        want_jacobian = want_sums
        w = self.w.astype(dt)
        wc = (self.w[:, :, None] * self.centres[:, None, :]).reshape(n, 9)  # w_ik c_ij
        w12 = np.concatenate([self.w, wc], axis=1).astype(dt)  # one product gives sum psi w and sum psi w c
        # r^2 = |u|^2 + |c|^2 - 2 u.c as one float64 product of (m, 5) [u, |u|^2, 1] by (5, n)
        # [-2 c; 1; |c|^2]: one pass instead of eight (differences, squares, sums). Its
        # rounding (~1e-16 of the unit box) is far below float32's; where u is a centre it
        # leaves ~1e-16 instead of 0, so entries r^2 <= _AT_CENTRE count as r = 0.
        u_aug = np.empty((len(u), 5))
        u_aug[:, :3] = u
        u_aug[:, 3] = np.einsum("ij,ij->i", u, u)
        u_aug[:, 4] = 1.0
        c_aug = np.empty((5, n))
        c_aug[:3] = -2.0 * self.centres.T
        c_aug[3] = 1.0
        c_aug[4] = np.einsum("ij,ij->i", self.centres, self.centres)
        # per point: sum_i phi_i w_i (3) and sum_i psi_i w_ik, sum_i psi_i w_ik c_ij (12),
        # assembled into displacements (and Jacobians) once after the loop
        sums3 = np.empty((len(u), 3), dt)
        sums12 = np.empty((len(u), 12), dt) if want_jacobian else None

        def rows_of(first: int, last: int) -> None:
            # The (chunk, n) matrices are made once per part and reused by its chunks: a
            # fresh array per step cost page faults beside the passes of arithmetic.
            rows = min(self._CHUNK, last - first)
            r2_64 = np.empty((rows, n))
            r2_buf = r2_64 if dt is np.float64 else np.empty((rows, n), dt)
            log_buf = np.empty((rows, n), dt)
            near_buf = np.empty((rows, n), bool)
            for lo in range(first, last, self._CHUNK):
                m = min(self._CHUNK, last - lo)
                r2, log_r2, near = r2_buf[:m], log_buf[:m], near_buf[:m]
                np.matmul(u_aug[lo:lo + m], c_aug, out=r2_64[:m])
                np.less_equal(r2_64[:m], self._AT_CENTRE, out=near)
                at_centre = np.flatnonzero(near)  # a few entries: the points that are centres
                if r2 is not r2_64[:m]:
                    np.copyto(r2, r2_64[:m], casting="same_kind")
                # r^2 = 1 there gives log 0, so 2 phi = r^2 log r^2 = 0; psi is zeroed below
                r2.flat[at_centre] = 1.0
                np.log(r2, out=log_r2)  # log r^2
                np.multiply(r2, log_r2, out=r2)  # r2 now holds 2 phi = r^2 log r^2 (0 at r = 0)
                np.matmul(r2, w, out=sums3[lo:lo + m])
                if want_jacobian:
                    # d/dx phi(|x - c|) = (x - c)(2 log r + 1), 0 at r = 0.
                    log_r2 += dt(1.0)
                    log_r2.flat[at_centre] = 0.0  # psi
                    np.matmul(log_r2, w12, out=sums12[lo:lo + m])

        if dt is np.float32:
            rows_of = self._rows_f32(u, sums3, sums12)
        # Parts of whole chunks on every core (NumPy lets go of the GIL in these passes and
        # products): each chunk's rows are computed as alone, so the bits do not depend on it.
        run_parts(rows_of, len(u), quantum=self._CHUNK, min_part=4 * self._CHUNK)
        disp = dt(0.5) * sums3 + self.affine[0] + times3x3(u, self.affine[1:])
        return x + disp * self.scale, u, sums12

    def _rows_f32(self, u: np.ndarray, sums3: np.ndarray, sums12: np.ndarray | None):
        """The float32 evaluation's step over rows [first, last) (see :meth:`_eval_sums`),
        the same bits on every CPU (the warp's: M2's output must not depend on the machine):

        - r^2 by differences in float64 (elementwise: correctly rounded on every SIMD path;
          exactly 0 where u is a centre);
        - log r^2 in float64 by NumPy, rounded to float32; NumPy's float64 log may round a
          last bit differently by CPU (AVX-512), so the rare entry within 16 float64 ulps of
          a float32 rounding boundary is recomputed by the scalar ``math.log`` first:
          :func:`round_log_f32`;
        - phi = r^2 log r^2 and psi = log r^2 + 1 in float32 (elementwise);
        - the sums over the centres by a float64 product of the float32 matrices (each
          product exact in float64, the sum within gamma_n of exact in any order: BLAS may
          sum in any order), rounded once to float32; the rare sum within twice that bound
          of a float32 rounding boundary is summed again in a fixed order first
          (:func:`sum_products_f32`). Either way every CPU rounds to the same float32."""
        n = len(self.centres)
        cols = [np.ascontiguousarray(self.centres[:, j]) for j in range(3)]
        w = self.w.astype(np.float32).astype(np.float64)  # the float32 weights, exactly
        wc = (self.w[:, :, None] * self.centres[:, None, :]).reshape(n, 9)
        w12 = np.concatenate([self.w, wc], axis=1).astype(np.float32).astype(np.float64)
        at_centre = self._AT_CENTRE

        def rows_of(first: int, last: int) -> None:
            rows = min(self._CHUNK, last - first)
            r2_buf = np.empty((rows, n))
            tmp_buf = np.empty((rows, n))
            near_buf = np.empty((rows, n), bool)
            for lo in range(first, last, self._CHUNK):
                m = min(self._CHUNK, last - lo)
                r2, tmp, near = r2_buf[:m], tmp_buf[:m], near_buf[:m]
                self._r2_into(u[lo:lo + m], cols, r2, tmp)
                np.less_equal(r2, at_centre, out=near)
                centre = np.flatnonzero(near)
                r2.flat[centre] = 1.0  # log 0 there: 2 phi = r^2 log r^2 = 0, psi zeroed below
                log32 = round_log_f32(r2, tmp)
                phi = r2.astype(np.float32)
                phi *= log32  # 2 phi
                sum_products_f32(phi, w, sums3[lo:lo + m])
                if sums12 is not None:
                    log32 += np.float32(1.0)
                    log32.flat[centre] = 0.0  # psi
                    sum_products_f32(log32, w12, sums12[lo:lo + m])
        return rows_of

    def _eval_single(self, x: np.ndarray, want_jacobian: bool):
        # thin products: one BLAS thread is faster and thread-count independent (geometry_texture says why)
        with _blas_controller().limit(limits=1, user_api="blas"):
            return self._eval(x, want_jacobian)

    def __call__(self, points) -> np.ndarray:
        """W at (m, 3) points: (m, 3) float64."""
        return self._eval_single(as_points3("points", points), False)[0]

    def jacobian(self, points) -> np.ndarray:
        """The analytic Jacobian dW/dx at (m, 3) points: (m, 3, 3) float64, J[m, k, j] = dW_k/dx_j."""
        return self._eval_single(as_points3("points", points), True)[1]

    def transform(self, points, normals) -> tuple[np.ndarray, np.ndarray]:
        """W(p) and the normals ``(J u x J v) / |J u x J v|`` (u, v orthonormal tangents
        of n, so that the result keeps n's side): (m, 3) float64 each. A normal whose
        tangents the Jacobian collapses keeps its direction."""
        p = as_points3("points", points)
        n = as_unit_vectors("normals", as_points3("normals", normals, len(p)))
        return self._transform_checked(p, n)

    def _transform_checked(self, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`transform` of checked (m, 3) float64 points and unit normals. With float32
        kernel matrices the Jacobians are assembled from the kernel sums inside the compiled
        host step ``host_warp.spline_normals_kernel`` (no (m, 3, 3) array); else as
        :func:`_jacobian_normals` of :meth:`jacobian` (the oracle)."""
        if self.dtype is not np.float32:
            wp, jac = self._eval_single(p, True)
            return wp, _jacobian_normals(jac, n)
        from geosynth.compute.host_steps import host_array, host_launch
        from geosynth.kernels import host_warp

        with _blas_controller().limit(limits=1, user_api="blas"):
            wp, u, sums12 = self._eval_sums(p, True)
        out = np.empty((len(p), 3))
        host_launch(host_warp.spline_normals_kernel, len(p), [
            host_array(u, np.float64)[0], host_array(sums12, np.float32)[0], host_array(self.affine, np.float64)[0],
            host_array(n, np.float64)[0], host_array(out)[0]])
        return wp, out


def _jacobian_normals(jac: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The warped normals ``(J u x J v) / |J u x J v|`` ((m, 3) float64) from the Jacobians
    ``jac`` ((m, 3, 3), J[m, k, j] = dW_k/dx_j) and unit normals ``n`` ((m, 3)), with u, v
    the tangents of :func:`_tangents`; n where the Jacobian collapses them (|J u x J v| <
    1e-12). The compiled host step ``host_warp.jacobian_normals_kernel``;
    :func:`_jacobian_normals_numpy` is its oracle."""
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels import host_warp

    out = np.empty((len(n), 3))
    jw, _j = host_array(jac, np.float64)
    nw, _n = host_array(n, np.float64)
    ow, _ = host_array(out)
    host_launch(host_warp.jacobian_normals_kernel, len(n), [jw, nw, ow])
    return out


def _jacobian_normals_numpy(jac: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The NumPy form of :func:`_jacobian_normals` (its oracle)."""
    u, v = _tangents(n)
    cross = np.cross(np.einsum("mkj,mj->mk", jac, u), np.einsum("mkj,mj->mk", jac, v))
    length = np.linalg.norm(cross, axis=1)
    bad = length < 1e-12
    cross[bad] = n[bad]
    length[bad] = 1.0
    return cross / length[:, None]


@functools.lru_cache(maxsize=1)
def _blas_controller():
    """One threadpoolctl controller for every spline evaluation: ``threadpool_limits`` scans
    the process's loaded libraries on each call (about 2 ms, once a patch: 0.1-0.2 s of a
    Table 1 row); a controller scans once. Made after scipy.linalg is loaded (by the first
    spline), so that SciPy's OpenBLAS is among the libraries it limits."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def _tangents(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal u, v with u x v = n for unit normals n (m, 3)."""
    helper = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(helper, n)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(n, u)
    return u, v


# ------------------------------------------------------------------------ the warp


def _free_corners(target: np.ndarray, box_min: np.ndarray, box_max: np.ndarray, z_lo: float, z_hi: float) -> np.ndarray:
    ext = box_max[:2] - box_min[:2]
    radius = 0.25 * float(ext.min())
    corners = np.array([[box_min[0], box_min[1]], [box_max[0], box_min[1]],
                        [box_min[0], box_max[1]], [box_max[0], box_max[1]]])
    if len(target):
        # the nearest target of each corner, horizontally: 4 x T squared distances directly
        # (a k-d tree over the targets cost more to build than this)
        dx = target[None, :, 0] - corners[:, 0, None]
        dy = target[None, :, 1] - corners[:, 1, None]
        d = np.sqrt((dx * dx + dy * dy).min(axis=1))
        free = corners[d > radius]
    else:
        free = corners
    return np.concatenate([np.c_[free, np.full(len(free), z_lo)], np.c_[free, np.full(len(free), z_hi)]])


def _neighbour_mean(p: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``p[idx].mean(axis=1)`` for (m, k) neighbour indices: (m, 3) float64, the same bits
    (NumPy reduces that middle axis neighbour by neighbour, 0, 1, ..., k - 1; so does this,
    tests/test_warping.py checks it), a coordinate at a time from contiguous columns, without
    the (m, k, 3) copy."""
    out = np.empty((len(idx), 3))
    for j in range(3):
        g = np.ascontiguousarray(p[:, j])[idx]  # (m, k)
        acc = g[:, 0].copy()
        for i in range(1, idx.shape[1]):
            acc += g[:, i]
        out[:, j] = acc
    return out / idx.shape[1]


def _outskirts(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Targets whose k-neighbour centroid lies far from them (boundary of the set):
    ((n,) bool outskirt flags, (n, k) int64 the neighbour indices), for (n, 3) float64
    points. The k-d tree query, then the compiled host step ``host_warp.outskirts_kernel``;
    :func:`_outskirts_numpy` is its oracle."""
    from geosynth.compute.host_steps import host_array, host_launch
    from geosynth.kernels import host_warp

    k = int(min(k, len(p)))
    dist, idx = _kdtree(p).query(p, k=k)
    dist, idx = dist.reshape(len(p), k), idx.reshape(len(p), k)
    flags = np.empty(len(p), np.int32)
    host_launch(host_warp.outskirts_kernel, len(p), [host_array(p, np.float64)[0], host_array(dist, np.float64)[0],
                                                     host_array(idx, np.int32)[0], k, _LOPSIDED, host_array(flags)[0]])
    return flags.astype(bool), idx


def _outskirts_numpy(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy form of :func:`_outskirts` (its oracle)."""
    k = int(min(k, len(p)))
    dist, idx = _kdtree(p).query(p, k=k)
    dist, idx = dist.reshape(len(p), k), idx.reshape(len(p), k)
    offset = np.linalg.norm(_neighbour_mean(p, idx) - p, axis=1)
    mean_d = dist[:, 1:].mean(axis=1) if k > 1 else np.zeros(len(p))
    return offset > _LOPSIDED * mean_d, idx


def warp_patch(
    src_points,
    src_normals,
    target_points,
    target_normals,
    box_min,
    box_max,
    weights: WarpWeights,
    spacing: float,
    rng: np.random.Generator,
    *,
    src_variation=None,
    target_variation=None,
    iterations: int = 3,
    cluster_size: int = 12,
    max_pairs: int = 200,
    fixed_corners: bool = True,
    length_unit: float = 32.0,
    smoothing: float = 0.1,
    keep_height_scale: bool = True,
) -> WarpResult:
    """Warp a pasted patch F_k to fit the output's neighbourhood N_k (Sec. 5.2).

    Args:
        src_points, src_normals: (S, 3) float F_k (patch and extra region, already
            translated into place, extended a little beyond the box so that the box
            stays covered after warping); normals need not be unit length.
        target_points, target_normals: (T, 3) float, the output's points of N_k in the
            overlap (T may be 0: the identity warp).
        box_min, box_max: (3,) F_k's box B_k (x, y; z for the fixed corner points).
        weights: :class:`WarpWeights` (see :data:`WARP_PRESETS`).
        spacing: the exemplar's mean nearest-neighbour distance (world units, > 0).
        rng: a seeded NumPy generator (orders equal pair costs).
        src_variation, target_variation: (S,) / (T,) surface variation when already
            known (else computed here from 16 neighbours).
        iterations: greedy passes with the coherence term after the first.
        cluster_size: most points per adaptive cluster of Q (|Q| is about T / cluster_size
            and never more than S).
        max_pairs: the most targets in Q; larger clusters are used until |Q| fits
            (the spline's cost grows as S x |Q|).
        fixed_corners: add pairs mapping to themselves in the box's free corners.
        length_unit: the unit of lengths in the costs, in spacings.
        smoothing: thin-plate smoothing, >= 0 (0 interpolates the pairs: the paper's spline).
        keep_height_scale: drop the spline's vertical scaling (see the module docstring);
            False: the paper's spline.

    Returns:
        :class:`WarpResult`, in output coordinates.

    Raises:
        ValueError / TypeError: bad shapes, NaN, zero normals, spacing <= 0, a box with
            no horizontal extent.
    """
    ps = as_points3("src_points", src_points)
    ns = as_unit_vectors("src_normals", as_points3("src_normals", src_normals, len(ps)))
    pt = as_points3("target_points", target_points)
    nt = as_unit_vectors("target_normals", as_points3("target_normals", target_normals, len(pt))) if len(pt) else np.zeros((0, 3))
    spacing = check_positive("spacing", spacing)
    lo = np.asarray(box_min, np.float64).reshape(-1)
    hi = np.asarray(box_max, np.float64).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise ValueError(f"box_min and box_max must be finite (3,) arrays, got shapes {lo.shape} and {hi.shape}.")
    if not (hi[:2] > lo[:2]).all():
        raise ValueError(f"the box must have a positive x and y extent, got box_min {lo} and box_max {hi}.")
    if not isinstance(weights, WarpWeights):
        raise TypeError(f"weights must be a WarpWeights (see WARP_PRESETS), got {type(weights).__name__}.")
    if not isinstance(cluster_size, (int, np.integer)) or cluster_size < 1:
        raise ValueError(f"cluster_size must be an integer >= 1, got {cluster_size!r}.")
    if not isinstance(max_pairs, (int, np.integer)) or max_pairs < 1:
        raise ValueError(f"max_pairs must be an integer >= 1, got {max_pairs!r}.")
    if isinstance(smoothing, bool) or not isinstance(smoothing, (int, float, np.integer, np.floating)) or not (
            math.isfinite(float(smoothing)) and float(smoothing) >= 0):
        raise ValueError(f"smoothing must be a finite number >= 0, got {smoothing!r}.")
    empty = np.zeros(0, np.int64)
    if len(ps) == 0 or len(pt) == 0:
        return WarpResult(ps.copy(), ns.copy(), np.zeros((0, 2), np.int64), np.zeros((0, 3)), (0.0,), empty)

    k_var = 16
    if len(pt) >= 3:
        outskirt, t_idx = _outskirts(pt, k_var)
        core = np.flatnonzero(~outskirt)
        if core.size == 0:
            core = np.arange(len(pt))
    else:
        t_idx = None
        core = np.arange(len(pt))
    # Start from the cluster size that fits max_pairs, at least cluster_size; if the
    # variation criterion still makes too many clusters, cluster by size alone, then
    # keep an even draw of max_pairs of them.
    size = max(int(cluster_size), int(math.ceil(len(core) / max_pairs)))
    # (the first clustering stops as soon as it passes max_pairs: the second one is used then)
    q_local = _adaptive_clusters(pt[core], size, _CLUSTER_VARIATION, limit=max_pairs,
                                 fallback_size=max(size, int(math.ceil(1.5 * len(core) / max_pairs))))
    if len(q_local) > max_pairs:
        q_local = q_local[np.sort(rng.choice(len(q_local), max_pairs, replace=False))]
    q_index = core[q_local]
    if len(q_index) > len(ps):  # |Q| <= |S|
        q_index = q_index[np.sort(rng.choice(len(q_index), len(ps), replace=False))]
    pq = pt[q_index]
    # Surface variation where the pairing reads it: Q, and the sources near Q.
    if target_variation is not None:
        vq = _checked_variation("target_variation", target_variation, len(pt))[q_index]
    else:
        vq = _variation_of(pt, t_idx[q_index]) if t_idx is not None else np.zeros(len(q_index))
    if src_variation is not None:
        vs = _checked_variation("src_variation", src_variation, len(ps))
    else:
        vs = np.zeros(len(ps))
        if len(ps) >= 3:
            tree = _kdtree(ps)
            k = int(min(_CANDIDATES, len(ps)))
            near = tree.query(pq, k=k, distance_upper_bound=weights.max_distance * spacing)[1].reshape(-1)
            near = np.unique(near[near < len(ps)])
            if near.size:
                vs[near] = _variation_of(ps, tree.query(ps[near], k=int(min(k_var, len(ps))))[1])

    pairs_q, costs = greedy_pairing(ps, ns, vs, pq, nt[q_index], vq, weights, spacing, rng,
                                    iterations=iterations, candidates=_CANDIDATES, length_unit=length_unit)
    pairs = np.stack([pairs_q[:, 0], q_index[pairs_q[:, 1]]], 1) if len(pairs_q) else np.zeros((0, 2), np.int64)

    z_lo = float(min(lo[2], ps[:, 2].min()))
    z_hi = float(max(hi[2], ps[:, 2].max()))
    if z_hi - z_lo < spacing:
        z_lo, z_hi = z_lo - spacing, z_hi + spacing
    fixed = _free_corners(pt, lo, hi, z_lo, z_hi) if fixed_corners else np.zeros((0, 3))
    if len(pairs) == 0:
        return WarpResult(ps.copy(), ns.copy(), pairs, fixed, costs, q_index)
    centres = np.concatenate([ps[pairs[:, 0]], fixed])
    values = np.concatenate([pt[pairs[:, 1]], fixed])
    spline = ThinPlateSpline(centres, values, smoothing=float(smoothing), dtype=np.float32)
    if keep_height_scale:
        spline.affine[3, 2] = 0.0  # no z -> z term: the relief's heights keep their scale
    wp, wn = spline._transform_checked(ps, ns)
    return WarpResult(wp, wn, pairs, fixed, costs, q_index)


def _checked_variation(name: str, v, n: int) -> np.ndarray:
    a = np.asarray(v, np.float64).reshape(-1)
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {np.shape(v)}.")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} holds NaN or inf values.")
    return a
