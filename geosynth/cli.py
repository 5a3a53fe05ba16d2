"""The ``geosynth`` command line."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import geosynth
from geosynth.backend import describe_devices


def _cmd_devices(args: argparse.Namespace) -> int:
    for name, desc in describe_devices():
        print(f"  {name:<14} {desc}")
    print(f"  'auto' picks: {geosynth.get_backend('auto').name}")
    return 0


def _outline(image: np.ndarray, y0: int, x0: int, size: int, colour, width: int = 2) -> None:
    y1, x1 = y0 + size, x0 + size
    image[y0:y0 + width, x0:x1] = colour
    image[y1 - width:y1, x0:x1] = colour
    image[y0:y1, x0:x0 + width] = colour
    image[y0:y1, x1 - width:x1] = colour


def _cmd_demo(args: argparse.Namespace) -> int:
    from geosynth.examples import quantize_distance, spheres_field
    from geosynth.render import write_png

    say = (lambda *a, **k: None) if args.quiet else print
    say("geosynth demo: nearest-block search (M1's linear search) on a generated field\n")
    say("Devices present:")
    for name, desc in describe_devices():
        say(f"  {name:<14} {desc}")

    size, block = args.size, args.block
    rng = np.random.default_rng(args.seed)
    field = quantize_distance(spheres_field(size, count=max(1, size**3 // 6500), seed=args.seed), band=4.0)
    offsets = np.stack(np.meshgrid(*[np.arange(block)] * 3, indexing="ij"), -1).reshape(-1, 3)
    # The query: of a few random blocks, the one with the most structure (not empty space).
    draws = rng.integers(0, size - block + 1, (32, 3))
    origin = max(draws, key=lambda o: float(field[tuple((o + offsets).T)].std()))
    query = field[tuple((origin + offsets).T)].astype(np.int16)
    query = np.clip(query + rng.integers(-6, 7, query.shape), 0, 255).astype(np.uint8)  # a noisy copy
    n_cand = int(np.prod(geosynth.lattice_shape(field.shape, offsets)))
    say(f"\nSource: {size}^3 uint8 distance field of random spheres (seed {args.seed}); "
        f"query: the {block}^3 block at {tuple(int(v) for v in origin)} plus noise in [-6, 6];")
    say(f"{n_cand:,} candidate blocks x {len(offsets):,} samples = {n_cand * len(offsets) / 1e6:,.0f} M squared differences.\n")

    devices = geosynth.devices() if args.device == "all" else [geosynth.get_backend(args.device).name]
    say(f"{'device':<14} {'best origin':<16} {'score':>9} {'time':>10} {'candidates/s':>14}")
    results = {}
    for dev in devices:
        backend = geosynth.get_backend(dev)
        grid = geosynth.to_device(field, dev)
        scores = geosynth.score_gather(grid, offsets, query, keep_on_device=True)  # warm-up: builds kernels
        geosynth.argmin(scores)
        best_t = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            scores = geosynth.score_gather(grid, offsets, query, keep_on_device=True)
            best = geosynth.argmin(scores)  # reads back one index
            best_t = min(best_t, time.perf_counter() - t0)
        backend.synchronize()
        found = geosynth.candidate_origins(field.shape, offsets)[best]
        score = int(scores.numpy()[best])
        results[dev] = (tuple(int(v) for v in found), score)
        say(f"{dev:<14} {str(tuple(int(v) for v in found)):<16} {score:>9,} {best_t * 1e3:>8.1f}ms {n_cand / best_t:>14,.0f}")

    agree = len(set(results.values())) == 1
    hit = all(found == tuple(int(v) for v in origin) for found, _ in results.values())
    say(f"\nEvery device found the same block: {'yes' if agree else 'NO'}; it is the true origin: {'yes' if hit else 'NO'}.")

    # A picture: the slice through the query's centre, true block green, found block red.
    found = np.array(next(iter(results.values()))[0])
    zc = int(origin[0] + block // 2)
    scale = 4
    grey = np.repeat(np.repeat(field[zc], scale, 0), scale, 1)
    image = np.stack([grey] * 3, -1)
    _outline(image, origin[1] * scale, origin[2] * scale, block * scale, (0, 220, 0))
    _outline(image, found[1] * scale + 3, found[2] * scale + 3, block * scale - 6, (230, 0, 0))
    out = write_png(Path(args.output) / "nearest_block.png", image)
    say(f"Picture: {out} (slice z={zc}; green: the query's true block, red: the best match)")
    return 0 if (agree and hit) else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="geosynth", description="Example-based geometry synthesis.")
    parser.add_argument("--version", action="version", version=f"geosynth {geosynth.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("devices", help="list the devices present")
    p.set_defaults(func=_cmd_devices)

    p = sub.add_parser("demo", help="nearest-block search on a generated field, on every device")
    p.add_argument("--device", default="all", help="a device string, or 'all' (default) for every present device")
    p.add_argument("--size", type=int, default=64, help="source field size (default 64)")
    p.add_argument("--block", type=int, default=16, help="block size (default 16)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeat", type=int, default=3, help="timed repetitions per device (best is shown)")
    p.add_argument("-o", "--output", default="demo_out", help="folder for the picture (default demo_out)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "command", None) == "demo" and not (2 <= args.block <= args.size):
        print(f"geosynth demo: --block must be between 2 and --size ({args.size}), got {args.block}.", file=sys.stderr)
        return 2
    try:
        return args.func(args)
    except (ValueError, RuntimeError, TypeError) as exc:
        print(f"geosynth {args.command}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
