"""Relief grown from an example over any mesh (issue 34): our synthesis (``--method synth``, M4's
growth) beside the projection baseline (``--method project``, triplanar) on the issue's two shapes,
in one run: time and the quality numbers of :mod:`geosynth.relief.quality`.

Shapes: a vase (a body of revolution, ``trimesh.creation.revolve`` of a profile, 100 units tall,
closed) and a (2, 3) torus knot (genus 1: a circle swept along the knot with rotation-minimizing
frames, closed). Examples: the knurl and cobbles built-ins. For each: the refined mesh's vertex
count, seconds, the relief amplitude and dominant period per k-means region against the example's
(median and worst region), the share of the surface within 10% on both, the seam numbers (local
amplitude at the projection's blends and at the synthesis' patch borders, against inside), and
whether the output is watertight. Pictures (input, synth, project, close-ups) in bench/out/.

The issue's targets: amplitude and period within 10% everywhere (per region), no visible seam,
1 million output vertices in <= 60 s on 2 cores (opencl), watertight.

``--scale`` multiplies the examples' size (default 2.5: about 25,000 vertices on the vase; 1 gives
the issue's ~150,000); ``--quick``: scale 6, the vase only.

The speed target's run (about a million output vertices on the vase; peak RSS printed):
``python bench/bm_relief.py --devices opencl:0:0 --shapes vase --examples knurl --methods synth --resolution 0.2
--refine 0 --out bench/out/bm_relief_1m.md``.

Usage: python bench/bm_relief.py [--quick] [--devices opencl:0:0] [--scale S] [--shapes ..] [--examples ..]
[--methods ..] [--resolution R] [--refine N] [--out FILE]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import finish, parse_args, start  # noqa: E402

from geosynth.relief.shapes import torus_knot, vase  # noqa: E402

OUT = Path(__file__).resolve().parent / "out"


def _options(parser) -> None:
    parser.add_argument("--scale", type=float, default=2.5, help="the examples' size factor (default 2.5)")
    parser.add_argument("--shapes", default="vase,knot", help="comma-separated: vase, knot")
    parser.add_argument("--examples", default="knurl,cobbles", help="comma-separated built-ins")
    parser.add_argument("--methods", default="synth,project", help="comma-separated: synth, project")
    parser.add_argument("--resolution", type=float, default=None,
                        help="the output's longest edge, mesh units (default: grow_relief's)")
    parser.add_argument("--refine", type=int, default=1, help="refinement passes of the synthesis (default 1)")


def options(argv=None):
    """The command line (see the module docstring)."""
    return parse_args(__doc__, argv, extras=_options, default_out=str(OUT / "bm_relief.md"),
                      quick="the vase only, examples at scale 6, for a smoke run",
                      out="write the Markdown report here (default bench/out/bm_relief.md)")


def _row(shape, example, method, n_in, r, seconds) -> str:
    q = r.quality
    a = q.amplitude / q.example_amplitude
    p = q.period / q.example_period
    wa, wp = q.worst()
    watertight = r.to_mesh().is_watertight
    return (f"| {shape} | {example} | {method} | {n_in:,} -> {len(r.vertices):,} | {seconds:.1f} | "
            f"{np.nanmedian(a):.2f} ({100 * wa:.0f}%) | {np.nanmedian(p):.2f} ({100 * wp:.0f}%) | "
            f"{100 * q.within:.0f}% | "
            f"{100 * q.seam_projection:+.1f}% | {100 * q.seam_synthesis:+.1f}% | {'yes' if watertight else 'NO'} |")


def main(argv=None) -> int:
    import geosynth
    from geosynth.io.files import write_image
    from geosynth.relief.quality import relief_picture

    args = options(argv)
    devices = start(args)
    device = devices[0]
    scale = 6.0 if args.quick else args.scale
    shapes = ["vase"] if args.quick else [s for s in args.shapes.split(",") if s]
    makers = {"vase": vase, "knot": torus_knot}
    OUT.mkdir(exist_ok=True)
    quick = " --quick" if args.quick else ""
    extra = "".join(f" --{k} {getattr(args, k)}" for k in ("shapes", "examples", "methods", "resolution", "refine")
                    if getattr(args, k) is not None)
    lines = [f"Command: `python bench/bm_relief.py{quick} --devices {device} --scale {scale:g}{extra}`"
             f" ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}); examples at scale {scale:g}, seed 0.", "",
             "Ratios are result / example, per k-means region: median (worst region's deviation); within: the share of "
             "the surface in regions within 10% on both; seams: local amplitude on the border / inside - 1.", "",
             "| shape | example | method | vertices in -> out | s | amplitude ratio | period ratio | within 10% | "
             "seam at blends | seam at patch borders | watertight |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for shape in shapes:
        mesh = makers[shape]()
        for example in [e for e in args.examples.split(",") if e]:
            pictures = []
            for method in [m for m in args.methods.split(",") if m]:
                t0 = time.perf_counter()
                r = geosynth.grow_relief(mesh, example, scale=scale, method=method, device=device, progress=False,
                                         baseline=False, resolution=args.resolution, refine=args.refine)
                seconds = time.perf_counter() - t0
                lines.append(_row(shape, example, method, len(mesh.vertices), r, seconds))
                print(lines[-1], flush=True)
                print("   " + "\n   ".join(r.lines()), flush=True)
                pictures.append(relief_picture((mesh.vertices, mesh.faces), (r.vertices, r.faces), r.colours))
                del r
            path = write_image(OUT / f"relief_{shape}_{example}.png", np.concatenate(pictures, 0))
            print(f"picture: {path} (rows: {args.methods})", flush=True)
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    lines += ["", f"Peak RSS of the run: {peak:,.0f} MB; refinement passes {args.refine}; output resolution "
              f"{args.resolution if args.resolution is not None else 'default'}."]
    return finish("\n".join(lines), args, title="# bm_relief: relief grown over a mesh against triplanar projection")


if __name__ == "__main__":
    sys.exit(main())
