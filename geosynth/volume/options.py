"""Which settings does an M1 synthesis take, and are they valid?

:class:`VolumeOptions` declares, checks and documents once the settings that
:func:`geosynth.volume.synthesis.synthesize_volume`, :func:`geosynth.volume.synthesis.synthesize_geometry`,
:func:`geosynth.volume.tiled.synthesize_volume_tiled` and ``geosynth volume`` share (issue 33);
the tiled run's own settings ride in it as one :class:`TileOptions`. Every value is checked
when the object is made, before any work. What depends on the input (the most levels a
source can halve to, the blocks that fit it) is checked by the entry point that has it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.core.options import settings_from

__all__ = ["DEFAULT_METHOD", "GEOMETRY_SMOOTH", "METHODS", "SCALE_RANGE", "SEARCHES", "TileOptions", "VolumeOptions", "check_int", "check_scale",
           "level_blocks", "parse_tiles", "volume_options"]

# How each level is made from its matches: "paper" (scan-order copying, already
# synthesized samples kept), "graphcut" (the same scan, pasted along a minimum-error
# cut, geosynth.volume.graphcut), "optimize" (texture optimization, geosynth.volume.optimize).
METHODS = ("paper", "graphcut", "optimize")
# The default, "auto": the method that scores best on the built-in exemplars' structure
# metrics for the kind of run (bench/bm_volume.py --part quality; opencl, 64 -> 128, 3
# levels; the zoo, bench/bm_zoo.py): "graphcut" for a slab (elements: chainmail 0.99 against optimize's 0.74,
# rings 1.00 against 0.91; domes alike), "optimize" otherwise (balls 0.86 against
# graphcut's 0.58, fibers 0.48 against 0.43, terrain's debris 0.0% against 0.5% and no
# overhangs against 10.7%), a slab that is a terrain included (:func:`is_terrain`: the
# zoo's terrain slab kept its hills' spacing, 1.01 against graphcut's 0.80), and a slab of
# separate tubes across its footprint (:func:`is_tubes_across`: the zoo's wavy tubes 0.11 of
# random tiling's block distance against graphcut's 0.25, their height 1.00 against 0.94).
DEFAULT_METHOD = "auto"

# Taubin smoothing iterations of synthesize_geometry's mesh when VolumeOptions.smooth is None
# (the tiled run's merged mesh: none).
GEOMETRY_SMOOTH = 10

# The block searches; all three return the same block.
SEARCHES = ("cascade", "tree", "linear")

# band and spacing scale float32 fields (distance = value * band * spacing): within these
# bounds every product stays a normal float32 number.
SCALE_RANGE = (1e-15, 1e15)


def is_int(value) -> bool:
    """An integer that is not a bool (NumPy's included)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def check_int(name: str, value, minimum: int, maximum: int | None = None, why: str = "") -> int:
    """``value`` as an int in [minimum, maximum]; TypeError for a non-integer (floats are
    not truncated), ValueError out of range. ``why`` ends the range message."""
    if maximum is None:
        want = f"an integer >= {minimum}"
    else:
        want = f"an integer from {minimum} to {maximum}"
    if not is_int(value):
        raise TypeError(f"{name} must be {want}, got {value!r}.")
    if value < minimum or (maximum is not None and value > maximum):
        raise ValueError(f"{name} must be {want}{why}, got {value}.")
    return int(value)


def check_scale(name: str, value, what: str) -> float:
    """A real number in SCALE_RANGE (``what`` says what it measures)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number ({what}), got {value!r}.")
    lo, hi = SCALE_RANGE
    if not (math.isfinite(float(value)) and lo <= value <= hi):
        raise ValueError(f"{name} must be a finite number from {lo:g} to {hi:g} ({what}), got {value!r}.")
    return float(value)


def check_block(block) -> None:
    """Integers only (a power-of-two check and the per-level count follow in level_blocks)."""
    values = [block] if np.ndim(block) == 0 else list(np.asarray(block, dtype=object).reshape(-1))
    if np.ndim(block) > 1 or not values or not all(is_int(v) for v in values):
        raise TypeError(f"block must be an integer (a power of two >= 2) or one per level, got {block!r}.")


def level_blocks(levels: int, block, slab: bool = False) -> list[int]:
    """Each level's block, coarsest first, from one finest size or one per level.

    Raises:
        ValueError: a count other than ``levels``, a size that is not a power of two >= 2.
    """
    if np.ndim(block) == 0:
        finest = int(block)
        # Coarser levels: the same block in samples covers twice the space per level;
        # halve it (not below 4) so the coarsest keeps enough candidates. A slab's
        # halves it at the coarsest level only: its blocks hold whole columns, and the
        # finest block across at the levels between keeps more whole pieces (measured,
        # opencl, 64 -> 128: chainmail elements 0.69 -> 0.74, rings 0.84 -> 0.91, domes
        # slopes 0.95 -> 0.96).
        coarse = levels - 1 if not slab else min(1, levels - 1)
        blocks = [max(4, finest // 2)] * coarse + [finest] * (levels - coarse)
    else:
        blocks = [int(b) for b in block]
        if len(blocks) != levels:
            raise ValueError(f"block must be one size or one per level ({levels}), got {list(block)}.")
    for b in blocks:
        if b < 2 or b & (b - 1):
            raise ValueError(f"block sizes must be powers of two >= 2, got {b}.")
    return blocks


def parse_tiles(tiles) -> tuple[int, int]:
    """(nx, ny) from (nx, ny), one integer for both, or "NXxNY"."""
    if isinstance(tiles, str):
        parts = tiles.lower().split("x")
        if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
            raise ValueError(f"tiles must be NXxNY (e.g. 4x4), got {tiles!r}.")
        tiles = tuple(int(p) for p in parts)
    if np.ndim(tiles) == 0:
        tiles = (tiles, tiles)
    tiles = tuple(tiles)
    if len(tiles) != 2 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in tiles):
        raise TypeError(f"tiles must be one integer or (nx, ny), got {tiles!r}.")
    if min(tiles) < 1:
        raise ValueError(f"tiles must be at least 1 x 1, got {tiles[0]} x {tiles[1]}.")
    return int(tiles[0]), int(tiles[1])


@dataclass(frozen=True)
class TileOptions:
    """How :func:`geosynth.volume.tiled.synthesize_volume_tiled` cuts and schedules the target
    (``VolumeOptions(tiles=TileOptions(...))``; the untiled entry points refuse it).

    Attributes:
        tiles: (nx, ny) tiles across x and y; one integer for both, or "NXxNY", are read as
            that pair. Each tiled level's cores must hold its block plus the margin.
        workers: workers of the LocalCluster started when no scheduler is given (or threads
            of the threaded scheduler), >= 1.
        margin: samples of margin at every level (None: the largest block; at least it).
        coarse_whole: run the coarse levels that fit in one tile as one task (False: tile
            every level; for tests of the tiled path).
        phases: 3 (the checkerboard schedule, then a window on every interior corner point,
            where two phase-B tiles meet diagonally: :meth:`geosynth.volume.tiles.TileGrid.corners`),
            2 (the checkerboard only: the B-B corners chosen twice) or 1 (every tile
            independent: the naive baseline whose seams the schedule removes).
    """

    tiles: tuple[int, int] = (2, 2)
    workers: int = 2
    margin: int | None = None
    coarse_whole: bool = True
    phases: int = 3

    def __post_init__(self) -> None:
        object.__setattr__(self, "tiles", parse_tiles(self.tiles))
        workers = self.workers
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers must be an integer >= 1, got {workers!r}.")
        if self.margin is not None:
            check_int("margin", self.margin, 0)
        _checks.check_bool("coarse_whole", self.coarse_whole)
        if self.phases not in (1, 2, 3):
            raise ValueError(f"phases must be 1, 2 or 3, got {self.phases!r}.")


@dataclass(frozen=True)
class VolumeOptions:
    """M1's settings, declared, checked and documented once (issue 33):
    :func:`~geosynth.volume.synthesis.synthesize_volume`, :func:`~geosynth.volume.synthesis.synthesize_geometry`
    and :func:`~geosynth.volume.tiled.synthesize_volume_tiled` take them as keywords or as
    ``options=``, and ``geosynth volume`` builds one from its options. Every value is checked
    when the object is made (a bad one is a ``TypeError`` or ``ValueError`` naming it); the
    most levels a source allows is checked by the entry point that has the source.

    Attributes:
        levels: resolution levels, >= 1 (3 in the paper); at most as many as the source can
            halve to (:func:`geosynth.volume.synthesis.max_levels`, or log2 of
            ``source_resolution`` for a mesh exemplar).
        block: the finest level's block size (a power of two; coarser levels use half of it,
            at least 4, and at most the largest power of two that fits in their source and
            target; a slab's only at the coarsest level), or one size per level, coarsest
            first. A slab's is its size across. None: 16 for a field
            (``synthesize_volume``, the tiled run), chosen from a mesh exemplar by
            ``synthesize_geometry`` (16, or 32 where the source resolution was doubled, or
            larger where the exemplar's separate elements need it,
            :func:`geosynth.volume.synthesis.choose_settings`).
        tileable: make the target periodic (blocks wrap around its faces); not tiled.
        search: "cascade" (eq. 2 lower bounds of every block, coarse to fine, on the device,
            then exact SSDs of the few survivors: :class:`geosynth.volume.cascade.CascadeSearch`),
            "tree" (the paper's exact best-first search, :class:`geosynth.volume.tree.BlockSearch`;
            fast for clean queries, slower for synthesis queries whose random or upsampled
            samples weaken its bounds; cubic blocks only) or "linear" (every block scored by
            the gather kernel). All three return the same block.
        method: how a level is made from the matches (:data:`METHODS`): "paper" (scan-order
            copying), "graphcut" (the same scan, each block pasted along a minimum-error cut
            through the overlap, :func:`geosynth.volume.graphcut.min_cut`) or "optimize"
            (texture optimization, :func:`geosynth.volume.optimize.optimize_level`: the
            coarsest level starts from random source blocks, every level iterates exact
            matches of blocks on a stride-N/4 lattice and a robust vote, until under 1% of
            the matches change or ``iterations``), or "auto" (graphcut for a slab, optimize
            otherwise and for a terrain or tubes slab: :func:`geosynth.volume.synthesis.resolve_method`).
        iterations: the most texture-optimization iterations ("optimize"): one number for
            every level or one per level, coarsest first; None: 12 at the coarsest level
            (cheap, and it sets the layout), 6 in between and 3 at the finest (it mostly
            refines; its searches cost the most); 6 for one level.
        slab: blocks span each level's full thickness along z, (Z_l, B, B) with B from
            ``block``, and the synthesis grows across only; None: chosen by
            :func:`geosynth.volume.synthesis.is_slab` (a source ``SLAB_RATIO`` times thinner
            along z than across, a target no thicker).
        band: the distance mapped to the ends of the uint8 range, in samples, for float
            sources (None: half the finest block); finite in [1e-15, 1e15].
        lattice: restrict a slab's scan ("paper", "graphcut") to source blocks congruent
            to their target position modulo the exemplar's lattice
            (:mod:`geosynth.volume.lattice`), so that linked rings close across stitches;
            None: when the exemplar is a network with loops (linked rings: no whole element,
            :func:`geosynth.volume.synthesis.is_network`) and has a lattice; True: whenever it
            has one; False: never. Levels whose source is smaller than the lattice's cell plus
            a block match freely. ``result.lattice`` says what ran.
        smooth: Taubin smoothing iterations of the output mesh, >= 0 (None: ``GEOMETRY_SMOOTH``,
            10, for ``synthesize_geometry``; none for the tiled run's merged mesh).
        source_resolution: a mesh exemplar's samples along its longest side, >= 8
            (:func:`geosynth.volume.synthesis.exemplar_grid`); None: chosen from the exemplar
            (64, or 128 for thin features, the size then doubled to keep its world extent).
            ``synthesize_geometry`` and the command; a field's synthesis does not use it.
        quality_samples: blocks sampled each way for ``synthesize_geometry``'s quality
            numbers, >= 0 (0 skips them; the command's tiled run then does not gather the
            field).
        tiles: the tiled run's :class:`TileOptions` (None: its defaults); only
            ``synthesize_volume_tiled`` takes it.
    """

    levels: int = 3
    block: int | tuple[int, ...] | None = None
    tileable: bool = False
    search: str = "cascade"
    method: str = DEFAULT_METHOD
    iterations: int | tuple[int, ...] | None = None
    slab: bool | None = None
    band: float | None = None
    lattice: bool | None = None
    smooth: int | None = None
    source_resolution: int | None = None
    quality_samples: int = 100
    tiles: TileOptions | None = None

    def __post_init__(self) -> None:
        levels = check_int("levels", self.levels, 1)
        if self.block is not None:
            check_block(self.block)
            level_blocks(levels, self.block)
        _checks.check_bool("tileable", self.tileable)
        if not isinstance(self.search, str) or self.search not in SEARCHES:
            raise ValueError(f"search must be one of {', '.join(SEARCHES)}, got {self.search!r}.")
        if self.method != DEFAULT_METHOD and self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)} or auto, got {self.method!r}.")
        iterations = self.iterations
        if iterations is not None:
            caps = [iterations] * levels if np.ndim(iterations) == 0 else list(iterations)
            if len(caps) != levels or any(not is_int(c) or c < 1 for c in caps):
                raise ValueError(f"iterations must be a positive integer or one per level ({levels}), "
                                 f"got {iterations!r}.")
        if self.slab is not None:
            _checks.check_bool("slab", self.slab)
        if self.band is not None:
            check_scale("band", self.band, "the distance mapped to the ends of the uint8 range, in samples")
        if self.lattice is not None:
            _checks.check_bool("lattice", self.lattice)
        if self.smooth is not None:
            check_int("smooth", self.smooth, 0)
        if self.source_resolution is not None:
            check_int("source_resolution", self.source_resolution, 8)
        check_int("quality_samples", self.quality_samples, 0)
        if self.tiles is not None and not isinstance(self.tiles, TileOptions):
            raise TypeError(f"tiles must be a TileOptions or None, got {type(self.tiles).__name__}.")

    @property
    def tiling(self) -> TileOptions:
        """The tiled run's settings: ``tiles``, or the defaults."""
        return TileOptions() if self.tiles is None else self.tiles

    def untiled(self, entry: str) -> VolumeOptions:
        """These options, for an untiled entry point (named ``entry``): refused with tiles."""
        if self.tiles is not None:
            raise ValueError(f"{entry} does not tile; for tiles use synthesize_volume_tiled (or leave "
                             "VolumeOptions.tiles None).")
        return self


def volume_options(options: VolumeOptions | None, keywords: Mapping[str, Any], defaults: Mapping[str, Any],
                   levels_bound: Callable[[Mapping[str, Any]], tuple[int, str]],
                   build: Callable[[], VolumeOptions] | None = None) -> VolumeOptions:
    """An M1 entry point's settings as one :class:`VolumeOptions`
    (:func:`geosynth.core.options.settings_from`), the levels checked against its input first.

    Args:
        options, keywords, defaults: as :func:`geosynth.core.options.settings_from`.
        levels_bound: given the settings (the keywords, or the options' fields), the most
            levels this input allows and the reason that ends the message.
        build: makes the options from the keywords (None: ``VolumeOptions(**keywords)``).

    Raises:
        TypeError, ValueError: a bad setting, levels beyond the input's, both forms given.
    """
    given = keywords if not isinstance(options, VolumeOptions) else {f.name: getattr(options, f.name)
                                                                      for f in fields(options)}
    most, why = levels_bound(given)
    check_int("levels", given["levels"], 1, most, why)
    return settings_from(VolumeOptions, options, keywords, defaults, build)
