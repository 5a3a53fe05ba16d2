"""Which candidate wins? Implements no paper section: the argmin and near-best picks after
scoring.

Selection on scores: the best candidate, the near-best set, the best fraction,
and a seeded random pick.

Scores may be a NumPy array (uploaded to ``device``) or a DeviceArray returned by a
scoring call with ``keep_on_device=True``; then the selection runs where the scores
are and only indices come back. Ties are always broken by the lowest index, and
every threshold is computed on the host in one place, so the same scores give the
same indices on every device.
"""

from __future__ import annotations

import math

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.core.arrays import NONFINITE_SCORES, SELECT_EQ, SELECT_LEQ, SELECT_LT, DeviceArray

_FLOAT32_MAX = np.finfo(np.float32).max

__all__ = ["argmin", "best_fraction", "random_pick", "tolerance_threshold", "within_tolerance"]


def _as_scores(scores, device):
    """Check scores, return (DeviceArray, backend)."""
    if not isinstance(scores, DeviceArray):
        scores = np.asarray(scores)
        if scores.dtype not in (np.dtype(np.float32), np.dtype(np.uint32)):
            if np.issubdtype(scores.dtype, np.floating):
                scores = scores.astype(np.float32)
            else:
                raise TypeError(f"scores has dtype {scores.dtype}: expected float32 or uint32 (as scoring returns).")
        if scores.dtype == np.float32 and not np.isfinite(scores).all():
            raise ValueError(NONFINITE_SCORES)
        if scores.dtype == np.float32 and scores.size and scores.min() < 0:
            raise ValueError("scores must be non-negative (sums of squared differences).")
    elif scores.known_stats() is not None:  # uploaded by to_device: checked like host scores
        bad, lo, _ = scores.known_stats()
        if bad:
            raise ValueError(NONFINITE_SCORES)
        if lo < 0:
            raise ValueError("scores must be non-negative (sums of squared differences).")
    if not (scores.ndim == 1 or (scores.ndim == 2 and scores.shape[0] == 1)):
        raise ValueError(f"scores must be 1-D (or (1, N)) for one query, got shape {scores.shape}; select per row.")
    if scores.size == 0:
        raise ValueError("scores is empty: there is no candidate to select.")
    backend = _checks.resolve_backend(device, scores)
    if not isinstance(scores, DeviceArray):
        scores = backend.to_device(np.ascontiguousarray(scores))
    return scores, backend


def tolerance_threshold(min_score, eps: float, dtype) -> np.generic:
    """The largest score of ``dtype`` that is <= (1 + eps) * min_score.

    Computed in float64 on the host, so every device compares against the same value.
    """
    bound = (1.0 + float(eps)) * float(min_score)
    if np.dtype(dtype) == np.uint32:
        return np.uint32(min(math.floor(bound), np.iinfo(np.uint32).max))
    t = np.float32(bound)
    if float(t) > bound:
        t = np.nextafter(t, np.float32(-np.inf))
    return t


def argmin(scores: np.ndarray | DeviceArray, *, device: str | None = None) -> int:
    """Index of the smallest score; the lowest index on ties.

    Args:
        scores: (N,) float32 or uint32 scores (or (1, N)), NumPy or DeviceArray.
        device: where NumPy scores are reduced; None means "auto" (DeviceArrays
            stay where they are).

    Returns:
        The index, an int in [0, N).

    Raises:
        ValueError: empty or wrongly shaped scores, negative scores, or a NaN or inf
            score: NumPy scores are checked on the host, device scores by the reduction
            itself (the same message either way; no index is returned for them).
        TypeError: a dtype other than float32 or uint32.
    """
    scores, backend = _as_scores(scores, device)
    return backend.argmin(scores)[0]


def within_tolerance(scores: np.ndarray | DeviceArray, eps: float, *, device: str | None = None) -> np.ndarray:
    """Indices of every score within ``(1 + eps)`` times the minimum.

    Args:
        scores: (N,) float32 or uint32 scores, NumPy or DeviceArray.
        eps: the relative tolerance, >= 0 (0 keeps the exact ties of the minimum).
        device: as for :func:`argmin`.

    Returns:
        (M,) int64 indices, ascending; never empty.
    """
    if not (isinstance(eps, (int, float, np.floating, np.integer)) and math.isfinite(eps) and eps >= 0):
        raise ValueError(f"eps must be a finite number >= 0, got {eps!r}.")
    scores, backend = _as_scores(scores, device)
    _, min_score = backend.argmin(scores)
    return backend.select(scores, tolerance_threshold(min_score, eps, scores.dtype), SELECT_LEQ)


def best_fraction(scores: np.ndarray | DeviceArray, fraction: float, *, device: str | None = None) -> np.ndarray:
    """Indices of the best ``ceil(fraction * N)`` scores (at least one).

    Ties at the cut are taken in index order. The cut value is found by bisection
    over the ordered values of the score dtype (float32 bit patterns of
    non-negative scores sort like the scores), with one counting pass per step.

    Args:
        scores: (N,) float32 or uint32 scores, NumPy or DeviceArray.
        fraction: in (0, 1].
        device: as for :func:`argmin`.

    Returns:
        (M,) int64 indices, ascending (a set, not a ranking).
    """
    if not (isinstance(fraction, (int, float, np.floating, np.integer)) and 0 < fraction <= 1):
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}.")
    unchecked = isinstance(scores, DeviceArray) and scores.known_stats() is None
    scores, backend = _as_scores(scores, device)
    n = scores.size
    if unchecked and scores.dtype == np.float32 and backend.count(scores, _FLOAT32_MAX, SELECT_LEQ) != n:
        raise ValueError(NONFINITE_SCORES)  # device scores: the NaN or inf ones are not <= max
    k = max(1, math.ceil(fraction * n))
    bits = np.uint32 if scores.dtype == np.uint32 else np.float32

    def value(b: int):
        return np.array([b], np.uint32).view(bits)[0]

    # Smallest v (as bits) with count(scores <= v) >= k; scores are >= 0 so bits order them.
    lo, hi = 0, int(np.array([np.inf if bits is np.float32 else np.iinfo(np.uint32).max], bits).view(np.uint32)[0])
    while lo < hi:
        mid = (lo + hi) // 2
        if backend.count(scores, value(mid), SELECT_LEQ) >= k:
            hi = mid
        else:
            lo = mid + 1
    cut = value(lo)
    below = backend.select(scores, cut, SELECT_LT)
    ties = backend.select(scores, cut, SELECT_EQ)[: k - below.size]
    return np.sort(np.concatenate([below, ties]))


def random_pick(indices: np.ndarray, seed: int | np.random.Generator | None = None) -> int:
    """One index drawn uniformly from ``indices`` with a host Generator.

    Args:
        indices: (M,) candidate indices, e.g. from :func:`within_tolerance`.
        seed: an int seed or a ``numpy.random.Generator`` (never the global state).

    Returns:
        The chosen index.
    """
    idx = np.asarray(indices)
    if idx.ndim != 1 or idx.size == 0:
        raise ValueError(f"indices must be a non-empty 1-D array, got shape {idx.shape}.")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    return int(idx[rng.integers(idx.size)])
