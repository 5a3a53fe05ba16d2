"""Which texel of a texture best matches a point neighbourhood?

The texel search of M3: eq. 5 of Zhang, Qiu and Kaufman, "Fast Hybrid Approach for
Texturing Point Models", Sec. 4 (point neighbourhood matching), ``E(t) = sum_j
|I(t + offset_j) - colour_j|^2`` over a neighbourhood's coloured entries, for every
candidate texel t of one texture level, on a device:

- The texture is supersampled m times (bilinear, m = 8 by default, which the paper
  finds as good as bilinear lookups) so that a lookup rounds to the nearest
  supersampled pixel: offsets become integer pixel offsets ``rint(m * offset)``
  (:func:`pixel_offsets`); only the original texels (stride m) are candidates.
- Scores are exact integers in uint8 data, the same on every device; the lowest score
  wins, the lowest texel index on ties. One query is one :func:`geosynth.score_gather`
  call (:meth:`TexelSearch.best`); :meth:`TexelSearch.best_batch` puts up to 64 queries
  in one launch of the batched kernel pair ``kernels/texel.py`` / ``kernels/texel.cl``
  (measured: score_gather + argmin costs ~0.6-1.3 ms per call whatever the work, so
  one call per point caps matching near 1,000 points/s).
- Multiresolution (Sec. 4.1): the next coarser texture level resampled onto the same
  pixels is a second z-slice of one 3D grid; coarse entries carry dz = 1.
- Sub-texel refinement (our addition): :meth:`TexelSearch.refine` replaces the chosen
  texel's colour by the supersampled pixel within half a texel that matches best.

Candidate windows: the supersampled grid is padded by R pixels (R a multiple of m that
covers every offset of the level; periodically for tileable textures, by the edge
texels otherwise). For score_gather every query carries two zero-weight entries at
(-R, -R) and (R, R), so the lattice of candidate origins is exactly the texel centres
and the padded grid is uploaded once (``wrap=True`` would pad and cache one copy per
distinct reach of the offsets). The batched kernel reads a copy in phase-plane layout
(channel, z, y % m, x % m, y // m, x // m): consecutive texels are consecutive bytes,
one 16-byte load per entry and strip of 16 texels.
"""

from __future__ import annotations

import math
import time

import numpy as np

from geosynth.texturing.textures import sample_bilinear_grid

__all__ = ["DEFAULT_M", "TexelSearch", "pixel_offsets", "refine_shifts"]

DEFAULT_M = 8  # supersampling factor: the paper finds m = 8 as good as bilinear lookups
MAX_REACH_TEXELS = 48  # neighbourhood offsets beyond this many texels are clipped (outliers of sparse regions)


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
        from geosynth.compute.backend import to_device

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
        self.device_grid = to_device(np.ascontiguousarray(self.host), device if device else "auto")
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
        from geosynth.compute.scoring import score_gather

        off, vals, wts = self._query(np.asarray(offsets_px, np.int64), np.asarray(values, np.uint8))
        return score_gather(self.device_grid, off, vals, wts, stride=(2, self.m, self.m)[-self.nd:],
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


def pixel_offsets(offsets: np.ndarray, m: int) -> np.ndarray:
    """Texel offsets -> supersampled pixel offsets, rounded to the nearest pixel.

    Args:
        offsets: (..., 2) float texel offsets (x, y).
        m: the supersampling factor.

    Returns:
        (..., 2) int64 pixel offsets (dy, dx) = rint(m * (y, x)).
    """
    return np.rint(offsets[..., ::-1] * m).astype(np.int64)
