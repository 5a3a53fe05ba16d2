"""geosynth.completion.spectrum: period, orientation, amplitude and anisotropy of gridded reliefs (issue 32)."""

import math

import numpy as np
import pytest

from geosynth.completion.spectrum import heights_on_grid, relief_spectrum


def _wave(h, w, sx, sy, period, deg, phase=0.7):
    y, x = np.mgrid[0:h, 0:w]
    a = math.radians(deg)
    return np.sin(2 * np.pi * (x * sx * math.cos(a) + y * sy * math.sin(a)) / period + phase)


@pytest.mark.parametrize("shape,spacing", [((64, 96), 0.05), ((80, 60), (0.03, 0.05))])
@pytest.mark.parametrize("deg", [0.0, 27.0, 90.0, 150.0])
def test_sinusoid_period_angle_amplitude(shape, spacing, deg):
    sx, sy = (spacing, spacing) if np.ndim(spacing) == 0 else spacing
    rng = np.random.default_rng(int(deg))
    period = float(rng.uniform(0.35, 0.7))
    z = 0.3 * _wave(*shape, sx, sy, period, deg) + 0.2 * np.mgrid[0:shape[0], 0:shape[1]][1] * sx  # + a tilt
    r = relief_spectrum(z, spacing)
    assert abs(r.period / period - 1) < 0.03
    assert abs((math.degrees(r.angle) - deg + 90) % 180 - 90) < 3
    assert 0 <= r.angle < math.pi
    assert abs(r.amplitude / (0.3 / math.sqrt(2)) - 1) < 0.05  # the tilt is detrended away
    assert r.anisotropy > 0.9


def test_noise_is_isotropic_and_mask_respected():
    rng = np.random.default_rng(3)
    for seed in range(3):
        z = np.random.default_rng(seed).normal(size=(96, 96))
        assert relief_spectrum(z, 0.1).anisotropy < 0.15
    # a masked-out corner of garbage changes nothing much
    z = 0.1 * _wave(64, 64, 0.05, 0.05, 0.5, 60.0)
    m = np.ones_like(z, bool)
    m[:10, :10] = False
    z2 = z.copy()
    z2[:10, :10] = rng.normal(size=(10, 10)) * 5
    z2[0, 0] = np.nan
    r = relief_spectrum(z2, 0.05, m)
    assert abs(r.period / 0.5 - 1) < 0.03 and abs(math.degrees(r.angle) - 60) < 3
    assert math.isnan(relief_spectrum(np.zeros((16, 16)), 1.0).period)
    with pytest.raises(ValueError, match="4 x 4"):
        relief_spectrum(np.zeros((3, 8)), 1.0)


def test_scattered_knurl_on_grid():
    """A half cylinder's knurl, sin(12 theta) sin(2 pi z) at r = 1: two mirrored diagonals, one answer."""
    rng = np.random.default_rng(1)
    th = rng.uniform(0, np.pi, 8000)
    zz = rng.uniform(0, 2, 8000)
    g, m = heights_on_grid(np.stack([th, zz], 1), 0.04 * np.sin(12 * th) * np.sin(2 * np.pi * zz), 0.02)
    assert g.shape == (int(np.floor(np.ptp(zz) / 0.02)) + 1, int(np.floor(np.ptp(th) / 0.02)) + 1)
    assert m.mean() > 0.95 and np.isnan(g[~m]).all()
    r = relief_spectrum(g, 0.02, m)
    expect = 1 / math.hypot(12 / (2 * np.pi), 1)
    assert abs(r.period / expect - 1) < 0.03
    assert abs(math.degrees(r.angle) - math.degrees(math.atan2(1, 12 / (2 * np.pi)))) < 3
    assert abs(r.amplitude - 0.02) < 0.002 and 0.4 < r.anisotropy < 0.7


def _gaussian_bumps(n: int, sigma: float, count: int, seed: int) -> np.ndarray:
    """(n, n) heights: ``count`` Gaussian bumps of ``sigma`` cells at random places and heights."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    z = np.zeros((n, n))
    for (cx, cy), hgt in zip(rng.uniform(0, n, (count, 2)), rng.uniform(0.5, 1.0, count)):
        z += hgt * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))
    return z


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_correlation_length_is_the_bumps_size_not_their_spacing(seed):
    """Sparse Gaussian bumps of sigma: their autocorrelation is a Gaussian of variance 2 sigma^2,
    1/2 at 2 sqrt(ln 2) sigma, whatever their spacing (which the spectrum's peak reports)."""
    from geosynth.completion.spectrum import correlation_length

    sigma = 4.0
    expected = 2 * math.sqrt(math.log(2)) * sigma
    sparse = _gaussian_bumps(160, sigma, 30, seed)
    assert abs(correlation_length(sparse, 1.0) / expected - 1) < 0.12
    assert abs(correlation_length(sparse, 0.05) / (0.05 * expected) - 1) < 0.12  # world units
    denser = _gaussian_bumps(160, sigma, 90, seed)
    assert abs(correlation_length(denser, 1.0) / correlation_length(sparse, 1.0) - 1) < 0.15
    assert relief_spectrum(sparse, 1.0).period > 3 * expected  # the spectrum's peak reads the bumps' spacing
    mask = np.ones_like(sparse, bool)
    mask[:, 100:] = False
    half = correlation_length(np.where(mask, sparse, 1e3), 1.0, mask)  # the masked garbage is not read
    assert abs(half / expected - 1) < 0.2
    assert math.isnan(correlation_length(np.zeros((32, 32)), 1.0))
