"""M3: texturing point models from a sample texture (Zhang, Qiu and Kaufman, "Fast hybrid
approach for texturing point models"): point parameterization, point neighbourhood
matching, and the hybrid of the two. :func:`texture_points` is the API.

Point neighbourhood matching (paper Sec. 4):

- The irregular neighbourhood of a point: its k nearest neighbours mapped onto its
  tangent plane by the patch mapping of Appendix A (:func:`neighbourhood_offsets`), in
  texels, x along the frame's S axis and y along T (frames from an up vector, or a
  random direction; in the hybrid, the patches' own frames).
- The texture is supersampled m times (bilinear, m = 8 by default) so that a lookup
  rounds to the nearest supersampled pixel: offsets become integer pixel offsets
  ``rint(m * offset)``; only the original texels (stride m) are candidates.
- Eq. 5, ``E(t) = sum_j |I(t + offset_j) - colour_j|^2`` over the coloured neighbours,
  for every candidate texel t, on the device, in uint8 data: exact integer scores, the
  same on every device; the lowest score wins, the lowest texel index on ties. One query
  is one :func:`geosynth.score_gather` call (``batch=1``); by default up to 64 queries go
  in one launch of the batched kernel pair ``kernels/texel.py`` / ``kernels/texel.cl``
  (measured: score_gather + argmin costs ~0.6-1.3 ms per call whatever the work, so one
  call per point caps matching near 1,000 points/s).
- Order: most coloured neighbours first. A batch takes the best points (coloured
  neighbours within MATCH_KEY_SLACK of the best and at least MATCH_KEY_FRACTION of it),
  none in another's k-neighbourhood, so colouring one cannot change another's query.
- Sub-texel refinement (our addition, ``subtexel=True``): the chosen texel's colour is
  replaced by the supersampled pixel within half a texel that matches best, so a point
  that sits between texel centres of its window gets the colour there.
- Multiresolution: a point hierarchy by greedy 4-point clustering (next: the
  unclustered point with the most clustered neighbours) and a texture pyramid of the
  same depth. The coarsest level is coloured randomly; each finer level matches its
  coloured neighbours (texture level l) plus the coarser points of its neighbourhood
  (texture level l + 1), both in one call: the two supersampled levels are the two
  z-slices of one 3D grid and the coarse entries carry dz = 1.
- Coherent mode: the candidates are only the texels that the sources of the coloured
  neighbours suggest (their source texel minus their offset), scored exactly in
  integers, so every device agrees. A level with no coarser one (one level, or the
  coarsest matched level) is matched whole in one kernel launch in the paper's
  sequential order, tangent-plane offsets, suggestions, scores and sub-texel refinement
  included (kernels/growth.py, ``match_coherent``); finer levels of a hierarchy score
  the batches' suggestions on the host, vectorized.

Hybrid (Sec. 5): the parameterization colours the patch points; gaps are widened
towards the texture's pattern size (each round turns every patch point in the
k-neighbourhood of a gap point into a gap point, about sqrt(k) wider); matching then
colours the gaps, a coarse point counting as coloured iff all its fine points are.

Candidate windows: the supersampled grid is padded by R pixels (R a multiple of m that
covers every offset of the level; periodically for tileable textures, by the edge
texels otherwise). For score_gather every query carries two zero-weight entries at
(-R, -R) and (R, R), so the lattice of candidate origins is exactly the texel centres and
the padded grid is uploaded once (``wrap=True`` would pad and cache one copy per distinct
reach of the offsets). The batched kernel reads a copy in phase-plane layout (channel,
z, y % m, x % m, y // m, x // m): consecutive texels are consecutive bytes, one 16-byte
load per entry and strip of 16 texels.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from geosynth.parameterize import (
    DEFAULT_THRESHOLD, DEFAULT_WEIGHTS, GAP, CheckedModel, _as_model, check_k, check_up, colour_parameterization,
    frames_from_up, mean_spacing, neighbourhood_offsets, parameterize_with_device_arrays, propagate,
)
from geosynth.pointsets import PointSet
from geosynth.textures import as_texture, sample_bilinear_grid, texture_pyramid

__all__ = [
    "METHODS", "PointLevel", "TextureReport", "TexelSearch", "build_hierarchy", "neighbourhood_error",
    "texture_points",
]

METHODS = ("param", "match", "hybrid")
DEFAULT_M = 8  # supersampling factor: the paper finds m = 8 as good as bilinear lookups
MAX_REACH_TEXELS = 48  # neighbourhood offsets beyond this many texels are clipped (outliers of sparse regions)
# A matching batch takes points whose coloured-neighbour count is within MATCH_KEY_SLACK of
# the best and at least MATCH_KEY_FRACTION of it (early on, a 1-neighbour query is ambiguous).
# Measured on a 12k-point blob, 64^2 textures, opencl (eq. 5 error noise / bricks, points per
# launch, matching points/s): (0.75, 5): 55 / 588, 8, 3,300; (0.6, 8): 55 / 667, 17, 4,500-5,100;
# (0.5, 10): 57 / 648, 25, 5,700; (0.3, 25): 58 / 718, 33, 5,800-6,400.
MATCH_KEY_SLACK = 8
MATCH_KEY_FRACTION = 0.6
DEFAULT_MATCH_BATCH = 64  # points searched per launch (none in another's neighbourhood); 1: sequential
QUALITY_ROTATIONS = 8  # the quality error takes the best of this many neighbourhood rotations (45 degree steps)


# ------------------------------------------------------------------ the texel search (eq. 5)


def _pack(queries: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A list of (offsets (K_b, nd), values (K_b, 3)) queries as (offsets (E, nd), values (E, 3), counts (B,))."""
    offs = np.concatenate([np.asarray(o, np.int64) for o, _ in queries])
    vals = np.concatenate([np.asarray(v, np.uint8).reshape(-1, 3) for _, v in queries])
    return offs, vals, np.array([len(o) for o, _ in queries], np.int64)


class TexelSearch:
    """Eq. 5 over every texel of one texture level, on a device.

    The m-times supersampled level (and, with ``coarse``, the next coarser level
    resampled onto the same pixels as a second z-slice) is padded, uploaded once and
    kept on the device; each :meth:`best` is one :func:`geosynth.score_gather` call
    plus a device argmin, :meth:`best_batch` one launch of the batched kernel pair for
    many queries (same answers), :meth:`best_among` and :meth:`refine` exact host
    searches over a few candidates.

    Args:
        texture: (H, W, 3) uint8 texture of this level.
        coarse: None, or the (H // 2, W // 2, 3) next pyramid level.
        m: supersampling factor.
        reach: the largest |offset| (in texels) a query will use; offsets are clipped to it.
        tileable: periodic texture (else its edge texels extend outwards).
        device: a device string.
    """

    def __init__(self, texture: np.ndarray, coarse: np.ndarray | None, m: int, reach: float, tileable: bool,
                 device: str | None):
        import geosynth

        self.texture = texture
        self.h, self.w = texture.shape[:2]
        self.m = int(m)
        self.pad = self.m * int(min(math.ceil(max(reach, 1.0)) + 1, MAX_REACH_TEXELS))
        self.tileable = tileable
        yy = np.arange(self.m * self.h, dtype=np.float64) / self.m
        xx = np.arange(self.m * self.w, dtype=np.float64) / self.m
        slices = [sample_bilinear_grid(texture, yy, xx, tileable)]
        if coarse is not None:  # coarse texel i covers fine texels 2i, 2i + 1: centre at 2i + 0.5
            slices.append(sample_bilinear_grid(coarse, (yy - 0.5) / 2, (xx - 0.5) / 2, tileable))
        grid = np.clip(np.rint(np.stack(slices)), 0, 255).astype(np.uint8)  # (Z, mH, mW, 3)
        pad = ((0, 0), (self.pad, self.pad), (self.pad, self.pad), (0, 0))
        grid = np.pad(grid, pad, mode="wrap" if tileable else "edge")
        self.host = grid if coarse is not None else grid[0]
        self.nd = 3 if coarse is not None else 2
        self.device_grid = geosynth.to_device(np.ascontiguousarray(self.host), device if device else "auto")
        self.device = self.device_grid.backend.name
        self.phase_grid = None  # the batched kernel's layout, uploaded on first use
        self.phase_dims = (0, 0)
        self._scratch = None  # batched scores, reused across launches
        self.searches = 0  # queries answered on the device
        self.launches = 0  # device launches (score_gather calls or batches)
        self.seconds = 0.0

    def _query(self, offsets_px: np.ndarray, values: np.ndarray):
        r = self.pad
        off = np.clip(offsets_px, -r, r)
        if self.nd == 3:
            dummies = np.array([[0, -r, -r], [1, r, r]], np.int64)
        else:
            dummies = np.array([[-r, -r], [r, r]], np.int64)
        off = np.concatenate([off, dummies])
        vals = np.concatenate([values, np.zeros((2, 3), np.uint8)])
        wts = np.ones(len(off), np.uint32)
        wts[-2:] = 0
        return off, vals, wts

    def scores(self, offsets_px: np.ndarray, values: np.ndarray):
        """Eq. 5 for every texel, as a DeviceArray of (H * W,) uint32 (texel index y * W + x).

        Args:
            offsets_px: (K, 2) (dy, dx) or, with a coarse slice, (K, 3) (dz, dy, dx)
                supersampled-pixel offsets, dz = 0 for this level and 1 for the coarse one.
            values: (K, 3) uint8 colours.
        """
        import geosynth

        off, vals, wts = self._query(np.asarray(offsets_px, np.int64), np.asarray(values, np.uint8))
        return geosynth.score_gather(self.device_grid, off, vals, wts, stride=(2, self.m, self.m)[-self.nd:],
                                     keep_on_device=True)

    def best(self, offsets_px: np.ndarray, values: np.ndarray) -> tuple[int, int]:
        """The texel of least eq. 5 error (lowest index on ties) and that error."""
        t0 = time.perf_counter()
        s = self.scores(offsets_px, values)
        idx, score = s.backend.argmin(s)  # sync: one index and its score come back
        self.searches += 1
        self.launches += 1
        self.seconds += time.perf_counter() - t0
        return int(idx), int(score)

    def best_batch(self, queries: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 5 of several queries against every texel in one launch (our batching):
        the batched twin of :meth:`best`, same answers (lowest index on ties).

        Args:
            queries: B pairs (offsets_px (K_b, nd) int, values (K_b, 3) uint8), K_b >= 1.

        Returns:
            (texel indices (B,) int64, errors (B,) int64).
        """
        return self.best_packed(*_pack(queries))

    def best_packed(self, offsets: np.ndarray, values: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`best_batch` of packed queries: offsets (E, nd) and values (E, 3) grouped by
        query, counts (B,) entries per query (each >= 1)."""
        t0 = time.perf_counter()
        backend = self.device_grid.backend
        r, m = self.pad, self.m
        if self.phase_grid is None:
            # Phase-plane layout for the batch kernel: pixel (y, x) of the padded grid goes to
            # plane (y % m, x % m) at (y // m, x // m), so the texel centres of a row, and
            # the pixels one offset reads for consecutive texels, are consecutive in memory.
            # Channels are planes too (channel, z, phase y, phase x, y, x): one offset of one
            # channel reads consecutive bytes for consecutive texels (16-byte loads in OpenCL).
            g = self.host if self.nd == 3 else self.host[None]
            z, yp, xp, _ = g.shape
            hp, wp_ = yp // m, xp // m
            phase = g.reshape(z, hp, m, wp_, m, 3).transpose(5, 0, 2, 4, 1, 3)
            self.phase_grid = backend.to_device(np.ascontiguousarray(phase).reshape(-1))
            self.phase_dims = (hp, wp_)
        hp, wp_ = self.phase_dims
        p0 = r // m  # texel (0, 0) sits at padded texel (p0, p0) of phase (0, 0)
        plane = hp * wp_  # one phase plane
        zplanes = (2 if self.nd == 3 else 1) * m * m * plane  # one channel
        nq = len(counts)
        o = np.clip(np.asarray(offsets, np.int64), -r, r)
        dy, dx = o[:, -2], o[:, -1]
        f = ((dy % m) * m + dx % m) * plane + (dy // m) * wp_ + dx // m
        if self.nd == 3:
            f = f + o[:, 0] * (m * m * plane)
        counts = np.asarray(counts, np.int64)
        # query b's 3 K_b entries are contiguous: entry-major, channel-minor (as the values)
        flat = (f[:, None] + np.arange(3)[None, :] * zplanes).reshape(-1)
        vals = np.ascontiguousarray(values, np.uint8).reshape(-1)
        qstart = np.zeros(nq + 1, np.int32)
        np.cumsum(counts * 3, out=qstart[1:])
        n = self.h * self.w
        need = nq * n
        if self._scratch is None or self._scratch.size < need:
            self._scratch = backend.empty((max(need, 64 * n),), np.uint32)
        idx = backend.empty((nq,), np.int32)
        score = backend.empty((nq,), np.uint32)
        backend.texel_search(self.phase_grid, n, self.w, wp_, 1, p0 * wp_ + p0,
                             backend.to_device(qstart), backend.to_device(flat.astype(np.int32)),
                             backend.to_device(vals), nq, self._scratch, idx, score)
        # sync: the orchestrator needs the chosen texels now; 2 x B numbers come back
        out = backend.to_host(idx).astype(np.int64), backend.to_host(score).astype(np.int64)
        self.searches += nq
        self.launches += 1
        self.seconds += time.perf_counter() - t0
        return out

    def best_among(self, offsets_px: np.ndarray, values: np.ndarray, texels: np.ndarray) -> tuple[int, int]:
        """Eq. 5 over the given candidate texels only (coherent mode), exactly, on the host.

        Args:
            texels: (C,) candidate texel indices (y * W + x); ties go to the lowest index.
        """
        cand = np.unique(np.asarray(texels, np.int64))
        off, vals, wts = self._query(np.asarray(offsets_px, np.int64), np.asarray(values, np.uint8))
        off, vals = off[:-2], vals[:-2].astype(np.int64)
        ty, tx = cand // self.w, cand % self.w
        y = self.pad + self.m * ty[:, None] + off[None, :, -2]
        x = self.pad + self.m * tx[:, None] + off[None, :, -1]
        window = self.host[off[None, :, 0], y, x] if self.nd == 3 else self.host[y, x]  # (C, K, 3)
        err = ((window.astype(np.int64) - vals[None]) ** 2).sum((1, 2))
        i = int(np.argmin(err))
        return int(cand[i]), int(err[i])

    def _padded(self, offsets: np.ndarray, values: np.ndarray, counts: np.ndarray):
        """Packed queries as padded arrays: flat pixel offsets rel (B, K) into the host grid
        (K = the longest query), values (B, K, 3) int32 and a mask (B, K) of real entries."""
        nq = len(counts)
        kmax = int(counts.max())
        slot = np.arange(len(offsets)) - np.repeat(np.cumsum(counts) - counts, counts)
        owner = np.repeat(np.arange(nq), counts)
        off = np.clip(np.asarray(offsets, np.int64), -self.pad, self.pad)
        yp, xp = self.host.shape[-3], self.host.shape[-2]
        flat = off[:, -2] * xp + off[:, -1]
        if self.nd == 3:
            flat = flat + off[:, 0] * (yp * xp)
        rel = np.zeros((nq, kmax), np.int64)
        val = np.zeros((nq, kmax, 3), np.int32)
        mask = np.zeros((nq, kmax), bool)
        rel[owner, slot] = flat
        val[owner, slot] = values
        mask[owner, slot] = True
        return rel, val, mask

    def best_among_packed(self, offsets: np.ndarray, values: np.ndarray, counts: np.ndarray,
                          candidates: np.ndarray, cand_counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`best_among` of packed queries, vectorized on the host (coherent mode).

        Args:
            offsets, values, counts: packed queries (see :meth:`best_packed`).
            candidates: (C,) candidate texels grouped by query; cand_counts (B,) per query (each >= 1).

        Returns:
            (texels (B,) int64, errors (B,) int64); ties go to the lowest texel.
        """
        nq = len(counts)
        rel, val, mask = self._padded(offsets, values, counts)
        owner = np.repeat(np.arange(nq), cand_counts)
        pairs = np.unique(owner * (self.h * self.w) + np.asarray(candidates, np.int64))  # sorted by query, texel
        q, t = pairs // (self.h * self.w), pairs % (self.h * self.w)
        xp = self.host.shape[-2]
        base = (self.pad + self.m * (t // self.w)) * xp + self.pad + self.m * (t % self.w)
        win = np.take(self.host.reshape(-1, 3), base[:, None] + rel[q], axis=0).astype(np.int32) - val[q]
        win *= win
        err = (win.sum(-1, dtype=np.int64) * mask[q]).sum(-1)  # (P,)
        start = np.searchsorted(q, np.arange(nq))
        low = np.minimum.reduceat(err, start)
        first = np.flatnonzero(err == low[q])
        pick = first[np.searchsorted(q[first], np.arange(nq))]  # first (lowest texel) minimum per query
        return t[pick], err[pick]

    def refine(self, offsets_px: np.ndarray, values: np.ndarray, texel: int) -> np.ndarray:
        """Sub-texel refinement of one query (see :meth:`refine_packed`); (3,) uint8."""
        off = np.asarray(offsets_px, np.int64)
        return self.refine_packed(off, np.asarray(values, np.uint8), np.array([len(off)]), np.array([texel]))[0]

    def refine_batch(self, queries: list[tuple[np.ndarray, np.ndarray]], texels: np.ndarray) -> np.ndarray:
        """:meth:`refine_packed` of a list of (offsets_px, values) queries; (B, 3) uint8."""
        return self.refine_packed(*_pack(queries), np.asarray(texels, np.int64))

    def refine_packed(self, offsets: np.ndarray, values: np.ndarray, counts: np.ndarray,
                      texels: np.ndarray) -> np.ndarray:
        """Sub-texel refinement (our addition), exactly on the host, vectorized over queries.

        The texel search compares the neighbours' colours at their exact (rounded to 1/m)
        positions, but a texel-centre colour would sit the point up to half a texel off the
        window it matched. This looks for the supersampled pixel within half a texel of the
        chosen texel whose window matches best (eq. 5 again), in two steps: a 4 x 4 grid of
        step m/4 pixels, then the 3 x 3 pixels around the best of those (25 windows, not
        m^2 = 64), the texel centre first and winning ties in each step.

        Args:
            offsets: (E, nd) pixel offsets of all queries, grouped by query; values (E, 3)
                uint8; counts (B,) entries per query (each >= 1); texels (B,) chosen texels.

        Returns:
            (B, 3) uint8: the supersampled colours at the best pixels.
        """
        nq = len(counts)
        rel, val, mask = self._padded(offsets, values, counts)
        xp = self.host.shape[-2]
        texels = np.asarray(texels, np.int64)
        cy = self.pad + self.m * (texels // self.w)  # (B,) texel centre pixel
        cx = self.pad + self.m * (texels % self.w)
        colours = self.host.reshape(-1, 3)

        def best_shift(dy, dx):  # dy, dx: (B, S) pixel shifts -> index of the best per query
            pix = ((cy[:, None] + dy) * xp + (cx[:, None] + dx))[:, :, None] + rel[:, None, :]  # (B, S, K)
            win = np.take(colours, pix, axis=0).astype(np.int32) - val[:, None]
            win *= win
            err = (win.sum(-1, dtype=np.int64) * mask[:, None, :]).sum(-1)
            return np.argmin(err, axis=1)  # first minimum: the order of the shifts breaks ties

        half = self.m // 2
        dy1, dx1, ring = refine_shifts(self.m)
        pick = best_shift(np.broadcast_to(dy1, (nq, len(dy1))), np.broadcast_to(dx1, (nq, len(dx1))))
        by, bx = dy1[pick], dx1[pick]
        if ring:
            cells = np.array([(0, 0)] + [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)])
            dy2 = np.clip(by[:, None] + cells[None, :, 0], -half, self.m - half - 1)
            dx2 = np.clip(bx[:, None] + cells[None, :, 1], -half, self.m - half - 1)
            pick = best_shift(dy2, dx2)
            by, bx = dy2[np.arange(nq), pick], dx2[np.arange(nq), pick]
        flat = self.host[0] if self.nd == 3 else self.host
        return flat[cy + by, cx + bx]



def refine_shifts(m: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """The sub-texel refinement's first shifts: a grid of step max(1, m // 4) pixels over
    [-m // 2, m - m // 2), centre first (by |dy| + |dx|, then dy, then dx); and whether a
    second pass over the 3 x 3 pixels around the best follows (step > 1).

    Returns:
        (dy (S,) int64, dx (S,) int64, ring).
    """
    half, step = m // 2, max(1, m // 4)
    grid1 = np.arange(-half, m - half, step)
    dy1, dx1 = np.repeat(grid1, len(grid1)), np.tile(grid1, len(grid1))
    first = np.lexsort((dx1, dy1, np.abs(dy1) + np.abs(dx1)))
    return dy1[first], dx1[first], step > 1


# ------------------------------------------------------------------ point hierarchy


@dataclass
class PointLevel:
    """One level of the point hierarchy (level 0 is the model itself).

    Attributes:
        positions, normals: (n, 3) float64.
        s_axis, t_axis: (n, 3) float64 tangent frames (texture x and y directions).
        neighbours: (n, k) int32 k-nearest neighbours (self excluded); distances (n, k) float64.
        unit: world length of one texel of this level's texture.
        parent: (n,) int64 index of the coarser point each point was clustered into,
            or None on the coarsest level.
        children: for levels > 0, (n, 4) int64 indices of the finer points clustered
            into each point (-1 padded).
    """

    positions: np.ndarray
    normals: np.ndarray
    s_axis: np.ndarray
    t_axis: np.ndarray
    neighbours: np.ndarray
    distances: np.ndarray
    unit: float
    parent: np.ndarray | None = None
    children: np.ndarray | None = None


def _cluster(neighbours: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Greedy 4-point clustering (paper Sec. 4.1): the next cluster centre is the
    unclustered point with the most clustered points in its k-neighbourhood; it takes
    its 3 nearest unclustered neighbours. Returns (parent (n,), children (c, 4))."""
    n, k = neighbours.shape
    # Plain Python lists and local names throughout: this loop is sequential by nature and
    # NumPy scalar indexing would cost more than the work (1.7x faster than on ndarrays).
    parent = [-1] * n
    key = [0] * n
    buckets: list[list[int]] = [[] for _ in range(k + 1)]
    buckets[0] = rng.permutation(n).tolist()[::-1]  # popped from the end
    top = 0
    children: list[list[int]] = []
    nb_list = neighbours.tolist()
    clustered = 0
    while clustered < n:
        while True:
            while top > 0 and not buckets[top]:
                top -= 1
            i = buckets[top].pop()
            if parent[i] < 0 and key[i] == top:
                break
        members = [i] + [j for j in nb_list[i] if parent[j] < 0][:3]
        cid = len(children)
        children.append(members + [-1] * (4 - len(members)))
        for j in members:
            parent[j] = cid
        clustered += len(members)
        for j in members:
            for q in nb_list[j]:
                if parent[q] < 0:
                    kq = key[q]
                    if kq < k:
                        kq += 1
                        key[q] = kq
                        buckets[kq].append(q)
                        if kq > top:
                            top = kq
    return np.asarray(parent, np.int64), np.asarray(children, np.int64)


def build_hierarchy(positions: np.ndarray, normals: np.ndarray, s_axis: np.ndarray, t_axis: np.ndarray,
                    k: int, levels: int, unit: float, rng: np.random.Generator,
                    neighbours: tuple[np.ndarray, np.ndarray] | None = None) -> list[PointLevel]:
    """The multiresolution point hierarchy: ``levels`` levels, each a 4-point clustering
    of the one below (positions and normals averaged, frames taken from the first
    child and re-orthogonalized), one texel = ``unit * 2^l`` on level l.

    Raises:
        ValueError: a level would have k or fewer points.
    """
    from geosynth.pointmodels import knn_table

    dist, nb = neighbours if neighbours is not None else knn_table(positions, k)
    out = [PointLevel(positions, normals, s_axis, t_axis, nb, dist, unit)]
    for lvl in range(1, levels):
        fine = out[-1]
        parent, children = _cluster(fine.neighbours, rng)
        fine.parent = parent
        valid = children >= 0
        cnt = valid.sum(1, keepdims=True)
        safe = np.where(valid, children, children[:, :1])
        pos = (fine.positions[safe] * valid[..., None]).sum(1) / cnt
        nrm = (fine.normals[safe] * valid[..., None]).sum(1)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        first = children[:, 0]
        t = fine.t_axis[first] - np.einsum("ij,ij->i", fine.t_axis[first], nrm)[:, None] * nrm
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
        s = np.cross(t, nrm)
        if len(pos) <= k:
            raise ValueError(f"level {lvl} of the point hierarchy has only {len(pos)} points, not more than k = {k}: "
                             "use fewer levels or a smaller k.")
        d, idx = knn_table(pos, k)
        out.append(PointLevel(pos, nrm, s, t, idx, d, unit * 2**lvl, children=children))
    return out


# ------------------------------------------------------------------ matching one level


def _tangent_offsets(level: PointLevel, centres: np.ndarray, others: np.ndarray, unit: float) -> np.ndarray:
    """(M, J, 2) texel offsets (x, y) of points ``others`` (M, J, 3) on the tangent planes of ``centres``."""
    c = centres
    zero = np.zeros((len(c), 1, 2))
    uv, _, _, _, _, ok = propagate(others, level.positions[c][:, None], zero, level.normals[c][:, None],
                                   level.s_axis[c][:, None], level.t_axis[c][:, None], unit)
    v = others - level.positions[c][:, None]
    plain = np.stack([np.einsum("...i,...i->...", v, level.s_axis[c][:, None]),
                      np.einsum("...i,...i->...", v, level.t_axis[c][:, None])], -1) / unit
    return np.where(ok[..., None], uv, plain)


def _coarse_entries(level: PointLevel, coarse: PointLevel, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For the points ``centres``: the coarser points of their neighbourhoods (parents of
    each point and of its k neighbours, each once) and their texel offsets on its tangent
    plane. Returns (indices (c, k + 1) with -1 for repeats, offsets (c, k + 1, 2))."""
    par = level.parent[np.c_[centres, level.neighbours[centres]]]  # (c, k + 1)
    srt = np.sort(par, axis=1)
    first = np.ones(srt.shape, bool)
    first[:, 1:] = srt[:, 1:] != srt[:, :-1]
    idx = np.where(first, srt, -1)
    off = _tangent_offsets(level, centres, coarse.positions[np.maximum(idx, 0)], level.unit)
    return idx, off


def _px(offsets: np.ndarray, m: int) -> np.ndarray:
    """Texel offsets (x, y) -> supersampled pixel offsets (dy, dx), rounded to nearest."""
    return np.rint(offsets[..., ::-1] * m).astype(np.int64)


def _match_level(level: PointLevel, tex: np.ndarray, search: TexelSearch, colours: np.ndarray, coloured: np.ndarray,
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
    level runs in one kernel launch (:func:`_match_coherent_level`); with one, it scores
    each point's few suggested texels exactly on the host (vectorized over the batch) and
    searches every texel only for points whose neighbours suggest none.
    """
    from geosynth.parameterize import _pick_batch

    n, k = level.neighbours.shape
    m = search.m
    todo = int(np.count_nonzero(~coloured))
    if todo == 0:
        return 0
    if coherent and coarse is None:
        return _match_coherent_level(level, search, colours, coloured, source, rng, subtexel)
    # the irregular neighbourhoods of the points to colour (rows of other points stay 0)
    need = np.flatnonzero(~coloured)
    off_px = np.zeros((n, k, 2), np.int64)
    off_px[need] = _px(neighbourhood_offsets(level.positions, level.s_axis, level.t_axis, level.normals,
                                             level.neighbours[need], level.unit, centres=need), m)  # (dy, dx)
    if coarse is not None:
        c_idx = np.full((n, k + 1), -1, np.int64)
        c_px = np.zeros((n, k + 1, 2), np.int64)
        c_idx[need], c_off = _coarse_entries(level, coarse, need)
        c_px[need] = _px(c_off, m)
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
            chosen = _pick_batch(top, nb, blocked, batch) if batch > 1 else top[:1].astype(np.int64)
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


def _match_coherent_level(level: PointLevel, search: TexelSearch, colours: np.ndarray, coloured: np.ndarray,
                          source: np.ndarray, rng: np.random.Generator, subtexel: bool) -> int:
    """Coherent matching of a level with no coarser one, in the paper's sequential order,
    in one kernel launch (kernels/growth.py, ``match_coherent``, gives the rules).
    Updates colours (n, 3) uint8, coloured (n,) bool and source (n,) int64 in place;
    returns the count coloured."""
    from geosynth._backends.interfaces import MatchInputs, MatchScratch, MatchState
    from geosynth.parameterize import growth_buckets

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


# ------------------------------------------------------------------ quality


def neighbourhood_error(level: PointLevel, colours: np.ndarray, search: TexelSearch, sample: np.ndarray,
                        rotations: int = QUALITY_ROTATIONS) -> float:
    """Mean eq. 5 error of the colouring over the neighbourhoods of ``sample`` points.

    For each sampled point, its neighbourhood (itself at offset 0 plus its k neighbours,
    all with their colours) is matched against every texel for each of ``rotations``
    rotations about the normal; the best error is divided by the number of entries and
    channels: the mean squared colour difference per channel (0..65025) of the best
    texture window. Rotations make the number fair to colourings whose texture axes turn
    over the surface (parameterized patches).
    """
    nb = level.neighbours[sample]
    base = neighbourhood_offsets(level.positions, level.s_axis, level.t_axis, level.normals, nb, level.unit,
                                 centres=sample)
    base = np.concatenate([np.zeros((len(sample), 1, 2)), base], 1)
    vals = np.concatenate([colours[sample][:, None], colours[nb]], 1)
    queries = []
    for i in range(len(sample)):
        for r in range(rotations):
            a = 2 * np.pi * r / rotations
            rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            queries.append((_px(base[i] @ rot.T, search.m), vals[i]))
    errors = np.concatenate([search.best_batch(queries[j:j + DEFAULT_MATCH_BATCH])[1]
                             for j in range(0, len(queries), DEFAULT_MATCH_BATCH)])
    best = errors.reshape(len(sample), rotations).min(1)
    total = float((best / (vals.shape[1] * 3)).sum())
    return total / max(1, len(sample))


# ------------------------------------------------------------------ the API


@dataclass
class TextureReport:
    """What :func:`texture_points` did, how fast, and how well.

    Attributes:
        method: param, match or hybrid.
        device: the device the texel searches ran on.
        points: number of points.
        k, levels, coherent, m: the options used.
        unit: world length of one texel.
        patches: number of parameterized patches (param, hybrid).
        gap_fraction: gap points after the parameterization (param, hybrid).
        matched_fraction: points coloured by neighbourhood matching on the finest level
            (hybrid: the widened gaps).
        seconds: stage -> wall seconds.
        rates: stage -> points per second.
        searches: device texel searches: count, kernel launches, mean time per search (ms).
        error: quality numbers (see :func:`neighbourhood_error`): ``result``, ``random``
            (each point a random texel's colour) and ``parameterization``.
    """

    method: str
    device: str
    points: int
    k: int
    levels: int
    coherent: bool
    m: int
    unit: float
    patches: int = 0
    gap_fraction: float = 0.0
    matched_fraction: float = 0.0
    seconds: dict = field(default_factory=dict)
    rates: dict = field(default_factory=dict)
    searches: dict = field(default_factory=dict)
    error: dict = field(default_factory=dict)

    def lines(self) -> list[str]:
        """Human-readable summary lines."""
        out = [f"{self.method} on {self.points:,} points, k={self.k}, levels={self.levels}, "
               f"{'coherent, ' if self.coherent else ''}m={self.m}, device {self.device}"]
        if self.method != "match":
            out.append(f"patches: {self.patches}, gap points after parameterization: {100 * self.gap_fraction:.1f}%")
        if self.method != "param":
            out.append(f"coloured by neighbourhood matching: {100 * self.matched_fraction:.1f}%")
        for stage, sec in self.seconds.items():
            rate = self.rates.get(stage)
            out.append(f"  {stage:<26} {sec:8.2f} s" + (f"  {rate:12,.0f} points/s" if rate else ""))
        if self.searches.get("count"):
            out.append(f"  texel searches: {self.searches['count']:,} in {self.searches['launches']:,} launches, "
                       f"{self.searches['ms_each']:.3f} ms per search ({self.searches['candidates']:,} texels each)")
        if self.error:
            out.append("mean eq. 5 error per entry and channel (best texture window; lower is better): "
                       + ", ".join(f"{k2} {v:.0f}" for k2, v in self.error.items()))
        return out


def _require_texture(n_pts: int, h: int, w: int, method: str, k: int, levels: int, m: int, quality: bool) -> None:
    """Refuse, before any allocation, a texture_points run whose estimate
    (:func:`texture_bytes`) exceeds the memory available: option ``"texture_size"`` (the
    texture's side; largest: a square that fits) when the texture search alone does not
    fit, else ``"count"`` (the point count; largest by bisection)."""
    from geosynth.memory import available_memory, largest_fitting, require

    def est(n, hh, ww):
        return texture_bytes(n, hh, ww, method=method, k=k, levels=levels, m=m, quality=quality)

    need = est(n_pts, h, w)
    avail = available_memory()
    if need <= avail:
        return
    what = f"texturing {n_pts:,} points (k = {k}) from a {w:,} x {h:,} texture (m = {m})"
    if est(k + 1, h, w) > avail:  # the texture search alone is too large
        side = max(h, w)
        smallest = max(2, math.ceil(math.sqrt(k + 1))) << (levels - 1)
        best = largest_fitting(lambda s_: est(n_pts, s_, s_), avail, smallest, side)
        require(need, option="texture_size", value=side, largest=best, available=avail, what=what)
    best = largest_fitting(lambda n: est(n, h, w), avail, k + 1, n_pts)
    require(need, option="count", value=n_pts, largest=best, available=avail, what=what)


def _check_options(method, k, levels, m, n_pts, texture, coherent):
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}.")
    k = check_k(k, n_pts)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 1:
        raise ValueError(f"levels must be an integer >= 1, got {levels!r}.")
    if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 1 <= m <= 32:
        raise ValueError(f"m (supersampling) must be an integer in [1, 32], got {m!r}.")
    h, w = texture.shape[:2]
    side = math.ceil(math.sqrt(k + 1))  # a k-neighbourhood spans about sqrt(k) x sqrt(k) texels
    if method != "param" and min(h, w) >> (levels - 1) < side:
        raise ValueError(
            f"the texture ({w} x {h}) is smaller than the neighbourhood: k = {k} spans about {side} x {side} texels"
            + (f" on the coarsest of {levels} levels ({w >> (levels - 1)} x {h >> (levels - 1)})" if levels > 1 else "")
            + "; use a larger texture, a smaller k or fewer levels."
        )
    return k, int(levels), int(m)


# Peak bytes per point and neighbour (k) of the point work of texture_points, per method:
# the kNN tables and frames, the parameterization's patch growth, and for matching the
# per-query neighbourhood offsets and tangent-plane mappings ((M, k, 3) float64
# temporaries). Measured (RSS high-water delta, Warp CPU, blobs of 4k, 16k and 64k points,
# k = 25): param 33.7-34, match 266-270, hybrid 75-149 (it matches the gaps only, and their
# share varies with the model); with levels > 1 matching adds ~155 (the clustering's
# Python neighbour lists, ~36 B per entry, and the hierarchy).
_POINT_NEIGHBOUR_BYTES = {"param": 34, "hybrid": 105, "match": 268}
_LEVELS_NEIGHBOUR_BYTES = 155  # more per point and neighbour with levels > 1 (matching)


def texture_bytes(n_points: int, height: int, width: int, *, method: str = "hybrid", k: int = 25, levels: int = 1,
                  m: int = DEFAULT_M, quality: bool = True) -> int:
    """Estimated peak bytes of :func:`texture_points` for ``n_points`` points and an
    ``height`` x ``width`` texture.

    The larger of two stages: the point work (``_POINT_NEIGHBOUR_BYTES`` per point and
    neighbour for the method, plus ``_LEVELS_NEIGHBOUR_BYTES`` with a hierarchy), and
    the texel search's supersampled texture while the points' tables (16 B per point
    and neighbour + 40) stay alive: per supersampled pixel (m^2 per texel) 96 B per
    z-slice while a search is built (the bilinear resampling's float64 (mH, mW, 3) taps,
    their stack, rounding and clipping; two slices on the finest of several levels), and
    while the quality numbers' search is built, the matching's padded uint8 grid, its
    device copy and the batched kernel's phase-plane copy (9 B per pixel and slice; pad
    2 sqrt(k) + 3 texels a side). 512 KiB of small buffers. Measured (RSS, Warp CPU):
    6,055-6,134 B per texel at m = 8 for 64^2-256^2 textures.
    """
    n, h, w, k, m = int(n_points), int(height), int(width), int(k), int(m)
    per_nb = _POINT_NEIGHBOUR_BYTES[method] + (_LEVELS_NEIGHBOUR_BYTES if levels > 1 and method != "param" else 0)
    points_stage = per_nb * k * n
    searching = method != "param" or quality
    z = 2 if levels > 1 and method != "param" else 1
    pad = 2 * math.isqrt(k) + 3
    # the build's float64 taps (99 B per pixel and slice, uint8 result included), while the
    # matching's search (its uint8 copies, 9 B) is alive when the quality search is built
    kept = 9 * z * (h + 2 * pad) * (w + 2 * pad) if method != "param" and quality else 0
    texture_stage = m * m * (99 * z * h * w + kept) if searching else 0
    return max(points_stage, texture_stage + (16 * k + 40) * n) + (512 << 10)


def texture_points(
    points: PointSet,
    texture: np.ndarray,
    *,
    method: str = "hybrid",
    k: int = 25,
    levels: int = 1,
    coherent: bool = False,
    m: int = DEFAULT_M,
    unit_scale: float = 1.0,
    up=(0.0, 1.0, 0.0),
    tileable: bool = True,
    weights=DEFAULT_WEIGHTS,
    threshold: float = DEFAULT_THRESHOLD,
    max_patch: float | None = None,
    pattern_size: float | None = None,
    subtexel: bool = True,
    batch: int = DEFAULT_MATCH_BATCH,
    quality: bool = True,
    quality_samples: int = 200,
    device: str | None = None,
    seed: int = 0,
    progress: bool = False,
) -> tuple[PointSet, TextureReport]:
    """Colour every point of a point model from a sample texture (M3).

    Args:
        points: PointSet with positions and normals (estimate missing normals with
            :func:`geosynth.pointsets.estimate_normals`).
        texture: (H, W, 3) uint8 RGB texture (grey is converted; RGBA must be opaque).
        method: ``"param"`` (point parameterization), ``"match"`` (neighbourhood
            matching) or ``"hybrid"`` (parameterization, then matching in the gaps).
        k: neighbours per point (>= 3); 25 or 49 in the paper.
        levels: multiresolution levels of matching (point hierarchy + texture pyramid).
        coherent: coherent matching (candidates near the neighbours' source texels).
        m: supersampling factor of the texel search.
        unit_scale: one texel = ``unit_scale`` x the mean nearest-neighbour distance
            (larger: a larger texture on the model).
        up: up vector for the texture orientation, or None for a random direction.
        tileable: the texture tiles (unbounded patches, periodic lookups); else patches
            are capped at ``max_patch`` texels and lookups clamp at the edge.
        weights, threshold: the distortion measure (w1..w4) and its bound.
        max_patch: largest patch extent in texels when not tileable (default 0.8 x the
            texture's smaller side).
        pattern_size: the texture's pattern size in texels, for the hybrid's gap widening
            (default: one widening round).
        subtexel: refine each matched texel to the best supersampled pixel within half
            a texel and take that pixel's colour (our addition; False: the texel's own
            colour, as in the paper).
        batch: points searched per kernel launch (none in another's k-neighbourhood);
            1 is the paper's sequential order with one :func:`geosynth.score_gather` call
            per point (same texel choices per query; the order differs a little).
        quality: compute the quality numbers (mean eq. 5 error of the result, of a
            random colouring and of the pure parameterization).
        quality_samples: points whose neighbourhoods the quality numbers average over.
        device: where the texel searches run (a device string; None: "auto").
        seed: seed of every random choice; the same seed gives the same colours on every device.
        progress: show progress bars.

    Returns:
        (the coloured PointSet (positions and normals as given), a :class:`TextureReport`).

    Raises:
        TypeError: points is not a PointSet.
        ValueError: no normals, NaN positions, k < 3 or >= the point count, a texture
            smaller than the neighbourhood, transparent texels, bad options.
        RuntimeError: the device is absent.
        MemoryBudgetError: the estimate (:func:`texture_bytes`) exceeds the memory
            available, before anything is allocated: option ``"texture_size"`` when the
            texture search alone is too large, else ``"count"`` (the points).
    """
    import geosynth

    tex = as_texture(texture)
    p, nrm = _as_model(points)
    n_pts = len(p)
    k, levels, m = _check_options(method, k, levels, m, n_pts, tex, coherent)
    check_up(up)
    if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
        raise ValueError(f"batch must be an integer >= 1, got {batch!r}.")
    if method == "param":
        levels = 1
    _require_texture(n_pts, tex.shape[0], tex.shape[1], method, k, levels, m, quality)
    rng = np.random.default_rng(seed)
    h, w = tex.shape[:2]
    if max_patch is None and not tileable:
        max_patch = 0.8 * min(h, w)
    dev_name = geosynth.get_backend(device or "auto").name
    report = TextureReport(method, dev_name, n_pts, k, levels, coherent, m, 0.0)
    sec, rates = report.seconds, report.rates

    from geosynth.pointmodels import knn_table, spatial_order

    t0 = time.perf_counter()
    # everything below runs on the points in a spatial order (cache locality of the
    # neighbour reads); the colours go back to the given order at the end
    in_order = spatial_order(p)
    p, nrm = p[in_order], nrm[in_order]
    model = CheckedModel(p, nrm)
    dist, nb = knn_table(p, k)
    sec["neighbours (kNN)"] = time.perf_counter() - t0
    rates["neighbours (kNN)"] = n_pts / max(sec["neighbours (kNN)"], 1e-9)
    unit = mean_spacing(dist) * float(unit_scale)
    report.unit = unit

    colours = np.zeros((n_pts, 3), np.uint8)
    coloured = np.zeros(n_pts, bool)
    source = np.full(n_pts, -1, np.int64)
    param = None
    param_colours = None

    def run_param():
        t1 = time.perf_counter()
        par, grown = parameterize_with_device_arrays(
            model, k, unit_scale=unit_scale, up=up, weights=weights, threshold=threshold,
            max_patch=None if tileable else max_patch, seed=rng, neighbours=(dist, nb), device=dev_name)
        sec["parameterization"] = time.perf_counter() - t1
        rates["parameterization"] = n_pts / max(sec["parameterization"], 1e-9)
        t1 = time.perf_counter()
        cols, _, offs = colour_parameterization(model, par, tex, tileable=tileable, seed=rng, device=dev_name,
                                                grown=grown)
        sec["texture mapping + gaps"] = time.perf_counter() - t1
        rates["texture mapping + gaps"] = n_pts / max(sec["texture mapping + gaps"], 1e-9)
        return par, cols, offs

    if method in ("param", "hybrid"):
        param, param_colours, patch_offsets = run_param()
        report.patches, report.gap_fraction = param.patch_count, param.gap_fraction

    if method == "param":
        colours[:] = param_colours
        coloured[:] = True
    else:
        # frames: the patches' own (hybrid) or from the up vector / a random direction (match)
        if method == "hybrid":
            s_ax, t_ax = param.s_axis.copy(), param.t_axis.copy()
            gap = param.state == GAP
            # gap widening toward the pattern size (each round: about sqrt(k) wider)
            t1 = time.perf_counter()
            width0 = math.sqrt(k) / 2
            target = (pattern_size * unit_scale) if pattern_size is not None else width0 + math.sqrt(k)
            rounds = max(0, math.ceil((target - width0) / math.sqrt(k)))
            for _ in range(rounds):
                grow = np.zeros(n_pts, bool)
                grow[nb[gap].reshape(-1)] = True
                gap |= grow
            report.matched_fraction = float(gap.mean())
            keep = ~gap
            colours[keep] = param_colours[keep]
            coloured[keep] = True
            ty = np.mod(np.rint(param.uv[keep, 1] + patch_offsets[param.patch[keep], 1]), h) if tileable else \
                np.clip(np.rint(param.uv[keep, 1] + patch_offsets[param.patch[keep], 1]), 0, h - 1)
            tx = np.mod(np.rint(param.uv[keep, 0] + patch_offsets[param.patch[keep], 0]), w) if tileable else \
                np.clip(np.rint(param.uv[keep, 0] + patch_offsets[param.patch[keep], 0]), 0, w - 1)
            source[keep] = (ty * w + tx).astype(np.int64)
            # gap points (and any without a frame) take the frame of their nearest framed neighbour
            framed = np.isfinite(s_ax).all(1) & keep
            s_up, t_up = frames_from_up(nrm, up if up is not None else rng.standard_normal(3))
            need = np.flatnonzero(~framed)
            has = framed[nb[need]]
            first = np.argmax(has, 1)
            src = nb[need, first]
            ok = has.any(1)
            t_new = np.where(ok[:, None], t_ax[src], t_up[need])
            t_new = t_new - np.einsum("ij,ij->i", t_new, nrm[need])[:, None] * nrm[need]
            bad = np.linalg.norm(t_new, axis=1) < 1e-6
            t_new[bad] = t_up[need][bad]
            t_new /= np.linalg.norm(t_new, axis=1, keepdims=True)
            t_ax[need] = t_new
            s_ax[need] = np.cross(t_new, nrm[need])
            sec["gap widening"] = time.perf_counter() - t1
        else:
            s_ax, t_ax = frames_from_up(nrm, up if up is not None else rng.standard_normal(3))
            report.matched_fraction = 1.0

        t1 = time.perf_counter()
        hierarchy = build_hierarchy(p, nrm, s_ax, t_ax, k, levels, unit, rng, neighbours=(dist, nb))
        pyramid = texture_pyramid(tex, levels)
        if levels > 1:
            sec["hierarchy + pyramid"] = time.perf_counter() - t1
            rates["hierarchy + pyramid"] = n_pts / max(sec["hierarchy + pyramid"], 1e-9)

        # coloured state per level: a coarse point is coloured iff all its fine points are
        lv_col = [colours]
        lv_done = [coloured]
        lv_src = [source]
        for lvl in range(1, levels):
            ch = hierarchy[lvl].children
            valid = ch >= 0
            safe = np.where(valid, ch, ch[:, :1])
            done = (lv_done[-1][safe] | ~valid).all(1)
            mean = (lv_col[-1][safe].astype(np.float64) * valid[..., None]).sum(1) / valid.sum(1, keepdims=True)
            lv_col.append(np.where(done[:, None], np.rint(mean), 0).astype(np.uint8))
            lv_done.append(done)
            lv_src.append(np.full(len(ch), -1, np.int64))

        t1 = time.perf_counter()
        searchers = []
        matched_total = 0
        for lvl in range(levels - 1, -1, -1):
            level = hierarchy[lvl]
            top_level = lvl == levels - 1
            if top_level and method == "match" and levels > 1:
                # the coarsest level of the pure matching is coloured randomly (paper Sec. 4.1)
                todo = np.flatnonzero(~lv_done[lvl])
                texel = rng.integers(0, pyramid[lvl].shape[0] * pyramid[lvl].shape[1], len(todo))
                lv_col[lvl][todo] = pyramid[lvl].reshape(-1, 3)[texel]
                lv_src[lvl][todo] = texel
                lv_done[lvl][todo] = True
                continue
            coarse = None if top_level else hierarchy[lvl + 1]
            # reach of the neighbourhoods: a tangent-plane offset is as long as |V|, so the
            # farthest k-th neighbour bounds the level's own entries; the coarse entries get
            # twice that as a margin (anything beyond is clipped to the padding)
            reach = float(level.distances[:, -1].max()) / level.unit * (2.0 if coarse is not None else 1.0)
            search = TexelSearch(pyramid[lvl], None if coarse is None else pyramid[lvl + 1], m, reach, tileable,
                                 dev_name)
            searchers.append(search)
            matched_total += _match_level(level, pyramid[lvl], search, lv_col[lvl], lv_done[lvl], lv_src[lvl], coarse,
                                          None if coarse is None else lv_col[lvl + 1], coherent, rng, progress,
                                          f"matching level {lvl + 1}/{levels}", subtexel, batch)
        colours, coloured, source = lv_col[0], lv_done[0], lv_src[0]
        sec["neighbourhood matching"] = time.perf_counter() - t1
        rates["neighbourhood matching"] = matched_total / max(sec["neighbourhood matching"], 1e-9)
        count = sum(s.searches for s in searchers)
        if count:
            report.searches = {"count": count, "ms_each": 1e3 * sum(s.seconds for s in searchers) / count,
                               "candidates": h * w, "launches": sum(s.launches for s in searchers)}
    sec["total"] = sum(v for kk, v in sec.items())
    rates["total"] = n_pts / max(sec["total"], 1e-9)

    if quality:
        t1 = time.perf_counter()
        level0 = PointLevel(p, nrm, *frames_from_up(nrm, up if up is not None else (0.0, 1.0, 0.0)), nb, dist, unit)
        search = TexelSearch(tex, None, m, float(np.sqrt(k) * 2 + 2), tileable, dev_name)
        sample = np.sort(np.random.default_rng(seed + 1).choice(n_pts, min(quality_samples, n_pts), replace=False))
        report.error["result"] = neighbourhood_error(level0, colours, search, sample)
        random_colours = tex.reshape(-1, 3)[np.random.default_rng(seed + 2).integers(0, h * w, n_pts)]
        report.error["random"] = neighbourhood_error(level0, random_colours, search, sample)
        if method != "param":
            if param_colours is None:
                _, param_colours, _ = run_param()
                sec.pop("parameterization"), sec.pop("texture mapping + gaps")
                rates.pop("parameterization"), rates.pop("texture mapping + gaps")
            report.error["parameterization"] = neighbourhood_error(level0, param_colours, search, sample)
        sec["quality numbers"] = time.perf_counter() - t1

    given_order = np.empty_like(colours)
    given_order[in_order] = colours
    out = PointSet(points.positions, points.normals, given_order)
    return out, report
