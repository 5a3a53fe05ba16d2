"""M1 benchmark: exact block matching (the paper's Table 1 cases) and end-to-end synthesis.

Matching: sources of 64^3 (block 8), 128^3 (block 16) and 256^3 (block 32) samples of a
real distance field (random periodic spheres, like the BALLS exemplar, quantized to
uint8 with a band of half a block). Queries are the first finest-level queries of a real 2-level
synthesis from that source (upsampled coarse content plus earlier matches). Per
backend: the mean time per exact match of the cascade search (default; alone, and with
the coherence bound synthesis gives it), the paper's best-first tree and our own linear
search (every block scored by the gather kernel, no early exit), the speedup over
linear, and the paper's time per match (2 GHz PC, 2004). Every search returns the same
block; the benchmark checks it.

End to end: ``synthesize_geometry`` with the defaults (64 samples across the exemplar,
128 x 128 target, 3 levels, block 16) per backend and built-in exemplar, plus a full
64^3 -> 128^3 cube of spheres, with the time of each stage.

Batch: texture optimization's matching with the batched cascade (every query of an
iteration's chunk in one fused launch) against one launch per query (the search before
it), ``synthesize_geometry(method="optimize")`` with no quality numbers, per backend and
exemplar: synthesis seconds (wall and process CPU), the ratio, and that the fields are
the same bits.

Quality: per built-in exemplar and method (paper, graphcut, optimize), with the
defaults otherwise, the structure metrics (elements, or debris / slopes / overhangs)
and the mean block distance beside random tiling's, whether it grew as a slab, and
the time, on the first OpenCL device given (else the first device; a seed gives the
same field on every device).

Usage: python bench/bm_volume.py [--quick] [--devices cpu,opencl:0:0] [--out FILE]
       [--budget SECONDS] [--part matching|end-to-end|batch|quality] [--cases 64,128,256]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import finish, parse_args, start  # noqa: E402

import geosynth  # noqa: E402
from geosynth.compute.scoring import GatherScorer  # noqa: E402
from geosynth.volume import synthesis as volume  # noqa: E402
from geosynth.volume.blocks import block_offsets  # noqa: E402
from geosynth.volume.cascade import CascadeSearch  # noqa: E402
from geosynth.volume.examples import EXEMPLARS, spheres_field  # noqa: E402 (the end-to-end cube)
from geosynth.volume.synthesis import quantize_field, synthesize_geometry, synthesize_volume  # noqa: E402
from geosynth.volume.tree import BlockSearch  # noqa: E402

PAPER_SECONDS = {(64, 8): 0.025, (128, 16): 0.5, (256, 32): 10.0}
# Warp on the CPU runs one thread: linear searches past this many sample comparisons
# per match are estimated from the smaller cases instead of run.
WARP_CPU_LINEAR_LIMIT = 2e9


def sphere_source(side: int, block: int, seed: int) -> np.ndarray:
    """A side^3 uint8 field of random periodic spheres (radii 3-7 samples, 40 per 64^3).

    Quantized with a band of half a block, so only distances within the band matter:
    each sphere updates the periodic box of samples within radius + band of its centre
    (exact there), which takes seconds for 256^3 where
    :func:`geosynth.volume.examples.spheres_field`'s whole-grid loop takes minutes.
    """
    rng = np.random.default_rng(seed)
    count = max(8, int(40 * (side / 64) ** 3))
    band = block / 2
    field = np.full((side, side, side), band, np.float32)
    for centre, radius in zip(rng.random((count, 3)) * side, rng.uniform(3.0, 7.0, count)):
        reach = int(np.ceil(radius + band))
        axes = [np.arange(int(np.floor(c)) - reach, int(np.floor(c)) + reach + 2) for c in centre]
        d2 = sum(np.ix_(*[(a - c) ** 2 for a, c in zip(axes, centre)]))
        box = np.ix_(*[a % side for a in axes])
        field[box] = np.minimum(field[box], (np.sqrt(d2) - radius).astype(np.float32))
    return quantize_field(field, band)


class _Enough(Exception):
    pass


def synthesis_queries(source: np.ndarray, block: int, count: int, dev: str) -> tuple[list, list]:
    """The first ``count`` finest-level queries of a real synthesis from ``source``.

    A 2-level run (block ``block // 2``, then ``block``) to a target of the source's size
    (at most 128 per side);
    the finest level's queries hold upsampled coarse content and earlier matches, as in
    any multiresolution run. Returns the queries and their coherence bounds (the SSD of
    a neighbour's match moved on, or None), which synthesis passes as thresholds.
    """
    queries, bounds = [], []
    original = volume.Matcher.nearest

    def record(self, query, threshold=None, order=None):
        if self.block == block and self.finest:
            queries.append(query.copy())
            bounds.append(threshold)
            if len(queries) >= count:
                raise _Enough
        return original(self, query, threshold, order)

    original_init = volume.Matcher.__init__

    def init(self, src, b, device, search):
        original_init(self, src, b, device, search)
        self.finest = src.shape == source.shape

    volume.Matcher.nearest, volume.Matcher.__init__ = record, init
    try:
        # The coarse level (half the resolution) matches half-size blocks, as a multiresolution
        # run would; its queries start from random samples, which no bound prunes well.
        # The target is at most 128^3: the 256^3 source's queries come from a 128^3 target (a
        # 256^3 one spends minutes on coarse queries seeded at random, which no bound prunes).
        target = tuple(min(s, 128) for s in source.shape)
        synthesize_volume(source, target, levels=2, block=[block // 2, block], device=dev, progress=False,
                          method="paper")  # the paper's scan queries
    except _Enough:
        pass
    finally:
        volume.Matcher.nearest, volume.Matcher.__init__ = original, original_init
    return queries, bounds


PASSES = 3  # timed passes over the same queries; the best is reported, all are listed


def time_searches(name, nearest, queries, budget):
    """Seconds per match: the best pass's mean over as many queries as fit in ``budget``
    (>= 1) per pass, the answers, and every pass's mean (this machine's 2 vCPUs are shared:
    the same pass ran up to 2x slower at times, so one pass is a poor measure)."""
    nearest(queries[0])  # warm-up: kernels are built on first use
    pass_means, answers = [], []
    for _ in range(PASSES):
        answers, spent = [], 0.0
        for q in queries:
            t0 = time.perf_counter()
            answers.append(nearest(q))
            spent += time.perf_counter() - t0
            if spent > budget:
                break
        pass_means.append(spent / len(answers))
        if spent > budget:  # a slow search: one pass is all the budget allows
            break
    return min(pass_means), answers, pass_means


def matching(devices, cases, n_queries, budget) -> list[str]:
    lines = ["## Exact matching (paper Table 1 cases)", "",
             "| source / block | device | search | build | time/match (best pass) | queries x passes (pass means) | vs linear | paper (2004) | vs paper | blocks alive after each stage |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---|"]
    linear_rate = {}  # sample comparisons per second of the linear search, per device
    for side, block in cases:
        source = sphere_source(side, block, seed=side)
        t0 = time.perf_counter()
        queries, coherence = synthesis_queries(source, block, n_queries, devices[-1])
        n_blocks = (side - block + 1) ** 3
        paper = PAPER_SECONDS.get((side, block))
        print(f"  {side}^3 / block {block}: {n_blocks:,} blocks, {len(queries)} queries "
              f"(recorded in {time.perf_counter() - t0:.0f} s)", flush=True)
        for dev in devices:
            results = {}
            t0 = time.perf_counter()
            cascade = CascadeSearch(source, block, device=dev)
            build_c = time.perf_counter() - t0
            alive = []

            def run_cascade(q, cascade=cascade):
                r = cascade.nearest(q)
                alive.append(cascade.last_info["alive"])
                return r

            results["cascade"] = (build_c,) + time_searches("cascade", run_cascade, queries, budget)
            want = results["cascade"][2]
            bound_of = {id(q): b for q, b in zip(queries, coherence)}
            results["cascade + coherence bound"] = (build_c,) + time_searches(
                "cascade+", lambda q, cascade=cascade: cascade.nearest(q, threshold=bound_of[id(q)]), queries, budget)
            if side <= 128:
                t0 = time.perf_counter()
                tree = BlockSearch(source, block, device=dev)
                build_t = time.perf_counter() - t0
                results["tree"] = (build_t,) + time_searches("tree", tree.nearest, queries, budget)
                del tree
            work = n_blocks * block**3
            if dev == "cpu" and work > WARP_CPU_LINEAR_LIMIT:
                rate = linear_rate.get("cpu")
                results["linear"] = (0.0, work / rate if rate else float("nan"), None, [])
            else:
                t0 = time.perf_counter()
                scorer = GatherScorer(geosynth.to_device(source, dev), block_offsets(block))
                build_l = time.perf_counter() - t0

                def run_linear(q, scorer=scorer):
                    s = scorer(q.reshape(-1))
                    i = int(np.argmin(s))  # lowest index on ties
                    return cascade.origin_of(i), int(s[i])

                results["linear"] = (build_l,) + time_searches("linear", run_linear, queries, budget / 2)
                linear_rate[dev] = work / results["linear"][1]
            lin_t = results["linear"][1]
            for search, (build, per, answers, pass_means) in results.items():
                if answers is not None:
                    k = min(len(answers), len(want))  # each search times as many queries as fit its budget
                    assert answers[:k] == want[:k], f"{search} on {dev} disagrees with the cascade"
                stages = ""
                if search == "cascade" and alive:
                    stages = " -> ".join(f"{v:,.0f}" for v in np.mean(np.array(alive), axis=0))
                note_q = str(len(answers)) if answers is not None else "estimated"
                if len(pass_means) > 1:
                    note_q += " x " + str(len(pass_means)) + " (" + ", ".join(f"{m * 1e3:,.2f}" for m in pass_means) + " ms)"
                vs_paper = "-" if not paper else f"{paper / per:,.0f}x" if paper >= 10 * per else f"{paper / per:.2f}x"
                lines.append(f"| {side}^3 / {block} | {dev} | {search} | {build:.2f} s | {per * 1e3:,.2f} ms | {note_q} | "
                             f"{lin_t / per:,.1f}x | {paper} s | {vs_paper} | {stages} |")
                print("   ", lines[-1], flush=True)
    lines += ["", "Linear rows marked 'estimated' were not run (Warp's CPU backend is one thread): their time is "
              "the work divided by the rate measured on the smallest case. 'vs paper' is the paper's time per "
              "match divided by ours."]
    return lines


def end_to_end(devices, exemplars, size, source_resolution, cube) -> list[str]:
    lines = ["## End to end (synthesize_geometry defaults: 3 levels, block 16)", "",
             "| exemplar | device | source (x, y, z) | target (x, y, z) | distance field | level 1 | level 2 | level 3 | "
             "mesh | synthesis total | quality numbers | whole run | synthesis / random tiling (mean block distance) |",
             "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for name in exemplars:
        for dev in devices:
            t0 = time.perf_counter()
            r = synthesize_geometry(name, size, source_resolution=source_resolution, device=dev, progress=False)
            whole = time.perf_counter() - t0
            t = r.timings
            lv = [t.get(f"synthesis level {i}", 0.0) + t.get(f"synthesis level {i} search build", 0.0) for i in (1, 2, 3)]
            q = r.quality
            src = " x ".join(str(v) for v in r.volume.source.shape[::-1])
            tgt = " x ".join(str(v) for v in r.volume.quantized.shape[::-1])
            lines.append(f"| {name} | {dev} | {src} | {tgt} | {t['exemplar distance field']:.2f} s | {lv[0]:.2f} s | {lv[1]:.2f} s | "
                         f"{lv[2]:.2f} s | {t['marching cubes + smoothing']:.2f} s | {t['synthesis total']:.2f} s | "
                         f"{t.get('quality numbers', 0):.2f} s | {whole:.2f} s | "
                         f"{q['synthesis']['mean']:.0f} / {q['random tiling']['mean']:.0f} |")
            print("   ", lines[-1], flush=True)
    if cube:
        source = spheres_field(64, seed=0)
        for dev in devices:
            r = synthesize_volume(source, 128, levels=3, block=16, device=dev, progress=False)
            t = r.timings
            lines.append(f"| spheres cube (field) | {dev} | 64 x 64 x 64 | 128 x 128 x 128 | - | {t['level 1']:.2f} s | "
                         f"{t['level 2']:.2f} s | {t['level 3']:.2f} s | - | {t['total']:.2f} s | - | {t['total']:.2f} s | - |")
            print("   ", lines[-1], flush=True)
    lines += ["", "Level times include building the level's search. 'whole run' adds making the exemplar mesh and "
              "computing the quality numbers (a second, random-tiling synthesis and 100 exact nearest-block "
              "searches each way)."]
    return lines


def _per_query(self, queries, thresholds=None):
    """CascadeSearch.nearest_batch as it was before the batched kernel: one search (one
    fused launch) per query."""
    origins = np.empty((len(queries), 3), np.int64)
    ssds = np.empty(len(queries), np.int64)
    alive = []
    for i, q in enumerate(queries):
        t = None if thresholds is None or thresholds[i] is None else int(thresholds[i])
        origins[i], ssds[i] = self.nearest(q, threshold=t)
        alive.append(list(self.last_info["alive"]))
    return origins, ssds, alive


def batch(devices, exemplars, size, source_resolution, repeats: int = 2) -> list[str]:
    lines = ["## Texture optimization: one launch per chunk of queries vs one per query", "",
             "| exemplar | device | matches | per query: synthesis s (CPU s) | batched: synthesis s (CPU s) | "
             "speed-up (wall, CPU) | same field |", "|---|---|---:|---:|---:|---:|---|"]
    for name in exemplars:
        for dev in devices:
            runs = {}
            for mode in ("per query", "batched"):
                best = None
                for _ in range(repeats):
                    saved = CascadeSearch.nearest_batch
                    if mode == "per query":
                        CascadeSearch.nearest_batch = _per_query
                    try:
                        c0 = time.process_time()
                        r = synthesize_geometry(name, size, source_resolution=source_resolution, device=dev,
                                                progress=False, method="optimize", quality_samples=0)
                        cpu = time.process_time() - c0
                    finally:
                        CascadeSearch.nearest_batch = saved
                    wall = r.timings["synthesis total"]
                    if best is None or wall < best[0]:
                        best = (wall, cpu, r)
                runs[mode] = best
            (w0, c0, r0), (w1, c1, r1) = runs["per query"], runs["batched"]
            same = np.array_equal(r0.volume.quantized, r1.volume.quantized)
            matches = sum(lv.matches for lv in r1.volume.levels)
            lines.append(f"| {name} | {dev} | {matches} | {w0:.2f} ({c0:.2f}) | {w1:.2f} ({c1:.2f}) | "
                         f"{w0 / w1:.2f}x, {c0 / c1:.2f}x | {'yes' if same else 'NO'} |")
            print("   ", lines[-1], flush=True)
    lines += ["", f"Best of {repeats} runs each; CPU s = process time of all threads (the whole run: exemplar "
              "field, synthesis, mesh). Matches: exact searches over all levels and iterations."]
    return lines


def _structure_text(report: dict) -> str:
    """A short cell: "elements 0.74", or "debris 0.0%, slopes 0.96, overhangs 0.0% (exemplar 0.0%)"."""
    if report["kind"] == "elements":
        e = report["elements"]["score"]
        return "elements n/a" if np.isnan(e) else f"elements {e:.2f}"
    s = report["surface"]
    return (f"debris {100 * s['debris']['output']:.1f}%, slopes {s['slopes']['score']:.2f}, overhangs "
            f"{100 * s['overhangs']['output']:.1f}% (exemplar {100 * s['overhangs']['exemplar']:.1f}%)")


def quality(device: str, exemplars, size: int, source_resolution: int, methods=volume.METHODS) -> list[str]:
    """The quality table: per exemplar and method, structure and block distance beside random tiling."""
    lines = [f"## Quality per method (synthesize_geometry defaults: 3 levels, block 16; {source_resolution} "
             f"samples across -> {size}; device {device})", "",
             "| exemplar | method | slab | structure | random tiling's | block distance (synthesis / random) | "
             "ratio | synthesis | whole run |",
             "|---|---|---|---|---|---:|---:|---:|---:|"]
    for name in exemplars:
        for method in methods:
            t0 = time.perf_counter()
            r = synthesize_geometry(name, size, source_resolution=source_resolution, device=device, progress=False,
                                    method=method)
            whole = time.perf_counter() - t0
            q = r.quality
            syn, ran = q["synthesis"], q["random tiling"]
            default = volume.resolve_method(volume.DEFAULT_METHOD, r.volume.slab) == method
            lines.append(f"| {name} | {method}{' (default)' if default else ''} | {'yes' if r.volume.slab else 'no'} | "
                         f"{_structure_text(syn['structure'])} | {_structure_text(ran['structure'])} | "
                         f"{syn['mean']:.0f} / {ran['mean']:.0f} | {syn['mean'] / ran['mean']:.2f} | "
                         f"{r.timings['synthesis total']:.1f} s | {whole:.1f} s |")
            print("   ", lines[-1], flush=True)
    lines += ["", "Targets: elements >= 0.6 (pieces), debris <= 0.5% (one piece), slopes >= 0.8 and overhangs "
              "within 5 points of the exemplar's (surfaces), block distance ratio <= 0.5, whole run <= 60 s. "
              "'whole run' includes the exemplar's distance field and the quality numbers (a random-tiling "
              "synthesis and 100 exact nearest-block searches each way)."]
    return lines


def _options(parser) -> None:
    parser.add_argument("--budget", type=float, default=20.0, help="seconds per search and case (at least one query)")
    parser.add_argument("--part", choices=["all", "matching", "end-to-end", "batch", "quality"], default="all")
    parser.add_argument("--cases", default=None, type=_sides,
                        help="comma-separated matching source sides, e.g. 64,128 (default: 64,128,256)")


def _sides(text: str) -> set[int]:
    try:
        return {int(side) for side in text.split(",")}
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give whole numbers separated by commas, e.g. 64,128") from None


def options(argv=None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    return parse_args(__doc__, argv, quick="small cases, for a smoke run", extras=_options)


def main(argv=None) -> int:
    args = options(argv)
    if args.quick:
        cases, n_queries, exemplars, size, res, cube = [(32, 8)], 4, ["terrain"], 64, 32, False
        quality_exemplars = ["terrain", "domes"]
    else:
        cases, n_queries, exemplars, size, res, cube = [(64, 8), (128, 16), (256, 32)], 50, list(EXEMPLARS), 128, 64, True
        quality_exemplars = list(EXEMPLARS)
    if args.cases:
        cases = [case for case in cases if case[0] in args.cases]
        if not cases:
            args.parser.error(f"--cases {','.join(map(str, sorted(args.cases)))}: choose among 32 (with --quick), 64, 128, 256")
    devices = start(args)
    lines = []
    if args.part in ("all", "matching"):
        lines += matching(devices, cases, n_queries, args.budget) + [""]
    if args.part in ("all", "end-to-end"):
        lines += end_to_end(devices, exemplars, size, res, cube) + [""]
    if args.part in ("all", "batch"):
        lines += batch(devices, ["terrain", "chainmail"] if not args.quick else ["terrain"], size, res) + [""]
    if args.part in ("all", "quality"):
        # the targets are OpenCL's; the fields are the same on every device, the times are not
        lines += quality(next((d for d in devices if d.startswith("opencl")), devices[0]), quality_exemplars, size, res)
    return finish("\n".join(lines), args)


if __name__ == "__main__":
    sys.exit(main())
