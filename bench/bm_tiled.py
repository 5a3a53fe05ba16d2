"""Tiled M1 synthesis on Dask (geosynth.volume.tiled): a large terrain and a slab texture (chainmail)
from the built-ins on a 2-worker LocalCluster: wall time, per-level time, peak memory per
worker, tasks, bytes moved between workers, seam against interior quality; the same
target untiled (where it fits) for the ratio; and from those figures an estimate for
4096 x 4096 x 256 samples on N workers.

Usage: python bench/bm_tiled.py [--quick] [--devices D] [--out FILE] [--size N] [--tiles K]
         [--png FILE]

Full mode: 1024 x 1024 x (the exemplar's thickness) samples in 4 x 4 tiles with M1's
defaults (3 levels, block 16, source resolution 64, the default iterations: the settings
whose results look like the exemplar; a slab exemplar, chainmail, with blocks through its
thickness, untiled as well). --quick: 128 x 128 in 2 x 2 tiles, plus the naive baseline
(independent tiles).
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import finish, parse_args, start  # noqa: E402

# M1's defaults (geosynth.volume.synthesis.synthesize_geometry): with 2 levels, block 8, source 32
# and one iteration a level (this bench's settings until 2026-12-03) the terrain came out
# as blocky noise (slopes 0.11 against the defaults' 0.8), so those runs judged seams only.
LEVELS, BLOCK, RESOLUTION = 3, 16, 64
ITERATIONS = None  # the default texture-optimization iterations per level
BIG = (256, 4096, 4096)


def _options(parser) -> None:
    parser.add_argument("--size", type=int, default=None, help="target samples along x and y (default 1024; quick 128)")
    parser.add_argument("--tiles", type=int, default=None, help="tiles along x and y (default 4; quick 2)")
    parser.add_argument("--exemplars", default="terrain,chainmail", help="built-in exemplars, comma-separated")
    parser.add_argument("--untiled", default="terrain,chainmail", help="exemplars also run untiled, for the ratio")
    parser.add_argument("--png", default=None, help="top view (height map) of the first tiled result, tile borders marked")


def options(argv=None):
    return parse_args(__doc__, argv, quick="128 x 128 in 2 x 2 tiles, with the independent-tiles baseline",
                      extras=_options)


def _height_map(field: np.ndarray) -> np.ndarray:
    """(Y, X) height of the surface (first inside sample from the top, in samples)."""
    inside = field < 128
    z = field.shape[0]
    top = np.where(inside.any(axis=0), z - 1 - np.argmax(inside[::-1], axis=0), 0)
    return top.astype(np.float32)


def _picture(path: str, field: np.ndarray, grid) -> None:
    from geosynth.io.files import write_image
    from geosynth.io.pictures import side_by_side

    h = _height_map(field)
    g = (h - h.min()) / max(1e-6, float(h.max() - h.min()))
    # shaded relief: light from the upper left
    gy, gx = np.gradient(h)
    shade = np.clip(0.6 + 0.4 * (-gx - gy) / max(1e-6, np.abs(gx).max() + np.abs(gy).max()) * 4, 0, 1)
    grey = (255 * (0.5 * g + 0.5 * shade)).astype(np.uint8)
    scale = max(1, 512 // max(grey.shape))  # small quick-mode fields: nearest-neighbour enlarged
    grey = np.kron(grey, np.ones((scale, scale), np.uint8))
    img = np.stack([grey] * 3, -1)
    marked = img.copy()
    for c in grid.cores(grid.levels - 1).values():
        if c.y0:
            marked[c.y0 * scale, :, :] = (220, 40, 40)
        if c.x0:
            marked[:, c.x0 * scale, :] = (220, 40, 40)
    write_image(path, side_by_side([img, marked], labels=["tiled result, top view", "tile borders marked"]))


def _run(name, size, tiles, device, png, untiled: bool, baseline: bool) -> list[str]:
    from distributed import Client, LocalCluster

    from geosynth.core.memory import format_bytes
    from geosynth.volume.synthesis import is_slab, synthesize_volume
    from geosynth.volume.tiled import WORKER_RUNTIME_BYTES, exemplar_source, seam_report, synthesize_volume_tiled, tile_bytes
    from geosynth.volume.tiles import TileGrid

    import logging

    src, spacing, _ = exemplar_source(name, RESOLUTION, LEVELS, 0, device)
    shape = (src.shape[0] // 2 * 2, size, size)
    kw = dict(levels=LEVELS, block=BLOCK, seed=0, device=device, iterations=ITERATIONS, progress=False)
    lines = [f"### {name}: {size} x {size} x {shape[0]} samples (x y z), {tiles} x {tiles} tiles, exemplar "
             f"{src.shape[2]} x {src.shape[1]} x {src.shape[0]}", ""]
    lines[0] += " (a slab: blocks through its thickness)" if is_slab(src.shape, shape) else ""
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR)
    client = Client(cluster)
    try:
        client.run(lambda: __import__("geosynth.volume.synthesis"))  # imports out of the timing
        t0 = time.perf_counter()
        r = synthesize_volume_tiled(src, shape, (tiles, tiles), scheduler=client, **kw)
        wall = time.perf_counter() - t0
        naive = None
        if baseline:
            naive = synthesize_volume_tiled(src, shape, (tiles, tiles), scheduler=client, phases=1, **kw)
    finally:
        client.close()
        cluster.close()
    finest = None  # the grid's finest block: a slab's spans the thickness, as its tiles matched
    q = seam_report(r.source, r.quantized, r.grid, finest, stride=max(2, size // 128), device=device)
    rss = list(r.peak_rss.values())
    n = int(np.prod(shape))
    lines += [f"| figure | value |", "|---|---:|",
              f"| wall time (2-worker LocalCluster, processes) | {wall:.1f} s |"]
    for i, lv in enumerate(r.levels):
        lines.append(f"| level {i + 1} ({'whole, 1 task' if lv['whole'] else str(lv['tasks']) + ' tiles'}) | "
                     f"{lv['seconds']:.1f} s wall, {lv['task_seconds']:.1f} s in tasks, {lv['matches']:,} matches |")
    lines += [f"| tasks: tiles / whole graph (tiles, crops, info; outputs excluded) | {r.tasks} / "
              f"{sum(lv['graph_tasks'] for lv in r.levels)} |",
              f"| bytes moved between workers | {format_bytes(r.bytes_moved)} ({r.bytes_moved / n:.2f} B per target sample) |",
              f"| peak memory per worker (VmHWM) | {', '.join(format_bytes(v) for v in rss) or '-'} |",
              f"| estimated peak of one tile task | {format_bytes(r.tile_estimate)} |",
              f"| seams: block distance across borders / inside tiles | {q['seam']:.1f} / {q['interior']:.1f} "
              f"(ratio {q['ratio']:.3f}; {q['seam_blocks']} / {q['interior_blocks']} blocks) |",
              f"| seams: step across borders / elsewhere | {q['step_seam']:.2f} / {q['step_interior']:.2f} "
              f"(ratio {q['step_ratio']:.2f}) |"]
    if naive is not None:
        qn = seam_report(naive.source, naive.quantized, naive.grid, finest, stride=max(2, size // 128), device=device)
        lines.append(f"| naive baseline (independent tiles): block distance ratio, step ratio | {qn['ratio']:.3f}, "
                     f"{qn['step_ratio']:.2f} |")
    ratio_line = None
    if untiled:
        t0 = time.perf_counter()
        u = synthesize_volume(src, shape, method=r.settings.method, slab=r.grid.slab, **kw)  # the tiles' choices
        u_wall = time.perf_counter() - t0
        qu = seam_report(u.source, u.quantized, r.grid, finest, stride=max(2, size // 128), device=device)
        lines.append(f"| untiled, one process | {u_wall:.1f} s (tiled / untiled {wall / u_wall:.2f}); the same "
                     f"columns: block distance ratio {qu['ratio']:.3f}, step ratio {qu['step_ratio']:.2f} |")
        ratio_line = wall / u_wall
    if png:
        _picture(png, r.quantized, r.grid)
        lines.append(f"| picture | {png} |")
    # the estimate for 4096 x 4096 x 256 on N workers, from this run's per-sample figures
    busy = sum(lv["task_seconds"] for lv in r.levels)
    per_sample = busy / n  # worker-seconds per target sample
    big_n = int(np.prod(BIG))
    core = max(256, r.grid.core[1])  # this run's tile size, at least 256 (the quick run's 64 would not hold the blocks)
    big_tiles = BIG[2] // core
    g = TileGrid.make(BIG, (big_tiles, big_tiles), r.grid.blocks)
    big_tile = tile_bytes(g, (BIG[0] // 2 * 2, src.shape[1], src.shape[2]), "cascade")
    measured = max(rss) if rss else 0
    lines += ["", f"Estimate for {BIG[2]} x {BIG[1]} x {BIG[0]} ({big_n / 1e9:.1f} G samples) in {big_tiles} x "
              f"{big_tiles} tiles of {core} x {core}, linear in samples from this run "
              f"({per_sample * 1e6:.2f} worker-us per sample, {r.bytes_moved / n:.2f} B moved per sample; an exemplar "
              f"of thickness 256 costs more per match than this one, so this is a lower bound on time):", "",
              "| workers | time | traffic |", "|---:|---:|---:|"]
    for workers in (2, 16, 64, 256):
        lines.append(f"| {workers} | {per_sample * big_n / workers / 3600:.1f} h | {format_bytes(r.bytes_moved / n * big_n)} |")
    lines += ["", f"Memory per worker: one tile task of the big run is estimated at {format_bytes(big_tile)} "
              f"(this run: estimate {format_bytes(r.tile_estimate)}, measured worker peak (VmHWM) {format_bytes(measured)}, "
              f"which includes the worker's runtime, estimated at {format_bytes(WORKER_RUNTIME_BYTES)}), plus the worker's share of the "
              f"results it keeps: {format_bytes(1.14 * big_n)} in all over the cluster (uint8, every level), i.e. "
              f"{format_bytes(1.14 * big_n / 64)} per worker on 64 workers.", ""]
    return lines


def main(argv=None) -> int:
    args = options(argv)
    devices = start(args)
    device = next((d for d in devices if d.startswith(("cuda", "opencl"))), devices[0])
    size = args.size or (128 if args.quick else 1024)
    tiles = args.tiles or (2 if args.quick else 4)
    names = [n.strip() for n in args.exemplars.split(",") if n.strip()]
    untiled = {n.strip() for n in args.untiled.split(",") if n.strip()}
    load = os.getloadavg()
    lines = [f"Load when started (uptime): {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores; "
             f"device {device}; {LEVELS} levels, block {BLOCK}, source resolution {RESOLUTION}, "
             f"iterations {ITERATIONS}.", ""]
    for i, name in enumerate(names):
        png = args.png if i == 0 else None
        lines += _run(name, size, tiles, device, png, name in untiled, args.quick)
    load = os.getloadavg()
    lines.append(f"Load when done: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.")
    return finish("\n".join(lines), args, title="## Tiled M1 synthesis on Dask (bench/bm_tiled.py)")


if __name__ == "__main__":
    sys.exit(main())
