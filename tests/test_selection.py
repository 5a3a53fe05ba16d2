"""Selection on scores (argmin, near-best set, best fraction, random pick) per device."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import geosynth
from geosynth.compute import reference


def scores_with_ties(rng, n, dtype):
    if dtype == np.uint32:
        return rng.integers(0, 50, n).astype(np.uint32)  # many ties
    return (rng.integers(0, 50, n) * 0.25).astype(np.float32)


@pytest.mark.parametrize("dtype", [np.float32, np.uint32])
@pytest.mark.parametrize("n", [1, 7, 1000, 100_003])
@pytest.mark.parametrize("reduce_on", ["default", "kernel", "gpu-layout kernel"])
def test_argmin_lowest_index_on_ties(device, rng, dtype, n, reduce_on, monkeypatch):
    backend = geosynth.get_backend(device)
    if reduce_on != "default":  # small inputs too through the partial-minimum kernel
        monkeypatch.setattr(backend, "host_reduce_below", 0)
    if reduce_on == "gpu-layout kernel":  # OpenCL on a CPU reduces contiguous chunks; a GPU, strided shares
        if not hasattr(backend, "is_cpu"):
            pytest.skip("one layout on Warp")
        monkeypatch.setattr(backend, "is_cpu", not backend.is_cpu)
    s = scores_with_ties(rng, n, dtype)
    s[n // 2] = 0
    s[n - 1] = 0
    assert geosynth.argmin(s, device=device) == reference.argmin_naive(s) == (0 if s[0] == 0 else np.flatnonzero(s == 0)[0])


def test_argmin_on_device_scores(device, rng):
    s = rng.random(5000).astype(np.float32) + 1
    s[4321] = 0.5
    sd = geosynth.to_device(s, device)
    assert geosynth.argmin(sd) == 4321


@pytest.mark.parametrize("dtype", [np.float32, np.uint32])
@pytest.mark.parametrize("eps", [0.0, 0.1, 1.0])
def test_within_tolerance(device, rng, dtype, eps):
    s = scores_with_ties(rng, 20_000, dtype) + dtype(3)
    got = geosynth.within_tolerance(s, eps, device=device)
    want = reference.within_tolerance_naive(s, eps)
    np.testing.assert_array_equal(got, want)
    assert got.size >= 1 and np.all(s[got] <= (1 + eps) * s.min() + 1e-6)


def test_within_tolerance_threshold_is_exact_at_the_boundary(device):
    s = np.array([10, 11, 12, 13], np.uint32)  # (1 + 0.2) * 10 = 12 exactly
    np.testing.assert_array_equal(geosynth.within_tolerance(s, 0.2, device=device), [0, 1, 2])


@pytest.mark.parametrize("dtype", [np.float32, np.uint32])
@pytest.mark.parametrize("fraction", [1e-9, 0.1, 0.5, 1.0])
def test_best_fraction(device, rng, dtype, fraction):
    s = scores_with_ties(rng, 9_999, dtype)
    got = geosynth.best_fraction(s, fraction, device=device)
    np.testing.assert_array_equal(got, reference.best_fraction_naive(s, fraction))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(values=st.lists(st.integers(0, 20), min_size=1, max_size=400), fraction=st.floats(0.001, 1.0),
       eps=st.floats(0, 2), as_float=st.booleans())
def test_selection_generated(device, values, fraction, eps, as_float):
    s = np.array(values, np.float32 if as_float else np.uint32)
    np.testing.assert_array_equal(geosynth.best_fraction(s, fraction, device=device), reference.best_fraction_naive(s, fraction))
    np.testing.assert_array_equal(geosynth.within_tolerance(s, eps, device=device), reference.within_tolerance_naive(s, eps))
    assert geosynth.argmin(s, device=device) == reference.argmin_naive(s)


def test_random_pick_is_seeded(rng):
    idx = np.arange(100, 200)
    picks = [geosynth.random_pick(idx, seed=7) for _ in range(3)]
    assert picks[0] == picks[1] == picks[2] and picks[0] in idx
    many = {geosynth.random_pick(idx, seed=s) for s in range(50)}
    assert len(many) > 10  # different seeds reach different members
    g1, g2 = np.random.default_rng(3), np.random.default_rng(3)
    assert [geosynth.random_pick(idx, g1) for _ in range(5)] == [geosynth.random_pick(idx, g2) for _ in range(5)]


def test_pipeline_stays_on_device(device, rng):
    """Score on the device, select there, read back only indices."""
    grid = rng.integers(0, 256, (24, 24, 24), dtype=np.uint8)
    off = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    vals = grid[5:9, 6:10, 7:11].reshape(-1)
    gd = geosynth.to_device(grid, device)
    scores = geosynth.score_gather(gd, off, vals, keep_on_device=True)
    near = geosynth.within_tolerance(scores, 0.0)
    best = geosynth.argmin(scores)
    origins = geosynth.candidate_origins(grid.shape, off)
    np.testing.assert_array_equal(origins[best], [5, 6, 7])
    assert best in near
