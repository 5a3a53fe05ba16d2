"""The quality claims of the test suite measured over seeds (issue 40, item 2).

Each claim is a function of one seed, at the sizes of its test, returning the numbers its
test asserts on (ratios: lower is better unless the name says otherwise). For every claim
the script prints one JSON line per seed and a summary per number: mean, worst (the
largest, or the smallest for a number named ``*_min``), sd, min, max.

    PYTHONPATH=. python bench/quality_over_seeds.py [--seeds 10] [--out FILE] [CLAIM ...]
    ../shared/cpu-matrix .venv/bin/python bench/quality_over_seeds.py --seeds 10 CLAIM

The results are in bench/RESULTS.md, "Quality claims over seeds".
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))

from conftest import ONE_DEVICE  # noqa: E402  the tests' device

CLAIMS = {}


def claim(fn):
    CLAIMS[fn.__name__] = fn
    return fn


# ------------------------------------------------------------------ M1


def _spheres():
    from geosynth.volume.examples import spheres_field

    return spheres_field(20, count=7, radius=(2.0, 4.0), seed=5)


@claim
def volume_beats_random_tiling(seed):
    """tests/test_volume.py::test_beats_random_tiling: block distance synthesis / random tiling."""
    from geosynth.volume.quality import bidirectional_block_distance
    from geosynth.volume.synthesis import synthesize_volume

    src = _spheres()
    kw = dict(size=32, levels=2, block=8, progress=False, device=ONE_DEVICE, seed=seed, method="paper")
    s, b = synthesize_volume(src, **kw), synthesize_volume(src, **kw, baseline=True)
    qs = bidirectional_block_distance(s.source, s.quantized, 8, samples=40, seed=seed, device=ONE_DEVICE)["mean"]
    qb = bidirectional_block_distance(b.source, b.quantized, 8, samples=40, seed=seed, device=ONE_DEVICE)["mean"]
    return {"block_ratio": qs / qb, "match_ratio": s.levels[-1].mean_match_distance / b.levels[-1].mean_match_distance}


@claim
def volume_tileable_wraps(seed):
    """tests/test_volume.py::test_tileable_output_wraps: seam / (2 interior + 50) tiled, and
    plain seam - tiled seam (> 0)."""
    from test_volume import _seam_and_interior_distance

    from geosynth.volume.synthesis import synthesize_volume

    src = _spheres()
    kw = dict(size=32, levels=2, block=8, progress=False, device=ONE_DEVICE, seed=seed, method="paper")
    t = synthesize_volume(src, **kw, tileable=True)
    seam, inner = _seam_and_interior_distance(t.quantized, t.source, 8, ONE_DEVICE)
    p = synthesize_volume(src, **kw, tileable=False)
    seam_p, _ = _seam_and_interior_distance(p.quantized, p.source, 8, ONE_DEVICE)
    return {"tiled_seam_bound": seam / (2 * inner + 50), "plain_minus_tiled_min": seam_p - seam}


@claim
def methods_beat_random_tiling(seed):
    """tests/test_optimize.py::test_methods_beat_random_tiling: block distance per method / random tiling."""
    from geosynth.volume.quality import bidirectional_block_distance
    from geosynth.volume.synthesis import synthesize_volume

    src = _spheres()
    kw = dict(levels=2, block=8, progress=False, device="cpu", seed=seed)
    b = synthesize_volume(src, 32, **kw, baseline=True)
    qb = bidirectional_block_distance(b.source, b.quantized, 8, samples=40, seed=seed, device="cpu")["mean"]
    out = {}
    for m in ("paper", "graphcut", "optimize"):
        r = synthesize_volume(src, 32, **kw, method=m, iterations=3)
        q = bidirectional_block_distance(r.source, r.quantized, 8, samples=40, seed=seed, device="cpu")["mean"]
        out[m] = q / qb
    return out


def _geometry(name, seed, size=48, res=32):
    from geosynth.volume.synthesis import synthesize_geometry

    r = synthesize_geometry(name, size, source_resolution=res, levels=2, block=8, quality_samples=40, seed=seed,
                            device=ONE_DEVICE, progress=False, smooth=2, iterations=[4, 2])
    return {"ratio": r.quality["synthesis"]["mean"] / r.quality["random tiling"]["mean"],
            "watertight_min": float(r.mesh.is_watertight)}


@claim
def geometry_terrain(seed):
    """tests/test_volume.py::test_geometry_beats_random_tiling_on_built_in_exemplars[terrain]."""
    return _geometry("terrain", seed)


@claim
def geometry_balls(seed):
    """tests/test_volume.py::test_geometry_beats_random_tiling_on_built_in_exemplars[balls]."""
    return _geometry("balls", seed)


@claim
def geometry_terrain_32(seed):
    """The same at 32 samples across (the test's size since issue 40)."""
    return _geometry("terrain", seed, size=32)


@claim
def geometry_balls_32(seed):
    """The same at 32 samples across (the test's size since issue 40)."""
    return _geometry("balls", seed, size=32)


@claim
def metrics_random_tiling_scores_low(seed):
    """tests/test_metrics.py::test_builtin_balls_and_terrain_against_random_tiling: the
    structure scores of randomly tiled balls and terrain."""
    from geosynth.volume.examples import balls_field, terrain_heights
    from geosynth.volume.quality import structure_report
    from geosynth.volume.synthesis import synthesize_volume

    ex = balls_field(resolution=48)
    h = float(ex.spacing[0])
    z = ex.shape[0] // 2 * 2
    tiled = synthesize_volume(ex.values[:z] / np.float32(h), (z, 64, 64), levels=2, block=8, seed=seed,
                              progress=False, baseline=True, spacing=h)
    balls = structure_report(ex, tiled.field)["elements"]["score"]
    heights = terrain_heights(48, seed=0)
    d = (np.arange(24)[:, None, None] - (4 + 14 * heights.T[None])).astype(np.float32)
    tiled = synthesize_volume(d, (24, 64, 64), levels=2, block=8, seed=seed, progress=False, baseline=True)
    itself, against = structure_report(d, d), structure_report(d, tiled.field)
    return {"balls_score": balls, "terrain_slopes": against["surface"]["slopes"]["score"],
            "overhangs_gain_min": against["surface"]["overhangs"]["output"] - itself["surface"]["overhangs"]["output"]}


@claim
def metrics_noise_scores_low(seed):
    """tests/test_metrics.py::test_random_noise_scores_low: wholeness of smoothed noise."""
    from scipy import ndimage
    from test_metrics import TORI_SHAPE, tori

    from geosynth.volume.quality import element_wholeness

    noise = ndimage.gaussian_filter(np.random.default_rng(seed).standard_normal(TORI_SHAPE), 2)
    noise = (3 * noise / noise.std()).astype(np.float32)
    return {"score": element_wholeness(tori(), noise)["score"]}


@claim
def slab_thin_plate(seed, size=96, res=48):
    """tests/test_slab.py::test_defaults_grow_a_thin_plate_that_they_refused."""
    from geosynth.volume.synthesis import synthesize_geometry

    r = synthesize_geometry("domes", size, source_resolution=res, device=ONE_DEVICE, progress=False, seed=seed,
                            quality_samples=20, smooth=0, iterations=2)
    s = r.quality["synthesis"]["structure"]["surface"]
    return {"debris": s["debris"]["output"], "slopes_min": s["slopes"]["score"],
            "ratio": r.quality["synthesis"]["mean"] / r.quality["random tiling"]["mean"]}


@claim
def tiled_seams(seed):
    """tests/test_tiled.py::test_seams_as_good_as_inside (threads instead of a Dask cluster:
    the bits do not depend on the engine)."""
    from geosynth.volume.tiled import exemplar_source, seam_report, synthesize_volume_tiled

    out = {}
    kw = dict(levels=2, block=8, seed=seed, progress=False, iterations=2, device=ONE_DEVICE, scheduler="threads",
              workers=1)
    for name in ("terrain", "chainmail"):
        src, _, _ = exemplar_source(name, 32, 2)
        shape = (src.shape[0] // 2 * 2, 64, 64)
        r = synthesize_volume_tiled(src, shape, (2, 2), **kw)
        s = seam_report(r.source, r.quantized, r.grid, 8, stride=2, device=ONE_DEVICE)
        out[name + "_ratio"] = s["ratio"]
        if name == "terrain":
            out["terrain_step"] = s["step_ratio"]
            n = synthesize_volume_tiled(src, shape, (2, 2), phases=1, **kw)
            out["naive_step_gain_min"] = seam_report(n.source, n.quantized, n.grid, 8, stride=2,
                                                     device=ONE_DEVICE)["step_ratio"] - s["step_ratio"]
    return out


# ------------------------------------------------------------------ M2


@claim
def point_texture_beats_random_pasting(seed):
    """tests/test_point_texture.py::test_synthesis_beats_random_pasting (weave)."""
    from geosynth.pointtexture.examples import point_texture_example
    from geosynth.pointtexture.synthesis import synthesize_point_texture

    tex = point_texture_example("weave", count=10_000)
    _, report, _ = synthesize_point_texture(tex, device=ONE_DEVICE, seed=seed, scale=1.2, patch=0.5, resolution=24,
                                            quality=True, quality_samples=6)
    q = report.quality
    return {"field": q["field_distance"][2] / q["field_distance_baseline"][2],
            "seam_after_before": q["seam_after"] / q["seam_before"],
            "seam_before_baseline": q["seam_before"] / q["seam_baseline"], "stray": q["stray"]}


@claim
def point_texture_keeps_element_size(seed):
    """Issue 32 item 2 (no test: about 20 s a seed): with the default (automatic) patch and
    resolution, the output's element size and relief amplitude over the exemplar's
    (geosynth.pointtexture.element_size, printed by every run), and the patch-field distance over random
    pasting's, on a bumps relief nobody tuned for (tests/test_element_size.py's _relief:
    domes of radius 0.06 on a jittered 0.2 lattice, a new layout per seed) and on flowers
    (its sampling seed)."""
    from test_element_size import _bumps, _relief

    from geosynth.pointtexture.examples import point_texture_example
    from geosynth.pointtexture.synthesis import synthesize_point_texture

    out = {}
    for name, tex in (("bumps", _relief(_bumps(0.06, 0.2, 100 + seed), n=110, seed=seed)),
                      ("flowers", point_texture_example("flowers", count=20_000, seed=seed))):
        _, report, _ = synthesize_point_texture(tex, device=ONE_DEVICE, seed=seed, quality=True, quality_samples=8)
        r, q = report.relief, report.quality
        out[name + "_period"] = r["output"][0] / r["exemplar"][0]
        out[name + "_amplitude"] = r["output"][1] / r["exemplar"][1]
        out[name + "_field"] = q["field_distance"][2] / q["field_distance_baseline"][2]
    return out


@claim
def point_texture_tileable(seed):
    """tests/test_point_texture.py::test_tileable_output_continues_across_its_borders: the median
    distance of the right border's points, moved one period, to the left border's surface, in spacings."""
    from test_point_texture import SMALL, _wavy

    from geosynth.geometry.pointsets import pointset_distance
    from geosynth.pointtexture.synthesis import synthesize_point_texture

    pts, report, _ = synthesize_point_texture(_wavy(), device=ONE_DEVICE, tileable=True, seed=seed, **SMALL)
    w = np.asarray(report.size)
    p, n = pts.positions.astype(np.float64), pts.normals
    h = 2 * report.spacing
    right, left = p[:, 0] > w[0] - 2 * h, p[:, 0] < 4 * h
    moved = p[right] - [w[0], 0, 0]
    d, _ = pointset_distance(np.r_[p[left], moved].astype(np.float32), np.r_[n[left], n[right]],
                             moved.astype(np.float32), radius=h, device=ONE_DEVICE)
    return {"median_spacings": float(np.median(np.abs(d))) / report.spacing}


@claim
def blending_scene(seed):
    """tests/test_blending.py::test_blending_lowers_the_seam_error_and_keeps_points_on_the_surface
    and test_cutting_the_overlap_keeps_whole_pieces_and_lowers_the_seam_error: the synthetic
    scenes drawn with rng(seed) (the tests' rng fixture is seed 1234)."""
    from test_blending import SP, flowers_edge, flowers_scene, height, scene, scene_edge

    from geosynth.pointtexture.blending import blend_patch, cut_pieces, overlap_ramp, seam_error

    rng = np.random.default_rng(seed)
    out = {}
    for offset in (0.5, 2.0):
        (p, n), (nbp, nbn) = scene(offset, rng)
        ramp = overlap_ramp(p, [0, 0], [1, 1], 0.3, 0.3)
        bp, bn = blend_patch(p, n, ramp, nbp, nbn, SP)
        edge = scene_edge()
        before, after = seam_error(p, n, nbp, nbn, edge, SP), seam_error(bp, bn, nbp, nbn, edge, SP)
        out[f"after_before_{offset}"] = after / before
        out[f"before_offset_{offset}_min"] = before / offset
        sel = ramp > 0
        off = np.abs(bp[sel, 2] - height(bp[sel, :2])) / SP
        out[f"off_excess_{offset}"] = float(np.max(off - (1 - ramp[sel]) * offset))
    (p, n, lp), (q, qn, lq) = flowers_scene(rng)
    box = ([0, 0, -1], [1, 1, 1])
    ramp = overlap_ramp(p, *box, 0.3, 0.3)
    drop, unblend, restore = cut_pieces(p, ramp, q, overlap_ramp(q, *box, 0.3, 0.3), *box, SP)
    bp, bn = blend_patch(p, n, np.where(unblend, 0.0, ramp), q, qn, SP)
    edge = flowers_edge()
    plain, _ = blend_patch(p, n, ramp, q, qn, SP)
    warped, blended = seam_error(p, n, q, qn, edge, SP), seam_error(plain, n, q, qn, edge, SP)
    cut = seam_error(np.concatenate([bp[~drop], q[restore]]), np.concatenate([bn[~drop], qn[restore]]), q, qn, edge, SP)
    out["cut_blended"], out["cut_warped"] = cut / blended, cut / warped
    return out


@claim
def blending_relax(seed):
    """tests/test_blending.py::test_relaxation_spreads_points_and_keeps_the_surface and
    test_relaxation_keeps_curved_geometry, drawn with rng(seed)."""
    from scipy.spatial import cKDTree
    from test_blending import SP, grid_xy, height, normal

    from geosynth.pointtexture.blending import relax_points

    rng = np.random.default_rng(seed)
    xy = grid_xy(0, 1, 0, 1, rng, 0.45)
    p, n = np.c_[xy, height(xy)], normal(xy)
    rp, rn = relax_points(p, n, SP, iterations=2)
    inner = ((rp[:, :2] > 0.1) & (rp[:, :2] < 0.9)).all(axis=1)
    pairs = len(cKDTree(rp).query_pairs(0.5 * SP)) / len(cKDTree(p).query_pairs(0.5 * SP))
    off = np.abs(rp[inner, 2] - height(rp[inner, :2])).max() / SP
    radius = 2.5 * SP
    a = rng.uniform(0, 2 * np.pi, 3000)
    y = rng.uniform(-0.3, 0.3, 3000)
    p = np.c_[radius * np.cos(a), y, radius * np.sin(a)]
    n = np.c_[np.cos(a), np.zeros(3000), np.sin(a)]
    rp, _ = relax_points(p, n, SP, iterations=2)
    r = np.linalg.norm(rp[np.abs(rp[:, 1]) < 0.2][:, [0, 2]], axis=1)
    return {"close_pairs_after_before": pairs, "plane_off_max": off, "thread_shrink": abs(np.mean(r - radius)) / SP,
            "thread_off_max": np.abs(r - radius).max() / SP}


# ------------------------------------------------------------------ M3


@claim
def texture_flat_grid(seed):
    """tests/test_texture.py::test_matching_a_flat_grid_reproduces_the_exemplar (batched): result / random."""
    from geosynth.texturing.models import point_model  # noqa: F401
    from geosynth.texturing.synthesis import texture_points
    from geosynth.texturing.textures import texture_example
    from test_texture import grid_points

    tex = texture_example("noise", 24, seed=4)
    ps = grid_points(30, 30, spacing=1.0)
    _, rep = texture_points(ps, tex, method="match", k=24, device=ONE_DEVICE, seed=seed, quality_samples=40)
    return {"result_random": rep.error["result"] / rep.error["random"]}


@claim
def texture_hybrid(seed):
    """tests/test_texture.py::test_hybrid_colours_every_point_and_is_close_to_parameterization."""
    from geosynth.texturing.models import point_model
    from geosynth.texturing.synthesis import texture_points
    from geosynth.texturing.textures import texture_example

    tex = texture_example("noise", 32, seed=0)
    ps = point_model("sphere", 2500, seed=0)
    _, rep = texture_points(ps, tex, method="hybrid", device=ONE_DEVICE, seed=seed, quality_samples=50)
    _, rep0 = texture_points(ps, tex, method="hybrid", pattern_size=0, device=ONE_DEVICE, seed=seed, quality_samples=50)
    return {"result_random": rep.error["result"] / rep.error["random"],
            "gaps_param": rep0.error["result"] / rep0.error["parameterization"]}


@claim
def texture_coherent(seed):
    """tests/test_texture.py::test_multilevel_and_coherent_matching: coherent result / random."""
    from geosynth.texturing.models import point_model
    from geosynth.texturing.synthesis import texture_points
    from geosynth.texturing.textures import texture_example

    tex = texture_example("bricks", 64, seed=0)
    ps = point_model("torus", 1000, seed=0)
    _, rep = texture_points(ps, tex, method="match", coherent=True, k=16, device=ONE_DEVICE, seed=seed,
                            quality_samples=15)
    return {"result_random": rep.error["result"] / rep.error["random"],
            "searches": rep.searches.get("count", 0) / len(ps)}


# ------------------------------------------------------------------ M4


def _wave(seed, refine=0):
    from test_completion import WAVE_REGION, _sine_fit, _wave_capture

    from geosynth.completion.synthesis import complete_surface

    surface, report, _ = complete_surface(_wave_capture(), fit="plane", region=WAVE_REGION, window=3,
                                          device=ONE_DEVICE, seed=seed, refine=refine)
    p = surface.positions[surface.completed].astype(np.float64)
    amp, period = _sine_fit(surface.fit.to_param(p)[:, 0], surface.fit.distance(p))
    q = report.quality
    return {"amplitude_err": abs(amp / 0.08 - 1), "period_err": abs(period / 0.5 - 1),
            "volume_diff_pct": q["volume_diff_pct"], "slope": q["slope_diff_pct"] / q["slope_baseline_diff_pct"],
            "hist": q["hist_distance"], "hist_baseline": q["hist_distance"] / q["hist_baseline"],
            "colour_step": q["colour_step_diff_pct"] / q["colour_step_baseline_diff_pct"]}


@claim
def completion_wave(seed):
    """tests/test_completion.py::test_wave_keeps_amplitude_and_period."""
    return _wave(seed)


@claim
def completion_wave_refined(seed):
    """tests/test_completion.py::test_refinement_passes_keep_the_wave_and_change_sources."""
    return _wave(seed, refine=2)


@claim
def completion_balance(seed):
    """tests/test_completion.py::test_balanced_pick_stays_in_the_penalized_set_and_tracks_the_histogram:
    histogram distance of the balanced pick / the paper's uniform pick, the case, the picks
    and the offers drawn from seed (the test: case 0, picks 1, offers 2)."""
    from test_completion import _balance_case

    from geosynth.completion.matching import Matches

    bal, level = _balance_case(seed=seed)
    uni, _ = _balance_case(seed=seed)
    rng, rng_u, offer = (np.random.default_rng([seed, k]) for k in (1, 1, 2))
    for _ in range(300):
        s = offer.choice(len(level), 12, replace=False)
        code = offer.integers(1000, 1501, 12).astype(np.uint32)
        m = Matches(s, s, np.zeros(12, np.int64), code, code / 1e4, np.ones(12, bool), code.min() / 1e4)
        bal.add(int(s[bal.pick(m, rng)]))
        uni.add(int(s[rng_u.integers(12)]))
    dist = [0.5 * np.abs(b.counts / b.n - b.share).sum(1).mean() for b in (bal, uni)]
    return {"balanced_uniform": dist[0] / dist[1]}


@claim
def completion_tower(seed):
    """tests/test_completion.py::test_tower_keeps_its_ledges_at_the_median_spacing."""
    from geosynth.completion.examples import tower_example
    from geosynth.completion.synthesis import complete_surface

    ex = tower_example()
    surface, report, _ = complete_surface(ex.capture, fit=ex.fit, region=ex.region, window=3, rotations=1,
                                          frames="fit", refine=0, spacing="median", device=ONE_DEVICE,
                                          seed=seed)  # the test's explicit pre-#32 settings
    h = surface.fit.distance(surface.positions.astype(np.float64))
    q = report.quality
    return {"ledge_diff": abs(np.mean(h[surface.completed] > 0.035) - np.mean(h[surface.captured] > 0.035)),
            "volume": q["volume_diff_pct"] / q["volume_baseline_diff_pct"]}


def summary(rows):
    keys = rows[0].keys()
    out = {}
    for k in keys:
        v = np.array([r[k] for r in rows], float)
        worst = v.min() if k.endswith("_min") else v.max()
        sd = float(v.std(ddof=1)) if len(v) > 1 else 0.0
        out[k] = {"mean": round(float(v.mean()), 4), "worst": round(float(worst), 4), "sd": round(sd, 4),
                  "min": round(float(v.min()), 4), "max": round(float(v.max()), 4)}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("claims", nargs="*", help=f"of {', '.join(CLAIMS)} (all when none)")
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--out", help="append the JSON lines to this file too")
    args = ap.parse_args()
    setting = os.environ.get("OPENBLAS_CORETYPE", "native")
    for name in args.claims or list(CLAIMS):
        rows, t0 = [], time.perf_counter()
        for seed in range(args.first, args.first + args.seeds):
            t = time.perf_counter()
            r = {k: float(v) for k, v in CLAIMS[name](seed).items()}
            rows.append(r)
            print(json.dumps({"claim": name, "seed": seed, "s": round(time.perf_counter() - t, 2), **r}), flush=True)
        line = {"claim": name, "setting": setting, "seeds": f"{args.first}-{args.first + args.seeds - 1}",
                "s": round(time.perf_counter() - t0, 1), "summary": summary(rows)}
        print(json.dumps(line), flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
