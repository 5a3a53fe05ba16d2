"""Which texel colours each point of one hierarchy level?

M3's point neighbourhood matching, level by level: Zhang, Qiu and Kaufman, "Fast Hybrid
Approach for Texturing Point Models", Sec. 4 (point neighbourhood matching), 4.1
(multi-resolution synthesis) and 4.2 (coherent synthesis).

- A point's irregular neighbourhood: its k nearest neighbours mapped onto its tangent
  plane by the patch mapping of the paper's Appendix A
  (:func:`geosynth.texturing.parameterize.tangent_offsets`), in texels, x along the frame's S axis
  and y along T; it is scored against every texel by :mod:`geosynth.texturing.texel_search`.
- Order: most coloured neighbours first. A batch takes the best points (coloured
  neighbours within MATCH_KEY_SLACK of the best and at least MATCH_KEY_FRACTION of it),
  none in another's k-neighbourhood, so colouring one cannot change another's query.
- Multiresolution: each finer level matches its coloured neighbours (texture level l)
  plus the coarser points of its neighbourhood (texture level l + 1), both in one call.
- Coherent mode: the candidates are only the texels that the sources of the coloured
  neighbours suggest (their source texel minus their offset), scored exactly in
  integers, so every device agrees. A level with no coarser one is matched whole in one
  kernel launch in the paper's sequential order (kernels/growth.py, ``match_coherent``);
  finer levels of a hierarchy score the batches' suggestions on the host, vectorized.
"""

from __future__ import annotations

import math

import numpy as np

from geosynth._backends.interfaces import MatchInputs, MatchScratch, MatchState
from geosynth.texturing.hierarchy import PointLevel
from geosynth.texturing.parameterize import growth_buckets, pick_batch, tangent_offsets
from geosynth.texturing.texel_search import TexelSearch, pixel_offsets, refine_shifts

__all__ = ["DEFAULT_MATCH_BATCH", "match_coherent_level", "match_level"]

# A matching batch takes points whose coloured-neighbour count is within MATCH_KEY_SLACK of
# the best and at least MATCH_KEY_FRACTION of it (early on, a 1-neighbour query is ambiguous).
# Measured on a 12k-point blob, 64^2 textures, opencl (eq. 5 error noise / bricks, points per
# launch, matching points/s): (0.75, 5): 55 / 588, 8, 3,300; (0.6, 8): 55 / 667, 17, 4,500-5,100;
# (0.5, 10): 57 / 648, 25, 5,700; (0.3, 25): 58 / 718, 33, 5,800-6,400.
MATCH_KEY_SLACK = 8
MATCH_KEY_FRACTION = 0.6
DEFAULT_MATCH_BATCH = 64  # points searched per launch (none in another's neighbourhood); 1: sequential


def _coarse_entries(level: PointLevel, coarse: PointLevel, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For the points ``centres``: the coarser points of their neighbourhoods (parents of
    each point and of its k neighbours, each once) and their texel offsets on its tangent
    plane. Returns (indices (c, k + 1) with -1 for repeats, offsets (c, k + 1, 2))."""
    par = level.parent[np.c_[centres, level.neighbours[centres]]]  # (c, k + 1)
    srt = np.sort(par, axis=1)
    first = np.ones(srt.shape, bool)
    first[:, 1:] = srt[:, 1:] != srt[:, :-1]
    idx = np.where(first, srt, -1)
    off = tangent_offsets(level.positions, level.s_axis, level.t_axis, level.normals, centres,
                          coarse.positions[np.maximum(idx, 0)], level.unit)
    return idx, off


def match_level(level: PointLevel, tex: np.ndarray, search: TexelSearch, colours: np.ndarray, coloured: np.ndarray,
                 source: np.ndarray, coarse: PointLevel | None, coarse_colours: np.ndarray | None,
                 coherent: bool, rng: np.random.Generator, progress: bool, desc: str, subtexel: bool = True,
                 batch: int = 64) -> int:
    """Colour every uncoloured point of a level by neighbourhood matching; returns the count coloured.

    Order: most coloured neighbours first (ties in a seeded random order). Each step takes
    up to ``batch`` of the best points (coloured-neighbour counts within MATCH_KEY_SLACK of
    the best and at least MATCH_KEY_FRACTION of it), none in another's k-neighbourhood, so
    that colouring one cannot change another's query, and searches them in one launch
    (``batch=1``: one :func:`geosynth.score_gather` call per point, the paper's sequential
    order). While nothing near is coloured (the very first point of a level without a
    coarser one) a single point takes a random texel. Coherent mode without a coarser
    level runs in one kernel launch (:func:`match_coherent_level`); with one, it scores
    each point's few suggested texels exactly on the host (vectorized over the batch) and
    searches every texel only for points whose neighbours suggest none.
    """
    n, k = level.neighbours.shape
    m = search.m
    todo = int(np.count_nonzero(~coloured))
    if todo == 0:
        return 0
    if coherent and coarse is None:
        return match_coherent_level(level, search, colours, coloured, source, rng, subtexel)
    # the irregular neighbourhoods of the points to colour (rows of other points stay 0)
    need = np.flatnonzero(~coloured)
    off_px = np.zeros((n, k, 2), np.int64)
    off_px[need] = pixel_offsets(tangent_offsets(level.positions, level.s_axis, level.t_axis, level.normals, need,
                                                 level.positions[level.neighbours[need]], level.unit), m)  # (dy, dx)
    if coarse is not None:
        c_idx = np.full((n, k + 1), -1, np.int64)
        c_px = np.zeros((n, k + 1, 2), np.int64)
        c_idx[need], c_off = _coarse_entries(level, coarse, need)
        c_px[need] = pixel_offsets(c_off, m)
    nb = level.neighbours
    key = np.zeros(n, np.int64)
    unc = np.flatnonzero(~coloured)
    key[unc] = coloured[nb[unc]].sum(1)
    rank = rng.permutation(n)
    blocked = np.zeros((n, 2), bool)
    h, w = tex.shape[:2]
    flat_tex = tex.reshape(-1, 3)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=todo, desc=desc, unit="pt", leave=False, mininterval=0.5)
    done = 0
    while done < todo:
        unc = np.flatnonzero(~coloured)
        kf = key[unc]
        best = int(kf.max())
        if best == 0 and coarse is None:
            chosen = unc[np.argmin(rank[unc])][None]
        else:
            top = unc[kf >= max(min(best, 1), best - MATCH_KEY_SLACK, math.ceil(MATCH_KEY_FRACTION * best))]
            top = top[np.lexsort((rank[top], -key[top]))]
            chosen = pick_batch(top, nb, blocked, batch) if batch > 1 else top[:1].astype(np.int64)
        # the batch's queries, packed: each point's coloured neighbours (dz = 0), then its
        # coarser points (dz = 1)
        nq = len(chosen)
        rows = nb[chosen]
        have = coloured[rows]
        f_off = off_px[chosen][have]
        f_val = colours[rows[have]]
        f_cnt = np.count_nonzero(have, axis=1)
        if coarse is not None:
            cm = c_idx[chosen] >= 0
            c_cnt = np.count_nonzero(cm, axis=1)
            owner = np.r_[np.repeat(np.arange(nq), f_cnt), np.repeat(np.arange(nq), c_cnt)]
            order = np.argsort(owner, kind="stable")
            offs = np.r_[np.c_[np.zeros(len(f_off), np.int64), f_off], np.c_[np.ones(int(c_cnt.sum()), np.int64),
                                                                               c_px[chosen][cm]]][order]
            vals = np.r_[f_val, coarse_colours[c_idx[chosen][cm]]][order]
            counts = f_cnt + c_cnt
        else:
            offs, vals, counts = f_off, f_val, f_cnt
        starts = np.cumsum(counts) - counts
        texels = np.full(nq, -1, np.int64)
        empty = counts == 0  # nothing coloured near and no coarser level: a random texel
        texels[empty] = rng.integers(0, h * w, int(empty.sum()))
        exhaustive = ~empty
        if coherent and exhaustive.any():
            # each coloured neighbour j at offset o_j suggests its source texel minus o_j
            src = np.where(have, source[rows], -1)  # (B, k)
            cy = src // w - np.rint(off_px[chosen][..., 0] / m).astype(np.int64)
            cx = src % w - np.rint(off_px[chosen][..., 1] / m).astype(np.int64)
            if search.tileable:
                cy, cx = cy % h, cx % w
            ok = (src >= 0) & (cy >= 0) & (cy < h) & (cx >= 0) & (cx < w) & exhaustive[:, None]
            n_cand = ok.sum(1)
            use = n_cand > 0
            if use.any():
                sel = np.repeat(use, counts)
                texels[use], _ = search.best_among_packed(offs[sel], vals[sel], counts[use], (cy * w + cx)[ok],
                                                          n_cand[use])
                exhaustive &= ~use
        if exhaustive.any():
            ex = np.flatnonzero(exhaustive)
            sel = np.repeat(exhaustive, counts)
            if batch > 1:
                texels[ex], _ = search.best_packed(offs[sel], vals[sel], counts[ex])
            else:
                sl = slice(starts[ex[0]], starts[ex[0]] + counts[ex[0]])
                texels[ex[0]], _ = search.best(offs[sl], vals[sl])
        cols = flat_tex[texels]
        if subtexel and (~empty).any():
            ne = np.flatnonzero(~empty)
            sel = np.repeat(~empty, counts)
            cols[ne] = search.refine_packed(offs[sel], vals[sel], counts[ne], texels[ne])
        colours[chosen] = cols
        source[chosen] = texels
        coloured[chosen] = True
        done += len(chosen)
        nbs = nb[chosen].reshape(-1)
        nbs = nbs[~coloured[nbs]]
        np.add.at(key, nbs, 1)
        if bar is not None:
            bar.update(len(chosen))
    if bar is not None:
        bar.close()
    return done


def match_coherent_level(level: PointLevel, search: TexelSearch, colours: np.ndarray, coloured: np.ndarray,
                          source: np.ndarray, rng: np.random.Generator, subtexel: bool) -> int:
    """Coherent matching of a level with no coarser one, in the paper's sequential order,
    in one kernel launch (kernels/growth.py, ``match_coherent``, gives the rules).
    Updates colours (n, 3) uint8, coloured (n,) bool and source (n,) int64 in place;
    returns the count coloured."""
    backend = search.device_grid.backend
    n, k = level.neighbours.shape
    todo = int(np.count_nonzero(~coloured))
    order = rng.permutation(n).astype(np.int32)
    rand_texel = rng.integers(0, search.h * search.w, n).astype(np.int32)
    dy1, dx1, ring = refine_shifts(search.m)
    n_buckets = growth_buckets(k)
    f64, i32 = np.float64, np.int32
    up = backend.to_device
    inputs = MatchInputs(*(up(np.ascontiguousarray(a, f64)) for a in
                           (level.positions, level.normals, level.s_axis, level.t_axis)),
                         up(level.neighbours.astype(i32, copy=False)))
    state = MatchState(up(coloured.astype(i32)), up(np.ascontiguousarray(colours, np.uint8)), up(source.astype(i32)))
    backend.match_coherent(n, k, inputs, level.unit, search.device_grid, search.host.shape[1], search.pad, search.m,
                           search.h, search.w, int(search.tileable), int(subtexel),
                           up(np.stack([dy1, dx1], 1).astype(i32).reshape(-1)), len(dy1), int(ring), up(order),
                           up(rand_texel), n_buckets, state, MatchScratch.allocate(backend, n, k, n_buckets))
    done = state.to_host(backend)
    coloured[:] = done["coloured"].astype(bool)
    colours[:] = done["colours"]
    source[:] = done["source"]
    return todo
