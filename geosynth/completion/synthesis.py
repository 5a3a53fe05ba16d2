"""How is the missing part grown? Breckon and Fisher, "Plausible 3D colour surface completion
using non-parametric techniques": GrowSurface of Appendix A (Sec. 3), with the colour
extension of Sec. 6, and the evaluation of Sec. 5 (Table 1: the mean integral of the
volume between the fit and the surface, original vs completed part) and Sec. 6 (Fig. 13:
RGB histograms of the original and completed parts).

:func:`complete_surface` fits the underlying surface (:mod:`geosynth.completion.fit`),
prepares samples, targets and their triangulation (:mod:`geosynth.completion.prep`), uploads
the samples once (:class:`geosynth.completion.matching.ReliefIndex`) and grows:

- L = the untextured targets with a textured vertex among their edge neighbours, sorted
  by decreasing number of textured vertices in their W_t-ring neighbourhood;
- for each t in L: its matches (every sample x R rotations, within 1.1x the best score,
  :func:`geosynth.completion.matching.find_matches`), one picked with the seeded generator
  (the paper: uniformly; by default our histogram-aware pick, :class:`_Balance`); if
  its score is below MaxErrThreshold, t gets the match's displacement (and colour) and is
  textured; otherwise t is skipped and its window W_t shrinks by one ring (not below 1);
- a whole list without progress raises MaxErrThreshold by 10%. Bound: ``max_error`` lies
  in [2^-24, 128] (:func:`check_max_error`; the scores' resolution and clamp); once the
  threshold is over 128 every valid match is accepted, so a list without progress there
  and with final windows (no window shrank) would repeat for ever: the growth stops and
  the rest is reported unreached. Hence at most (targets) lists with progress and
  log(140.8 / max_error) / log(1.1) + W without.

Batches. Ties in the count are broken by a greedy colouring in id order: targets of one
count level are split into classes none of whose members lies within another's window
(ring distance <= max(W_a, W_b)), processed class after class, by id within a class. A
class is then scored in one launch per window size; the picks are made in list order
afterwards. Since no member of a class is in another's neighbourhood, and a partner is
valid only when it is a captured sample, this gives the same result as one target at a
time in that order.

Candidates. The paper (Sec. 4-5) uses the oversampled capture as its sample set: the
1-to-4 subdivision adds intermediate vertices so that a target whose position is out of
phase with the capture's sampling still finds partners at the right places. Those new
vertices are interpolated, though: smoother heights and averaged colours, no new detail
(the paper says as much), and about 3 of every 4 samples. As candidates they were the
matches' favourites (85% of the copies on bark, for 74% of the pool: their smoother
neighbourhoods score lower) and the completions came out 5-19% flatter with narrower
colour histograms. So by default (``candidates="capture"``) only the capture's own
vertices are candidates, i.e. copied from, while every sample, the oversampled ones
included, is a neighbour partner (``ReliefIndex.build(partners=ids)``): the phase
alignment the oversampling is for is kept, the copies are real captured values, and the
matching does 4x less work. ``candidates="samples"`` is the paper's pool.

Quality (printed with every run, :class:`CompletionReport`): the paper's mean integral
(mean |h| of the signed distance h to the fit) of the captured part and of the completed
part with the % difference; the RGB histogram distance (16 bins a channel, half the L1
distance of the normalized histograms, mean over R, G, B, in [0, 1]); the mean relief
slope |h_i - h_j| / |b_i - b_j| and the mean colour step |c_i - c_j| (RGB L1 / 3) over
pairs of vertices of a part about one target spacing apart (the capture's own vertices,
the completed targets; they see whether neighbouring displacements and colours fit
together); each beside a baseline that gives every target the displacement (in the
frames) and colour of a uniformly random candidate, reported as the mean (with min and
max) over ``BASELINE_DRAWS`` seeded draws, since one draw is a noisy yardstick. The
baseline keeps the distribution of |h| and of the colours by construction: on the volume and histogram numbers it shows
the sampling noise of independent copies, which a completion made of coherent patches
(fewer independent draws) only matches by chance; the slope and colour step are where
random copies fail. The honest yardstick for the volume and histogram numbers is the
capture against itself: its two halves (split at the median of the first fit parameter)
compared with each other, two coherent real parts of the surface.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from geosynth.completion.fit import FIT_KINDS, SurfaceFit, fit_frames, fit_surface, latitude_axis
from geosynth.completion.prep import (ReliefSurface, as_capture, capture_depth, check_spacing_rule, prepare_relief,
                                  ring_neighbourhoods, target_spacing)
from geosynth.core.exact import exp_fixed, norm3
from geosynth.core.options import keyword_defaults, settings_from

__all__ = ["AutoSettings", "CompletedSurface", "CompletionOptions", "CompletionReport", "check_max_error",
           "choose_settings", "complete_surface", "completion_picture", "match_chunk", "write_completion"]

DEFAULT_WINDOW = 3
DEFAULT_ROTATIONS = 4
DEFAULT_MU = 0.5
DEFAULT_MAX_ERROR = 0.1  # MaxErrThreshold on the [0, 1] normalized ssd (Efros and Leung's 0.1)
TOLERANCE = 1.1  # matches within 1.1x the best (Appendix A)
RELAX = 1.1  # MaxErrThreshold x 1.1 after a list without progress
# The range of max_error that means something: the scores are integer codes, SCORE_ONE (2^24) for
# an ssd of 1, clamped at CODE_CAP (2^31, an ssd of 128). Below one code step every threshold
# accepts only exact copies (the same as 2^-24); above 128 it no longer tells matches apart.
MIN_MAX_ERROR = 2.0 ** -24
MAX_MAX_ERROR = 128.0
HIST_BINS = 16
_MAX_BATCH = 64
_BATCH_CODES = 1 << 25  # codes (Q x S x R) one launch may hold at most
HINT_RINGS = 3  # coherence hints: the candidates within 3 edge rings of the samples that textured the neighbours
HINT_PROBES: tuple[int, ...] | None = ()  # stride probes after the hints (None: find_matches' default)
SEARCHES = ("exhaustive", "coherent")
# FindMatches' search (issue 32: 20,000 captured vertices in 60 s). "exhaustive" is the paper's
# (every candidate; exact pruning keeps it the paper's selection) and costs targets x candidates;
# "coherent" picks among the coherence hints, COHERENT_PROBES candidates evenly spread over the
# capture and the candidates around the best of those (coarse to fine), linear in the targets.
# "auto" takes the exhaustive search while targets x candidates x R stays under AUTO_EXHAUSTIVE_WORK.
COHERENT_PROBES = 128
COHERENT_AROUND = 4  # ... then the candidates within HINT_RINGS rings of each target's 4 best found so far
AUTO_EXHAUSTIVE_WORK = 4e7  # ~20 s of the full pass on 2 cores (measured 2e6 candidate-rotations/s, opencl)
BALANCE_STRENGTH = 4.0  # the histogram-aware draw: weights exp(strength x deficit score), score in [-1, 1]
BALANCE_PENALTY = 0.5  # codes x (1 + penalty x (1 - score) / 2) before the 1.1x rule (find_matches at 1.1 x 1.5)
BASELINE_DRAWS = 5  # the random-copy baseline: mean (and min, max) over this many seeded draws
# Automatic settings (issue 32, :func:`choose_settings`): measured on the capture, the same for a
# built-in and a file.
AUTO_COARSEN = 12.0  # a capture with more samples on its dominant period than this is resampled ...
AUTO_PER_PERIOD = 6.0  # ... to targets this many to a period (the built-ins grow well at 5-10) ...
AUTO_BAND = 0.02  # ... when under this share of its power lies below half that period (band-limited)
AUTO_FEATURE_COARSEN = 4.0  # a relief that is not band-limited whose correlation length spans more targets
# than this (the zoo's drawn captures and the built-ins: 1.2-3.0) ...
AUTO_PER_FEATURE = 3.0  # ... is resampled to targets at that length / this
AUTO_WINDOW_PERIODS = 0.75  # window W = round(this x samples a period): (2W + 1) spacings ~ 1.5 periods
AUTO_WINDOW_RANGE = (3, 5)  # the paper's W = 3 at least; 5 at most (a 5-ring query holds ~91 vertices)
AUTO_WHOLE = 2 / 3  # ... and no larger than two thirds of the capture's vertices can hold whole (3 at least),
AUTO_WHOLE_SPACED = 0.4  # ... or, for an isotropic relief whose window spans a period, this share (its elements
# are spaced by what a window sees of their neighbours: under a period, bumps grow into chains and bare bands)
AUTO_DIRECTED = 0.2  # anisotropy at or above this: a directed relief, copied unturned in the fit's frames
AUTO_SLOPE_ORDER = 0.3  # ... and its slopes keep to one direction or two at right angles at least this much
AUTO_FINE = 0.05  # share of the power below 4 samples a wavelength at or above this: sharp features,
AUTO_REFINE = 2  # ... refined this many passes when directed but not stripes (one-sided growth breaks them)
AUTO_STRIPES = 0.5  # anisotropy at or above this: stripes (R 4 in the paper's frames, no refinement)
LATITUDE_SHARE = 0.25  # latitude_axis's least-eigenvalue share under this (1/3: no axis): slopes about that axis
AUTO_REGULAR = 0.9  # 10th percentile / median nearest-neighbour spacing at or above this: a regular lattice


@dataclass
class CompletedSurface:
    """The completed surface: the oversampled capture and the completed targets in one mesh.

    Attributes:
        positions: (V, 3) float32 positions ``base + D``.
        normals: (V, 3) float32 unit vertex normals of the mesh.
        colors: (V, 3) uint8 colours, or None when the capture had none.
        faces: (F, 3) int32 triangles.
        completed: (V,) bool, True for the targets (the completed part).
        captured: (V,) bool, True for the capture's own vertices (not the oversampling's).
        textured: (V,) bool, False only for targets the growth could not reach.
        fit: the :class:`~geosynth.completion.fit.SurfaceFit`.
        alpha: (V,) uint8 alpha of the colours when the capture gave one, else None.
    """

    positions: np.ndarray
    normals: np.ndarray
    colors: np.ndarray | None
    faces: np.ndarray
    completed: np.ndarray
    captured: np.ndarray
    textured: np.ndarray
    fit: SurfaceFit
    alpha: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.positions)

    def to_mesh(self):
        """A ``trimesh.Trimesh`` (unprocessed) with the vertex colours."""
        import trimesh

        kw = {}
        if self.colors is not None:
            alpha = np.full(len(self), 255, np.uint8) if self.alpha is None else self.alpha
            kw["vertex_colors"] = np.column_stack([self.colors, alpha])
        return trimesh.Trimesh(self.positions, self.faces, process=False, **kw)


@dataclass
class CompletionReport:
    """What a completion did and how good it is (:func:`complete_surface`).

    Attributes:
        fit: the fit's one-line description.
        samples, targets, textured, unreached: counts (``samples`` after oversampling).
        spacing: the target spacing (world units); ``spacing_rule`` how it was chosen
            ("minimum" or "median" edge of the capture, :func:`complete_surface`).
        window, rotations, mu, max_error: the parameters; ``final_max_error`` the
            MaxErrThreshold at the end.
        lists, passes_without_progress, failed_matches: growth statistics.
        refine: refinement passes after the growth; ``refined``: how many targets
            changed their source sample in them (summed over the passes).
        quality: name -> value; keys ``volume_original``, ``volume_completed``,
            ``volume_diff_pct``, ``volume_baseline``, ``volume_baseline_diff_pct``,
            ``hist_distance``, ``hist_baseline`` (None without colour), ``slope_original``,
            ``slope_completed``, ``slope_diff_pct``, ``slope_baseline``,
            ``slope_baseline_diff_pct``, ``colour_step_original``, ``colour_step_completed``,
            ``colour_step_diff_pct``, ``colour_step_baseline``, ``colour_step_baseline_diff_pct``
            (None without colour). The baseline's numbers are means over ``baseline_draws``
            (``BASELINE_DRAWS``, 5) seeded random-copy draws; ``volume_baseline_diff_pct_range``,
            ``slope_baseline_diff_pct_range``, ``colour_step_baseline_diff_pct_range`` and
            ``hist_baseline_range`` hold the draws' (min, max). ``volume_self_diff_pct`` and
            ``hist_self`` (the capture's two halves, split at the median of the first fit
            parameter, against each other: how much two real parts of the surface differ;
            ``hist_self`` None without colour).
        device: the device string the matching ran on.
        whole_windows: how many of the capture's own vertices lie at least ``window``
            target spacings from the captured part's border (their W-ring neighbourhood is
            all captured relief; :func:`geosynth.completion.prep.capture_depth`).
        picked_original: the fraction of completed targets that copied one of the
            capture's own vertices (the rest copied oversampling vertices); n_original: how
            many of the samples are the capture's own vertices.
        auto: the automatic settings' one-line reason (:func:`choose_settings`; "" when every
            setting was given); n_candidates: how many samples are candidates.
        frame_axis: a sphere's latitude frames' axis (:func:`geosynth.completion.fit.latitude_axis`)
            and its least-eigenvalue share, or None.
        search: FindMatches' search, one of ``SEARCHES`` (:func:`choose_search`).
        The quality also holds the relief's scale, captured part against completed part, both
        measured in the fit's unrolled frame at the target spacing
        (:mod:`geosynth.completion.spectrum`): ``relief_captured`` and ``relief_completed``
        (ReliefSpectrum, None when a part is too small to measure), ``period_ratio``,
        ``amplitude_ratio`` (completed / captured) and ``angle_diff_deg`` (in [0, 90]).
    """

    fit: str
    samples: int
    targets: int
    textured: int
    unreached: int
    spacing: float
    window: int
    rotations: int
    mu: float
    max_error: float
    final_max_error: float
    lists: int
    passes_without_progress: int
    failed_matches: int
    quality: dict = dc_field(default_factory=dict)
    device: str = "cpu"
    picked_original: float = float("nan")
    n_original: int = 0
    frames: str = "paper"
    refine: int = 0
    refined: int = 0
    spacing_rule: str = "minimum"
    whole_windows: int = -1
    auto: str = ""
    n_candidates: int = 0
    frame_axis: tuple | None = None
    search: str = "exhaustive"

    def lines(self) -> list[str]:
        """The report as printed by the CLI."""
        q = self.quality
        out = [f"fit: {self.fit}",
               f"samples {self.samples:,} ({'captured part oversampled once' if self.samples > self.n_original else 'the capture, not oversampled'}"
               + (f", {self.n_candidates:,} of them candidates" if 0 < self.n_candidates < self.n_original else "")
               + f"), targets {self.targets:,} at spacing {self.spacing:.4g} "
               + (f"(the capture's {self.spacing_rule} edge)" if self.spacing_rule in ("minimum", "median") else
                  "(chosen from the relief's period)") + f"; window {self.window}, rotations {self.rotations}, frames {self.frames}"
               + ("" if self.frame_axis is None else
                  f" (latitudes about ({', '.join(f'{x:.3f}' for x in self.frame_axis[0])}), "
                  + ("the relief's axis" if self.frame_axis[1] < LATITUDE_SHARE else "the fit's axis: the relief has "
                     "none") + f", share {self.frame_axis[1]:.3f})")
               + f", mu {self.mu:g}, search {self.search}, device "
               f"{self.device}"
               + ("" if self.whole_windows < 0 else
                  f"; {self.whole_windows:,} of the capture's {self.n_original:,} vertices "
                  f"({self.n_original and self.whole_windows / self.n_original:.0%}) hold a whole window")]
        out += [self.auto] if self.auto else []
        out += [
               f"growth: {self.lists} boundary lists, {self.failed_matches} skipped matches, "
               f"{self.passes_without_progress} lists without progress (MaxErrThreshold {self.max_error:g} -> "
               f"{self.final_max_error:.4g}), {self.unreached} targets unreached; "
               f"{self.picked_original:.0%} of the copies from the capture's own vertices "
               f"({self.samples and self.n_original / self.samples:.0%} of the samples)"]
        if self.refine:
            out.append(f"refinement: {self.refine} pass{'es' if self.refine > 1 else ''} over every completed target "
                       f"with its whole window, {self.refined:,} source changes")
        if q and q.get("relief_captured") is not None and q.get("relief_completed") is not None:
            out.append(f"relief scale, captured: {q['relief_captured'].describe()}; completed: "
                       f"{q['relief_completed'].describe()}; completed / captured: period "
                       f"{q['period_ratio']:.3f}, amplitude {q['amplitude_ratio']:.3f}, orientation "
                       + (f"{q['angle_diff_deg']:.1f} deg apart" if q['relief_captured'].anisotropy >= AUTO_DIRECTED
                          else f"not compared (an isotropic relief: anisotropy {q['relief_captured'].anisotropy:.2f})"))
        if q:
            lo, hi = q["volume_baseline_diff_pct_range"]
            out.append(f"volume integral (Table 1): original {q['volume_original']:.5g}, completed "
                       f"{q['volume_completed']:.5g} ({q['volume_diff_pct']:.2f}% difference); random baseline, "
                       f"mean of {q['baseline_draws']} draws: {q['volume_baseline']:.5g} "
                       f"({q['volume_baseline_diff_pct']:.2f}%, draws {lo:.2f}-{hi:.2f}%)")
            out.append(f"the capture's two halves against each other: volume {q['volume_self_diff_pct']:.2f}% "
                       f"difference" + ("" if q.get("hist_self") is None else
                                        f", RGB histogram distance {q['hist_self']:.4f}"))
            out.append(f"relief slope at the target spacing: original {q['slope_original']:.4g}, completed "
                       f"{q['slope_completed']:.4g} ({q['slope_diff_pct']:.1f}% difference); random baseline "
                       f"{q['slope_baseline']:.4g} ({q['slope_baseline_diff_pct']:.1f}%, mean of "
                       f"{q['baseline_draws']} draws)")
            if q.get("hist_distance") is not None:
                lo, hi = q["hist_baseline_range"]
                out.append(f"RGB histogram distance original vs completed: {q['hist_distance']:.4f}; random "
                           f"baseline, mean of {q['baseline_draws']} draws: {q['hist_baseline']:.4f} (draws "
                           f"{lo:.4f}-{hi:.4f}; 0 = same histograms, 1 = disjoint)")
                out.append(f"colour step at the target spacing: original {q['colour_step_original']:.4g}, completed "
                           f"{q['colour_step_completed']:.4g} ({q['colour_step_diff_pct']:.1f}% difference); random "
                           f"baseline {q['colour_step_baseline']:.4g} ({q['colour_step_baseline_diff_pct']:.1f}%, mean "
                           f"of {q['baseline_draws']} draws)")
        return out


# ---------------------------------------------------------------------- checks


def check_max_error(max_error, name: str | None = "max_error") -> float:
    """``max_error`` as a float if it lies in [MIN_MAX_ERROR, MAX_MAX_ERROR], else a one-line
    ValueError naming ``name`` (None: the message starts "must be", for argparse) and the range.

    The MaxErrThreshold is compared with integer scores (SCORE_ONE = an ssd of 1, clamped at
    an ssd of 128): a smaller value accepts no more than 2^-24 does (exact copies only) and
    only adds lists without progress (the threshold grows 10% a list: from 1e-30, about 600
    before the first copy); a larger one accepts every valid match, as 128 nearly does.
    Within the range, :func:`_grow` makes at most (targets) lists with progress and
    log(128 x 1.1 / max_error) / log(1.1) + W lists without (at most 237 + W from 2^-24)."""
    ok = isinstance(max_error, (int, float, np.integer, np.floating)) and not isinstance(max_error, (bool, np.bool_))
    if not ok or not MIN_MAX_ERROR <= float(max_error) <= MAX_MAX_ERROR:
        raise ValueError(f"{name + ' ' if name else ''}must be a number from {MIN_MAX_ERROR:.2g} to {MAX_MAX_ERROR:g} (the match scores' "
                         f"range: {MIN_MAX_ERROR:.2g} is one step of the integer scores, {MAX_MAX_ERROR:g} the "
                         f"largest score; the paper's normalized ssd lies in [0, 1], default {DEFAULT_MAX_ERROR:g}), "
                         f"got {max_error!r}.")
    return float(max_error)


def _check_seed(seed) -> None:
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}.")


@dataclass(frozen=True)
class CompletionOptions:
    """M4's settings, declared, checked and documented once (issue 33): :func:`complete_surface`
    takes them as keywords or as ``options=``, and ``geosynth complete`` builds one from its
    options. Every value is checked when the object is made, before any work (a bad one is a
    ``ValueError`` naming it).

    Attributes:
        window: W, the neighbourhood radius in edge rings (>= 1); None: chosen from the
            relief (:func:`choose_settings`, as are ``rotations``, ``frames``, ``refine`` and
            ``spacing`` when None; explicit values override, the report names both).
        rotations: R, orientations tried about the normal (1..64).
        frames: the tangent frames the R rotations start from: "paper" (Sec. 3: per-normal,
            deterministic, locally consistent) or "fit" (our option: the fit's own orientation,
            on a cylinder u around it and v along its axis, on a plane its u and v axes, on a
            sphere along its latitudes about the relief's axis when it has one
            (:func:`geosynth.completion.fit.latitude_axis`, share under ``LATITUDE_SHARE``), else
            the fit's polar axis, :func:`geosynth.completion.fit.fit_frames`). With "fit" a
            relief with a preferred direction keeps it at R = 1 (R = 2 when a half turn is a
            symmetry of the relief).
        refine: refinement passes after the growth (our extension; 0 is the paper's single
            pass): every completed target matched again against its whole window, textured on
            every side by then (:func:`_refine`). 0 to 8.
        spacing: the target lattice's spacing: "minimum" (Sec. 4: the capture's minimum edge
            length) or "median" (our option: the median length of its edges on the fit, targets
            as dense as the capture; see :func:`geosynth.completion.prep.prepare_relief`), or a
            length (world units). When the automatic choice coarsens the targets, the
            candidates are thinned to one a target spacing in the fit's frame.
        mu: weight of shape against colour in [0, 1] (1: relief only).
        max_error: the initial MaxErrThreshold on the [0, 1] normalized ssd, from 2^-24 (about
            6e-8, one step of the integer scores) to 128 (the largest score); each list
            without progress raises it 10%, so the lists are bounded (module docstring).
        search: FindMatches' candidates: "exhaustive" (the paper: every candidate, cost
            targets x candidates), "coherent" (our option: the coherence hints and
            ``COHERENT_PROBES`` candidates spread evenly over the capture, then the candidates
            around each target's ``COHERENT_AROUND`` best of those; linear in the targets, the
            same selection rule among them), or "auto": exhaustive while targets x
            candidates x R is under ``AUTO_EXHAUSTIVE_WORK``, else coherent.
        balance: True: the histogram-aware pick among the matches within 1.1x the best (our
            extension, :class:`_Balance`, strength ``BALANCE_STRENGTH``); a number > 0: the
            same with that strength; False: the paper's uniform pick.
        candidates: "capture": only the capture's own vertices are candidate matches (their
            displacements and colours are copied), the oversampling's vertices serve as
            neighbour partners only; "samples": every sample, the oversampled ones included
            (the paper, Sec. 5). See the module docstring.
        oversample: "butterfly", "midpoint" (the paper's coplanar midpoints) or "none"; see
            :func:`geosynth.completion.prep.prepare_relief`. None: "butterfly", or "none" when
            the automatic spacing makes the targets coarser than the capture.
        max_targets: refuse a completion with more targets (None: no limit).
    """

    window: int | None = None
    rotations: int | None = None
    frames: str | None = None
    refine: int | None = None
    spacing: str | float | None = None
    mu: float = DEFAULT_MU
    max_error: float = DEFAULT_MAX_ERROR
    search: str = "auto"
    balance: bool | float = True
    candidates: str = "capture"
    oversample: str | None = None
    max_targets: int | None = 200_000

    def __post_init__(self) -> None:
        window, rotations, mu = self.window, self.rotations, self.mu
        if window is not None and (isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1):
            raise ValueError(f"window must be an integer >= 1 (edge rings), got {window!r}.")
        if rotations is not None and (isinstance(rotations, bool) or not isinstance(rotations, (int, np.integer))
                                      or not 1 <= rotations <= 64):
            raise ValueError(f"rotations must be an integer from 1 to 64, got {rotations!r}.")
        if not isinstance(mu, (int, float, np.floating)) or not 0 <= float(mu) <= 1:
            raise ValueError(f"mu must be a number in [0, 1] (1: relief only), got {mu!r}.")
        check_max_error(self.max_error)
        if self.frames is not None and (not isinstance(self.frames, str) or self.frames not in ("paper", "fit")):
            raise ValueError(f"frames must be 'paper' or 'fit', got {self.frames!r}.")
        refine = self.refine
        if refine is not None and (isinstance(refine, (bool, np.bool_)) or not isinstance(refine, (int, np.integer))
                                   or not 0 <= refine <= 8):
            raise ValueError(f"refine must be an integer from 0 to 8 (refinement passes), got {refine!r}.")
        if self.spacing is not None:
            check_spacing_rule(self.spacing)
        if not isinstance(self.search, str) or self.search not in SEARCHES + ("auto",):
            raise ValueError(f"search must be one of {', '.join(SEARCHES + ('auto',))}, got {self.search!r}.")
        balance = self.balance
        if isinstance(balance, (bool, np.bool_)):
            object.__setattr__(self, "balance", bool(balance))
        elif not isinstance(balance, (int, float, np.integer, np.floating)) or not 0 < float(balance) < math.inf:
            raise ValueError(f"balance must be True, False or a finite strength > 0, got {balance!r}.")
        if self.candidates not in ("capture", "samples"):
            raise ValueError(f"candidates must be 'capture' or 'samples', got {self.candidates!r}.")
        if self.oversample is not None and self.oversample not in ("butterfly", "midpoint", "none"):
            raise ValueError(f"oversample must be 'butterfly', 'midpoint' or 'none', got {self.oversample!r}.")
        mt = self.max_targets
        if mt is not None and (isinstance(mt, bool) or not isinstance(mt, (int, np.integer)) or mt < 1):
            raise ValueError(f"max_targets must be an integer >= 1 or None, got {mt!r}.")


@dataclass(frozen=True)
class AutoSettings:
    """What :func:`choose_settings` measured on a capture and chose from it (issue 32).

    Attributes:
        window, rotations, frames, refine, spacing: the choices, in
            :func:`complete_surface`'s terms (``spacing`` "minimum", "median" or a length).
        coarse: True when the targets are coarser than the capture (the capture then is not
            oversampled and its candidates are thinned to the target spacing).
        capture_spacing: the capture's median nearest-neighbour spacing in the fit's frame.
        spectrum: the capture's :class:`~geosynth.completion.spectrum.ReliefSpectrum` in the fit's
            unrolled frame (:func:`geosynth.completion.fit.relief_frame`).
        fine: the share of its power below 4 capture spacings a wavelength.
        regular: 10th percentile / median of the nearest-neighbour spacings.
        reason: the one-line report.
        latitude: a sphere's :func:`geosynth.completion.fit.latitude_axis` (axis, share) when it
            was measured (a relief with a period), else None.
    """

    window: int
    rotations: int
    frames: str
    refine: int
    spacing: str | float
    coarse: bool
    capture_spacing: float
    spectrum: object
    fine: float
    regular: float
    reason: str
    latitude: tuple | None = None
    targets_per_period: float = float("nan")
    spaced: bool = False

    def whole_share(self, window: int) -> float:
        """The share of the capture that must hold a whole window of ``window`` rings for it to
        be kept (:data:`AUTO_WHOLE`; :data:`AUTO_WHOLE_SPACED` for a relief of elements spaced in
        every direction, neither directed nor stripes (``spaced``), whose window of
        (2 ``window`` + 1) target spacings spans its period)."""
        # a window is whole rings: one within 10% of the period spans it (5 rings on 11.3 targets a period)
        spans = math.isfinite(self.targets_per_period) and 2 * window + 1 >= 0.9 * self.targets_per_period
        return AUTO_WHOLE_SPACED if self.spaced and spans else AUTO_WHOLE


def _relief_grid(fit: SurfaceFit, points: np.ndarray, spacing: float | None = None, cut: float | None = None):
    """(grid, mask, step, nn spacing, regularity, cut): points' heights in the fit's unrolled frame
    on a grid of ``spacing`` (None: their median nearest-neighbour spacing), at most 1024 a side."""
    from geosynth.completion.fit import relief_frame
    from geosynth.completion.spectrum import heights_on_grid
    from geosynth.core.neighbours import nearest

    uv, h, cut = relief_frame(fit, points, cut)
    nn = nearest(uv, k=1)[0][:, 0]
    med = float(np.median(nn))
    regular = float(np.quantile(nn, 0.1)) / med if med > 0 else 0.0
    step = med if spacing is None else float(spacing)
    # a grid no larger than 1024 a side (an oversampled capture is measured at a coarser step)
    step = max(step, float(np.max(np.ptp(uv, axis=0))) / 1024.0)
    grid, mask = heights_on_grid(uv, h, step)
    return grid, mask, step, med, regular, cut


def _capture_relief(fit: SurfaceFit, points: np.ndarray, spacing: float | None = None, cut: float | None = None):
    """(spectrum, fine share, nn spacing, regularity, cut, share of power below half the period,
    slope order, correlation length) of points' relief in the fit's frame."""
    from geosynth.completion.spectrum import correlation_length, fine_share, relief_spectrum

    grid, mask, step, med, regular, cut = _relief_grid(fit, points, spacing, cut)
    spec = relief_spectrum(grid, step, mask)
    # power below half the dominant period: ~0 for a band-limited relief (a sine, a knurl), a few % and
    # more for broadband ones (bumps of many sizes), which keep the capture's own sampling
    band = fine_share(grid, step, spec.period / 2, mask) if math.isfinite(spec.period) else 1.0
    return (spec, fine_share(grid, step, 4 * step, mask), med, regular, cut, band, _slope_order(grid, mask),
            correlation_length(grid, step, mask))


def _slope_order(grid: np.ndarray, mask: np.ndarray) -> float:
    """How much the relief's slopes keep to one direction (|sum w e^(2i phi)| / sum w) or to
    two at right angles (the same with e^(4i phi): rows and columns of features), the larger,
    over the grid's slope vectors g with phi their angle and w = |g|^2, in [0, 1]. Random
    bumps score ~0 (the zoo's bumped cylinder: 0.06, where its spectrum's anisotropy read
    0.22 from a handful of bumps), a tower's arches 0.54, ridges 1. Elementwise arithmetic
    and NumPy sums: the same bits on every device."""
    z = np.where(mask, grid, np.nan)
    gy, gx = np.gradient(z)
    ok = np.isfinite(gx) & np.isfinite(gy)
    gx, gy = gx[ok], gy[ok]
    w = gx * gx + gy * gy
    total = float(np.sum(w))
    if not total > 0:
        return 0.0
    c2, s2 = gx * gx - gy * gy, 2.0 * gx * gy  # w e^(2i phi)
    safe = np.where(w > 0, w, 1.0)
    c4, s4 = (c2 * c2 - s2 * s2) / safe, 2.0 * c2 * s2 / safe  # w e^(4i phi)
    a2 = math.hypot(float(np.sum(c2)), float(np.sum(s2))) / total
    a4 = math.hypot(float(np.sum(c4)), float(np.sum(s4))) / total
    return max(a2, a4)


def _decided(length: float) -> float:
    """A measured length that sets a choice (a target spacing), rounded to 3 significant digits:
    the spectrum's and the autocorrelation's last bits may differ between CPUs' SIMD paths; the
    rounded value differs only at an exact rounding boundary."""
    return float(f"{length:.3g}")


def choose_settings(capture, fit: SurfaceFit) -> AutoSettings:
    """Measure a capture's relief and choose M4's settings from it (issue 32), the same for a
    built-in and a user's file.

    The relief's heights over the fit, unrolled into the fit's own (u, v) frame
    (:func:`geosynth.completion.fit.relief_frame`), give its dominant period T, orientation and
    anisotropy (:func:`geosynth.completion.spectrum.relief_spectrum`) and the share of power in
    sharp features (:func:`~geosynth.completion.spectrum.fine_share`); the capture's sampling s is
    the median nearest-neighbour spacing there. Then:

    - target spacing: a band-limited relief (< 2% of its power below T / 2) with more than
      ``AUTO_COARSEN`` (12) capture samples on T is sampled denser than the growth needs:
      targets at T / ``AUTO_PER_PERIOD`` (6), no oversampling, the
      candidates thinned to that spacing (cost falls with the square of both). Otherwise the
      capture's own sampling: its median edge on the fit when the fit is curved and the sampling
      regular (10th percentile of the spacings >= 0.9x the median: relief recesses below a
      curved fit shorten the 3-D edges, so the minimum edge measures the relief, not the
      sampling), else the paper's minimum edge (Sec. 4), unless that edge is under 0.9x the
      capture's median spacing (an irregular sampling, e.g. latitude-longitude rows closing up
      towards a sphere's poles: the minimum edge, floored at half the median, put 2.6x the
      targets on a zoo sphere, each window reaching half as far, for no detail the capture
      holds), which takes the median edge on the fit too. Both samplings are weighed: the
      coarser targets above are taken when either the capture or the rule's targets hold more
      than 12 on T. A relief that is not band-limited is coarsened by its elements' size instead:
      when its correlation length L (:func:`geosynth.completion.spectrum.correlation_length`, about a
      bump's radius) spans more than ``AUTO_FEATURE_COARSEN`` (4) of the rule's targets, targets at
      L / ``AUTO_PER_FEATURE`` (3). Sparse bumps' spectral period is their spacing, not their size:
      a zoo bumps sphere resampled to 20,000 vertices held 30 samples on T and 7 on L, and its
      5-ring window, under half a bump, grew worms (the zoo's drawn captures and the built-ins
      hold 1.2-3.0 on L and are unchanged). The chosen length is rounded to 3 significant digits;
    - window: W = round(0.75 x targets on T), in [3, 5]: the window spans about 1.5 periods
      (bark, T ~ 5 samples: W 3 left the completion 8.7% flat, W 4 kept it); then, in
      :func:`complete_surface`, lowered (not below 3) until most of the capture's vertices
      hold a whole window (two thirds; a small capture's candidates are otherwise mostly its border's: the
      noise plane at W 5 held 32%, and missed the volume and histogram targets);
    - rotations and frames: a relief directed but not stripes (anisotropy 0.2 to 0.5: rows and
      columns of features, a tower's arches), whose slopes keep to one direction or two at
      right angles (:func:`_slope_order` >= ``AUTO_SLOPE_ORDER``: a spectrum of a few random
      bumps can read 0.2 too; the zoo's bumped cylinder copied unturned came out 1.18x its
      size, 1.08x at R = 4), on a plane or cylinder is copied unturned in the
      fit's own frames (R = 1): a turned copy is something the capture never shows (the tower at
      R = 4 copied rows into vertical bands). Stripes (anisotropy >= 0.5: a sine, ridges, a
      knurl), isotropic and flat reliefs and spheres: the paper's R = 4 in its frames, except
      a sphere whose relief's slopes run about one axis (stripes, a knurl:
      :func:`geosynth.completion.fit.latitude_axis` share under ``LATITUDE_SHARE``, 1/3 meaning
      no axis), which gets R = 4 in the latitude frames about that axis
      (:func:`geosynth.completion.fit.fit_frames`; the paper's frames turn against such a relief
      over a sphere, where no tangent field is without a singular point: these turn only at
      the axis' poles). Stripes are their own half turn and a quarter turn scores badly, so the extra
      rotations only add candidates: the wave at R = 1 lost histogram (0.029-0.034 against
      0.020-0.021 at R = 4);
    - refine: such a directed relief with sharp features (>= 5% of its power below 4 samples a wavelength) gets
      2 refinement passes: one-sided growth breaks thin features (a tower's ledges), a second
      match with both sides textured rejoins them. Stripes (bark's ridges) run on without: on
      bark the passes made the volume worse (0.31% -> 1.03%, m4refine in `git log -p bench/RESULTS.md`).

    Args:
        capture: anything :func:`geosynth.completion.prep.as_capture` takes.
        fit: the capture's :class:`SurfaceFit`.

    Returns:
        :class:`AutoSettings` with the one-line ``reason``.
    """
    cap = as_capture(capture)
    spec, fine, s_c, regular, _, band, order, feature = _capture_relief(fit, cap.positions)
    period = spec.period
    lo, hi = AUTO_WINDOW_RANGE
    rule = "median" if fit.kind != "plane" and regular >= AUTO_REGULAR else "minimum"
    s_t = target_spacing(cap, fit, rule)
    denser = rule == "minimum" and s_t < AUTO_REGULAR * s_c
    if denser:  # an irregular sampling's minimum edge (a latitude-longitude sphere's rows close up towards
        # its poles) puts the targets up to 2x denser than the capture's own median sampling: 4x the targets,
        # each window's reach cut in half, no detail the capture holds
        rule = "median"
        s_t = target_spacing(cap, fit, rule)
    if not math.isfinite(period):
        per = per_rule = float("nan")
        coarse = False
    else:
        per, per_rule = period / s_c, period / s_t
        coarse = max(per, per_rule) > AUTO_COARSEN and band < AUTO_BAND
    # elements (correlation length L) spanning many targets: a relief that is not band-limited (sparse bumps,
    # whose spectral "period" is their spacing, not their size) sampled far denser than its elements need;
    # the window (at most 5 rings) then spans under half an element and grows worms from bumps
    on_feature = feature / s_t if math.isfinite(feature) else float("nan")
    elements = not coarse and on_feature > AUTO_FEATURE_COARSEN
    if coarse:
        spacing: str | float = _decided(period / AUTO_PER_PERIOD)
        per_t = period / spacing
        why_s = (f"targets at T/{AUTO_PER_PERIOD:g} = {spacing:.4g} (a band-limited relief, {band:.1%} of its power "
                 f"below T/2, and the capture holds {per:.1f} samples on T, its {rule} edge {per_rule:.1f}; "
                 f"no oversampling, candidates thinned to the target spacing)")
    elif elements:
        coarse = True
        spacing = _decided(feature / AUTO_PER_FEATURE)
        per_t = period / spacing
        why_s = (f"targets at L/{AUTO_PER_FEATURE:g} = {spacing:.4g} (its elements' correlation length L = "
                 f"{feature:.4g} spans {on_feature:.1f} targets at its {rule} edge, over {AUTO_FEATURE_COARSEN:g}: "
                 f"no oversampling, candidates thinned to the target spacing; {per:.1f} capture samples on T)")
    else:
        spacing = rule
        per_t = per_rule
        why_s = (f"targets at the capture's {spacing} edge ("
                 + ("its minimum edge is under 0.9x its median spacing" if denser else
                    "a regular sampling on a curved fit" if spacing == "median" else "the paper")
                 + ("" if not math.isfinite(per) else f"; {per:.1f} capture samples on T, {per_rule:.1f} targets") + ")")
    window = lo if not math.isfinite(per_t) else int(min(hi, max(lo, math.floor(AUTO_WINDOW_PERIODS * per_t + 0.5))))
    stripes = math.isfinite(period) and spec.anisotropy >= AUTO_STRIPES
    directed = (fit.kind != "sphere" and math.isfinite(period) and spec.anisotropy >= AUTO_DIRECTED
                and not stripes and order >= AUTO_SLOPE_ORDER)
    # a sphere: the paper's frames turn continuously over it, against a relief whose slopes run about one
    # axis (stripes, a knurl), so that no rotation of R lines a candidate up with the target; the
    # latitude frames about that axis (:func:`fit_frames`) turn only at its poles. A relief without
    # such an axis keeps the paper's: the golf ball's dimples (share 0.32) came out 1.24x their period
    # in latitude frames, 0.96x in the paper's; a zoo knurl (share 0.19) 0.87x its size against 0.70x
    latitude = latitude_axis(fit, cap.positions) if fit.kind == "sphere" and math.isfinite(period) else None
    share = 1.0 if latitude is None else latitude[1]
    latitudes = share < LATITUDE_SHARE
    rotations, frames = (1, "fit") if directed else (DEFAULT_ROTATIONS, "fit" if latitudes else "paper")
    # a relief directed both ways (rows and columns of features) with sharp features breaks them
    # under one-sided growth (a tower's ledges); stripes run on
    refine = AUTO_REFINE if directed and fine >= AUTO_FINE else 0
    why_r = (f"R 1 in the fit's frames (a directed relief, not stripes; slope order {order:.2f})" if directed else
             f"R 4 in the sphere's latitude frames (its slopes run about one axis, share {share:.2f}: the "
             "paper's frames turn against them over a sphere)" if latitudes else
             "R 4 in the paper's frames (" + ("a sphere" if fit.kind == "sphere" else
                                               "stripes: a half turn is a symmetry, a quarter turn the "
                                               "matching rejects" if stripes else
                                               f"slopes in every direction, slope order {order:.2f}"
                                               if math.isfinite(period) and spec.anisotropy >= AUTO_DIRECTED
                                               else "an isotropic relief" if math.isfinite(period)
                                               else "a flat relief") + ")")
    reason = (f"automatic settings: relief {spec.describe()}, sharp-feature share {fine:.3f}, capture spacing "
              f"{s_c:.4g} -> {why_s}; window {window}"
              + ("" if not math.isfinite(per_t) else f" (~{(2 * window + 1) / per_t:.1f} periods)")
              + f"; {why_r}; refine {refine}")
    return AutoSettings(window=window, rotations=rotations, frames=frames, refine=refine, spacing=spacing,
                        coarse=coarse, capture_spacing=s_c, spectrum=spec, fine=fine, regular=regular, reason=reason,
                        latitude=latitude, targets_per_period=float(per_t),
                        spaced=bool(math.isfinite(period) and not directed and not stripes))


def choose_search(search: str, n_targets: int, n_candidates: int, rotations: int) -> tuple[str, str]:
    """FindMatches' search for a completion: ``search`` itself unless "auto", else
    "exhaustive" (the paper) while n_targets x n_candidates x rotations stays under
    ``AUTO_EXHAUSTIVE_WORK`` and "coherent" above it. Returns (search, the reason to print, ""
    when the search was given)."""
    if search != "auto":
        return search, ""
    work = float(n_targets) * n_candidates * rotations
    chosen = "exhaustive" if work <= AUTO_EXHAUSTIVE_WORK else "coherent"
    return chosen, (f"search {chosen} ({n_targets:,} targets x {n_candidates:,} candidates x R {rotations} = "
                    f"{work:.2g}, " + (f"within {AUTO_EXHAUSTIVE_WORK:.0e})" if chosen == "exhaustive" else
                                       f"over {AUTO_EXHAUSTIVE_WORK:.0e}: each target scored against its neighbours' "
                                       f"sources, {COHERENT_PROBES} candidates spread over the capture and those "
                                       f"around its {COHERENT_AROUND} best)"))


def _thin(fit: SurfaceFit, points: np.ndarray, delta: float) -> np.ndarray:
    """(k,) int64 ids of ``points`` one per cell of a ``delta`` grid in the fit's unrolled
    frame: the point nearest its cell's centre (lowest id on ties), sorted."""
    from geosynth.completion.fit import relief_frame

    uv = relief_frame(fit, points)[0]
    cell = np.floor(uv / delta)
    off = uv / delta - cell - 0.5
    d2 = off[:, 0] * off[:, 0] + off[:, 1] * off[:, 1]
    order = np.lexsort((np.arange(len(uv)), d2, cell[:, 1], cell[:, 0]))
    c = cell[order]
    first = np.ones(len(order), bool)
    first[1:] = (c[1:] != c[:-1]).any(axis=1)
    return np.sort(order[first]).astype(np.int64)


# ---------------------------------------------------------------------- growth


def _classes(members: np.ndarray, w_t: np.ndarray, ring_ptr, ring_idx, ring_d, slot_of: np.ndarray) -> list[np.ndarray]:
    """Greedy colouring, in id order, of targets none of which lies in another's window."""
    colour = {}
    classes: list[list[int]] = []
    member_set = set(int(m) for m in members)
    for t in sorted(member_set):
        k = slot_of[t]
        lo, hi = ring_ptr[k], ring_ptr[k + 1]
        banned = set()
        for a, d in zip(ring_idx[lo:hi], ring_d[lo:hi]):
            a = int(a)
            if a in colour and d <= max(w_t[k], w_t[slot_of[a]]):
                banned.add(colour[a])
        c = 0
        while c in banned:
            c += 1
        colour[t] = c
        if c == len(classes):
            classes.append([])
        classes[c].append(t)
    return [np.asarray(c, dtype=np.int64) for c in classes]


def _grow(rs: ReliefSurface, index, rm, window: int, rotations: int, mu: float, max_error: float,
          rng: np.random.Generator, progress: bool, balance: "_Balance | None" = None, search: str = "exhaustive"):
    """GrowSurface (Appendix A); returns (textured (V,) bool, stats dict). Updates rs in place.

    ``balance``: None picks uniformly among the matches (the paper); a :class:`_Balance`
    weights the same draw by how much each match's bins are still missing."""
    n_v, n_s = rs.n_vertices, rs.n_samples
    targets = np.arange(n_s, n_v, dtype=np.int64)
    slot_of = np.full(n_v, -1, dtype=np.int64)
    slot_of[targets] = np.arange(len(targets))
    ring_ptr, ring_idx, ring_d = ring_neighbourhoods(rs.adjacency, targets, window)
    adj_ptr, adj_idx = rs.adjacency
    textured = np.zeros(n_v, dtype=bool)
    textured[:n_s] = True
    w_t = np.full(len(targets), window, dtype=np.int64)
    sigmas = {w: (2 * w + 1) * rs.spacing / 6.4 for w in range(1, window + 1)}
    err = float(max_error)
    stats = dict(lists=0, passes_without_progress=0, failed_matches=0)
    picked = np.full(n_v, -1, dtype=np.int64)  # the sample each target copied
    per_launch = max(1, min(_MAX_BATCH, _BATCH_CODES // max(1, len(index.samples) * rotations)))
    hints = _HintTable(rs, index) if HINT_RINGS > 0 else None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(targets), unit="target", desc="completion", leave=False)
    try:
        while True:
            left = targets[~textured[targets]]
            if len(left) == 0:
                break
            # boundary: untextured targets with a textured edge neighbour
            deg = np.diff(adj_ptr)[left]
            owner = np.repeat(np.arange(len(left)), deg)
            nb = adj_idx[np.concatenate([np.arange(adj_ptr[t], adj_ptr[t + 1]) for t in left])] if len(left) else []
            has = np.zeros(len(left), dtype=bool)
            np.logical_or.at(has, owner, textured[nb])
            boundary = left[has]
            if len(boundary) == 0:
                break  # the rest is not connected to the textured part
            stats["lists"] += 1
            # textured count in each one's W_t-ring
            slots = slot_of[boundary]
            counts = np.empty(len(boundary), dtype=np.int64)
            for i, k in enumerate(slots):
                lo, hi = ring_ptr[k], ring_ptr[k + 1]
                sel = ring_d[lo:hi] <= w_t[k]
                counts[i] = int(textured[ring_idx[lo:hi][sel]].sum())
            progress_made = False
            shrunk = False  # a window shrank in this list
            for level in np.unique(counts)[::-1]:
                members = boundary[counts == level]
                for cls in _classes(members, w_t, ring_ptr, ring_idx, ring_d, slot_of):
                    for start in range(0, len(cls), per_launch):
                        chunk = cls[start:start + per_launch]
                        got = match_chunk(rs, index, rm, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d, sigmas,
                                           rotations, mu, err, hints, picked, textured,
                                           TOLERANCE if balance is None else TOLERANCE * (1.0 + balance.penalty),
                                           search)
                        accepted_t, accepted_s, accepted_r = [], [], []
                        for t, m in zip(chunk, got):  # picks in list order (one draw per non-empty match set)
                            k = slot_of[t]
                            if len(m.sample) == 0:
                                shrunk |= bool(w_t[k] > 1)
                                stats["failed_matches"] += 1
                                w_t[k] = max(1, w_t[k] - 1)
                                continue
                            j = int(rng.integers(len(m.sample))) if balance is None else balance.pick(m, rng)
                            if bool(m.accepted[j]):
                                if balance is not None:
                                    balance.add(int(m.sample[j]))
                                accepted_t.append(int(t))
                                accepted_s.append(int(m.sample[j]))
                                accepted_r.append(int(m.rotation[j]))
                            else:
                                shrunk |= bool(w_t[k] > 1)
                                stats["failed_matches"] += 1
                                w_t[k] = max(1, w_t[k] - 1)
                        if accepted_t:
                            at = _copy_matches(rs, index, accepted_t, accepted_s, accepted_r, rotations, picked)
                            textured[at] = True
                            progress_made = True
                            if bar is not None:
                                bar.update(len(at))
            if not progress_made:
                stats["passes_without_progress"] += 1
                err *= RELAX
                if err > MAX_MAX_ERROR * RELAX and not shrunk:
                    break  # every valid match is accepted now and the windows are final: the rest is unreached
    finally:
        if bar is not None:
            bar.close()
    stats["final_max_error"] = err
    stats["picked"] = picked
    return textured, stats


def _refine(rs: ReliefSurface, index, rm, window: int, rotations: int, mu: float, rng: np.random.Generator,
            picked: np.ndarray, textured: np.ndarray, passes: int, balance: "_Balance | None" = None,
            search: str = "exhaustive") -> int:
    """Refinement passes after GrowSurface (our extension, not the paper's; the two-pass idea
    of Wei and Levoy 2000, "Fast texture synthesis using tree-structured vector quantization",
    Sec. 3.4): every completed target is matched again against its whole W-ring, which is
    textured on every side now (the growth saw only the side it grew from), and takes the
    picked match's displacement and colour. Broken thin features (a tower's one-row ledges)
    are rejoined by the context of both sides. Targets are visited in the growth's batch
    order (classes of targets none of which lies in another's window, by id), so the result
    is the same as one target at a time in that order; the pick is the growth's rule (the
    balanced draw or the paper's uniform one), with no MaxErrThreshold (every target keeps a
    match: its old one is among the candidates). Updates rs, index, picked and balance in
    place; returns how many targets changed their source sample."""
    n_v, n_s = rs.n_vertices, rs.n_samples
    targets = np.arange(n_s, n_v, dtype=np.int64)
    slot_of = np.full(n_v, -1, dtype=np.int64)
    slot_of[targets] = np.arange(len(targets))
    ring_ptr, ring_idx, ring_d = ring_neighbourhoods(rs.adjacency, targets, window)
    w_t = np.full(len(targets), window, dtype=np.int64)
    sigmas = {w: (2 * w + 1) * rs.spacing / 6.4 for w in range(1, window + 1)}
    per_launch = max(1, min(_MAX_BATCH, _BATCH_CODES // max(1, len(index.samples) * rotations)))
    hints = _HintTable(rs, index) if HINT_RINGS > 0 else None
    tolerance = TOLERANCE if balance is None else TOLERANCE * (1.0 + balance.penalty)
    accept_all = rm.CODE_CAP / rm.SCORE_ONE  # a MaxErrThreshold every unclamped code is below
    changed = 0
    for _ in range(passes):
        todo = targets[textured[targets]]
        for cls in _classes(todo, w_t, ring_ptr, ring_idx, ring_d, slot_of):
            for start in range(0, len(cls), per_launch):
                chunk = cls[start:start + per_launch]
                got = match_chunk(rs, index, rm, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d, sigmas,
                                   rotations, mu, accept_all, hints, picked, textured, tolerance, search)
                at, src, rot = [], [], []
                for t, m in zip(chunk, got):  # picks in list order, one draw each
                    if len(m.sample) == 0:
                        continue
                    if balance is not None:
                        balance.remove(int(picked[t]))  # t's old copy leaves the counts before the draw
                        j = balance.pick(m, rng)
                        balance.add(int(m.sample[j]))
                    else:
                        j = int(rng.integers(len(m.sample)))
                    changed += int(m.sample[j] != picked[t])
                    at.append(int(t))
                    src.append(int(m.sample[j]))
                    rot.append(int(m.rotation[j]))
                if at:
                    _copy_matches(rs, index, at, src, rot, rotations, picked)
    return changed


def _copy_matches(rs: ReliefSurface, index, targets, samples, rots, rotations: int, picked: np.ndarray) -> np.ndarray:
    """Give each of ``targets`` the displacement (moved from ``samples``' frames at rotation
    ``rots``) and colour of its match, on the host (rs, picked) and in the index; returns
    the targets as an (n,) int64 array."""
    at = np.asarray(targets, dtype=np.int64)
    src = np.asarray(samples, dtype=np.int64)
    d = index.transfer(src, np.asarray(rots, dtype=np.int64), at, rotations)
    rs.displacement[at] = d
    picked[at] = src
    col = None
    if rs.colors is not None:
        rs.colors[at] = rs.colors[src]
        col = rs.colors[at].astype(np.float64) / 255.0
        if rs.alpha is not None:  # the alpha travels with its colour (it takes no part in matching)
            rs.alpha[at] = rs.alpha[src]
    index.update(at, d, col)
    return at

class _Balance:
    """A histogram-aware pick among the matches (our extension, not the paper's).

    The paper draws one match uniformly from those within 1.1x the best. Measured: that set
    holds a single match for 50-70% of the targets (noise, golf), so a reweighted draw alone
    moves little; hence two parts, both switched off by ``complete_surface(balance=False)``
    (CLI ``--no-balance``), which restores the paper's uniform pick bit for bit. Coherent patches
    copy runs of neighbouring samples, so the completed part is made of fewer independent
    draws than it has vertices and its histograms wander from the capture's. In the spirit
    of histogram-preserving texture optimization (Kopf et al. 2007, "Solid texture synthesis
    from 2D exemplars", Sec. 3.3: reweighting by histogram counts), the seeded draw among
    the matches is weighted against those whose bins the completed part already holds
    more of than the capture: features are the colour of each channel (the metric's
    ``HIST_BINS`` bins) and the signed height h over the fit (``HIST_BINS`` bins at the
    capture's h quantiles, so each holds 1/HIST_BINS of the capture). For a match in bins
    b_f, with n vertices completed so far and c_f their counts, the deficit of feature f is
    d_f = p_f(b_f) (n + 1) - c_f(b_f) (how many more the bin needs to be at the capture's
    share after one more copy), clipped to [-1, 1]; the score is the mean of the colour
    channels' and the height's deficits (height alone without colour) and the weight
    exp(strength x score). (1) The 1.1x rule is applied to penalized codes
    code x (1 + penalty (1 - score) / 2), a factor in [1, 1 + penalty] (matches in bins
    the completion lacks keep their code, over-represented ones pay up to 1 + penalty);
    find_matches is called with tolerance 1.1 (1 + penalty), which holds every match the
    penalized rule can select (the penalized best is at most (1 + penalty) x the best).
    (2) Among those, the draw is weighted by exp(strength x score). MaxErrThreshold is
    tested on the true code. One ``rng.random()`` a draw; the
    weights are host float64 arithmetic on the device-independent match lists, so the
    same seed gives the same bits on every device.
    """

    def __init__(self, rs: ReliefSurface, strength: float, penalty: float):
        n0 = rs.n_original
        h = rs.fit.distance(rs.base + rs.displacement)  # every vertex's signed height (targets: 0 until copied)
        q = np.quantile(h[:n0], np.linspace(0, 1, HIST_BINS + 1)[1:-1])
        feats = [np.searchsorted(q, h, side="right")]
        if rs.colors is not None:
            edges = np.linspace(0, 256, HIST_BINS + 1)[1:-1]
            feats += [np.searchsorted(edges, rs.colors[:, c], side="right") for c in range(3)]
        self.bins = np.stack(feats).astype(np.int64)  # (F, V) bin of each vertex's values
        nf = len(feats)
        self.share = np.stack([np.bincount(b[:n0], minlength=HIST_BINS) / n0 for b in self.bins])  # (F, B)
        self.counts = np.zeros((nf, HIST_BINS), dtype=np.int64)
        # colour channels share one half of the score, the height the other (height alone without colour)
        self.feature_weight = np.array([1.0] if nf == 1 else [0.5] + [0.5 / 3] * 3)
        self.strength = float(strength)
        self.penalty = float(penalty)
        self.n = 0

    def score(self, samples: np.ndarray) -> np.ndarray:
        """(k,) float64 deficit scores in [-1, 1] of copying each of ``samples`` next."""
        b = self.bins[:, samples]  # (F, k)
        f = np.arange(len(b))[:, None]
        d = np.clip(self.share[f, b] * (self.n + 1) - self.counts[f, b], -1.0, 1.0)
        # the weighted sum in a fixed order, elementwise: BLAS's gemv (feature_weight @ d) rounds by
        # the CPU, and the score decides which matches are drawn (issue 40)
        out = self.feature_weight[0] * d[0]
        for f in range(1, len(d)):
            out = out + self.feature_weight[f] * d[f]
        return out

    def pick(self, m, rng: np.random.Generator) -> int:
        """Index into the arrays of ``m`` (a non-empty Matches found with tolerance
        TOLERANCE x (1 + penalty)): the candidates within TOLERANCE x the best of the
        penalized codes, drawn with the deficit weights."""
        score = self.score(m.sample)
        adj = m.code.astype(np.float64) * (1.0 + self.penalty * (1.0 - score) / 2)
        sel = np.flatnonzero(adj <= TOLERANCE * adj.min())
        w = exp_fixed(self.strength * (score[sel] - score[sel].max()))  # not np.exp: AVX-512's rounds otherwise
        cum = np.cumsum(w)
        return int(sel[min(np.searchsorted(cum, rng.random() * cum[-1], side="right"), len(sel) - 1)])

    def add(self, sample: int) -> None:
        """Count a copy of ``sample``'s values into the completed part."""
        self.counts[np.arange(len(self.bins)), self.bins[:, sample]] += 1
        self.n += 1

    def remove(self, sample: int) -> None:
        """Take a copy of ``sample``'s values out of the counts (a refined target's old one)."""
        self.counts[np.arange(len(self.bins)), self.bins[:, sample]] -= 1
        self.n -= 1


class _HintTable:
    """Coherence hints for FindMatches (Ashikhmin's idea): a target next to a vertex that
    holds sample x's values likely matches near x. For every sample vertex, the candidate
    slots within HINT_RINGS edge rings of it (itself included); they only tighten the
    pruning limit, never change the matches (find_matches' hints)."""

    def __init__(self, rs: ReliefSurface, index):
        n_s = rs.n_samples
        slot = np.full(rs.n_vertices, -1, dtype=np.int64)
        slot[index.samples] = np.arange(len(index.samples))
        ptr, idx, _ = ring_neighbourhoods(rs.adjacency, np.arange(n_s), HINT_RINGS)
        own = np.repeat(np.arange(n_s), np.diff(ptr))
        keys = np.concatenate([np.arange(n_s), own])
        vals = slot[np.concatenate([np.arange(n_s), idx])]
        keep = vals >= 0
        keys, vals = keys[keep], vals[keep]
        order = np.argsort(keys, kind="stable")
        self.ptr = np.concatenate([[0], np.cumsum(np.bincount(keys, minlength=n_s))]).astype(np.int64)
        self.slots = vals[order]
        self.n_samples = n_s
        self.adjacency = rs.adjacency

    def for_targets(self, chunk: np.ndarray, picked: np.ndarray, textured: np.ndarray) -> np.ndarray | None:
        """(len(chunk), k) int64: each target's candidate slots near the sources of its own
        textured edge neighbours (a row per target, padded with -1: find_matches scores
        each query against its own row); None when no neighbour has a source. (Measured:
        the chunk's union for every query cost 13e6 triples at the Fig. 9 size, the rows
        0.6e6; scoring the 1-ring first, in a pass of its own, gained nothing: one more
        launch.)"""
        adj_ptr, adj_idx = self.adjacency
        deg = adj_ptr[chunk + 1] - adj_ptr[chunk]
        row = np.repeat(np.arange(len(chunk)), deg)
        nb = adj_idx[np.repeat(adj_ptr[chunk] - np.cumsum(deg) + deg, deg) + np.arange(int(deg.sum()))]
        keep = textured[nb]
        row, nb = row[keep], nb[keep]
        src = np.where(nb < self.n_samples, nb, picked[nb])
        row, src = row[src >= 0], src[src >= 0]
        return None if len(src) == 0 else self._near(row, src, len(chunk))

    def around(self, index, slots: np.ndarray) -> np.ndarray:
        """(Q, k) int64 candidate slots within HINT_RINGS edge rings of each row's ``slots``
        ((Q, m) positions in index.samples, -1: none), padded with -1."""
        q, m = slots.shape
        row = np.repeat(np.arange(q), m)
        flat = slots.reshape(-1)
        v = np.where(flat >= 0, index.samples[np.maximum(flat, 0)], -1)
        row, v = row[v >= 0], v[v >= 0]
        return np.full((q, 0), -1, np.int64) if len(v) == 0 else self._near(row, v, q)

    def _near(self, row: np.ndarray, src: np.ndarray, n_rows: int) -> np.ndarray:
        """(n_rows, k) int64: row r holds the candidate slots within HINT_RINGS rings of every
        sample vertex src[i] with row[i] == r, each once, ascending, padded with -1."""
        n = self.ptr[src + 1] - self.ptr[src]
        at = np.repeat(self.ptr[src] - np.cumsum(n) + n, n) + np.arange(int(n.sum()))
        pairs = np.unique(np.stack([np.repeat(row, n), self.slots[at]], 1), axis=0)  # sorted by row, then slot
        counts = np.bincount(pairs[:, 0], minlength=n_rows)
        col = np.arange(len(pairs)) - np.repeat(np.cumsum(counts) - counts, counts)
        grid = np.full((n_rows, int(counts.max())), -1, np.int64)
        grid[pairs[:, 0], col] = pairs[:, 1]
        return grid


def match_chunk(rs, index, rm, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d, sigmas, rotations, mu, err,
                 hints=None, picked=None, textured=None, tolerance=TOLERANCE, search="exhaustive",
                 hint_probes=HINT_PROBES):
    """find_matches for a chunk of one class, one launch per window size; in chunk order (the calls
    the growth makes; :mod:`geosynth.relief` grows over any mesh through it too). ``rm``: the module
    (or an object) with ``neighbourhood_queries`` and ``find_matches``; ``hints``: with
    ``for_targets(chunk, picked, textured)`` and ``around(index, best)``; ``search``: one of SEARCHES;
    ``hint_probes``: the exhaustive search's probes when hints exist."""
    out = [None] * len(chunk)
    hint_slots = None if hints is None else hints.for_targets(chunk, picked, textured)
    ks = slot_of[chunk]
    for w in np.unique(w_t[ks]):
        pos = np.flatnonzero(w_t[ks] == w)
        starts, lists = [0], []
        for p in pos:
            k = ks[p]
            lo, hi = ring_ptr[k], ring_ptr[k + 1]
            nbr = ring_idx[lo:hi][ring_d[lo:hi] <= w]
            lists.append(nbr)
            starts.append(starts[-1] + len(nbr))
        queries = rm.neighbourhood_queries(index, chunk[pos], np.asarray(starts, dtype=np.int64),
                                           np.concatenate(lists).astype(np.int64), sigmas[int(w)],
                                           rotations=rotations, mu=mu)
        hint_rows = None if hint_slots is None else hint_slots[pos]
        if search == "coherent":
            probes = (max(1, -(-len(index.samples) // COHERENT_PROBES)),)
        else:
            probes = hint_probes if hint_rows is not None and (hint_rows >= 0).any() else None
        around = None if hints is None or search != "coherent" else (lambda best: hints.around(index, best))
        for p, m in zip(pos, rm.find_matches(index, queries, err, tolerance=tolerance, probes=probes,
                                             hints=hint_rows, exhaustive=search == "exhaustive", around=around,
                                             around_best=COHERENT_AROUND)):
            out[p] = m
    return out


# ---------------------------------------------------------------------- quality


def _histogram_distance(a: np.ndarray, b: np.ndarray) -> float:
    edges = np.linspace(0, 256, HIST_BINS + 1)
    total = 0.0
    for c in range(3):
        ha = np.histogram(a[:, c], edges)[0] / max(1, len(a))
        hb = np.histogram(b[:, c], edges)[0] / max(1, len(b))
        total += 0.5 * np.abs(ha - hb).sum()
    return total / 3


def _pairs(rs: ReliefSurface, part: np.ndarray):
    """(i, j, length): the pairs of the part's vertices whose base positions lie 0.7 to 1.3
    target spacings apart (one scale for every part, so that the oversampled capture and
    the coarser targets compare); None when there are none."""
    from geosynth.core.neighbours import pairs_within

    ids = np.flatnonzero(part)
    if len(ids) < 2:
        return None
    b = rs.base[ids]
    pairs = pairs_within(b, 1.3 * rs.spacing)
    length = norm3(b[pairs[:, 0]] - b[pairs[:, 1]]) if len(pairs) else np.zeros(0)
    keep = length >= 0.7 * rs.spacing
    if not keep.any():
        return None
    return ids[pairs[keep, 0]], ids[pairs[keep, 1]], length[keep]


def _pair_means(pairs, h: np.ndarray, colours: np.ndarray | None):
    """(mean |h_i - h_j| / |b_i - b_j|, mean |c_i - c_j| (RGB L1 / 3, 0..255) or None) over
    ``pairs`` (:func:`_pairs`)."""
    if pairs is None:
        return float("nan"), None if colours is None else float("nan")
    i, j, length = pairs
    slope = float(np.mean(np.abs(h[i] - h[j]) / length))
    if colours is None:
        return slope, None
    step = float(np.mean(np.abs(colours[i].astype(np.float64) - colours[j].astype(np.float64)).mean(1)))
    return slope, step


def _pct(a: float, b: float) -> float:
    return 100.0 * abs(b - a) / abs(a) if a != 0 else (0.0 if b == 0 else math.inf)


def _baseline_draw(rs: ReliefSurface, h: np.ndarray, tgt: np.ndarray, rng: np.random.Generator, cand: np.ndarray):
    """One random-copy baseline: every target takes a uniformly random candidate's
    displacement (frame components) and colour. Returns (pick, heights of every vertex)."""
    pick = cand[rng.integers(0, len(cand), len(tgt))]  # the completion's candidates (vertex ids)
    d = rs.displacement[pick]
    comp = np.stack([(d * rs.frame_u[pick]).sum(1), (d * rs.frame_v[pick]).sum(1), (d * rs.normals[pick]).sum(1)], 1)
    dbase = comp[:, :1] * rs.frame_u[tgt] + comp[:, 1:2] * rs.frame_v[tgt] + comp[:, 2:] * rs.normals[tgt]
    hb = h.copy()
    hb[tgt] = rs.fit.distance(rs.base[tgt] + dbase)
    return pick, hb


def _quality(rs: ReliefSurface, textured: np.ndarray, seed: int, cand: np.ndarray) -> dict:
    fit = rs.fit
    n_s, n0 = rs.n_samples, rs.n_original
    tgt = np.arange(n_s, rs.n_vertices)
    done = tgt[textured[tgt]]
    h = fit.distance(rs.positions)
    orig = np.zeros(rs.n_vertices, bool)
    orig[:n0] = True  # the capture's own vertices
    part = np.zeros(rs.n_vertices, bool)
    part[done] = True
    allt = np.zeros(rs.n_vertices, bool)
    allt[tgt] = True
    vo = float(np.mean(np.abs(h[:n0])))
    vc = float(np.mean(np.abs(h[done]))) if len(done) else float("nan")
    # the capture's pairs among its candidate vertices: all of them, or one a target spacing when
    # the candidates were thinned (a capture 4x denser than the targets: 16x the pairs, 20 s)
    own = np.zeros(rs.n_vertices, bool)
    own[cand[cand < n0]] = True
    (so, co), (sc, cc) = _pair_means(_pairs(rs, own), h, rs.colors), _pair_means(_pairs(rs, part), h, rs.colors)
    # the baseline: BASELINE_DRAWS independent random-copy draws (seeds [seed, 1, k]); one
    # draw is a noisy yardstick, so its numbers are reported as the mean over the draws with
    # their min and max
    target_pairs = _pairs(rs, allt)
    draws = {k: [] for k in ("vb", "vbp", "sb", "sbp", "cbs", "cbsp", "hb")}
    for k in range(BASELINE_DRAWS):
        pick, hb = _baseline_draw(rs, h, tgt, np.random.default_rng([seed, 1, k]), cand)
        vb = float(np.mean(np.abs(hb[tgt])))
        cb = None
        if rs.colors is not None:
            cb = rs.colors.copy()
            cb[tgt] = rs.colors[pick]
        sb, cbs = _pair_means(target_pairs, hb, cb)
        draws["vb"].append(vb)
        draws["vbp"].append(_pct(vo, vb))
        draws["sb"].append(sb)
        draws["sbp"].append(_pct(so, sb))
        if rs.colors is not None:
            draws["cbs"].append(cbs)
            draws["cbsp"].append(_pct(co, cbs))
            draws["hb"].append(_histogram_distance(rs.colors[:n0], rs.colors[pick]))

    def mean(key):
        return float(np.mean(draws[key])) if draws[key] else None

    def span(key):
        return (float(np.min(draws[key])), float(np.max(draws[key]))) if draws[key] else None

    q = dict(volume_original=vo, volume_completed=vc, volume_diff_pct=_pct(vo, vc), volume_baseline=mean("vb"),
             volume_baseline_diff_pct=mean("vbp"), volume_baseline_diff_pct_range=span("vbp"), slope_original=so,
             slope_completed=sc, slope_diff_pct=_pct(so, sc), slope_baseline=mean("sb"),
             slope_baseline_diff_pct=mean("sbp"), slope_baseline_diff_pct_range=span("sbp"),
             hist_distance=None, hist_baseline=None, hist_baseline_range=None, colour_step_original=co,
             colour_step_completed=cc, colour_step_diff_pct=None, colour_step_baseline=mean("cbs"),
             colour_step_baseline_diff_pct=None, colour_step_baseline_diff_pct_range=None,
             baseline_draws=BASELINE_DRAWS)
    if rs.colors is not None:
        q["colour_step_diff_pct"] = _pct(co, cc)
        q["colour_step_baseline_diff_pct"], q["colour_step_baseline_diff_pct_range"] = mean("cbsp"), span("cbsp")
        q["hist_distance"] = _histogram_distance(rs.colors[:n0], rs.colors[done])
        q["hist_baseline"], q["hist_baseline_range"] = mean("hb"), span("hb")
    # the capture against itself: its two halves split at the median of the first parameter
    # (two coherent regions; how much real parts of this surface differ)
    u = rs.param[:n0, 0]
    lo = u <= np.median(u)
    ha, hb2 = np.abs(h[:n0][lo]), np.abs(h[:n0][~lo])
    q["volume_self_diff_pct"] = _pct(float(ha.mean()), float(hb2.mean())) if len(hb2) and len(ha) else float("nan")
    q["hist_self"] = None
    if rs.colors is not None and lo.any() and (~lo).any():
        q["hist_self"] = _histogram_distance(rs.colors[:n0][lo], rs.colors[:n0][~lo])
    q.update(_relief_scale(rs, done))
    return q


def _spectrum_of(fit: SurfaceFit, points: np.ndarray, spacing: float):
    """The spectrum alone of points' relief in the fit's frame (what the quality numbers need)."""
    from geosynth.completion.spectrum import relief_spectrum

    grid, mask, step, *_ = _relief_grid(fit, points, spacing)
    return relief_spectrum(grid, step, mask)


def _relief_scale(rs: ReliefSurface, done: np.ndarray) -> dict:
    """The captured part's and the completed part's relief spectra at the target spacing (issue 32)."""
    out = dict(relief_captured=None, relief_completed=None, period_ratio=float("nan"),
               amplitude_ratio=float("nan"), angle_diff_deg=float("nan"))
    p = rs.positions
    try:
        a = _spectrum_of(rs.fit, p[: rs.n_original], rs.spacing)
        b = _spectrum_of(rs.fit, p[done], rs.spacing) if len(done) >= 16 else None
    except (ValueError, RuntimeError):  # a part too thin or small to grid (scipy's qhull: RuntimeError-like QhullError)
        return out
    except Exception as e:  # noqa: BLE001 - qhull's own error class; the measurement is a report only
        if type(e).__name__ != "QhullError":
            raise
        return out
    out["relief_captured"], out["relief_completed"] = a, b
    if b is not None:
        out["period_ratio"] = b.period / a.period if math.isfinite(a.period) else float("nan")
        out["amplitude_ratio"] = b.amplitude / a.amplitude if a.amplitude > 0 else float("nan")
        d = abs(b.angle - a.angle) % math.pi
        out["angle_diff_deg"] = math.degrees(min(d, math.pi - d))
    return out


# ---------------------------------------------------------------------- the public function


def _vertex_normals(positions: np.ndarray, faces: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    a, b, c = (positions[faces[:, i]] for i in range(3))
    fn = np.cross(b - a, c - a)
    vn = np.zeros_like(positions)
    for i in range(3):
        np.add.at(vn, faces[:, i], fn)
    length = norm3(vn)[:, None]  # not np.linalg.norm: the same bits on every CPU (issue 40)
    return np.where(length > 0, vn / np.maximum(length, 1e-300), fallback)


def complete_surface(capture, fit: str | SurfaceFit | None = None, region=None, window: int | None = None,
                     rotations: int | None = None, mu: float = DEFAULT_MU, max_error: float = DEFAULT_MAX_ERROR,
                     device: str | None = None, seed: int = 0, progress: bool = False,
                     max_targets: int | None = 200_000, oversample: str | None = None,
                     candidates: str = "capture", balance: bool | float = True, frames: str | None = None,
                     refine: int | None = None, spacing: str | float | None = None, search: str = "auto", *,
                     options: CompletionOptions | None = None):
    """Complete the relief and colour of a partly captured surface (Sec. 3-6, Appendix A).

    Args:
        capture: the captured part: a :class:`~geosynth.completion.prep.Capture`, a
            ``trimesh.Trimesh`` (vertex colours kept), a :class:`~geosynth.geometry.pointsets.PointSet`
            or an (N, 3) array; optional colours (N, 3) uint8.
        fit: None (chosen by residual), "plane", "sphere", "cylinder", or a SurfaceFit.
        region: ((low, high), (low, high)) parameter ranges to complete (plane: u, v
            lengths with u = x, v = y for a plane z = c; sphere: azimuth and polar angle,
            radians; cylinder: angle (radians) and height), or None: the plane's bounding
            box, the cylinder's full circle over the captured height, the whole sphere.
        window, rotations, mu, max_error, max_targets, oversample, candidates, balance, frames,
            refine, spacing, search: the settings, each documented and checked once in
            :class:`CompletionOptions` (None: chosen from the relief where it says so).
        device: the matching device ("cpu", "opencl", "cuda", "auto"/None).
        seed: seed of the random picks (an int >= 0).
        progress: show a progress bar over the targets.
        options: the settings as one :class:`CompletionOptions` instead of the keywords
            (then the keywords must keep their defaults).

    Returns:
        (surface, report, timings): the :class:`CompletedSurface`, the
        :class:`CompletionReport` (quality numbers included) and a dict of seconds
        (``fit``, ``prepare``, ``index``, ``grow`` (the refinement passes included),
        ``quality``, ``total``) plus
        ``targets_per_s``.

    Raises:
        ValueError: bad parameters; a capture with NaN positions, colours of the wrong
            length or fewer points than one neighbourhood; a window larger than the capture
            (no captured vertex ``window`` target spacings from its border); a fit that does not converge or
            a named fit far from the data (with its residual); an empty region.
    """
    from geosynth.completion import matching as rm
    from geosynth.compute.backend import resolve_device

    t0 = time.perf_counter()
    given = dict(window=window, rotations=rotations, frames=frames, refine=refine, spacing=spacing, mu=mu,
                 max_error=max_error, search=search, balance=balance, candidates=candidates, oversample=oversample,
                 max_targets=max_targets)
    # every setting checked here, before any work
    options = settings_from(CompletionOptions, options, given, keyword_defaults(complete_surface, given))
    _check_seed(seed)
    cap = as_capture(capture)
    _check_neighbourhood(cap, DEFAULT_WINDOW if options.window is None else options.window)
    dev = resolve_device(device or "auto")
    sf = _fit(cap, fit)
    chosen = _chosen_settings(cap, sf, options)
    t1 = time.perf_counter()
    rs, window, auto_line, whole = _prepared_relief(cap, sf, region, options, chosen)
    t2 = time.perf_counter()
    frame_rows, frame_axis = _tangent_frames(cap, sf, rs, chosen)
    samples = _candidates(sf, rs, options.candidates, chosen.coarse)
    search, why = choose_search(options.search, rs.n_targets, len(samples), int(chosen.rotations))
    if why:
        auto_line = f"{auto_line}; {why}" if auto_line else f"automatic settings: {why}"
    textured0 = np.zeros(rs.n_vertices, dtype=bool)
    textured0[: rs.n_samples] = True
    colours = None if rs.colors is None else rs.colors.astype(np.float64) / 255.0
    use_mu = float(options.mu) if rs.colors is not None else 1.0
    index = rm.ReliefIndex.build(rs.base, rs.normals, rs.displacement, textured0, rs.faces, samples,
                                 colours=colours, partners=np.arange(rs.n_samples, dtype=np.int64),
                                 frames=frame_rows, device=dev)
    t3 = time.perf_counter()
    rng = np.random.default_rng(seed)
    balance, rotations, refine = options.balance, int(chosen.rotations), int(chosen.refine)
    strength = BALANCE_STRENGTH if balance is True else float(balance) if balance is not False else 0.0
    bal = _Balance(rs, strength, BALANCE_PENALTY) if strength > 0 else None
    textured, stats = _grow(rs, index, rm, int(window), rotations, use_mu, float(options.max_error), rng, progress,
                            bal, search)
    refined = _refine(rs, index, rm, int(window), rotations, use_mu, rng, stats["picked"], textured, refine, bal,
                      search) if refine else 0
    t4 = time.perf_counter()
    quality = _quality(rs, textured, int(seed), samples)
    t5 = time.perf_counter()
    surface = _completed_surface(rs, textured, sf)
    spacing = chosen.spacing
    report = CompletionReport(
        fit=sf.describe(), samples=rs.n_samples, targets=rs.n_targets,
        textured=int(textured[rs.n_samples:].sum()), unreached=int((~textured[rs.n_samples:]).sum()),
        spacing=rs.spacing, window=int(window), rotations=rotations, mu=use_mu, max_error=float(options.max_error),
        final_max_error=stats["final_max_error"], lists=stats["lists"],
        passes_without_progress=stats["passes_without_progress"], failed_matches=stats["failed_matches"],
        quality=quality, device=str(dev), n_original=rs.n_original, frames=chosen.frames, refine=refine,
        refined=refined, spacing_rule=spacing if isinstance(spacing, str) else "chosen", whole_windows=whole,
        auto=auto_line, n_candidates=len(samples), frame_axis=frame_axis, search=search,
        picked_original=float(np.mean(stats["picked"][rs.n_samples:][textured[rs.n_samples:]] < rs.n_original))
        if textured[rs.n_samples:].any() else float("nan"))
    timings = dict(fit=t1 - t0, prepare=t2 - t1, index=t3 - t2, grow=t4 - t3, quality=t5 - t4,
                   total=time.perf_counter() - t0)
    timings["targets_per_s"] = rs.n_targets / max(timings["grow"], 1e-9)
    return surface, report, timings


# ---------------------------------------------------------------------- complete_surface's steps


def _check_neighbourhood(cap, window: int, chosen: bool = False) -> None:
    """Refuse a capture with fewer points than one W-ring neighbourhood of a regular
    triangulation (3 W (W + 1) + 1 vertices); ``chosen``: the window was chosen from its relief."""
    need = 3 * window * (window + 1) + 1
    if len(cap) < need:
        if chosen:
            raise ValueError(f"the capture has {len(cap)} points, fewer than one neighbourhood of window {window} "
                             f"({need} vertices, chosen from its relief); give a larger capture or pass a smaller "
                             f"window.")
        raise ValueError(f"the capture has {len(cap)} points, fewer than one neighbourhood of window {window} "
                         f"({need} vertices); give a larger capture or a smaller window.")


def _fit(cap, fit: str | SurfaceFit | None) -> SurfaceFit:
    """The smooth surface that underlies the capture (Sec. 3): the one given, or a plane,
    sphere or cylinder fit (chosen by residual when None)."""
    if isinstance(fit, SurfaceFit):
        return fit
    if fit is None or fit in FIT_KINDS:
        return fit_surface(cap.positions, fit, normals=cap.normals)
    raise ValueError(f"fit must be one of {', '.join(FIT_KINDS)}, None or a SurfaceFit, got {fit!r}.")


@dataclass(frozen=True)
class _Chosen:
    """The settings one completion runs with: the options', the automatic choices
    (:func:`choose_settings`) where they were None.

    Attributes:
        window, rotations, frames, refine, spacing: the settings as run (the window may still
            shrink to the capture's depth, :func:`_prepared_relief`).
        auto: what :func:`choose_settings` measured and chose, or None when all were given.
        window_auto: the window was chosen.
        coarse: the targets are coarser than the capture (no oversampling, thinned candidates).
    """

    window: int
    rotations: int
    frames: str
    refine: int
    spacing: str | float
    auto: AutoSettings | None
    window_auto: bool
    coarse: bool


def _chosen_settings(cap, sf: SurfaceFit, options: CompletionOptions) -> _Chosen:
    """The options' settings, those left None chosen from the capture's relief
    (:func:`choose_settings`, issue 32), the capture checked against the chosen window."""
    given = (options.window, options.rotations, options.frames, options.refine, options.spacing)
    if None not in given:
        return _Chosen(*given, auto=None, window_auto=False, coarse=False)
    auto = choose_settings(cap, sf)
    window, rotations, frames, refine, spacing = (auto_value if value is None else value for value, auto_value in
                                                  zip(given, (auto.window, auto.rotations, auto.frames, auto.refine,
                                                              auto.spacing)))
    _check_neighbourhood(cap, window, chosen=True)
    return _Chosen(window, rotations, frames, refine, spacing, auto, options.window is None,
                   auto.coarse and options.spacing is None)


def _prepared_relief(cap, sf: SurfaceFit, region, options: CompletionOptions,
                     chosen: _Chosen) -> tuple[ReliefSurface, int, str, int]:
    """Samples, targets and their triangulation (Sec. 4, :func:`geosynth.completion.prep.prepare_relief`);
    a chosen window shrunk until most of the capture holds a whole one (else the candidates
    are its border's); a window no captured vertex holds refused. Returns (the relief, the
    window, the automatic settings' line, the vertices that hold a whole window)."""
    oversample = options.oversample
    if oversample is None:
        oversample = "none" if chosen.coarse else "butterfly"
    rs = prepare_relief(cap, sf, region, max_targets=options.max_targets, oversample=oversample,
                        spacing=chosen.spacing)
    depth = capture_depth(rs) / rs.spacing  # in target spacings: a W-ring reaches about W of them
    auto_line = "" if chosen.auto is None else chosen.auto.reason
    window = chosen.window
    if chosen.window_auto:
        w0 = window
        need = (lambda w: AUTO_WHOLE) if chosen.auto is None else chosen.auto.whole_share
        while window > AUTO_WINDOW_RANGE[0] and float(np.mean(depth >= window)) < need(window):
            window -= 1
        if window != w0:
            auto_line += (f"; window {w0} -> {window}: {float(np.mean(depth >= w0)):.0%} of the capture holds a "
                          f"whole window of {w0}, under {need(w0):.0%}")
        elif chosen.auto is not None and need(w0) < AUTO_WHOLE and float(np.mean(depth >= w0)) < AUTO_WHOLE:
            auto_line += (f"; window {w0} kept: {float(np.mean(depth >= w0)):.0%} of the capture holds it, at least "
                          f"{need(w0):.0%} for elements spaced in every direction, whose window spans their period")
    whole = int((depth >= window).sum())
    if whole == 0:
        deepest = float(depth.max()) if len(depth) else 0.0
        raise ValueError(f"window {window} is larger than the capture: its deepest vertex lies {deepest:.1f} target "
                         f"spacings from its border and a window of W edge rings reaches about W, so no candidate's "
                         f"neighbourhood is all captured relief; "
                         + (f"use a window from 1 to {int(deepest)}, or a larger capture." if deepest >= 1 else
                            "give a larger capture (the capture is thinner than one target spacing)."))
    return rs, window, auto_line, whole


def _tangent_frames(cap, sf: SurfaceFit, rs: ReliefSurface, chosen: _Chosen):
    """The frames the R rotations start from (Sec. 3): None for the paper's per-normal frames;
    for "fit" the fit's own orientation (a sphere's latitudes about the relief's axis when it
    has one), as (targets, 3, 3) rows u, v, n. Returns (rows, (axis, share) of a sphere's)."""
    if chosen.frames != "fit":
        return None, None
    axis = frame_axis = None
    if sf.kind == "sphere":  # latitudes about the relief's own axis when it has one
        measured = chosen.auto.latitude if chosen.auto is not None else None  # choose_settings measured it already
        axis, share = measured if measured is not None else latitude_axis(sf, cap.positions)
        if share >= LATITUDE_SHARE:
            axis = np.asarray(sf.axis, np.float64)
        frame_axis = (tuple(float(x) for x in axis), share)
    fu, fv = fit_frames(sf, rs.normals, axis)
    return np.stack([fu, fv, rs.normals / norm3(rs.normals)[:, None]], axis=1), frame_axis


def _candidates(sf: SurfaceFit, rs: ReliefSurface, candidates: str, coarse: bool) -> np.ndarray:
    """The samples matches are copied from: the capture's own vertices or every sample
    (``candidates``), thinned to one a target spacing when the targets are coarser."""
    samples = np.arange(rs.n_original if candidates == "capture" else rs.n_samples, dtype=np.int64)
    if coarse:
        samples = samples[_thin(sf, rs.base[samples], rs.spacing)]
    return samples


def _completed_surface(rs: ReliefSurface, textured: np.ndarray, sf: SurfaceFit) -> CompletedSurface:
    """The completed mesh as written: float32 positions, their normals, colours, faces and
    which vertices were captured, completed and textured."""
    completed = np.zeros(rs.n_vertices, bool)
    completed[rs.n_samples:] = True
    captured = np.zeros(rs.n_vertices, bool)
    captured[: rs.n_original] = True
    written = rs.positions.astype(np.float32)
    return CompletedSurface(
        positions=written,
        # the normals of the mesh as written: from its float32 positions, which every CPU
        # rounds alike (the float64 ones carry the fit's last bits, which LAPACK's and
        # NumPy's SIMD paths round by the CPU; issue 40)
        normals=_vertex_normals(written.astype(np.float64), rs.faces, rs.normals).astype(np.float32),
        colors=None if rs.colors is None else rs.colors.copy(),
        faces=rs.faces.astype(np.int32), completed=completed, captured=captured, textured=textured.copy(), fit=sf,
        alpha=None if rs.colors is None or rs.alpha is None else rs.alpha.copy())


# ---------------------------------------------------------------------- output


def write_completion(path: str | os.PathLike, surface: CompletedSurface, *, inputs=()) -> Path:
    """Write the completed surface as a binary PLY mesh, atomically.

    Vertex properties: x, y, z, nx, ny, nz (float32), red, green, blue (uchar, when
    coloured; then alpha too when the capture gave one), completed (uchar: 1 for the
    completed part); faces as vertex_indices.

    Args:
        path: the .ply file.
        surface: the :class:`CompletedSurface`.
        inputs: files never to overwrite.

    Returns:
        The path written.

    Raises:
        ValueError: the output is refused (:func:`geosynth.io.files.check_output`), or a
            position or normal is NaN or inf (before any file is created).
    """
    from plyfile import PlyData, PlyElement

    from geosynth.io.files import atomic_write, check_finite_output, check_output

    check_finite_output(path, "point", position=surface.positions, normal=surface.normals)
    out = check_output(path, inputs=inputs, suffixes=(".ply",), what="completion output")
    layout = [(c, "<f4") for c in ("x", "y", "z", "nx", "ny", "nz")]
    if surface.colors is not None:
        layout += [(c, "u1") for c in ("red", "green", "blue")]
        if surface.alpha is not None:
            layout.append(("alpha", "u1"))
    layout.append(("completed", "u1"))
    v = np.empty(len(surface), dtype=layout)
    for i, c in enumerate("xyz"):
        v[c] = surface.positions[:, i]
    for i, c in enumerate(("nx", "ny", "nz")):
        v[c] = surface.normals[:, i]
    if surface.colors is not None:
        for i, c in enumerate(("red", "green", "blue")):
            v[c] = surface.colors[:, i]
        if surface.alpha is not None:
            v["alpha"] = surface.alpha
    v["completed"] = surface.completed.astype(np.uint8)
    f = np.empty(len(surface.faces), dtype=[("vertex_indices", "i4", (3,))])
    f["vertex_indices"] = surface.faces
    data = PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")], text=False, byte_order="<")

    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            data.write(fh)

    return atomic_write(out, write, inputs=inputs)


TINT = np.array([230, 90, 40], dtype=np.float64)


def _direction_view(d: np.ndarray, lift: float = 0.35):
    d = d / max(np.linalg.norm(d), 1e-12) + lift * np.array([0.0, 0.0, 1.0])
    d = d / np.linalg.norm(d)
    return math.degrees(math.atan2(d[1], d[0])), float(np.clip(math.degrees(math.asin(np.clip(d[2], -1, 1))), -80, 80))


def _views(surface: CompletedSurface):
    """(azimuth, elevation) of three views: the captured part from outside, the completed
    part from outside, and a view across the border between them."""
    fit = surface.fit
    p = surface.positions.astype(np.float64)
    if fit.kind == "plane":
        n = fit.axis if fit.axis[2] >= 0 else -fit.axis
        d = n + 0.6 * np.array([0.0, -1.0, 0.0]) if abs(n[2]) > 0.5 else n
        v = _direction_view(d, 0.0)
        return v, v, v
    centre = fit.center if fit.kind == "sphere" else fit.center + (p - fit.center).mean(0) @ fit.axis * fit.axis

    def outward(mask):
        d = p[mask].mean(0) - centre if mask.any() else np.array([1.0, 0, 0])
        if fit.kind == "cylinder":
            d = d - (d @ fit.axis) * fit.axis
        if np.linalg.norm(d) < 1e-9:
            d = fit.basis[0]
        return d / np.linalg.norm(d)

    a, b = outward(~surface.completed), outward(surface.completed)
    mid = a + b
    if np.linalg.norm(mid) < 1e-6:  # opposite halves: look across the border
        mid = np.cross(fit.axis if fit.kind == "cylinder" else np.array([0.0, 0, 1]), a)
    return _direction_view(a), _direction_view(b), _direction_view(mid)


def completion_picture(surface: CompletedSurface, size=(420, 380)) -> np.ndarray:
    """Three views side by side: the captured part seen from its outside, the completion
    seen from the completed part's side, and the completion across the border with the
    completed part tinted orange.

    Returns:
        (H, W, 3) uint8 picture.
    """
    from geosynth.io.pictures import render_mesh, side_by_side

    v_cap, v_done, v_border = _views(surface)
    grey = np.full((len(surface), 3), 200, np.uint8)
    colors = surface.colors if surface.colors is not None else grey
    keep = ~surface.completed[surface.faces].any(1)
    bounds = np.stack([surface.positions.min(0), surface.positions.max(0)])
    captured = render_mesh((surface.positions, surface.faces[keep]), size=size, view=v_cap, vertex_colors=colors,
                           bounds=bounds)
    full = render_mesh((surface.positions, surface.faces), size=size, view=v_done, vertex_colors=colors,
                       bounds=bounds)
    tinted = colors.astype(np.float64)
    tinted[surface.completed] = 0.45 * tinted[surface.completed] + 0.55 * TINT
    tint = render_mesh((surface.positions, surface.faces), size=size, view=v_border,
                       vertex_colors=np.clip(np.round(tinted), 0, 255).astype(np.uint8), bounds=bounds)
    return side_by_side([captured, full, tint], labels=["captured", "completion (completed side)",
                                                        "completed part tinted"])
