"""M1 volumetric synthesis end to end on small fields, on every present device."""

from __future__ import annotations

import numpy as np
import pytest

from geosynth.volume.examples import spheres_field
from geosynth.volume.quality import bidirectional_block_distance
from geosynth.volume.synthesis import block_offsets, downsample, scan_positions, synthesize_volume


@pytest.fixture(scope="module")
def source():
    return spheres_field(20, count=7, radius=(2.0, 4.0), seed=5)


def run(source, device, **kw):
    args = dict(size=32, levels=2, block=8, progress=False, device=device, seed=3, method="paper")  # the paper's scan
    args.update(kw)
    return synthesize_volume(source, **args)


def test_same_seed_same_field_on_every_device(device_pair, source):
    a, b = (run(source, d).quantized for d in device_pair)
    np.testing.assert_array_equal(b, a)


def test_the_seed_decides_the_field(device, source):
    first = run(source, device).quantized
    np.testing.assert_array_equal(run(source, device).quantized, first)
    assert not np.array_equal(run(source, device, seed=4).quantized, first)


SEEDS = range(3)  # quality claims over seeds (issue 40): the mean and the worst, never one picked seed


def test_beats_random_tiling(device, source):
    """Block distance of the synthesis / random tiling's, over 3 seeds (synthesis, tiling and
    the metric's draw): worst < 0.7, mean < 0.65; the last level's mean match distance
    likewise, worst < 0.4, mean < 0.32. Measured over seeds 0-9, the same under native,
    AVX2 and SSE4 (M1 is exact): block 0.559 mean, 0.602 worst (sd 0.032); match 0.248
    mean, 0.271 worst (sd 0.012); bench/RESULTS.md."""
    block, match = [], []
    for seed in SEEDS:
        synth = run(source, device, seed=seed)
        base = run(source, device, seed=seed, baseline=True)
        assert synth.quantized.shape == (32, 32, 32)
        q_synth = bidirectional_block_distance(synth.source, synth.quantized, 8, samples=40, seed=seed, device=device)
        q_base = bidirectional_block_distance(base.source, base.quantized, 8, samples=40, seed=seed, device=device)
        block.append(q_synth["mean"] / q_base["mean"])
        match.append(synth.levels[-1].mean_match_distance / base.levels[-1].mean_match_distance)
    assert max(block) < 0.7 and np.mean(block) < 0.65, block
    assert max(match) < 0.4 and np.mean(match) < 0.32, match


def test_every_target_sample_comes_from_the_source_at_one_level(device, source):
    """Single resolution: the output is made of copied source samples only."""
    r = run(source, device, levels=1, block=8)
    assert set(np.unique(r.quantized)) <= set(np.unique(r.source))
    assert r.levels[0].matches == len(scan_positions(32, 8, False)) ** 3


def _seam_and_interior_distance(out, src, block, device):
    """Mean nearest-source distance of blocks straddling the wrap seam vs interior blocks."""
    from geosynth.compute.backend import to_device
    from geosynth.compute.scoring import score_gather
    from geosynth.compute.selection import argmin

    grid = to_device(src, device)
    off = block_offsets(block)
    n = out.shape[0]

    def dist(origin):
        idx = np.ix_(*[np.arange(o, o + block) % n for o in origin])
        scores = score_gather(grid, off, out[idx].reshape(-1), keep_on_device=True)
        return int(scores.numpy()[argmin(scores)]) / block**3

    rng = np.random.default_rng(0)
    seam = [dist((n - block // 2, rng.integers(n), rng.integers(n))) for _ in range(12)]
    interior = [dist((rng.integers(0, n - block), rng.integers(0, n - block), rng.integers(0, n - block))) for _ in range(12)]
    return float(np.mean(seam)), float(np.mean(interior))


def test_tileable_output_wraps(one_device, source):
    """Over 3 seeds (one device: the fields are the same bits on every device): the tileable
    field's blocks across the wrap seam against inside, seam / (2 interior + 50) worst < 1
    and mean < 0.85; the plain field's seam is worse than the tileable one's on average,
    mean (plain - tileable) > 0. Measured over seeds 0-9, the same under native, AVX2 and
    SSE4 (M1 is exact): bound 0.724 mean, 0.954 worst (sd 0.119); plain - tileable 80 mean,
    sd 62, and -18.9 worst: on seed 7 of 10 the plain seam (12 sampled blocks) scored
    better, so the old claim, plain > tileable on seed 3, holds on average, not per seed."""
    bound, gain = [], []
    for seed in SEEDS:
        tiled = run(source, one_device, seed=seed, tileable=True)
        seam, interior = _seam_and_interior_distance(tiled.quantized, tiled.source, 8, one_device)
        bound.append(seam / (2.0 * interior + 50))
        plain = run(source, one_device, seed=seed, tileable=False)
        seam_plain, _ = _seam_and_interior_distance(plain.quantized, plain.source, 8, one_device)
        gain.append(seam_plain - seam)  # without wrapping the faces do not continue each other
    assert max(bound) < 1 and np.mean(bound) < 0.85, bound
    assert np.mean(gain) > 0, gain


def test_downsample_and_positions():
    v = np.arange(64, dtype=np.uint8).reshape(4, 4, 4)
    d = downsample(v)
    assert d.shape == (2, 2, 2)
    assert d[0, 0, 0] == round(np.mean(v[:2, :2, :2]) + 1e-9)
    assert scan_positions(32, 8, False) == [0, 4, 8, 12, 16, 20, 24]
    assert scan_positions(30, 8, False)[-1] == 22
    assert scan_positions(32, 8, True) == list(range(0, 32, 4))


def test_invalid_input(source, monkeypatch, one_device):
    with pytest.raises(ValueError, match="powers of two"):
        run(source, one_device, block=6)
    with pytest.raises(ValueError, match="larger than the source"):
        synthesize_volume(source[:6, :6, :6], 32, levels=1, block=8, search="linear", progress=False)
    with pytest.raises(ValueError, match="smaller than its block"):
        run(source, one_device, size=4, levels=1)
    with pytest.raises(ValueError, match="multiple of 2"):
        run(source, one_device, size=33)
    with pytest.raises(ValueError, match="source contains"):
        bad = source.copy()
        bad[0, 0, 0] = np.nan
        run(bad, one_device)
    with pytest.raises(ValueError, match="source must be a"):
        run(source[0], one_device)
    monkeypatch.setenv("GEOSYNTH_MEMORY_LIMIT", "1000")
    with pytest.raises(MemoryError, match=r"size .* needs about .* more than the 1000 B available"):
        run(source, one_device)


def test_geometry_refuses_bad_meshes():
    import trimesh

    from geosynth.volume.synthesis import synthesize_geometry

    with pytest.raises(ValueError, match="empty"):
        synthesize_geometry(trimesh.Trimesh(), 32, progress=False)
    box = trimesh.creation.box()
    box.vertices[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN|finite"):
        synthesize_geometry(box, 32, progress=False)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        synthesize_geometry("no-such-exemplar.ply", 32, progress=False)
    with pytest.raises(ValueError, match="neither a built-in exemplar .*chainmail"):
        synthesize_geometry("chainmial", 32, progress=False)


def test_linear_tree_and_cascade_searches_give_the_same_field(device, source):
    """All three searches are exact (the linear one with its early exit), so the fields agree."""
    linear = run(source, device, search="linear")
    tree = run(source, device, search="tree")
    cascade = run(source, device, search="cascade")
    np.testing.assert_array_equal(linear.quantized, tree.quantized)
    np.testing.assert_array_equal(linear.quantized, cascade.quantized)


# Block distance synthesis / random tiling at 32 across over 3 seeds: (worst, mean) bounds, from
# seeds 0-9 at 32 across, the same under native, AVX2 and SSE4 (bench/RESULTS.md): terrain mean
# 0.154, worst 0.218 (sd 0.037); balls mean 0.278, worst 0.332 (sd 0.037). (At 48 across, the
# size before issue 40: terrain 0.130 / 0.171, balls 0.253 / 0.313; the test asserted < 1 on seed 0.)
GEOMETRY_BEATS = {"terrain": (0.35, 0.25), "balls": (0.45, 0.38)}


@pytest.mark.parametrize("name", ["terrain", "balls"])
def test_geometry_beats_random_tiling_on_built_in_exemplars(name, one_device):
    """Mesh in, mesh out on a built-in exemplar (small settings for CI): a closed surface,
    and matched blocks closer to the exemplar's than randomly tiled ones, over 3 seeds on
    the mean and the worst (GEOMETRY_BEATS)."""
    from geosynth.volume.synthesis import synthesize_geometry

    ratios = []
    for seed in SEEDS:
        r = synthesize_geometry(name, 32, source_resolution=32, levels=2, block=8, quality_samples=40, seed=seed,
                                device=one_device, progress=False, smooth=2, iterations=[4, 2])
        assert r.mesh.is_watertight and len(r.mesh.faces) > 100
        assert r.volume.quantized.shape[1:] == (32, 32)
        assert r.volume.quantized.shape[0] == r.exemplar_field.shape[0]  # the slab keeps its thickness
        ratios.append(r.quality["synthesis"]["mean"] / r.quality["random tiling"]["mean"])
        # the default, "auto": graphcut for a slab, optimize otherwise
        assert r.method == r.quality["synthesis"]["method"] == ("graphcut" if r.volume.slab else "optimize")
        kind = "surface" if name == "terrain" else "elements"
        for side in ("synthesis", "random tiling"):
            assert r.quality[side]["structure"]["kind"] == kind
    worst, mean = GEOMETRY_BEATS[name]
    assert max(ratios) < worst and np.mean(ratios) < mean, ratios


def test_exemplar_grid_and_target_size():
    import trimesh

    from geosynth.volume.synthesis import exemplar_grid, target_size

    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    g = exemplar_grid(box, 32, margin=2, multiple=4)
    assert g.shape[2] == 32 and g.shape[1] == 16  # x: longest extent; y: same spacing
    assert g.shape[0] % 4 == 0 and g.shape[0] >= 8 + 4
    z = g.origin[2] + g.spacing[2] * np.arange(g.shape[0])
    assert z[0] < -0.25 - g.spacing[2] and z[-1] > 0.25 + g.spacing[2]  # margins above and below
    assert target_size(64, g.shape, 3) == (g.shape[0], 64, 64)
    assert target_size((16, 32, 48), g.shape, 3) == (16, 32, 48)
    with pytest.raises(ValueError, match="source_resolution"):
        exemplar_grid(box, 4)
