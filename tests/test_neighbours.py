"""geosynth.core.neighbours: the one k-nearest-neighbour path, against brute force (issue 33 item 5)."""

import numpy as np
import pytest

from geosynth.core.neighbours import NeighbourIndex, nearest, pairs_within


def brute(points, queries, k, upper=np.inf, exclude_self=False):
    """(distances, indices) of the k nearest by a full distance matrix, ties by lower index."""
    d = np.sqrt(((queries[:, None, :] - points[None, :, :]) ** 2).sum(-1))
    if exclude_self:
        d[np.arange(len(points)), np.arange(len(points))] = np.inf
    order = np.lexsort((np.broadcast_to(np.arange(len(points)), d.shape), d), axis=-1)[:, :k]
    dk = np.take_along_axis(d, order, axis=1)
    idx = np.where(dk < upper, order, len(points))
    return np.where(dk < upper, dk, np.inf), idx


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_points_match_brute_force(dim, seed):
    rng = np.random.default_rng(seed)
    p, q = rng.random((400, dim)), rng.random((150, dim))
    for k in (1, 5):
        d, i = nearest(p, q, k)
        bd, bi = brute(p, q, k)
        np.testing.assert_array_equal(i, bi)
        np.testing.assert_allclose(d, bd, rtol=1e-12)


def test_lattice_ties_list_the_lower_index_first():
    """On a lattice every interior point has 4 neighbours at one distance: they come by index."""
    g = np.stack(np.meshgrid(np.arange(12.0), np.arange(12.0)), -1).reshape(-1, 2)
    perm = np.random.default_rng(3).permutation(len(g))
    p = g[perm]
    d, i = nearest(p, k=4)
    bd, bi = brute(p, p, 4, exclude_self=True)
    np.testing.assert_array_equal(i, bi)
    np.testing.assert_array_equal(d, bd)


def test_upper_bound_marks_missing_neighbours():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0], [5.0, 0, 0]])
    d, i = NeighbourIndex(p).query(np.array([[0.2, 0, 0], [9.0, 0, 0]]), 2, upper=1.5)
    assert i.tolist() == [[0, 1], [3, 3]]
    assert np.isinf(d[1]).all() and d[0].tolist() == pytest.approx([0.2, 0.8])


def test_self_excluded_even_with_coincident_points():
    p = np.array([[0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0]])
    d, i = nearest(p, k=2)
    for row in range(len(p)):
        assert row not in i[row]
    assert i[0].tolist() == [1, 2] and i[1].tolist() == [0, 2] and d[0, 0] == 0.0


def test_pairs_within():
    p = np.array([[0.0, 0], [0.5, 0], [2.0, 0], [2.4, 0]])
    assert sorted(map(tuple, pairs_within(p, 0.6).tolist())) == [(0, 1), (2, 3)]
    assert pairs_within(p, 0.1).shape == (0, 2)
