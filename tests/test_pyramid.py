"""Block pyramids on every present device against the NumPy oracles (exact integers)."""

from __future__ import annotations

import numpy as np
import pytest

from geosynth.volume import reference
from geosynth.volume.examples import spheres_field
from geosynth.volume.pyramid import build_pyramid, compare_level
from geosynth.volume.synthesis import quantize_field


def _real_field(size: int = 24) -> np.ndarray:
    return quantize_field(spheres_field(size, count=8, radius=(2.0, 5.0), seed=2), 4.0)


@pytest.mark.parametrize("kind", ["random", "real"])
@pytest.mark.parametrize("block", [2, 8])
def test_pyramid_levels_match_oracle(device, rng, kind, block):
    field = rng.integers(0, 256, (13, 17, 15), dtype=np.uint8) if kind == "random" else _real_field()
    pyr = build_pyramid(field, block, device=device)
    assert pyr.levels == block.bit_length()
    cell = 1
    while cell <= block:
        np.testing.assert_array_equal(pyr.cell_sums(cell), reference.box_sums_naive(field, cell), err_msg=f"cell {cell}")
        np.testing.assert_array_equal(pyr.means(cell), reference.box_means_naive(field, cell), err_msg=f"cell {cell}")
        cell *= 2
    np.testing.assert_array_equal(pyr.means(1), field)


@pytest.mark.parametrize("block", [4, 8])
def test_compare_level_matches_oracle(device, rng, block):
    field = rng.integers(0, 256, (14, 12, 13), dtype=np.uint8)
    pyr = build_pyramid(field, block, device=device)
    query = rng.integers(0, 256, (block,) * 3, dtype=np.uint8)
    origins = rng.integers(0, np.array(field.shape) - block + 1, (50, 3))
    for level in range(1, pyr.levels + 1):
        got = compare_level(pyr, query, origins, level)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, reference.compare_level_naive(field, query, origins, level))
        if level < pyr.levels:
            rounded = compare_level(pyr, query, origins, level, rounded=True)
            np.testing.assert_array_equal(rounded, reference.compare_level_naive(field, query, origins, level, True))
            assert (rounded <= got).all()  # the parent-node bound is weaker
    # the last level is the exact SSD; every coarser level, divided by c^3, bounds it (eq. 2)
    ssd = compare_level(pyr, query, origins, pyr.levels)
    for level in range(1, pyr.levels):
        c3 = (block >> (level - 1)) ** 3
        assert (compare_level(pyr, query, origins, level) / c3 <= ssd).all()


def test_pyramid_invalid_input(one_device):
    field = np.zeros((8, 8, 8), np.uint8)
    with pytest.raises(ValueError, match="power of two"):
        build_pyramid(field, 6, device=one_device)
    with pytest.raises(ValueError, match="larger than the source"):
        build_pyramid(field, 16, device=one_device)
    with pytest.raises(TypeError, match="uint8"):
        build_pyramid(field.astype(np.float32), 4, device=one_device)
    with pytest.raises(ValueError, match="3-D"):
        build_pyramid(np.zeros((8, 8), np.uint8), 4, device=one_device)
    pyr = build_pyramid(field, 4, device=one_device)
    with pytest.raises(ValueError, match="shape"):
        compare_level(pyr, np.zeros((2, 2, 2), np.uint8), np.zeros((1, 3), int), 1)
    with pytest.raises(ValueError, match="level"):
        compare_level(pyr, np.zeros((4, 4, 4), np.uint8), np.zeros((1, 3), int), 4)
    with pytest.raises(ValueError, match="inside the field"):
        compare_level(pyr, np.zeros((4, 4, 4), np.uint8), np.array([[5, 0, 0]]), 1)
    with pytest.raises(ValueError, match="cell"):
        pyr.means(3)


def test_pyramid_memory_refused(monkeypatch, one_device):
    import geosynth.volume.pyramid as pyramid

    monkeypatch.setattr(pyramid, "available_memory", lambda: 1000)
    with pytest.raises(MemoryError, match=r"estimated [0-9.]+ MiB"):
        build_pyramid(np.zeros((16, 16, 16), np.uint8), 4, device=one_device)
