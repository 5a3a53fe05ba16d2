"""Candidate SSD scoring on every present device against the NumPy oracles."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import geosynth
from geosynth.compute import reference
from geosynth.core.constants import tol

DTYPES = [np.float32, np.uint8]


def random_data(rng, shape, dtype):
    if dtype == np.uint8:
        return rng.integers(0, 256, size=shape, dtype=np.uint8)
    return rng.standard_normal(shape).astype(np.float32)


def assert_scores(got, want, data_dtype):
    if data_dtype == np.uint8:
        assert got.dtype == np.uint32
        np.testing.assert_array_equal(got, want)
    else:
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, want, rtol=tol.ssd_rtol, atol=tol.ssd_atol)


# ---------------------------------------------------------------------------- dense


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("n, d, b", [(1000, 64, 1), (257, 37, 5), (33, 100, 9), (1, 16, 1), (50, 1, 3), (3, 4096, 2)])
def test_dense_matches_oracle(device, rng, dtype, n, d, b):
    x, q = random_data(rng, (n, d), dtype), random_data(rng, (b, d), dtype)
    got = geosynth.score_dense(x, q, device=device)
    assert got.shape == (b, n)
    assert_scores(got, reference.score_dense_naive(x, q), dtype)


@pytest.mark.parametrize("b", [1, 7])
def test_dense_uint8_extremes_exact(device, rng, b):
    """Largest differences over long rows: exact even where float lanes would lose
    integers (a lane sum past 2^24), for single queries and batches."""
    d = 9000
    x = np.where(rng.random((37, d)) < 0.9, 255, 0).astype(np.uint8)
    q = np.where(rng.random((b, d)) < 0.1, 255, 0).astype(np.uint8)
    got = geosynth.score_dense(x, q, device=device)
    assert_scores(got, reference.score_dense_naive(x, q), np.uint8)
    assert got.max() > 2**24


@pytest.mark.parametrize("dtype", DTYPES)
def test_dense_weights(device, rng, dtype):
    x, q = random_data(rng, (300, 45), dtype), random_data(rng, (4, 45), dtype)
    w = rng.integers(0, 5, 45) if dtype == np.uint8 else rng.random(45).astype(np.float32)
    got = geosynth.score_dense(x, q, w, device=device)
    assert_scores(got, reference.score_dense_naive(x, q, w), dtype)
    # zero weights switch entries off: the score equals that of the reduced rows
    w0 = np.zeros(45, w.dtype)
    w0[:10] = 1
    assert_scores(geosynth.score_dense(x, q, w0, device=device), reference.score_dense_naive(x[:, :10], q[:, :10]), dtype)


def test_dense_single_query_vector_and_self_match(device, rng):
    x = random_data(rng, (500, 20), np.uint8)
    got = geosynth.score_dense(x, x[123], device=device)
    assert got.shape == (500,)
    assert got[123] == 0
    assert geosynth.argmin(got, device=device) == 123


def test_dense_on_device_inputs(device, rng):
    x, q = random_data(rng, (200, 24), np.float32), random_data(rng, (3, 24), np.float32)
    xd = geosynth.to_device(x, device)
    out = geosynth.score_dense(xd, q, keep_on_device=True)
    assert isinstance(out, geosynth.DeviceArray) and out.device == xd.device and out.shape == (3, 200)
    assert_scores(out.numpy(), reference.score_dense_naive(x, q), np.float32)


def test_dense_float64_input_is_converted(device, rng):
    x, q = rng.standard_normal((40, 8)), rng.standard_normal((2, 8))
    got = geosynth.score_dense(x, q, device=device)
    assert got.dtype == np.float32
    assert_scores(got, reference.score_dense_naive(x.astype(np.float32), q.astype(np.float32)), np.float32)


# --------------------------------------------------------------------------- gather


def block_offsets(size, nd):
    return np.stack(np.meshgrid(*[np.arange(size)] * nd, indexing="ij"), -1).reshape(-1, nd)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("nd, shape", [(2, (23, 31)), (2, (17, 20, 3)), (3, (19, 21, 18)), (3, (12, 14, 13, 2))])
def test_gather_lattice_matches_oracle(device, rng, dtype, nd, shape):
    grid = random_data(rng, shape, dtype)
    channels = shape[nd] if len(shape) > nd else 1
    off = block_offsets(4, nd)
    vals = random_data(rng, (len(off), channels), dtype)
    got = geosynth.score_gather(grid, off, vals, device=device)
    counts = geosynth.lattice_shape(shape[:nd], off)
    assert counts == tuple(s - 3 for s in shape[:nd])
    assert got.shape == (int(np.prod(counts)),)
    assert_scores(got, reference.score_gather_naive(grid, off, vals), dtype)


@pytest.mark.parametrize("dtype", DTYPES)
def test_gather_block_query_finds_its_own_window(device, rng, dtype):
    """M1's linear search: a block cut from the source is its own best match, score 0."""
    grid = random_data(rng, (20, 22, 24), dtype)
    off = block_offsets(8, 3)
    origin = np.array([5, 9, 11])
    vals = grid[tuple((origin + off).T)]
    scores = geosynth.score_gather(grid, off, vals, device=device)
    best = geosynth.argmin(scores, device=device)
    np.testing.assert_array_equal(geosynth.candidate_origins(grid.shape, off)[best], origin)
    assert scores[best] == 0


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("stride", [2, (3, 1), (1, 4)])
def test_gather_strides(device, rng, dtype, stride):
    grid = random_data(rng, (40, 37, 3), dtype)
    off = np.array([[0, 0], [2, -1], [-3, 5], [1, 1]])
    vals = random_data(rng, (4, 3), dtype)
    got = geosynth.score_gather(grid, off, vals, stride=stride, device=device)
    assert_scores(got, reference.score_gather_naive(grid, off, vals, stride=stride), dtype)


@pytest.mark.parametrize("dtype", DTYPES)
def test_gather_explicit_origins_and_weights(device, rng, dtype):
    grid = random_data(rng, (16, 15, 14), dtype)
    off = rng.integers(-2, 3, size=(30, 3))
    vals = random_data(rng, (30,), dtype)
    w = rng.integers(0, 4, 30) if dtype == np.uint8 else rng.random(30).astype(np.float32)
    origins = rng.integers(2, 12, size=(77, 3))
    got = geosynth.score_gather(grid, off, vals, w, origins=origins, device=device)
    assert got.shape == (77,)
    assert_scores(got, reference.score_gather_naive(grid, off, vals, w, origins=origins), dtype)


@pytest.mark.parametrize("dtype", DTYPES)
def test_gather_wrap(device, rng, dtype):
    """A periodic grid: every position is a candidate and windows continue across faces."""
    grid = random_data(rng, (12, 10, 3), dtype)
    off = np.array([[-3, -3], [0, 0], [4, 2], [5, 9]])
    vals = random_data(rng, (4, 3), dtype)
    got = geosynth.score_gather(grid, off, vals, wrap=True, device=device)
    assert got.shape == (120,)
    assert_scores(got, reference.score_gather_naive(grid, off, vals, wrap=True), dtype)
    # explicit origins outside the grid wrap too
    origins = np.array([[-1, -1], [12, 10], [25, 3]])
    got = geosynth.score_gather(grid, off, vals, origins=origins, wrap=True, device=device)
    assert_scores(got, reference.score_gather_naive(grid, off, vals, origins=origins, wrap=True), dtype)
    # a grid on the device wraps too (its padded copy is made once and cached)
    gd = geosynth.to_device(grid, device)
    for _ in range(2):
        assert_scores(geosynth.score_gather(gd, off, vals, wrap=True), reference.score_gather_naive(grid, off, vals, wrap=True), dtype)
    assert len(gd._derived) == 1


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("wrap", [False, True])
def test_gather_strided_multichannel_3d(device, rng, dtype, wrap):
    """Strided, multi-channel 3D lattices (scored on the polyphase copy) equal the oracle,
    with a threshold, and the same scorer still serves explicit origins from the plain grid."""
    grid = random_data(rng, (9, 11, 13, 2), dtype)
    off = rng.integers(-3, 4, size=(7, 3)) if wrap else rng.integers(0, 4, size=(7, 3))
    vals = random_data(rng, (7, 2), dtype)
    stride = (2, 3, 4)
    want = reference.score_gather_naive(grid, off, vals, stride=stride, wrap=wrap)
    gd = geosynth.to_device(grid, device)
    scorer = geosynth.compute.scoring.GatherScorer(gd, off, stride=stride, wrap=wrap)
    assert_scores(scorer(vals), want, dtype)
    thr = float(np.sort(want)[want.size // 3])
    got = scorer(vals, threshold=thr)
    kept = want <= thr
    assert_scores(got[kept], want[kept], dtype)
    assert (got[~kept] > thr).all()
    origins = geosynth.compute.scoring.candidate_origins(grid.shape, off, stride, wrap)[::-1]
    assert_scores(scorer(vals, origins=origins), want[::-1], dtype)


def test_gather_supersampled_texture_neighbourhood(device, rng):
    """M3's eq. 5 form: irregular offsets on an x8 supersampled texture, one candidate per texel."""
    texture = rng.random((16, 16, 3)).astype(np.float32)
    supersampled = np.repeat(np.repeat(texture, 8, axis=0), 8, axis=1)
    off = rng.integers(-20, 21, size=(25, 2))
    vals = rng.random((25, 3)).astype(np.float32)
    got = geosynth.score_gather(supersampled, off, vals, stride=8, wrap=True, device=device)
    assert got.shape == (256,)
    assert_scores(got, reference.score_gather_naive(supersampled, off, vals, stride=8, wrap=True), np.float32)


def test_gather_device_grid_reused(device, rng):
    grid = random_data(rng, (30, 30, 30), np.uint8)
    gd = geosynth.to_device(grid, device)
    off = block_offsets(4, 3)
    for _ in range(2):
        vals = random_data(rng, (64,), np.uint8)
        assert_scores(geosynth.score_gather(gd, off, vals), reference.score_gather_naive(grid, off, vals), np.uint8)


# ---------------------------------------------------------------- generated shapes


@st.composite
def gather_cases(draw):
    nd = draw(st.sampled_from([2, 3]))
    dims = draw(st.lists(st.integers(1, 14 if nd == 3 else 30), min_size=nd, max_size=nd))
    channels = draw(st.sampled_from([0, 1, 3]))  # 0: no channel axis
    k = draw(st.integers(1, 12))
    off = np.array(draw(st.lists(st.lists(st.integers(-3, 3), min_size=nd, max_size=nd), min_size=k, max_size=k)))
    stride = draw(st.integers(1, 3))
    wrap = draw(st.booleans())
    dtype = draw(st.sampled_from(DTYPES))
    seed = draw(st.integers(0, 2**31))
    return nd, dims, channels, off, stride, wrap, dtype, seed


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=gather_cases())
def test_gather_generated_shapes(device, case):
    nd, dims, channels, off, stride, wrap, dtype, seed = case
    rng = np.random.default_rng(seed)
    shape = tuple(dims) + ((channels,) if channels else ())
    grid = random_data(rng, shape, dtype)
    vals = random_data(rng, (len(off), max(channels, 1)), dtype)
    if min(geosynth.lattice_shape(dims, off, stride, wrap)) == 0:
        with pytest.raises(ValueError, match="no valid candidate"):
            geosynth.score_gather(grid, off, vals, stride=stride, wrap=wrap, device=device)
        return
    got = geosynth.score_gather(grid, off, vals, stride=stride, wrap=wrap, device=device)
    assert_scores(got, reference.score_gather_naive(grid, off, vals, stride=stride, wrap=wrap), dtype)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 300), d=st.integers(1, 70), b=st.integers(1, 10), dtype=st.sampled_from(DTYPES),
       weighted=st.booleans(), seed=st.integers(0, 2**31))
def test_dense_generated_shapes(device, n, d, b, dtype, weighted, seed):
    rng = np.random.default_rng(seed)
    x, q = random_data(rng, (n, d), dtype), random_data(rng, (b, d), dtype)
    w = None
    if weighted:
        w = rng.integers(0, 9, d) if dtype == np.uint8 else rng.random(d).astype(np.float32)
    assert_scores(geosynth.score_dense(x, q, w, device=device), reference.score_dense_naive(x, q, w), dtype)


# ------------------------------------------------------------------ across devices


def test_uint8_scores_identical_on_every_device(device_pair, rng):
    """Integer scoring is exact: every two test devices return the same bits."""
    x, q = random_data(rng, (700, 53), np.uint8), random_data(rng, (3, 53), np.uint8)
    grid = random_data(rng, (18, 19, 20), np.uint8)
    off = block_offsets(4, 3)
    vals = random_data(rng, (64,), np.uint8)
    results = [
        (geosynth.score_dense(x, q, device=d), geosynth.score_gather(grid, off, vals, device=d))
        for d in device_pair
    ]
    for dense, gather in results[1:]:
        np.testing.assert_array_equal(dense, results[0][0])
        np.testing.assert_array_equal(gather, results[0][1])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("weighted", [False, True])
def test_gather_threshold_keeps_the_argmin_exact(device, rng, dtype, weighted):
    """Early exit: scores at or below the threshold are exact, the rest stay above it,
    so the argmin with any candidate's score as threshold is the true argmin."""
    grid = random_data(rng, (26, 27, 40), dtype)
    off = block_offsets(8, 3)  # 512 entries: two early-exit checks
    origin = np.array([9, 4, 17])
    vals = grid[tuple((origin + off).T)].astype(np.float64) + rng.normal(0, 3, len(off))
    vals = np.clip(vals, 0, 255).astype(dtype) if dtype == np.uint8 else vals.astype(np.float32)
    w = None
    if weighted:
        w = rng.integers(1, 3, len(off)) if dtype == np.uint8 else rng.random(len(off)).astype(np.float32) + 0.5
    exact = reference.score_gather_naive(grid, off, vals, w)
    for guess in (0, 123, int(np.argmin(exact))):
        thr = float(exact[guess])
        got = geosynth.score_gather(grid, off, vals, w, threshold=thr, device=device)
        low = exact <= thr
        assert_scores(got[low], exact[low], dtype)
        assert np.all(got[~low] > np.float32(thr) * (1 - 1e-6))
        assert geosynth.argmin(got, device=device) == int(np.argmin(exact))


def test_gather_threshold_invalid(device):
    grid = np.zeros((8, 8), np.uint8)
    with pytest.raises(ValueError, match="threshold must be a finite number >= 0"):
        geosynth.score_gather(grid, np.array([[0, 0]]), np.zeros(1, np.uint8), threshold=-1, device=device)


@pytest.mark.parametrize("channels", [1, 3])
def test_gather_scorer_bases_equal_origins(device, rng, channels):
    """score_bases over lattice_bases / flat_bases gives what origins give."""
    from geosynth.compute.scoring import GatherScorer

    shape = (9, 11, 13) + ((channels,) if channels > 1 else ())
    grid = rng.integers(0, 256, shape, dtype=np.uint8)
    offsets = rng.integers(0, 4, (7, 3))
    values = rng.integers(0, 256, (7, channels) if channels > 1 else (7,), dtype=np.uint8)
    scorer = GatherScorer(grid, offsets, device=device)
    every = scorer(values)
    pick = np.sort(rng.choice(every.size, 40, replace=False))
    origins = np.stack(np.unravel_index(pick, scorer.lattice), 1)
    np.testing.assert_array_equal(scorer.score_bases(values, scorer.lattice_bases(pick)), every[pick])
    np.testing.assert_array_equal(scorer.score_bases(values, scorer.flat_bases(origins)), every[pick])
    np.testing.assert_array_equal(scorer(values, origins=origins), every[pick])
    with pytest.raises(ValueError, match="indices must lie"):
        scorer.lattice_bases([every.size])
    with pytest.raises(ValueError, match="bases must be a non-empty"):
        scorer.score_bases(values, np.zeros(0, np.int32))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("block, channels", [(16, 1), (32, 1), (16, 2)])
def test_gather_explicit_origins_of_block_rows(device, rng, dtype, block, channels):
    """Block offsets come in x runs (16-lane loads on OpenCL); explicit origins, with and
    without a threshold, give the oracle's scores (the argmin stays exact)."""
    from geosynth.compute.scoring import GatherScorer, offset_run

    shape = (block + 3, block + 2, block + 5) + ((channels,) if channels > 1 else ())
    grid = random_data(rng, shape, dtype)
    off = block_offsets(block, 3)[: block * block * 4]  # 4 z-slices of the block
    vals = random_data(rng, (len(off), channels) if channels > 1 else (len(off),), dtype)
    origins = np.stack([rng.integers(0, 4, 50), rng.integers(0, 3, 50), rng.integers(0, 6, 50)], 1)
    scorer = GatherScorer(grid, off, device=device)
    assert offset_run(scorer._flat_off_host) == min(64, block * channels)
    want = reference.score_gather_naive(grid, off, vals, origins=origins)
    assert_scores(scorer(vals, origins=origins), want, dtype)
    thr = float(np.sort(want)[5])
    got = scorer(vals, origins=origins, threshold=thr)
    best = int(np.argmin(want))
    assert int(np.argmin(got)) == best
    assert_scores(got[best:best + 1], want[best:best + 1], dtype)
    assert np.all(got[want > thr * 1.001] > thr)
