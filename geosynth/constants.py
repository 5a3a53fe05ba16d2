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
