"""Texture optimization (geosynth.volume.optimize), the minimum-error cut (geosynth.volume.graphcut)
and the synthesis methods end to end, on every present device."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import geosynth
from geosynth.volume.cascade import CascadeSearch
from geosynth.volume.examples import spheres_field
from geosynth.volume.graphcut import cut_cost, min_cut, must_keep
from geosynth.volume.optimize import falloff, irls_weights, lattice_positions, optimize_level, vote
from geosynth.volume.synthesis import METHODS, synthesize_volume


@pytest.fixture(scope="module")
def source():
    return spheres_field(20, count=7, radius=(2.0, 4.0), seed=5)


@pytest.fixture(scope="module")
def codes(source):
    from geosynth.volume.synthesis import quantize_field

    return quantize_field(source, 4.0)


# ------------------------------------------------------------------ the IRLS vote


@pytest.mark.parametrize("wrap,sigma", [(False, None), (True, None), (True, 0.3)])
def test_vote_is_the_irls_weighted_mean_per_sample(wrap, sigma):
    rng = np.random.default_rng(0)
    shape, block = (5, 4, 6), 3
    axes = [lattice_positions(n, block, 2, wrap) for n in shape]
    positions = np.array(list(itertools.product(*axes)), np.int64)
    patches = rng.integers(0, 256, (len(positions), block, block, block)).astype(np.uint8)
    ssd = rng.integers(0, 5000, len(positions))
    ssd[0] = 0  # a perfect match: weight of SSD 1, finite
    weights = irls_weights(ssd)
    np.testing.assert_allclose(weights, np.maximum(ssd, 1.0) ** ((0.8 - 2) / 2))
    g = falloff(block, sigma) if sigma else None
    # the same thing sample by sample, the slow way
    num = np.zeros(shape)
    den = np.zeros(shape)
    for p, patch, w in zip(positions, patches, weights):
        for d in itertools.product(range(block), repeat=3):
            at = tuple((p + np.array(d)) % np.array(shape)) if wrap else tuple(p + np.array(d))
            c = 1.0 if g is None else np.exp(-0.5 * sum(((k - 1) / (sigma * block)) ** 2 for k in d))
            num[at] += w * c * float(patch[d])
            den[at] += w * c
    assert (den > 0).all()
    expected = np.floor(num / den + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(vote(shape, positions, patches, weights, wrap, falloff=g), expected)


@pytest.mark.parametrize("wrap", [False, True])
def test_max_vote_copies_the_heaviest_patch_per_sample(wrap):
    rng = np.random.default_rng(2)
    shape, block = (4, 5, 6), 3
    axes = [lattice_positions(n, block, 2, wrap) for n in shape]
    positions = np.array(list(itertools.product(*axes)), np.int64)
    patches = rng.integers(0, 256, (len(positions), block, block, block)).astype(np.uint8)
    weights = irls_weights(rng.integers(0, 5000, len(positions)))
    g = falloff(block, 0.3)
    best = np.full(shape, -1.0)
    expected = np.zeros(shape, np.uint8)
    for p, patch, w in zip(positions, patches, weights):
        for d in itertools.product(range(block), repeat=3):
            at = tuple((p + np.array(d)) % np.array(shape)) if wrap else tuple(p + np.array(d))
            if w * g[d] > best[at]:
                best[at], expected[at] = w * g[d], patch[d]
    # (with wrap the fold visits samples in another order: only exact ties could differ, none here)
    np.testing.assert_array_equal(vote(shape, positions, patches, weights, wrap, falloff=g, mode="max"), expected)


def test_lattice_covers_every_sample():
    assert lattice_positions(10, 4, 2, False) == [0, 2, 4, 6]
    assert lattice_positions(11, 4, 2, False) == [0, 2, 4, 6, 7]
    assert lattice_positions(10, 4, 3, True) == [0, 3, 6, 9]


# ------------------------------------------------------------------ texture optimization


def test_iterations_stop_when_matches_stop_changing(codes, device):
    """A target that is the source itself: every block finds itself (SSD 0), the vote
    gives the source back, the second iteration changes no match and the loop stops."""
    src = np.ascontiguousarray(codes[:12, :12, :12])
    target = src.copy()
    got = optimize_level(src, target, 4, CascadeSearch(src, 4, device=device), stride=2, iterations=8)
    assert got["iterations"] == 2 and got["stopped"] == "matches settled"
    assert got["changed"] == [1.0, 0.0]
    assert got["mean_distance"] == 0.0
    np.testing.assert_array_equal(target, src)


def test_iteration_cap_and_tolerance(codes):
    src = np.ascontiguousarray(codes[:16, :16, :16])
    rng = np.random.default_rng(1)
    start = rng.integers(0, 256, (16, 16, 16)).astype(np.uint8)
    t1 = start.copy()
    got = optimize_level(src, t1, 8, CascadeSearch(src, 8, device="cpu"), iterations=1)
    assert got["iterations"] == 1 and got["matches"] == len(lattice_positions(16, 8, 2, False)) ** 3
    t2 = start.copy()
    got = optimize_level(src, t2, 8, CascadeSearch(src, 8, device="cpu"), iterations=20, tolerance=0.01)
    assert {"matches settled": got["changed"][-1] < 0.01, "iteration cap": got["iterations"] == 20,
            "energy rose": got["energy"][-1] > got["energy"][-2]}[got["stopped"]]
    assert all(c >= 0.01 for c in got["changed"][:-1])
    assert all(a > b for a, b in zip(got["energy"][:-2], got["energy"][1:-1]))  # it went down until it stopped
    # the optimized field is closer to the source's blocks than the random start
    assert not np.array_equal(t2, start)


# ------------------------------------------------------------------ the minimum cut


def test_min_cut_matches_brute_force():
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(40):
        shape = (2, 2, 3)
        old = rng.integers(0, 256, shape).astype(np.uint8)
        new = rng.integers(0, 256, shape).astype(np.uint8)
        must_new = rng.random(shape) < 0.2
        must_old = (rng.random(shape) < 0.25) & ~must_new
        if not must_new.any() or not must_old.any():
            continue
        got = min_cut(old, new, must_new, must_old)
        assert got[must_new].all() and not got[must_old].any()
        free = np.flatnonzero(~(must_new | must_old).reshape(-1))
        best = min(
            cut_cost(old, new, np.where(np.isin(np.arange(12), free[np.array(bits, bool)]) | must_new.reshape(-1),
                                        True, False).reshape(shape))
            for bits in itertools.product([0, 1], repeat=free.size)
        )
        assert cut_cost(old, new, got) == best
        checked += 1
    assert checked >= 15


def test_min_cut_follows_the_agreement():
    """Old and new agree on the left half: the seam goes there, not through the disagreement."""
    old = np.zeros((4, 4, 6), np.uint8)
    new = np.full((4, 4, 6), 200, np.uint8)
    new[:, :, :3] = 0  # agrees with old at x < 3
    must_old = np.zeros(old.shape, bool)
    must_old[:, :, 0] = True
    must_new = np.zeros(old.shape, bool)
    must_new[:, :, 5] = True
    take = min_cut(old, new, must_new, must_old)
    assert take[:, :, 3:].all() and not take[:, :, :1].any()
    assert cut_cost(old, new, take) == 16  # 16 edges of cost 1 cross the x planes between agreeing samples


def test_must_keep_marks_faces_next_to_synthesized_samples():
    done = np.zeros((4, 4, 8), bool)
    done[:, :, :4] = True  # the left half is synthesized
    keep = must_keep(done, (0, 0, 2), 4, wrap=False)  # x 2..5: x = 1 outside is synthesized
    assert keep[:, :, 0].all() and not keep[:, :, 1:].any()
    assert not must_keep(done, (0, 0, 4), 4, wrap=False).any()  # its samples are not synthesized
    big = np.zeros((8, 8, 8), bool)
    big[:, :, :4] = True
    keep = must_keep(big, (0, 0, 2), 4, wrap=False)  # the y and z faces touch synthesized samples too
    assert keep[:, 3, :2].all() and keep[3, :, :2].all() and not keep[:, 3, 2:].any()
    done2 = np.zeros((2, 2, 8), bool)
    done2[:, :, 0] = True
    done2[:, :, 6:] = True
    keep = must_keep(done2, (0, 0, 6), 2, wrap=True)
    assert keep[:, :, 1].all() and not keep[:, :, 0].any()  # x = 0 is the neighbour across the wrap
    assert not must_keep(done2, (0, 0, 6), 2, wrap=False).any()


# ------------------------------------------------------------------ end to end


@pytest.mark.parametrize("method", METHODS)
def test_each_method_same_bits_on_every_device(source, method):
    runs = [synthesize_volume(source, 32, levels=2, block=8, progress=False, device=d, seed=3, method=method,
                              iterations=3) for d in geosynth.devices()]
    for r in runs:
        assert r.method == method and r.quantized.shape == (32, 32, 32) and r.quantized.dtype == np.uint8
    for other in runs[1:]:
        np.testing.assert_array_equal(other.quantized, runs[0].quantized)


# Block distance of each method / random tiling's over 3 seeds: (worst, mean) bounds. Measured
# over seeds 0-9, the same under native, AVX2 and SSE4 (M1 is exact), mean / worst (sd):
# paper 0.559 / 0.602 (0.032), graphcut 0.521 / 0.602 (0.039), optimize 0.214 / 0.274 (0.023).
# The test once asserted < 0.6 on seed 3 alone: paper (seed 7) and graphcut (seed 6) are at 0.602.
# The paper's scan, with the same settings and seeds, is tests/test_volume.py::test_beats_random_tiling.
BEATS = {"graphcut": (0.7, 0.65), "optimize": (0.35, 0.3)}


def test_methods_beat_random_tiling(source):
    from geosynth.volume.quality import bidirectional_block_distance

    ratios = {m: [] for m in BEATS}
    for seed in range(3):
        kw = dict(levels=2, block=8, progress=False, device="cpu", seed=seed)
        base = synthesize_volume(source, 32, **kw, baseline=True)
        assert base.method == "random tiling"
        q_base = bidirectional_block_distance(base.source, base.quantized, 8, samples=40, seed=seed,
                                              device="cpu")["mean"]
        for method in BEATS:
            r = synthesize_volume(source, 32, **kw, method=method, iterations=3)
            q = bidirectional_block_distance(r.source, r.quantized, 8, samples=40, seed=seed, device="cpu")["mean"]
            ratios[method].append(q / q_base)
        opt = r.levels[-1]
        assert opt.iterations >= 1 and "texture optimization" in opt.search
    for method, (worst, mean) in BEATS.items():
        assert max(ratios[method]) < worst and np.mean(ratios[method]) < mean, (method, ratios[method])


def test_bad_method_is_refused(source):
    with pytest.raises(ValueError, match="method must be one of paper, graphcut, optimize"):
        synthesize_volume(source, 32, levels=2, block=8, progress=False, method="magic")
