"""Outputs pinned by hash: one small volume synthesis and three small point texturings.

The hashes were recorded from the code before the modules were restructured (search and
texturing split into one question per module) and are the outputs of the current
algorithms: synthesize_volume's paper method (the cascade and the tree search, which
must agree), texture_points' hybrid, multiresolution matching and coherent hybrid. A change
that moves code must leave them as they are; re-record a hash only in a change that
means to change that output, and say so in its message.

Both M1 searches and every M3 method are exact integer searches with seeded random
choices, so every device gives the same bytes: each case runs on every test device
against the one recorded hash.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from geosynth.examples import exemplar_field
from geosynth.pointmodels import point_model
from geosynth.textures import texture_example
from geosynth.texturing import texture_points
from geosynth.volume import synthesize_volume


def _digest(*arrays: np.ndarray) -> str:
    """First 16 hex digits of the SHA-256 of the arrays' dtypes, shapes and bytes."""
    d = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        d.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return d.hexdigest()[:16]


@pytest.fixture(scope="module")
def balls_source() -> np.ndarray:
    return exemplar_field("balls", resolution=32, seed=0, device="cpu").values


@pytest.mark.parametrize("search", ["cascade", "tree"])
def test_volume_synthesis_output_unchanged(device, balls_source, search):
    result = synthesize_volume(balls_source, 32, levels=2, block=8, seed=0, device=device, search=search,
                               method="paper", progress=False)
    assert result.quantized.shape == (32, 32, 32)
    assert _digest(result.quantized, result.field.values) == "202341cbd84c47e2"


@pytest.mark.parametrize("options, expected", [
    ({}, "ebe4eb4ff5beaeab"),
    ({"method": "match", "levels": 2}, "01ae93c9559e6cf8"),
    ({"method": "hybrid", "levels": 2, "coherent": True}, "f43b86d9350af3b8"),
])
def test_point_texturing_output_unchanged(device, options, expected):
    points = point_model("sphere", 2000, seed=0)
    texture = texture_example("bricks", 32, seed=0)
    out, report = texture_points(points, texture, seed=0, device=device, quality_samples=50, **options)
    assert out.colors.shape == (2000, 3)
    errors = np.array(sorted(report.error.items()), dtype=object).astype(str)  # exact float reprs
    assert _digest(out.colors, errors) == expected
