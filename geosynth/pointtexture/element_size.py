"""How large is one texture element of a point-set geometry texture, and how high is its
relief? The measurement behind M2's automatic patch size (issue 32, item 1) and its
feature-scale check (item 2).

"Geometry texture synthesis with point-set surfaces", Sec. 3: "the patch size should be
chosen according to the size and distribution of features in T_in. It should be large
enough to encompass at least a texture element plus some neighborhood." Nothing in the
method measured that; a built-in carried its own patch size and a user's file got 0.4.

The measurement (:func:`relief_scale`): the points' heights above the reference plane
(z; :class:`geosynth.pointtexture.texture.PointTexture`'s plane is xy) as a height map over the
box B (the highest point in each cell: what one sees from above; empty cells take their
nearest filled cell's height), windowed, zero-padded 4x and Fourier transformed; its power
averaged over rings of equal frequency |k|. The element size is the period 1/|k| of the
ring profile's local maximum with the largest sqrt(|k|) P(|k|): the period of the strongest
spectral peak, weighted a little towards shorter periods. Chosen by measuring on the
built-ins and on height fields with known spacing (ridges at periods 0.1-0.3 of B and
0, 30, 45, 90 degrees; bumps of radius 0.03-0.12 on jittered lattices of 0.12-0.3; cells
of 0.1 and 0.25; "M2 element size" in `git log -p bench/RESULTS.md`): the plain power P picked the large
scale of the stones' random heights on small cells (0.36 for cells of 0.1); sqrt(|k|) P
picks the cells; |k| P or |k|^2 P (power per octave) picked the tubes' harmonics of
chainmail and weave. The radially averaged autocorrelation's first peak was the other
candidate: 10-18% long on ridges (a ring average of a 1D pattern peaks at 1.12 periods)
and 47% long on bumps of mixed sizes. A peak must be clear: 1.6 times the lowest ring an
octave towards longer periods, and at least half the band's largest sqrt(|k|) P. Without
one (``peak`` False) the element size is the ring of the largest sqrt(|k|) P: for a
spectrum falling towards short periods (a terrain, a period longer than half of B) the
longest period measured, half of B's shorter side; for flowers whose few elements in B
make a weak ring (one sampling seed of ten), that ring. Heights within 0.1 spacings RMS of
their plane are flat: no period, the longest.

The amplitude is the height map's 5th to 95th percentile range (world units).

Same bits on every x86-64 CPU (issue 40): the height map is maxima of the points' z
(exact); the mean is ``math.fsum`` (correctly rounded); the window is a polynomial
(16 x^2 (1 - x)^2, elementwise + - *); NumPy's FFT (pocketfft) picks no code by the CPU at
run time; the ring sums are ``np.bincount`` (a sequential loop); the comparisons act on
those. The period is one of a discrete set (a ring of the padded spectrum), so the patch
size it feeds takes one of a few values. tests/test_element_size.py compares an SSE4
subprocess's numbers with its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ReliefScale", "height_map", "relief_scale"]

MOST_CELLS = 128  # height-map cells along B's longer side at most (a few ms of FFT)
PAD = 4  # zero padding of the spectrum: rings of 1/(4 L), L = the map's shorter side
PROMINENCE = 1.6  # a spectral peak's least height over the dip on its long-period side
DOMINANT = 0.5  # a peak's least sqrt(k) P against the largest over the band measured
FLAT = 0.1  # heights within this many point spacings RMS of their plane: no relief (a tilted plane
# binned by the highest point per cell: 0.04)


@dataclass(frozen=True)
class ReliefScale:
    """The element size and relief amplitude of a point-set texture (world units).

    Attributes:
        period: the element size: the dominant period of the relief over the plane.
        amplitude: 5th to 95th percentile of the height map.
        angle: direction of the dominant spectral peak's wave vector, degrees in [0, 180)
            (0: the relief varies along x).
        peak: whether the spectrum had a clear peak (False: ``period`` is the ring of
            the largest sqrt(k) P over the band measured, or the longest for a flat map).
        cell: (2,) the height map's cell (x, y).
        shape: (ny, nx) of the height map.
    """

    period: float
    amplitude: float
    angle: float
    peak: bool
    cell: tuple
    shape: tuple


def height_map(points: np.ndarray, lo, hi, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The highest point's z in each cell of a grid over [lo, hi] in x and y.

    Args:
        points: (N, 3) positions, world units (float32 or float64).
        lo, hi: (>= 2,) the map's corners in x and y.
        cell: wanted cell side, world units, > 0; the grid has floor(extent / cell) cells
            per side (at least 8), so the actual cells are (extent / count) in x and y.

    Returns:
        ``(heights, cell)``: (ny, nx) float64 heights (empty cells filled with their
        nearest filled cell's, by the Euclidean distance transform), and the (2,) actual
        cell sides (x, y).

    Raises:
        ValueError: no point inside the map.
    """
    from scipy import ndimage

    p = np.asarray(points, np.float64)
    lo2, hi2 = np.asarray(lo, np.float64)[:2], np.asarray(hi, np.float64)[:2]
    ext = hi2 - lo2
    n = np.maximum(8, np.floor(ext / float(cell))).astype(np.int64)
    g = ext / n
    inside = ((p[:, :2] >= lo2) & (p[:, :2] <= hi2)).all(axis=1)
    if not inside.any():
        raise ValueError("height_map: no point lies over the map's area; give the box around the points.")
    q = p[inside]
    ij = np.minimum(np.floor((q[:, :2] - lo2) / g).astype(np.int64), n - 1)
    h = np.full(int(n[0] * n[1]), -np.inf)
    np.maximum.at(h, ij[:, 1] * n[0] + ij[:, 0], q[:, 2])
    h = h.reshape(int(n[1]), int(n[0]))
    empty = ~np.isfinite(h)
    if empty.any():
        idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        h = h[tuple(idx)]
    return h, g


def _window(n: int) -> np.ndarray:
    """(n,) 16 x^2 (1 - x)^2 at cell centres: Hann-like, elementwise arithmetic only."""
    x = (np.arange(n, dtype=np.float64) + 0.5) / n
    y = 1.0 - x
    return 16.0 * (x * x) * (y * y)


def relief_scale(points: np.ndarray, lo, hi, spacing: float, cell: float | None = None,
                 band: tuple[float, float] | None = None, near: float | None = None) -> ReliefScale:
    """The element size (dominant period) and relief amplitude over the box [lo, hi].

    Args:
        points: (N, 3) positions, world units; z is the height.
        lo, hi: (>= 2,) the area measured (a texture's B, an output's extent).
        spacing: the points' spacing (world units): the height map's cells are 1.5
            spacings, or B's longer side / 128 when that is larger.
        cell: the height map's cell instead (world units): an output measured at its
            exemplar's cell (``ReliefScale.cell[0]``), so that both see the same detail.
        band: (shortest, longest) periods considered (world units; default two cells to
            half the map's shorter side). An output is measured near its exemplar's
            period (half to twice it): is the exemplar's element size still there, and
            where; over the whole band its larger extent's long waves (seams, a stone's
            random height) can win.
        near: of the clear peaks, the one nearest this period (world units; default the
            strongest): an output's peak that tracks its exemplar's element (weave's output
            has a peak at its threads' pitch and one at 0.64 of it, either may be stronger).

    Returns:
        A :class:`ReliefScale`.
    """
    lo2, hi2 = np.asarray(lo, np.float64)[:2], np.asarray(hi, np.float64)[:2]
    if cell is None:
        cell = max(1.5 * float(spacing), float((hi2 - lo2).max()) / MOST_CELLS)
    h, g = height_map(points, lo2, hi2, float(cell))
    return _scale_of_map(h, g, float(spacing), band, near)


def _scale_of_map(h: np.ndarray, g: np.ndarray, spacing: float, band=None, near=None) -> ReliefScale:
    ny, nx = h.shape
    amplitude = float(np.percentile(h, 95) - np.percentile(h, 5))
    # heights above the map's least-squares plane (on a regular grid the x and y slopes
    # decouple: each a sum over centred coordinates, math.fsum: correctly rounded)
    cx = np.arange(nx, dtype=np.float64) - 0.5 * (nx - 1)
    cy = np.arange(ny, dtype=np.float64) - 0.5 * (ny - 1)
    mean = math.fsum(h.ravel().tolist()) / h.size
    sx = math.fsum((h * cx[None, :]).ravel().tolist()) / (ny * math.fsum((cx * cx).tolist()))
    sy = math.fsum((h * cy[:, None]).ravel().tolist()) / (nx * math.fsum((cy * cy).tolist()))
    d = (h - mean) - sx * cx[None, :] - sy * cy[:, None]
    # no relief beyond a plane (rounding, at most a tilt): no period to find
    flat = math.sqrt(math.fsum((d * d).ravel().tolist()) / d.size) <= FLAT * spacing
    a = d * (_window(ny)[:, None] * _window(nx)[None, :])
    f = np.fft.fft2(a, s=(PAD * ny, PAD * nx))
    power = f.real * f.real + f.imag * f.imag
    ky = np.fft.fftfreq(PAD * ny, float(g[1]))
    kx = np.fft.fftfreq(PAD * nx, float(g[0]))
    side = min(ny * float(g[1]), nx * float(g[0]))
    dk = 1.0 / (PAD * side)
    ring = np.rint(np.sqrt(ky[:, None] * ky[:, None] + kx[None, :] * kx[None, :]) / dk).astype(np.int64).ravel()
    sums = np.bincount(ring, power.ravel())
    counts = np.bincount(ring)
    profile = sums / np.maximum(1, counts)
    first = 2 * PAD  # periods up to half the shorter side
    last = min(len(profile) - 1, int(0.5 / float(g.max()) / dk))  # down to two cells
    if band is not None:
        first = max(first, int(math.ceil(1.0 / (float(band[1]) * dk) - 1e-9)))
        last = min(last, int(math.floor(1.0 / (float(band[0]) * dk) + 1e-9)))
    k = np.arange(len(profile), dtype=np.float64)
    score = np.sqrt(k) * profile
    best = None
    if not flat:
        for i in range(first + 1, last):
            if not (profile[i] > profile[i - 1] and profile[i] >= profile[i + 1]):
                continue
            # a peak, not a ripple: PROMINENCE times the lowest ring within an octave towards
            # longer periods (a window's sidelobes on a falling spectrum, a terrain's bumps and
            # the harmonics of a period longer than measured were 1.25-1.4; real peaks >= 1.9)
            if profile[i] < PROMINENCE * profile[max(first, i // 2):i].min():
                continue
            # and a dominant one: a ripple far below the longest periods' power (a terrain's
            # falling spectrum, a period longer than measured) is no element
            if score[i] < DOMINANT * score[first:last].max():
                continue
            if near is not None:  # the peak nearest the given period (log scale)
                if best is None or abs(math.log(i * dk * near)) < abs(math.log(best * dk * near)):
                    best = i
            elif best is None or score[i] > score[best]:
                best = i
    peak = best is not None
    if not peak:  # no clear peak: the strongest ring (a falling spectrum's: the longest period)
        best = first + int(np.argmax(score[first:last + 1])) if not flat else first
    on_ring = np.flatnonzero(ring == best)
    j = on_ring[int(np.argmax(power.ravel()[on_ring]))]
    angle = math.degrees(math.atan2(ky[j // (PAD * nx)], kx[j % (PAD * nx)])) % 180.0
    return ReliefScale(period=1.0 / (best * dk), amplitude=amplitude, angle=round(angle, 1) % 180.0, peak=peak,
                       cell=(float(g[0]), float(g[1])), shape=(ny, nx))
