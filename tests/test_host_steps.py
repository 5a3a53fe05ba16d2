"""geosynth.compute.host_steps: the compiled host steps' wrappers (Warp's cpu device for every run):
zero-copy views both ways, empty arrays, dtypes, and a launch that writes into NumPy memory."""

from __future__ import annotations

import gc

import numpy as np
import pytest
import warp as wp

from geosynth.compute.host_steps import host_array, host_launch, host_threads, part_bounds, run_parts


@wp.kernel
def _scale_rows(x: wp.array(dtype=wp.float64), ids: wp.array(dtype=wp.int32), factor: float,
                out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    out[i] = x[ids[i]] * wp.float64(factor)


def test_views_share_memory_and_a_launch_writes_into_numpy():
    x = np.arange(12.0).reshape(4, 3)
    wx, hx = host_array(x, np.float64)
    assert hx is x or np.shares_memory(hx, x)  # already contiguous float64: no copy
    ids = [3, 0, 11, 5]
    wi, _ = host_array(np.asarray(ids), np.int32)  # int64 -> int32: a converted copy
    wo, out = host_array(np.full(4, np.nan))
    host_launch(_scale_rows, 4, [wx, wi, 2.5, wo])
    assert np.array_equal(out, 2.5 * x.reshape(-1)[ids])
    x[0, 0] = 100.0  # a write on the host is seen by the view
    assert wx.numpy()[0] == 100.0


def test_a_view_keeps_its_memory_and_empty_arrays_get_one_element():
    w, _ = host_array(np.arange(5, dtype=np.float64) * 3)
    gc.collect()
    assert np.array_equal(w.numpy(), [0.0, 3.0, 6.0, 9.0, 12.0])
    e, a = host_array(np.zeros((0, 3)))
    assert a.shape == (0, 3) and e.shape == (1,)
    host_launch(_scale_rows, 0, [e, host_array(np.zeros(0), np.int32)[0], 1.0, e])  # dim 0: nothing runs


def test_unsupported_dtype_is_refused():
    with pytest.raises(TypeError, match="complex128 has no Warp twin"):
        host_array(np.zeros(3, np.complex128))


@wp.kernel
def _scale_rows_part(x: wp.array(dtype=wp.float64), ids: wp.array(dtype=wp.int32), factor: float,
                     out: wp.array(dtype=wp.float64), part_start: int):
    i = part_start + wp.tid()
    s = wp.float64(0.0)
    for k in range(i % 7 + 1):  # uneven work per item
        s += x[ids[i]] * wp.float64(factor) / wp.float64(k + 1)
    out[i] = s


@pytest.mark.parametrize("threads", ["1", "2", "3"])
def test_a_split_launch_covers_every_item_once_with_the_same_bits(monkeypatch, threads):
    rng = np.random.default_rng(3)
    x = rng.normal(size=1001)
    ids = rng.integers(0, 1001, size=1001)
    args = [host_array(x, np.float64)[0], host_array(ids, np.int32)[0], 1.5]
    monkeypatch.setenv("GEOSYNTH_HOST_THREADS", "1")
    wo1, whole = host_array(np.full(1001, np.nan))
    host_launch(_scale_rows_part, 1001, args + [wo1], split=True)  # the first launch: whole
    monkeypatch.setenv("GEOSYNTH_HOST_THREADS", threads)
    for min_part in (1, 64, 600, 5000):
        wo, out = host_array(np.full(1001, np.nan))
        host_launch(_scale_rows_part, 1001, args + [wo], split=True, min_part=min_part)
        assert np.array_equal(out, whole)  # every item written, the same bits
    expected = [sum(x[ids[i]] * 1.5 / (k + 1) for k in range(i % 7 + 1)) for i in range(1001)]
    assert np.allclose(whole, expected, rtol=1e-12)


def test_part_bounds_cut_on_the_quantum_and_cover_the_range():
    assert part_bounds(1000, 2, 256) == [(0, 512), (512, 1000)]
    assert part_bounds(10, 3) == [(0, 3), (3, 6), (6, 10)]
    assert part_bounds(100, 4, 256) == [(0, 100)]  # one chunk: one part
    for count, parts, quantum in [(1, 2, 1), (7, 16, 1), (4097, 3, 256), (513, 2, 256)]:
        b = part_bounds(count, parts, quantum)
        assert b[0][0] == 0 and b[-1][1] == count and len(b) <= parts
        assert all(hi == lo2 for (_, hi), (lo2, _) in zip(b[:-1], b[1:]))
        assert all(lo % quantum == 0 for lo, _ in b)


def test_run_parts_runs_every_range_and_raises_a_parts_error(monkeypatch):
    monkeypatch.setenv("GEOSYNTH_HOST_THREADS", "2")
    seen = []
    run_parts(lambda lo, hi: seen.append((lo, hi)), 10)
    assert sorted(seen) == [(0, 5), (5, 10)]
    seen.clear()
    run_parts(lambda lo, hi: seen.append((lo, hi)), 10, min_part=8)  # too small for two parts
    assert seen == [(0, 10)]

    def fail(lo, hi):
        if lo > 0:
            raise RuntimeError("part two failed")

    with pytest.raises(RuntimeError, match="part two failed"):
        run_parts(fail, 10)
    monkeypatch.setenv("GEOSYNTH_HOST_THREADS", "zero")
    with pytest.raises(ValueError, match="GEOSYNTH_HOST_THREADS must be a whole number"):
        host_threads()
