"""The lattice of a periodic slab exemplar, and block matches restricted to it.

A network of linked rings (chainmail, a knitted lattice) has no element a block could
hold whole: block-by-block growth stitches arcs of different rings together and the
rings never close (issue #32: "hardly a whole loop survives"). Such exemplars are
periodic across their footprint. Copies of the exemplar moved by whole lattice vectors
agree with each other wherever the exemplar is periodic, so a scan whose every block
comes from a source position congruent to its target position modulo the lattice
makes rings that close across every stitch. The match is still the exact best one,
among those positions: where the exemplar's borders break its periodicity, the
border's copies lose.

The lattice is measured, not given: the exemplar field's self-difference (mean squared
difference of the field and its copy moved by a shift across the footprint, over their
overlap) is low at lattice vectors and high between them. Its deep local minima give
the two shortest independent vectors, refined by a least-squares fit over every
minimum the lattice explains. Everything here that feeds a decision is computed from
exact integer sums and plain IEEE arithmetic (no reduction order), so the same exemplar
gives the same lattice and the same matches on every CPU.

No paper section: our extension of Lagae, Dumont and Dutré, "Geometry Synthesis"
(Sec. 4's block copying), for interlinked elements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

__all__ = ["Lattice", "find_lattice", "lattice_origins", "lattice_text"]

# A shift is a lattice vector when the exemplar's self-difference there is at most this
# share of an unrelated copy's (0: identical, 1: unrelated). Linked rings on a 4 x 4
# lattice read 0.09-0.36 (the rings along the exemplar's borders have no partners to
# link), washers and separate tori 0.003-0.03, a terrain's best shift 0.5 and more.
LATTICE_DIFFERENCE = 0.4
# ... and when the self-difference halfway to it is at least this much higher: a valley,
# not a plateau (a tube along x differs little from itself moved by any shift along x).
LATTICE_CONTRAST = 0.2
# The basis: the shortest pair of minima matching at most this much worse than the best pair.
LATTICE_BASIS_SLACK = 0.1
# Shifts shorter than this (samples) are the field's own smoothness, not its lattice.
LATTICE_MIN_SAMPLES = 4
# Shifts up to this share of the footprint's side: their copies overlap on half of it.
LATTICE_MAX_SHARE = 0.5
# The self-difference is measured on a source at most this many samples across (the
# finest source halved as often as needed); the vectors are then refined at the finest.
LATTICE_MEASURE_SAMPLES = 64


@dataclass(frozen=True)
class Lattice:
    """Two lattice vectors across a slab's footprint.

    Attributes:
        vectors: (2, 2) float64, rows (dy, dx) in samples of the source measured.
        difference: the self-difference at each vector (0 identical, 1 unrelated).
        minima: how many local minima of the self-difference the fit used.
    """

    vectors: np.ndarray
    difference: tuple[float, float]
    minima: int

    def scaled(self, factor: float) -> np.ndarray:
        """The vectors at a source ``factor`` times finer (0.5: one level coarser)."""
        return self.vectors * float(factor)

    def extent(self, factor: float = 1.0) -> np.ndarray:
        """(2,) the (y, x) extent of the lattice's fundamental parallelogram: a box of
        valid origins at least this large holds a position congruent to every target."""
        return np.abs(self.scaled(factor)).sum(axis=0)


def _variance_times_count(a: np.ndarray) -> Fraction:
    """Sum over z slices of the slice's squared deviations from its own mean (exact):
    the field's variation across the footprint, not its rise through the slab."""
    total = Fraction(0)
    n = a.shape[1] * a.shape[2]
    for z in range(a.shape[0]):
        s1 = int(a[z].sum())
        s2 = int((a[z] * a[z]).sum())
        total += Fraction(n * s2 - s1 * s1, n)
    return total


def _self_difference(a: np.ndarray, shifts: list[tuple[int, int]]) -> dict[tuple[int, int], float]:
    """Self-difference of the int64 (Z, Y, X) field ``a`` at each (dy, dx) shift:
    mean squared difference over the overlap / (2 x mean slice variance)."""
    z, y, x = a.shape
    scale = _variance_times_count(a) * 2 / a.size
    out = {}
    for dy, dx in shifts:
        p = a[:, max(dy, 0):y + min(dy, 0), max(dx, 0):x + min(dx, 0)]
        q = a[:, max(-dy, 0):y - max(dy, 0), max(-dx, 0):x - max(dx, 0)]
        ssd = int(((p - q) ** 2).sum())
        out[(dy, dx)] = math.inf if scale == 0 else float(Fraction(ssd, p.size) / scale)
    return out


def _halve(a: np.ndarray) -> np.ndarray:
    """Mean of 2 x 2 footprint cells (z kept), as int64: the measure's coarser field."""
    z, y, x = a.shape
    a = a[:, : y // 2 * 2, : x // 2 * 2]
    return (a[:, 0::2, 0::2] + a[:, 1::2, 0::2] + a[:, 0::2, 1::2] + a[:, 1::2, 1::2]) // 4


_NEIGHBOURS = [(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]


def _minima(a: np.ndarray) -> list[tuple[float, int, int]]:
    """Deep local minima (difference, dy, dx) of the self-difference over the half plane
    of shifts (dy > 0, or dy == 0 and dx > 0; the other half mirrors it)."""
    z, y, x = a.shape
    ry, rx = int(y * LATTICE_MAX_SHARE), int(x * LATTICE_MAX_SHARE)
    shifts = [(dy, dx) for dy in range(-ry, ry + 1) for dx in range(-rx, rx + 1)]
    half = [s for s in shifts if s[0] > 0 or (s[0] == 0 and s[1] >= 0)]
    d = _self_difference(a, half)
    for (dy, dx), v in list(d.items()):
        d[(-dy, -dx)] = v
    found = []
    for (dy, dx), v in d.items():
        if not (dy > 0 or (dy == 0 and dx > 0)) or dy * dy + dx * dx < LATTICE_MIN_SAMPLES ** 2:
            continue
        if v > LATTICE_DIFFERENCE:
            continue
        around = {(dy + i, dx + j): d.get((dy + i, dx + j), math.inf) for i, j in _NEIGHBOURS}
        # a strict minimum; a flat one counts once, at its first shift
        if any(w < v or (w == v and s < (dy, dx)) for s, w in around.items()):
            continue
        mid = d.get((round(dy / 2), round(dx / 2)), math.inf)
        if mid < v + LATTICE_CONTRAST:
            continue
        found.append((v, dy, dx))
    return sorted(found, key=lambda t: (t[1] * t[1] + t[2] * t[2], t[0], t[1], t[2]))


def _reduced(u: tuple[int, int], v: tuple[int, int]) -> tuple[tuple[int, int], tuple[int, int]]:
    """Gauss's reduction of an integer basis: the same lattice, the two shortest vectors."""
    def norm(w):
        return w[0] * w[0] + w[1] * w[1]

    if norm(u) > norm(v):
        u, v = v, u
    while True:
        k = round((u[0] * v[0] + u[1] * v[1]) / norm(u))
        v = (v[0] - k * u[0], v[1] - k * u[1])
        if norm(v) >= norm(u):
            return u, v
        u, v = v, u


def _basis(minima: list[tuple[float, int, int]]):
    """The shortest two independent minima whose worse self-difference is within
    ``LATTICE_BASIS_SLACK`` of the lowest such pair's, reduced; None when every pair is parallel. A superlattice (half the true vectors, whose
    copies fall between the elements) and a sublattice (twice them) lose: their vectors
    include shifts that match worse than the true lattice's."""
    pairs = []
    shortest = minima[:12]
    for a in range(len(shortest)):
        for b in range(a + 1, len(shortest)):
            (da, ya, xa), (db, yb, xb) = shortest[a], shortest[b]
            cross = ya * xb - xa * yb
            # independent: the angle between them is at least 30 degrees
            if 2 * abs(cross) < math.hypot(ya, xa) * math.hypot(yb, xb):
                continue
            pairs.append((max(da, db), ya * ya + xa * xa + yb * yb + xb * xb, a, b, (ya, xa), (yb, xb)))
    if not pairs:
        return None
    worst = min(p[0] for p in pairs) + LATTICE_BASIS_SLACK
    best = min((p for p in pairs if p[0] <= worst), key=lambda p: (p[1], p[0], p[2], p[3]))
    best = (None, best[4], best[5])
    u, v = _reduced(best[1], best[2])
    return (0.0, u[0], u[1]), (0.0, v[0], v[1])


def _fit(basis, minima) -> tuple[np.ndarray, int]:
    """Least-squares lattice vectors from every minimum (difference, dy, dx) within 1.5
    samples of a lattice point of ``basis`` (plain float arithmetic in a fixed order: the same bits anywhere)."""
    (_, y1, x1), (_, y2, x2) = basis
    det = y1 * x2 - x1 * y2
    rows = []
    for _, dy, dx in minima:
        i = round((dy * x2 - dx * y2) / det)
        j = round((y1 * dx - x1 * dy) / det)
        if (i or j) and math.hypot(dy - i * y1 - j * y2, dx - i * x1 - j * x2) <= 1.5:
            rows.append((i, j, dy, dx))
    # normal equations (sum of c c^T) v = sum of c t, per coordinate: 2 x 2, solved by Cramer's rule
    a11 = a12 = a22 = 0.0
    by = [0.0, 0.0]
    bx = [0.0, 0.0]
    for i, j, dy, dx in rows:
        a11 += i * i
        a12 += i * j
        a22 += j * j
        by[0] += i * dy
        by[1] += j * dy
        bx[0] += i * dx
        bx[1] += j * dx
    den = a11 * a22 - a12 * a12
    if den == 0:
        return np.array([[y1, x1], [y2, x2]], np.float64), len(rows)
    v1 = ((by[0] * a22 - a12 * by[1]) / den, (bx[0] * a22 - a12 * bx[1]) / den)
    v2 = ((a11 * by[1] - a12 * by[0]) / den, (a11 * bx[1] - a12 * bx[0]) / den)
    return np.array([v1, v2], np.float64), len(rows)


def _surface_band(source: np.ndarray, band: float | None) -> np.ndarray:
    """The uint8 codes clipped to one sample either side of the surface, as int64: where
    the material is, not how far away the next element lies. The distance far from a
    surface depends on every element around, and an exemplar's border elements miss half
    of theirs: that biases the far field's best shift by a sample (linked rings: 15.0
    samples measured for a true 14.1), the surface's does not."""
    a = np.asarray(source).astype(np.int64)
    if band is None:
        return a
    k = max(1, int(round(127.5 / float(band))))
    return np.clip(a, 128 - k, 127 + k)


def _refine(a: np.ndarray, dy: float, dx: float, radius: int) -> tuple[float, float, float]:
    """The self-difference minimum near the shift (dy, dx) of the finest field ``a``: the
    lowest integer shift within ``radius`` (ties: the first), then a parabola through it and
    its neighbours along each axis (a sub-sample vertex, at most half a sample away).
    Returns (difference, dy, dx)."""
    y0, x0 = int(round(dy)), int(round(dx))
    window = [(y0 + i, x0 + j) for i in range(-radius, radius + 1) for j in range(-radius, radius + 1)]
    d = _self_difference(a, window)
    by, bx = min(window, key=lambda s: (d[s], s))
    more = [s for s in ((by - 1, bx), (by + 1, bx), (by, bx - 1), (by, bx + 1)) if s not in d]
    d.update(_self_difference(a, more))

    def vertex(lo: float, mid: float, hi: float) -> float:
        curve = lo - 2 * mid + hi
        return 0.0 if curve <= 0 else max(-0.5, min(0.5, (lo - hi) / (2 * curve)))

    c = d[(by, bx)]
    return c, by + vertex(d[(by - 1, bx)], c, d[(by + 1, bx)]), bx + vertex(d[(by, bx - 1)], c, d[(by, bx + 1)])


def find_lattice(source: np.ndarray, band: float | None = None) -> Lattice | None:
    """The lattice of a slab exemplar's footprint, or None when it has none.

    Args:
        source: (Z, Y, X) uint8 quantized distance field of a slab (z through it).
        band: the quantization band (samples; :func:`geosynth.volume.synthesis.quantize_field`):
            the self-difference is measured one sample either side of the surface
            (None: over the whole band).

    Returns:
        Lattice with vectors in samples of ``source`` (to a fraction of a sample: the
        least-squares fit of every minimum the lattice explains, each refined at the
        finest), or None (no two independent shifts with a self-difference at most
        ``LATTICE_DIFFERENCE``).
    """
    fine = _surface_band(source, band)
    a = fine
    factor = 1
    while max(a.shape[1:]) > LATTICE_MEASURE_SAMPLES:
        a = _halve(a)
        factor *= 2
    minima = _minima(a)
    basis = _basis(minima)
    if basis is None:
        return None
    refined = [_refine(fine, dy * factor, dx * factor, factor) for _, dy, dx in minima]
    scaled = tuple((0.0, y * factor, x * factor) for _, y, x in basis)
    vectors, used = _fit(scaled, refined)
    diffs = [_refine(fine, v[0], v[1], 1)[0] for v in vectors]
    return Lattice(vectors, (diffs[0], diffs[1]), used)


def lattice_origins(position, vectors: np.ndarray, last_origin) -> np.ndarray:
    """Source origins congruent to a target block's position modulo the lattice.

    Args:
        position: the block's target (y, x) origin.
        vectors: (2, 2) lattice vectors (dy, dx) at this level, samples.
        last_origin: (y, x) the largest valid source origin.

    Returns:
        (K, 2) int64 (y, x) origins round(position + i v1 + j v2) inside [0, last_origin],
        sorted and unique (K may be 0 when the source is too small for the lattice).
    """
    v = np.asarray(vectors, np.float64)
    p = np.asarray(position, np.float64)
    last = np.asarray(last_origin, np.int64)
    det = v[0, 0] * v[1, 1] - v[0, 1] * v[1, 0]
    centre = last / 2.0 - p  # i v1 + j v2 close to this puts the origin mid-source
    i0 = (centre[0] * v[1, 1] - centre[1] * v[1, 0]) / det
    j0 = (v[0, 0] * centre[1] - v[0, 1] * centre[0]) / det
    reach = int(math.ceil(float(last.max()) / max(1.0, float(np.hypot(v[:, 0], v[:, 1]).min())))) + 2
    i = np.arange(int(math.floor(i0)) - reach, int(math.floor(i0)) + reach + 2)
    j = np.arange(int(math.floor(j0)) - reach, int(math.floor(j0)) + reach + 2)
    ii, jj = np.meshgrid(i, j, indexing="ij")
    pts = p[None, :] + ii.reshape(-1, 1) * v[0] + jj.reshape(-1, 1) * v[1]
    origins = np.floor(pts + 0.5).astype(np.int64)
    inside = ((origins >= 0) & (origins <= last)).all(axis=1)
    return np.unique(origins[inside], axis=0)


def lattice_text(lattice: Lattice) -> str:
    """One line: the vectors and how periodic the exemplar is along them."""
    parts = [f"({v[1]:.1f}, {v[0]:.1f})" for v in lattice.vectors]
    diffs = ", ".join(f"{d:.2f}" for d in lattice.difference)
    return (f"lattice {parts[0]} and {parts[1]} samples (x, y), self-difference {diffs} "
            f"(0 periodic, 1 unrelated)")
