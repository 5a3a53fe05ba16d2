"""Bad input: one assertion each, every error names the argument at fault."""

from __future__ import annotations

import numpy as np
import pytest

import geosynth

X = np.zeros((10, 4), np.float32)
Q = np.zeros((2, 4), np.float32)
GRID = np.zeros((8, 8, 8), np.uint8)
OFF = np.array([[0, 0, 0], [1, 1, 1]])
VALS = np.zeros(2, np.uint8)


def test_dense_invalid_input(device):
    with pytest.raises(ValueError, match="candidates must have 2 dimensions"):
        geosynth.score_dense(np.zeros(10, np.float32), Q, device=device)
    with pytest.raises(ValueError, match=r"queries must have shape \(B, 4\)"):
        geosynth.score_dense(X, np.zeros((2, 5), np.float32), device=device)
    with pytest.raises(TypeError, match="candidates has unsupported dtype int64"):
        geosynth.score_dense(X.astype(np.int64), Q, device=device)
    with pytest.raises(TypeError, match="queries has dtype float32 but candidates is uint8"):
        geosynth.score_dense(X.astype(np.uint8), Q, device=device)
    with pytest.raises(ValueError, match="queries contains 1 NaN or inf"):
        geosynth.score_dense(X, np.array([[0, np.nan, 0, 0]], np.float32), device=device)
    with pytest.raises(ValueError, match="queries contains 1 NaN or inf"):
        geosynth.score_dense(X, np.array([[0, np.inf, 0, 0]], np.float32), device=device)
    with pytest.raises(ValueError, match="candidates contains"):
        geosynth.score_dense(np.full((3, 4), np.nan, np.float32), Q, device=device)
    with pytest.raises(ValueError, match="candidates is empty"):
        geosynth.score_dense(np.zeros((0, 4), np.float32), Q, device=device)
    with pytest.raises(ValueError, match="queries is empty"):
        geosynth.score_dense(X, np.zeros((0, 4), np.float32), device=device)
    with pytest.raises(ValueError, match=r"weights must have shape \(4,\)"):
        geosynth.score_dense(X, Q, np.ones(3), device=device)
    with pytest.raises(ValueError, match="weights must be non-negative"):
        geosynth.score_dense(X, Q, np.array([1, -1, 1, 1.0]), device=device)
    with pytest.raises(TypeError, match="weights has dtype float64: uint8 data is scored exactly"):
        geosynth.score_dense(X.astype(np.uint8), Q.astype(np.uint8), np.ones(4), device=device)
    with pytest.raises(ValueError, match="beyond uint32"):
        geosynth.score_dense(X.astype(np.uint8), Q.astype(np.uint8), np.full(4, 20_000), device=device)


def test_gather_invalid_input(device):
    with pytest.raises(ValueError, match=r"offsets must have shape \(K, 2\) or \(K, 3\)"):
        geosynth.score_gather(GRID, np.zeros((2, 4), int), VALS, device=device)
    with pytest.raises(ValueError, match="offsets is empty"):
        geosynth.score_gather(GRID, np.zeros((0, 3), int), VALS[:0], device=device)
    with pytest.raises(TypeError, match="offsets must be integers"):
        geosynth.score_gather(GRID, OFF + 0.5, VALS, device=device)
    with pytest.raises(ValueError, match="grid must have 3 or 4 dimensions"):
        geosynth.score_gather(np.zeros((8, 8), np.uint8), OFF, VALS, device=device)
    with pytest.raises(TypeError, match="grid has unsupported dtype int32"):
        geosynth.score_gather(GRID.astype(np.int32), OFF, VALS, device=device)
    with pytest.raises(ValueError, match=r"values must have shape \(2, 1\) or \(2,\)"):
        geosynth.score_gather(GRID, OFF, np.zeros(3, np.uint8), device=device)
    with pytest.raises(ValueError, match="values contains 1 NaN"):
        geosynth.score_gather(GRID.astype(np.float32), OFF, np.array([0, np.nan], np.float32), device=device)
    with pytest.raises(ValueError, match="offsets reach outside the grid .* first origins\\[1\\] = \\(7, 0, 0\\)"):
        geosynth.score_gather(GRID, OFF, VALS, origins=np.array([[0, 0, 0], [7, 0, 0]]), device=device)
    with pytest.raises(ValueError, match="origins is empty"):
        geosynth.score_gather(GRID, OFF, VALS, origins=np.zeros((0, 3), int), device=device)
    with pytest.raises(ValueError, match="no valid candidate"):
        geosynth.score_gather(GRID, np.array([[0, 0, 0], [9, 0, 0]]), VALS, device=device)
    with pytest.raises(ValueError, match="stride must be a positive integer"):
        geosynth.score_gather(GRID, OFF, VALS, stride=0, device=device)


def test_selection_invalid_input(device):
    with pytest.raises(ValueError, match="scores is empty"):
        geosynth.argmin(np.zeros(0, np.float32), device=device)
    with pytest.raises(ValueError, match="scores must be 1-D"):
        geosynth.argmin(np.zeros((3, 3), np.float32), device=device)
    with pytest.raises(ValueError, match="scores contains NaN"):
        geosynth.argmin(np.array([1, np.nan], np.float32), device=device)
    with pytest.raises(TypeError, match="scores has dtype int64"):
        geosynth.argmin(np.array([1, 2]), device=device)
    with pytest.raises(ValueError, match="eps must be a finite number >= 0"):
        geosynth.within_tolerance(np.ones(3, np.float32), -0.1, device=device)
    with pytest.raises(ValueError, match=r"fraction must be in \(0, 1\]"):
        geosynth.best_fraction(np.ones(3, np.float32), 0.0, device=device)
    with pytest.raises(ValueError, match="indices must be a non-empty 1-D array"):
        geosynth.random_pick(np.array([], np.int64), seed=0)


def test_unknown_and_absent_devices():
    for bad in ["gpu", "cuda:x", "opencl:1", "", "CPU0"]:
        with pytest.raises(ValueError, match="Malformed device"):
            geosynth.score_dense(X, Q, device=bad)
    with pytest.raises(ValueError, match="device must be a string"):
        geosynth.get_backend(0)
    for absent in ["cuda:7", "opencl:9:0", "opencl:0:9"]:
        with pytest.raises(RuntimeError, match=r"is not present.*Present devices: .*cpu"):
            geosynth.score_dense(X, Q, device=absent)


def test_inputs_on_different_devices():
    present = geosynth.devices()
    if len(present) < 2:
        pytest.skip("needs two devices")
    xd = geosynth.to_device(X, present[0])
    with pytest.raises(RuntimeError, match="inputs live on"):
        geosynth.score_dense(xd, geosynth.to_device(Q, present[1]))
    with pytest.raises(RuntimeError, match="inputs live on"):
        geosynth.score_dense(xd, Q, device=present[1])
