"""How are a point model's points coloured from a sample texture, and how well?

The public entry point of M3, :func:`texture_points`: Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", all three of its methods: the point
parameterization (Sec. 3, :mod:`geosynth.texturing.parameterize`), point neighbourhood matching
(Sec. 4, 4.1 and 4.2: :mod:`geosynth.texturing.hierarchy`, :mod:`geosynth.texturing.matching`,
:mod:`geosynth.texturing.texel_search`) and the hybrid of the two (Sec. 5). Also the quality
numbers (:func:`neighbourhood_error`), the report and the memory estimate.

Hybrid (Sec. 5): the parameterization colours the patch points; gaps are widened
towards the texture's pattern size (each round turns every patch point in the
k-neighbourhood of a gap point into a gap point, about sqrt(k) wider); matching then
colours the gaps, a coarse point counting as coloured iff all its fine points are.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from geosynth.compute.backend import get_backend
from geosynth.compute.checks import check_bool
from geosynth.core.options import keyword_defaults, settings_from
from geosynth.geometry.pointsets import PointSet
from geosynth.texturing.hierarchy import PointLevel, build_hierarchy
from geosynth.texturing.matching import DEFAULT_MATCH_BATCH, match_level
from geosynth.texturing.models import knn_table, spatial_order
from geosynth.texturing.parameterize import (
    DEFAULT_THRESHOLD, DEFAULT_WEIGHTS, GAP, CheckedModel, as_model, check_growth_options, check_k, check_up,
    colour_parameterization, frames_from_up, mean_spacing, parameterize_with_device_arrays, tangent_offsets,
)
from geosynth.texturing.texel_search import DEFAULT_M, TexelSearch, pixel_offsets
from geosynth.texturing.textures import as_texture, texture_pyramid

__all__ = ["METHODS", "TextureReport", "TexturingOptions", "neighbourhood_error", "texture_bytes", "texture_points"]

METHODS = ("param", "match", "hybrid")
QUALITY_ROTATIONS = 8  # the quality error takes the best of this many neighbourhood rotations (45 degree steps)


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
    base = tangent_offsets(level.positions, level.s_axis, level.t_axis, level.normals, sample, level.positions[nb],
                           level.unit)
    base = np.concatenate([np.zeros((len(sample), 1, 2)), base], 1)
    vals = np.concatenate([colours[sample][:, None], colours[nb]], 1)
    queries = []
    for i in range(len(sample)):
        for r in range(rotations):
            a = 2 * np.pi * r / rotations
            rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            queries.append((pixel_offsets(base[i] @ rot.T, search.m), vals[i]))
    errors = np.concatenate([search.best_batch(queries[j:j + DEFAULT_MATCH_BATCH])[1]
                             for j in range(0, len(queries), DEFAULT_MATCH_BATCH)])
    best = errors.reshape(len(sample), rotations).min(1)
    total = float((best / (vals.shape[1] * 3)).sum())
    return total / max(1, len(sample))


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
    from geosynth.core.memory import MemoryBudgetError, available_memory, format_bytes, largest_fitting, require

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
        best_m = largest_fitting(lambda m_: texture_bytes(n_pts, h, w, method=method, k=k, levels=levels, m=m_,
                                                          quality=quality), avail, 1, m)
        searching = method != "param" or quality
        z = " x 2 (two pyramid levels at once)" if levels > 1 and method != "param" else ""
        made = (f"the texel search holds the texture supersampled m x m times: ({m} x {w:,}) x ({m} x {h:,}) = "
                f"{m * m * w * h:,} pixels of about 99 B{z}, so texture_size, m and levels make its size together"
                + ("" if method != "param" else " (for the quality numbers)") if searching else "")
        fixes = [f"lower texture_size to at most {best:,} at m = {m}" if best else
                 f"even the smallest texture_size does not fit at m = {m}"]
        if best_m:
            fixes.append(f"or m (1 to 32) to at most {best_m} at this texture size")
        if levels > 1 and method != "param":
            fixes.append("or use fewer levels")
        raise MemoryBudgetError(f"{what} needs about {format_bytes(need)}, more than the {format_bytes(avail)} "
                                f"available: {made}; {', '.join(fixes)} (or free memory).",
                                option="texture_size", largest=best, estimate=need, available=avail)
    best = largest_fitting(lambda n: est(n, h, w), avail, k + 1, n_pts)
    require(need, option="count", value=n_pts, largest=best, available=avail, what=what)


require_texture_memory = _require_texture  # the CLI's check at parse time, for a built-in texture


def _check_scales(p: np.ndarray, unit: float, unit_scale: float, pattern_size, k: int, h: int, w: int,
                  method: str) -> None:
    """Refuse a ``unit_scale`` or ``pattern_size`` that maps the model or the texture to
    nothing a user would want, in one line naming the option and the range that works for
    this model and texture.

    - ``unit_scale``: one texel is ``unit_scale`` x the mean point spacing. The model's
      larger bounding-box side must span at least one neighbourhood (sqrt(k + 1) texels,
      as the texture must hold one), or every neighbourhood and patch falls into fewer
      texels than a neighbourhood spans (``texture --unit-scale 1e9``: the whole model in
      one texel); and a neighbourhood (sqrt(k + 1) spacings) must not span more texels
      than the texture's smaller side, or neighbouring points take unrelated texels.
    - ``pattern_size`` (texels, the hybrid's gap widening): at most the texture's larger
      side; a pattern cannot be larger than the texture (the widening also stops as soon
      as the gaps stop growing, so no value runs for ever).
    """
    side = math.sqrt(k + 1)
    extent = float((p.max(0) - p.min(0)).max()) if len(p) else 0.0
    spacing = unit / unit_scale
    high = extent / (side * spacing) if spacing > 0 else math.inf  # the model spans `side` texels
    low = side / min(h, w)  # a neighbourhood spans the texture's smaller side
    if not low <= unit_scale <= high:
        works = (f"from {low:.3g} to {high:.3g}" if low <= high else
                 "none: the model spans fewer point spacings than a neighbourhood texels; use a smaller k")
        raise ValueError(f"unit_scale {unit_scale:g} maps the model ({extent / spacing:,.0f} point spacings across) "
                         f"to {extent / unit:,.3g} texels and a neighbourhood (k = {k}) to {side / unit_scale:,.3g} "
                         f"texels of a {w} x {h} texture; the model must span at least a neighbourhood "
                         f"({side:.3g} texels) and a neighbourhood at most the texture: the range that works here is "
                         f"{works}.")
    if pattern_size is not None and method == "hybrid" and float(pattern_size) > max(h, w):
        raise ValueError(f"pattern_size {float(pattern_size):g} is larger than the texture ({w} x {h} texels): a "
                         f"pattern is at most the texture; use a pattern_size from 0 to {max(h, w)}.")


def _check_options(method, k, levels, m, n_pts, texture):
    """The settings against this model and texture (:class:`TexturingOptions` checked them alone):
    k below the point count, a neighbourhood the coarsest texture holds."""
    k = check_k(k, n_pts)
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


@dataclass(frozen=True)
class TexturingOptions:
    """M3's settings, declared, checked and documented once (issue 33): :func:`texture_points`
    takes them as keywords or as ``options=``, and ``geosynth texture`` builds one from its
    options. Every value is checked when the object is made, before any work (a bad one is a
    ``ValueError`` or ``TypeError`` naming it); what depends on the model and the texture (k
    below the point count, a neighbourhood the texture holds, ``unit_scale``'s and
    ``pattern_size``'s ranges) is checked by :func:`texture_points`.

    Attributes:
        method: ``"param"`` (point parameterization), ``"match"`` (neighbourhood matching) or
            ``"hybrid"`` (parameterization, then matching in the gaps).
        k: neighbours per point (>= 3); 25 or 49 in the paper.
        levels: multiresolution levels of matching (point hierarchy + texture pyramid), >= 1.
        coherent: coherent matching (candidates near the neighbours' source texels).
        m: supersampling factor of the texel search, 1 to 32.
        unit_scale: one texel = ``unit_scale`` x the mean nearest-neighbour distance (larger:
            a larger texture on the model), > 0.
        up: up vector for the texture orientation (a non-zero 3-vector), or None for a random
            direction.
        tileable: the texture tiles (unbounded patches, periodic lookups); else patches are
            capped at ``max_patch`` texels and lookups clamp at the edge.
        weights, threshold: the distortion measure (w1..w4, each >= 0) and its bound (> 0).
        max_patch: largest patch extent in texels when not tileable, >= 1 (None: 0.8 x the
            texture's smaller side).
        pattern_size: the texture's pattern size in texels, >= 0, for the hybrid's gap widening
            (None: one widening round).
        subtexel: refine each matched texel to the best supersampled pixel within half a texel
            and take that pixel's colour (our addition; False: the texel's own colour, as in
            the paper).
        batch: points searched per kernel launch (none in another's k-neighbourhood), >= 1;
            1 is the paper's sequential order with one :func:`geosynth.score_gather` call per
            point (same texel choices per query; the order differs a little).
        quality: compute the quality numbers (mean eq. 5 error of the result, of a random
            colouring and of the pure parameterization).
        quality_samples: points whose neighbourhoods the quality numbers average over, >= 1.
    """

    method: str = "hybrid"
    k: int = 25
    levels: int = 1
    coherent: bool = False
    m: int = DEFAULT_M
    unit_scale: float = 1.0
    up: tuple[float, float, float] | None = (0.0, 1.0, 0.0)
    tileable: bool = True
    weights: tuple[float, float, float, float] = DEFAULT_WEIGHTS
    threshold: float = DEFAULT_THRESHOLD
    max_patch: float | None = None
    pattern_size: float | None = None
    subtexel: bool = True
    batch: int = DEFAULT_MATCH_BATCH
    quality: bool = True
    quality_samples: int = 200

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}.")
        if isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)) or self.k < 3:
            raise ValueError(f"k (neighbours per point) must be an integer >= 3, got {self.k!r}.")
        levels, m = self.levels, self.m
        if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 1:
            raise ValueError(f"levels must be an integer >= 1, got {levels!r}.")
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 1 <= m <= 32:
            raise ValueError(f"m (supersampling) must be an integer in [1, 32], got {m!r}.")
        check_growth_options(self.weights, self.threshold, self.unit_scale, self.max_patch)
        check_up(self.up)
        pattern_size = self.pattern_size
        if pattern_size is not None and not (isinstance(pattern_size, (int, float, np.integer, np.floating))
                                             and math.isfinite(pattern_size) and pattern_size >= 0):
            raise ValueError(f"pattern_size must be a number of texels >= 0 (or None), got {pattern_size!r}.")
        for name in ("coherent", "tileable", "subtexel", "quality"):
            check_bool(name, getattr(self, name))
        for name in ("batch", "quality_samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}.")


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
    options: TexturingOptions | None = None,
) -> tuple[PointSet, TextureReport]:
    """Colour every point of a point model from a sample texture (M3).

    Args:
        points: PointSet with positions and normals (estimate missing normals with
            :func:`geosynth.geometry.pointsets.estimate_normals`).
        texture: (H, W, 3) uint8 RGB texture (grey is converted; RGBA must be opaque).
        method, k, levels, coherent, m, unit_scale, up, tileable, weights, threshold, max_patch,
            pattern_size, subtexel, batch, quality, quality_samples: the settings, each documented
            and checked once in :class:`TexturingOptions`.
        device: where the texel searches run (a device string; None: "auto").
        seed: seed of every random choice; the same seed gives the same colours on every device.
        progress: show progress bars.
        options: the settings as one :class:`TexturingOptions` instead of the keywords (then
            the keywords must keep their defaults).

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
    given = dict(method=method, k=k, levels=levels, coherent=coherent, m=m, unit_scale=unit_scale, up=up,
                 tileable=tileable, weights=weights, threshold=threshold, max_patch=max_patch,
                 pattern_size=pattern_size, subtexel=subtexel, batch=batch, quality=quality,
                 quality_samples=quality_samples)
    # every setting checked here, before any work
    options = settings_from(TexturingOptions, options, given, keyword_defaults(texture_points, given))
    method, k, levels, coherent, m, unit_scale, up, tileable = (
        options.method, options.k, options.levels, options.coherent, options.m, options.unit_scale, options.up,
        options.tileable)
    weights, threshold, max_patch, pattern_size, quality, quality_samples = (
        options.weights, options.threshold, options.max_patch, options.pattern_size, options.quality,
        options.quality_samples)
    tex, p, nrm, k, levels, m = _checked_inputs(points, texture, method, k, levels, m, quality)
    n_pts = len(p)
    rng = np.random.default_rng(seed)
    h, w = tex.shape[:2]
    if max_patch is None and not tileable:
        max_patch = 0.8 * min(h, w)
    dev_name = get_backend(device or "auto").name
    report = TextureReport(method, dev_name, n_pts, k, levels, coherent, m, 0.0)
    # everything below runs on the points in a spatial order (cache locality of the
    # neighbour reads); the colours go back to the given order at the end
    in_order, p, nrm, dist, nb = _neighbours_in_spatial_order(p, nrm, k, report)
    unit = mean_spacing(dist) * float(unit_scale)
    _check_scales(p, unit, float(unit_scale), pattern_size, k, h, w, method)
    report.unit = unit
    run_param = functools.partial(
        _parameterize, CheckedModel(p, nrm), tex, k, unit_scale=unit_scale, up=up, weights=weights,
        threshold=threshold, max_patch=None if tileable else max_patch, tileable=tileable, rng=rng,
        neighbours=(dist, nb), device=dev_name, report=report)

    colouring = _Colouring.empty(n_pts)
    colours = colouring.colours
    param_colours = None
    if method in ("param", "hybrid"):
        param, param_colours, patch_offsets = run_param()
        report.patches, report.gap_fraction = param.patch_count, param.gap_fraction
    if method == "param":
        colouring.colours[:] = param_colours
        colouring.coloured[:] = True
    else:
        # frames: the patches' own (hybrid) or from the up vector / a random direction (match)
        if method == "hybrid":
            s_ax, t_ax = _keep_patches_outside_gaps(param, param_colours, patch_offsets, nrm, nb, tex, options, rng,
                                                    colouring, report)
        else:
            s_ax, t_ax = frames_from_up(nrm, up if up is not None else rng.standard_normal(3))
            report.matched_fraction = 1.0
        t1 = time.perf_counter()
        hierarchy = build_hierarchy(p, nrm, s_ax, t_ax, k, levels, unit, rng, neighbours=(dist, nb))
        pyramid = texture_pyramid(tex, levels)
        if levels > 1:
            _timed(report, "hierarchy + pyramid", t1, n_pts)
        colours = _match_hierarchy(hierarchy, pyramid, options, m, colouring, rng, dev_name, progress, report)
    sec, rates = report.seconds, report.rates
    sec["total"] = sum(v for kk, v in sec.items())
    rates["total"] = n_pts / max(sec["total"], 1e-9)

    if quality:
        _quality_numbers(report, PointLevel(p, nrm, *frames_from_up(nrm, up if up is not None else (0.0, 1.0, 0.0)),
                                            nb, dist, unit),
                         tex, colours, param_colours, run_param, tileable, quality_samples, seed)

    given_order = np.empty_like(colours)
    given_order[in_order] = colours
    out = PointSet(points.positions, points.normals, given_order)
    return out, report


def _checked_inputs(points, texture, method, k, levels, m, quality):
    """texture_points' input checks and its memory refusal, before any allocation.

    Returns:
        (texture (H, W, 3) uint8, positions (N, 3) float64, unit normals (N, 3) float64,
        k, levels (1 for ``param``), m).
    """
    tex = as_texture(texture)
    p, nrm = as_model(points)
    k, levels, m = _check_options(method, k, levels, m, len(p), tex)
    if method == "param":
        levels = 1
    _require_texture(len(p), tex.shape[0], tex.shape[1], method, k, levels, m, quality)
    return tex, p, nrm, k, levels, m


def _timed(report: TextureReport, stage: str, t0: float, points: int) -> None:
    """Record a stage's wall seconds since ``t0`` and its rate over ``points`` points."""
    report.seconds[stage] = time.perf_counter() - t0
    report.rates[stage] = points / max(report.seconds[stage], 1e-9)


def _neighbours_in_spatial_order(p: np.ndarray, nrm: np.ndarray, k: int, report: TextureReport):
    """The points in a spatial order and their k nearest neighbours.

    Returns:
        (order (N,) int64 into the given points, positions (N, 3), normals (N, 3) in that
        order, distances (N, k) float64, neighbours (N, k) int32).
    """
    t0 = time.perf_counter()
    in_order = spatial_order(p)
    p, nrm = p[in_order], nrm[in_order]
    dist, nb = knn_table(p, k)
    _timed(report, "neighbours (kNN)", t0, len(p))
    return in_order, p, nrm, dist, nb


def _parameterize(model: CheckedModel, tex: np.ndarray, k: int, *, unit_scale, up, weights, threshold, max_patch,
                  tileable: bool, rng: np.random.Generator, neighbours, device: str, report: TextureReport):
    """The point parameterization (paper Sec. 3) and its texture mapping.

    Returns:
        (the Parameterization, (N, 3) uint8 colours, (P, 2) per-patch texture offsets).
    """
    t1 = time.perf_counter()
    par, grown = parameterize_with_device_arrays(model, k, unit_scale=unit_scale, up=up, weights=weights,
                                                 threshold=threshold, max_patch=max_patch, seed=rng,
                                                 neighbours=neighbours, device=device)
    _timed(report, "parameterization", t1, len(model.positions))
    t1 = time.perf_counter()
    cols, _, offs = colour_parameterization(model, par, tex, tileable=tileable, seed=rng, device=device,
                                            grown=grown)  # the growth's device arrays, not uploaded again
    _timed(report, "texture mapping + gaps", t1, len(model.positions))
    return par, cols, offs


@dataclass(frozen=True)
class _Colouring:
    """The points' colouring as the steps of :func:`texture_points` fill it in place: each
    point's (N, 3) uint8 colour, whether it has one, and the texel it came from (-1: none)."""

    colours: np.ndarray
    coloured: np.ndarray
    source: np.ndarray

    @classmethod
    def empty(cls, n_points: int) -> _Colouring:
        """No point coloured yet."""
        return cls(np.zeros((n_points, 3), np.uint8), np.zeros(n_points, bool), np.full(n_points, -1, np.int64))


def _keep_patches_outside_gaps(param, param_colours: np.ndarray, patch_offsets: np.ndarray, nrm: np.ndarray,
                               nb: np.ndarray, tex: np.ndarray, options: TexturingOptions, rng: np.random.Generator,
                               colouring: _Colouring, report: TextureReport) -> tuple[np.ndarray, np.ndarray]:
    """The hybrid's first step (paper Sec. 5): widen the parameterization's gaps toward the
    pattern size (each round about sqrt(k) wider), keep the patch colours and source
    texels outside them (``colouring`` updated in place), and give every gap point (and any
    point without a frame) the frame of its nearest framed neighbour.

    Returns:
        (S axes (N, 3), T axes (N, 3)) float64 frames for the matching.
    """
    k, up, pattern_size, unit_scale, tileable = (options.k, options.up, options.pattern_size, options.unit_scale,
                                                 options.tileable)
    colours, coloured, source = colouring.colours, colouring.coloured, colouring.source
    n_pts = len(nrm)
    h, w = tex.shape[:2]
    s_ax, t_ax = param.s_axis.copy(), param.t_axis.copy()
    gap = param.state == GAP
    t1 = time.perf_counter()
    width0 = math.sqrt(k) / 2
    target = (pattern_size * unit_scale) if pattern_size is not None else width0 + math.sqrt(k)
    rounds = max(0, math.ceil((target - width0) / math.sqrt(k)))
    for _ in range(rounds):
        grow = np.zeros(n_pts, bool)
        grow[nb[gap].reshape(-1)] = True
        if not (grow & ~gap).any():
            break  # the gaps cover their components: further rounds change nothing
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
    report.seconds["gap widening"] = time.perf_counter() - t1
    return s_ax, t_ax


def _level_states(hierarchy: list[PointLevel], colouring: _Colouring):
    """Colours, coloured flags and source texels per hierarchy level, finest first (the
    finest: ``colouring``'s own arrays): a coarse point is coloured iff all its fine points
    are (then it takes their rounded mean colour); coarse sources start unknown (-1)."""
    lv_col = [colouring.colours]
    lv_done = [colouring.coloured]
    lv_src = [colouring.source]
    for lvl in range(1, len(hierarchy)):
        ch = hierarchy[lvl].children
        valid = ch >= 0
        safe = np.where(valid, ch, ch[:, :1])
        done = (lv_done[-1][safe] | ~valid).all(1)
        mean = (lv_col[-1][safe].astype(np.float64) * valid[..., None]).sum(1) / valid.sum(1, keepdims=True)
        lv_col.append(np.where(done[:, None], np.rint(mean), 0).astype(np.uint8))
        lv_done.append(done)
        lv_src.append(np.full(len(ch), -1, np.int64))
    return lv_col, lv_done, lv_src


def _match_hierarchy(hierarchy: list[PointLevel], pyramid: list[np.ndarray], options: TexturingOptions, m: int,
                     colouring: _Colouring, rng: np.random.Generator, device: str, progress: bool,
                     report: TextureReport) -> np.ndarray:
    """Neighbourhood matching (paper Sec. 4) of every uncoloured point, coarsest level
    first, against ``pyramid`` (the texture pyramid, finest first, of the hierarchy's
    depth), with the options' method, tileability, coherence, subtexel refinement and
    batch, ``m`` the checked supersampling; the coarsest level of the pure matching is
    coloured randomly (Sec. 4.1).

    Returns:
        (N, 3) uint8 colours of the finest level (``colouring``'s flags and sources are
        updated in place).
    """
    method, tileable, coherent, subtexel, batch = (options.method, options.tileable, options.coherent,
                                                   options.subtexel, options.batch)
    levels = len(hierarchy)
    lv_col, lv_done, lv_src = _level_states(hierarchy, colouring)

    t1 = time.perf_counter()
    searchers = []
    matched_total = 0
    for lvl in range(levels - 1, -1, -1):
        level = hierarchy[lvl]
        top_level = lvl == levels - 1
        if top_level and method == "match" and levels > 1:
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
        search = TexelSearch(pyramid[lvl], None if coarse is None else pyramid[lvl + 1], m, reach, tileable, device)
        searchers.append(search)
        matched_total += match_level(level, pyramid[lvl], search, lv_col[lvl], lv_done[lvl], lv_src[lvl], coarse,
                                     None if coarse is None else lv_col[lvl + 1], coherent, rng, progress,
                                     f"matching level {lvl + 1}/{levels}", subtexel, batch)
    _timed(report, "neighbourhood matching", t1, matched_total)
    count = sum(s.searches for s in searchers)
    if count:
        h, w = pyramid[0].shape[:2]
        report.searches = {"count": count, "ms_each": 1e3 * sum(s.seconds for s in searchers) / count,
                           "candidates": h * w, "launches": sum(s.launches for s in searchers)}
    return lv_col[0]


def _quality_numbers(report: TextureReport, level0: PointLevel, tex: np.ndarray, colours: np.ndarray,
                     param_colours: np.ndarray | None, run_param, tileable: bool, quality_samples: int,
                     seed: int) -> None:
    """report.error: the mean eq. 5 error (:func:`neighbourhood_error`) of the result, of
    a random colouring and (matching methods) of the pure parameterization, over the
    neighbourhoods of ``quality_samples`` points."""
    t1 = time.perf_counter()
    n_pts, k = level0.neighbours.shape
    h, w = tex.shape[:2]
    search = TexelSearch(tex, None, report.m, float(np.sqrt(k) * 2 + 2), tileable, report.device)
    sample = np.sort(np.random.default_rng(seed + 1).choice(n_pts, min(quality_samples, n_pts), replace=False))
    report.error["result"] = neighbourhood_error(level0, colours, search, sample)
    random_colours = tex.reshape(-1, 3)[np.random.default_rng(seed + 2).integers(0, h * w, n_pts)]
    report.error["random"] = neighbourhood_error(level0, random_colours, search, sample)
    if report.method != "param":
        if param_colours is None:
            sec, rates = report.seconds, report.rates
            _, param_colours, _ = run_param()
            sec.pop("parameterization"), sec.pop("texture mapping + gaps")
            rates.pop("parameterization"), rates.pop("texture mapping + gaps")
        report.error["parameterization"] = neighbourhood_error(level0, param_colours, search, sample)
    report.seconds["quality numbers"] = time.perf_counter() - t1
