"""Why these tolerances and tuning values? Implements no paper section: each constant says
what it serves.

Tolerances and tuning constants, each with its reason."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Tolerance:
    """How closely float32 kernel results must match the float64 oracles.

    A float32 sum of D non-negative terms carries a relative rounding error of at most
    about D * 2^-24 and typically sqrt(D) * 2^-24; ``ssd_rtol`` allows the typical
    error of D = 4096 with a margin. uint8 scores are exact: no tolerance at all.
    """

    ssd_rtol: float = 2e-5
    ssd_atol: float = 1e-4


tol = Tolerance()

# M1's default source resolution (exemplar samples along its longest side) and finest
# block: the paper's (Sec. 5.2: source 64^3, block 16 at the finest level). A run that
# chooses its own settings (geosynth.volume.synthesis.choose_settings) doubles both when the
# exemplar's thinnest features span fewer than M1_MIN_FEATURE_SAMPLES samples at 64.
M1_DEFAULT_RESOLUTION = 64
M1_DEFAULT_BLOCK = 16
# A feature thinner than this many samples does not survive the synthesis: at 64 the
# washers of issue #32 (0.08 thick, 1.5 samples) came out broken or fused in the mesh
# (18% of the whole ones changed), at 128 with block 32 they were kept (2%). The built-ins'
# thinnest (median ridge thickness at 64): rings 3.2, domes 3.2, fibers 3.6, chainmail 3.8.
M1_MIN_FEATURE_SAMPLES = 3.0
# A block must hold a whole element and this margin (samples) to copy it whole: separate
# elements wider than the block come out as arcs. geosynth.volume.synthesis.choose_settings raises the
# finest block to the power of two that holds the exemplar's whole elements' span plus it,
# where the source still holds two such blocks across.
M1_ELEMENT_MARGIN_SAMPLES = 2.0
# Separate elements with at least this share of their volume in elements across the
# footprint (tubes: geosynth.volume.features' ``spanning``) get the largest finest block the
# source holds twice across (geosynth.volume.synthesis.choose_settings): the zoo's wavy tubes at block
# 16 fused and wobbled where blocks were stitched (block distance 51.9), at 32 ran on (17.6).
M1_ACROSS_SHARE = 0.5
