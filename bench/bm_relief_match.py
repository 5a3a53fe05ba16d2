"""M4 FindMatches speed: (target, sample, rotation) triples per second, per backend, vs the
NumPy oracle (geosynth.completion.reference.relief_scores_reference).

The case is the paper's Fig. 9 size (Breckon and Fisher, "3D Surface Relief and Colour
Completion", Sec. 5: s = 12,852 samples, t = 7,200 targets, R = 4): a plane with a wave
and noise relief and colours, the captured part sampled at twice the targets' density (as
after the 1-to-4 oversampling), samples and targets in one Delaunay triangulation, queries
the 2-ring neighbourhoods of boundary targets (sigma = 5 * spacing / 6.4). Rows:

- ``score``: every query against every sample and rotation, no limit (the whole
  neighbourhood evaluated for every valid triple);
- ``find_matches``: the same queries as GrowSurface asks them (MaxErrThreshold 0.1,
  tolerance 1.1): probe passes on every 256th and 16th sample set each query's limit, then
  the pruned full pass (the same BestMatches as ``score``, checked here);
- ``oracle``: the NumPy twin on a subset of the samples.

The note projects the whole completion's FindMatches (7,200 targets x 12,852 samples x 4)
at the row's rate, by wall time and by CPU time (process time, all threads: the machine
is shared, so wall times vary with the other load; 2 idle cores give ~CPU s / 2 for
opencl, CPU s for Warp's one-thread cpu). Usage: python bench/bm_relief_match.py [--quick]
[--devices cpu,opencl:0:0] [--out FILE]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import Row, finish, parse_args, start, table, time_call  # noqa: E402

FIG9_TRIPLES = 7200 * 12852 * 4


def options(argv=None) -> argparse.Namespace:
    def extras(p):
        p.add_argument("--queries", type=int, default=16, help="targets per batch (default 16)")
    return parse_args(__doc__, argv, quick="a 1,600-sample plane, 4 queries", extras=extras,
                      default_out=str(Path(__file__).resolve().parent / "out" / "bm_relief_match.md"))


def plane_case(samples_side: int, seed: int = 0):
    """(ReliefIndex.build keyword arguments, triangles, target spacing): samples at spacing
    0.5 over a square, targets at spacing 1 over an equal square beside it."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    n = samples_side
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2) * 0.5
    g = g + rng.uniform(-0.1, 0.1, g.shape)
    m = (n + 1) // 2
    t = np.stack(np.meshgrid(np.arange(m), np.arange(m), indexing="ij"), -1).reshape(-1, 2).astype(float)
    t = t * [1.0, 0.5 * (n - 1) / (m - 1)] + [0.5 * n + 0.25, 0.0]
    xy = np.concatenate([g, t])
    tri = Delaunay(xy).simplices
    v, s = len(xy), len(g)
    h = 0.3 * np.sin(xy[:, 0] * 0.9) * np.cos(xy[:, 1] * 0.7) + 0.05 * rng.standard_normal(v)
    disp = np.zeros((v, 3))
    disp[:s, 2] = h[:s]
    tex = np.zeros(v, bool)
    tex[:s] = True
    col = np.clip(np.c_[0.5 + h, 0.45 + 0.5 * h, 0.3 + 0 * h], 0, 1)
    return dict(base=np.c_[xy, np.zeros(v)], normals=np.tile([0.0, 0.0, 1.0], (v, 1)), displacements=disp,
                textured=tex, triangles=tri, samples=np.arange(s), colours=col), 1.0


def boundary_queries(index, triangles, count: int, spacing: float, w: int = 2):
    from geosynth.completion import matching as rm

    v = index.n_vertices
    nb = [set() for _ in range(v)]
    for a, b, c in triangles:
        nb[a] |= {b, c}
        nb[b] |= {a, c}
        nb[c] |= {a, b}

    def ring(t):
        seen, cur = {t}, {t}
        for _ in range(w):
            cur = set().union(*(nb[x] for x in cur)) - seen
            seen |= cur
        return sorted(seen - {t})

    tex = index.textured
    base = index.base
    near = lambda t: all(np.linalg.norm(base[x] - base[t]) < 1.6 * spacing for x in nb[t])  # noqa: E731 (no hull slivers)
    cands = [t for t in range(v) if not tex[t] and any(tex[x] for x in nb[t]) and near(t)]
    pick = [cands[i] for i in np.linspace(0, len(cands) - 1, count).astype(int)]
    rings = [ring(t) for t in pick]
    start = np.r_[0, np.cumsum([len(r) for r in rings])]
    return rm.neighbourhood_queries(index, pick, start, np.concatenate(rings), (2 * w + 1) * spacing / 6.4,
                                    rotations=4, mu=0.5)


def _cpu_time(fn, repeats: int) -> float:
    """Smallest process time (all threads) of ``fn()`` over ``repeats`` calls, after one
    warm-up call."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def main(argv=None) -> int:
    from geosynth.completion import matching as rm
    from geosynth.completion.reference import relief_scores_reference

    args = options(argv)
    devices = start(args)
    side = 40 if args.quick else 113  # 113^2 = 12,769 samples (the paper's 12,852)
    nq = 4 if args.quick else args.queries
    kw, spacing = plane_case(side)
    rows, notes = [], []
    codes_by_device = {}
    for dev in devices:
        t0 = time.perf_counter()
        index = rm.ReliefIndex.build(**kw, device=dev)
        build = time.perf_counter() - t0
        q = boundary_queries(index, kw["triangles"], nq, spacing)
        triples = nq * len(index.samples) * 4
        full = rm.score(index, q)
        codes_by_device[dev] = full.codes
        t_score = time_call(lambda: rm.score(index, q), min_time=0.5, max_repeats=5)
        t_find = time_call(lambda: rm.find_matches(index, q, 0.1), min_time=0.5, max_repeats=5)
        c_score = _cpu_time(lambda: rm.score(index, q), 2)
        c_find = _cpu_time(lambda: rm.find_matches(index, q, 0.1), 5)
        got = rm.find_matches(index, q, 0.1)
        same = all(np.array_equal(m.code, full.codes[i][full.codes[i] <= np.floor(1.1 * full.codes[i][full.valid[i]].min())])
                   for i, m in enumerate(got) if len(m.code))
        entries = np.diff(q.qstart).mean()
        for name, t, c in (("score", t_score, c_score), ("find_matches", t_find, c_find)):
            rows.append(Row("FindMatches", f"geosynth {dev} {name}", t, triples, 0, False,
                            f"CPU {c * 1e3:.0f} ms/call; Fig. 9 FindMatches ~{FIG9_TRIPLES * t / triples:.0f} s wall, "
                            f"~{FIG9_TRIPLES * c / triples:.0f} CPU s"))
        notes.append(f"- {dev}: index build {build:.2f} s (V = {index.n_vertices}, S = {len(index.samples)}), "
                     f"{entries:.1f} textured neighbours a query, valid triples {full.valid.mean():.1%}, "
                     f"find_matches = unpruned selection: {same}, matches a query "
                     f"{np.mean([len(m.code) for m in got]):.1f}")
    sub = np.arange(0, len(kw["samples"]), max(1, len(kw["samples"]) // 300))
    index = rm.ReliefIndex.build(**kw, device=devices[0])
    q = boundary_queries(index, kw["triangles"], 2, spacing)
    t0 = time.perf_counter()
    ref = relief_scores_reference(index, q, slots=sub)
    t_ref = time.perf_counter() - t0
    full = rm.score(index, q).codes[:, sub]
    rows.append(Row("FindMatches", "NumPy oracle", t_ref, 2 * len(sub) * 4, 0, True,
                    f"equal to {devices[0]}: {np.array_equal(ref, full)}; Fig. 9 ~{FIG9_TRIPLES / (2 * len(sub) * 4 / t_ref):.0f} s"))
    if len(codes_by_device) > 1:
        first = next(iter(codes_by_device.values()))
        notes.append(f"- codes bit-identical on {', '.join(codes_by_device)}: "
                     f"{all(np.array_equal(first, c) for c in codes_by_device.values())}")
    body = table(rows).replace("elements/s", "triples/s") + "\n\n" + "\n".join(notes)
    return finish(body, args, title=f"# bm_relief_match: M4 FindMatches ({len(kw['samples'])} samples, {nq} queries, R = 4)")


if __name__ == "__main__":
    raise SystemExit(main())
