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


MESH_EXAMPLES = ("torus", "chainmail")


def _example_mesh(name: str):
    from geosynth.examples import chainmail_mesh, torus_mesh

    return {"torus": torus_mesh, "chainmail": chainmail_mesh}[name]()


def _cmd_field(args: argparse.Namespace) -> int:
    import trimesh

    from geosynth.fields import mesh_distance, pointset_distance
    from geosynth.render import field_slices_image, write_png

    say = (lambda *a, **k: None) if args.quiet else print
    out = Path(args.output)
    if out.suffix != ".npz":
        raise ValueError(f"-o/--output must end in .npz, got {str(out)!r}.")
    if args.input is None and args.example is None:
        raise ValueError("give an INPUT mesh or point-set file, or --example NAME (torus, chainmail).")
    if args.input is not None and out.resolve() == Path(args.input).resolve():
        raise ValueError(f"-o/--output {str(out)!r} is the input file; choose another name (inputs are never overwritten).")

    t0 = time.perf_counter()
    if args.example is not None:
        source, label = _example_mesh(args.example), f"example {args.example}"
    else:
        source, label = trimesh.load(args.input), args.input
    if isinstance(source, trimesh.Scene):
        source = source.to_geometry() if hasattr(source, "to_geometry") else source.dump(concatenate=True)
    t_load = time.perf_counter() - t0

    t0 = time.perf_counter()
    if isinstance(source, trimesh.Trimesh) and len(source.faces):
        say(f"{label}: mesh with {len(source.vertices):,} vertices, {len(source.faces):,} faces")
        field = mesh_distance(source, resolution=args.resolution, padding=args.padding, signed=not args.unsigned,
                              band=args.band, drop_degenerate=args.drop_degenerate, device=args.device)
        distance = field
    else:
        from geosynth.pointsets import read_point_set

        points = read_point_set(args.input)
        say(f"{label}: point set of {len(points.positions):,} points"
            + ("" if points.normals is not None else " without normals"))
        if points.normals is None:
            if not args.estimate_normals:
                raise ValueError(f"{args.input} has no normals; pass --estimate-normals to estimate them (PCA over k neighbours).")
            from geosynth.pointsets import estimate_normals

            points.normals = estimate_normals(points.positions)
        distance, gradient = pointset_distance(points, resolution=args.resolution, padding=args.padding,
                                               radius=args.radius, device=args.device)
        if args.band is not None:
            distance.values = np.clip(distance.values, -args.band, args.band)
        field = type(distance)(np.concatenate([distance.values[..., None], gradient.values], -1),
                               distance.origin, distance.spacing)
    t_field = time.perf_counter() - t0
    field.save(out)
    n = int(np.prod(field.shape))
    say(f"field {field.shape[2]} x {field.shape[1]} x {field.shape[0]} (x, y, z), spacing {field.spacing[0]:.4g}: "
        f"{n:,} samples in {t_field:.2f} s ({n / t_field:,.0f} samples/s; loading {t_load:.2f} s) on "
        f"{geosynth.get_backend(args.device or 'auto').name}")
    say(f"written {out}" + (" (channels: distance, gradient x, y, z)" if field.values.ndim == 4 else ""))
    png = Path(args.png) if args.png else out.with_suffix(".png")
    write_png(png, field_slices_image(distance.values, count=3))
    say(f"picture: {png} (three z slices; blue inside, orange outside, black: the zero level)")
    return 0


def _cmd_volume(args: argparse.Namespace) -> int:
    from geosynth.examples import EXEMPLARS
    from geosynth.render import render_mesh, side_by_side, write_png
    from geosynth.surface import save_mesh
    from geosynth.volume import synthesize_geometry

    say = (lambda *a, **k: None) if args.quiet else print
    if (args.exemplar is None) == (args.example is None):
        raise ValueError(f"give an EXEMPLAR mesh file or --example NAME (one of {', '.join(EXEMPLARS)}), not both or neither.")
    out = Path(args.output)
    inputs = [args.exemplar] if args.exemplar else []
    if args.exemplar and out.resolve() == Path(args.exemplar).resolve():
        raise ValueError(f"-o/--output {str(out)!r} is the exemplar file; choose another name (inputs are never overwritten).")
    if len(args.size) not in (1, 3) or len(args.block) not in (1, args.levels):
        raise ValueError("--size takes one or three numbers (x y z); --block one or one per level.")
    size = tuple(args.size[::-1]) if len(args.size) == 3 else args.size[0]  # (z, y, x) or one number
    block = args.block if len(args.block) > 1 else args.block[0]
    label = args.example or args.exemplar
    shape_text = (f"{args.size[0]} x {args.size[1]} x {args.size[2]}" if len(args.size) == 3
                  else f"{args.size[0]} x {args.size[0]} x (the exemplar's thickness)")
    say(f"geosynth volume: {label} -> {shape_text} samples, {args.levels} levels, "
        f"block {block}, {'tileable, ' if args.tileable else ''}seed {args.seed}, device {args.device or 'auto'}")
    result = synthesize_geometry(
        args.example or args.exemplar, size,
        source_resolution=args.source_resolution, levels=args.levels, block=block, tileable=args.tileable,
        seed=args.seed, device=args.device, search=args.search, smooth=args.smooth,
        quality_samples=args.quality_samples, progress=not args.quiet,
    )
    save_mesh(result.mesh, out, inputs=inputs)
    say(f"\nwritten {out}: {len(result.mesh.vertices):,} vertices, {len(result.mesh.faces):,} faces")
    say("\nper level:")
    for i, lv in enumerate(result.volume.levels):
        src_xyz, tgt_xyz = (" x ".join(str(v) for v in shape[::-1]) for shape in (lv.source_shape, lv.target_shape))
        say(f"  level {i + 1}: source {src_xyz}, target {tgt_xyz} (x, y, z), block {lv.block}: "
            f"{lv.matches:,} matches, mean best-match distance {lv.mean_match_distance:.1f} per sample, {lv.seconds:.1f} s "
            f"({lv.seconds / max(1, lv.matches) * 1e3:.2f} ms per match)")
        say("    search: " + lv.search.replace("\n", "\n    "))
    say("timings:")
    for k, v in result.timings.items():
        say(f"  {k:<34} {v:8.2f} s")
    if result.quality:
        say("quality (bidirectional block distance, squared uint8 units per sample; lower is better):")
        for k, q in result.quality.items():
            say(f"  {k:<14} output->exemplar {q['output_to_exemplar']:9.1f}   exemplar->output {q['exemplar_to_output']:9.1f}"
                f"   mean {q['mean']:9.1f}")
    png = Path(args.png) if args.png else out.with_suffix(".png")
    from geosynth.volume import _exemplar_mesh

    exemplar_mesh = _exemplar_mesh(args.example or args.exemplar, args.seed)
    picture = side_by_side([render_mesh(exemplar_mesh), render_mesh(result.mesh)], labels=["exemplar", "synthesized"])
    write_png(png, picture)
    say(f"picture: {png} (exemplar left, result right)")
    return 0


def _cmd_texture(args: argparse.Namespace) -> int:
    from geosynth.pointmodels import POINT_MODELS, load_point_model, point_model
    from geosynth.pointsets import write_point_set
    from geosynth.render import render_points, side_by_side, write_png
    from geosynth.texture import texture_points
    from geosynth.textures import TEXTURES, read_texture, texture_example

    say = (lambda *a, **k: None) if args.quiet else print
    inputs = list(args.inputs)
    model_path = None if args.example else (inputs.pop(0) if inputs else None)
    texture_path = None if args.texture_example else (inputs.pop(0) if inputs else None)
    if inputs:
        raise ValueError(f"unexpected argument(s): {' '.join(inputs)}; give [MODEL|--example NAME] [TEXTURE|--texture-example NAME].")
    if model_path is None and args.example is None:
        raise ValueError(f"give a MODEL file (PLY point set or any mesh) or --example NAME ({', '.join(POINT_MODELS)}).")
    if texture_path is None and args.texture_example is None:
        raise ValueError(f"give a TEXTURE image (PNG/JPEG) or --texture-example NAME ({', '.join(TEXTURES)}).")
    out = Path(args.output)
    if out.suffix.lower() != ".ply":
        raise ValueError(f"-o/--output must end in .ply, got {str(out)!r}.")
    png = Path(args.png) if args.png else out.with_suffix(".png")
    inputs_used = [p for p in (model_path, texture_path) if p]
    for target in (out, png):
        for src in inputs_used:
            if target.resolve() == Path(src).resolve():
                raise ValueError(f"the output {str(target)!r} is an input file; choose another name (inputs are never overwritten).")

    if args.example:
        model, model_label = point_model(args.example, args.count, seed=args.seed), f"example {args.example}"
    else:
        model, model_label = load_point_model(model_path, count=args.count, seed=args.seed), model_path
    if texture_path:
        texture, tex_label = read_texture(texture_path), Path(texture_path).name
        tileable = bool(args.tileable)
        pattern = args.pattern_size
    else:
        texture = texture_example(args.texture_example, args.texture_size, seed=args.seed)
        tex_label = f"{args.texture_example} {args.texture_size}x{args.texture_size}"
        tileable = args.tileable is not False
        pattern = args.pattern_size
    say(f"geosynth texture: {model_label} ({len(model):,} points) with {tex_label} "
        f"({texture.shape[1]} x {texture.shape[0]}, {'tileable' if tileable else 'not tileable'}), method {args.method}")
    coloured, report = texture_points(
        model, texture, method=args.method, k=args.k, levels=args.levels, coherent=args.coherent, m=args.m,
        unit_scale=args.unit_scale, up=None if args.random_orientation else (0.0, 1.0, 0.0), tileable=tileable,
        threshold=args.threshold, pattern_size=pattern, quality=not args.no_quality,
        quality_samples=args.quality_samples, device=args.device, seed=args.seed, progress=not args.quiet,
    )
    write_point_set(out, coloured)
    for line in report.lines():
        say(line)
    say(f"written {out}")
    azimuths = (-60, 60, 180, -150)[:max(1, min(4, args.views))]
    views = [render_points(coloured.positions, coloured.normals, coloured.colors, size=(360, 320), view=(az, 25))
             for az in azimuths]
    scale = max(1, 256 // max(texture.shape[:2]))
    tex_big = np.repeat(np.repeat(texture, scale, 0), scale, 1)
    labels = ["texture"] + [f"view {i + 1}" for i in range(len(views))]
    write_png(png, side_by_side([tex_big] + views, labels=labels))
    say(f"picture: {png} (the texture, then {len(views)} view(s))")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="geosynth", description="Example-based geometry synthesis.")
    parser.add_argument("--version", action="version", version=f"geosynth {geosynth.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("devices", help="list the devices present")
    p.set_defaults(func=_cmd_devices)

    p = sub.add_parser("volume", help="M1: synthesize a larger piece of geometry from an exemplar mesh")
    p.add_argument("exemplar", nargs="?", help="an exemplar mesh file (any format trimesh reads)")
    p.add_argument("--example", help="a built-in exemplar instead: chainmail, balls, grid, fibers, terrain")
    p.add_argument("-o", "--output", required=True, help="the output mesh (.ply, .obj or .stl)")
    p.add_argument("--size", type=int, nargs="+", default=[128], help="target samples along x and y (z keeps the exemplar's thickness), or x y z (default 128)")
    p.add_argument("--levels", type=int, default=3, help="resolution levels (default 3)")
    p.add_argument("--block", type=int, nargs="+", default=[16], help="finest block size, or one per level (default 16)")
    p.add_argument("--source-resolution", type=int, default=64, help="exemplar samples along its longest side (default 64)")
    p.add_argument("--tileable", action="store_true", help="make the output periodic (copies tile without seams)")
    p.add_argument("--search", choices=["cascade", "tree", "linear"], default="cascade",
                   help="exact block search: cascade of lower bounds (default, fastest), the paper's tree, or linear")
    p.add_argument("--smooth", type=int, default=10, help="Taubin smoothing iterations (default 10)")
    p.add_argument("--quality-samples", type=int, default=100, help="blocks per direction for the quality numbers (0: skip)")
    p.add_argument("--device", default=None, help="cpu, cuda[:N], opencl[:P:D] or auto (default)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--png", default=None, help="picture of exemplar and result (default: OUTPUT with .png)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_volume)

    p = sub.add_parser("texture", help="M3: colour a point model from a sample texture (parameterization, matching, hybrid)")
    p.add_argument("inputs", nargs="*", metavar="[MODEL] [TEXTURE]",
                   help="a point model (PLY point set, or a mesh to sample) and a texture image (PNG/JPEG)")
    p.add_argument("--example", choices=["sphere", "torus", "blob"], help="a built-in point model instead of MODEL")
    p.add_argument("--count", type=int, default=20_000, help="points of a built-in model or sampled from a mesh (default 20000)")
    p.add_argument("--texture-example", choices=["bricks", "checker", "noise"], help="a built-in texture instead of TEXTURE")
    p.add_argument("--texture-size", type=int, default=64, help="size of a built-in texture (default 64)")
    p.add_argument("-o", "--output", required=True, help="the coloured point set, .ply")
    p.add_argument("--method", choices=["param", "match", "hybrid"], default="hybrid", help="default hybrid")
    p.add_argument("-k", type=int, default=25, help="neighbours per point (default 25)")
    p.add_argument("--levels", type=int, default=1, help="multiresolution levels of matching (default 1)")
    p.add_argument("--coherent", action="store_true", help="coherent matching (candidates near the neighbours' sources)")
    p.add_argument("--m", type=int, default=8, help="texture supersampling of the texel search (default 8)")
    p.add_argument("--unit-scale", type=float, default=1.0, help="one texel = this x the mean point spacing (default 1)")
    p.add_argument("--random-orientation", action="store_true", help="random texture direction instead of the up vector (0, 1, 0)")
    p.add_argument("--tileable", action=argparse.BooleanOptionalAction, default=None,
                   help="the texture tiles (default: yes for built-ins, no for images)")
    p.add_argument("--threshold", type=float, default=1.6, help="distortion threshold of the parameterization (default 1.6)")
    p.add_argument("--pattern-size", type=float, default=None, help="texture pattern size in texels, for the hybrid's gap widening")
    p.add_argument("--quality-samples", type=int, default=200, help="points whose neighbourhoods the quality numbers use (default 200)")
    p.add_argument("--no-quality", action="store_true", help="skip the quality numbers")
    p.add_argument("--device", default=None, help="cpu, cuda[:N], opencl[:P:D] or auto (default)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--png", default=None, help="picture: the texture and the views (default: OUTPUT with .png)")
    p.add_argument("--views", type=int, default=3, help="views of the result in the picture, 1 to 4 (default 3)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_texture)

    p = sub.add_parser("field", help="sample the signed distance of a mesh or an oriented point set on a grid")
    p.add_argument("input", nargs="?", help="a mesh (any format trimesh reads) or a PLY point set with normals")
    p.add_argument("--example", choices=MESH_EXAMPLES, help="a built-in mesh instead of INPUT")
    p.add_argument("-o", "--output", required=True, help="the field, .npz")
    p.add_argument("--resolution", type=int, default=64, help="samples along the longest axis (default 64)")
    p.add_argument("--padding", type=float, default=0.1, help="grid margin, a fraction of the largest extent (default 0.1)")
    p.add_argument("--band", type=float, default=None, help="clamp distances to [-W, W]")
    p.add_argument("--unsigned", action="store_true", help="unsigned distance (meshes)")
    p.add_argument("--drop-degenerate", action="store_true", help="drop zero-area faces instead of refusing the mesh")
    p.add_argument("--radius", type=float, default=None, help="MLS Gaussian width for point sets (default: from the spacing)")
    p.add_argument("--estimate-normals", action="store_true", help="estimate missing point normals")
    p.add_argument("--device", default=None, help="cpu, cuda[:N], opencl[:P:D] or auto (default)")
    p.add_argument("--png", default=None, help="picture of the slices (default: OUTPUT with .png)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_field)

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
