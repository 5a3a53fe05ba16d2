"""Which partly captured surfaces complete with no input file? Procedural stand-ins for the
captures of Breckon and Fisher, "Plausible 3D colour surface completion using
non-parametric techniques": Fig. 1 (a golf ball), Fig. 8 (wave and noise reliefs on
planes), Figs. 9, 11, 12 (tree bark on a cylinder) and Fig. 10 (the tower of Pisa: rows of
arches on a cylinder).

Each example is generated on the whole object and then cut: :func:`completion_example`
returns the captured part as a :class:`~geosynth.completion.prep.Capture` (positions, colours,
no faces: they are triangulated over the fit) and the hidden part's ground truth for
comparison, with the fit and region to complete.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geosynth.completion.prep import Capture

__all__ = ["COMPLETION_EXAMPLES", "CompletionExample", "completion_example"]


@dataclass
class CompletionExample:
    """A built-in capture.

    Attributes:
        name: the example's name.
        capture: the captured part.
        hidden: (M, 3) float64 positions of the part left out (the ground truth), with
            ``hidden_colors`` (M, 3) uint8.
        fit: the fit to use ("plane", "sphere", "cylinder").
        region: the region to complete (None: the fit's default).
        note: what it stands for.

    The scene only: no method settings. A built-in gets what a user's file gets, the settings
    :func:`geosynth.completion.synthesis.choose_settings` measures and chooses (issue 32).
    """

    name: str
    capture: Capture
    hidden: np.ndarray
    hidden_colors: np.ndarray
    fit: str
    region: tuple | None
    note: str


def _hex_grid(width: float, height: float, delta: float) -> np.ndarray:
    dy = delta * math.sqrt(3) / 2
    j, i = np.mgrid[0:int(height / dy) + 1, 0:int(width / delta) + 1]
    x = (i + 0.5 * (j % 2)) * delta
    y = j * dy
    q = np.stack([x.ravel(), y.ravel()], 1)
    return q[(q[:, 0] <= width + 1e-9)]


def _colour_ramp(t: np.ndarray, low, high, rng, noise: float) -> np.ndarray:
    t = np.clip(t, 0, 1)[:, None]
    c = (1 - t) * np.asarray(low, float) + t * np.asarray(high, float)
    c = c + rng.normal(0, noise, (len(t), 1)) + rng.normal(0, noise / 3, c.shape)
    return np.clip(np.round(c), 0, 255).astype(np.uint8)


def _split(name, points, colors, captured, fit, region, note) -> CompletionExample:
    return CompletionExample(name, Capture(points[captured], colors[captured]), points[~captured], colors[~captured],
                             fit, region, note)


def _plane_example(name: str, height_fn, seed: int, size: float, delta: float, keep: float,
                   note: str) -> CompletionExample:
    rng = np.random.default_rng(seed)
    q = _hex_grid(size, size * 0.75, delta)
    h = height_fn(q, rng)
    span = max(float(np.ptp(h)), 1e-9)
    colors = _colour_ramp((h - h.min()) / span, (70, 90, 140), (220, 200, 150), rng, 6.0)
    points = np.stack([q[:, 0], q[:, 1], h], 1)
    captured = q[:, 0] < keep * size
    region = ((0.0, size), (0.0, size * 0.75))
    return _split(name, points, colors, captured, "plane", region, note)


def wave_example(seed: int = 0, delta: float = 0.05) -> CompletionExample:
    """A plane with a periodic wave relief (Fig. 8 top): h = A cos(2 pi x / L), A = 0.08, L = 0.5
    (even about the capture's centre, so that the least-squares plane is level)."""
    return _plane_example("wave", lambda q, rng: 0.08 * np.cos(2 * math.pi * q[:, 0] / 0.5), seed, 2.0, delta, 0.5,
                          "plane, sine wave relief (Fig. 8)")


def noise_example(seed: int = 0, delta: float = 0.05) -> CompletionExample:
    """A plane with a band-limited noise relief (Fig. 8 bottom): a sum of random Gaussian bumps."""
    def heights(q, rng):
        centres = rng.uniform(-0.2, 2.2, (160, 2))
        amp = rng.normal(0, 0.05, 160)
        width = rng.uniform(0.06, 0.14, 160)
        d2 = ((q[:, None, :] - centres[None]) ** 2).sum(2)
        return (amp * np.exp(-d2 / (2 * width ** 2))).sum(1)
    return _plane_example("noise", heights, seed, 2.0, delta, 0.45, "plane, stochastic bump relief (Fig. 8)")


def flat_example(seed: int = 0, delta: float = 0.05) -> CompletionExample:
    """A flat plane with noisy colours only: completes flat."""
    return _plane_example("flat", lambda q, rng: np.zeros(len(q)), seed, 1.2, delta, 0.5, "a flat plane")


def _fibonacci(count: int) -> np.ndarray:
    k = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * k / count)
    az = math.pi * (1 + math.sqrt(5)) * k
    return np.stack([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar)], 1)


def golf_example(seed: int = 0, delta: float = 0.065, dimples: int = 72) -> CompletionExample:
    """A golf ball (Fig. 1): a unit sphere with spherical dimples on a Fibonacci layout,
    white with grey dimple floors; the cap above 50 degrees of latitude is missing."""
    rng = np.random.default_rng(seed)
    count = int(4 * math.pi / (delta * delta * math.sqrt(3) / 2))
    d = _fibonacci(count)
    centres = _fibonacci(dimples)
    # d . centre in a fixed order, elementwise (BLAS's d @ centres.T rounds by the CPU: 158
    # coordinates of the default capture moved under SSE4; issue 40)
    cosang = np.clip(d[:, None, 0] * centres[None, :, 0] + d[:, None, 1] * centres[None, :, 1]
                     + d[:, None, 2] * centres[None, :, 2], -1, 1)
    ang = np.arccos(cosang.max(1))
    radius = 0.55 * math.sqrt(4 * math.pi / dimples) / 2 * 1.6
    depth = 0.035
    inside = ang < radius
    h = np.where(inside, -depth * (1 - (ang / radius) ** 2), 0.0)
    points = d * (1 + h)[:, None]
    colors = _colour_ramp(1 - (-h / depth), (170, 172, 180), (242, 242, 236), rng, 3.0)
    captured = d[:, 2] < math.sin(math.radians(50))
    return _split("golf", points, colors, captured, "sphere", None, "golf ball, a cap missing (Fig. 1)")


def _cylinder_lattice(delta: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """(angles, heights) of a hexagonal lattice of spacing ``delta`` on a unit cylinder
    of the given height (rows dz = delta * sqrt(3) / 2 apart, odd rows offset by half)."""
    n_a = int(2 * math.pi / delta)
    dz = delta * math.sqrt(3) / 2
    j, i = np.mgrid[0:int(height / dz) + 1, 0:n_a]
    return ((i + 0.5 * (j % 2)) * 2 * math.pi / n_a).ravel(), (j * dz).ravel()


def bark_example(seed: int = 0, delta: float = 0.06, height: float = 1.6, fraction: float = 0.5) -> CompletionExample:
    """Tree bark (Figs. 9, 11, 12): a unit cylinder with wandering ridges and cracks along
    the axis and bark colours (dark cracks, lighter grey-brown ridges); ``fraction`` of the
    circumference captured (default half)."""
    rng = np.random.default_rng(seed)
    a, z = _cylinder_lattice(delta, height)
    h = np.zeros_like(a)
    ridges = 22
    for k in range(ridges):
        a0 = 2 * math.pi * (k + rng.uniform(-0.3, 0.3)) / ridges
        wob = 0.08 * np.sin(2 * math.pi * z / rng.uniform(0.8, 2.0) + rng.uniform(0, 2 * math.pi))
        dist = np.angle(np.exp(1j * (a - a0 - wob)))
        w = rng.uniform(0.06, 0.1)
        h += rng.uniform(0.03, 0.05) * np.exp(-(dist / w) ** 2)
    # cracks: short breaks across the ridges
    for _ in range(int(round(60 * height / 1.6))):
        ac, zc = rng.uniform(0, 2 * math.pi), rng.uniform(0, height)
        dist_a = np.angle(np.exp(1j * (a - ac)))
        h -= 0.03 * np.exp(-(dist_a / 0.12) ** 2 - ((z - zc) / 0.03) ** 2)
    h += rng.normal(0, 0.002, len(h))
    t = (h - h.min()) / max(float(np.ptp(h)), 1e-9)
    colors = _colour_ramp(t, (52, 34, 22), (150, 128, 104), rng, 8.0)
    r = 1 + h
    points = np.stack([r * np.cos(a), r * np.sin(a), z], 1)
    captured = a < 2 * math.pi * fraction
    return _split("bark", points, colors, captured, "cylinder", None,
                  "tree bark on a cylinder, half missing (Figs. 9, 11, 12)")


def tower_example(seed: int = 0, delta: float = 0.055, height: float = 1.8) -> CompletionExample:
    """A tower (Fig. 10): a unit cylinder with rows of recessed round-topped arches and
    raised ledges between the rows, stone colours with dark arch recesses; half the
    circumference captured."""
    rng = np.random.default_rng(seed)
    a, z = _cylinder_lattice(delta, height)
    arches, row = 12, 0.6
    s = a * 12 / (2 * math.pi)  # arch coordinate, one arch per unit
    x = (s % 1.0) - 0.5  # -0.5..0.5 across an arch
    zr = (z % row) / row  # 0..1 up a row
    half = 0.3
    body = (np.abs(x) < half) & (zr > 0.15) & (zr < 0.65)
    top = ((zr >= 0.65) & ((x / half) ** 2 + ((zr - 0.65) / 0.2) ** 2 < 1))
    arch = body | top
    ledge = zr < 0.08
    h = np.where(arch, -0.05, 0.0) + np.where(ledge, 0.03, 0.0) + rng.normal(0, 0.0015, len(a))
    base = np.where(arch, 0.2, np.where(ledge, 1.0, 0.75))
    colors = _colour_ramp(base, (70, 62, 55), (228, 218, 196), rng, 5.0)
    r = 1 + h
    points = np.stack([r * np.cos(a), r * np.sin(a), z], 1)
    captured = a < math.pi
    assert arches == 12
    return _split("tower", points, colors, captured, "cylinder", None,
                  "tower with rows of arches, half missing (Fig. 10)")


COMPLETION_EXAMPLES = {
    "golf": golf_example,
    "bark": bark_example,
    "wave": wave_example,
    "noise": noise_example,
    "tower": tower_example,
    "flat": flat_example,
}


def completion_example(name: str, seed: int = 0, **options) -> CompletionExample:
    """A built-in capture by name (see :data:`COMPLETION_EXAMPLES`)."""
    make = COMPLETION_EXAMPLES.get(name)
    if make is None:
        raise ValueError(f"unknown completion example {name!r}; choose one of {', '.join(COMPLETION_EXAMPLES)}.")
    return make(seed=seed, **options)
