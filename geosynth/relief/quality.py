"""How close is the result to the example? (issue 34, item 4.)

- Per region: the vertices split into k-means regions (8 by default, seeded); in each, the heights
  (along the normals, relative to the un-displaced surface) are laid on the region's mean tangent
  plane (vertices whose normal is within 35 degrees of the region's mean), gridded with
  :func:`geosynth.completion.spectrum.heights_on_grid` and measured with
  :func:`geosynth.completion.spectrum.relief_spectrum`: amplitude (std of the heights after removing their
  best plane) and dominant period, against the example's own (its grid, the same measure).
  The share of the surface within the example's statistics: the vertices of regions whose amplitude
  and period are both within 10% of the example's.
- Distortion of the example's features: the aspect ratio of its typical element, from the
  autocorrelation of the heights (its central lobe above 0.5, the second moment's eigenvalues:
  sqrt(largest / smallest)), per region against the example's. A parameterization that stretches
  the relief stretches the lobe; 1 is kept.
- Seams: the local amplitude (std of the heights within one period of a vertex, at up to 3000
  seeded vertices, over a seeded subset of about 256 vertices a ball) on border vertices against
  inside ones, for two kinds of border: the projection's blends
  (:func:`geosynth.relief.project.blend_share` > 0.15) and the synthesis' patch borders (edges whose
  two ends copied example cells more than 2 cells apart). A seam that flattens or
  doubles the relief shows as a local amplitude below (or above) the inside's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["QualityReport", "element_aspect", "measure", "patch_borders", "relief_picture"]

REGIONS = 8
WITHIN = 0.10  # the target: amplitude and period within 10% of the example's
_BLEND = 0.15
_SAMPLES = 3000


@dataclass
class QualityReport:
    """Quality numbers of one result (all lengths world units).

    Attributes:
        method: "synth" or "project".
        example_amplitude, example_period: the example's (relief_spectrum of its grid).
        amplitude, period: (K,) per region (nan where a region held too few cells).
        region_share: (K,) share of the vertices in each region.
        within: share of the surface in regions within 10% on both amplitude and period.
        seam_projection, seam_synthesis: local amplitude on that border / inside - 1 (nan: no border).
        border_share: share of the sampled vertices on (projection, synthesis) borders.
        example_aspect: the example's element aspect ratio (:func:`element_aspect`, >= 1).
        aspect: (K,) per region, the same measure (nan where a region held too few cells).
    """

    method: str
    example_amplitude: float
    example_period: float
    amplitude: np.ndarray
    period: np.ndarray
    region_share: np.ndarray
    within: float
    seam_projection: float
    seam_synthesis: float
    border_share: tuple[float, float] = field(default=(math.nan, math.nan))
    example_aspect: float = math.nan
    aspect: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def worst(self) -> tuple[float, float]:
        """(largest |amplitude / example - 1|, largest |period / example - 1|) over the regions measured."""
        a = np.abs(self.amplitude / self.example_amplitude - 1)
        p = np.abs(self.period / self.example_period - 1)
        return float(np.nanmax(a)) if np.isfinite(a).any() else math.nan, \
            float(np.nanmax(p)) if np.isfinite(p).any() else math.nan

    def distortion(self) -> tuple[float, float]:
        """(median, worst) over the regions of their element aspect ratio / the example's (1: kept)."""
        r = self.aspect / self.example_aspect if len(self.aspect) else np.zeros(0)
        if not np.isfinite(r).any():
            return math.nan, math.nan
        return float(np.nanmedian(r)), float(r[np.nanargmax(np.abs(np.log(np.where(np.isfinite(r), r, 1.0))))])

    def line(self) -> str:
        """One line: medians and worst regions against the example, the share within 10%, the
        features' distortion, seams."""
        a = self.amplitude / self.example_amplitude - 1
        p = self.period / self.example_period - 1
        wa, wp = self.worst()
        dm, dw = self.distortion()
        return (f"{self.method:>7}: amplitude {np.nanmedian(self.amplitude):.4g} "
                f"({100 * np.nanmedian(a):+.1f}% median, "
                f"worst region {100 * wa:.1f}%), period {np.nanmedian(self.period):.4g} "
                f"({100 * np.nanmedian(p):+.1f}% median, worst {100 * wp:.1f}%), within 10% on "
                f"{100 * self.within:.0f}% of the surface; element aspect x{dm:.2f} of the example's (worst region "
                f"x{dw:.2f}); seams: local amplitude at projection blends "
                f"{100 * self.seam_projection:+.1f}%, at synthesis patch borders {100 * self.seam_synthesis:+.1f}%")


def patch_borders(faces: np.ndarray, source: np.ndarray, example_shape: tuple[int, int], periodic: bool) -> np.ndarray:
    """(V,) bool: vertices on an edge whose two ends copied example cells more than 2 cells apart
    (rows or columns; wrapped when the example tiles), i.e. a border between copied patches."""
    f = np.asarray(faces, np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    s0, s1 = source[e[:, 0]], source[e[:, 1]]
    ok = (s0 >= 0) & (s1 >= 0)
    h, w = example_shape
    dy = np.abs(s0 // w - s1 // w)
    dx = np.abs(s0 % w - s1 % w)
    if periodic:
        dy, dx = np.minimum(dy, h - dy), np.minimum(dx, w - dx)
    jump = ok & ((dy > 2) | (dx > 2))
    out = np.zeros(len(source), bool)
    out[e[jump, 0]] = True
    out[e[jump, 1]] = True
    return out


def element_aspect(grid: np.ndarray, mask: np.ndarray | None = None) -> float:
    """The aspect ratio (>= 1) of a relief's typical element: the heights' autocorrelation
    (normalized by the mask's, so a region's outline does not count), its central lobe above
    0.5, and sqrt(largest / smallest eigenvalue) of that lobe's second moment about its middle,
    weighted by the correlation. nan for a flat grid or a lobe of fewer than 5 cells. Our
    measure for issue 34 item 4 (no paper section)."""
    from scipy import ndimage

    g = np.asarray(grid, np.float64)
    m = np.isfinite(g) if mask is None else (np.asarray(mask, bool) & np.isfinite(g))
    if m.sum() < 16:
        return math.nan
    z = np.where(m, g - g[m].mean(), 0.0)
    shape = (2 * g.shape[0], 2 * g.shape[1])

    def correlate(a):
        f = np.fft.rfft2(a, s=shape)
        return np.fft.fftshift(np.fft.irfft2(f * np.conj(f), s=shape))

    counts = correlate(m.astype(np.float64))
    ac = np.where(counts > 0.25 * m.sum(), correlate(z) / np.maximum(counts, 1.0), 0.0)
    centre = (shape[0] // 2, shape[1] // 2)
    if ac[centre] <= 0:
        return math.nan
    ac /= ac[centre]
    labels, _ = ndimage.label(ac > 0.5)
    lobe = labels == labels[centre]
    if lobe.sum() < 5:
        return math.nan
    y, x = np.nonzero(lobe)
    w = ac[y, x]
    dy, dx = y - centre[0], x - centre[1]
    cov = np.array([[np.sum(w * dy * dy), np.sum(w * dy * dx)], [np.sum(w * dy * dx), np.sum(w * dx * dx)]])
    lo, hi = np.linalg.eigvalsh(cov)
    return float(math.sqrt(hi / lo)) if lo > 0 else math.inf


def _region_spectrum(p: np.ndarray, n: np.ndarray, h: np.ndarray, spacing: float):
    from geosynth.completion.matching import paper_frames
    from geosynth.completion.spectrum import heights_on_grid, relief_spectrum

    mean_n = n.mean(0)
    mean_n /= max(np.linalg.norm(mean_n), 1e-300)
    keep = n @ mean_n > math.cos(math.radians(35))
    if keep.sum() < 32:
        return math.nan, math.nan, math.nan
    fr = paper_frames(mean_n[None])[0]
    uv = np.stack([p[keep] @ fr[0], p[keep] @ fr[1]], 1)
    try:
        grid, mask = heights_on_grid(uv, h[keep], spacing)
        s = relief_spectrum(grid, spacing, mask)
    except ValueError:
        return math.nan, math.nan, math.nan
    return s.amplitude, s.period, element_aspect(grid, mask)


def _local_amplitude(p: np.ndarray, h: np.ndarray, at: np.ndarray, radius: float, seed: int = 0,
                     per_ball: int = 256) -> np.ndarray:
    """(len(at),) std of the heights within ``radius`` of each vertex ``at`` (nan with 3 or fewer), over a
    seeded subset of the vertices holding about ``per_ball`` a ball (all of them when the balls are
    smaller): one vectorized k-nearest query instead of a Python list a ball (a period's ball on a fine
    mesh holds thousands)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(p)
    probe = tree.query_ball_point(p[at[:64]], radius, return_length=True)
    mean = float(np.mean(probe)) if len(probe) else 0.0
    pts, hs = p, h
    if mean > per_ball:
        rng = np.random.default_rng(seed)
        sub = np.sort(rng.choice(len(p), size=max(8, int(len(p) * per_ball / mean)), replace=False))
        pts, hs = p[sub], h[sub]
        tree = cKDTree(pts)
    k = min(len(pts), 2 * per_ball)
    d, i = tree.query(p[at], k=k, distance_upper_bound=radius)
    d, i = d.reshape(len(at), k), i.reshape(len(at), k)
    ok = np.isfinite(d)
    vals = np.where(ok, hs[np.minimum(i, len(pts) - 1)], 0.0)
    n = ok.sum(1)
    mean_h = vals.sum(1) / np.maximum(n, 1)
    var = (np.where(ok, (vals - mean_h[:, None]) ** 2, 0.0)).sum(1) / np.maximum(n, 1)
    out = np.sqrt(var)
    out[n <= 3] = np.nan
    return out


def measure(method: str, example, vertices: np.ndarray, normals: np.ndarray, heights: np.ndarray, spacing: float,
            faces: np.ndarray, source: np.ndarray | None, *, regions: int = REGIONS, seed: int = 0,
            active: np.ndarray | None = None) -> QualityReport:
    """The quality numbers of heights laid on a mesh (module docstring).

    Args:
        method: a name for the line ("synth", "project").
        example: the :class:`~geosynth.relief.examples.ReliefExample` the heights came from.
        vertices: (V, 3) float64 un-displaced positions; normals: (V, 3) unit float64; heights: (V,)
            float64 along the normals (before any clearance limit: the relief as made).
        spacing: the mesh's median edge, world units (the grid spacing).
        faces: (F, 3) int64; source: (V,) int64 example cells copied (synthesis) or None.
        regions: k-means regions; seed: the k-means' and the sampling's seed.
        active: (V,) bool vertices that carry relief (not masked bare), or None (all).

    Returns:
        :class:`QualityReport`.
    """
    from scipy.cluster.vq import kmeans2

    from geosynth.relief.project import blend_share
    from geosynth.completion.spectrum import relief_spectrum

    v = np.asarray(vertices, np.float64)
    act = np.ones(len(v), bool) if active is None else np.asarray(active, bool)
    ex = relief_spectrum(example.heights, example.spacing)
    ids = np.flatnonzero(act)
    k = max(1, min(regions, len(ids) // 200))
    _, label = kmeans2(v[ids], k, minit="++", seed=np.random.default_rng(seed), iter=20)
    amp, per, aspect, share = np.full(k, np.nan), np.full(k, np.nan), np.full(k, np.nan), np.zeros(k)
    for r in range(k):
        sel = ids[label == r]
        share[r] = len(sel) / len(ids)
        if len(sel):
            amp[r], per[r], aspect[r] = _region_spectrum(v[sel], normals[sel], heights[sel], spacing)
    ok = (np.abs(amp / ex.amplitude - 1) <= WITHIN) & (np.abs(per / ex.period - 1) <= WITHIN)
    within = float(share[ok].sum())
    rng = np.random.default_rng(seed)
    at = np.sort(rng.choice(ids, size=min(_SAMPLES, len(ids)), replace=False))
    radius = ex.period if math.isfinite(ex.period) else 4 * spacing
    local = _local_amplitude(v, heights, at, radius, seed)
    blend = blend_share(normals)[at] > _BLEND
    seams = []
    borders = [blend]
    if source is not None:
        borders.append(patch_borders(faces, source, example.shape, example.periodic)[at])
    else:
        borders.append(np.zeros(len(at), bool))
    for b in borders:
        inside = np.nanmean(local[~b]) if (~b).any() else math.nan
        seams.append(float(np.nanmean(local[b]) / inside - 1) if b.any() and inside > 0 else math.nan)
    return QualityReport(method, float(ex.amplitude), float(ex.period), amp, per, share, within, seams[0], seams[1],
                         (float(borders[0].mean()), float(borders[1].mean())), element_aspect(example.heights), aspect)


def relief_picture(before, after, colours: np.ndarray | None, size: int = 420) -> np.ndarray:
    """(H, W, 3) uint8: the input, the result and a close-up (3x zoom on the same view), side by side.

    Args:
        before: (vertices, faces) of the input; after: (vertices, faces) of the result;
        colours: (V, 3) uint8 vertex colours of the result or None.
    """
    from geosynth.io.pictures import View, render_mesh, side_by_side

    bounds = np.stack([np.minimum(before[0].min(0), after[0].min(0)), np.maximum(before[0].max(0), after[0].max(0))])
    a = render_mesh(before, size=(size, size), bounds=bounds)
    b = render_mesh(after, size=(size, size), vertex_colors=colours, bounds=bounds)
    c = render_mesh(after, size=(size, size), vertex_colors=colours, view=View(zoom=3.0), bounds=bounds)
    return side_by_side([a, b, c], ["input", "result", "close-up (3x)"])
