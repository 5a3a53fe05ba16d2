"""geosynth.host_steps: the compiled host steps' wrappers (Warp's cpu device for every run):
zero-copy views both ways, empty arrays, dtypes, and a launch that writes into NumPy memory."""

from __future__ import annotations

import gc

import numpy as np
import pytest
import warp as wp

from geosynth.host_steps import host_array, host_launch


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
