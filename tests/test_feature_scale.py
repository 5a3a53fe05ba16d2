"""M1 keeps the exemplar's feature scale (issue #32): settings chosen from the exemplar's
thinnest feature, histogram matching after texture optimization's coarse levels, and
element size, height and wholeness measured over seeds on small generated inputs."""

import math

import numpy as np
import pytest

import geosynth.volume.synthesis as volume
from geosynth.volume.features import compare_features, element_features
from geosynth.volume.synthesis import choose_settings, match_histogram, synthesize_volume

SEEDS = (0, 1, 2)


def _discs(n: int = 40, thickness: float = 4.0, radius: float = 3.5, zs: int = 10, seed: int = 0) -> np.ndarray:
    """(zs, n, n) signed distances (samples) of one layer of separate flat discs on a
    jittered 10-sample lattice (a slab of elements, like washers or coins)."""
    rng = np.random.default_rng(seed)
    z, y, x = np.mgrid[0:zs, 0:n, 0:n].astype(np.float32)
    f = np.full((zs, n, n), 9.0, np.float32)
    for cy in np.arange(5, n, 10.0):
        for cx in np.arange(5, n, 10.0):
            oy, ox = rng.uniform(-1, 1, 2)
            d = np.maximum(np.hypot(y - cy - oy, x - cx - ox) - radius, np.abs(z - zs / 2 + 0.4) - thickness / 2)
            f = np.minimum(f, d)
    return f


def _terrain(n: int = 48, zs: int = 16, seed: int = 0) -> np.ndarray:
    """(zs, n, n) signed distances (samples, along z) of a terrain of six cosine waves
    of 12-32 samples at random angles, height std 2.2 samples."""
    rng = np.random.default_rng(seed)
    z, y, x = np.mgrid[0:zs, 0:n, 0:n].astype(np.float32)
    h = np.zeros((n, n))
    for _ in range(6):
        f, a, ph = rng.uniform(1.5, 4.0) / n, rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi)
        h += np.cos(2 * np.pi * f * (np.cos(a) * x[0] + np.sin(a) * y[0]) + ph)
    h = 7 + 2.2 * h / h.std()
    return z - h[None].astype(np.float32)


def test_separate_elements_kept_whole_over_seeds():
    """A slab of discs 4 samples thick: >= 80% of the output's whole discs are whole
    copies (not broken, not fused), diameter and height within 15%, on every seed."""
    src = _discs()
    ex = element_features(src)
    assert ex.count == 16 and not ex.relief
    for seed in SEEDS:
        out = synthesize_volume(src, (10, 48, 48), levels=2, block=16, seed=seed, progress=False)
        assert out.slab
        r = compare_features(ex, element_features(out.field.values, 1.0, False))
        assert r["whole"] >= 0.8, (seed, r)
        assert abs(r["diameter"] - 1) <= 0.15 and abs(r["height"] - 1) <= 0.15, (seed, r)


def test_element_span():
    """The whole elements' horizontal span is their diameter to a sample; a relief and a
    tube crossing the box (no whole element) have none."""
    for radius in (2.5, 3.5):
        assert abs(element_features(_discs(radius=radius)).span - 2 * radius) <= 1.0
    assert math.isnan(element_features(_terrain()).span)
    z, y, x = np.mgrid[0:8, 0:32, 0:32].astype(np.float32)
    assert math.isnan(element_features(np.sqrt((z - 3.6) ** 2 + (y - 16.3) ** 2) - 2.0).span)


def test_relief_height_kept_by_histogram_matching(monkeypatch):
    """Texture optimization's votes (and the upsampling between levels) lower a
    terrain's relief; matching the code histogram after the coarse levels and the
    upsampling keeps its height within 15% on every seed, and higher than without."""
    src = _terrain()
    ex = element_features(src)
    assert ex.relief

    def heights(mode):
        monkeypatch.setattr(volume, "HISTOGRAM_MATCH", mode)
        out = []
        for seed in SEEDS:
            v = synthesize_volume(src, (16, 48, 48), levels=2, block=8, seed=seed, progress=False, method="optimize",
                                  iterations=[3, 1])
            out.append(compare_features(ex, element_features(v.field.values, 1.0, True))["height"])
        return np.array(out)

    matched = heights("coarse+init")
    assert (np.abs(matched - 1) <= 0.15).all(), matched
    assert matched.mean() > heights(None).mean()


def test_match_histogram():
    rng = np.random.default_rng(0)
    src = rng.integers(0, 256, (4, 16, 16)).astype(np.uint8)
    assert np.array_equal(match_histogram(src, src, True), src)
    # a target pulled toward the middle (a vote's average) regains each slice's inside share
    field = _terrain(32, 12)
    codes = volume.quantize_field(field, 4.0)
    blurred = ((codes.astype(np.int32) + 128) // 2).astype(np.uint8)
    out = match_histogram(blurred, codes, True)
    for z in range(codes.shape[0]):
        assert abs(int((out[z] < 128).sum()) - int((codes[z] < 128).sum())) <= 0.02 * codes[z].size
    # per slice, a monotone map of the codes: one code keeps one code (no tie artifacts)
    for z in range(codes.shape[0]):
        b, o = blurred[z].ravel(), out[z].ravel()
        order = np.argsort(b, kind="stable")
        assert (np.diff(o[order].astype(int)) >= 0).all()
        assert all(len(np.unique(o[b == c])) == 1 for c in np.unique(b))


def _washers(height: float, cells: int = 4, spacing: float = 0.8):
    import trimesh

    parts = []
    for i in range(cells):
        for j in range(cells):
            w = trimesh.creation.annulus(r_min=0.15, r_max=0.3, height=height)
            w.apply_translation([spacing * i, spacing * j, 0])
            parts.append(w)
    return trimesh.util.concatenate(parts)


def test_settings_follow_the_thinnest_feature():
    """Washers 0.05 thick over a 2.9-unit layer are 1.1 samples at 64: the resolution
    and block double, the size doubles (the same world extent); 0.3 thick ones keep the
    defaults and the measuring field is the synthesis's. Given values are kept."""
    thin = choose_settings(_washers(0.05), 48, 2)
    assert (thin.source_resolution, thin.block, thin.size) == (128, 32, 96)
    assert thin.thickness == pytest.approx(0.05, rel=0.35) and thin.field is None
    assert "source resolution 128" in thin.text and "block 32" in thin.text
    thick = choose_settings(_washers(0.3), (8, 40, 48), 2)
    assert (thick.source_resolution, thick.block, thick.size) == (64, 16, (8, 40, 48))
    assert thick.field is not None and thick.field.values.shape[2] == 64
    given = choose_settings(_washers(0.05), 48, 2, source_resolution=64, block=8)
    assert (given.source_resolution, given.block, given.size, given.text) == (64, 8, 48, "")
    assert math.isnan(given.thickness)
    refused = choose_settings(_washers(0.05), 48, 2, fits=lambda size, res, block: False)
    assert (refused.source_resolution, refused.block, refused.size) == (64, 16, 48)
    assert "would not fit" in refused.text
    # 3 x 3 washers 0.6 across on a 2-unit layer: 19 samples at 64, wider than block 16 with a margin
    big = choose_settings(_washers(0.15, 3, 0.7), 64, 3)
    assert (big.source_resolution, big.block, big.size) == (64, 32, 64) and "whole elements" in big.text
    assert choose_settings(_washers(0.15, 3, 0.7), 64, 3, fits=lambda size, res, block: block < 32).block == 16


def test_border_slivers_dropped():
    """Loose pieces reaching at most 2 samples in from an x/y face go; the main piece,
    pieces reaching further in and pieces away from the faces stay."""
    from geosynth.volume.synthesis import drop_border_slivers, quantize_field

    z, y, x = np.mgrid[0:8, 0:32, 0:32].astype(np.float32)
    tube = np.sqrt((z - 3.6) ** 2 + (y - 16.3) ** 2) - 2.0  # across the whole field: the main piece
    stub = np.maximum(np.sqrt((z - 3.6) ** 2 + (y - 5.2) ** 2) - 1.5, x - 1.4)  # x < 1.4: a sliver
    long = np.maximum(np.sqrt((z - 3.6) ** 2 + (y - 26.2) ** 2) - 1.5, x - 6.4)  # reaches 6 samples in
    ball = np.sqrt((z - 3.6) ** 2 + (y - 9.0) ** 2 + (x - 20.0) ** 2) - 2.0  # inside, away from the faces
    codes = quantize_field(np.minimum.reduce([tube, stub, long, ball]), 4.0)
    out, n = drop_border_slivers(codes, 2.0)
    assert n == 1
    assert (out[:, :9, :4] >= 128).all() and (codes[:, :9, :4] < 128).any()
    assert np.array_equal(out[:, 10:, :], codes[:, 10:, :])


def _padded(f: np.ndarray, pad: int) -> np.ndarray:
    """``f`` inside a grid ``pad`` samples larger on every x/y side and above (empty space),
    as a mesh's field padded around its bounds is."""
    out = np.full((f.shape[0] + pad, f.shape[1] + 2 * pad, f.shape[2] + 2 * pad), 9.0, np.float32)
    out[:f.shape[0], pad:pad + f.shape[1], pad:pad + f.shape[2]] = f
    return out


def test_measures_ignore_the_grids_empty_padding():
    """A relief and a slab of elements measure the same inside a padded grid: the padding's
    empty columns are not read as a low relief, and an element cut by the material's side
    is not whole (the grid's border is not where the material ends): at most the 3 x 3
    discs away from the cut sides are."""
    terrain = _terrain()
    a, b = element_features(terrain, slab=True), element_features(_padded(terrain, 6), slab=True)
    assert abs(b.height / a.height - 1) < 0.05 and abs(b.diameter / a.diameter - 1) < 0.1, (a, b)
    discs = _discs()
    cut = discs[:, 5:, 5:]  # the first row and column of discs cut in half by the material's side
    e, p = element_features(cut, slab=False), element_features(_padded(cut, 6), slab=False)
    assert e.count == p.count == 16 and e.whole_fraction == p.whole_fraction <= 9 / 16, (e, p)


def test_spanning_share_of_tubes():
    """Tubes across the footprint: all the volume spans it; cut into pieces it does not."""
    n, zs = 40, 8
    z, y, x = np.mgrid[0:zs, 0:n, 0:n].astype(np.float32)
    tubes = np.min([np.hypot(y - c, z - 4) - 2.0 for c in (5.0, 15.0, 25.0, 35.0)], axis=0)
    assert element_features(_padded(tubes, 4), slab=False).spanning == 1.0
    broken = np.maximum(tubes, -(np.abs(x - 20) - 1.5))  # a gap across every tube at x = 20
    assert element_features(_padded(broken, 4), slab=False).spanning == 0.0


def test_auto_method_optimizes_a_terrain_slab_and_cuts_a_plate():
    """is_terrain: a relief with no flat ground (graphcut's seams crease it) -> texture
    optimization under "auto"; a plate with bumps and a layer of discs stay graphcut slabs."""
    from geosynth.volume.synthesis import choose_volume_settings, is_terrain

    terrain = _terrain(n=48, zs=12)
    z, y, x = np.mgrid[0:12, 0:48, 0:48].astype(np.float32)
    plate = np.minimum(z - 4, np.hypot(np.hypot(y % 12 - 6, x % 12 - 6), z - 4) - 3.5)
    assert is_terrain(terrain) and is_terrain(np.where(terrain < 0, 0, 255).astype(np.uint8))
    assert not is_terrain(plate) and not is_terrain(_discs())
    for field, method in ((terrain, "optimize"), (plate, "graphcut")):
        s = choose_volume_settings(field.shape, (12, 96, 96), 2, 8, terrain=is_terrain(field))
        assert s.slab and s.method == method, (s.slab, s.method)


def test_auto_method_optimizes_tubes_across_and_cuts_discs_and_broken_tubes():
    """is_tubes_across: separate tubes over the footprint (graphcut's stitches break or fuse
    them) -> texture optimization under "auto", from quantized codes too; a layer of discs,
    tubes cut in two and one tube stay graphcut slabs."""
    from geosynth.volume.synthesis import choose_volume_settings, is_tubes_across, optimizes_better, quantize_field

    n, zs = 40, 8
    z, y, x = np.mgrid[0:zs, 0:n, 0:n].astype(np.float32)
    tubes = np.min([np.hypot(y - c, z - 4) - 2.0 for c in (5.0, 15.0, 25.0, 35.0)], axis=0)
    broken = np.maximum(tubes, -(np.abs(x - 20) - 1.5))
    one = np.hypot(y - 20, z - 4) - 2.0
    assert is_tubes_across(tubes) and is_tubes_across(quantize_field(tubes, 4.0)) and optimizes_better(tubes)
    assert not is_tubes_across(broken) and not is_tubes_across(one) and not is_tubes_across(_discs())
    for field, method in ((tubes, "optimize"), (broken, "graphcut")):
        s = choose_volume_settings(field.shape, (8, 80, 80), 2, 8, terrain=optimizes_better(field))
        assert s.slab and s.method == method, (s.slab, s.method)


def test_tubes_across_get_the_largest_block_the_source_holds_twice():
    """Seven separate tubes across a square layer 3.84 units wide (4 samples thick at 64):
    no element size a block could hold, so the fewest stitches: block 32 (half the source
    across); given, the block is kept."""
    import trimesh

    tubes = []
    for i in range(7):
        t = trimesh.creation.cylinder(radius=0.12, height=3.84, sections=24)
        t.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
        t.apply_translation([0.0, 0.6 * i, 0.0])
        tubes.append(t)
    mesh = trimesh.util.concatenate(tubes)
    s = choose_settings(mesh, 128, 3)
    assert (s.source_resolution, s.block) == (64, 32) and "(tubes) -> block 32" in s.text, s.text
    assert choose_settings(mesh, 128, 3, block=16).block == 16


def test_tubes_run_between_breaks():
    """A woodpile of tubes (two layers across each other, the upper one reaching further than
    the lower): whole, no end counts as a break (the lower rods stop short of the upper layer:
    cut, not broken); a gap across one rod is one break; the connection to the exemplar falls
    below 1 only when the breaks come more often than once an exemplar's length."""
    from geosynth.volume.features import tube_connection

    n, zs = 64, 16
    z, y, x = np.mgrid[0:zs, 0:n, 0:n].astype(np.float32)
    lower = np.min([np.hypot(y - c, z - 5) - 2.0 for c in (12.0, 24.0, 36.0, 48.0)], axis=0)
    lower = np.maximum(lower, np.maximum(6 - x, x - 57))  # x in [6, 57]: shorter than the upper layer
    upper = np.min([np.hypot(x - c, z - 10) - 2.0 for c in (6.0, 18.0, 30.0, 42.0, 54.0)], axis=0)
    whole = np.minimum(lower, upper)
    e = element_features(_padded(whole, 4), slab=False)
    assert math.isinf(e.run) and e.extent == pytest.approx(n, abs=2), e
    one = np.minimum(np.maximum(lower, -(np.abs(x - 30) - 1.5) * (np.abs(y - 24) < 4)), upper)
    b = element_features(_padded(one, 4), slab=False)
    assert math.isfinite(b.run) and b.run > n, b  # one break in ~9 rods of ~55 samples
    assert tube_connection(e, b) == 1.0 and tube_connection(e, e) == 1.0
    many = np.minimum(np.maximum(lower, -(np.abs(x % 8 - 4) - 1.5)), upper)  # every lower rod cut 6 times
    m = element_features(_padded(many, 4), slab=False)
    assert m.run < b.run and tube_connection(e, m) < 0.8, (m.run, tube_connection(e, m))


def test_element_height_is_not_read_from_debris():
    """Specks of debris (many, tiny) do not lower the elements' height: it is weighted by volume,
    as the diameter is, and taken over every element (an element cut by the side keeps its
    height, so a layer of tubes across the footprint, none whole, is measured by its tubes)."""
    discs = _discs()
    clean = element_features(_padded(discs, 4), slab=False)
    z, y, x = np.mgrid[0:discs.shape[0], 0:discs.shape[1], 0:discs.shape[2]].astype(np.float32)
    specks = discs.copy()
    for cy, cx in [(10, 10), (10, 20), (20, 10), (20, 30), (30, 20), (30, 30), (10, 30), (30, 10), (20, 20), (5, 25)]:
        specks = np.minimum(specks, np.hypot(np.hypot(y - cy, x - cx), z - 2.0) - 0.8)
    dirty = element_features(_padded(specks, 4), slab=False)
    assert dirty.count > clean.count and abs(dirty.height / clean.height - 1) < 0.05, (clean.height, dirty.height)
    n, zs = 40, 8
    z, y, x = np.mgrid[0:zs, 0:n, 0:n].astype(np.float32)
    tubes = np.min([np.hypot(y - c, z - 4) - 2.0 for c in (5.0, 15.0, 25.0, 35.0)], axis=0)
    speck = np.minimum(tubes, np.hypot(np.hypot(y - 10, x - 20), z - 4) - 0.8)  # the one whole element
    assert abs(element_features(_padded(speck, 4), slab=False).height - 4.0) < 0.6
