"""The one resampler (geosynth.core.interpolate), the one quantizer and the mesh components."""

import numpy as np
import pytest

from geosynth.core.interpolate import lerp_axis, linear_taps
from geosynth.geometry.meshes import _components, orient_faces
from geosynth.io.pictures import _bilinear
from geosynth.texturing.textures import sample_bilinear_grid
from geosynth.volume.synthesis import dequantize_field, quantize_field, upsample


def test_linear_taps_edges():
    i0, i1, t = linear_taps([-0.5, 0.0, 1.25, 3.0, 3.5], 4, wrap=False)
    np.testing.assert_array_equal(i0, [0, 0, 1, 3, 3])
    np.testing.assert_array_equal(i1, [1, 1, 2, 3, 3])
    np.testing.assert_array_equal(t, [0.0, 0.0, 0.25, 0.0, 0.0])  # clamped first: edge samples exactly
    i0, i1, t = linear_taps([-0.25, 3.25], 4, wrap=False, dtype=np.float32, clamp="taps")
    np.testing.assert_array_equal(i0, [0, 3])
    np.testing.assert_array_equal(i1, [0, 3])
    np.testing.assert_array_equal(t, np.float32([0.75, 0.25]))
    assert t.dtype == np.float32
    i0, i1, t = linear_taps([-0.25, 3.5], 4, wrap=True)
    np.testing.assert_array_equal(i0, [3, 3])
    np.testing.assert_array_equal(i1, [0, 0])
    np.testing.assert_array_equal(t, [0.75, 0.5])
    with pytest.raises(ValueError, match="clamp"):
        linear_taps([0.0], 4, False, clamp="edge")


def test_lerp_axis_values():
    v = np.array([[0.0, 10.0], [20.0, 30.0]])
    out = lerp_axis(v, 1, linear_taps([0.0, 0.25, 1.0], 2, False))
    np.testing.assert_array_equal(out, [[0.0, 2.5, 10.0], [20.0, 22.5, 30.0]])
    out = lerp_axis(v, 0, linear_taps([0.5], 2, False))
    np.testing.assert_array_equal(out, [[10.0, 20.0]])


def _upsample_before(values, shape, wrap):
    """The volume upsampling as it was written before the shared resampler (the bits to keep)."""
    out = values.astype(np.float32)
    for axis, n in enumerate(shape):
        m = out.shape[axis]
        pos = (np.arange(n) + 0.5) * m / n - 0.5
        lo = np.floor(pos).astype(np.int64)
        t = (pos - lo).astype(np.float32)
        hi = lo + 1
        lo, hi = (lo % m, hi % m) if wrap else (np.clip(lo, 0, m - 1), np.clip(hi, 0, m - 1))
        shape_t = [1] * out.ndim
        shape_t[axis] = n
        t = t.reshape(shape_t)
        out = np.take(out, lo, axis=axis) * (1 - t) + np.take(out, hi, axis=axis) * t
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("wrap", [False, True])
def test_upsample_bits_unchanged(wrap):
    rng = np.random.default_rng(4)
    for _ in range(60):
        m = rng.integers(1, 9, 3)
        shape = [int(2 * k + rng.integers(0, 2)) for k in m]  # the pyramid's shapes: 2n or 2n + 1
        v = rng.integers(0, 256, tuple(m)).astype(np.uint8)
        np.testing.assert_array_equal(upsample(v, shape, wrap), _upsample_before(v, shape, wrap))


def test_picture_slices_use_the_texture_lookup():
    rng = np.random.default_rng(5)
    img = rng.normal(size=(7, 5))
    for factor in (1, 2, 3):
        coords = [(np.arange(n * factor) + 0.5) / factor - 0.5 for n in img.shape]
        expected = sample_bilinear_grid(img[:, :, None], coords[0], coords[1], False)[:, :, 0]
        np.testing.assert_array_equal(_bilinear(img, factor), expected)
    np.testing.assert_array_equal(_bilinear(img, 1), img)


def test_quantize_field():
    q = quantize_field(np.array([-5.0, -2.0, 0.0, 2.0, 9.0]), 2.0)
    np.testing.assert_array_equal(q, [0, 0, 128, 255, 255])
    assert q.dtype == np.uint8
    d = dequantize_field(quantize_field(np.linspace(-1.9, 1.9, 50), 2.0), 2.0)
    assert np.abs(d - np.linspace(-1.9, 1.9, 50)).max() <= 2.0 / 255 + 1e-6
    with pytest.raises(ValueError, match="band must be > 0"):
        quantize_field(np.zeros(3), 0.0)


def test_components_and_orientation():
    labels = _components(6, np.array([4, 1, 5]), np.array([2, 4, 3]))
    np.testing.assert_array_equal(labels, [0, 1, 1, 2, 1, 2])  # numbered by each component's smallest node
    assert labels.dtype == np.int64
    # two separate triangles, one flipped and inside-out-free (open): each keeps its own orientation
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 0, 0], [6, 0, 0], [5, 1, 0]], float)
    f = np.array([[0, 1, 2], [3, 5, 4]])
    np.testing.assert_array_equal(orient_faces(v, f), f)
