"""M2 geometry texture synthesis with point-set surfaces: the paper's Table 1 rows with the
built-in exemplars at its point counts, per stage (precompute, search, warp, blend, other,
total) and backend, beside the paper's times (Athlon 64 2.2 GHz, 2006) and the target: 10x faster than
the paper, a total at most a tenth of the paper's.

Rows (points in -> out; the paper's seconds): height field 33,194 -> 87,101 (30.7),
chainmail 71,454 -> 197,282 (38.0), weave 43,592 -> 126,139 (28.0), flowers 37,473 ->
68,290 (36.0); with --large also chainmail large 71,454 -> 2,947,085 (710.8). The output
size is chosen so that the output holds about the paper's point count (scale =
sqrt(out / points inside B)). A run of the first device before its timed one gives the quality numbers
beside random pasting (their time is not in the total).

Usage: python bench/bm_pointtexture.py [--quick] [--large] [--devices cpu,opencl:0:0] [--out FILE]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import finish, parse_args, start  # noqa: E402

# name, exemplar, points in, points out, the paper's (search, warp, blend, other, total) seconds
PAPER = [
    ("height field", "heightfield", 33_194, 87_101, (6.7, 11.2, 10.8, 2.0, 30.7)),
    ("chainmail", "chainmail", 71_454, 197_282, (8.5, 7.3, 18.4, 3.8, 38.0)),
    ("weave", "weave", 43_592, 126_139, (5.7, 7.7, 12.0, 2.6, 28.0)),
    ("flowers", "flowers", 37_473, 68_290, (11.0, 14.9, 7.4, 2.7, 36.0)),
]
LARGE = ("chainmail (large)", "chainmail", 71_454, 2_947_085, (147.5, 201.3, 316.2, 45.8, 710.8))
QUICK = [("height field (quick)", "heightfield", 8_000, 15_000, None), ("weave (quick)", "weave", 10_000, 18_000, None)]


def options(argv=None):
    def extras(p):
        p.add_argument("--large", action="store_true", help="also the chainmail (large) row (2.9M output points)")
        p.add_argument("--no-quality", action="store_true", help="skip the quality numbers")

    return parse_args(__doc__, argv, quick="two small rows (height field, weave), a smoke run", extras=extras)


def run_case(label, name, n_in, n_out, devices, quality):
    from geosynth.pointtexture.examples import point_texture_example
    from geosynth.pointtexture.synthesis import synthesize_point_texture

    tex = point_texture_example(name, count=n_in)
    inside = int(tex.inside_mask(tex.points, tex.box_min, tex.box_max).sum())
    scale = float(np.sqrt(n_out / inside))
    rows = []
    for k, dev in enumerate(devices):
        print(f"  {label}: {len(tex):,} points ({inside:,} inside B), scale {scale:.2f}, device {dev}", flush=True)
        report = None
        if quality and k == 0:  # the quality numbers from their own run: on two growth threads the
            # seam measurements overlap the synthesis, so the times come from a run without them
            _, report, _ = synthesize_point_texture(tex, scale=scale, device=dev, seed=0, quality=True)
        t0 = time.perf_counter()
        pts, plain, timings = synthesize_point_texture(tex, scale=scale, device=dev, seed=0, quality=False)
        wall = time.perf_counter() - t0
        report = report or plain
        rows.append((dev, len(tex), len(pts), timings, report, wall))
    return rows


def main(argv=None) -> int:
    args = options(argv)
    devices = start(args)
    cases = QUICK if args.quick else PAPER + ([LARGE] if args.large else [])
    lines = ["| case | device | points in -> out | precompute | search | warp | blend | other | total | paper total "
             "| total / (paper / 10) |", "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    quality_lines = []
    for label, name, n_in, n_out, paper in cases:
        # quality beside random pasting for the Table 1 sizes (the large row's would double its run)
        rows = run_case(label, name, n_in, n_out, devices, not args.no_quality and not args.quick and n_out < 500_000)
        for dev, a, b, t, report, _ in rows:
            ratio = f"{t['total'] / (paper[4] / 10):.2f}" if paper else "-"
            lines.append(f"| {label} | {dev} | {a:,} -> {b:,} | {t['precompute']:.2f} | {t['search']:.2f} | "
                         f"{t['warp']:.2f} | {t['blend']:.2f} | {t['other']:.2f} | {t['total']:.2f} | "
                         f"{paper[4] if paper else '-'} | {ratio} |")
            if report.quality:
                quality_lines.append(f"- {label} ({dev}): " + "; ".join(line.strip() for line in report.lines()[4:]))
        if paper:
            lines.append(f"| {label} | paper (2006) | {n_in:,} -> {n_out:,} | <10 | {paper[0]} | {paper[1]} | "
                         f"{paper[2]} | {paper[3]} | {paper[4]} | {paper[4]} | 10.00 |")
    body = "\n".join(lines) + "\n\nSeconds; the total excludes the quality numbers. The last column is the total " \
        "over a tenth of the paper's: at most 1.00 meets the target.\n"
    if quality_lines:
        body += "\nQuality (synthesized vs random pasting):\n\n" + "\n".join(quality_lines) + "\n"
    return finish(body, args, title="M2 point-set geometry texture synthesis (Table 1)")


if __name__ == "__main__":
    sys.exit(main())
