"""The output's hashed grid of point buckets (M2, Sec. 4) against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from geosynth.pointtexture.output_grid import PointGrid


def _cloud(rng, n, lo=0.0, hi=1.0):
    p = rng.uniform(lo, hi, (n, 3))
    p[:, 2] *= 0.1
    n_ = rng.normal(size=(n, 3))
    return p, n_ / np.linalg.norm(n_, axis=1, keepdims=True)


def test_insert_box_remove_neighbours_match_brute_force(rng):
    p, n = _cloud(rng, 3000)
    g = PointGrid(0.07)
    g.insert(p[:1000], n[:1000])
    g.insert(p[1000:], n[1000:])
    assert len(g) == 3000
    lo, hi = np.array([0.2, 0.3]), np.array([0.55, 0.61])
    bp, bn = g.in_box(lo, hi)
    want = ((p[:, :2] >= lo) & (p[:, :2] <= hi)).all(axis=1)
    np.testing.assert_array_equal(bp, p[want])  # insertion order
    np.testing.assert_array_equal(bn, n[want])
    removed = g.remove_box(lo, hi)
    assert removed == int((((p[:, :2] >= lo) & (p[:, :2] < hi)).all(axis=1)).sum())
    alive = ~(((p[:, :2] >= lo) & (p[:, :2] < hi)).all(axis=1))
    ap, _ = g.all_points()
    np.testing.assert_array_equal(ap, p[alive])
    q = rng.uniform(0, 1, (5, 3))
    npnt, _ = g.neighbours(q, 0.1)
    d = np.linalg.norm(p[alive][:, None, :] - q[None], axis=2).min(axis=1)
    np.testing.assert_array_equal(npnt, p[alive][d <= 0.1])


def test_periodic_grid_wraps_inserts_and_boxes(rng):
    g = PointGrid(0.1, period=(1.0, 2.0))
    p = np.array([[1.05, 0.5, 0.0], [-0.05, 2.1, 0.0], [0.5, 0.5, 0.0]])
    g.insert(p, np.tile([0, 0, 1.0], (3, 1)))
    stored, _ = g.all_points()
    np.testing.assert_allclose(stored[:, :2], [[0.05, 0.5], [0.95, 0.1], [0.5, 0.5]], atol=1e-12)
    # a box beyond the right border sees the first point's image, translated into its frame
    bp, _ = g.in_box([0.9, 0.4], [1.2, 0.6])
    np.testing.assert_allclose(bp[:, :2], [[1.05, 0.5]], atol=1e-12)
    assert g.remove_box([0.9, 0.0], [1.2, 0.6]) == 2  # both wrapped points
    assert len(g) == 1


def test_bad_cell():
    with pytest.raises(ValueError, match="cell"):
        PointGrid(0.0)


def test_many_inserts_and_removals_match_brute_force(rng):
    """A growth's pattern (insert, box queries, removals; 45,000 points, negative cells
    included): every box query is brute force's, in insertion order."""
    g = PointGrid(0.05)
    pos, nrm, alive = [], [], []
    for step in range(30):
        p, n = _cloud(rng, 1500, lo=-1.0, hi=1.0)
        g.insert(p, n)
        pos.append(p), nrm.append(n), alive.append(np.ones(len(p), bool))
        lo = rng.uniform(-1.0, 0.6, 2)
        hi = lo + rng.uniform(0.05, 0.5, 2)
        P, N, A = np.concatenate(pos), np.concatenate(nrm), np.concatenate(alive)
        want = A & ((P[:, :2] >= lo) & (P[:, :2] <= hi)).all(axis=1)
        bp, bn = g.in_box(lo, hi)
        np.testing.assert_array_equal(bp, P[want])
        np.testing.assert_array_equal(bn, N[want])
        if step % 3 == 0:
            gone = A & ((P[:, :2] >= lo) & (P[:, :2] < hi)).all(axis=1)
            assert g.remove_box(lo, hi) == int(gone.sum())
            cut = np.cumsum([0] + [len(a) for a in alive])
            for j in range(len(alive)):
                alive[j] &= ~gone[cut[j]:cut[j + 1]]
    assert len(g) == int(np.concatenate(alive).sum())
    ap, _ = g.all_points()
    np.testing.assert_array_equal(ap, np.concatenate(pos)[np.concatenate(alive)])
