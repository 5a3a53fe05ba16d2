"""geosynth.volume.features on analytic fields of known size (issue #32)."""

import math

import numpy as np
import pytest

from geosynth.volume.features import ElementFeatures, compare_features, element_features, format_features

Z, Y, X = np.mgrid[0:24, 0:64, 0:64].astype(np.float32)


def spheres(radius: float, spacing: float = 0.1, shift=(0.0, 0.0, 0.0), grid: int = 16) -> np.ndarray:
    """Spheres of ``radius`` samples on a ``grid``-sample lattice, off the sample lattice, in world units."""
    cz, cy, cx = Z - 11.6 - shift[0], (Y - shift[1]) % grid - grid / 2 + 0.3, (X - shift[2]) % grid - grid / 2 + 0.3
    return (np.sqrt(cz**2 + cy**2 + cx**2) - radius) * np.float32(spacing)


@pytest.mark.parametrize("radius", [2.5, 4.0, 5.5])
def test_spheres_of_known_radius(radius):
    f = element_features(spheres(radius), spacing=0.1)
    d = 2 * radius * 0.1
    # the 2 x 2 inside ones are whole: the others reach the material's sides, where an output is cut
    assert f.count == 16 and f.whole_fraction == 0.25 and not f.relief
    assert f.diameter == pytest.approx(d, rel=0.06)
    assert f.height == pytest.approx(d, rel=0.06)
    assert f.thickness == pytest.approx(d, rel=0.06)


@pytest.mark.parametrize("grid", [12, 16])
def test_period_of_a_lattice(grid):
    f = element_features(spheres(3.0, grid=grid), spacing=0.1)
    assert f.period == pytest.approx(grid * 0.1, rel=0.08)
    assert f.diameter == pytest.approx(0.6, rel=0.06)


@pytest.mark.parametrize("radius", [1.5, 2.5, 4.0])
def test_tube_of_known_radius(radius):
    f = element_features(np.sqrt((Y - 31.6) ** 2 + (Z - 11.3) ** 2) - np.float32(radius))
    assert f.count == 1 and f.whole_fraction == 0.0  # it runs across the grid
    assert f.thickness == pytest.approx(2 * radius, rel=0.1)
    assert f.height == pytest.approx(2 * radius, rel=0.1)


def test_cut_spheres_are_not_whole():
    f = element_features(spheres(4.0, shift=(0, 8, 8)), spacing=0.1)  # centres on the borders
    assert f.whole_fraction < 0.6


def test_relief_bumps_and_height():
    cy, cx = Y % 16 - 7.7, X % 16 - 8.3
    widths = []
    for r in (3.0, 5.0):
        field = np.minimum(Z - 6.3, np.sqrt(cy**2 + cx**2 + (Z - 6.3) ** 2) - r)
        f = element_features(field)
        assert f.relief and f.count == 16 and len(f.sizes) == 16
        assert f.sizes[0] == pytest.approx(math.pi * 0.75 * r * r, rel=0.2)  # the disc at half height
        widths.append(f.diameter)
    assert widths[1] / widths[0] == pytest.approx(5 / 3, rel=0.15)
    low = element_features(np.minimum(Z - 6.3, np.sqrt(cy**2 + cx**2 + (Z - 6.3) ** 2) - 3.0))
    high = element_features(np.minimum(Z - 6.3, np.sqrt(cy**2 + cx**2 + (Z - 6.3) ** 2) - 5.0))
    assert high.height > 1.5 * low.height


@pytest.mark.parametrize("period", [10.0, 16.0, 24.0])
def test_terrain_period(period):
    h = 8 + 3 * np.sin(2 * np.pi * X[0] / period)
    f = element_features(Z - h[None])
    assert f.relief
    assert f.period == pytest.approx(period, rel=0.08)
    assert f.height == pytest.approx(3 / math.sqrt(2), rel=0.08)


def test_compare_and_format():
    a = element_features(spheres(4.0), spacing=0.1)
    b = element_features(spheres(3.0), spacing=0.1)
    r = compare_features(a, b)
    assert set(r) >= {"diameter", "height", "thickness", "period", "whole_fraction"}
    assert r["diameter"] == pytest.approx(0.75, rel=0.08)
    assert r["whole_fraction"] == pytest.approx(1.0)
    assert "diameter" in format_features(a, b)
    empty = element_features(np.ones((8, 16, 16), np.float32))
    assert isinstance(empty, ElementFeatures) and empty.count == 0
    assert math.isnan(compare_features(empty, a)["diameter"])


def _torus(cy: float, cx: float, major: float = 6.0, minor: float = 1.6) -> np.ndarray:
    """A flat ring (torus about z) centred at (11.3, cy, cx), distances in samples."""
    ring = np.sqrt((Y - cy) ** 2 + (X - cx) ** 2) - major
    return np.sqrt(ring**2 + (Z - 11.3) ** 2) - np.float32(minor)


def test_loops_count_rings_and_their_fusions():
    """A ring is one loop, a ball none; two rings fused where they overlap make three (issue 32: a
    linked knit whose rings fuse into a finer mesh of arcs holds more loops than the exemplar)."""
    def box(inside):  # the (y, x) bounding box's area in samples
        rows, cols = np.flatnonzero(inside.any(axis=(0, 2))), np.flatnonzero(inside.any(axis=(0, 1)))
        return (rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1)

    rings = [_torus(20.3, 20.7), _torus(20.3, 44.2)]
    apart = np.minimum(*rings)
    fused = np.minimum(_torus(20.3, 20.7, 8.0, 1.2), _torus(20.3, 30.7, 8.0, 1.2))  # a lens 3.6 samples wide
    ball = np.sqrt((Z - 11.3) ** 2 + (Y - 31.6) ** 2 + (X - 30.2) ** 2) - np.float32(5.0)
    for field, loops in ((rings[0], 1), (apart, 2), (fused, 3), (ball, 0)):
        f = element_features(field)
        assert f.loops == pytest.approx(loops / box(field < 0), rel=1e-6), (loops, f)
    assert compare_features(element_features(apart), element_features(fused))["loops"] > 1


def test_a_network_has_no_element_diameter():
    """One component across the footprint (tubes, linked rings) has no element size; a speck of
    debris beside it is not its element."""
    tube = np.sqrt((Y - 31.6) ** 2 + (Z - 11.3) ** 2) - np.float32(2.5)
    assert math.isnan(element_features(tube).diameter)
    speck = np.sqrt((Z - 20.5) ** 2 + (Y - 31.6) ** 2 + (X - 30.2) ** 2) - np.float32(1.5)  # above it
    with_speck = element_features(np.minimum(tube, speck))
    assert with_speck.diameter == pytest.approx(3.0, rel=0.1)  # the speck is whole: read as an element
    assert math.isnan(compare_features(element_features(tube), with_speck)["diameter"])
