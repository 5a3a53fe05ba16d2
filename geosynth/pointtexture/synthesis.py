"""Which larger point-set texture looks like the exemplar? The synthesis algorithm of
"Geometry texture synthesis with point-set surfaces", Sec. 4 (steps 1 to 8) with the patch
processing of Sec. 5 (search 5.1, warping 5.2, blending 5.3).

:func:`synthesize_point_texture` grows the output T_out over the xy plane in scan-line
order, one patch at a time: the output's neighbourhood N_k of the next patch box gives
the overlap field D(O^N) (MLS distance + gradient on the overlap's grid samples); the
patch search (:class:`geosynth.pointtexture.patch_search.PatchSearch`) keeps every exemplar patch
within (1 + eps) of the best and draws one; the patch with its extra region E_k (F_k),
translated into place, is warped to N_k by a thin-plate spline
(:func:`geosynth.pointtexture.warping.warp_patch`), blended into N_k across the overlap
(:func:`geosynth.pointtexture.blending.blend_patch`) and pasted: the output's points inside F_k's box
are removed and F''_k's copied in (:class:`geosynth.pointtexture.output_grid.PointGrid`). A border of
width w_E is cut at the end (step 8); ``tileable=True`` grows a periodic output instead
(the last column and row overlap the first ones, nothing is cut).

Quality numbers beside a baseline that pastes random patches with no search, warp or
blend: the bidirectional patch-field distance (every sampled output patch's field
against its nearest exemplar patch, and the other way), the seam error (RMS MLS distance
difference between a pasted patch and N_k on the overlap's outer edge, in spacings)
before and after blending, and the share of stray points (farther than one spacing from
the MLS surface of the output).
"""

from __future__ import annotations

import functools
import math
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field as dc_field

import numpy as np
from threadpoolctl import threadpool_limits
from geosynth.compute.checks import UINT32_MAX
from geosynth.core.config import passive_openmp_threads
from geosynth.core.options import keyword_defaults, settings_from
from geosynth.pointtexture.output_grid import PointGrid
from geosynth.pointtexture.texture import PointTexture

__all__ = ["PATCH_PERIODS", "PatchChoice", "PointTextureOptions", "PointTextureReport", "check_synthesis", "choose_patch", "output_mesh", "output_mesh_bytes", "synthesis_bytes",
           "synthesize_point_texture"]


@dataclass
class PointTextureReport:
    """What a run did and how good it is (see :func:`synthesize_point_texture`).

    Attributes:
        exemplar: the exemplar's name; points_in, points_out: point counts.
        size: (2,) output extent in x and y, world units; tileable: periodic output.
        grid: (nz, ny, nx) of D(T_in); cell: its spacing (world units).
        patch, extra, overlap: patch side, extra-region width and overlap width, cells.
        patches: patches pasted; candidates: mean candidates within (1 + eps) of the best.
        patch_choice: with ``patch=None``, the line that says what was measured and which
            patch size was chosen (:func:`choose_patch`); else "".
        relief: ``{"exemplar": (period, amplitude, peak), "output": (...), "baseline":
            (...)}``, world units, peak a bool (:func:`geosynth.pointtexture.element_size.relief_scale`;
            the output and the baseline measured over their extent at the exemplar's
            height-map cell, at half to twice the exemplar's period; the baseline with
            ``quality`` only).
        spacing, radius: the exemplar's mean point spacing and the MLS width h.
        arbitrated: field samples the host recomputed for identical codes on every device.
        kept_warp: patches pasted as warped, without the blend and the cut, because blending
            would have raised their seam error against N_k (our extension of Sec. 4 step 5).
        quality: name -> value (see :meth:`lines`).
        device: the device used.
        baseline: the random-pasting output as a PointSet (with ``quality``), else None.
    """

    exemplar: str
    points_in: int
    points_out: int
    size: tuple
    tileable: bool
    grid: tuple
    cell: float
    patch: int
    extra: int
    overlap: int
    patches: int
    candidates: float
    spacing: float
    radius: float
    arbitrated: int
    device: str
    kept_warp: int = 0
    quality: dict = dc_field(default_factory=dict)
    baseline: object = None  # the random-pasting output (a PointSet) when quality was asked
    patch_choice: str = ""  # the automatic patch size's line (patch=None), else ""
    relief: dict = dc_field(default_factory=dict)  # (period, amplitude) of exemplar, output, baseline

    def lines(self) -> list[str]:
        """The report as printable lines."""
        out = [self.patch_choice] if self.patch_choice else []
        out += [
            f"exemplar {self.exemplar}: {self.points_in:,} points, spacing {self.spacing:.4g}, MLS width {self.radius:.4g}",
            f"D(T_in): {self.grid[2]} x {self.grid[1]} x {self.grid[0]} samples (x, y, z), cell {self.cell:.4g}; "
            f"patch {self.patch} cells, extra region {self.extra}, overlap {self.overlap}; {self.arbitrated:,} field "
            "samples recomputed on the host (float64) so that every device gives the same codes",
            f"output: {self.size[0]:.4g} x {self.size[1]:.4g}{' (tileable)' if self.tileable else ''}, "
            f"{self.points_out:,} points from {self.patches} patches; {self.candidates:.1f} candidates within "
            f"(1+eps) of the best on average; device {self.device}",
            f"blend: kept on {self.patches - self.kept_warp} of {self.patches} patches; {self.kept_warp} pasted as "
            "warped, where blending would have raised the seam error against the neighbourhood",
        ]
        r = self.relief
        if r:
            (pe, ae, ke), (po, ao, ko) = r["exemplar"], r["output"]
            vague = " (no clear spectral peak)"
            line = (f"element size / relief amplitude (world units): exemplar {pe:.4g}{'' if ke else vague} / {ae:.4g}, "
                    f"output {po:.4g}{'' if ko else vague} / {ao:.4g} ({po / pe:.2f}x / {ao / ae:.2f}x)")
            if "baseline" in r:
                pb, ab, kb = r["baseline"]
                line += f"; random pasting {pb:.4g}{'' if kb else vague} / {ab:.4g} ({pb / pe:.2f}x / {ab / ae:.2f}x)"
            out.append(line)
        q = self.quality
        if q:
            out.append("quality (synthesized vs random pasting without search, warp or blend; lower is better):")
            if "field_distance" in q:
                s, b = q["field_distance"], q["field_distance_baseline"]
                out.append(f"  patch-field distance, mean squared code per sample: output->exemplar {s[0]:.1f} vs "
                           f"{b[0]:.1f}, exemplar->output {s[1]:.1f} vs {b[1]:.1f}, mean {s[2]:.1f} vs {b[2]:.1f}")
            if "seam_before" in q:
                out.append(f"  seam error (RMS distance across patch borders, spacings): after warping "
                           f"{q['seam_before']:.3f}, after blending {q['seam_after']:.3f}; random pasting "
                           f"{q['seam_baseline']:.3f}")
            if "stray" in q:
                out.append(f"  stray points (farther than one spacing from the MLS surface): {100 * q['stray']:.2f}% "
                           f"vs {100 * q['stray_baseline']:.2f}%")
        return out


# ------------------------------------------------------------------ parameters

# The automatic patch size (issue 32; Sec. 3: "large enough to encompass at least a texture
# element plus some neighborhood"): this many of the relief's dominant periods, within
# [_PATCH_FEWEST_CELLS cells, _PATCH_MOST of B's shorter side]. Chosen by measuring the
# built-ins at 1.25 to 2 periods ("M2 element size -> patch size" in `git log -p bench/RESULTS.md`): at 1.5
# the flowers' patch-field distance came near random pasting's (0.96 of it; 0.76 at 1.25),
# as at the old default 0.4; at 1.25 every built-in's mean was at or below its old default's.
PATCH_PERIODS = 1.25
_PATCH_MOST = 0.5  # a larger patch leaves few candidates in B (and no variation)
_PATCH_FEWEST_CELLS = 6  # an overlap of 2 cells and an interior of 2


@dataclass(frozen=True)
class PatchChoice:
    """The automatic patch size (:func:`choose_patch`).

    Attributes:
        patch: the patch side as a fraction of B's shorter side (2 decimals).
        scale: the exemplar's :class:`geosynth.pointtexture.element_size.ReliefScale`.
        line: one line: what was measured and what was chosen.
    """

    patch: float
    scale: object
    line: str


def choose_patch(texture: PointTexture, resolution: int = 48) -> PatchChoice:
    """The patch size from the exemplar's element size: ``PATCH_PERIODS`` dominant periods
    of its relief (:func:`geosynth.pointtexture.element_size.relief_scale`), rounded to 0.01 of B's
    shorter side, at most ``_PATCH_MOST`` of it and at least ``_PATCH_FEWEST_CELLS`` cells
    of D(T_in) at ``resolution``. The same for a built-in and a file; CPU-exact (the
    period is one of a discrete set; see geosynth.pointtexture.element_size).

    Args:
        texture: the exemplar.
        resolution: samples of D(T_in) along B's longer side (as
            :func:`synthesize_point_texture`; a bad value is left to its own check).

    Returns:
        A :class:`PatchChoice`.
    """
    from geosynth.pointtexture.element_size import relief_scale

    rs = relief_scale(texture.points, texture.box_min, texture.box_max, texture.spacing)
    ext = (texture.box_max - texture.box_min)[:2]
    side = float(ext.min())
    want = PATCH_PERIODS * rs.period / side
    patch = round(want, 2)
    why = f"{PATCH_PERIODS:g} periods"
    fewest = 0.0
    if isinstance(resolution, (int, np.integer)) and not isinstance(resolution, bool) and resolution >= 8:
        cell = float(ext.max()) / (int(resolution) - 1)
        fewest = math.ceil(100 * (_PATCH_FEWEST_CELLS - 0.5) * cell / side) / 100  # rounds to >= 6 cells
    if patch > _PATCH_MOST:
        patch, why = _PATCH_MOST, f"{want:.2f} ({PATCH_PERIODS:g} periods) capped at {_PATCH_MOST:g}: B holds few elements"
    elif patch < fewest:
        patch, why = fewest, (f"{want:.2f} ({PATCH_PERIODS:g} periods) raised to {_PATCH_FEWEST_CELLS} field cells at "
                              f"resolution {resolution}: a finer --resolution resolves the elements")
    found = (f"dominant period {rs.period:.4g} ({rs.period / side:.2f} of B's side, wave vector at {rs.angle:.0f} deg)"
             if rs.peak else f"no clear spectral peak; its strongest period {rs.period:.4g} ({rs.period / side:.2f} "
             "of B's side)")
    line = (f"patch {patch:.2f} of B's shorter side (automatic; --patch overrides): the exemplar's relief has {found}, "
            f"amplitude {rs.amplitude:.4g}; patch = {why}")
    return PatchChoice(patch, rs, line)


def _fraction(name: str, value, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__}.")
    v = float(value)
    if not (np.isfinite(v) and lo < v <= hi):
        raise ValueError(f"{name} must be in ({lo:g}, {hi:g}], got {value!r}.")
    return v


@dataclass(frozen=True)
class _Layout:
    cell: float
    patch: int
    extra: int
    overlap: int
    step: int
    cols: int
    rows: int
    canvas_origin: np.ndarray  # (2,) world xy of canvas cell (0, 0)
    size: np.ndarray  # (2,) the final output's extent
    period: np.ndarray | None  # tileable: (2,) period


# The patch search sums uint8 codes in uint32 (geosynth.compute.scoring.GatherScorer): at most this many
# overlap samples (4 codes each, 255^2 per code at worst) in one patch's query.
_MAX_OVERLAP_SAMPLES = UINT32_MAX // (4 * 255 * 255)


def _grid_layers(box_min, box_max, cell: float) -> int:
    """nz of D(T_in) (:class:`geosynth.pointtexture.patch_search.PatchSearch`'s rule: B's height plus
    a cell above and below)."""
    return int(np.ceil((float(box_max[2]) - float(box_min[2])) / cell - 1e-9)) + 3


def _grid_columns(box_min, box_max, cell: float) -> tuple[int, int]:
    """(nx, ny) of D(T_in), as :class:`geosynth.pointtexture.patch_search.PatchSearch` counts them."""
    return tuple(int(np.floor((float(box_max[a]) - float(box_min[a])) / cell + 1e-9)) + 1 for a in range(2))


def _overlap_samples(lay: "_Layout", layers: int, tileable: bool) -> int:
    """The most overlap samples of one patch's query: the last patch's (it has every side
    any patch has: -x, -y, and when tileable +x, +y), times the grid's layers."""
    pc, oc = lay.patch, lay.overlap  # 2 oc < pc: the bands of opposite sides do not meet
    wx = 0 if lay.cols == 1 else oc * (2 if tileable else 1)
    wy = 0 if lay.rows == 1 else oc * (2 if tileable else 1)
    return (pc * pc - (pc - wx) * (pc - wy)) * layers


def _check_resolution(resolution) -> None:
    """D(T_in)'s samples along B's longer side: an integer >= 8."""
    if not isinstance(resolution, (int, np.integer)) or isinstance(resolution, bool) or resolution < 8:
        raise ValueError(f"resolution must be an integer >= 8 (field samples along the exemplar box's longer side), "
                         f"got {resolution!r}.")


def _check_size(size) -> np.ndarray:
    """The output's (2,) x and y extent, world units, both finite and > 0."""
    try:
        s = np.asarray(size, np.float64).reshape(-1)
    except (TypeError, ValueError):
        s = np.zeros(0)
    if s.shape != (2,) or not (np.isfinite(s).all() and (s > 0).all()):
        raise ValueError(f"size must be two numbers > 0 (the output's x and y extent, world units), got {size!r}.")
    return s


def _layout_box(box_min, box_max, size, scale, patch, extra, overlap, resolution, tileable,
                quality: bool = False) -> _Layout:
    """The patch layout for an exemplar box B (box_min, box_max), with every combination
    the growth cannot use refused in one line (see :func:`check_synthesis`)."""
    box_min, box_max = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
    ext = (box_max - box_min)[:2]
    _check_resolution(resolution)
    cell = float(ext.max()) / (int(resolution) - 1)
    p = _fraction("patch", patch, 0.0, 1.0)
    pc = int(round(p * float(ext.min()) / cell))
    if pc < 4:
        raise ValueError(f"patch {patch!r} is only {pc} field cells wide; use a larger patch or resolution.")
    ec = max(1, int(round(_fraction("extra", extra, 0.0, 0.5) * pc)))
    oc = max(1, int(round(_fraction("overlap", overlap, 0.0, 0.5) * pc)))
    if 2 * oc >= pc:
        # a patch is blended across its overlap with the patch before it and overwritten from
        # pc - oc on by the next one: two overlaps that meet leave it no cell of its own
        most = (pc - 1) // 2
        raise ValueError(
            f"overlap {overlap!r} is {oc} cells of a {pc}-cell patch: the overlaps on a patch's two sides "
            f"({2 * oc} cells) leave it no interior of its own; use an overlap of at most "
            f"{np.floor(100 * most / pc) / 100:.2f} ({most} cells) (or a larger patch).")
    nx, ny = _grid_columns(box_min, box_max, cell)
    span = pc + ec + 1
    if span > min(nx, ny):
        raise ValueError(
            f"the patch ({pc} cells) plus its extra region ({ec}) spans {span} samples but the exemplar's box is only "
            f"{nx} x {ny} samples of the search grid; use a smaller patch (or a smaller extra region).")
    step = pc - oc
    if size is not None:
        s = _check_size(size)
    else:
        sc = _fraction("scale", scale, 0.0, 1e4)
        s = sc * ext
    if tileable:
        counts = np.maximum(1, np.round(s / (step * cell))).astype(np.int64)
        period = counts * step * cell
        lay = _Layout(cell, pc, ec, oc, step, int(counts[0]), int(counts[1]), box_min[:2].copy(), period, period)
    else:
        canvas = s + 2 * ec * cell
        counts = np.maximum(1, np.ceil((canvas / cell - pc) / step).astype(np.int64) + 1)
        lay = _Layout(cell, pc, ec, oc, step, int(counts[0]), int(counts[1]), box_min[:2] - ec * cell, s, None)
    layers = _grid_layers(box_min, box_max, cell)
    samples = _overlap_samples(lay, layers, tileable)
    if samples > _MAX_OVERLAP_SAMPLES:
        raise _TooFine(f"resolution {int(resolution):,} gives a patch overlap of {samples:,} field samples, more than "
                       f"the {_MAX_OVERLAP_SAMPLES:,} the patch search can sum exactly (uint8 codes in uint32)")
    if quality and layers * pc * pc > _MAX_OVERLAP_SAMPLES:  # the patch-field distance compares whole patches
        raise _TooFine(f"resolution {int(resolution):,} gives patches of {layers * pc * pc:,} field samples, more than "
                       f"the {_MAX_OVERLAP_SAMPLES:,} the quality numbers' patch-field distance can sum exactly "
                       "(uint8 codes in uint32; or skip the quality numbers)")
    return lay


class _TooFine(ValueError):
    """A resolution whose overlap queries exceed the search's exact sums (see _layout_box)."""


def _sides(i, j, lay: _Layout, tileable: bool):
    sides = []
    if i > 0:
        sides.append(("-x", lay.overlap))
    if j > 0:
        sides.append(("-y", lay.overlap))
    if tileable and i == lay.cols - 1 and lay.cols > 1:
        sides.append(("+x", lay.overlap))
    if tileable and j == lay.rows - 1 and lay.rows > 1:
        sides.append(("+y", lay.overlap))
    return sides


# ------------------------------------------------------------------ the growth


def _as_texture(exemplar, seed) -> PointTexture:
    if isinstance(exemplar, PointTexture):
        return exemplar
    if isinstance(exemplar, str):
        from geosynth.pointtexture.examples import POINT_EXAMPLES, point_texture_example

        if exemplar in POINT_EXAMPLES:
            return point_texture_example(exemplar, seed=seed)
        from geosynth.pointtexture.texture import read_point_texture

        return read_point_texture(exemplar, seed=seed)
    import os

    if isinstance(exemplar, os.PathLike):
        from geosynth.pointtexture.texture import read_point_texture

        return read_point_texture(exemplar, seed=seed)
    raise TypeError(f"exemplar must be a PointTexture, a built-in name or a file path, got {type(exemplar).__name__}.")


def _default_weights(texture: PointTexture):
    from geosynth.pointtexture.warping import WARP_PRESETS, WarpWeights

    from geosynth.pointtexture.examples import POINT_EXAMPLES

    ex = POINT_EXAMPLES.get(texture.name)
    return WARP_PRESETS[ex.preset] if ex is not None else WarpWeights()


class _Timer:
    def __init__(self):
        self.t = {"precompute": 0.0, "search": 0.0, "warp": 0.0, "blend": 0.0, "other": 0.0, "quality": 0.0}

    def add(self, key, t0):
        now = time.perf_counter()
        self.t[key] += now - t0
        return now


@dataclass(frozen=True)
class _Growth:
    """What every growth of one :func:`synthesize_point_texture` run shares (the synthesis and
    its random-pasting baseline): the exemplar, its search structure D(T_in) and the patch
    layout, the warp's weights and the candidates' tolerance, whether the output tiles, the
    device, the exemplar's point spacing and MLS width h, and its surface variation."""

    texture: PointTexture
    search: object
    lay: _Layout
    weights: object
    eps: float
    tileable: bool
    device: str
    spacing: float
    h: float
    variation: np.ndarray


def _grow(growth: _Growth, rng, timer, *, baseline=False, seams_wanted=True, progress=False, label="synthesis",
          cut=False):
    """Steps 1 to 7 of Sec. 4; returns (PointGrid, stats dict). ``seams_wanted``: measure the
    seam errors (quality numbers; their time goes to the timer's "quality", not to a stage).
    ``cut``: the exemplar has disconnected pieces (blending.has_pieces): those one side of
    the overlap lacks are cut whole instead of blended (blending.cut_pieces).

    Each patch draws from its own generator (``rng.spawn``, in scan order), so a patch's
    outcome depends on the seed and on what lies around it, not on when it runs. On two
    or more cores (not tileable, not the baseline) two threads grow the rows, one the even
    rows, one the odd: a patch starts once the row above has finished every patch whose
    box or neighbourhood could meet its own (:func:`_row_lag`), so it sees what the scan
    order would show it; the grid orders points by scan rank, so the output is the same
    bits as one thread's. Stage times are then summed over both threads. The stats' "threads"
    says how many grew it."""
    from geosynth.compute.host_steps import host_threads
    from geosynth.pointtexture.patch_search import quantized_fields

    texture, search, lay, weights, eps = growth.texture, growth.search, growth.lay, growth.weights, growth.eps
    tileable, device, spacing, h, variation = growth.tileable, growth.device, growth.spacing, growth.h, growth.variation
    if not baseline:
        from geosynth.pointtexture.blending import blend_patch, cut_pieces, overlap_ramp, seam_errors
        from geosynth.pointtexture.warping import warp_patch

    cell, pc = lay.cell, lay.patch
    reach = 3.0 * h
    grid = PointGrid(cell=max(2 * reach, cell * 2), period=lay.period)
    inp, inn = texture.points, texture.normals
    # F_k's points by x range first: the exemplar sorted by x once, each patch's box then a
    # searchsorted slice (the same points as testing all of them, in the same order after
    # the sort of their ids; chainmail: ~5 ms a patch of full-array comparisons saved)
    by_x = np.argsort(inp[:, 0], kind="stable")
    xs = inp[by_x, 0]
    zlo, zhi = search.z0, search.z0 + (search.shape[0] - 1) * cell
    margin = 4.0 * spacing  # the warp moves points by at most a few spacings (its pairs are <= 4 apart)
    total = lay.cols * lay.rows
    rngs = rng.spawn(total)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=label, unit="patch", leave=False, mininterval=0.5, file=sys.stderr)

    def one_patch(j: int, i: int, rng, timer) -> dict:
        """Patch (i, j): search, warp, blend, paste; returns its statistics."""
        out = {}
        t0 = time.perf_counter()
        ox, oy = i * lay.step, j * lay.step
        lo = lay.canvas_origin + cell * np.array([ox, oy], np.float64)
        sides = _sides(i, j, lay, tileable)
        ex_x = 0 if (tileable and i == lay.cols - 1) else lay.extra
        ex_y = 0 if (tileable and j == lay.rows - 1) else lay.extra
        hi = lo + cell * np.array([pc + ex_x, pc + ex_y], np.float64)
        offsets = search.overlap_offsets(sides)
        # --- search (steps 2 and 3)
        nb_p = nb_n = None
        if len(offsets):
            q = np.column_stack([lo[0] + offsets[:, 2] * cell, lo[1] + offsets[:, 1] * cell,
                                 search.z0 + offsets[:, 0] * cell])
            nb_p, nb_n = grid.in_box(q[:, :2].min(0) - 2 * reach - margin, q[:, :2].max(0) + 2 * reach + margin)
        if baseline or not len(offsets) or len(nb_p) == 0:
            choice = search.choose(np.zeros((0, 3), np.int64), None, eps, rng)
        else:
            values, na = quantized_fields(nb_p, nb_n, q, h, search.band, device)
            out["arbitrated"] = na
            choice = search.choose(offsets, values, eps, rng)
            out["candidates"] = choice.candidates
        t0 = timer.add("search", t0) if not baseline else t0
        # --- F_k = P_k + E_k, translated into place, extended by a margin
        src = search.window_world(search.origins[choice.index])
        shift = np.r_[lo - src, 0.0]
        f_lo, f_hi = src - margin, src + (hi - lo) + margin
        ids = by_x[np.searchsorted(xs, f_lo[0], "left"):np.searchsorted(xs, f_hi[0], "left")]
        y = inp[ids, 1]
        sel = np.sort(ids[(y >= f_lo[1]) & (y < f_hi[1])])
        fp, fn = inp[sel] + shift, inn[sel]
        box_min, box_max = np.r_[lo, zlo], np.r_[hi, zhi]
        drop = restore = None
        if not baseline and len(offsets) and len(nb_p):
            # --- warp (step 4): targets are N_k's points in the overlap
            ramp_nb = overlap_ramp(nb_p, box_min, box_max, lay.overlap * cell, lay.overlap * cell,
                                   [s for s, _ in sides])
            inside = ((nb_p[:, :2] >= lo) & (nb_p[:, :2] <= hi)).all(axis=1) & (ramp_nb > 0)
            t0 = timer.add("other", t0)
            wr = warp_patch(fp, fn, nb_p[inside], nb_n[inside], box_min, box_max, weights, spacing, rng,
                            src_variation=variation[sel])
            t0 = timer.add("warp", t0)
            # --- blend (step 5); disconnected pieces that one side lacks are cut, not blended
            names = [s for s, _ in sides]
            ramp = overlap_ramp(wr.points, box_min, box_max, lay.overlap * cell, lay.overlap * cell, names)
            if cut:
                wide = 0.5 * pc * cell  # N_k's pieces are whole up to half a patch beyond the box
                if lay.period is not None:  # one image of each point: the window within a period
                    wide = min(wide, max(0.0, 0.5 * float((lay.period - (hi - lo)).min()) - cell))
                cq, cqn, cs = grid.in_box(lo - wide, hi + wide, sources=True)
                ramp_q = overlap_ramp(cq, box_min, box_max, lay.overlap * cell, lay.overlap * cell, names)
                drop, unblend, restore = cut_pieces(wr.points, ramp, cq, ramp_q, box_min, box_max, spacing,
                                                    window=(lo - margin, hi + margin),
                                                    neighbourhood_window=(lo - wide, hi + wide))
                if unblend.any():
                    ramp = np.where(unblend, 0.0, ramp)
            bp, bn = blend_patch(wr.points, wr.normals, ramp, nb_p, nb_n, spacing, device)
            # --- keep the blend (and the cut) only where it lowers the seam error against N_k
            # (our extension: blending made the seam worse on a third of the flowers' seeds)
            edge = _edge_samples(search, offsets, q, sides)
            ap, an = bp, bn  # what is pasted there: the patch's points kept and N_k's pieces restored
            if drop is not None and (drop.any() or restore.any()):
                ap, an = np.concatenate([bp[~drop], cq[restore]]), np.concatenate([bn[~drop], cqn[restore]])
            before, after = seam_errors([(wr.points, wr.normals), (ap, an)], nb_p, nb_n, edge, spacing)
            if _worse(after, before):
                bp, bn, after = wr.points, wr.normals, before
                drop = restore = None
                out["kept_warp"] = 1
            if seams_wanted:
                out["before"], out["after"] = before, after
            t0 = timer.add("blend", t0)
            fp, fn = bp, bn
        elif baseline and seams_wanted and len(offsets) and nb_p is not None and len(nb_p):
            from geosynth.pointtexture.blending import seam_error as _seam

            edge = _edge_samples(search, offsets, q, sides)
            out["baseline"] = _seam(fp, fn, nb_p, nb_n, edge, spacing)
        # --- paste (step 6)
        keep = ((fp[:, :2] >= lo) & (fp[:, :2] < hi)).all(axis=1)
        if drop is not None:
            keep &= ~drop
        grid.remove_box(lo, hi)
        # the scan order's rank, whichever thread; each point keeps the exemplar point it came from
        # (warp and blend move points one for one), so its colour can follow it
        grid.insert(fp[keep], fn[keep], rank=2 * (j * lay.cols + i), sources=sel[keep])
        if restore is not None and restore.any():  # N_k's pieces kept whole go back in
            grid.insert(cq[restore], cqn[restore], rank=2 * (j * lay.cols + i) + 1, sources=cs[restore])
        if not baseline:
            timer.add("other", t0)
        return out

    results: dict = {}
    lag = _row_lag(lay, reach, margin, cut)
    threads = 1 if (baseline or tileable or lay.rows < 2 or lag >= lay.cols) else min(2, host_threads())
    if threads == 1:
        for j in range(lay.rows):
            for i in range(lay.cols):
                results[j, i] = one_patch(j, i, rngs[j * lay.cols + i], timer)
                if bar is not None:
                    bar.update(1)
    else:
        _grow_two_rows(lay, lag, one_patch, rngs, timer, results, bar)
    if bar is not None:
        bar.close()
    seams = {"before": [], "after": [], "baseline": []}
    cands = []
    arbitrated = kept_warp = 0
    for j in range(lay.rows):  # the statistics in scan order
        for i in range(lay.cols):
            r = results[j, i]
            for key in seams:
                if key in r:
                    seams[key].append(r[key])
            if "candidates" in r:
                cands.append(r["candidates"])
            arbitrated += r.get("arbitrated", 0)
            kept_warp += r.get("kept_warp", 0)
    return grid, {"seams": seams, "candidates": cands, "arbitrated": arbitrated, "threads": threads,
                  "kept_warp": kept_warp}


# Seam errors (spacings) are compared after rounding to this step: a decision must not
# depend on the last bits of a float sum, which differ between CPUs' SIMD paths.
_SEAM_STEP = 1e-6


def _worse(after: float, before: float) -> bool:
    """Whether the blended patch's seam error is larger than the warped one's (NaN: no
    sample with support on both sides, nothing to compare: the blend is kept)."""
    if not (np.isfinite(after) and np.isfinite(before)):
        return False
    return round(after / _SEAM_STEP) > round(before / _SEAM_STEP)


def _row_lag(lay, reach: float, margin: float, cut: bool) -> int:
    """How many patches of the row above must be finished beyond a patch's own column before
    it may start: the smallest L with L patch steps >= a patch's box width (patch + extra
    region) plus the farthest its reads reach beyond its box (N_k's window: 2 reaches and the
    margin; the flowers' cut: half a patch), so that neither row writes where the other
    still reads."""
    cell = lay.cell
    reads = 2.0 * reach + margin
    if cut:
        reads = max(reads, 0.5 * lay.patch * cell)
    width = (lay.patch + lay.extra) * cell + reads
    return int(np.ceil(width / (lay.step * cell) - 1e-9))


def _grow_two_rows(lay, lag: int, one_patch, rngs, timer, results: dict, bar) -> None:
    """Run ``one_patch(j, i, rng, timer)`` for every patch on two threads, one the even
    rows and one the odd, patch (i, j) starting once row j - 1 has finished its first
    min(cols, i + lag + 1) patches; each thread times into its own timer, added to
    ``timer`` at the end. An error in either thread stops both and is raised here."""
    import threading

    from geosynth.compute.host_steps import CoreShare

    cores = CoreShare()
    done = [0] * lay.rows
    state = {"error": None}
    ready = threading.Condition()
    timers = [_Timer(), _Timer()]

    def rows_of(first: int) -> None:
        try:
            _rows(first)
        except BaseException as error:  # noqa: BLE001 - handed to the caller's thread
            with ready:
                state["error"] = error
                ready.notify_all()

    def _rows(first: int) -> None:
        for j in range(first, lay.rows, 2):
            for i in range(lay.cols):
                if state["error"] is not None:
                    return
                if j > 0:
                    need = min(lay.cols, i + lag + 1)
                    with ready:
                        while done[j - 1] < need and state["error"] is None:
                            ready.wait()
                        if state["error"] is not None:
                            return
                with cores.busy():  # two patches at once: each its share of the cores
                    results[j, i] = one_patch(j, i, rngs[j * lay.cols + i], timers[first])
                with ready:
                    done[j] = i + 1
                    ready.notify_all()
                    if bar is not None:  # one thread at a time
                        bar.update(1)

    second = threading.Thread(target=rows_of, args=(1,), name="geosynth-rows", daemon=True)
    second.start()
    try:
        rows_of(0)
    finally:
        second.join()
    if state["error"] is not None:
        raise state["error"]
    for t in timers:
        for key, v in t.t.items():
            timer.t[key] += v


def _edge_samples(search, offsets, q, sides):
    """The overlap's samples on its outer edge (the first column of each side), (L, 3)."""
    p = search.patch
    m = np.zeros(len(offsets), bool)
    for side, _ in sides:
        if side == "-x":
            m |= offsets[:, 2] == 0
        elif side == "+x":
            m |= offsets[:, 2] == p - 1
        elif side == "-y":
            m |= offsets[:, 1] == 0
        elif side == "+y":
            m |= offsets[:, 1] == p - 1
    return q[m]


def _cut(grid: PointGrid, lay: _Layout, texture: PointTexture, tileable: bool):
    """Step 8: the final border cut (none when tileable); points in output coordinates
    (x and y from the exemplar box's corner), normals, and the (N,) int64 exemplar point
    each was copied from."""
    p, n, src = grid.all_points(sources=True)
    lo = texture.box_min[:2]
    if tileable:  # one period, from B's corner (the grid keeps [0, period))
        p[:, :2] = lo + np.mod(p[:, :2] - lo, lay.period)
        p[:, :2] = np.where(p[:, :2] >= lo + lay.period, lo, p[:, :2])
        return p, n, src
    hi = lo + lay.size
    keep = ((p[:, :2] >= lo) & (p[:, :2] < hi)).all(axis=1)
    return p[keep], n[keep], src[keep]


def _source_colors(texture: PointTexture, src: np.ndarray) -> np.ndarray | None:
    """(N, 3) uint8: each output point's colour, its exemplar point's (None without colour)."""
    if texture.colors is None:
        return None
    return texture.colors[src]


# ------------------------------------------------------------------ quality


def _field_codes(points, normals, lay, search, h, device, lo, size):
    """D of an output on the search grid's spacing over [lo, lo + size] (codes (nz, ny, nx, 4))."""
    from geosynth.pointtexture.patch_search import quantized_fields

    cell = lay.cell
    nx, ny = (int(np.floor(size[a] / cell + 1e-9)) + 1 for a in range(2))
    nz = search.shape[0]
    k, jj, ii = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    q = np.stack([lo[0] + ii.ravel() * cell, lo[1] + jj.ravel() * cell, search.z0 + k.ravel() * cell], 1)
    codes, _ = quantized_fields(points, normals, q, h, search.band, device)
    return codes.reshape(nz, ny, nx, 4)


def _nearest_window(grid_codes, origins, offsets, values, device):
    from geosynth.compute.scoring import score_gather

    s = score_gather(grid_codes, offsets, values, origins=origins, device=device)
    return float(s.min())


def _window_origins(shape, patch, stride):
    nz, ny, nx = shape
    oy, ox = np.meshgrid(np.arange(0, ny - patch + 1, stride), np.arange(0, nx - patch + 1, stride), indexing="ij")
    return np.stack([np.zeros(ox.size, np.int64), oy.ravel(), ox.ravel()], 1)


def _field_distance(out_codes, in_codes, patch, samples, rng, device):
    """Bidirectional patch-field distance: (output->exemplar, exemplar->output, mean), mean
    squared code difference per field value."""
    nz = in_codes.shape[0]
    jy, ix = np.meshgrid(np.arange(patch), np.arange(patch), indexing="ij")
    off = np.column_stack([np.repeat(np.arange(nz), patch * patch), np.tile(jy.ravel(), nz), np.tile(ix.ravel(), nz)])
    per = len(off) * 4
    res = []
    for a, b in ((out_codes, in_codes), (in_codes, out_codes)):
        src = _window_origins(a.shape[:3], patch, 1)
        dst = _window_origins(b.shape[:3], patch, 2 if b is out_codes else 1)
        pick = src[rng.choice(len(src), size=min(samples, len(src)), replace=False)]
        vals = []
        for o in pick:
            win = a[o[0] + off[:, 0], o[1] + off[:, 1], o[2] + off[:, 2]]
            vals.append(_nearest_window(b, dst, off, win, device) / per)
        res.append(float(np.mean(vals)))
    return res[0], res[1], 0.5 * (res[0] + res[1])


def _stray_share(points, normals, spacing, h, device) -> float:
    from geosynth.geometry.pointsets import pointset_distance

    if len(points) < 4:
        return 1.0
    d, _ = pointset_distance(points.astype(np.float32), normals.astype(np.float32), points.astype(np.float32),
                             radius=h, far="reach", device=device)
    return float(np.mean(np.abs(d) > spacing))


# ------------------------------------------------------------------ the public function

_BYTES_PER_OUTPUT_POINT = 400  # grid arrays (48 B) at up to 2x capacity, the cut copy, float32 output,
# the stray-point query and, with quality, the baseline's copy of all of them (measured: about 160 B
# a point on the weave, 400k exemplar points, 190k to 760k output points, no quality)
_BYTES_PER_EXEMPLAR_POINT = 600  # making a built-in (the weave: 330-360 B a point, transient), the
# texture (48 B), its k-d trees, surface variation, pieces' pairs and MLS cell grids (measured: about
# 340 B a point of the weave beside the texture, 100k to 400k points)
_BYTES_PER_FIELD_SAMPLE = 320  # D(T_in) on the host: query positions, nearest points, kernel results,
# float64 codes before rounding (measured: 265-290 B a sample, PatchSearch on 0.2M-1.6M samples);
# with quality, the output's D on the same spacing, one at a time
_MESH_BYTES_PER_SAMPLE = 24  # beyond pointsets.grid_mls_bytes: marching cubes' padded float32 copy
# and its per-cell work (geosynth.geometry.surface.field_to_mesh)


def synthesis_bytes(box_min, box_max, points_in: int, points_inside: int, lay: _Layout, quality: bool) -> dict:
    """Estimated peak bytes of a synthesis, by what drives them: ``"exemplar"`` (its points:
    making, precomputing), ``"field"`` (the D(T_in) grid's samples and, with quality, the
    output's D) and ``"output"`` (the grown points: the exemplar's density inside B times
    the canvas; doubled with quality for the baseline)."""
    area = float(np.prod((np.asarray(box_max, np.float64) - np.asarray(box_min, np.float64))[:2]))
    density = points_inside / area
    canvas = (lay.cols * lay.step + lay.patch + lay.extra) * (lay.rows * lay.step + lay.patch + lay.extra) * lay.cell ** 2
    nz = _grid_layers(box_min, box_max, lay.cell)
    nx, ny = _grid_columns(box_min, box_max, lay.cell)
    samples = nz * ny * nx
    if quality:
        out_x, out_y = (int(np.floor(lay.size[a] / lay.cell + 1e-9)) + 1 for a in range(2))
        samples = max(samples, nz * out_x * out_y)
    return {"exemplar": int(points_in) * _BYTES_PER_EXEMPLAR_POINT,
            "field": samples * _BYTES_PER_FIELD_SAMPLE,
            "output": int(density * canvas * _BYTES_PER_OUTPUT_POINT * (2 if quality else 1))}


def output_mesh_bytes(size_xy, z_span: float, points: int, spacing: float, resolution: int) -> int:
    """Estimated peak bytes of :func:`output_mesh` for an output of ``size_xy`` (x, y extent)
    and ``z_span`` (its points' height range, before the mesh's margin), ``points`` points
    of mean spacing ``spacing``, at ``resolution``: :func:`geosynth.geometry.pointsets.grid_mls_bytes`'s
    count plus marching cubes' (``_MESH_BYTES_PER_SAMPLE`` a sample)."""
    from geosynth.geometry.field import cubic_grid_geometry
    from geosynth.geometry.pointsets import MLS_REACH, grid_mls_bytes

    z = float(z_span) + 6.0 * spacing
    box = np.array([[0.0, 0.0, 0.0], [float(size_xy[0]), float(size_xy[1]), z]])
    nz, ny, nx = cubic_grid_geometry(box, int(resolution), 0.0)[2]
    n = nz * ny * nx
    probe = np.array([[0.0, 0.0, 0.0], [float(size_xy[0]), float(size_xy[1]), z]])  # the points' extent only
    extra = (int(points) - len(probe)) * 200  # grid_mls_bytes counts 200 B per input point
    return grid_mls_bytes(n, probe, 2.0 * spacing) + extra + n * _MESH_BYTES_PER_SAMPLE


def _largest_float(fits, value: float, digits: int = 3) -> float | None:
    """The largest v in (0, value) (``digits`` significant digits) with ``fits(v)``, by
    bisection (fits nondecreasing in badness); None when not even value * 1e-6 fits."""
    lo, hi = value * 1e-6, value
    if not fits(lo):
        return None
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if fits(mid):
            lo = mid
        else:
            hi = mid
    v = float(f"{lo:.{digits}g}")
    while v > lo:  # rounding to the digits went up
        v = float(f"{v - 10 ** (np.floor(np.log10(v)) - digits + 1):.{digits}g}")
    return v


def check_synthesis(box_min, box_max, points_in: int, points_inside: int, *, size=None, scale: float = 2.0,
                    patch: float = 0.4, extra: float = 0.2, overlap: float = 0.25, resolution: int = 48,
                    tileable: bool = False, quality: bool = True, count: bool = False,
                    mesh_resolution: int | None = None, z_span: float = 0.0, spacing: float | None = None,
                    available: int | None = None) -> _Layout:
    """Refuse, before any work, a synthesis whose options do not go together or cannot fit.

    The options' rules (the growth of Sec. 4: a patch of ``patch`` cells is blended with
    the output across its overlap and overwritten from ``patch - overlap`` on by the next
    one; F_k is the patch plus its extra region, cut from the exemplar box):

    - the overlaps on a patch's two sides must leave it an interior: 2 x overlap cells
      < patch cells (an overlap fraction below about 0.5);
    - the patch plus its extra region (plus one sample) must fit in the exemplar box's
      D(T_in) samples, so that there is a candidate to cut;
    - a patch of at least 4 cells; a patch's overlap query at most
      ``_MAX_OVERLAP_SAMPLES`` field samples (the search's exact uint32 sums), which
      bounds ``resolution``;
    - the memory: :func:`synthesis_bytes` (and :func:`output_mesh_bytes` with
      ``mesh_resolution``) within :func:`geosynth.core.memory.available_memory`.

    Args:
        box_min, box_max: the exemplar box B; points_in, points_inside: the exemplar's
            points, all and inside B (for a built-in or a mesh not yet sampled: the
            expected numbers).
        size, scale, patch, extra, overlap, resolution, tileable, quality: as
            :func:`synthesize_point_texture`.
        count: the exemplar's point count is an option (``count``, built-ins and sampled
            meshes): it may be named as the one to lower.
        mesh_resolution: also check :func:`output_mesh` at this resolution, with the
            output's height ``z_span`` and the exemplar's ``spacing``.
        available: bytes available (default :func:`geosynth.core.memory.available_memory`).

    Returns:
        The layout.

    Raises:
        ValueError: the combinations above, and a ``resolution`` too fine for the search
            (naming the largest that works).
        MemoryBudgetError: the estimate exceeds what is available; its ``option`` is the
            one whose part of the estimate is largest among those that can be lowered
            (``count``, ``resolution``, ``scale`` or ``size``; ``mesh_resolution`` for the
            mesh), with the largest value that fits.
    """
    from geosynth.core.memory import MemoryBudgetError, available_memory, format_bytes, largest_fitting

    share = points_inside / max(1, points_in)
    args = dict(size=size, scale=scale, patch=patch, extra=extra, overlap=overlap, resolution=resolution,
                tileable=tileable)

    def total(n_in=points_in, **over) -> int:
        a = dict(args, **over)
        lay = _layout_box(box_min, box_max, a["size"], a["scale"], a["patch"], a["extra"], a["overlap"],
                          a["resolution"], a["tileable"], quality)
        return sum(synthesis_bytes(box_min, box_max, n_in, int(round(n_in * share)), lay, quality).values())

    def resolution_works(r: int, avail: int | None) -> bool:
        try:
            need = total(resolution=r)
        except ValueError:
            return False
        return avail is None or need <= avail

    def largest_resolution(avail: int | None) -> int | None:
        lo = next((r for r in range(8, min(int(resolution), 4096)) if resolution_works(r, None)), None)
        if lo is None or not resolution_works(lo, avail):
            return None
        hi = int(resolution) - 1
        while lo < hi:  # bisection; the rules grow with r but for the cells' rounding
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if resolution_works(mid, avail) else (lo, mid - 1)
        return lo

    avail = available_memory() if available is None else int(available)
    try:
        lay = _layout_box(box_min, box_max, size, scale, patch, extra, overlap, resolution, tileable, quality)
    except _TooFine as exc:
        best = largest_resolution(avail) or largest_resolution(None)  # within the memory too, where one is
        raise ValueError(f"{exc}; use a resolution of at most {best:,} (or a smaller patch or overlap)."
                         if best else f"{exc}; use a smaller patch or overlap.") from None
    parts = synthesis_bytes(box_min, box_max, points_in, points_inside, lay, quality)
    need = sum(parts.values())
    if need > avail:
        out_option = "size" if size is not None else "scale"
        order = sorted(parts, key=parts.get, reverse=True)
        options = {"exemplar": "count" if count else None, "field": "resolution", "output": out_option}
        tried = [options[k] for k in order if options[k] is not None]
        largest, option = None, tried[0]
        for opt in tried:
            if opt == "count":
                largest = largest_fitting(lambda n: total(n_in=n), avail, 1000, points_in)
            elif opt == "resolution":
                largest = largest_resolution(avail)
            elif opt == "scale":
                largest = _largest_float(lambda v: _fits(lambda: total(scale=v), avail), float(scale))
            else:
                f = _largest_float(lambda v: _fits(lambda: total(size=tuple(v * np.asarray(size, float))), avail), 1.0)
                largest = None if f is None else " ".join(f"{v:.4g}" for v in f * np.asarray(size, float))
            if largest is not None:
                option = opt
                break
        flag = {"count": "count", "resolution": "resolution", "scale": "scale", "size": "size"}[option]
        fix = (f"lower {flag} to at most {largest:,}" if isinstance(largest, int) else
               f"lower {flag} to at most {largest}" if largest is not None else
               f"even the smallest {flag} does not fit")
        what = (f"a synthesis from {points_in:,} exemplar points ({points_inside:,} inside B), D(T_in) of "
                f"{_grid_layers(box_min, box_max, lay.cell) * np.prod(_grid_columns(box_min, box_max, lay.cell)):,} "
                f"samples and an output of {lay.size[0]:.4g} x {lay.size[1]:.4g} "
                f"(about {parts['output'] // (_BYTES_PER_OUTPUT_POINT * (2 if quality else 1)):,} points)")
        raise MemoryBudgetError(f"{what} needs about {format_bytes(need)}, more than the {format_bytes(avail)} "
                                f"available; {fix} (or free memory).", option=option, largest=largest,
                                estimate=need, available=avail)
    if mesh_resolution is not None:
        from geosynth.core.memory import require

        sp = float(spacing) if spacing else float(lay.cell)
        n_out = parts["output"] // (_BYTES_PER_OUTPUT_POINT * (2 if quality else 1))

        def mesh(r: int) -> int:
            return need + output_mesh_bytes(lay.size, z_span, n_out, sp, r)

        require(mesh(int(mesh_resolution)), option="mesh_resolution", value=int(mesh_resolution), largest_fn=mesh,
                smallest=8, available=avail,
                what=f"the output's mesh at resolution {int(mesh_resolution):,} (beside the synthesis)")
    return lay


def _fits(fn, avail: int) -> bool:
    try:
        return fn() <= avail
    except ValueError:
        return False



# One BLAS thread for the whole synthesis: the thin-plate spline's thin (S, n) x (n, 3)
# products, split over OpenBLAS's threads, left the idle ones spinning (a 9,736-point
# chainmail patch: 226 ms of CPU with 2 threads, 35 ms with one; the spinning also took
# the cores from PoCL's workers), and a threaded product's sums depend on the thread count.
# One OpenMP thread too: pykdtree's many small queries (a few thousand points each; the
# blend's then, the seam errors' MLS surfaces now) took more CPU with a second OpenMP thread
# than they saved (height field, blend stage: 3.2 CPU s with 2 threads, 2.7 s with one).
def _one_thread(fn):
    """Run ``fn`` with one BLAS and one OpenMP thread. pykdtree is loaded first: threadpoolctl
    limits only the libraries loaded when the limit starts, and pykdtree brings its own libgomp."""
    @functools.wraps(fn)
    def run(*args, **kwargs):
        passive_openmp_threads()
        import pykdtree.kdtree  # noqa: F401

        with threadpool_limits(limits={"blas": 1, "openmp": 1}):
            return fn(*args, **kwargs)
    return run


@dataclass(frozen=True)
class PointTextureOptions:
    """M2's settings, declared, checked and documented once (issue 33):
    :func:`synthesize_point_texture` takes them as keywords or as ``options=``, and
    ``geosynth pointtexture`` builds one from its options. Every value is checked when the
    object is made, before any work (a bad one is a ``ValueError`` or ``TypeError`` naming it);
    what depends on the exemplar (a patch of at least 4 cells that fits in its box with its
    extra region, the overlaps leaving it an interior) is checked by :func:`check_synthesis`.

    Attributes:
        size: (2,) output extent in x and y, world units, both > 0; None: ``scale`` times B's.
        scale: output extent in units of the exemplar box B's (when ``size`` is None), in (0, 1e4].
        patch: patch side as a fraction of B's shorter side, in (0, 1]; None: chosen from the
            exemplar's element size (:func:`choose_patch`, the same for a built-in and a file;
            the report's ``patch_choice`` says what it measured).
        extra: width w_E of the extra region E_k as a fraction of the patch (the paper used
            1/8 to 1/4), in (0, 0.5].
        overlap: overlap width as a fraction of the patch, in (0, 0.5], leaving the patch an
            interior (2 x overlap < patch, in cells; see :func:`check_synthesis`).
        resolution: samples of D(T_in) along B's longer side (>= 8; the paper's grids had
            51 to 84).
        weights: a :class:`geosynth.pointtexture.warping.WarpWeights`; None: the paper's preset
            for a built-in, else WarpWeights().
        eps: the relative tolerance of the candidate set (step 2), finite, >= 0.
        tileable: grow a periodic output (its opposite borders continue each other).
        relax: relax the final point set (:func:`geosynth.pointtexture.blending.relax_points`).
        quality: compute the quality numbers and the random-pasting baseline.
        quality_samples: patches sampled per direction for the patch-field distance, >= 1.
    """

    size: tuple[float, float] | None = None
    scale: float = 2.0
    patch: float | None = None
    extra: float = 0.2
    overlap: float = 0.25
    resolution: int = 48
    weights: object | None = None
    eps: float = 0.1
    tileable: bool = False
    relax: bool = False
    quality: bool = True
    quality_samples: int = 16

    def __post_init__(self) -> None:
        from geosynth.compute.checks import check_bool
        from geosynth.pointtexture.warping import WarpWeights

        if self.size is not None:
            object.__setattr__(self, "size", tuple(float(v) for v in _check_size(self.size)))
        _fraction("scale", self.scale, 0.0, 1e4)
        if self.patch is not None:
            _fraction("patch", self.patch, 0.0, 1.0)
        _fraction("extra", self.extra, 0.0, 0.5)
        _fraction("overlap", self.overlap, 0.0, 0.5)
        _check_resolution(self.resolution)
        if self.weights is not None and not isinstance(self.weights, WarpWeights):
            raise TypeError(f"weights must be a geosynth.pointtexture.warping.WarpWeights, got "
                            f"{type(self.weights).__name__}.")
        eps = self.eps
        if not (isinstance(eps, (int, float, np.integer, np.floating)) and np.isfinite(eps) and eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got {eps!r}.")
        for name in ("tileable", "relax", "quality"):
            object.__setattr__(self, name, check_bool(name, getattr(self, name)))
        qs = self.quality_samples
        if isinstance(qs, (bool, np.bool_)) or not isinstance(qs, (int, np.integer)) or qs < 1:
            raise ValueError(f"quality_samples must be an integer >= 1, got {qs!r}.")


@_one_thread
def synthesize_point_texture(
    exemplar,
    size=None,
    *,
    scale: float = 2.0,
    patch: float | None = None,
    extra: float = 0.2,
    overlap: float = 0.25,
    resolution: int = 48,
    weights=None,
    eps: float = 0.1,
    tileable: bool = False,
    relax: bool = False,
    quality: bool = True,
    quality_samples: int = 16,
    device: str | None = None,
    seed: int = 0,
    progress: bool = False,
    options: PointTextureOptions | None = None,
):
    """Grow a larger point-set geometry texture from an exemplar (Sec. 4 and 5).

    Args:
        exemplar: a :class:`geosynth.pointtexture.texture.PointTexture`, a built-in name
            (heightfield, chainmail, weave, flowers) or a file (PLY point set or mesh).
        size, scale, patch, extra, overlap, resolution, weights, eps, tileable, relax, quality,
            quality_samples: the settings, each documented and checked once in
            :class:`PointTextureOptions`.
        device: a device string; None means "auto".
        seed: seed of every random choice.
        progress: show a progress bar on stderr.
        options: the settings as one :class:`PointTextureOptions` instead of the keywords
            (then the keywords must keep their defaults).

    Runs with one BLAS and one OpenMP thread (threadpoolctl: faster for the spline's thin
    products and the small k-d tree queries, and the output does not depend on the BLAS
    thread count).

    Returns:
        ``(points, report, timings)``: a :class:`geosynth.geometry.pointsets.PointSet` (float32
        positions and unit normals, x and y from B's corner to B's corner + size; uint8
        colours when the exemplar has them, each point's from the exemplar point it was
        warped from), a
        :class:`PointTextureReport`, and seconds per stage (precompute, search, warp,
        blend, other, total; quality apart). On two or more cores the rows grow on two
        threads: the stage times are then summed over both (more than the total), and with
        ``quality`` the seam measurements inside the growth stay in the total (time with
        ``quality=False`` for clean numbers, as bench/bm_pointtexture.py does).

    Raises:
        ValueError: a patch larger than the exemplar box (with its extra region), bad
            numbers, and the input errors of :class:`PointTexture`.
        TypeError: arguments of the wrong type.
    """
    from geosynth.compute import checks as _checks
    from geosynth.compute.host_steps import host_threads
    from geosynth.geometry.pointsets import MLS_REACH, PointSet
    from geosynth.pointtexture.blending import has_pieces
    from geosynth.pointtexture.patch_search import PatchSearch
    from geosynth.pointtexture.warping import surface_variation

    t_start = time.perf_counter()
    given = dict(size=size, scale=scale, patch=patch, extra=extra, overlap=overlap, resolution=resolution,
                 weights=weights, eps=eps, tileable=tileable, relax=relax, quality=quality,
                 quality_samples=quality_samples)
    # every setting checked here, before any work
    options = settings_from(PointTextureOptions, options, given, keyword_defaults(synthesize_point_texture, given))
    size, scale, patch, extra, overlap, resolution = (options.size, options.scale, options.patch, options.extra,
                                                      options.overlap, options.resolution)
    weights, eps, tileable, relax, quality, quality_samples = (options.weights, options.eps, options.tileable,
                                                               options.relax, options.quality, options.quality_samples)
    texture = _as_texture(exemplar, seed)
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}.")
    host_threads()  # a bad GEOSYNTH_HOST_THREADS is refused here, before any work
    if weights is None:
        weights = _default_weights(texture)
    backend = _checks.resolve_backend(device)
    device = backend.name  # the resolved device ("auto" / None made concrete): every stage runs on this one
    choice = None
    if patch is None:
        choice = choose_patch(texture, resolution)
        patch = choice.patch
    inside = int(texture.inside_mask(texture.points, texture.box_min, texture.box_max).sum())
    lay = check_synthesis(texture.box_min, texture.box_max, len(texture), inside, size=size, scale=scale, patch=patch,
                          extra=extra, overlap=overlap, resolution=resolution, tileable=tileable, quality=quality)
    timer = _Timer()
    spacing = texture.spacing
    smallest = float(np.max(texture.points.max(axis=0) - texture.points.min(axis=0))) * 2.0 ** -16
    if not spacing > smallest:  # float32 kernels cannot resolve the MLS width (pointsets.smallest_radius)
        raise ValueError(f"the exemplar's mean point spacing {spacing:.3g} is below its extent's float32 resolution "
                         f"({smallest:.3g}): its points nearly coincide in pairs; thin or merge them.")
    h = 2.0 * spacing
    band = MLS_REACH * h
    # D(T_in) (the device's kernel, host steps) while a second thread finds the exemplar's
    # surface variation and its pieces (compiled steps and SciPy, which let go of the GIL)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="geosynth-precompute") as pool:
        variation_job = pool.submit(surface_variation, texture.points)
        pieces_job = pool.submit(has_pieces, texture.points, spacing)
        search = PatchSearch(texture, lay.cell, lay.patch, lay.extra, h, band, device)
        variation = variation_job.result()
        cut = pieces_job.result()  # disconnected pieces (flowers): cut, not blended
    timer.add("precompute", t_start)
    growth = _Growth(texture, search, lay, weights, eps, tileable, device, spacing, h, variation)
    grid, stats = _grow(growth, np.random.default_rng(seed), timer, seams_wanted=quality, progress=progress, cut=cut)
    t0 = time.perf_counter()
    p, n, src = _cut(grid, lay, texture, tileable)
    if relax:
        from geosynth.pointtexture.blending import relax_points

        p, n = relax_points(p, n, spacing, device=device)
    measured = _relief_measure(texture, choice, lay, spacing)
    relief = {"exemplar": measured.exemplar, "output": measured(p)}
    timer.add("other", t0)
    timings = dict(timer.t)
    seam_time = timings.pop("quality")  # the seam errors measured during the growth
    # On two growth threads a seam measurement overlaps the other thread's synthesis: its time
    # stays in the total then (an over-read, never an under-read; quality=False times cleanly).
    timings["total"] = time.perf_counter() - t_start - (seam_time if stats["threads"] == 1 else 0.0)
    report = PointTextureReport(
        exemplar=texture.name, points_in=len(texture), points_out=len(p), size=tuple(float(v) for v in lay.size),
        tileable=tileable, grid=search.shape, cell=lay.cell, patch=lay.patch, extra=lay.extra, overlap=lay.overlap,
        patches=lay.cols * lay.rows, candidates=float(np.mean(stats["candidates"])) if stats["candidates"] else 0.0,
        spacing=spacing, radius=h, arbitrated=search.arbitrated + stats["arbitrated"], device=device,
        kept_warp=int(stats["kept_warp"]), patch_choice=choice.line if choice is not None else "",
        relief=relief,
    )
    if quality:
        timings["quality"] = _quality_numbers(growth, report, p, n, stats, seed, quality_samples, measured) + seam_time
    points = PointSet(p.astype(np.float32), n.astype(np.float32), _source_colors(texture, src))
    return points, report, timings


class _ReliefMeasure:
    """Item 2 of issue 32: a point set's element size and relief amplitude measured as the
    exemplar's were (:func:`geosynth.pointtexture.element_size.relief_scale` over the output's
    box, near the exemplar's period: half to twice it, within what the exemplar's map
    measures). ``exemplar``: its (period, amplitude, peak); calling it on points gives theirs."""

    def __init__(self, exemplar_scale, out_lo: np.ndarray, out_hi: np.ndarray, spacing: float):
        ex_side = min(exemplar_scale.shape[0] * exemplar_scale.cell[1], exemplar_scale.shape[1] * exemplar_scale.cell[0])
        self.scale, self.lo, self.hi, self.spacing = exemplar_scale, out_lo, out_hi, spacing
        self.band = (0.5 * exemplar_scale.period, min(2.0 * exemplar_scale.period, 0.5 * ex_side))
        self.exemplar = (exemplar_scale.period, exemplar_scale.amplitude, exemplar_scale.peak)

    def __call__(self, points) -> tuple[float, float, bool]:
        from geosynth.pointtexture.element_size import relief_scale

        rs = relief_scale(points, self.lo, self.hi, self.spacing, cell=self.scale.cell[0], band=self.band,
                          near=self.scale.period)
        return rs.period, rs.amplitude, rs.peak


def _relief_measure(texture: PointTexture, choice, lay: _Layout, spacing: float) -> _ReliefMeasure:
    """The measure of the output's relief beside the exemplar's (the patch choice's measurement
    of the exemplar when the patch was chosen, else measured here)."""
    from geosynth.pointtexture.element_size import relief_scale

    ex_scale = choice.scale if choice is not None else relief_scale(texture.points, texture.box_min, texture.box_max,
                                                                    spacing)
    out_lo = texture.box_min[:2]
    return _ReliefMeasure(ex_scale, out_lo, out_lo + np.asarray(lay.size, np.float64), spacing)


def _quality_numbers(growth: _Growth, report, p: np.ndarray, n: np.ndarray, stats: dict, seed: int,
                     quality_samples: int, measured: _ReliefMeasure) -> float:
    """The quality numbers beside random pasting's (the baseline grown with seed + 1): the
    patch-field distance of the output's D to the exemplar's, the seam errors before and
    after blending, the share of stray points, the relief; written into ``report`` (the
    baseline's points too). Returns the seconds they took."""
    from geosynth.geometry.pointsets import PointSet

    tq = time.perf_counter()
    texture, search, lay, tileable, device = growth.texture, growth.search, growth.lay, growth.tileable, growth.device
    base_grid, base_stats = _grow(growth, np.random.default_rng(seed + 1), _Timer(), baseline=True)
    bp, bn, bsrc = _cut(base_grid, lay, texture, tileable)
    qrng = np.random.default_rng(seed)
    lo = texture.box_min[:2]
    out_codes = _field_codes(p, n, lay, search, growth.h, device, lo, lay.size)
    base_codes = _field_codes(bp, bn, lay, search, growth.h, device, lo, lay.size)
    q = report.quality
    q["field_distance"] = _field_distance(out_codes, search.codes, lay.patch, quality_samples, qrng, device)
    q["field_distance_baseline"] = _field_distance(base_codes, search.codes, lay.patch, quality_samples,
                                                   np.random.default_rng(seed), device)
    s = stats["seams"]
    if s["before"]:
        q["seam_before"] = float(np.sqrt(np.mean(np.square(s["before"]))))
        q["seam_after"] = float(np.sqrt(np.mean(np.square(s["after"]))))
        q["seam_baseline"] = float(np.sqrt(np.mean(np.square(base_stats["seams"]["baseline"]))))
    q["stray"] = _stray_share(p, n, growth.spacing, growth.h, device)
    q["stray_baseline"] = _stray_share(bp, bn, growth.spacing, growth.h, device)
    report.baseline = PointSet(bp.astype(np.float32), bn.astype(np.float32), _source_colors(texture, bsrc))
    report.relief["baseline"] = measured(bp)
    return time.perf_counter() - tq


def output_mesh(points, normals, spacing: float, resolution: int = 160, device: str | None = None):
    """A watertight mesh of a synthesized point set (item 7 of the method): the MLS signed
    distance sampled on a grid over its bounds (:func:`geosynth.geometry.pointsets.pointset_distance`)
    and marching cubes closed at the grid's border (:func:`geosynth.geometry.surface.field_to_mesh`).

    Args:
        points, normals: (N, 3) the point set.
        spacing: its mean point spacing (sets the MLS width, 2 x spacing).
        resolution: grid samples along the longest axis, >= 8.
        device: a device string.

    Returns:
        A ``trimesh.Trimesh``.
    """
    from geosynth.geometry.pointsets import pointset_distance
    from geosynth.geometry.surface import field_to_mesh

    p = np.asarray(points, np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    margin = 3.0 * spacing  # room above and below the surface; none in x and y, so that the
    lo[2] -= margin         # cut edges are capped flat at the output's border
    hi[2] += margin
    dist, _ = pointset_distance(p.astype(np.float32), np.asarray(normals, np.float32), resolution=int(resolution),
                                bounds=np.stack([lo, hi]), padding=0.0, radius=2.0 * spacing, device=device)
    return field_to_mesh(dist, level=0.0, close=True)
