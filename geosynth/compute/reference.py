"""What must scoring and selection return? Implements no paper section: plain NumPy oracles
of :func:`geosynth.score_dense`, :func:`geosynth.score_gather`, :func:`geosynth.argmin`,
:func:`geosynth.within_tolerance` and :func:`geosynth.best_fraction`, which every method uses.

These oracles are slow, obvious and never on a production path. Each takes the same arguments
as the operation it checks and returns the same result; float sums are accumulated in float64,
uint8 sums in exact integers.
"""

from __future__ import annotations

import math

import numpy as np

from geosynth.compute.selection import tolerance_threshold


def score_dense_naive(candidates: np.ndarray, queries: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Same arguments and result as :func:`geosynth.score_dense` (float64 or int64 here)."""
    exact = candidates.dtype == np.uint8
    acc = np.int64 if exact else np.float64
    x = candidates.astype(acc)
    q = np.atleast_2d(queries).astype(acc)
    w = np.ones(x.shape[1], acc) if weights is None else np.asarray(weights).astype(acc)
    out = np.empty((q.shape[0], x.shape[0]), acc)
    for b in range(q.shape[0]):
        out[b] = (((x - q[b]) ** 2) * w).sum(axis=1)
    return out[0] if np.ndim(queries) == 1 else out


def score_gather_naive(
    grid: np.ndarray,
    offsets: np.ndarray,
    values: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    origins: np.ndarray | None = None,
    stride=1,
    wrap: bool = False,
) -> np.ndarray:
    """Same arguments and result as :func:`geosynth.score_gather`, one candidate at a time."""
    from geosynth.compute.scoring import candidate_origins

    off = np.asarray(offsets, np.int64)
    k, nd = off.shape
    exact = grid.dtype == np.uint8
    acc = np.int64 if exact else np.float64
    g = grid.astype(acc)
    if g.ndim == nd:
        g = g[..., None]
    dims = np.array(g.shape[:nd])
    vals = np.asarray(values).astype(acc).reshape(k, -1)
    w = np.ones(k, acc) if weights is None else np.asarray(weights).astype(acc)
    if origins is None:
        origins = candidate_origins(grid.shape[:nd], off, stride, wrap)
    out = np.empty(len(origins), acc)
    for i, o in enumerate(np.asarray(origins, np.int64)):
        pos = o + off
        if wrap:
            pos = np.mod(pos, dims)
        window = g[tuple(pos.T)]  # (K, C)
        out[i] = (((window - vals) ** 2).sum(axis=1) * w).sum()
    return out


def argmin_naive(scores: np.ndarray) -> int:
    """Same as :func:`geosynth.argmin`: np.argmin already returns the first minimum."""
    return int(np.argmin(np.ravel(scores)))


def within_tolerance_naive(scores: np.ndarray, eps: float) -> np.ndarray:
    """Same as :func:`geosynth.within_tolerance`."""
    s = np.ravel(scores)
    return np.flatnonzero(s <= tolerance_threshold(s.min(), eps, s.dtype)).astype(np.int64)


def best_fraction_naive(scores: np.ndarray, fraction: float) -> np.ndarray:
    """Same as :func:`geosynth.best_fraction`: sort by (score, index), keep the first k."""
    s = np.ravel(scores)
    k = max(1, math.ceil(fraction * s.size))
    order = np.lexsort((np.arange(s.size), s))
    return np.sort(order[:k]).astype(np.int64)
