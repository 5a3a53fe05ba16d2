"""M1: which larger field looks like the exemplar? Volumetric geometry synthesis by
block matching on distance fields (Lagae, Dumont and Dutré, "Geometry Synthesis",
Report CW 381, K.U. Leuven, 2004, Sec. 5).

From an exemplar's signed distance field (the *source*, quantized to uint8), grow a
larger field (the *target*) block by block, coarse to fine, then extract its surface.
The method and its parameters are the report's (Sec. 5):

- Single resolution (Sec. 5.1): the target starts as random source samples; blocks
  of N^3 samples are visited in scan order (z slowest) with a step of N/2, so that in
  the interior 7 octants of each block are already synthesized and 1 is new; each
  block's best match in the source (whole blocks are matched) is copied into the
  target, overwriting only samples not yet synthesized.
- Multiresolution (Sec. 5.2): the source is subsampled by 2x2x2 averaging; the first
  level runs on the coarsest source from random samples with a relatively large
  block; each next level starts from the upsampled previous result (trilinear) and
  resynthesizes it with its own block size.
- Tileable targets wrap: a block that crosses a face continues on the opposite face,
  so copies of the output tile without seams.

Slab exemplars (beyond the paper): when the exemplar is much thinner along z than
across (:func:`is_slab`) and the target keeps its thickness, every level's block spans
the level's full thickness along z, (Z_l, B, B), and the synthesis grows across only:
a block then holds whole columns of the slab (a dome, a ring of a single layer), and
no block position along z can stack a slab's top on its bottom.

Beyond the paper (``method=``): "graphcut" pastes each block of the same
scan along a minimum-error cut through the overlap (:mod:`geosynth.volume.graphcut`) instead
of keeping every synthesized sample; "optimize" replaces the scan by texture
optimization per level (:mod:`geosynth.volume.optimize`, Kwatra et al. 2005): exact matches
of every block on a dense lattice and a robust weighted vote, iterated.

Matching is exact (the lowest source index on ties) and integer-scored, and the votes
and cuts run on the host in a fixed order, so a seed gives the same field bit for bit
on every device.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field as dc_field

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.core.constants import (M1_ACROSS_SHARE, M1_DEFAULT_BLOCK, M1_DEFAULT_RESOLUTION,
                                M1_ELEMENT_MARGIN_SAMPLES, M1_MIN_FEATURE_SAMPLES)
from geosynth.core.interpolate import lerp_axis, linear_taps
from geosynth.core.memory import require
from geosynth.core.options import keyword_defaults
from geosynth.geometry.field import Field
from geosynth.volume.blocks import block_offsets, block_shape
from geosynth.volume.examples import resolve_exemplar_mesh as _exemplar_mesh
from geosynth.volume.optimize import lattice_positions, level_stride, memory_estimate as optimize_memory
from geosynth.volume.options import (DEFAULT_METHOD, GEOMETRY_SMOOTH, METHODS, SCALE_RANGE, VolumeOptions,
                                     check_int, check_scale, is_int, level_blocks, volume_options)

__all__ = [
    "DEFAULT_METHOD",
    "LevelReport",
    "METHODS",
    "VolumeResult",
    "VolumeSettings",
    "SLAB_RATIO",
    "block_offsets",
    "block_text",
    "choose_volume_settings",
    "downsample",
    "is_terrain",
    "is_tubes_across",
    "optimizes_better",
    "is_slab",
    "max_levels",
    "resolve_method",
    "quantize_field",
    "scan_positions",
    "synthesize_volume",
]



def resolve_method(method: str, slab: bool, terrain: bool = False) -> str:
    """The method a run uses: ``method``, or for "auto" "graphcut" on a slab and
    "optimize" otherwise, a slab that ``terrain`` says is continuous
    (:func:`optimizes_better`: a terrain or tubes across) included (see DEFAULT_METHOD)."""
    if method == "auto":
        return "graphcut" if slab and not terrain else "optimize"
    return method


# A source is a terrain when it is one relief (geosynth.volume.features.covers_footprint)
# and fewer than TERRAIN_FLAT of its columns top out at its commonest height (no flat
# ground). On the zoo and the built-ins, plates with rivets, domes or cobbles have
# 0.47-0.79 of their columns on the plate, terrains 0.07-0.12.
TERRAIN_FLAT = 0.25


def is_terrain(values: np.ndarray) -> bool:
    """Whether a (Z, Y, X) source (uint8 codes, inside < 128, or float signed
    distances, inside < 0) is a terrain: a height field (:func:`is_height_field`) that is
    one relief (:func:`geosynth.volume.features.covers_footprint`) with no flat ground
    (TERRAIN_FLAT). Graphcut's seams cross such a surface as creases and steps: the zoo's
    terrain slab came out with its hills 0.80x their spacing under graphcut, 1.01x under
    texture optimization, whose histogram matching keeps the height (bench/RESULTS.md, the
    zoo); on a plate the seams run over the flat ground, and the domes' slopes score 0.98
    under graphcut against 0.93. Decided from the inside mask alone (the quantized codes'
    sign, the same on every device)."""
    return _terrain(values)


def _terrain(values: np.ndarray, labels: np.ndarray | None = None) -> bool:
    """:func:`is_terrain`, with the inside's components (:func:`_inside_labels`) when known."""
    from geosynth.volume.features import covers_footprint

    v = np.asarray(values)
    codes = v if v.dtype == np.uint8 else np.where(v < 0, 0, 255).astype(np.uint8)
    if not is_height_field(codes):
        return False
    inside = codes < 128
    if not covers_footprint(_inside_labels(codes) if labels is None else labels):
        return False
    has = inside.any(axis=0)
    top = (inside.shape[0] - 1 - np.argmax(inside[::-1], axis=0))[has]  # each column's highest inside sample
    return bool(np.bincount(top).max() < TERRAIN_FLAT * top.size)


def is_tubes_across(values: np.ndarray) -> bool:
    """Whether a (Z, Y, X) source (uint8 codes or float signed distances) is separate
    elements of which at least M1_ACROSS_SHARE of the inside runs across the footprint
    (tubes; :func:`geosynth.volume.features.across_share`). Graphcut's stitches across such
    tubes break or fuse them; texture optimization blends them on (the zoo's wavy tubes:
    block distance 0.11 of random tiling's against 0.25, their height 1.00 against 0.94;
    straight tubes 0.05 against 0.06). From the inside mask alone, as :func:`is_terrain`."""
    return _tubes_across(_inside_labels(values))


def _inside_labels(values: np.ndarray) -> np.ndarray:
    """The 26-connected components of a source's inside (uint8 codes < 128, or float < 0)."""
    from scipy import ndimage

    v = np.asarray(values)
    inside = v < 128 if v.dtype == np.uint8 else v < 0
    return ndimage.label(inside, structure=np.ones((3, 3, 3), bool))[0]


def _tubes_across(labels: np.ndarray) -> bool:
    from geosynth.volume.features import across_share, covers_footprint

    if int(labels.max()) < 2 or covers_footprint(labels):
        return False
    return bool(across_share(labels) >= M1_ACROSS_SHARE)


def optimizes_better(values: np.ndarray) -> bool:
    """Whether "auto" runs texture optimization on a slab source: a terrain
    (:func:`is_terrain`) or tubes across its footprint (:func:`is_tubes_across`); the inside
    is labelled once for both."""
    labels = _inside_labels(values)
    return _terrain(values, labels) or _tubes_across(labels)


# A source is a slab when its across sides are at least this many times its thickness.
# The built-in sources at 64 samples across: domes 5.3, rings 8 and chainmail 2.7 (one
# layer of linked rings) are slabs; fibers 2.3 (tubes in every direction), terrain 2,
# balls 1.8 and grid 1.3 are not. Measured (opencl, 64 -> 128, 3 levels): chainmail's
# elements 0.49 -> 0.69 as a slab (and 4x faster); fibers' 0.48 -> 0.37 as a slab;
# terrain the same either way.
SLAB_RATIO = 2.5


def is_slab(source_shape, target_shape) -> bool:
    """Whether a synthesis from a (Z, Y, X) source to a (Z, Y, X) target is a slab's:
    the source's thinnest side is z, ``SLAB_RATIO`` times thinner than across, and the
    target is no thicker than the source (it grows across only)."""
    z, y, x = (int(v) for v in source_shape)
    return z * SLAB_RATIO <= min(y, x) and int(target_shape[0]) <= z


def max_levels(source_shape, slab: bool | None = None) -> int:
    """The most levels a (Z, Y, X) source allows: each level halves it, and beyond log2
    of its smallest side no block fits (a slab's: of its smallest side across, while its
    thickness keeps a sample). ``slab`` None: a slab when the source is SLAB_RATIO times
    thinner along z than across."""
    z, y, x = (int(v) for v in source_shape)
    thin = slab is True or (slab is None and z * SLAB_RATIO <= min(y, x))
    most = max(1, min((y, x) if thin else (z, y, x)).bit_length() - 1)
    return min(most, z.bit_length()) if thin else most


def source_levels(source_shape, slab: bool | None = None) -> tuple[int, str]:
    """The most levels a (Z, Y, X) source allows (:func:`max_levels`) and why, for the
    levels' message."""
    return max_levels(source_shape, slab), f" (each level halves the source {tuple(source_shape)})"


def source_pyramid(source: np.ndarray, band: float, levels: int) -> list[np.ndarray]:
    """The exemplar at every level, coarsest first: a float source quantized with ``band``
    (:func:`quantize_field`), then halved ``levels - 1`` times (:func:`downsample`)."""
    if source.dtype != np.uint8:
        source = quantize_field(source, band)
    sources = [np.ascontiguousarray(source)]
    for _ in range(levels - 1):
        sources.insert(0, downsample(sources[0]))
    return sources


def downsample(values: np.ndarray) -> np.ndarray:
    """2x2x2 box average of a uint8 (Z, Y, X) volume, rounded half up; odd sizes drop
    their last sample. The same averaging the block pyramids use."""
    z, y, x = (s // 2 * 2 for s in values.shape)
    v = values[:z, :y, :x].astype(np.uint16)
    s = v.reshape(z // 2, 2, y // 2, 2, x // 2, 2).sum(axis=(1, 3, 5))
    return ((s + 4) // 8).astype(np.uint8)


def upsample(values: np.ndarray, shape: Sequence[int], wrap) -> np.ndarray:
    """Trilinear x2 upsampling of a uint8 (Z, Y, X) volume to ``shape`` (cell centres
    aligned; clamped at the faces, or periodic when ``wrap``: one bool, or one per axis
    (z, y, x)), in float32, rounded to uint8."""
    out = values.astype(np.float32)
    wraps = (bool(wrap),) * 3 if np.ndim(wrap) == 0 else tuple(bool(w) for w in wrap)
    for axis, n in enumerate(shape):
        m = out.shape[axis]
        pos = (np.arange(n) + 0.5) * m / n - 0.5
        out = lerp_axis(out, axis, linear_taps(pos, m, wraps[axis], np.float32, clamp="taps"))
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def quantize_field(distance: np.ndarray, band: float) -> np.ndarray:
    """Signed distances -> uint8 codes: -band -> 0, 0 -> 127.5 (between codes 127 and 128),
    +band -> 255, linear between, clamped outside the band.

    Args:
        distance: any-shape float array of signed distances (negative inside).
        band: half-width of the band, in the distances' units, > 0.

    Returns:
        uint8 array of the same shape (the project's one quantizer; inverse:
        :func:`dequantize_field`).
    """
    if not band > 0:
        raise ValueError(f"band must be > 0, got {band!r}.")
    t = (np.clip(distance, -band, band) + band) / (2 * band)
    return np.round(t * 255).astype(np.uint8)


def dequantize_field(values: np.ndarray, band: float) -> np.ndarray:
    """Inverse of :func:`quantize_field` (float32 distances, within the band)."""
    return (values.astype(np.float32) / 255.0 * 2.0 - 1.0) * np.float32(band)


# On a height field (a terrain, :func:`is_height_field`) whose target keeps the source's
# thickness, texture optimization matches each z slice's code histogram to the source's
# (:func:`match_histogram`) at the end of every coarser level and after each upsampling
# ("coarse+init"; "coarse": the ends of the coarser levels only; "all": also the end
# of the finest; None: never). Measured on the built-in terrain (opencl, 64 -> 96,
# seeds 1-3): relief height 0.85 -> 1.00 of the exemplar's (coarse: 0.99), hill width
# (autocorrelation) 0.87 -> 0.99, block distance 92 -> 89 (coarse: 87); "all" reached
# 1.00 but raised the block distance to 145 (the remapped codes are no longer the
# source's blocks). On balls, grid and fibers (not height fields; per-slice matching
# after the coarse levels, seed 0, 64 -> 128) the structure scores moved both ways
# (balls' elements 0.86 -> 0.79, grid's slopes 0.96 -> 0.91, fibers' block distance
# 256 -> 228): left off there.
HISTOGRAM_MATCH = "coarse+init"
# A source is a height field when at least this share of its (y, x) columns hold one
# run of inside samples (or none): no overhangs, no stacked pieces.
HEIGHT_FIELD_SHARE = 0.95


def is_height_field(values: np.ndarray) -> bool:
    """Whether a uint8 (Z, Y, X) source is a height field: HEIGHT_FIELD_SHARE of its
    columns hold at most one run of inside samples (codes < 128) along z, and it has
    inside and outside samples."""
    inside = values < 128
    if not inside.any() or inside.all():
        return False
    runs = inside[0].astype(np.int32) + (inside[1:] & ~inside[:-1]).sum(axis=0)
    return float((runs <= 1).mean()) >= HEIGHT_FIELD_SHARE


def match_histogram(target: np.ndarray, source: np.ndarray, per_slice: bool) -> np.ndarray:
    """The uint8 (Z, Y, X) ``target`` with its code histogram matched to ``source``'s,
    per z slice (``per_slice``: the two have the same Z, a slab or terrain whose
    height distribution is the share of inside samples per slice) or over the whole
    volume: a monotone lookup table of the 256 codes, code c -> the source quantile at
    the middle of c's share in the target's cumulative histogram (Heeger and Bergen
    1995; Kopf et al., "Solid Texture Synthesis from 2D Exemplars", SIGGRAPH 2007, match
    histograms inside the optimization for the same reason: a vote's averages pull the
    codes toward the middle, shrinking features and lowering relief). Samples of one
    code keep one code (no tie artifacts); integer counts only, so the same bits on every
    device."""
    out = np.empty_like(target)
    pairs = zip(target, source) if per_slice else [(target, source)]
    views = out if per_slice else [out]
    for t, s, o in ((a, b, c) for (a, b), c in zip(pairs, views)):
        tc = np.cumsum(np.bincount(t.ravel(), minlength=256)).astype(np.int64)
        sc = np.cumsum(np.bincount(s.ravel(), minlength=256)).astype(np.int64)
        nt, ns = int(tc[-1]), int(sc[-1])
        # the middle of each code's share, as a fraction mid / (2 nt): (tc_prev + tc) / 2
        mid = np.concatenate([[0], tc[:-1]]) + tc  # 2x the middle rank
        # the source code whose cumulative share first exceeds it: sc * 2 nt > mid * ns
        lut = np.searchsorted(sc * (2 * nt), mid * ns, side="right").clip(0, 255).astype(np.uint8)
        o[...] = lut[t]
    return out


def scan_positions(size: int, block: int, wrap: bool) -> list[int]:
    """Block origins along one axis: steps of block/2 from 0; without wrap the last
    block is aligned to the end, with wrap blocks run up to the end and cross it."""
    return lattice_positions(size, block, block // 2, wrap)


def _box(origin, block, shape, wrap: bool):
    """Index arrays (np.ix_) for the block (N or (bz, by, bx)) at ``origin`` (wrapping when asked)."""
    axes = [np.arange(o, o + b) % n if wrap else np.arange(o, o + b)
            for o, b, n in zip(origin, block_shape(block), shape)]
    return np.ix_(*axes)


@dataclass
class LevelReport:
    """What one resolution level did.

    Attributes:
        source_shape, target_shape: (Z, Y, X) sizes at this level.
        block: block size N, or (bz, by, bx) for a slab (bz the level's thickness).
        matches: blocks matched (texture optimization: over all its iterations).
        mean_match_distance: mean over matches of SSD / N^3 (squared uint8 units;
            texture optimization: over the last iteration's matches).
        seconds: wall time of the level.
        search: what the search was: the tree's size (nodes per level, branching
            factor) or the cascade's stages and mean blocks alive after each.
        iterations: texture-optimization iterations (1 for the scan methods).
    """

    source_shape: tuple[int, int, int]
    target_shape: tuple[int, int, int]
    block: int
    matches: int
    mean_match_distance: float
    seconds: float
    search: str = ""
    iterations: int = 1


@dataclass
class VolumeResult:
    """The synthesized field and how it was made.

    Attributes:
        quantized: (Z, Y, X) uint8 target at the finest level.
        field: the same as float32 signed distances (a Field; spacing of the source).
        source: the uint8 source the finest level matched against.
        levels: one LevelReport per level, coarsest first.
        band: the distance band of the quantization.
        timings: seconds per stage.
        method: the method that made it (:data:`METHODS`, "auto" resolved), or "random tiling".
        slab: whether the blocks spanned the full thickness (:func:`is_slab`).
        settings: what was chosen from the input (:func:`choose_volume_settings`).
        lattice: the exemplar's lattice the scan followed
            (:class:`geosynth.volume.lattice.Lattice`), or None.
        lattice_text: one line on the lattice ("" when none was looked for).
    """

    quantized: np.ndarray
    field: Field
    source: np.ndarray
    levels: list[LevelReport]
    band: float
    timings: dict = dc_field(default_factory=dict)
    method: str = "optimize"
    slab: bool = False
    settings: VolumeSettings | None = None
    lattice: object = None
    lattice_text: str = ""


def check_size(size) -> None:
    """One positive integer or three (z, y, x); floats are refused, not truncated."""
    values = [size] if np.ndim(size) == 0 else list(np.asarray(size, dtype=object).reshape(-1))
    if np.ndim(size) > 1 or len(values) not in (1, 3) or not all(is_int(v) for v in values):
        raise TypeError(f"size must be a positive integer or three of them (z, y, x), got {size!r}.")
    if any(v < 1 for v in values):
        raise ValueError(f"size must be a positive integer or three of them (z, y, x), got {size!r}.")


def check_run(seed, device, progress) -> None:
    """The arguments of one run that every M1 entry point takes beside its settings
    (:class:`~geosynth.volume.options.VolumeOptions`), checked before any work."""
    _checks.check_bool("progress", progress)
    if seed is not None:
        check_int("seed", seed, 0)
    if device is not None:
        from geosynth.compute.backend import parse_device

        parse_device(device)  # a malformed string now; absence is found when the search starts


def _as_shape(name: str, size) -> tuple[int, int, int]:
    s = np.asarray(size)
    if s.ndim == 0:
        s = np.full(3, s)
    if s.shape != (3,) or s.dtype.kind not in "iu" or (s < 1).any():
        raise ValueError(f"{name} must be a positive integer or three of them (z, y, x), got {size!r}.")
    return tuple(int(v) for v in s)


class Matcher:
    """Exact nearest block of a uint8 source: the cascade of lower bounds (default),
    the search tree, or the plain linear search (every block scored by the gather
    kernel, argmin on the device). All three return the same block."""

    def __init__(self, source: np.ndarray, block, device, search: str):
        self.block = block
        self.offsets = block_offsets(block)
        self.search = search
        self.engine = None
        # cascade: blocks alive after each stage, summed over the matches (tally_alive), and the matches
        self.alive_sums: list[int] = []
        self.alive_matches = 0
        if search == "tree" and np.ndim(block) != 0:
            raise ValueError(f"search='tree' takes cubic blocks only; a slab's block {tuple(block)} needs "
                             "search='cascade' or 'linear'.")
        if search == "tree":
            from geosynth.volume.tree import BlockSearch

            self.engine = BlockSearch(source, block, device=device)
        elif search == "cascade":
            from geosynth.volume.cascade import CascadeSearch

            self.engine = CascadeSearch(source, block, device=device)
        else:
            from geosynth.compute.backend import to_device
            from geosynth.compute.scoring import candidate_origins

            self.grid = to_device(source, "auto" if device is None else device)
            self.origins = candidate_origins(source.shape, self.offsets)

    def summary(self) -> str:
        """One line (tree: several) saying what the search was and did."""
        if self.search == "tree":
            return "tree: " + str(self.engine.stats())
        if self.search == "cascade" and self.engine.stages and self.alive_matches:
            mean = [v / self.alive_matches for v in self.alive_sums]
            cells = ", ".join(f"{c}^3" if np.ndim(c) == 0 else "x".join(map(str, c)) for c in self.engine.stages)
            return (f"cascade over {self.engine.n_blocks:,} blocks, bound cells {cells}: mean blocks alive "
                    + " -> ".join(f"{v:,.0f}" for v in mean))
        if self.search == "cascade":
            return f"cascade: every one of {self.engine.n_blocks:,} blocks scored in one launch (small search)"
        return "linear"

    def nearest_batch(self, queries: np.ndarray, thresholds=None) -> tuple[np.ndarray, np.ndarray, list]:
        """Exact nearest blocks of (Q, bz, by, bx) queries: ((Q, 3) origins, (Q,) SSDs, alive)."""
        if self.search == "cascade":
            origins, ssds, alive = self.engine.nearest_batch(queries, thresholds)
            from geosynth.volume.cascade import tally_alive

            self.alive_matches += tally_alive(self.alive_sums, alive)
            return origins, ssds, alive
        got = [self.nearest(q, None if thresholds is None else int(thresholds[i])) for i, q in enumerate(queries)]
        return (np.array([g[0] for g in got], np.int64).reshape(-1, 3), np.array([g[1] for g in got], np.int64), [])

    def nearest(self, query: np.ndarray, threshold: int | None = None,
                order: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """Exact nearest block (lowest source index on ties) and its SSD.

        ``threshold``: the SSD of any one source block (an upper bound on the best),
        letting the searches drop blocks that cannot win early; ``order``: a
        permutation of the block's samples putting the most telling first (linear).
        """
        if self.search == "tree":
            origin, ssd = self.engine.nearest(query)
            return np.asarray(origin), int(ssd)
        if self.search == "cascade":
            from geosynth.volume.cascade import tally_alive

            origin, ssd = self.engine.nearest(query, threshold=threshold)
            self.alive_matches += tally_alive(self.alive_sums, [self.engine.last_info["alive"]])
            return np.asarray(origin), int(ssd)
        from geosynth.compute.scoring import score_gather
        from geosynth.compute.selection import argmin

        offsets, values = self.offsets, query.reshape(-1)
        if order is not None:
            offsets, values = offsets[order], values[order]
        scores = score_gather(self.grid, offsets, values, threshold=threshold, keep_on_device=True)
        best = argmin(scores)
        # sync: one score comes back with the index.
        return self.origins[best], int(scores.numpy()[best])


def synthesize_level(source, target, block, matcher, wrap, rng, progress, label, random_tiles, cut=False,
                      fixed=None, lattice=None, offset=(0, 0)):
    """One level of the scan (the paper's copying, or graphcut with ``cut``), in place on
    ``target``; returns (blocks matched, mean SSD per sample). ``fixed``: None, or a
    (Z, Y, X) bool mask of given samples (a tiled run's neighbouring results): they count
    as synthesized, enter the matches and never change; blocks made only of them are skipped,
    and the scan runs away from them along y and x (from the side that holds more of them), so
    that a block meets given samples where the untiled scan meets synthesized ones.
    ``lattice``: None, or (2, 2) (dy, dx) lattice vectors at this level (a slab's,
    :mod:`geosynth.volume.lattice`): each block is the exact best among the source blocks
    whose origin is congruent to its position modulo the lattice; ``offset``: the (y, x)
    of ``target[:, 0, 0]`` in the whole level (a tiled run's tile), for that congruence."""
    shape = target.shape
    done = np.zeros(shape, bool) if fixed is None else fixed.copy()
    sides = block_shape(block)
    axes = [scan_positions(n, b, wrap) for n, b in zip(shape, sides)]
    if fixed is not None:
        for axis in (1, 2):
            per = fixed.sum(axis=tuple(a for a in range(3) if a != axis), dtype=np.int64)
            half = shape[axis] // 2
            if per[shape[axis] - half:].sum() > per[:half].sum():
                axes[axis] = axes[axis][::-1]
    positions = [(z, y, x) for z in axes[0] for y in axes[1] for x in axes[2]]
    if fixed is not None:
        positions = [p for p in positions if not fixed[_box(p, block, shape, wrap)].all()]
    ssd_sum = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(positions), desc=label, unit="block", leave=True, dynamic_ncols=True)
    last_origin = np.array(source.shape) - np.array(sides)
    matched: dict[tuple[int, int, int], np.ndarray] = {}

    def piece_at(origin):
        return source[origin[0]:origin[0] + sides[0], origin[1]:origin[1] + sides[1], origin[2]:origin[2] + sides[2]]

    try:  # an interrupted scan still ends its bar's line
        for pos in positions:
            box = _box(pos, block, shape, wrap)
            query = target[box]
            fresh = ~done[box]
            if random_tiles:  # the baseline: a random source block, no matching
                origin = np.array([rng.integers(n + 1) for n in last_origin])
                ssd = int(((piece_at(origin).astype(np.int64) - query) ** 2).sum())
            elif lattice is not None:
                where = (pos[0], pos[1] + offset[0], pos[2] + offset[1])
                origin, ssd = _lattice_match(source, query, fresh, sides, where, lattice, last_origin)
            else:
                # Coherence guesses: the earlier neighbours' matches moved on by the same step.
                # Their best SSD bounds the answer, so the search may drop hopeless blocks
                # early; the result is the same exact match.
                threshold = None
                for axis in range(3):
                    prev = list(pos)
                    i = axes[axis].index(pos[axis])
                    if i == 0:
                        continue
                    prev[axis] = axes[axis][i - 1]
                    if tuple(prev) in matched:
                        guess = matched[tuple(prev)].copy()
                        guess[axis] += pos[axis] - prev[axis] if pos[axis] > prev[axis] else 0
                        guess = np.clip(guess, 0, last_origin)
                        g = int(((piece_at(guess).astype(np.int64) - query) ** 2).sum())
                        threshold = g if threshold is None else min(threshold, g)
                order = np.argsort(fresh.reshape(-1), kind="stable")  # synthesized samples first
                origin, ssd = matcher.nearest(query, threshold=threshold, order=order)
                matched[pos] = np.asarray(origin)
            piece = piece_at(origin)
            if cut:  # graphcut: a minimum-error seam through the overlap decides which samples change
                from geosynth.volume.graphcut import min_cut, must_keep

                keep = must_keep(done, pos, block, wrap)
                fresh = min_cut(query, piece, fresh, keep if fixed is None else keep | fixed[box])
            query[fresh] = piece[fresh]
            target[box] = query
            done[box] = True
            ssd_sum += ssd
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    return len(positions), ssd_sum / max(1, len(positions)) / int(np.prod(sides))


def _lattice_match(source, query, fresh, sides, position, vectors, last_origin) -> tuple[np.ndarray, int]:
    """The best source block among those whose (y, x) origin is congruent to ``position``
    modulo the lattice (z from 0: a slab's block spans its thickness): the lowest SSD over
    the block's samples already synthesized (``~fresh``), then the one nearest the source's
    middle (the exemplar's borders break its periodicity), then the lowest origin. The
    samples not yet synthesized hold the coarser level's guess, whose layout need not follow
    the lattice: they do not vote. A handful of candidates: scored here on the host, in int64.
    Returns the origin and the SSD over the whole block."""
    from geosynth.volume.lattice import lattice_origins

    yx = lattice_origins(position[1:], vectors, last_origin[1:])
    if len(yx) == 0:  # the level's source is smaller than the lattice's cell: checked before the scan
        raise ValueError(f"no source block congruent to {tuple(position)} under the lattice {vectors.tolist()}.")
    q = query.astype(np.int64)
    given = ~fresh
    middle = np.asarray(last_origin[1:], np.int64)  # twice the middle origin: integers
    best_key, best, best_ssd = None, None, 0
    for y, x in yx:
        piece = source[0:sides[0], y:y + sides[1], x:x + sides[2]].astype(np.int64)
        diff = (piece - q) ** 2
        key = (int(diff[given].sum()), int(abs(2 * y - middle[0]) + abs(2 * x - middle[1])), int(y), int(x))
        if best_key is None or key < best_key:
            best_key, best, best_ssd = key, (0, int(y), int(x)), int(diff.sum())
    return np.array(best, np.int64), best_ssd


# Per-block bookkeeping of a level's scan (Python objects): the position tuple and its
# ints in the scan list, the matched origin (a small ndarray) and its dict entry.
_BYTES_PER_BLOCK = 500


def matcher_bytes(shape, block, search: str) -> int:
    """Bytes of one level's search structure on a uint8 source of ``shape`` (device
    buffers included: host memory on Warp CPU and PoCL)."""
    total = int(np.prod(shape, dtype=object))
    n_blocks = int(np.prod([max(0, int(s) - b + 1) for s, b in zip(shape, block_shape(block))], dtype=object))
    if search == "tree" and np.ndim(block) == 0:
        from geosynth.volume.tree import BlockSearch

        return BlockSearch.memory_estimate(tuple(int(v) for v in shape), int(block))
    if search == "cascade":  # the field, up to two float32 bound grids and their box sums; per block 40 B
        return total * 25 + n_blocks * 40
    return 2 * total + n_blocks * 40  # linear: the field on the device, origins (24 B) and scores per block


def volume_bytes(target_shape, source_shape, blocks, search: str = "cascade", float_source: bool = False,
                 baseline: bool = False, method: str = "paper", tileable: bool = False) -> int:
    """Estimated peak bytes of :func:`synthesize_volume` (beyond its input), for a
    target (Z, Y, X), a source (Z, Y, X) and the blocks per level (coarsest first;
    each N or a slab's (bz, by, bx)).

    What it counts: the uint8 source pyramid (alive throughout; 13 B per source sample
    more while a float source is quantized); then the largest of the stages, per level
    with n samples and B blocks: the first level's random start (an int64 index per
    sample and the target, 9 n), a finer level's trilinear upsampling (float32 input,
    two float32 taps, their rounded and clipped copies and the uint8 result: 15 n measured, plus
    the previous level's target and search), the scan (target and mask 2 n, 400 B per
    block of Python bookkeeping, the level's search) and the result (uint8 target and
    float32 field, 5 n); 128 KiB of small buffers (the matcher's objects, the levels' reports).
    With ``method="optimize"`` each level's scan stage also holds texture optimization's
    vote accumulators and query chunk (:func:`geosynth.volume.optimize.memory_estimate`).
    Measured (tracemalloc; RSS agrees): see tests/test_memory.py.
    """
    levels = len(blocks)
    sources = [tuple(int(v) for v in source_shape)]
    for _ in range(levels - 1):
        sources.insert(0, tuple(v // 2 for v in sources[0]))
    pyramid = sum(int(np.prod(sh, dtype=object)) for sh in sources)
    stages = [13 * int(np.prod(source_shape, dtype=object)) if float_source else 0]
    prev_n, prev_m = 0, 0
    for lvl, (sh, b) in enumerate(zip(sources, blocks)):
        shape = [int(v) // 2 ** (levels - 1 - lvl) for v in target_shape]
        n = int(np.prod(shape, dtype=object))
        n_blocks = int(np.prod([len(range(0, v, max(1, s // 2))) for v, s in zip(shape, block_shape(b))],
                               dtype=object))
        m = 0 if baseline else matcher_bytes(sh, b, search)
        stages.append(9 * n if lvl == 0 else 15 * n + prev_n + prev_m)
        vote = (optimize_memory(shape, b, level_stride(block_shape(b)[-1], lvl == levels - 1), tileable)
                if method == "optimize" and not baseline else 0)
        stages.append(2 * n + _BYTES_PER_BLOCK * n_blocks + m + vote)
        prev_n, prev_m = n, m
    stages.append(5 * prev_n + prev_m)
    return pyramid + max(stages) + (128 << 10)


def plan_blocks(source_shape, target_shape, levels: int, block, blocks: list[int], slab: bool = False) -> list[int]:
    """The block of each level (coarsest first) for a source and target (Z, Y, X):
    ``blocks`` (from :func:`level_blocks`) with the default scheme's coarse blocks
    shrunk to fit a thin source or target there (sizes given per level are taken as
    they are). With ``slab`` the blocks are the across sides B only (z spans the
    level's thickness, :func:`level_block_shapes`) and only y and x must hold them.
    Only shapes are used: nothing is allocated.

    Raises:
        ValueError: a block larger than the source or the target at its level; a slab
            target thicker than its source.
    """
    blocks = list(blocks)
    # the source pyramid's shapes (downsample halves each side, dropping an odd sample)
    source_shapes = [tuple(int(v) for v in source_shape)]
    for _ in range(levels - 1):
        source_shapes.insert(0, tuple(v // 2 for v in source_shapes[0]))
    first = 1 if slab else 0  # the axes a block must fit in
    if np.ndim(block) == 0:
        for lvl, s in enumerate(source_shapes):
            t = [n // 2 ** (levels - 1 - lvl) for n in target_shape]
            fit = 1 << (int(min(min(s[first:]), min(t[first:]))).bit_length() - 1)
            if lvl < levels - 1 and fit >= 2:
                blocks[lvl] = min(blocks[lvl], fit)
    for lvl, (s, b) in enumerate(zip(source_shapes, blocks)):
        t = tuple(n // 2 ** (levels - 1 - lvl) for n in target_shape)
        if slab and t[0] > s[0]:
            raise ValueError(f"a slab's target is no thicker than its source: level {lvl + 1} has target {t} "
                             f"and source {s}; give a size of the source's thickness or slab=False.")
        if slab and b > min(s[1:]):
            raise ValueError(
                f"block {b} at level {lvl + 1} is larger across than the slab source there {s}; "
                "use a smaller block, fewer levels or a larger source."
            )
        if slab and b > min(t[1:]):
            raise ValueError(f"the target at level {lvl + 1} {t} is smaller across than its block {b}; "
                             "use a larger size.")
        if slab:
            continue
        if b > min(s):
            raise ValueError(
                f"block {b} at level {lvl + 1} is larger than the source there {s}; "
                "use a smaller block, fewer levels or a larger source."
            )
        if b > min(t):
            raise ValueError(f"the target at level {lvl + 1} {t} is smaller than its block {b}; use a larger size.")
    return blocks


def level_block_shapes(target_shape, levels: int, blocks: list[int], slab: bool) -> list:
    """Each level's block (coarsest first): B (a cube) or, for a slab, (Z_l, B, B) with
    Z_l the target's thickness at that level (a cube again where Z_l = B)."""
    if not slab:
        return list(blocks)
    out = []
    for lvl, b in enumerate(blocks):
        z = int(target_shape[0]) // 2 ** (levels - 1 - lvl)
        out.append(int(b) if z == int(b) else (z, int(b), int(b)))
    return out


def _require_size(size, target_shape, levels: int, estimate, option: str = "size", blocks=None) -> None:
    """Refuse a target whose estimate exceeds the memory available. The largest size
    that fits keeps the form given: one number that made a cube, a cube; one number of
    :func:`synthesize_geometry` (x = y = size, z the source's), that; three numbers
    (z, y, x), z kept and y, x scaled together (multiples of the level factor)."""
    from geosynth.core.memory import available_memory, largest_fitting

    factor = 2 ** (levels - 1)
    z, y, x = target_shape
    if estimate(target_shape) <= (avail := available_memory()):
        return
    side = max(x, y)

    def scaled(s):
        return (z, max(factor, y * s // side // factor * factor), max(factor, x * s // side // factor * factor))

    if np.ndim(size) == 0 and (z, y, x) == (int(size),) * 3:
        def shape_at(s):
            return (s, s, s)
    elif np.ndim(size) == 0:
        def shape_at(s):
            return (z, s, s)
    else:
        shape_at = scaled
    # the smallest size whose every level holds its block (a multiple of the level factor)
    smallest = max([factor] + [int(b) << (levels - 1 - lvl) for lvl, b in enumerate(blocks or ())])
    smallest = -(-smallest // factor) * factor
    best = largest_fitting(lambda s: estimate(shape_at(s)), avail, smallest, side, factor)
    largest = best if best is None or np.ndim(size) == 0 else shape_at(best)
    require(estimate(target_shape), option=option, value=size, largest=largest, available=avail,
            what=f"{option} {x:,} x {y:,} x {z:,} (x y z)")

def check_source_and_size(src: np.ndarray, size, levels: int) -> tuple[bool, tuple[int, int, int]]:
    """The checks of a source volume and target size that synthesize_volume and the tiled
    synthesis share: (whether the source is float distances, which must then be finite;
    the target shape, a multiple of 2^(levels-1))."""
    float_source = src.dtype != np.uint8
    if float_source:
        if not np.issubdtype(src.dtype, np.floating):
            raise TypeError(f"source must be uint8 or float distances, got {src.dtype}.")
        _checks.check_finite("source", src)
    target_shape = _as_shape("size", size)
    factor = 2 ** (levels - 1)
    if any(s % factor for s in target_shape):
        raise ValueError(f"size {target_shape} must be a multiple of 2^(levels-1) = {factor} on every axis.")
    return float_source, target_shape


@dataclass(frozen=True)
class VolumeSettings:
    """What an M1 synthesis chose from its input (:func:`choose_volume_settings`): one
    answer for the untiled and the tiled synthesis.

    Attributes:
        slab: blocks span each level's full thickness along z (:func:`is_slab`).
        slab_auto: ``slab`` was chosen from the shapes (the caller gave None).
        method: the method that runs (:data:`METHODS`; "auto": :func:`resolve_method`).
        method_auto: ``method`` was chosen ("auto" given).
        blocks: each level's block (its side across for a slab), coarsest first
            (:func:`level_blocks`, :func:`plan_blocks`).
        block_shapes: each level's block as matched: N or (Z_l, B, B) (:func:`level_block_shapes`).
        band: the quantization band, in samples (default half the finest block).
        iterations: texture-optimization iteration caps per level, coarsest first.
        tiled: chosen for the tiled synthesis.
    """

    slab: bool
    slab_auto: bool
    method: str
    method_auto: bool
    blocks: tuple[int, ...]
    block_shapes: tuple
    band: float
    iterations: tuple[int, ...]
    tiled: bool = False

    def lines(self, source_shape) -> list[str]:
        """What was chosen, one line each: the method, and for a slab (source (Z, Y, X)) the
        slab line. The untiled and the tiled CLI print these."""
        out = [f"method: {self.method}" + (" (auto: graphcut for a slab, optimize otherwise and for a terrain or tubes across)" if self.method_auto
                                            else "")]
        if self.slab:
            z, y, x = (int(v) for v in source_shape)
            out.append(f"slab exemplar ({x} x {y} x {z} samples, x y z): blocks span its full thickness along z, "
                       "grown across only" + (" (chosen automatically)" if self.slab_auto else ""))
        return out


def choose_volume_settings(source_shape, target_shape, levels: int, block, *, slab: bool | None = None,
                           method: str = "auto", band: float | None = None, iterations=None,
                           tiled: bool = False, terrain: bool = False) -> VolumeSettings:
    """The choices of an M1 synthesis from a (Z, Y, X) source to a (Z, Y, X) target, made
    in one place for :func:`synthesize_volume` and :func:`geosynth.volume.tiled.synthesize_volume_tiled`:
    slab or not (:func:`is_slab` when ``slab`` is None), each level's block (:func:`level_blocks`,
    shrunk to fit by :func:`plan_blocks`), the method ("auto": :func:`resolve_method`), the
    band and the iteration caps (``tiled`` is recorded only: a tiled run chooses the same).
    Only shapes are used, and ``terrain`` (:func:`is_terrain` of the source, which the caller
    measures where it has one): nothing is allocated, so a tiling can be refused before any
    field is computed.

    Raises:
        ValueError: blocks that do not fit (:func:`plan_blocks`), an unknown method, bad
            iterations.
    """
    VolumeOptions(levels=levels, block=block, slab=slab, method=method, band=band, iterations=iterations)  # checked
    flat = is_slab(source_shape, target_shape) if slab is None else bool(slab)
    blocks = plan_blocks(source_shape, target_shape, levels, block, level_blocks(levels, block, flat), flat)
    shapes = level_block_shapes(target_shape, levels, blocks, flat)
    if iterations is None:
        iterations = ([12] + [6] * (levels - 2) + [3]) if levels > 1 else [6]
    caps = [iterations] * levels if np.ndim(iterations) == 0 else list(iterations)
    return VolumeSettings(flat, slab is None, resolve_method(method, flat, terrain), method == "auto",
                          tuple(int(b) for b in blocks),
                          tuple(shapes), float(blocks[-1] / 2 if band is None else band),
                          tuple(int(c) for c in caps), bool(tiled))


def synthesize_volume(
    source: np.ndarray,
    size=128,
    *,
    levels: int = 3,
    block=16,
    tileable: bool = False,
    seed: int | None = 0,
    device: str | None = None,
    search: str = "cascade",
    band: float | None = None,
    spacing: float = 1.0,
    progress: bool = True,
    baseline: bool = False,
    method: str = DEFAULT_METHOD,
    iterations=None,
    slab: bool | None = None,
    lattice: bool | None = None,
    options: VolumeOptions | None = None,
) -> VolumeResult:
    """Synthesize a larger distance field from an exemplar's (multiresolution M1).

    Args:
        source: (Z, Y, X) exemplar field: uint8 (already quantized) or float signed
            distances in units of samples (quantized here with ``band``).
        size: target size at the finest level, one int or (z, y, x); each must be a
            multiple of 2^(levels-1) and at least the finest block.
        levels, block, tileable, search, band, method, iterations, slab, lattice: the settings, each
            documented and checked once in :class:`~geosynth.volume.options.VolumeOptions`
            (``block`` None here: 16; ``band`` is used for float sources; ``result.slab`` says
            whether a slab ran).
        seed: seed of the numpy Generator drawing the random initial samples.
        device: a device string for the matching kernels (None: "auto").
        spacing: world size of one finest-level sample, for the returned Field.
        progress: show a progress bar per level.
        baseline: tile randomly chosen source blocks instead of matching (the naive
            baseline of the quality numbers; same scan and overwrite rule, whatever
            the method).
        options: the settings as one :class:`~geosynth.volume.options.VolumeOptions` instead
            of the keywords (then the keywords must keep their defaults; its ``tiles`` must
            be None).

    Returns:
        VolumeResult (uint8 and float fields, per-level reports, timings).

    Raises:
        TypeError: a non-integer size, levels, block or seed (never truncated), a
            non-bool flag, a non-numeric band or spacing, a source of another dtype.
        ValueError: bad sizes, levels < 1 or more than the source can halve, a negative
            seed, band or spacing not finite in [1e-15, 1e15], block not a power of two, block
            larger than the source at some level, target smaller than a block, NaN in the
            source, an unknown search or malformed device string.
        MemoryBudgetError: the estimate (:func:`volume_bytes`) exceeds the memory
            available (option ``"size"``), before anything is allocated.
    """
    t_start = time.perf_counter()
    src = np.asarray(source)
    if src.ndim != 3:
        raise ValueError(f"source must be a (Z, Y, X) volume, got shape {src.shape}.")
    if src.size == 0:
        raise ValueError(f"source is empty (shape {src.shape}).")
    check_size(size)
    given = dict(levels=levels, block=block, tileable=tileable, search=search, band=band, method=method,
                 iterations=iterations, slab=slab, lattice=lattice)
    opts = volume_options(options, given, keyword_defaults(synthesize_volume, given),
                          lambda chosen: source_levels(src.shape, chosen["slab"])).untiled("synthesize_volume")
    settings, target_shape = _check_volume_run(src, size, opts, seed=seed, device=device, progress=progress,
                                               spacing=spacing, baseline=baseline)
    sources = source_pyramid(src, settings.band, opts.levels)
    src = sources[-1]
    optimizing = settings.method == "optimize" and not baseline
    found, lattice_line = choose_lattice(src, settings.band, opts.lattice,
                                         settings.slab and settings.method in ("paper", "graphcut") and not baseline)
    run = _VolumeRun(opts.levels, opts.tileable, settings.slab, settings.method, settings.iterations, opts.search,
                     device, baseline, progress,
                     relief=bool(HISTOGRAM_MATCH) and optimizing and target_shape[0] == src.shape[0]
                     and is_height_field(src), lattice=found)
    rng = np.random.default_rng(seed)
    reports: list[LevelReport] = []
    target = None
    timings = {"prepare": time.perf_counter() - t_start}
    for lvl, (s, b, across) in enumerate(zip(sources, settings.block_shapes, settings.blocks)):
        t0 = time.perf_counter()
        shape = tuple(n // 2 ** (run.levels - 1 - lvl) for n in target_shape)
        target = _level_start(run, lvl, s, shape, b, target, rng)
        matcher = None if baseline else Matcher(s, b, device, run.search)
        t_build = time.perf_counter() - t0
        target, count, mean_dist, iters, search_text = _synthesize_volume_level(run, lvl, s, target, b, across, matcher, rng)
        seconds = time.perf_counter() - t0
        timings[f"level {lvl + 1} search build"] = t_build
        timings[f"level {lvl + 1}"] = seconds
        reports.append(LevelReport(s.shape, shape, b, count, mean_dist, seconds,
                                   search_text, iters))
    timings["total"] = time.perf_counter() - t_start
    distance = dequantize_field(target, settings.band) * np.float32(spacing)
    result_field = Field(distance, np.zeros(3), np.full(3, float(spacing)))
    return VolumeResult(target, result_field, src, reports, float(settings.band), timings,
                        "random tiling" if baseline else settings.method, settings.slab, settings, found, lattice_line)


def is_network(values: np.ndarray) -> bool:
    """Whether a (Z, Y, X) signed distance field (negative inside, any units) is a network
    with loops: material that is not a relief, with no whole separate element (every
    component touches the footprint's sides) and at least one loop (linked rings, a knit;
    :func:`geosynth.volume.features.element_features`)."""
    from geosynth.volume.features import element_features

    f = element_features(np.asarray(values, np.float32))
    return (not f.relief) and f.count > 0 and math.isnan(f.diameter) and math.isfinite(f.loops) and f.loops > 0


def choose_lattice(src: np.ndarray, band: float, wanted: bool | None, possible: bool):
    """The lattice a slab's scan follows (None: none) and one line saying why, for the
    untiled and the tiled synthesis alike.

    Args:
        src: the finest (Z, Y, X) uint8 source.
        band: its quantization band (samples).
        wanted: the ``lattice`` option (None: for a network, :func:`is_network`).
        possible: whether the run is a slab's scan (graphcut or paper, not the baseline).

    Returns:
        (:class:`geosynth.volume.lattice.Lattice` or None, the line; "" when none was looked for).
    """
    if wanted and not possible:  # asked for, but nothing here would follow it: say so
        return None, ("lattice: not used (it guides a slab's scan, graphcut or paper; this run is "
                      "not one)")
    if wanted is False or not possible:
        return None, ""
    from geosynth.volume.lattice import find_lattice, lattice_text

    if wanted is None and not is_network(dequantize_field(src, band)):
        return None, ""
    found = find_lattice(src, band)
    if found is None:
        return None, "lattice: none found (the exemplar is not periodic across its footprint)"
    why = "given" if wanted else "a network of linked elements: blocks follow its lattice"
    return found, f"{lattice_text(found)} ({why})"


def level_lattice(found, coarser: int, source_shape, block) -> np.ndarray | None:
    """The (2, 2) lattice vectors at a level ``coarser`` levels above the finest, or None
    (no lattice, or the level's (Z, Y, X) source has no room for the lattice's cell beside
    a ``block``: that level matches freely)."""
    if found is None:
        return None
    sides = block_shape(block)
    room = np.array([source_shape[1] - sides[1], source_shape[2] - sides[2]], np.float64)
    factor = 0.5 ** coarser
    if (found.extent(factor) > room).any():
        return None
    return found.scaled(factor)


def _check_volume_run(src: np.ndarray, size, opts: VolumeOptions, *, seed, device, progress, spacing,
                      baseline) -> tuple[VolumeSettings, tuple[int, int, int]]:
    """synthesize_volume's checks beside its settings' (the run's arguments, the source and
    size) and its choices from the input (:func:`choose_volume_settings`: slab, blocks,
    method, band, iteration caps), and the memory refusal (:func:`volume_bytes`, option
    ``"size"``), before anything is allocated. Returns (the choices, the target's shape)."""
    levels, block = opts.levels, M1_DEFAULT_BLOCK if opts.block is None else opts.block
    check_run(seed, device, progress)
    check_scale("spacing", spacing, "the world size of one sample")
    _checks.check_bool("baseline", baseline)
    float_source, target_shape = check_source_and_size(src, size, levels)
    settings = choose_volume_settings(src.shape, target_shape, levels, block, slab=opts.slab, method=opts.method,
                                      band=opts.band, iterations=opts.iterations,
                                      terrain=opts.method == "auto" and optimizes_better(src))
    blocks = list(settings.blocks)

    def estimate(shape) -> int:
        return volume_bytes(shape, src.shape, level_block_shapes(shape, levels, blocks, settings.slab), opts.search,
                            float_source, baseline, settings.method, opts.tileable)

    _require_size(size, target_shape, levels, estimate, "size", blocks)
    return settings, target_shape


@dataclass(frozen=True)
class _VolumeRun:
    """What every level of one :func:`synthesize_volume` run shares.

    Attributes:
        levels, tileable, search, device, baseline, progress: as given.
        slab, method, caps: the choices (:class:`VolumeSettings`: ``method`` resolved,
            ``caps`` its ``iterations``).
        relief: a height field's slices keep the exemplar's code histograms
            (``HISTOGRAM_MATCH``, texture optimization only).
        lattice: the exemplar's lattice a slab's scan follows (:func:`choose_lattice`), or None.
    """

    levels: int
    tileable: bool
    slab: bool
    method: str
    caps: tuple
    search: str
    device: str | None
    baseline: bool
    progress: bool
    relief: bool
    lattice: object = None

    @property
    def optimizing(self) -> bool:
        """Texture optimization makes the levels (not the scan, not the random baseline)."""
        return self.method == "optimize" and not self.baseline


def _level_start(run: _VolumeRun, lvl: int, source: np.ndarray, shape, block, coarser: np.ndarray | None,
                 rng: np.random.Generator) -> np.ndarray:
    """A level's starting field (the multiresolution synthesis, Sec. 5.2): at the coarsest,
    random source blocks (texture optimization, Kwatra et al. 2005) or random source samples
    (the scan); above it, the coarser level's result upsampled, a height field's slices given
    back the exemplar's code histograms (trilinear upsampling lowers the relief)."""
    if coarser is None and run.optimizing:
        from geosynth.volume.optimize import random_blocks

        return random_blocks(source, shape, block, rng, run.tileable)
    if coarser is None:
        return source.reshape(-1)[rng.integers(0, source.size, size=int(np.prod(shape)))].reshape(shape)
    target = upsample(coarser, shape, wrap=(run.tileable and not run.slab, run.tileable, run.tileable))
    if run.relief and HISTOGRAM_MATCH in ("coarse+init", "all"):
        target = match_histogram(target, source, per_slice=True)
    return target


def _synthesize_volume_level(run: _VolumeRun, lvl: int, source: np.ndarray, target: np.ndarray, block, across: int,
                             matcher, rng: np.random.Generator) -> tuple[np.ndarray, int, float, int, str]:
    """One level made from its matches: texture optimization (:func:`geosynth.volume.optimize.optimize_level`,
    exact matches of blocks on a lattice and a robust vote, iterated) or the scan in block
    order (the paper's Sec. 5.3 copying, graphcut pasting, or the random baseline,
    :func:`synthesize_level`; a slab's following the exemplar's lattice where it has one).
    Returns (the level's field, matches, mean match distance, iterations, the search's summary)."""
    last = lvl == run.levels - 1
    if not run.optimizing:
        label = (f"level {lvl + 1}/{run.levels} ({target.shape[2]}x{target.shape[1]}x{target.shape[0]}, "
                 f"block {block_text(block)})")
        vectors = level_lattice(run.lattice, run.levels - 1 - lvl, source.shape, block)
        count, mean_dist = synthesize_level(source, target, block, matcher, run.tileable, rng, run.progress, label,
                                            run.baseline, cut=run.method == "graphcut" and not run.baseline,
                                            lattice=vectors)
        summary = ("random tiling" if matcher is None else
                   "lattice: the best of the congruent source blocks" if vectors is not None else matcher.summary())
        return target, count, mean_dist, 1, summary
    from geosynth.volume.optimize import level_final, level_sigma, level_stride, optimize_level

    got = optimize_level(source, target, block, matcher, wrap=run.tileable, iterations=int(run.caps[lvl]),
                         stride=level_stride(across, last), sigma=level_sigma(last), final=level_final(last))
    if run.relief and (HISTOGRAM_MATCH == "all" or (HISTOGRAM_MATCH.startswith("coarse") and not last)):
        # the vote's averages lower the relief: restore each slice's code histogram (a height
        # field's height distribution is its inside share per slice)
        target = match_histogram(target, source, per_slice=True)
    changes = " -> ".join(f"{100 * c:.0f}%" for c in got["changed"]) + f" ({got['stopped']})"
    return (target, got["matches"], got["mean_distance"], got["iterations"],
            matcher.summary() + f"\ntexture optimization: {got['iterations']} iterations, matches changed {changes}")


def block_text(block) -> str:
    """"16" for a cube, "16 x 16 x 6 (x y z)" for a slab's block."""
    if np.ndim(block) == 0:
        return str(int(block))
    z, y, x = block
    return f"{x} x {y} x {z} (x y z)"


@dataclass(frozen=True)
class Settings:
    """What :func:`choose_settings` picked.

    Attributes:
        source_resolution: exemplar samples along its longest side.
        block: the finest block (or one per level), as given or chosen.
        size: the target (as :func:`synthesize_geometry` takes it), scaled with the
            resolution when that was chosen and raised.
        thickness: the exemplar's thinnest feature (median local thickness,
            :func:`geosynth.volume.features.element_features`), world units; nan when
            not measured (resolution given).
        text: one line saying what was chosen and why ("" when everything was given).
        field: the exemplar's distance Field measured at the chosen resolution, when it
            is the synthesis's (None: compute it).
    """

    source_resolution: int
    block: object
    size: object
    thickness: float
    text: str
    field: object = None


def _scaled_size(size, factor: int):
    if np.ndim(size) == 0:
        return int(size) * factor
    return tuple(int(v) * factor for v in size)


def choose_settings(mesh, size, levels: int, source_resolution: int | None = None, block=None, *,
                    device: str | None = None, drop_degenerate: bool = False, fits=None) -> Settings:
    """Source resolution, finest block and size for an exemplar mesh, from its thinnest
    feature (issue #32: the same rule for a built-in and a user's file).

    The exemplar's signed distance at the default resolution (64 samples along its
    longest side) gives its median local thickness (twice the distance to the surface on
    the medial axis, :func:`geosynth.volume.features.element_features`). A feature must
    span ``M1_MIN_FEATURE_SAMPLES`` (3) samples to survive the quantization, the block
    matching and marching cubes; a thinner exemplar gets twice the resolution, the
    block twice the samples (the same world span: the layout it copies is the one that
    worked at 64) and a size given as samples twice the samples (the world extent the
    size meant at the default resolution). Separate elements (rings, washers: whole
    ones, :attr:`~geosynth.volume.features.ElementFeatures.span`) wider than that block
    less ``M1_ELEMENT_MARGIN_SAMPLES`` get the power of two that holds one with the
    margin, where the source still holds two such blocks across (and the target one):
    a block narrower than an element copies arcs of it. Given values are kept: a given
    resolution is not measured; a given block is kept whatever the resolution.

    Args:
        mesh: the exemplar (trimesh.Trimesh, checked).
        size: the size as :func:`synthesize_geometry` takes it.
        levels: resolution levels (the grid's z count is a multiple of 2^(levels-1)).
        source_resolution, block: as given (None: choose).
        device: for the distance field.
        drop_degenerate: as :func:`synthesize_geometry`.
        fits: optional callable (size, resolution, block) -> bool: whether a raised
            choice fits in memory; when it does not, the defaults stay (and the line says so).

    Returns:
        Settings.
    """
    from geosynth.geometry.meshes import mesh_distance
    from geosynth.volume.features import element_features

    if source_resolution is not None:
        return Settings(int(source_resolution), M1_DEFAULT_BLOCK if block is None else block, size, math.nan,
                        "" if block is not None else f"settings: block {M1_DEFAULT_BLOCK} (the default; "
                        f"source resolution {int(source_resolution)} given)")
    base = M1_DEFAULT_RESOLUTION
    grid = exemplar_grid(mesh, base, multiple=2 ** (levels - 1))
    field = mesh_distance(mesh, field=grid, drop_degenerate=drop_degenerate, device=device)
    spacing = float(field.spacing[0])
    features = element_features(field.values, spacing)
    thickness = features.thickness
    samples = thickness / spacing if math.isfinite(thickness) else math.inf
    factor = 2 if samples < M1_MIN_FEATURE_SAMPLES else 1
    why = (f"thinnest feature {thickness:.3g} = {samples:.1f} samples at source resolution {base} "
           f"({'under' if factor > 1 else 'at least'} {M1_MIN_FEATURE_SAMPLES:g})")
    chosen_block = M1_DEFAULT_BLOCK * factor if block is None else block
    span_note = ""
    across = not features.relief and features.count >= 2 and features.spanning >= M1_ACROSS_SHARE
    if block is None and across:
        # separate tubes across the footprint have no size a block could hold: every stitch between
        # two blocks is where a tube may break or fuse, so the fewest stitches the source allows
        cap = _largest_block(mesh, base * factor, _scaled_size(size, factor), levels)
        if chosen_block < cap:
            chosen_block = cap
            span_note = (f"; {features.count} separate elements, {features.spanning:.0%} of the volume across the "
                         f"footprint (tubes) -> block {cap}, the largest the source holds twice across")
    elif block is None and math.isfinite(features.span):
        # the power of two that holds a whole element and the margin
        need = 1 << int(math.ceil(math.log2(max(1.0, features.span / spacing * factor + M1_ELEMENT_MARGIN_SAMPLES))))
        cap = _largest_block(mesh, base * factor, _scaled_size(size, factor), levels)
        if chosen_block < need <= cap:  # an element the source cannot hold twice across gains nothing
            chosen_block = need
            span_note = (f"; whole elements {features.span / spacing * factor:.0f} samples across at "
                         f"{base * factor} -> block {need} (holds one and {M1_ELEMENT_MARGIN_SAMPLES:g} samples)")
    note = ""
    if (factor > 1 or span_note) and fits is not None and not fits(_scaled_size(size, factor), base * factor,
                                                                   chosen_block):
        if span_note:
            note = f"; block {chosen_block} would not fit in memory, so {M1_DEFAULT_BLOCK * factor}"
            chosen_block, span_note = M1_DEFAULT_BLOCK * factor, ""
        if factor > 1 and not fits(_scaled_size(size, factor), base * factor, chosen_block):
            factor, chosen_block = 1, (M1_DEFAULT_BLOCK if block is None else block)
            note = f"; {base * 2} would not fit in memory, so {base} (thin features may break)"
    resolution = base * factor
    new_size = _scaled_size(size, factor)
    parts = [f"source resolution {resolution}"]
    parts.append(f"block {chosen_block}" + (" (given)" if block is not None else "" if span_note else
                                           " (the same world span as 16 at 64)" if factor > 1 else ""))
    if factor > 1:
        shown = new_size if np.ndim(new_size) == 0 else " x ".join(str(v) for v in tuple(new_size)[::-1])
        parts.append(f"size {shown} samples (the world extent of the size given, at resolution {base})")
    text = f"settings: {why}{span_note} -> " + ", ".join(parts) + note
    return Settings(resolution, chosen_block, new_size, float(thickness), text, field if factor == 1 else None)


def resolution_levels(source_resolution: int | None) -> tuple[int, str]:
    """The most levels a mesh exemplar sampled at ``source_resolution`` (None: the default)
    allows and why, for the levels' message."""
    resolution = (M1_DEFAULT_RESOLUTION if source_resolution is None
                  else check_int("source_resolution", source_resolution, 8))
    return (max(1, resolution.bit_length() - 1),
            f" (each level halves the source of source_resolution={resolution} samples)")


def _largest_block(mesh, resolution: int, size, levels: int) -> int:
    """The largest finest block the synthesis can use: a power of two at most half the
    source across, so that the finest level keeps candidates, and at most the target across
    (for an exemplar that is not a slab, along z too), whose uint8 score, samples x 255^2,
    stays within uint32, the matching kernels' range."""
    shape, _, _ = _exemplar_grid_geometry(mesh, resolution, multiple=2 ** (levels - 1))
    target = target_size(size, shape, levels)
    slab = is_slab(shape, target)
    axes = slice(1, None) if slab else slice(None)
    room = min(min(v // 2 for v in shape[axes]), min(target[axes]))
    cap = 1 << max(0, room.bit_length() - 1)
    while cap > 1 and cap * cap * (shape[0] if slab else cap) * 255**2 > np.iinfo(np.uint32).max:
        cap //= 2
    return cap


def _fits_geometry(mesh, size, resolution, levels, block, search, smooth, quality_samples, method, slab) -> bool:
    """Whether :func:`_require_geometry` accepts these settings."""
    from geosynth.core.memory import MemoryBudgetError

    try:
        _require_geometry(mesh, size, resolution, levels, block, search, smooth, quality_samples, method, slab)
    except (MemoryBudgetError, ValueError):
        return False
    return True


@dataclass
class GeometryResult:
    """What :func:`synthesize_geometry` returns.

    Attributes:
        mesh: the synthesized surface (trimesh.Trimesh, world units of the exemplar).
        volume: the VolumeResult (fields, per-level reports, timings).
        exemplar_field: the exemplar's signed distance Field the source was made from.
        quality: the quality numbers, if computed: {"synthesis": ..., "random tiling":
            ...}, each the block distance dict of
            :func:`geosynth.volume.quality.bidirectional_block_distance` plus "structure":
            :func:`geosynth.volume.quality.structure_report` of that field against the
            exemplar's (print it with :func:`geosynth.volume.quality.format_structure`);
            "synthesis" also has "method".
        method: the method that made the volume (:data:`METHODS`, "auto" resolved).
        timings: seconds per stage.
        cleanup: one line on the border slivers removed (:func:`drop_border_slivers`), or "".
        settings: one line: the source resolution, block and size chosen and why
            (:func:`choose_settings`); "" when all were given.
        features: the feature scale (:func:`geosynth.volume.features.element_features`)
            of "exemplar" (its field clamped to the synthesis band, as the output's is)
            and "synthesis" (and "random tiling" with the quality numbers); empty when
            quality_samples is 0.
    """

    mesh: object
    volume: VolumeResult
    exemplar_field: Field
    quality: dict
    timings: dict
    method: str = "optimize"
    features: dict = dc_field(default_factory=dict)
    settings: str = ""
    cleanup: str = ""


def synthesize_geometry(
    exemplar,
    size=128,
    *,
    source_resolution: int | None = None,
    levels: int = 3,
    block=None,
    tileable: bool = False,
    seed: int | None = 0,
    device: str | None = None,
    search: str = "cascade",
    smooth: int = GEOMETRY_SMOOTH,
    quality_samples: int = 100,
    progress: bool = True,
    drop_degenerate: bool = False,
    method: str = DEFAULT_METHOD,
    iterations=None,
    slab: bool | None = None,
    band: float | None = None,
    lattice: bool | None = None,
    options: VolumeOptions | None = None,
) -> GeometryResult:
    """Exemplar mesh in, larger mesh out: the whole M1 pipeline.

    1. The exemplar's exact signed distance on a cubic grid of ``source_resolution``
       samples along its longest side (:func:`geosynth.geometry.meshes.mesh_distance`).
    2. :func:`synthesize_volume` to ``size`` samples (same spacing as the source).
    3. Marching cubes at the zero level and Taubin smoothing
       (:func:`geosynth.geometry.surface.field_to_mesh`).
    4. Quality numbers beside the random-tiling baseline's: the block distance
       (``quality_samples`` blocks each way; 0 skips all quality numbers) and the
       structure metrics (:func:`geosynth.volume.quality.structure_report`).

    Args:
        exemplar: a trimesh.Trimesh, a mesh file path, or a built-in exemplar name
            (:data:`geosynth.volume.examples.EXEMPLARS`).
        size: the target: one number gives x = y = size samples and the source's
            thickness along z (see :func:`target_size`); three give (z, y, x).
        source_resolution, levels, block, tileable, search, smooth, quality_samples, method, iterations,
            slab, band, lattice: the settings, each documented and checked once in
            :class:`~geosynth.volume.options.VolumeOptions` (a slab exemplar, e.g. a plate with
            relief or one layer of rings, is found by its source grid's shape; the blocks then
            span its full padded thickness: ``result.volume.slab``).
        seed, device, progress: as in :func:`synthesize_volume`.
        drop_degenerate: drop the exemplar's zero-area faces instead of refusing it
            (:func:`geosynth.geometry.meshes.check_mesh`).
        options: the settings as one :class:`~geosynth.volume.options.VolumeOptions` instead
            of the keywords (then the keywords must keep their defaults; its ``tiles`` must
            be None).

    Returns:
        GeometryResult.

    Raises:
        TypeError: a non-integer size, source_resolution, levels, block, seed, smooth or
            quality_samples (never truncated), a non-bool flag.
        ValueError: as :func:`synthesize_volume`, plus source_resolution < 8, levels
            beyond log2(source_resolution), negative smooth or quality_samples, an
            exemplar that is neither a file nor a built-in name, a bad mesh.
        MemoryBudgetError: the estimate (:func:`geometry_bytes`) exceeds the memory
            available, before anything is allocated: option ``"size"`` when a smaller
            size fits at this source resolution, else ``"source_resolution"``.
    """
    check_size(size)
    given = dict(source_resolution=source_resolution, levels=levels, block=block, tileable=tileable, search=search,
                 smooth=smooth, quality_samples=quality_samples, method=method, iterations=iterations, slab=slab,
                 band=band, lattice=lattice)
    opts = volume_options(options, given, keyword_defaults(synthesize_geometry, given),
                          lambda chosen: resolution_levels(chosen["source_resolution"])).untiled("synthesize_geometry")
    source_resolution, levels, block, tileable, search = (opts.source_resolution, opts.levels, opts.block,
                                                          opts.tileable, opts.search)
    smooth = GEOMETRY_SMOOTH if opts.smooth is None else opts.smooth
    quality_samples, method, iterations, slab, band, lattice = (opts.quality_samples, opts.method, opts.iterations,
                                                                opts.slab, opts.band, opts.lattice)
    check_run(seed, device, progress)
    from geosynth.geometry.meshes import check_mesh
    from geosynth.geometry.surface import field_to_mesh
    from geosynth.volume.quality import bidirectional_block_distance, exemplar_structure, structure_kind, structure_report

    timings = {}
    t0 = time.perf_counter()
    mesh = _exemplar_mesh(exemplar, seed)
    check_mesh(mesh, "exemplar", drop_degenerate=drop_degenerate)  # empty, NaN or degenerate meshes: a clear error now
    timings["exemplar"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    settings = choose_settings(mesh, size, levels, source_resolution, block, device=device,
                               drop_degenerate=drop_degenerate,
                               fits=lambda sz, res, b: _fits_geometry(mesh, sz, res, levels, b, search, smooth,
                                                                      quality_samples, method, slab))
    size, source_resolution, block = settings.size, settings.source_resolution, settings.block
    timings["settings"] = time.perf_counter() - t0
    _require_geometry(mesh, size, source_resolution, levels, block, search, smooth, quality_samples, method, slab)
    t0 = time.perf_counter()
    # settings.field: the field the settings were measured on, when it is the one the synthesis needs
    distance_in_samples, spacing, exemplar_field = exemplar_distance(mesh, source_resolution, levels, device=device,
                                                                     drop_degenerate=drop_degenerate,
                                                                     field=settings.field)
    timings["exemplar distance field"] = time.perf_counter() - t0
    kind = None
    if quality_samples:  # the structure metrics' kind decides their memory: the estimate again, now exact
        kind = structure_kind(exemplar_field)  # its cores are dropped: they are not held through the synthesis
        _require_geometry(mesh, size, source_resolution, levels, block, search, smooth, quality_samples, method,
                          slab, kind)
    size = target_size(size, exemplar_field.shape, levels)
    vol = synthesize_volume(distance_in_samples, size, levels=levels, block=block, tileable=tileable, seed=seed,
                            device=device, search=search, spacing=spacing, progress=progress, method=method,
                            iterations=iterations, slab=slab, band=band, lattice=lattice)
    timings.update({f"synthesis {k}": v for k, v in vol.timings.items()})
    t0 = time.perf_counter()
    reach = max(BORDER_SLIVER_SAMPLES, 0.5 * settings.thickness / spacing) if math.isfinite(settings.thickness) \
        else BORDER_SLIVER_SAMPLES
    cleaned, slivers = drop_border_slivers(vol.quantized, 2 * reach)
    if slivers:
        vol.quantized = cleaned
        vol.field = Field(dequantize_field(cleaned, vol.band) * np.float32(spacing), vol.field.origin,
                          vol.field.spacing)
    timings["border slivers"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out_mesh = field_to_mesh(vol.field, level=0.0, smooth=smooth, close=True)
    timings["marching cubes + smoothing"] = time.perf_counter() - t0
    quality = {}
    if quality_samples:
        t0 = time.perf_counter()
        finest = vol.levels[-1].block  # a slab's: the full thickness along z
        base = synthesize_volume(distance_in_samples, size, levels=levels, block=block, tileable=tileable, seed=seed,
                                 device=device, search=search, spacing=spacing, progress=False, baseline=True,
                                 slab=vol.slab, band=vol.band)
        quality["synthesis"] = bidirectional_block_distance(vol.source, vol.quantized, finest, samples=quality_samples,
                                                            seed=seed, device=device)
        quality["random tiling"] = bidirectional_block_distance(base.source, base.quantized, finest,
                                                                samples=quality_samples, seed=seed, device=device)
        # the structure metrics ride inside each side's dict, so a loop over quality.items()
        # still finds the block distances
        ex_structure = exemplar_structure(exemplar_field) if kind == "elements" else exemplar_field  # labelled once
        for key, fld in (("synthesis", vol.field), ("random tiling", base.field)):
            quality[key]["structure"] = structure_report(ex_structure, fld, kind, periodic=tileable)
        quality["synthesis"]["method"] = vol.method
        features = synthesis_features(exemplar_field, vol, base)
        timings["quality numbers"] = time.perf_counter() - t0
    note = (f"dropped {slivers} sliver{'s' if slivers > 1 else ''} of cut elements along the x/y faces (loose "
            f"pieces reaching at most {reach:.1f} samples "
            "in)") if slivers else ""
    return GeometryResult(out_mesh, vol, exemplar_field, quality, timings, vol.method, features if quality else {},
                          settings.text, note)


# A piece that touches an x/y face of the output and reaches at most this many samples
# into it (or half the exemplar's median thickness, if more) is a sliver of an element
# cut by the face, disconnected from the rest: loose debris along the border (issue #32:
# the tori lattice left eight 2-sample stubs along x = 0). The exemplar, cut by its own
# bounding box, has none.
BORDER_SLIVER_SAMPLES = 2.0


def drop_border_slivers(quantized: np.ndarray, thickness_samples: float) -> tuple[np.ndarray, int]:
    """Remove the inside pieces (26-connected, codes < 128) of a uint8 (Z, Y, X) field that
    touch an x or y face and reach at most max(BORDER_SLIVER_SAMPLES, thickness / 2)
    samples into the volume from it (the piece's extent across that face); their
    samples become code 128 (just outside). Returns (the field, pieces removed); the
    input is not changed."""
    from scipy import ndimage

    inside = quantized < 128
    labels, n = ndimage.label(inside, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return quantized, 0
    reach = max(BORDER_SLIVER_SAMPLES, 0.5 * thickness_samples) if math.isfinite(thickness_samples) \
        else BORDER_SLIVER_SAMPLES
    drop = []
    sizes = np.bincount(labels.ravel())
    largest = int(np.argmax(sizes[1:])) + 1
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None or k == largest:
            continue
        _, ys, xs = sl
        ny, nx = quantized.shape[1:]
        cut = ((ys.start == 0 or ys.stop == ny) and ys.stop - ys.start <= reach) or \
              ((xs.start == 0 or xs.stop == nx) and xs.stop - xs.start <= reach)
        if cut:
            drop.append(k)
    if not drop:
        return quantized, 0
    out = quantized.copy()
    mask = np.isin(labels, drop)
    out[mask] = 128
    return out, len(drop)


def synthesis_features(exemplar_field: Field, vol: VolumeResult, base: VolumeResult | None = None) -> dict:
    """The feature scale of the exemplar (its distances clamped to the synthesis band,
    as the output's are: the same thickness ceiling on both sides) and of the output
    (and the random tiling's): {"exemplar", "synthesis"[, "random tiling"]} ->
    :class:`geosynth.volume.features.ElementFeatures`. Both sides are measured the same
    way (a relief or elements, decided on the exemplar)."""
    from geosynth.volume.features import element_features

    spacing = float(exemplar_field.spacing[0])
    limit = np.float32(vol.band * spacing)
    ex = element_features(np.clip(exemplar_field.values, -limit, limit), spacing)
    out = {"exemplar": ex, "synthesis": element_features(vol.field.values, spacing, ex.relief)}
    if base is not None:
        out["random tiling"] = element_features(base.field.values, spacing, ex.relief)
    return out


# Marching cubes faces per sample of the synthesized field, per exemplar surface area in
# cells (area / spacing^2 / samples): measured 2.2-4.2 on the five built-in exemplars at
# source resolutions 24 and 32, targets 64 and 128 (the synthesis roughens the surface
# and the caps of a closed slab grow with its side, not its area); 3.1 keeps every case
# within 1.4x. Peak bytes per face of field_to_mesh (close=True): 96-105 without
# smoothing, 258-268 with Taubin smoothing.
_FACES_PER_AREA_CELL = 3.1
_MESH_FACE_BYTES = (105, 270)
# Traced peak of geosynth.volume.quality.structure_report: the surface metrics 459-466 B per
# marching-cubes face of the larger of the exemplar's and the output's meshes (one at a
# time: terrain 64-256, domes 128); the element metrics ~25 B per output sample at refinement 1 (chainmail, balls), finer
# refinements only where the memory then available allows (metrics._refined_sample_cap).
_STRUCTURE_FACE_BYTES = 470
_STRUCTURE_SAMPLE_BYTES = 26


def geometry_bytes(grid_shape, spacing: float, area: float, target_shape, blocks, search: str = "cascade",
                   smooth: int = 10, quality_samples: int = 100, method: str = "paper",
                   structure: str | None = None) -> int:
    """Estimated peak bytes of :func:`synthesize_geometry` (beyond the exemplar mesh and
    its BVH), for the exemplar grid (Z, Y, X) of ``spacing``, the exemplar's surface
    ``area`` (world units^2) and the target (Z, Y, X).

    What it counts: the exemplar's field and its copy in samples (8 B per grid sample,
    alive throughout) plus the largest stage: the exemplar's distance field
    (:func:`geosynth.geometry.meshes.grid_distance_bytes`), the synthesis (:func:`volume_bytes`,
    float source), the surface (the result's uint8 and float32 fields, 5 B per target
    sample, and field_to_mesh's peak per marching-cubes face; faces estimated from the
    exemplar's area per sample) and the random-tiling baseline of the quality numbers
    (the result, its mesh at ~60 B per face, and a baseline synthesis), then the
    structure metrics beside both fields (the larger of the surface metrics' meshes of
    exemplar and output, or the element metrics' labels: ``structure`` is the kind,
    "surface" or "elements", from :func:`geosynth.volume.quality.structure_kind`; None, before
    the exemplar's field is known, takes the smaller); 1 MiB of small buffers.
    """
    from geosynth.geometry.meshes import grid_distance_bytes

    g = int(np.prod(grid_shape, dtype=object))
    n = int(np.prod(target_shape, dtype=object))
    faces = int(_FACES_PER_AREA_CELL * area / spacing**2 / max(g, 1) * n)
    stages = [
        grid_distance_bytes(grid_shape),
        volume_bytes(target_shape, grid_shape, blocks, search, float_source=True, method=method),
        5 * n + _MESH_FACE_BYTES[smooth > 0] * faces,
    ]
    if quality_samples:
        stages.append(5 * n + 60 * faces + volume_bytes(target_shape, grid_shape, blocks, search, True, baseline=True))
        exemplar_faces = int(_FACES_PER_AREA_CELL * area / spacing**2)
        kinds = {"surface": _STRUCTURE_FACE_BYTES * max(faces, exemplar_faces), "elements": _STRUCTURE_SAMPLE_BYTES * n}
        if structure is not None and structure not in kinds:
            raise ValueError(f"structure must be 'surface', 'elements' or None, got {structure!r}.")
        metrics = min(kinds.values()) if structure is None else kinds[structure]
        stages.append(10 * n + 60 * faces + metrics)
    return 8 * g + max(stages) + (1 << 20)


def _require_geometry(mesh, size, source_resolution, levels: int, block, search: str, smooth: int,
                      quality_samples: int, method: str, slab: bool | None = None,
                      structure: str | None = None) -> None:
    """Refuse a synthesize_geometry whose estimate exceeds the memory available, naming
    ``size`` when a smaller one fits at this source resolution, else ``source_resolution``
    (``structure``: the structure metrics' kind once the exemplar's field is known)."""
    from geosynth.core.memory import available_memory, largest_fitting

    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}.")
    factor = 2 ** (levels - 1)
    area = float(mesh.area)
    base_blocks = level_blocks(levels, block)
    if structure is None and quality_samples and mesh.body_count == 1:
        structure = "surface"  # one piece: its cores are one (the surface metrics, the larger), but for thin necks

    def estimate(sz, res) -> int:
        shape, _, spacing = _exemplar_grid_geometry(mesh, res, multiple=factor)
        target = target_size(sz, shape, levels)
        try:  # the synthesis's own choices (choose_volume_settings)
            chosen = choose_volume_settings(shape, target, levels, block, slab=slab, method=method)
            blocks, runs = list(chosen.block_shapes), chosen.method
        except ValueError:  # blocks that do not fit a small trial: as given (ValueErrors come later)
            flat = is_slab(shape, target) if slab is None else bool(slab)
            blocks, runs = level_block_shapes(target, levels, base_blocks, flat), resolve_method(method, flat)
        need = geometry_bytes(shape, spacing, area, target, blocks, search, smooth, quality_samples, runs, structure)
        if method == "auto" and runs == "graphcut":  # a slab that turns out a terrain or tubes runs optimize (optimizes_better)
            need = max(need, geometry_bytes(shape, spacing, area, target, blocks, search, smooth, quality_samples,
                                            "optimize", structure))
        return need

    shape, _, _ = _exemplar_grid_geometry(mesh, source_resolution, multiple=factor)
    target = target_size(size, shape, levels)
    if any(v % factor for v in target):
        return  # synthesize_volume says what is wrong with the size
    need = estimate(size, source_resolution)
    avail = available_memory()
    if need <= avail:
        return
    z, y, x = target
    what = f"size {x:,} x {y:,} x {z:,} (x y z) from source_resolution {int(source_resolution):,}"
    smallest = max(factor, base_blocks[-1])
    if np.ndim(size) == 0:
        best = largest_fitting(lambda s: estimate(s, source_resolution), avail, smallest, int(size), factor)
    else:  # (z, y, x): z kept, y and x scaled together
        side = max(x, y)

        def scaled(s):
            return (z, max(factor, y * s // side // factor * factor), max(factor, x * s // side // factor * factor))

        best = largest_fitting(lambda s: estimate(scaled(s), source_resolution), avail, smallest, side, factor)
        best = None if best is None else scaled(best)
    if best is not None:
        require(need, option="size", value=size, largest=best, available=avail, what=what)
    best = largest_fitting(lambda r: estimate(size, r), avail, 8, int(source_resolution))
    require(need, option="source_resolution", value=source_resolution, largest=best, available=avail, what=what)


def exemplar_distance(mesh, source_resolution: int, levels: int, *, device: str | None = None,
                      drop_degenerate: bool = False, before=None, field: Field | None = None
                      ) -> tuple[np.ndarray, float, Field]:
    """The source of an M1 synthesis from a checked exemplar mesh, one way for the untiled
    (:func:`synthesize_geometry`) and the tiled synthesis (:func:`geosynth.volume.tiled.exemplar_source`):
    its exact signed distance (:func:`geosynth.geometry.meshes.mesh_distance`) on
    :func:`exemplar_grid` of ``source_resolution`` samples along its longest side, z a
    multiple of 2^(levels-1).

    ``before``: None, or a callable taking the grid's (Z, Y, X) shape, called before the
    distance is computed (a tiling that cannot be is refused before the field's seconds).
    ``field``: None, or that distance already computed on that grid (by
    :func:`choose_settings`, which measured the exemplar on it): used as it is.

    Returns:
        (float32 (Z, Y, X) distances in samples, spacing (world units per sample), the
        exemplar's Field in world units).

    Raises:
        ValueError: samples that would lie outside [1e-15, 1e15] world units apart.
    """
    from geosynth.geometry.meshes import mesh_distance

    grid = exemplar_grid(mesh, source_resolution, multiple=2 ** (levels - 1))
    spacing = float(grid.spacing[0])
    if not SCALE_RANGE[0] <= spacing <= SCALE_RANGE[1]:
        raise ValueError(f"the exemplar's samples would lie {spacing:g} apart, outside [{SCALE_RANGE[0]:g}, "
                         f"{SCALE_RANGE[1]:g}] world units; scale the exemplar mesh.")
    if before is not None:
        before(grid.values.shape)
    if field is None:
        field = mesh_distance(mesh, field=grid, drop_degenerate=drop_degenerate, device=device)
    elif field.values.shape != grid.values.shape or float(field.spacing[0]) != spacing:
        raise ValueError(f"a precomputed exemplar field of shape {field.values.shape} does not lie on the synthesis "
                         f"grid {grid.values.shape}; pass field=None.")
    return field.values / np.float32(spacing), spacing, field


def exemplar_grid(mesh, resolution: int = 64, margin: int = 2, multiple: int = 1) -> Field:
    """The grid an exemplar mesh is sampled on for synthesis (values zero).

    Cubic cells of side ``max extent / resolution``. Along x and y the samples sit at
    the cell centres of the mesh's bounding box, with no margin: a footprint that
    tiles (the built-in terrain) gives a source that tiles, and no empty border
    enters the synthesis. Along z (up) at least ``margin`` extra samples lie above and
    below, so the top and bottom surfaces are inside the grid, and as many more as
    make the z count a multiple of ``multiple`` (the level factor of a synthesis).

    Args:
        mesh: a trimesh.Trimesh (its bounds are used).
        resolution: samples along the longest extent, >= 8.
        margin: samples added below and above along z, >= 0.
        multiple: the z count is rounded up to a multiple of it.

    Returns:
        a float32 Field of shape (Z, Y, X).
    """
    shape, origin, spacing = _exemplar_grid_geometry(mesh, resolution, margin, multiple)
    return Field(np.zeros(shape, np.float32), origin, np.full(3, spacing))


def _exemplar_grid_geometry(mesh, resolution: int, margin: int = 2, multiple: int = 1):
    """(shape (Z, Y, X), origin (3,), spacing) of :func:`exemplar_grid`, nothing allocated."""
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 8:
        raise ValueError(f"source_resolution must be an integer >= 8, got {resolution!r}.")
    lo, hi = np.asarray(mesh.bounds, np.float64)
    extent = hi - lo
    spacing = float(extent.max()) / int(resolution)
    counts = np.maximum(1, np.round(extent / spacing).astype(np.int64))  # x, y, z cells
    origin = lo + spacing / 2
    extra = 2 * int(margin) + (-(counts[2] + 2 * int(margin)) % int(multiple))
    counts[2] += extra
    origin[2] -= (extra // 2) * spacing
    shape = (int(counts[2]), int(counts[1]), int(counts[0]))
    return shape, origin, spacing


def target_size(size, source_shape, levels: int) -> tuple[int, int, int]:
    """The synthesis target (z, y, x) for a ``size`` given as one number or three.

    One number grows the exemplar sideways: x and y get ``size`` samples and z keeps
    the source's thickness (rounded down to a multiple of 2^(levels-1)), so a slab
    (chainmail, terrain) grows into a larger slab. Three numbers, (z, y, x), are taken
    as given.
    """
    if np.ndim(size) == 0:
        factor = 2 ** (levels - 1)
        z = max(factor, int(source_shape[0]) // factor * factor)
        return (z, int(size), int(size))
    return _as_shape("size", size)
