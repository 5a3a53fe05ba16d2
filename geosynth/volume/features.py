"""Feature scale of a volume: how large, high and thick are its elements, and how far
apart? The numbers a person sees first in an M1 result (issue #32), measured the same
way on the exemplar's field and the output's, so that their ratios say whether the
synthesis kept the feature scale. No paper section: our measure for Lagae, Dumont and
Dutré, "Geometry Synthesis", Sec. 6 (results).

Input: a (Z, Y, X) float signed distance field, negative inside, z up, in any units
(``spacing`` is the world size of one sample). Every length is measured below one
sample from the distances (zero crossings interpolated, partial volumes from the
distance at each sample), so a feature two samples wide is measured to a fraction of a
sample, not rounded to whole samples.

Two kinds of volume:

- *elements* (balls, rings, tubes, washers: several inside components, or one that
  does not span the footprint): every 26-connected inside component is an element;
  ``diameter`` is the volume-weighted median equivalent-sphere diameter and ``height``
  the median z-extent of the whole elements (those not touching an x/y border; all
  when none is whole).
- *relief* (a plate with rivets, a terrain: one inside component that covers the
  footprint): the elements (count, whole share, sizes) are the bumps of the top
  surface, the connected regions of the top-height map above the midpoint between its
  low (5th percentile) and high (99.5th percentile) heights; ``diameter`` is the full
  width at half maximum of the height map's autocorrelation (the typical width of a
  bump or hill; a bump count of a fractal terrain jumps with the threshold),
  ``height`` the standard deviation of the top surface height.

``thickness`` (median local thickness: twice the distance to the surface at the inside
ridge samples, the discrete medial axis) is measured the same way for both kinds;
``period``, the horizontal spacing of the top-height map from its power spectrum, is
the spectrum's peak for elements (their lattice) and 1 / its mean frequency for a
relief (a terrain's power law has no stable peak).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["ElementFeatures", "compare_features", "covers_footprint", "element_features", "format_features", "kept_whole"]

# A relief when the largest inside component covers at least this share of the columns.
RELIEF_COVER = 0.9
# The power spectrum is zero-padded to this many times the map's side, so the peak's
# frequency is read to a fraction of one cycle over the map (a 64-sample exemplar with a
# period of 13 samples has its peak between bins 4 and 5).
_PAD = 4
# The side of the tiles whose spectra are averaged (Welch): the default source resolution.
WELCH_TILE = 64


@dataclass(frozen=True)
class ElementFeatures:
    """Feature scale of one volume (see the module docstring for the definitions).

    Attributes:
        count: elements: connected inside components (relief: bumps of the top surface).
        whole_fraction: share of the elements not touching an x/y border, in [0, 1]
            (nan when there is none).
        diameter: volume-weighted median equivalent-sphere diameter of the whole elements
            (relief: autocorrelation width of the top surface), world units; nan when no
            element is whole: a network or tubes across the footprint have no element size
            (their equivalent sphere is the box's), and an output's whole specks of debris
            beside such a network are not its elements.
        height: elements: volume-weighted median z-extent of all of them (a speck of debris
            counts by its volume, as for the diameter; an element cut by the side keeps its
            height, so tubes across the footprint count too); relief: standard deviation of the top
            surface height; world units.
        thickness: median local thickness (twice the distance to the surface on the
            inside medial axis), world units (nan for an empty inside).
        period: horizontal spacing of the top surface (elements: the spectrum's
            peak; relief: 1 / its mean frequency), world units (nan for a flat top).
        relief: whether the volume was measured as a relief (one component covering
            the footprint) rather than as separate elements.
        sizes: the whole elements' sizes, ascending (volumes, world units^3; a
            relief's bumps: areas, world units^2).
        eulers: the whole elements' Euler numbers, in the order of ``sizes`` (a ball
            or a disc 1, a ring 0, a double ring -1).
        run: the inside skeleton's length per break, world units: a break is two free ends
            of the skeleton farther than a tube's thickness from the material's sides in their
            layer (:func:`_tube_run`); inf when nothing is broken (elements only; nan for a
            relief).
        extent: the material's longest horizontal side, world units (elements only; nan for a
            relief): how far the exemplar's tubes run at the most.
        spanning: share of the inside volume in elements that reach two opposite x or
            y sides of the material's bounding box (tubes across the footprint; a tube
            broken into pieces lowers it; elements only, nan for a relief).
        span: the whole elements' volume-weighted median horizontal extent (the larger
            of their x and y bounding-box sides, in whole inside samples), world units:
            the side a block across must have to hold a whole element (elements only;
            nan for a relief or when no element is whole).
        loops: independent loops of the material (first Betti number: components and
            enclosed cavities less the Euler number) per unit of its footprint's area,
            world units^-2 (elements only; nan for a relief): a ring is one loop, rings
            fused at their crossings make more and smaller ones, a ring broken into an arc
            none (issue 32: "hardly a whole loop survives").
    """

    count: int
    whole_fraction: float
    diameter: float
    height: float
    thickness: float
    period: float
    relief: bool = False
    sizes: tuple = ()
    eulers: tuple = ()
    run: float = math.nan
    extent: float = math.nan
    spanning: float = math.nan
    span: float = math.nan
    loops: float = math.nan


def _top_height(field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Top surface z (in samples, sub-sample) of each (y, x) column: the highest inside
    sample plus the interpolated zero crossing above it; columns with no inside sample
    get -0.5 (the grid's bottom face). Also the (Y, X) mask of columns with an inside sample."""
    inside = field < 0
    z_count = field.shape[0]
    has = inside.any(axis=0)
    # highest inside index per column
    top = z_count - 1 - np.argmax(inside[::-1], axis=0)
    y, x = np.indices(top.shape)
    v = field[top, y, x].astype(np.float64)
    above = np.minimum(top + 1, z_count - 1)
    va = field[above, y, x].astype(np.float64)
    # crossing between top (v < 0) and above (va >= 0); at the grid's top face: +0.5
    frac = np.where(above > top, -v / np.maximum(va - v, 1e-12), 0.5)
    h = np.where(has, top + np.clip(frac, 0.0, 1.0), -0.5)
    return h, has


def _footprint(h: np.ndarray, has: np.ndarray) -> np.ndarray:
    """The height map cropped to the box of rows and columns that are (nearly) all
    material, less one sample each side: the grid's padding columns hold no surface
    (-0.5, the grid's bottom) and a field with more padding below the plate would
    otherwise read as a higher, wider relief. The whole map when the material fills the
    grid or no such box exists."""
    rows, cols = np.flatnonzero(has.any(axis=1)), np.flatnonzero(has.any(axis=0))
    if rows.size < 10 or cols.size < 10:
        return h
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    for _ in range(2):  # the material's bounding box, then its nearly full rows, then columns
        r = np.flatnonzero(has[y0:y1, x0:x1].mean(axis=1) >= 0.98)
        if r.size < 10:
            return h
        y0, y1 = y0 + r[0], y0 + r[-1] + 1
        c = np.flatnonzero(has[y0:y1, x0:x1].mean(axis=0) >= 0.98)
        if c.size < 10:
            return h
        x0, x1 = x0 + c[0], x0 + c[-1] + 1
    if (y0, y1, x0, x1) == (0, h.shape[0], 0, h.shape[1]):
        return h  # the material fills the grid
    box = h[y0 + 1:y1 - 1, x0 + 1:x1 - 1]
    return box if min(box.shape) >= 8 else h


def _radial_power(h: np.ndarray):
    """(frequencies in cycles per sample, power summed over each ring of frequencies)
    of a (Y, X) height map by Welch's method: the mean power spectrum of Hann-windowed,
    mean-removed square tiles of WELCH_TILE samples (the map's smaller side when
    smaller) at half-tile steps, each zero-padded to _PAD times its side. Equal tiles
    give an exemplar and a larger output the same frequency band: a whole-map spectrum
    would let the larger map's lowest frequencies pull its spacing up. None for a flat
    or tiny map."""
    ny, nx = h.shape
    t = min(ny, nx, WELCH_TILE)
    if t < 8:
        return None
    win = np.outer(np.hanning(t), np.hanning(t))
    n = _PAD * t
    starts_y = sorted(set(list(range(0, ny - t + 1, t // 2)) + [ny - t]))
    starts_x = sorted(set(list(range(0, nx - t + 1, t // 2)) + [nx - t]))
    power = np.zeros((n, n // 2 + 1))
    flat = True
    for y0 in starts_y:
        for x0 in starts_x:
            d = h[y0:y0 + t, x0:x0 + t]
            d = d - d.mean()
            if np.any(np.abs(d) > 1e-9):
                flat = False
            power += np.abs(np.fft.rfft2(d * win, s=(n, n))) ** 2
    if flat:
        return None
    power[:, 1:-1] *= 2  # the half spectrum's mirrored columns
    f = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.rfftfreq(n)[None, :])
    bins = np.rint(f * n).astype(np.int64)
    radial = np.bincount(bins.ravel(), weights=power.ravel())
    return np.arange(radial.size) / n, radial


def _period(h: np.ndarray, mean: bool) -> float:
    """Horizontal spacing (in samples) of a (Y, X) height map from its power spectrum
    (:func:`_radial_power`), over periods from 2 samples to half the tile's
    side: the peak's period (``mean`` False: a lattice of elements, whose fundamental
    holds the most power), or 1 / the power-weighted mean frequency (``mean`` True: a
    relief, whose power-law spectrum's peak jumps between bins from seed to seed while
    its mean frequency moves with the feature scale and stays put). nan for a flat map."""
    got = _radial_power(h)
    if got is None:
        return math.nan
    k, radial = got
    ok = (k >= 2.0 / min(min(h.shape), WELCH_TILE)) & (k <= 0.5)
    total = radial[ok].sum()
    if not total > 0:
        return math.nan
    if mean:
        return float(total / (radial[ok] * k[ok]).sum())
    score = np.where(ok, radial, -1.0)
    i = int(np.argmax(score))
    ki = k[i]
    if 0 < i < radial.size - 1 and ok[i - 1] and ok[i + 1]:  # parabolic refinement on the padded spectrum
        a, b, c = score[i - 1], score[i], score[i + 1]
        den = a - 2 * b + c
        if den < 0:
            ki = (i + float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))) * (k[1] - k[0])
    return float(1.0 / ki)


def _correlation_width(h: np.ndarray) -> float:
    """Full width (in samples) at half maximum of the radially averaged autocorrelation
    of a (Y, X) height map (mean removed, zero-padded: no wrap): the typical width of
    its bumps and hills. nan for a flat map."""
    ny, nx = h.shape
    d = h - h.mean()
    if min(ny, nx) < 8 or not np.any(np.abs(d) > 1e-9):
        return math.nan
    spec = np.abs(np.fft.rfft2(d, s=(2 * ny, 2 * nx))) ** 2
    acf = np.fft.irfft2(spec, s=(2 * ny, 2 * nx))
    # unbiased: divide by the overlap count at each lag
    ones = np.abs(np.fft.rfft2(np.ones_like(d), s=(2 * ny, 2 * nx))) ** 2
    count = np.maximum(np.fft.irfft2(ones, s=(2 * ny, 2 * nx)), 1.0)
    acf = acf / count
    ly = np.fft.fftfreq(2 * ny, 1.0 / (2 * ny))[:, None]
    lx = np.fft.fftfreq(2 * nx, 1.0 / (2 * nx))[None, :]
    r = np.hypot(ly, lx)
    keep = r <= min(ny, nx) / 2
    bins = np.rint(r[keep]).astype(np.int64)
    prof = np.bincount(bins, weights=acf[keep]) / np.maximum(np.bincount(bins), 1)
    prof = prof / prof[0]
    below = np.flatnonzero(prof < 0.5)
    if below.size == 0:
        return math.nan
    i = int(below[0])
    # linear interpolation of the half-maximum crossing between lags i - 1 and i
    x = (i - 1) + (prof[i - 1] - 0.5) / max(prof[i - 1] - prof[i], 1e-12)
    return float(2.0 * x)


def _thickness(field: np.ndarray) -> float:
    """Median local thickness in samples: twice the inside distance at the ridge
    samples (inside samples whose distance to the surface is the largest of their
    3x3x3 neighbourhood: the discrete medial axis), each corrected by the ridge's
    sub-sample offset from it."""
    depth = np.maximum(-field, np.float32(0.0))
    if not (depth > 0).any():
        return math.nan
    peak = ndimage.maximum_filter(depth, size=3, mode="constant", cval=0.0)
    ridge = np.nonzero((depth > 0) & (depth >= peak))
    del peak
    # Sub-sample ridge: near the medial axis the depth is a tent of slope 1, d(x) =
    # r - |x - a|, so along each axis (d(+1) - d(-1)) / 2 = a, the ridge's offset from
    # the sample, and r = d(0) + |a| (a offset of at most half a cell diagonal).
    offset = np.zeros(ridge[0].size, np.float64)
    for ax in range(3):
        hi, lo = [list(ridge) for _ in range(2)]
        hi[ax] = np.minimum(ridge[ax] + 1, depth.shape[ax] - 1)
        lo[ax] = np.maximum(ridge[ax] - 1, 0)
        a = (depth[tuple(hi)].astype(np.float64) - depth[tuple(lo)]) / 2
        offset += a * a
    r = depth[ridge] + np.minimum(np.sqrt(offset), 0.5 * math.sqrt(3))
    return float(2.0 * np.median(r))


def _tube_run(inside: np.ndarray, thickness: float, margin: int = 3) -> tuple[float, float]:
    """(skeleton length per break, in samples; the material's longest (y, x) side, samples).

    A tube or a ring broken apart has two free ends (skeleton samples with one 26-neighbour);
    a tube cut by the piece's side has them too, within about its radius of the side. So an end
    counts as a break's only when it lies farther than ``thickness`` + ``margin`` samples from
    the sides of the material *in its own layer* (the inside samples within ``thickness`` of its
    z): in a woodpile each layer's rods may stop short of the layer across them, and those are
    cut, not broken. The run is the skeleton's length (its sample count) per break (two such
    ends), inf when there is none. Unlike the volume share across the footprint, a run does not
    fall as the output grows (a longer output has more places to break, and more skeleton) and
    does not reward tubes fused into a network. nan for an empty inside."""
    from skimage.morphology import skeletonize

    cols = inside.any(axis=0)
    if not cols.any():
        return math.nan, math.nan
    ys, xs = np.flatnonzero(cols.any(axis=1)), np.flatnonzero(cols.any(axis=0))
    extent = float(max(ys[-1] + 1 - ys[0], xs[-1] + 1 - xs[0]))
    skel = skeletonize(inside).astype(bool)
    neighbours = ndimage.convolve(skel.astype(np.uint8), np.ones((3, 3, 3), np.uint8), mode="constant") - 1
    reach = (thickness if math.isfinite(thickness) else 0.0) + margin
    layer = int(math.ceil(thickness)) if math.isfinite(thickness) else 1
    breaks = 0
    for z, y, x in np.argwhere(skel & (neighbours == 1)):
        cols = inside[max(0, z - layer):z + layer + 1].any(axis=0)
        ys, xs = np.flatnonzero(cols.any(axis=1)), np.flatnonzero(cols.any(axis=0))
        breaks += min(y - ys[0], ys[-1] - y, x - xs[0], xs[-1] - x) > reach
    length = float(skel.sum())
    return (length / (breaks / 2) if breaks else math.inf), extent


def _box_sides(labels: np.ndarray, boxes: list, material: bool = True, axes=(-2, -1)) -> list:
    """Per axis of ``axes`` (y, x), the (n,) bool pairs (starts at the low side, stops at
    the high side) of the labels' bounding ``boxes`` (:func:`scipy.ndimage.find_objects`)
    against the material's bounding box (``material``: an element cut by the side of an
    output padded inside its grid is cut all the same) or the grid's border."""
    out = []
    for ax in axes:
        ax = ax % labels.ndim
        here = [b for b in boxes if b is not None]
        lo = min(b[ax].start for b in here) if material else 0
        hi = max(b[ax].stop for b in here) if material else labels.shape[ax]
        out.append((np.array([b is not None and b[ax].start <= lo for b in boxes], bool),
                    np.array([b is not None and b[ax].stop >= hi for b in boxes], bool)))
    return out


def _touching(labels: np.ndarray, boxes: list, material: bool = True, axes=(-2, -1)) -> np.ndarray:
    """(n,) bool: which labels reach an x or y side of the material's bounding box (an
    exemplar's elements along its sides are not counted whole either) or of the grid
    (:func:`_box_sides`)."""
    touch = np.zeros(len(boxes), bool)
    for low, high in _box_sides(labels, boxes, material, axes):
        touch |= low | high
    return touch


def _spanning(labels: np.ndarray, boxes: list, volume: np.ndarray) -> float:
    """Share of ``volume`` (per label 1..n) in labels that reach both x sides or both
    y sides of the material's bounding box."""
    span = np.zeros(len(boxes), bool)
    for low, high in _box_sides(labels, boxes):
        span |= low & high
    total = float(volume.sum())
    return float(volume[span].sum() / total) if total > 0 else math.nan


def across_share(labels: np.ndarray) -> float:
    """Share of the inside samples of labelled (Z, Y, X) components that reach both x sides
    or both y sides of the material's bounding box (:func:`_spanning` by sample count: the
    inside mask alone, so the same for quantized codes on every device)."""
    n = int(labels.max()) if labels.size else 0
    if n == 0:
        return math.nan
    volume = np.bincount(labels.ravel(), minlength=n + 1)[1:].astype(np.float64)
    return _spanning(labels, ndimage.find_objects(labels, n), volume)


def covers_footprint(labels: np.ndarray) -> bool:
    """Whether the largest labelled (Z, Y, X) component covers RELIEF_COVER of the (y, x)
    columns: one relief (a plate with rivets, a terrain) rather than separate elements."""
    sizes = np.bincount(labels.ravel())[1:]
    if not sizes.size:
        return False
    return bool((labels == 1 + int(np.argmax(sizes))).any(axis=0).mean() >= RELIEF_COVER)


def _crossings(field: np.ndarray, inside: np.ndarray, labels: np.ndarray, n: int, up: bool) -> np.ndarray:
    """(n,) the highest (``up``) or lowest sub-sample z of each component's surface
    along z: at every inside sample whose neighbour above (below) is outside or beyond
    the grid, the sample's z plus (minus) the interpolated zero crossing. Only those
    samples are gathered (memory by the surface, not the volume)."""
    step = 1 if up else -1
    edge = np.zeros(inside.shape, bool)
    if up:
        edge[:-1] = inside[:-1] & ~inside[1:]
        edge[-1] = inside[-1]
    else:
        edge[1:] = inside[1:] & ~inside[:-1]
        edge[0] = inside[0]
    z, y, x = np.nonzero(edge)
    del edge
    v = field[z, y, x].astype(np.float64)
    zn = z + step
    beyond = (zn < 0) | (zn >= field.shape[0])
    vn = field[np.clip(zn, 0, field.shape[0] - 1), y, x].astype(np.float64)
    frac = np.where(beyond, 0.5, np.clip(-v / np.maximum(vn - v, 1e-12), 0.0, 1.0))
    value = z + step * frac
    out = np.full(n + 1, -np.inf if up else np.inf)
    (np.maximum if up else np.minimum).at(out, labels[z, y, x], value)
    return out[1:]


def _elements(field: np.ndarray, inside: np.ndarray, labels: np.ndarray, n: int):
    """(count, whole fraction, weighted median diameter, weighted median z-extent, whole
    elements' volumes, their Euler numbers, the spanning volume share, weighted median
    horizontal span of the whole elements), lengths in samples, of the 3D components."""
    idx = np.arange(1, n + 1)
    # partial volume of each sample from its distance (a plane through the cell): the
    # inside samples and the outside layer next to them, assigned to the nearest label
    occupancy = np.clip(np.float32(0.5) - field, 0.0, 1.0)
    owner = ndimage.grey_dilation(labels, size=(3, 3, 3))
    np.copyto(owner, labels, where=inside)
    owner[occupancy <= 0] = 0
    volume = np.asarray(ndimage.sum(occupancy, owner, idx), np.float64)
    del occupancy, owner
    diameter = np.cbrt(6.0 * volume / math.pi)
    extent = _crossings(field, inside, labels, n, True) - _crossings(field, inside, labels, n, False)
    boxes = ndimage.find_objects(labels, n)
    whole = ~_touching(labels, boxes)
    pick = whole if whole.any() else np.zeros(n, bool)
    eulers = _eulers(labels, np.flatnonzero(whole) + 1)
    # the larger horizontal side of each bounding box (whole elements only: an element cut by
    # the box, or a network crossing it, has no size a block could hold)
    span = np.array([max(b[1].stop - b[1].start, b[2].stop - b[2].start) if b is not None else 0 for b in boxes],
                    np.float64)
    return (n, float(whole.mean()), _weighted_median(diameter[pick], volume[pick]), _weighted_median(extent, volume),
            volume[whole], eulers, _spanning(labels, boxes, volume), _weighted_median(span[whole], volume[whole]))


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The median of ``values`` weighted by ``weights`` (a speck of debris counts by
    its size, not as one element)."""
    if values.size == 0:
        return math.nan
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    return float(values[order][min(int(np.searchsorted(cum, 0.5 * cum[-1])), values.size - 1)])


def _eulers(labels: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Euler numbers of the labelled components ``which`` (26-connected foreground in
    3D, 8-connected in 2D): 1 for a ball or disc, 0 for a ring or a torus."""
    from skimage.measure import euler_number

    slices = ndimage.find_objects(labels)
    out = []
    for k in which:
        sl = tuple(slice(max(0, a.start - 1), a.stop + 1) for a in slices[k - 1])
        # a 3D solid ball has Euler number 1 in skimage's convention (vertices - edges + faces - cells)
        out.append(int(euler_number(labels[sl] == k, connectivity=labels.ndim)))
    return np.asarray(out, np.int64)


def _bumps(h: np.ndarray):
    """(count, whole fraction, median equivalent-circle diameter) in samples of the
    regions of a height map above the midpoint of its 5th and 99.5th percentiles."""
    lo, hi = np.percentile(h, [5, 99.5])
    none = (0, math.nan, math.nan, np.zeros(0), np.zeros(0, np.int64))
    if hi - lo < 1e-6:
        return none
    labels, n = ndimage.label(h > 0.5 * (lo + hi), structure=np.ones((3, 3), bool))
    if n == 0:
        return none
    idx = np.arange(1, n + 1)
    area = np.asarray(ndimage.sum(np.ones_like(h), labels, idx), np.float64)
    # the map is the footprint already: its grid's border is the material's side
    whole = ~_touching(labels, ndimage.find_objects(labels, n), material=False, axes=(0, 1))
    pick = whole if whole.any() else np.ones(n, bool)
    return (n, float(whole.mean()), _weighted_median(2.0 * np.sqrt(area[pick] / math.pi), area[pick]), area[whole],
            _eulers(labels, np.flatnonzero(whole) + 1))


def element_features(field: np.ndarray, spacing: float = 1.0, slab: bool | None = None) -> ElementFeatures:
    """Measure the feature scale of a signed distance field.

    Args:
        field: (Z, Y, X) float signed distances, negative inside, z up (a
            :class:`~geosynth.geometry.field.Field` is taken too: its values and spacing).
            The distances are in world units; ``spacing`` converts samples.
        spacing: world size of one sample.
        slab: measure as a relief (the top surface's bumps: a plate with rivets, a
            terrain) when True, as separate elements when False; None: a relief when
            the largest inside component covers at least 90% of the (y, x) columns.

    Returns:
        ElementFeatures, lengths in world units.
    """
    from geosynth.geometry.field import Field

    if isinstance(field, Field):
        spacing = float(field.spacing[0])
        field = field.values
    f = np.asarray(field)
    if f.ndim != 3 or not np.issubdtype(f.dtype, np.floating):
        raise ValueError(f"field must be a (Z, Y, X) float array of signed distances, got {f.dtype} {f.shape}.")
    s = float(spacing)
    f = f.astype(np.float32) / np.float32(s)  # distances in samples
    inside = f < 0
    h, has = _top_height(f)
    thickness = _thickness(f)
    if not inside.any():
        return ElementFeatures(0, math.nan, math.nan, 0.0, math.nan, math.nan, False)
    labels, n = ndimage.label(inside, structure=np.ones((3, 3, 3), bool))
    if slab is None:
        slab = covers_footprint(labels)
    run = extent = spanning = span = loops = math.nan
    if slab:
        h = _footprint(h, has)
    period = _period(h, mean=bool(slab))
    if slab:
        count, whole, _, sizes, eulers = _bumps(h)
        diameter = _correlation_width(h)
        height, power = float(np.std(h)), 2
    else:
        count, whole, diameter, height, sizes, eulers, spanning, span = _elements(f, inside, labels, n)
        power = 3
        run, extent = _tube_run(inside, thickness)
        loops = _loops(inside, n) / s**2
    scale = lambda v: v * s if math.isfinite(v) else v  # noqa: E731
    order = np.argsort(sizes, kind="stable")
    return ElementFeatures(int(count), whole, scale(diameter), scale(height), scale(thickness), scale(period),
                           bool(slab), tuple(float(v) * s**power for v in np.asarray(sizes)[order]),
                           tuple(int(v) for v in np.asarray(eulers)[order]), scale(run), scale(extent), spanning,
                           scale(span), loops)


def _loops(inside: np.ndarray, n: int) -> float:
    """Independent loops per sample^2 of the inside's (y, x) bounding box: the first Betti
    number b1 = b0 + b2 - Euler number, with b0 the components ``n`` (26-connected, as they
    are labelled) and b2 the enclosed cavities (6-connected pockets of outside that do not
    reach the volume's sides: linked rings fused around a pocket make one, and left out they
    would each cancel a loop). 0 when the box is empty."""
    from skimage.measure import euler_number

    cols = np.flatnonzero(inside.any(axis=(0, 1)))
    rows = np.flatnonzero(inside.any(axis=(0, 2)))
    if len(cols) == 0:
        return 0.0
    area = float((rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1))
    outside, pockets = ndimage.label(np.pad(~inside, 1, constant_values=True))
    cavities = pockets - 1  # every pocket but the one around the padding
    return float(n + cavities - euler_number(inside, connectivity=3)) / area


def _ratio(a: float, b: float) -> float:
    if not (math.isfinite(a) and math.isfinite(b)) or a == 0:
        return math.nan
    return float(b / a)


# An output element is kept whole when its size is within this factor of a whole exemplar
# element's and its Euler number is one of theirs (a broken ring is a C, Euler 1; two
# fused rings are twice the size).
WHOLE_SIZE_TOLERANCE = 0.35


def kept_whole(exemplar: ElementFeatures, output: ElementFeatures) -> float:
    """Share of the output's whole elements (not touching an x/y border) that are
    whole copies of the exemplar's: size within :data:`WHOLE_SIZE_TOLERANCE` of a whole
    exemplar element of the same Euler number. nan when either side has no whole element."""
    if not exemplar.sizes or not output.sizes:
        return math.nan
    ex = {}
    for v, e in zip(exemplar.sizes, exemplar.eulers):
        lo, hi = ex.get(e, (math.inf, 0.0))
        ex[e] = (min(lo, v), max(hi, v))
    good = 0
    for v, e in zip(output.sizes, output.eulers):
        if e in ex and ex[e][0] * (1 - WHOLE_SIZE_TOLERANCE) <= v <= ex[e][1] * (1 + WHOLE_SIZE_TOLERANCE):
            good += 1
    return good / len(output.sizes)


def tube_connection(exemplar: ElementFeatures, output: ElementFeatures) -> float:
    """How far the output's tubes run between breaks against how far the exemplar's do: the
    output's :attr:`~ElementFeatures.run` over the exemplar's run or, when it has no break, its
    extent (its tubes run across it), at most 1: 1 when the output's tubes break no more often
    than once an exemplar's length (issue 32, "tubes stay connected"); nan for reliefs and
    empty insides."""
    need = min(exemplar.run, exemplar.extent)
    if not (math.isfinite(need) and need > 0) or math.isnan(output.run):
        return math.nan
    return float(min(1.0, output.run / need))


def compare_features(exemplar: ElementFeatures, output: ElementFeatures) -> dict[str, float]:
    """Ratios output / exemplar of ``diameter``, ``height``, ``thickness``, ``period``
    and ``whole_fraction`` (1 is kept; nan where the exemplar's is zero or undefined),
    plus ``whole``: the share of the output's whole elements that are whole copies of
    the exemplar's, neither broken nor fused (:func:`kept_whole`), ``connected``
    (:func:`tube_connection`) and ``spanning`` (the ratio of the volume shares across)."""
    out = {k: _ratio(getattr(exemplar, k), getattr(output, k))
           for k in ("diameter", "height", "thickness", "period", "whole_fraction", "loops")}
    out["whole"] = kept_whole(exemplar, output)
    out["connected"] = tube_connection(exemplar, output)
    out["spanning"] = _ratio(exemplar.spanning, output.spanning)
    return out


def format_features(exemplar: ElementFeatures, output: ElementFeatures) -> str:
    """One line: each feature's exemplar -> output value and their ratio."""
    r = compare_features(exemplar, output)
    parts = [f"{'relief' if exemplar.relief else 'elements'} {exemplar.count} -> {output.count}"]
    for k in ("diameter", "height", "thickness", "period"):
        parts.append(f"{k} {getattr(exemplar, k):.3g} -> {getattr(output, k):.3g} (x{r[k]:.2f})")
    parts.append(f"elements kept whole {r['whole']:.0%}")
    if not exemplar.relief:
        parts.append(f"volume in elements across {exemplar.spanning:.0%} -> {output.spanning:.0%}")
    if not exemplar.relief:
        parts.append(f"run between breaks {exemplar.run:.3g} -> {output.run:.3g} (connected x{r['connected']:.2f})")
        parts.append(f"loops per unit area {exemplar.loops:.3g} -> {output.loops:.3g} (x{r['loops']:.2f})")
    return ", ".join(parts)
