"""M2 per-patch warping and blending ("Geometry texture synthesis with point-set
surfaces", Sec. 5.2 and 5.3) on the built-in point textures at the paper's point counts.

Each case builds one patch step as the synthesis does: N_k is a window of the exemplar
(the output so far, kept on the L-shaped -x / -y side of the patch box and beyond), F_k
the window at the same place shifted by up to 3 spacings (a near match, as the search
returns), translated into the box (patch 0.4 of the exemplar's shorter side,
extra region 0.2 and overlap 0.25 of the patch, extended by max(2 spacings, half the
overlap)). Timed: warp_patch (pairing, spline, normals) and blend_patch (line crossings
and projections on N_k's MLS surface) per patch, best of repeated calls. Reported beside
them: the sizes (S sources, T targets, overlap points), the pairs, and the seam error
(RMS field difference along the overlap's outer edge, in spacings) of the raw patch,
the warped one and the blended one. Both steps run on the host (NumPy/SciPy; the blend
in float64 so that its output is the same bits on every device): there is one row per
case, not per device.

Usage: python bench/bm_warp_blend.py [--quick] [--out FILE]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import Row, finish, parse_args, start, table, time_call  # noqa: E402

from geosynth.pointtexture.blending import blend_patch, overlap_ramp, seam_error  # noqa: E402
from geosynth.pointtexture.examples import point_texture_example  # noqa: E402
from geosynth.pointtexture.warping import WARP_PRESETS, surface_variation, warp_patch  # noqa: E402


def patch_step(name: str, count: int | None, rng: np.random.Generator):
    """One synthesis step's inputs, in output coordinates with the box at the origin."""
    ex = point_texture_example(name, count=count, seed=0)
    p, n = ex.points, ex.normals
    sp = ex.spacing
    ext = (ex.box_max - ex.box_min)[:2]
    size = 0.4 * float(ext.min())
    extra, ov = 0.2 * size, 0.25 * size
    margin = max(2 * sp, 0.5 * ov)
    reach = 6 * sp
    side = size + extra
    lo, hi = np.zeros(2), np.full(2, side)

    def window(origin, a, b):
        sel = ((p[:, :2] >= origin + a) & (p[:, :2] < origin + b)).all(axis=1)
        return sel

    room = ext - side - 2 * (margin + reach)
    o1 = ex.box_min[:2] + margin + reach + rng.uniform(0, 1, 2) * np.maximum(room, 0)
    # F_k: the same place shifted by up to 3 spacings, a near match as the search finds
    # one (a random window would not match at all: warping is not meant to fix that).
    o2 = o1 + rng.uniform(-3, 3, 2) * sp
    # N_k: the output so far around the box's -x / -y sides.
    sel = window(o1, -(margin + reach), hi + margin)
    rel = p[sel, :2] - o1
    keep = (rel[:, 0] < ov) | (rel[:, 1] < ov)
    nb_p = np.c_[rel[keep], p[sel, 2][keep]]
    nb_n = n[sel][keep]
    # F_k: another window, translated into the box, extended by the margin.
    sel2 = window(o2, -margin, hi + margin)
    fp = np.c_[p[sel2, :2] - o2, p[sel2, 2]]
    fn = n[sel2]
    var = surface_variation(p)[sel2]
    zlo, zhi = float(ex.box_min[2]), float(ex.box_max[2])
    box_min, box_max = np.r_[lo, zlo], np.r_[hi, zhi]
    ramp_nb = overlap_ramp(nb_p, box_min, box_max, ov, ov)
    inside = ((nb_p[:, :2] >= lo) & (nb_p[:, :2] <= hi)).all(axis=1) & (ramp_nb > 0)
    e = np.linspace(0.02, 0.98, 48) * side
    edge_xy = np.concatenate([np.c_[np.full(48, 0.02 * ov), e], np.c_[e, np.full(48, 0.02 * ov)]])
    # Edge samples on N_k's surface height: its nearest point's z.
    from scipy.spatial import cKDTree

    _, near = cKDTree(nb_p[:, :2]).query(edge_xy)
    edge = np.c_[edge_xy, nb_p[near, 2]]
    return dict(ex=ex, sp=sp, fp=fp, fn=fn, var=var, nb_p=nb_p, nb_n=nb_n, inside=inside, box_min=box_min,
                box_max=box_max, ov=ov, edge=edge)


def rows_for(name: str, count: int | None, rng, repeats: float) -> list[Row]:
    s = patch_step(name, count, rng)
    weights = WARP_PRESETS[name]
    sp = s["sp"]

    def warp():
        return warp_patch(s["fp"], s["fn"], s["nb_p"][s["inside"]], s["nb_n"][s["inside"]], s["box_min"], s["box_max"],
                          weights, sp, np.random.default_rng(0), src_variation=s["var"])

    wr = warp()
    ramp = overlap_ramp(wr.points, s["box_min"], s["box_max"], s["ov"], s["ov"])

    def blend():
        return blend_patch(wr.points, wr.normals, ramp, s["nb_p"], s["nb_n"], sp)

    bp, bn = blend()
    t_warp = time_call(warp, min_time=repeats)
    t_blend = time_call(blend, min_time=repeats)
    seam = [seam_error(a, b, s["nb_p"], s["nb_n"], s["edge"], sp)
            for a, b in ((s["fp"], s["fn"]), (wr.points, wr.normals), (bp, bn))]
    n_s, n_t, n_o = len(s["fp"]), int(s["inside"].sum()), int((ramp > 0).sum())
    case = f"{name} ({len(s['ex'].points):,} pts): S {n_s:,}, T {n_t:,}, overlap {n_o:,}"
    note_w = f"|Q| {len(wr.q_index)}, pairs {len(wr.pairs)}, fixed {len(wr.fixed)}, cost {wr.costs[0]:.1f} -> {wr.costs[-1]:.1f}"
    note_b = f"seam error (spacings): raw {seam[0]:.3f}, warped {seam[1]:.3f}, blended {seam[2]:.3f}"
    print(f"  {case}: warp {t_warp * 1e3:.1f} ms, blend {t_blend * 1e3:.1f} ms; {note_w}; {note_b}", flush=True)
    return [Row(case, "warp_patch (host)", t_warp, n_s, 0, False, note_w),
            Row(case, "blend_patch (host, float64)", t_blend, n_o, 0, False, note_b)]


def options(argv=None):
    """The command line (see the module docstring)."""
    return parse_args(__doc__, argv, quick="the height field and chainmail at a third of their counts, short repeats")


def main(argv=None) -> int:
    args = options(argv)
    start(args)
    rng = np.random.default_rng(0)
    if args.quick:
        cases, repeats = [("heightfield", 11_000), ("chainmail", 24_000)], 0.05
    else:
        cases, repeats = [("heightfield", None), ("chainmail", None), ("weave", None), ("flowers", None)], 0.5
    rows: list[Row] = []
    for name, count in cases:
        rows += rows_for(name, count, rng, repeats)
    body = table(rows).replace("| elements/s |", "| points/s |")
    body += ("\n\npoints/s: source points warped per second (warp rows), overlap points blended per second "
             "(blend rows). No peer implements these steps.")
    return finish(body, args)


if __name__ == "__main__":
    sys.exit(main())
