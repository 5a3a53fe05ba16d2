"""M1's settings in one VolumeOptions (issue 33 item 2): each setting refused when the object
is made, frozen, the options object and the keywords give the same bits on every entry point,
not both at once, tiles only where the run is tiled."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import ONE_DEVICE
from geosynth.volume.options import TileOptions, VolumeOptions

RNG = np.random.default_rng(7)


@pytest.mark.parametrize("bad, error, words", [
    (dict(levels=0), ValueError, "levels must be an integer >= 1, got 0"),
    (dict(levels=1.5), TypeError, "levels must be an integer"),
    (dict(block=8.5), TypeError, r"block must be an integer \(a power of two >= 2\)"),
    (dict(block=6), ValueError, "block sizes must be powers of two"),
    (dict(block=[4, 8], levels=3), ValueError, "block must be one size or one per level"),
    (dict(tileable="no"), TypeError, "tileable must be True or False"),
    (dict(search="fast"), ValueError, "search must be one of cascade, tree, linear"),
    (dict(method="best"), ValueError, "method must be one of paper, graphcut, optimize or auto"),
    (dict(iterations=[2, 2], levels=3), ValueError, r"iterations must be a positive integer or one per level \(3\)"),
    (dict(iterations=0), ValueError, "iterations must be a positive integer"),
    (dict(slab="yes"), TypeError, "slab must be True or False"),
    (dict(lattice="yes"), TypeError, "lattice must be True or False"),
    (dict(band=0), ValueError, "band must be a finite number from 1e-15"),
    (dict(smooth=-1), ValueError, "smooth must be an integer >= 0"),
    (dict(source_resolution=7), ValueError, "source_resolution must be an integer >= 8"),
    (dict(quality_samples=1.5), TypeError, "quality_samples must be an integer >= 0"),
    (dict(tiles=(2, 2)), TypeError, "tiles must be a TileOptions or None"),
])
def test_each_bad_setting_is_refused_when_made(bad, error, words):
    with pytest.raises(error, match=words):
        VolumeOptions(**bad)


@pytest.mark.parametrize("bad, error, words", [
    (dict(tiles="4by4"), ValueError, "tiles must be NXxNY"),
    (dict(tiles=(0, 2)), ValueError, "tiles must be at least 1 x 1"),
    (dict(workers=0), ValueError, "workers must be an integer >= 1"),
    (dict(margin=2.5), TypeError, "margin must be an integer >= 0"),
    (dict(coarse_whole=1), TypeError, "coarse_whole must be True or False"),
    (dict(phases=4), ValueError, "phases must be 1, 2 or 3"),
])
def test_each_bad_tiling_is_refused_when_made(bad, error, words):
    with pytest.raises(error, match=words):
        TileOptions(**bad)


def test_options_are_frozen_and_tiles_read_as_a_pair():
    opts = VolumeOptions(levels=2, block=8)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.levels = 3  # type: ignore[misc]
    assert TileOptions(tiles="3x2").tiles == (3, 2) and TileOptions(tiles=4).tiles == (4, 4)
    assert VolumeOptions().tiling == TileOptions()


def test_options_and_keywords_give_the_same_volume():
    from geosynth.volume.synthesis import synthesize_volume

    source = RNG.standard_normal((16, 16, 16)).astype(np.float32)
    run = dict(seed=2, device=ONE_DEVICE, progress=False)
    a = synthesize_volume(source, 16, levels=2, block=8, iterations=1, method="optimize", **run)
    b = synthesize_volume(source, 16, options=VolumeOptions(levels=2, block=8, iterations=1, method="optimize"), **run)
    assert np.array_equal(a.quantized, b.quantized) and a.settings == b.settings
    with pytest.raises(ValueError, match=r"either as options= or as keywords, not both \(block, levels given"):
        synthesize_volume(source, 16, levels=2, block=8, options=VolumeOptions(levels=2), **run)
    with pytest.raises(TypeError, match="options must be a VolumeOptions, got dict"):
        synthesize_volume(source, 16, options=dict(levels=2), **run)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="synthesize_volume does not tile"):
        synthesize_volume(source, 16, options=VolumeOptions(levels=1, block=8, tiles=TileOptions()), **run)
    with pytest.raises(ValueError, match=r"levels must be an integer from 1 to 4 \(each level halves the source"):
        synthesize_volume(source, 16, options=VolumeOptions(levels=5), **run)  # the source's bound, with options too


def test_options_and_keywords_give_the_same_tiled_volume():
    from geosynth.volume.tiled import synthesize_volume_tiled

    source = RNG.standard_normal((8, 16, 16)).astype(np.float32)
    run = dict(seed=1, device=ONE_DEVICE, progress=False, scheduler="threads")
    a = synthesize_volume_tiled(source, (8, 32, 32), (2, 1), levels=1, block=8, iterations=1, workers=1, **run)
    opts = VolumeOptions(levels=1, block=8, iterations=1, tiles=TileOptions(tiles=(2, 1), workers=1))
    b = synthesize_volume_tiled(source, (8, 32, 32), options=opts, **run)
    assert np.array_equal(a.quantized, b.quantized) and a.grid.tiles == b.grid.tiles == (2, 1)
    with pytest.raises(ValueError, match=r"not both \(phases given"):
        synthesize_volume_tiled(source, (8, 32, 32), phases=2, options=opts, **run)
    with pytest.raises(ValueError, match="tileable targets are not tiled"):
        synthesize_volume_tiled(source, (8, 32, 32), options=VolumeOptions(levels=1, block=8, tileable=True), **run)


def test_options_and_keywords_give_the_same_geometry():
    from geosynth.volume.synthesis import synthesize_geometry

    run = dict(seed=0, device=ONE_DEVICE, progress=False)
    kw = dict(source_resolution=16, levels=2, block=8, iterations=1, quality_samples=0, smooth=2)
    a = synthesize_geometry("terrain", 16, **kw, **run)
    b = synthesize_geometry("terrain", 16, options=VolumeOptions(**kw), **run)
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.mesh.faces, b.mesh.faces)
    with pytest.raises(ValueError, match=r"not both \(smooth given"):
        synthesize_geometry("terrain", 16, smooth=3, options=VolumeOptions(**kw), **run)
    with pytest.raises(ValueError, match=r"levels must be an integer from 1 to 3 \(each level halves the source of "
                                         r"source_resolution=8 samples\), got 4"):
        synthesize_geometry("terrain", 16, options=VolumeOptions(source_resolution=8, levels=4), **run)
