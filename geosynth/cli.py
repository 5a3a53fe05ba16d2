"""What does the geosynth command do with these arguments? Implements no paper section: it
runs the methods' APIs.

The ``geosynth`` command line.

Every command checks its arguments before any work: each number against the range
the library accepts (at parse time), each input file for existence, each output path
with :func:`geosynth.io.files.check_output` (never an input, a folder, a path under a
file, an unwritable folder or the wrong extension; two outputs of one run never the
same file). An expected failure is one line on stderr, ``geosynth <command>:
<message>``, exit code 2 (``--debug``: the traceback instead); Ctrl-C exits 130 and
SIGTERM 143, quietly. One commit step per command (:func:`geosynth.io.files.staged_outputs`):
every output (mesh, picture, point set, store, tile meshes) waits in a temporary until
the command has finished, and all are moved in together; an interrupt at any moment,
even one that a library swallowed, leaves every old output as it was (exit 130/143). ``--verbose`` lets the libraries' warnings through (it sets
``GEOSYNTH_VERBOSE=1`` before any backend loads).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

import geosynth
from geosynth.core.config import set_verbose
from geosynth.core.constants import M1_DEFAULT_BLOCK as DEFAULT_BLOCK, M1_DEFAULT_RESOLUTION as DEFAULT_RESOLUTION
from geosynth.io.files import IMAGE_SUFFIXES, check_output
from geosynth.volume.examples import EXEMPLARS

MESH_OUT = (".ply", ".obj", ".stl")
POINTS_OUT = (".ply",)
FIELD_OUT = (".npz",)
MAX_LEVELS = 8
MAX_SMOOTH = 1000
DEMO_MAX_SIZE = 256  # the demo's spheres field costs size^6 / 6500 operations
# The library's messages name its parameters; per command, the flags that set them here.
_PARAMETER_FLAGS = {
    "volume": [(r"\bdrop_degenerate(?:=True)?\b", "--drop-degenerate")],
    "field": [(r"\bdrop_degenerate(?:=True)?\b", "--drop-degenerate")],
    "texture": [(r"(?<![\w-])k = ", "-k "), (r"\bsmaller k\b", "smaller -k"), (r"\bfewer levels\b", "fewer --levels"),
                (r"(?<![\w-])m = ", "--m "), (r"\bor m \(", "or --m ("), (r", m and levels\b", ", --m and --levels"),
                (r"\btexture_size\b", "--texture-size"), (r"\bunit_scale\b", "--unit-scale"),
                (r"\bpattern_size\b", "--pattern-size")],
    "complete": [(r"(?<![\w-])window (?=\d)", "--window "), (r"\ba window\b", "a --window"),
                 (r"\bsmaller window\b", "smaller --window")],
}


# ------------------------------------------------------------------ argument types


def _int_type(low: int, high: int | None = None, *, power_of_two: bool = False,
              each: bool = False) -> Callable[[str], int]:
    """An argparse ``type=``: an integer in [low, high] (a power of two if asked)."""
    allowed = ("a power of two" if power_of_two else "an integer") + (
        f" >= {low}" if high is None else f" from {low} to {high}")
    lead = "each number must be" if each else "must be"

    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{lead} {allowed}, got {text!r}") from None
        if value < low or (high is not None and value > high) or (power_of_two and value & (value - 1)):
            raise argparse.ArgumentTypeError(f"{lead} {allowed}, got {value}")
        return value

    return parse


def _float_type(low: float, *, inclusive: bool) -> Callable[[str], float]:
    """An argparse ``type=``: a finite number > low (>= low when ``inclusive``)."""
    allowed = f"a finite number {'>=' if inclusive else '>'} {low:g}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if not math.isfinite(value) or value < low or (value == low and not inclusive):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text}")
        return value

    return parse


def _device_type(allow_all: bool = False) -> Callable[[str], str]:
    """An argparse ``type=``: a well-formed device string (presence is checked later)."""

    def parse(text: str) -> str:
        from geosynth.compute.backend import parse_device

        if allow_all and text == "all":
            return text
        try:
            parse_device(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).rstrip(".")
                                             + (" (or 'all')" if allow_all else "")) from None
        return text

    return parse


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``geosynth volume: argument --seed: ...``, exit 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see '{self.prog} --help')\n")


# ------------------------------------------------------------------ checks before the work


def _check_input(path: str, what: str, fix: str) -> str:
    """Refuse an input that is missing, a folder or unreadable; returns ``path``."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{what} {path!r} does not exist; {fix}.")
    if p.is_dir():
        raise ValueError(f"{what} {path!r} is a folder; {fix}.")
    if not os.access(p, os.R_OK):
        raise ValueError(f"{what} {path!r} cannot be read (no read permission).")
    return path


def _file_or_example(path: str | None, example: str | None, names, what: str, kinds: str,
                     name_as_path: bool = True) -> tuple[str | None, str | None, list[str]]:
    """A command's input: a file or a built-in, exactly one, the file checked.

    Args:
        path: the positional argument (a file path, or None).
        example: ``--example`` (a built-in name, or None).
        names: the built-ins' names.
        what: the positional argument's name in messages (``"EXEMPLAR"``, ``"INPUT"``).
        kinds: what file it takes, with its article (``"a mesh file (.ply, .obj, .stl, ...)"``).
        name_as_path: a built-in's name given as ``path`` (and no such file) means ``--example``.

    Returns:
        ``(path, example, inputs)``: one of the two None; ``inputs`` the checked file, or empty.
    """
    if name_as_path and path is not None and example is None and path in names and not Path(path).exists():
        path, example = None, path  # a built-in name given as the file
    listed = ", ".join(names)
    if (path is None) == (example is None):
        raise ValueError(f"give {'an' if what[0] in 'AEIOU' else 'a'} {what}, {kinds}, or --example NAME "
                         f"(one of {listed}), not both or neither.")
    inputs = [] if path is None else [_check_input(path, what, f"give {kinds}, or --example NAME ({listed})")]
    return path, example, inputs


def _check_outputs(outputs: Sequence[tuple[str | os.PathLike, Sequence[str], str]],
                   inputs: Sequence[str]) -> None:
    """``check_output`` for every (path, suffixes, what) of a run, and no two the same file."""
    seen: dict[str, str] = {}
    for path, suffixes, what in outputs:
        out = check_output(path, inputs=inputs, suffixes=suffixes, what=what)
        real = os.path.realpath(out)
        if real in seen:
            raise ValueError(f"{what} {str(path)!r} is the same file as {seen[real]}; give each output its own name.")
        seen[real] = f"{what} {str(path)!r}"


def _picture_path(args: argparse.Namespace) -> tuple[Path, str]:
    """The picture's path and how messages name it (``--png``, or its default)."""
    if args.png:
        return Path(args.png), "--png"
    return Path(args.output).with_suffix(".png"), "the default --png (OUTPUT with .png)"


def _html_outputs(args: argparse.Namespace) -> list[tuple[Path, Sequence[str], str]]:
    """``--html``'s (path, suffixes, what) for :func:`_check_outputs`, or nothing."""
    from geosynth.io.viewer import HTML_SUFFIXES

    return [(Path(args.html), HTML_SUFFIXES, "--html")] if getattr(args, "html", None) else []


def _recorder(quiet: bool) -> tuple[Callable[..., None], list[str]]:
    """A command's ``say``: prints unless ``quiet``, and records every line it is given
    either way (the page and the gallery show them)."""
    lines: list[str] = []

    def say(*parts, **kwargs) -> None:
        text = " ".join(str(p) for p in parts)
        lines.extend(line for line in text.split("\n") if line.strip())
        if not quiet:
            print(*parts, **kwargs)

    return say, lines


def _summary(lines: Sequence[str], *prefixes: str) -> str:
    """The first of ``lines`` that starts (after its indent) with the first of ``prefixes``
    any line starts with, squeezed to single spaces; "" when none does."""
    squeezed = [" ".join(line.split()) for line in lines]
    for prefix in prefixes:
        for text in squeezed:
            if text.startswith(prefix):
                return text
    return ""


def _command_text(args: argparse.Namespace) -> str:
    """The command line that ran, as a shell would take it."""
    import shlex

    argv = getattr(args, "argv", None)
    if argv is None:
        return f"geosynth {args.command}"
    return "geosynth " + shlex.join(str(a) for a in argv)


def _write_page(args: argparse.Namespace, left, right, labels: Sequence[str], quality: Sequence[str],
                summary: str, inputs: Sequence[str], say, same_scale: bool = False) -> None:
    """``--html``: the viewer page of ``left`` (exemplar or capture) and ``right`` (the result);
    the quality lines and the summary are kept on ``args`` for the gallery either way."""
    args.quality_lines, args.quality_summary = list(quality), summary
    if not getattr(args, "html", None):
        return
    from geosynth.io.viewer import write_viewer

    write_viewer(args.html, left, right, labels=labels, quality_lines=quality, command=_command_text(args),
                 inputs=inputs, title=f"geosynth {args.command}: {labels[1]}", same_scale=same_scale)
    say(f"page: {args.html} ({labels[0]} left, {labels[1]} right; open it in a browser: drag to turn, wheel to zoom)")


def _check_device(device: str | None) -> None:
    """Refuse an absent device now, not after loading the inputs."""
    from geosynth.compute.backend import resolve_device

    try:
        resolve_device(device or "auto")
    except (ValueError, RuntimeError) as exc:
        raise type(exc)(f"--device {device or 'auto'}: {exc}") from exc


def _typed(values: Sequence[int]) -> str:
    return " ".join(str(v) for v in values)


def _volume_shape(args: argparse.Namespace) -> tuple[int | tuple[int, int, int], int | list[int]]:
    """--size/--block/--levels/--source-resolution checked together, in the user's x y z order.

    Returns:
        (size for synthesize_geometry: one int or (z, y, x); block: one int or a list).
    """
    given_block = args.block is not None  # None: chosen from the exemplar (geosynth.volume.synthesis.choose_settings)
    sizes, blocks, levels = list(args.size), list(args.block or [DEFAULT_BLOCK]), args.levels
    if len(sizes) not in (1, 3):
        raise ValueError(f"--size takes one number (x = y; z follows the exemplar) or three (x y z), "
                         f"got {len(sizes)}: {_typed(sizes)}.")
    if len(blocks) not in (1, levels):
        raise ValueError(f"--block takes one size (the finest level's) or one per level, coarsest first "
                         f"({levels} with --levels {levels}), got {len(blocks)}: {_typed(blocks)}.")
    factor = 2 ** (levels - 1)
    if any(s % factor for s in sizes):
        up = _typed([-(-s // factor) * factor for s in sizes])
        raise ValueError(f"--size {_typed(sizes)}: with --levels {levels} every number must be a multiple of "
                         f"2^(levels-1) = {factor}; try --size {up} or fewer --levels.")
    axes = "xyz" if len(sizes) == 3 else "xy"
    smallest = min(sizes)
    axis = axes[sizes.index(smallest)] if len(sizes) == 3 else "x and y"
    if len(blocks) == 1:
        if blocks[0] > smallest:
            raise ValueError(f"--block {blocks[0]} is larger than --size {_typed(sizes)} along {axis}; "
                             f"use --block {1 << (smallest.bit_length() - 1)} or less, or a larger --size.")
        if levels > 1 and smallest // factor < 2:
            raise ValueError(f"--size {_typed(sizes)} with --levels {levels}: the coarsest level would be "
                             f"{smallest // factor} sample(s) along {axis}; use a larger --size or fewer --levels.")
    else:
        for lvl, b in enumerate(blocks):
            target = [s // 2 ** (levels - 1 - lvl) for s in sizes]
            if b > min(target):
                raise ValueError(f"--block {_typed(blocks)}: level {lvl + 1}'s block {b} is larger than the target "
                                 f"there ({' x '.join(map(str, target))} samples, {' '.join(axes)}); use a smaller "
                                 "block or a larger --size.")
    finest = blocks[-1]
    if args.source_resolution is not None and args.source_resolution < finest:
        raise ValueError(f"--source-resolution {args.source_resolution} is smaller than the finest block {finest}: "
                         f"the exemplar must hold a whole block; use --source-resolution {max(8, finest)} or more.")
    size = tuple(sizes[::-1]) if len(sizes) == 3 else sizes[0]  # the library's (z, y, x)
    if not given_block:
        return size, None
    return size, (blocks if len(blocks) > 1 else blocks[0])


def _volume_options(args: argparse.Namespace, block, tiles: tuple[int, int] | None = None):
    """``geosynth volume``'s settings as one :class:`geosynth.volume.options.VolumeOptions`
    (with ``tiles``: a tiled run's, its :class:`~geosynth.volume.options.TileOptions`)."""
    from geosynth.volume.options import TileOptions, VolumeOptions

    tiling = None if tiles is None else TileOptions(tiles=tiles, workers=2 if args.workers is None else args.workers)
    choice = {"auto": None, "yes": True, "no": False}
    return VolumeOptions(levels=args.levels, block=block, tileable=args.tileable, search=args.search,
                         method=args.method, slab=choice[getattr(args, "slab", "auto")], lattice=choice[getattr(args, "lattice", "auto")],
                         smooth=args.smooth, source_resolution=args.source_resolution,
                         quality_samples=args.quality_samples, tiles=tiling)


# ------------------------------------------------------------------ commands


def _cmd_devices(args: argparse.Namespace) -> int:
    from geosynth.compute.backend import describe_devices

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
    size, block = args.size, args.block
    if block > size:
        raise ValueError(f"--block {block} is larger than --size {size}; use --block {size} or less.")
    folder = Path(args.output)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"-o/--output {args.output!r} is a file; demo writes its picture into a folder: "
                         "give a folder name (it is created).")
    picture = folder / "nearest_block.png"
    _check_outputs([(picture, IMAGE_SUFFIXES, "the picture in -o/--output")], [])
    if args.device != "all":
        _check_device(args.device)

    from geosynth.compute.backend import describe_devices
    from geosynth.io.files import write_image
    from geosynth.volume.examples import spheres_field
    from geosynth.volume.synthesis import quantize_field

    say = (lambda *a, **k: None) if args.quiet else print
    say("geosynth demo: nearest-block search (M1's linear search) on a generated field\n")
    say("Devices present:")
    for name, desc in describe_devices():
        say(f"  {name:<14} {desc}")

    rng = np.random.default_rng(args.seed)
    field = quantize_field(spheres_field(size, count=max(1, size**3 // 6500), seed=args.seed), band=4.0)
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
    out = write_image(picture, image)
    say(f"Picture: {out} (slice z={zc}; green: the query's true block, red: the best match)")
    return 0 if (agree and hit) else 1


MESH_EXAMPLES = ("torus", "chainmail")


def _example_mesh(name: str):
    from geosynth.volume.examples import chainmail_mesh, torus_mesh

    return {"torus": torus_mesh, "chainmail": chainmail_mesh}[name]()


def _cmd_field(args: argparse.Namespace) -> int:
    _, _, inputs = _file_or_example(args.input, args.example, MESH_EXAMPLES, "INPUT", "a mesh or PLY point-set file",
                                    name_as_path=False)
    out = Path(args.output)
    png, png_what = _picture_path(args)
    _check_outputs([(out, FIELD_OUT, "-o/--output"), (png, IMAGE_SUFFIXES, png_what)], inputs)
    if out.suffix != ".npz":  # Field.save takes the lower-case suffix only
        raise ValueError(f"-o/--output {args.output!r} must end in .npz (lower case).")
    _check_device(args.device)

    import trimesh

    from geosynth.geometry.distance import mesh_distance, pointset_distance
    from geosynth.geometry.pointsets import read_geometry
    from geosynth.io.files import write_image
    from geosynth.io.pictures import field_slices_image

    say = (lambda *a, **k: None) if args.quiet else print
    t0 = time.perf_counter()
    if args.example is not None:
        source, label = _example_mesh(args.example), f"example {args.example}"
    else:
        source, label = read_geometry(args.input), args.input  # a mesh when the file has faces, else a PointSet
    t_load = time.perf_counter() - t0

    t0 = time.perf_counter()
    if isinstance(source, trimesh.Trimesh) and len(source.faces):
        say(f"{label}: mesh with {len(source.vertices):,} vertices, {len(source.faces):,} faces")
        field = mesh_distance(source, resolution=args.resolution, padding=args.padding, signed=not args.unsigned,
                              band=args.band, drop_degenerate=args.drop_degenerate, device=args.device)
        distance = field
    else:
        points = source
        say(f"{label}: point set of {len(points.positions):,} points"
            + ("" if points.normals is not None else " without normals"))
        if points.normals is None:
            if not args.estimate_normals:
                raise ValueError(f"{args.input} has no normals; pass --estimate-normals to estimate them (PCA over k neighbours).")
            from geosynth.geometry.pointsets import estimate_normals

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
    write_image(png, field_slices_image(distance.values, count=3), inputs=inputs)
    say(f"picture: {png} (three z slices; blue inside, orange outside, black: the zero level)")
    return 0


def _cmd_volume(args: argparse.Namespace) -> int:
    exemplar, example, inputs = _file_or_example(args.exemplar, args.example, EXEMPLARS, "EXEMPLAR",
                                                 "a mesh file (.ply, .obj, .stl, ...)")
    size, block = _volume_shape(args)
    out = Path(args.output)
    png, png_what = _picture_path(args)
    _check_outputs([(out, MESH_OUT, "-o/--output"), (png, IMAGE_SUFFIXES, png_what)] + _html_outputs(args), inputs)
    _check_device(args.device)

    from geosynth.geometry.surface import save_mesh
    from geosynth.io.files import write_image
    from geosynth.io.pictures import render_mesh, side_by_side
    from geosynth.volume.examples import resolve_exemplar_mesh
    from geosynth.volume.synthesis import block_text, synthesize_geometry

    say, printed = _recorder(args.quiet)
    label = example or exemplar
    shape_text = (f"{args.size[0]} x {args.size[1]} x {args.size[2]}" if len(args.size) == 3
                  else f"{args.size[0]} x {args.size[0]} x (the exemplar's thickness)")
    say(f"geosynth volume: {label} -> {shape_text} samples, {args.levels} levels, "
        f"block {'auto' if block is None else block}, {'tileable, ' if args.tileable else ''}seed {args.seed}, "
        f"device {args.device or 'auto'}")
    _m1_colour_note(exemplar, say)
    result = synthesize_geometry(example or exemplar, size, seed=args.seed, device=args.device,
                                 progress=not args.quiet, drop_degenerate=args.drop_degenerate,
                                 options=_volume_options(args, block))
    if result.settings:
        say(result.settings)
    for line in result.volume.settings.lines(result.volume.source.shape):  # the tiled run prints the same
        say(line)
    if result.volume.lattice_text:
        say(result.volume.lattice_text)
    if result.cleanup:
        say(result.cleanup)
    save_mesh(result.mesh, out, inputs=inputs)
    say(f"\nwritten {out}: {len(result.mesh.vertices):,} vertices, {len(result.mesh.faces):,} faces")
    say("\nper level:")
    for i, lv in enumerate(result.volume.levels):
        src_xyz, tgt_xyz = (" x ".join(str(v) for v in shape[::-1]) for shape in (lv.source_shape, lv.target_shape))
        say(f"  level {i + 1}: source {src_xyz}, target {tgt_xyz} (x, y, z), block {block_text(lv.block)}: "
            f"{lv.matches:,} matches, mean best-match distance {lv.mean_match_distance:.1f} per sample, {lv.seconds:.1f} s "
            f"({lv.seconds / max(1, lv.matches) * 1e3:.2f} ms per match)")
        say("    search: " + lv.search.replace("\n", "\n    "))
    say("timings:")
    for k, v in result.timings.items():
        say(f"  {k:<34} {v:8.2f} s")
    first_quality = len(printed)
    if result.quality:
        say("quality (bidirectional block distance, squared uint8 units per sample; lower is better):")
        for k, q in result.quality.items():
            say(f"  {k:<14} output->exemplar {q['output_to_exemplar']:9.1f}   exemplar->output {q['exemplar_to_output']:9.1f}"
                f"   mean {q['mean']:9.1f}")
        structures = {k: q["structure"] for k, q in result.quality.items() if q.get("structure")}
        if structures:
            from geosynth.volume.quality import format_structure

            say("structure (what a person sees; beside random tiling):")
            for k, report in structures.items():
                say(f"  {k:<14} {format_structure(report)}")
    if result.features:
        from geosynth.volume.features import format_features

        say("feature scale (exemplar -> output, world units; x1.00 is kept):")
        ex = result.features["exemplar"]
        for k, f in result.features.items():
            if k != "exemplar":
                say(f"  {k:<14} {format_features(ex, f)}")
    quality = printed[first_quality:]
    exemplar_mesh = resolve_exemplar_mesh(example or exemplar, args.seed)
    boxes = same_scale_bounds([exemplar_mesh, result.mesh])
    picture = side_by_side([render_mesh(exemplar_mesh, bounds=boxes[0]), render_mesh(result.mesh, bounds=boxes[1])],
                           labels=["exemplar", "synthesized"])
    write_image(png, picture, inputs=inputs)
    say(f"picture: {png} (exemplar left, result right, at the same scale)")
    _write_page(args, exemplar_mesh, result.mesh, [f"exemplar ({label})", "synthesized (same scale)"], quality,
                _volume_summary(result.quality), inputs, say, same_scale=True)
    return 0


def _volume_summary(quality: dict | None) -> str:
    """M1's one quality line: the mean bidirectional block distance, beside random tiling's."""
    if not quality:
        return ""
    parts = [f"{k} {q['mean']:.1f}" for k, q in quality.items()]
    return "block distance (mean, lower is better): " + ", ".join(parts)


# The options that only a tiled run reads, with the value that means "not given".
_TILED_ONLY = (("--workers", "workers", None), ("--scheduler", "scheduler", None), ("--store", "store", None),
               ("--tile-meshes", "tile_meshes", None), ("--resume", "resume", False))


def same_scale_bounds(meshes) -> list[np.ndarray]:
    """One (2, 3) framing box per mesh, each centred on its mesh and as large as the
    largest extent of all of them per axis: rendered with these bounds, every mesh is
    drawn at the same world scale (an exemplar beside a larger synthesized piece shows
    its features at their true relative size)."""
    lows = [np.asarray(m.bounds[0], np.float64) for m in meshes]
    highs = [np.asarray(m.bounds[1], np.float64) for m in meshes]
    half = np.max([(h - lo) / 2 for lo, h in zip(lows, highs)], axis=0)
    return [np.stack([(lo + h) / 2 - half, (lo + h) / 2 + half]) for lo, h in zip(lows, highs)]


def _cmd_volume_any(args: argparse.Namespace) -> int:
    """``geosynth volume``: untiled, or with --tiles the tiled synthesis on Dask."""
    if args.tiles:
        return _cmd_volume_tiled(args)
    given = [flag for flag, name, unset in _TILED_ONLY if getattr(args, name) is not unset]
    if given:
        raise ValueError(f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} to tiled runs only; add "
                         "--tiles NXxNY (e.g. --tiles 2x2) or drop " + ("it" if len(given) == 1 else "them") + ".")
    return _cmd_volume(args)


def _checkpoint_path(out: Path) -> Path:
    """Where a tiled run writing ``out`` keeps its finished tasks until it succeeds."""
    return out.parent / f".{out.name}.geosynth-resume"


def _cmd_volume_tiled(args: argparse.Namespace) -> int:
    """``geosynth volume ... --tiles NXxNY``: :func:`geosynth.volume.tiled.synthesize_volume_tiled`."""
    from geosynth.volume.tiled import parse_tiles

    exemplar, example, inputs = _file_or_example(args.exemplar, args.example, EXEMPLARS, "EXEMPLAR",
                                                 "a mesh file (.ply, .obj, .stl, ...)")
    try:
        tiles = parse_tiles(args.tiles)
    except (TypeError, ValueError):
        raise ValueError(f"--tiles takes NXxNY, two integers >= 1 (e.g. 4x4), got {args.tiles!r}.") from None
    if args.tileable:
        raise ValueError("--tileable cannot be tiled yet (the tiles' margins would wrap); drop --tiles or --tileable.")
    size, block = _volume_shape(args)
    block = DEFAULT_BLOCK if block is None else block  # the parse-time checks; the exemplar may choose another
    out = Path(args.output)
    png, png_what = _picture_path(args)
    outputs = [(out, MESH_OUT, "-o/--output"), (png, IMAGE_SUFFIXES, png_what)] + _html_outputs(args)
    if args.tile_meshes is not None:  # every tile's file passes the guard, not only the first
        from geosynth.volume.tiled import tile_mesh_paths

        if os.path.exists(args.tile_meshes) and not os.path.isdir(args.tile_meshes):
            raise ValueError(f"--tile-meshes {args.tile_meshes!r} is a file; give a folder (it is created).")
        outputs += [(p, (".ply",), f"--tile-meshes' file") for p in tile_mesh_paths(args.tile_meshes, tiles)]
    _check_outputs(outputs, inputs)
    checkpoint = _checkpoint_path(out)
    if args.tile_meshes is not None:  # the folder itself must not be another output's path
        folder = os.path.realpath(args.tile_meshes)
        for path, what in ((out, "-o/--output"), (png, png_what), (checkpoint, "the checkpoint (beside -o/--output)"),
                           *((p, w) for p, _, w in _html_outputs(args))):
            if os.path.realpath(path) == folder:
                raise ValueError(f"--tile-meshes {args.tile_meshes!r} is the path of {what}; give the tile meshes a "
                                 "folder of their own.")
    if args.store is not None:
        store = os.path.realpath(args.store)
        for path, _, what in outputs + [(checkpoint, None, "the checkpoint (beside -o/--output)")]:
            real = os.path.realpath(path)
            if real == store or real.startswith(store + os.sep) or store.startswith(real + os.sep):
                raise ValueError(f"--store {args.store!r} and {what} {str(path)!r} are the same path or one lies "
                                 "inside the other (a store is replaced whole); give each its own place.")
    _check_device(args.device)

    from geosynth.core.memory import available_memory
    from geosynth.geometry.surface import save_mesh
    from geosynth.io.files import write_image
    from geosynth.io.pictures import render_mesh, side_by_side
    from geosynth.volume.examples import resolve_exemplar_mesh
    from geosynth.volume.synthesis import target_size
    from geosynth.volume.tiled import exemplar_source, seam_report, synthesize_volume_tiled, tile_grid

    say, printed = _recorder(args.quiet)
    label = example or exemplar
    _m1_colour_note(exemplar, say)
    options = _volume_options(args, block, tiles)

    def check_tiling(source_shape) -> None:  # before the exemplar's distance field: tiles too small fail at once
        tile_grid(source_shape, target_size(size, source_shape, args.levels), tiles, args.levels, block,
                  slab=options.slab, search=options.search, method=options.method)

    # the untiled run's automatic source resolution, block and size (geosynth.volume.synthesis.choose_settings),
    # after the tiling is checked on the default grid's shape (no distance computed yet)
    from geosynth.geometry.meshes import check_mesh
    from geosynth.volume.synthesis import choose_settings, exemplar_grid

    exemplar_mesh = resolve_exemplar_mesh(example or exemplar, args.seed)
    check_mesh(exemplar_mesh, "exemplar", drop_degenerate=args.drop_degenerate)
    check_tiling(exemplar_grid(exemplar_mesh, args.source_resolution or DEFAULT_RESOLUTION,
                               multiple=2 ** (args.levels - 1)).values.shape)
    settings = choose_settings(exemplar_mesh, size, args.levels, args.source_resolution,
                               None if args.block is None else block, device=args.device,
                               drop_degenerate=args.drop_degenerate)
    size, block = settings.size, settings.block
    if settings.text:
        say(settings.text)

    source, spacing, _ = exemplar_source(exemplar_mesh, settings.source_resolution, args.levels, args.seed,
                                         args.device, check=check_tiling, drop_degenerate=args.drop_degenerate,
                                         field=settings.field)
    shape = target_size(size, source.shape, args.levels)
    workers = options.tiling.workers
    engine = args.scheduler or f"a LocalCluster of {workers} workers"
    say(f"geosynth volume: {label} -> {shape[2]} x {shape[1]} x {shape[0]} samples in {tiles[0]}x{tiles[1]} tiles on "
        f"{engine}, {args.levels} levels, block {block}, seed {args.seed}, device {args.device or 'auto'}")
    if tiles == (1, 1):
        say("1x1 tiles: the whole target is one tile, run as one Dask task: the untiled synthesis's result "
            "(but for a height field's histogram matching, which tiles do not do yet; --store and --tile-meshes "
            "write it in one chunk and one file)")
    elif args.scheduler is None and workers > tiles[0] * tiles[1]:
        say(f"--workers {workers}: at most {tiles[0] * tiles[1]} tiles run at once; the other workers wait")

    def interrupt_note() -> str:
        saved = len([n for n in os.listdir(checkpoint) if n.endswith(".npz")]) if checkpoint.is_dir() else 0
        return (f"; the finished tile tasks are kept in {str(checkpoint)!r}: rerun the same command with --resume "
                "to continue from them" if saved else "")

    args.interrupt_note = interrupt_note
    gather = bool(args.quality_samples) and 2 * int(np.prod(shape)) < available_memory() // 4
    result = synthesize_volume_tiled(
        source, shape, seed=args.seed, device=args.device, spacing=spacing, scheduler=args.scheduler,
        store=args.store, gather=gather, mesh=True, tile_meshes=args.tile_meshes, inputs=inputs,
        progress=not args.quiet, checkpoint=checkpoint, resume=args.resume,
        options=dataclasses.replace(options, block=block))
    if args.resume:
        say(f"--resume: {result.resumed} finished task(s) of the interrupted run loaded from {str(checkpoint)!r}"
            if result.resumed else "--resume: no checkpoint of an interrupted run with these settings; ran from the start")
    for line in result.settings.lines(result.source.shape):  # the untiled run's lines, from the same choices
        say(line)
    if result.lattice_text:
        say(result.lattice_text)
    save_mesh(result.mesh, out, inputs=inputs)
    say(f"\nwritten {out}: {len(result.mesh.vertices):,} vertices, {len(result.mesh.faces):,} faces (tiles merged)")
    if result.store:
        say(f"store {result.store}: the uint8 field, chunks of {result.grid.core[1]} x {result.grid.core[0]} (x y)")
    if result.tile_meshes:
        say(f"tile meshes: {len(result.tile_meshes)} PLY files in {args.tile_meshes}")
    first_quality = len(printed)
    for line in result.lines():
        say("  " + line)
    quality = printed[first_quality:]
    say("timings:")
    for k, v in result.timings.items():
        say(f"  {k:<34} {v:8.2f} s")
    if gather:
        finest = result.grid.blocks[-1]  # a slab's block spans the thickness (the grid's block shape)
        q = seam_report(result.source, result.quantized, result.grid, stride=max(1, finest // 2), device=args.device)
        say(f"seams (block distance, squared uint8 units per sample; interior blocks are the baseline): across tile "
            f"borders {q['seam']:.1f}, inside tiles {q['interior']:.1f} (ratio {q['ratio']:.2f}); step across "
            f"borders {q['step_seam']:.2f}, elsewhere {q['step_interior']:.2f}")
        quality.append(printed[-1])
    exemplar_mesh = resolve_exemplar_mesh(example or exemplar, args.seed)
    picture = side_by_side([render_mesh(exemplar_mesh), render_mesh(result.mesh)],
                           labels=["exemplar", f"synthesized, {tiles[0]}x{tiles[1]} tiles"])
    write_image(png, picture, inputs=inputs)
    say(f"picture: {png} (exemplar left, result right)")
    _write_page(args, exemplar_mesh, result.mesh, [f"exemplar ({label})", f"synthesized, {tiles[0]}x{tiles[1]} tiles"],
                quality, _summary(quality, "seams"), inputs, say)
    return 0


def _texture_sizes(args: argparse.Namespace, model_is_sampled: bool) -> None:
    """--texture-size, --count, -k and --levels checked against each other where known now."""
    name, size = args.texture_example, args.texture_size
    if name == "bricks" and size % 16:
        raise ValueError(f"--texture-size {size}: the bricks texture tiles at multiples of 16 texels; "
                         f"use --texture-size {max(16, size // 16 * 16)} or {(size // 16 + 1) * 16}.")
    if name == "checker" and size < 24:
        raise ValueError(f"--texture-size {size}: the checker texture needs at least 24 texels (6 cells of 4).")
    if model_is_sampled and args.k >= args.count:
        raise ValueError(f"-k {args.k} needs more than {args.k} points but --count is {args.count}; "
                         "use a smaller -k or a larger --count.")
    if args.pattern_size is not None and args.method != "hybrid":
        raise ValueError(f"--pattern-size sets the hybrid's gap widening; --method {args.method} has none: drop "
                         "--pattern-size or use --method hybrid.")
    if name is not None and args.pattern_size is not None and args.pattern_size > size:
        raise ValueError(f"--pattern-size {args.pattern_size:g} is larger than the texture (--texture-size {size}): "
                         f"a pattern is at most the texture; use --pattern-size {size} or less.")
    if name is not None and args.method != "param":
        side = math.ceil(math.sqrt(args.k + 1))  # the texels a k-neighbourhood spans, as texture_points checks
        coarsest = size >> (args.levels - 1)
        if coarsest < side:
            raise ValueError(f"--texture-size {size} is smaller than the neighbourhood of -k {args.k} (about {side} x "
                             f"{side} texels)" + (f" on the coarsest of --levels {args.levels} ({coarsest} texels)"
                                                  if args.levels > 1 else "")
                             + "; use a larger --texture-size, a smaller -k or fewer --levels.")
    if name is not None:  # the texel search's memory, known now for a built-in texture (the model's points: later)
        from geosynth.texturing.synthesis import require_texture_memory

        levels = 1 if args.method == "param" else args.levels
        require_texture_memory(args.count if model_is_sampled else args.k + 1, size, size, args.method, args.k,
                               levels, args.m, not args.no_quality and args.quality_samples > 0)


def _cmd_texture(args: argparse.Namespace) -> int:
    from geosynth.texturing.models import POINT_MODELS
    from geosynth.texturing.textures import TEXTURES

    inputs = list(args.inputs)
    model_path = None if args.example else (inputs.pop(0) if inputs else None)
    texture_path = None if args.texture_example else (inputs.pop(0) if inputs else None)
    if inputs:
        raise ValueError(f"unexpected argument(s): {' '.join(inputs)}; give [MODEL|--example NAME] [TEXTURE|--texture-example NAME].")
    if model_path is None and args.example is None:
        raise ValueError(f"give a MODEL file (PLY point set or any mesh) or --example NAME ({', '.join(POINT_MODELS)}).")
    if texture_path is None and args.texture_example is None:
        raise ValueError(f"give a TEXTURE image (PNG/JPEG) or --texture-example NAME ({', '.join(TEXTURES)}).")
    used = []
    if model_path is not None:
        used.append(_check_input(model_path, "MODEL", "give a PLY point set or a mesh file, or --example NAME "
                                 f"({', '.join(POINT_MODELS)})"))
    if texture_path is not None:
        used.append(_check_input(texture_path, "TEXTURE", "give a PNG or JPEG image, or --texture-example NAME "
                                 f"({', '.join(TEXTURES)})"))
    _texture_sizes(args, model_is_sampled=args.example is not None)
    out = Path(args.output)
    png, png_what = _picture_path(args)
    _check_outputs([(out, POINTS_OUT, "-o/--output"), (png, IMAGE_SUFFIXES, png_what)] + _html_outputs(args), used)
    _check_device(args.device)

    from geosynth.geometry.pointsets import write_point_set
    from geosynth.io.files import write_image
    from geosynth.io.pictures import render_points, side_by_side
    from geosynth.texturing.models import load_point_model, point_model
    from geosynth.texturing.synthesis import TexturingOptions, texture_points
    from geosynth.texturing.textures import read_texture, texture_example

    say, printed = _recorder(args.quiet)
    if args.example:
        model, model_label = point_model(args.example, args.count, seed=args.seed), f"example {args.example}"
    else:
        model, model_label = load_point_model(model_path, count=args.count, seed=args.seed), model_path
    if model_path is not None and _has_colours(model_path):
        say(f"note: MODEL {model_path!r} has colours of its own; texture (M3) replaces them with the texture's.")
    if texture_path:
        texture, tex_label = read_texture(texture_path), Path(texture_path).name
        tileable = bool(args.tileable)
    else:
        texture = texture_example(args.texture_example, args.texture_size, seed=args.seed)
        tex_label = f"{args.texture_example} {args.texture_size}x{args.texture_size}"
        tileable = args.tileable is not False
    say(f"geosynth texture: {model_label} ({len(model):,} points) with {tex_label} "
        f"({texture.shape[1]} x {texture.shape[0]}, {'tileable' if tileable else 'not tileable'}), method {args.method}")
    options = TexturingOptions(
        method=args.method, k=args.k, levels=args.levels, coherent=args.coherent, m=args.m, unit_scale=args.unit_scale,
        up=None if args.random_orientation else (0.0, 1.0, 0.0), tileable=tileable, threshold=args.threshold,
        pattern_size=args.pattern_size, quality=not args.no_quality and args.quality_samples > 0,
        quality_samples=max(1, args.quality_samples))
    coloured, report = texture_points(model, texture, device=args.device, seed=args.seed, progress=not args.quiet,
                                      options=options)
    write_point_set(out, coloured)
    quality = list(report.lines())
    for line in quality:
        say(line)
    say(f"written {out}")
    azimuths = (-60, 60, 180, -150)[:args.views]
    views = [render_points(coloured.positions, coloured.normals, coloured.colors, size=(360, 320), view=(az, 25))
             for az in azimuths]
    scale = max(1, 256 // max(texture.shape[:2]))
    tex_big = np.repeat(np.repeat(texture, scale, 0), scale, 1)
    labels = ["texture"] + [f"view {i + 1}" for i in range(len(views))]
    write_image(png, side_by_side([tex_big] + views, labels=labels), inputs=used)
    say(f"picture: {png} (the texture, then {len(views)} view(s))")
    _write_page(args, _texture_plane(texture), coloured, [f"texture ({tex_label})", f"{model_label}, {args.method}"],
                quality, _summary(quality, "mean eq. 5 error"), used, say)
    return 0


def _texture_plane(texture: np.ndarray, largest: int = 256):
    """M3's exemplar in 3D: the texture image as a flat mesh in the xy plane, one vertex per
    texel (at most ``largest`` along a side) coloured by it, 1 unit wide."""
    import trimesh

    image = np.asarray(texture)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, -1)
    step = max(1, -(-max(image.shape[:2]) // largest))
    image = image[::step, ::step, :3]
    h, w = image.shape[:2]
    x, y = np.meshgrid(np.arange(w) / max(w - 1, 1), -np.arange(h) / max(w - 1, 1))
    vertices = np.stack([x, y, np.zeros_like(x)], -1).reshape(-1, 3)
    index = np.arange(h * w).reshape(h, w)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    colours = np.clip(image, 0, 255).astype(np.uint8).reshape(-1, 3)
    return trimesh.Trimesh(vertices, faces, vertex_colors=colours, process=False)


# ------------------------------------------------------------------ M2: pointtexture

# The library's words for the pointtexture options, in the command line's terms.
_POINTTEXTURE_FLAGS = [
    (r"^resolution ", "--resolution "), (r"\ba resolution of at most\b", "--resolution at most"),
    (r"^overlap ", "--overlap "), (r"\ban overlap of at most\b", "--overlap at most"), (r"^patch ", "--patch "),
    (r"\blarger patch or resolution\b", "larger --patch or --resolution"), (r"\ba larger patch\b", "a larger --patch"),
    (r"\bsmaller patch or overlap\b", "smaller --patch or --overlap"), (r"\ba smaller patch\b", "a smaller --patch"),
    (r"\ba smaller extra region\b", "a smaller --extra"), (r"\bskip the quality numbers\b", "give --no-quality"),
]


def _pointtexture_check(args: argparse.Namespace, box_min, box_max, points_in: int, points_inside: int, *,
                        count: bool, z_span: float, spacing: float, patch: float) -> None:
    """Every memory-scaling option of ``geosynth pointtexture`` (--count, --resolution, --scale or
    --size, --mesh-resolution) and every combination of --patch, --extra and --overlap checked
    before the work (:func:`geosynth.pointtexture.synthesis.check_synthesis`), with the flags named."""
    from geosynth.pointtexture.synthesis import check_synthesis

    try:
        check_synthesis(box_min, box_max, int(points_in), int(points_inside), size=args.size,
                        scale=2.0 if args.scale is None else args.scale, patch=patch, extra=args.extra,
                        overlap=args.overlap, resolution=args.resolution, tileable=args.tileable,
                        quality=not args.no_quality, count=count,
                        mesh_resolution=args.mesh_resolution if args.mesh else None, z_span=z_span, spacing=spacing)
    except ValueError as exc:  # (a MemoryBudgetError is no ValueError: it passes, its option named)
        text = str(exc)
        for pattern, flag in _POINTTEXTURE_FLAGS:
            text = re.sub(pattern, flag, text)
        raise ValueError(text) from None


def _pointtexture_exemplar(args: argparse.Namespace, exemplar: str | None, example: str | None, say):
    """The exemplar, with the options checked against it before it is made (a built-in: from
    a 1,000-point sample of it; a mesh: from its box before sampling --count points) and
    again once it is there (its own numbers)."""
    from geosynth.pointtexture.examples import POINT_EXAMPLES, point_texture_example
    from geosynth.pointtexture.texture import read_point_texture

    # before the exemplar exists its element size is unknown: its memory and the options are
    # checked with a patch of 0.4 (the old default), and again once it is there with the patch
    # chosen from it (choose_patch)
    patch = args.patch or 0.4
    if example:
        count = args.count or POINT_EXAMPLES[example].count
        probe = point_texture_example(example, 1000, seed=args.seed)  # B and the share inside it: count's own
        share = probe.inside_mask(probe.points, probe.box_min, probe.box_max).mean()
        _pointtexture_check(args, probe.box_min, probe.box_max, count, round(count * share), count=True,
                            z_span=float(np.ptp(probe.points[:, 2])),
                            spacing=probe.spacing * math.sqrt(len(probe) / count), patch=patch)
        texture = point_texture_example(example, count, seed=args.seed)
        sampled = True
    else:
        count = args.count or 40_000
        sampled = False

        def before_sampling(lo, hi, share):  # a mesh: count points spread by area, about ``share`` inside B
            nonlocal sampled
            sampled = True
            area = float(np.prod((hi - lo)[:2])) / share
            _pointtexture_check(args, lo, hi, count, round(share * count), count=True, z_span=float(hi[2] - lo[2]),
                                spacing=math.sqrt(area / count), patch=patch)

        texture = read_point_texture(exemplar, count=count, seed=args.seed, before_sampling=before_sampling)
        if args.count is not None and not sampled:
            raise ValueError(f"--count {args.count}: EXEMPLAR {exemplar!r} is a point set, whose {len(texture):,} "
                             "points are used as they are; --count is for --example and meshes (drop it).")
    if texture.merged:
        say(f"EXEMPLAR {texture.name}: {texture.merged:,} coincident point(s) merged (same position as an earlier "
            f"point; the first one's normal kept), {len(texture):,} left")
    inside = int(texture.inside_mask(texture.points, texture.box_min, texture.box_max).sum())
    line = ""
    if args.patch is None:  # issue 32: the patch from the exemplar's element size, said in one line
        from geosynth.pointtexture.synthesis import choose_patch

        choice = choose_patch(texture, args.resolution)
        patch, line = choice.patch, choice.line
    _pointtexture_check(args, texture.box_min, texture.box_max, len(texture), inside, count=sampled,
                        z_span=float(np.ptp(texture.points[:, 2])), spacing=texture.spacing, patch=patch)
    return texture, patch, line


def _has_colours(path) -> bool:
    from geosynth.io.readers import has_colours

    return has_colours(Path(path))


def _m1_colour_note(exemplar, say) -> None:
    """M1 synthesizes a signed distance field (shape only): an exemplar's colours cannot be
    carried, and a user is told so in one line rather than finding a grey output."""
    if exemplar is not None and _has_colours(exemplar):
        say(f"note: EXEMPLAR {exemplar!r} has colours; volume synthesis (M1) works on the shape's distance field and "
            "cannot carry them: the output mesh has no colour.")


def _cmd_pointtexture(args: argparse.Namespace) -> int:
    from geosynth.pointtexture.examples import POINT_EXAMPLES

    exemplar, example, inputs = _file_or_example(args.exemplar, args.example, POINT_EXAMPLES, "EXEMPLAR",
                                                 "a PLY point set or a mesh file")
    if args.scale is not None and args.size is not None:
        raise ValueError("give --scale or --size, not both.")
    out = Path(args.output)
    png, png_what = _picture_path(args)
    outputs = [(out, POINTS_OUT, "-o/--output"), (png, IMAGE_SUFFIXES, png_what)] + _html_outputs(args)
    if args.mesh:
        outputs.append((Path(args.mesh), MESH_OUT, "--mesh"))
    _check_outputs(outputs, inputs)
    _check_device(args.device)

    from geosynth.core.memory import MemoryBudgetError
    from geosynth.geometry.pointsets import write_point_set
    from geosynth.io.files import write_image
    from geosynth.io.pictures import render_points, side_by_side
    from geosynth.pointtexture.synthesis import PointTextureOptions, output_mesh, synthesize_point_texture

    say, printed = _recorder(args.quiet)
    texture, patch, patch_line = _pointtexture_exemplar(args, exemplar, example, say)
    scale = 2.0 if args.scale is None else args.scale
    say(f"geosynth pointtexture: {texture.name} ({len(texture):,} points) -> "
        + (f"{args.size[0]:g} x {args.size[1]:g}" if args.size else f"{scale:g} x the exemplar's box")
        + f", patch {patch:g}{'' if args.patch else ' (automatic)'}, {'tileable, ' if args.tileable else ''}seed {args.seed}, "
          f"device {args.device or 'auto'}")
    if patch_line:
        say(patch_line)
    options = PointTextureOptions(size=args.size, scale=scale, patch=patch, extra=args.extra, overlap=args.overlap,
                                  resolution=args.resolution, eps=args.eps, tileable=args.tileable, relax=args.relax,
                                  quality=not args.no_quality)
    points, report, timings = synthesize_point_texture(texture, device=args.device, seed=args.seed,
                                                       progress=not args.quiet, options=options)
    mesh = None
    if args.mesh:  # made before any output is written: a refusal leaves no output behind
        try:
            mesh = output_mesh(points.positions, points.normals, report.spacing, args.mesh_resolution,
                               device=args.device)
        except MemoryBudgetError as exc:  # output_mesh's resolution is --mesh-resolution
            raise MemoryBudgetError(str(exc).replace("resolution", "--mesh-resolution"), option="mesh_resolution",
                                    largest=exc.largest, estimate=exc.estimate, available=exc.available) from None
    write_point_set(out, points)
    quality = list(report.lines())
    for line in quality:
        say(line)
    say("timings (s): " + "  ".join(f"{k} {timings[k]:.2f}" for k in
                                    ("precompute", "search", "warp", "blend", "other", "total", "quality")
                                    if k in timings))
    coloured = " and the exemplar's colours" if points.colors is not None else ""
    say(f"written {out}: {len(points):,} points with normals{coloured}")
    if mesh is not None:
        from geosynth.geometry.surface import save_mesh

        save_mesh(mesh, args.mesh, inputs=inputs)
        say(f"mesh: {args.mesh}: {len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces "
            f"(watertight: {bool(mesh.is_watertight)})")
    inside = texture.inside_mask(texture.points, texture.box_min, texture.box_max)
    view = (-60, 40)
    pics = [render_points(texture.points[inside], texture.normals[inside],
                          None if texture.colors is None else texture.colors[inside], size=(360, 360), view=view),
            render_points(points.positions, points.normals, points.colors, size=(560, 560), view=view)]
    labels = ["exemplar (inside B)", "synthesized"]
    if report.baseline is not None:
        pics.append(render_points(report.baseline.positions, report.baseline.normals, report.baseline.colors,
                                  size=(560, 560), view=view))
        labels.append("random pasting")
    write_image(png, side_by_side(pics, labels=labels), inputs=inputs)
    say(f"picture: {png} ({', '.join(labels)})")
    exemplar_points = (texture.points[inside], None if texture.colors is None else texture.colors[inside],
                       texture.normals[inside])
    _write_page(args, exemplar_points, points, [f"exemplar {texture.name} (inside B)", "synthesized (same scale)"],
                quality, _summary(quality, "patch-field distance"), inputs, say, same_scale=True)
    return 0


def _add_pointtexture_parser(sub, common, seed: dict, device: dict) -> None:
    from geosynth.pointtexture.examples import POINT_EXAMPLES

    p = sub.add_parser("pointtexture", parents=[common],
                       help="M2: grow a larger point-set geometry texture from an exemplar (patches, warp, blend)")
    p.add_argument("exemplar", nargs="?", help="a PLY point set (normals estimated when absent) or a mesh file")
    p.add_argument("--example", choices=list(POINT_EXAMPLES), help="a built-in exemplar instead")
    p.add_argument("-o", "--output", required=True, help="the synthesized point set with normals, .ply")
    p.add_argument("--scale", type=_float_type(0, inclusive=False), default=None,
                   help="output extent in units of the exemplar's box, > 0 (default 2)")
    p.add_argument("--size", type=_float_type(0, inclusive=False), nargs=2, default=None, metavar=("W", "H"),
                   help="output extent in x and y, world units (instead of --scale)")
    p.add_argument("--patch", type=_float_type(0, inclusive=False), default=None,
                   help="patch side, a fraction of the exemplar box's shorter side, in (0, 1] (default: 1.25 "
                        "periods of the exemplar's relief, measured, within 6 field cells and 0.5; the run says what it "
                        "measured); the patch plus its extra region must fit in the exemplar box, else refused")
    p.add_argument("--extra", type=_float_type(0, inclusive=False), default=0.2,
                   help="extra region width, a fraction of the patch, in (0, 0.5] (default 0.2): cut with the patch "
                        "and overwritten by the next one; --patch plus --extra must fit in the exemplar box")
    p.add_argument("--overlap", type=_float_type(0, inclusive=False), default=0.25,
                   help="overlap width, a fraction of the patch, below 0.5 (default 0.25): a patch is blended across "
                        "its overlap and overwritten from patch - overlap on, so the overlaps on its two sides must "
                        "leave it an interior (2 x overlap < patch, in cells); refused otherwise")
    p.add_argument("--resolution", type=_int_type(8), default=48,
                   help="D(T_in) samples along the exemplar box's longer side, >= 8 (default 48); refused beyond "
                        "the memory and beyond the patch search's exact sums (about 100 to 130 for the built-ins, "
                        "less with the quality numbers), naming the largest that works")
    p.add_argument("--eps", type=_float_type(0, inclusive=True), default=0.1,
                   help="candidates within (1 + eps) of the best are drawn from, >= 0 (default 0.1)")
    p.add_argument("--count", type=_int_type(1000), default=None,
                   help="points of a built-in exemplar (default: the paper's Table 1 size) or sampled from a mesh "
                        "(default 40000); not for a PLY point set; refused beyond the memory")
    p.add_argument("--tileable", action="store_true", help="make the output periodic (copies tile without seams)")
    p.add_argument("--relax", action="store_true", help="relax the final point set")
    p.add_argument("--mesh", default=None, help="also write a watertight mesh of the result (.ply, .obj, .stl)")
    p.add_argument("--mesh-resolution", type=_int_type(8), default=160,
                   help="grid samples along the longest axis for --mesh, >= 8 (default 160); refused beyond the "
                        "memory before any work")
    p.add_argument("--no-quality", action="store_true", help="skip the quality numbers and the random-pasting baseline")
    p.add_argument("--device", **device)
    p.add_argument("--seed", **seed)
    p.add_argument("--png", default=None, help="picture of exemplar and result, .png or .jpg "
                                               "(default: OUTPUT with .png)")
    p.add_argument("--html", default=None, metavar="FILE",
                   help="also write a page that shows the exemplar and the result in 3D, turnable with the mouse (self-contained: no network), .html")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_pointtexture)


# ------------------------------------------------------------------ complete (M4)


def _max_error_type(text: str) -> float:
    """An argparse ``type=`` for --max-error: geosynth.completion.synthesis.check_max_error's range."""
    from geosynth.completion.synthesis import check_max_error

    try:
        value = float(text)
    except ValueError:
        value = text
    try:
        return check_max_error(value, name=None)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).rstrip(".")) from None


def _capture_colours(capture) -> str:
    """How the capture is coloured, for the run's first line: 'RGB colours', 'RGBA colours'
    or 'no colours' (then the completion matches relief only, mu 1)."""
    from geosynth.completion.prep import as_capture

    cap = capture if hasattr(capture, "colors") and hasattr(capture, "alpha") else None
    if cap is None and hasattr(capture, "visual"):
        kind = getattr(capture.visual, "kind", None)
        if kind not in ("vertex", "face"):
            return "no colours"
        try:
            cap = as_capture(capture)
        except ValueError:  # refused by complete_surface itself, in its words
            return "colours"
    if cap is None or cap.colors is None:
        return "no colours"
    return "RGBA colours" if cap.alpha is not None else "RGB colours"


def _cmd_complete(args: argparse.Namespace) -> int:
    from geosynth.completion.examples import COMPLETION_EXAMPLES

    _, _, inputs = _file_or_example(args.input, args.example, COMPLETION_EXAMPLES, "INPUT",
                                    "a mesh or PLY point set of the captured part (colours optional)",
                                    name_as_path=False)
    out = Path(args.output)
    png, png_what = _picture_path(args)
    _check_outputs([(out, POINTS_OUT, "-o/--output"), (png, IMAGE_SUFFIXES, png_what)] + _html_outputs(args), inputs)
    _check_device(args.device)

    from geosynth.completion.examples import completion_example
    from geosynth.completion.synthesis import CompletionOptions, complete_surface, completion_picture, write_completion
    from geosynth.io.files import write_image

    say, printed = _recorder(args.quiet)
    region = None
    if args.example:  # a built-in gets what a file gets: its scene (capture, fit, region), no method settings
        ex = completion_example(args.example, seed=args.seed)
        capture, label, region = ex.capture, f"example {args.example} ({ex.note})", ex.region
        fit = args.fit or ex.fit
    else:
        from geosynth.geometry.pointsets import read_geometry

        capture, label, fit = read_geometry(args.input), args.input, args.fit
    # unset options (None) are chosen from the capture's relief; the report's "automatic settings" line says how
    window, rotations, frames, refine, spacing = args.window, args.rotations, args.frames, args.refine, args.spacing
    mu = args.mu if args.mu is not None else 0.5

    def shown(v):
        return "auto" if v is None else v

    say(f"geosynth complete: {label}, {len(capture.vertices if hasattr(capture, 'vertices') else capture.positions):,} "
        f"captured points ({_capture_colours(capture)}), fit {fit or 'by residual'}, window {shown(window)}, "
        f"rotations {shown(rotations)}, frames {shown(frames)}, mu {mu:g}, refine {shown(refine)}, "
        f"spacing {shown(spacing)}, search {args.search}, seed {args.seed}, device {args.device or 'auto'}")
    options = CompletionOptions(window=window, rotations=rotations, frames=frames, refine=refine, spacing=spacing,
                                mu=mu, max_error=args.max_error, search=args.search, balance=not args.no_balance)
    surface, report, timings = complete_surface(capture, fit=fit, region=region, device=args.device, seed=args.seed,
                                                progress=not args.quiet, options=options)
    quality = list(report.lines())
    for line in quality:
        say(line)
    say("timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items() if k != "targets_per_s")
        + f"; {timings['targets_per_s']:.1f} targets/s")
    write_completion(out, surface, inputs=inputs)
    say(f"written {out}: {len(surface):,} vertices ({int(surface.completed.sum()):,} completed), "
        f"{len(surface.faces):,} faces")
    write_image(png, completion_picture(surface), inputs=inputs)
    say(f"picture: {png} (captured part, completion, completed part tinted)")
    if args.html:
        import trimesh

        colours = surface.colors
        keep = ~surface.completed[surface.faces].any(1)  # the captured part: faces of captured vertices only
        captured = trimesh.Trimesh(surface.positions, surface.faces[keep], vertex_colors=colours, process=False)
        completed = trimesh.Trimesh(surface.positions, surface.faces, vertex_colors=colours, process=False)
    else:
        captured = completed = None
    _write_page(args, captured, completed, ["captured part", "completed"], quality,
                _summary(quality, "relief slope", "volume integral"), inputs, say)
    return 0


# ------------------------------------------------------------------ gallery


# (name, model, texture) of M3's gallery runs: every built-in model and every built-in texture once
_TEXTURE_RUNS = (("blob", "bricks"), ("sphere", "checker"), ("torus", "noise"))
# (mesh, example) of the relief runs: every built-in example once, on the body of revolution or the knot
_RELIEF_RUNS = (("vase", "knurl"), ("vase", "bark"), ("vase", "weave"), ("vase", "scales"), ("knot", "cobbles"),
                ("knot", "hammered"))
# the README's sizes (--full) where the README names one; the command's defaults otherwise
_README_SIZES = {"volume-terrain": ["--size", "64"], "pointtexture-heightfield": ["--count", "10000"],
                 "texture-blob-bricks": ["--count", "10000"]}


def gallery_entries(full: bool = False) -> list[tuple[str, list[str]]]:
    """Every built-in of every method, as ``(name, arguments)`` of one run each (outputs not
    yet named): each command's defaults, at small sizes (M1 --size 64, M2 --count 4000, M3
    --count 5000; M4's built-ins have no size option: --search coherent, the cost that grows
    with the capture; relief --scale 8, examples 8x their size: ~5,000 vertices), or with ``full``
    at the README's sizes (the defaults where it names none)."""
    from geosynth.completion.examples import COMPLETION_EXAMPLES
    from geosynth.pointtexture.examples import POINT_EXAMPLES

    runs = [(f"volume-{name}", ["volume", "--example", name], ["--size", "64"]) for name in EXEMPLARS]
    runs += [(f"pointtexture-{name}", ["pointtexture", "--example", name], ["--count", "4000"])
             for name in POINT_EXAMPLES]
    runs += [(f"texture-{model}-{texture}", ["texture", "--example", model, "--texture-example", texture],
              ["--count", "5000"]) for model, texture in _TEXTURE_RUNS]
    runs += [(f"complete-{name}", ["complete", "--example", name], ["--search", "coherent"])
             for name in COMPLETION_EXAMPLES]
    runs += [(f"relief-{mesh}-{example}", ["relief", mesh, example], ["--scale", "8"]) for mesh, example in _RELIEF_RUNS]
    return [(name, argv + (_README_SIZES.get(name, []) if full else small)) for name, argv, small in runs]


def run_gallery(folder: str | os.PathLike, entries: Sequence[tuple[str, list[str]]], *, device: str | None = None,
                progress: bool = True, title: str = "geosynth gallery", note: str = "") -> list[dict]:
    """Run each entry in this process and write its outputs into ``folder`` (NAME.ply, the
    command's picture NAME.png, its page NAME.html), then ``folder``/index.html: one row per
    entry with its picture, time and quality line. A failing entry (bad arguments, an error
    of the run) is caught, its files dropped, and shown on the index; the others go on.

    Args:
        folder: the gallery's folder (created).
        entries: ``(name, arguments)`` pairs (:func:`gallery_entries`, or a subset).
        device: passed to every run as --device (None: each run's default, auto).
        progress: a tqdm bar over the runs, on stderr.

    Returns:
        The index's rows: ``name``, ``command``, ``seconds``, ``summary``, ``error``, ``page``, ``picture``.
    """
    import contextlib
    import io

    from tqdm import tqdm

    from geosynth.io.files import staged_section
    from geosynth.io.viewer import write_gallery_index

    folder = Path(folder)
    rows = []
    bar = tqdm(total=len(entries), desc="gallery", unit="run", file=sys.stderr, disable=not progress, leave=True)
    t_all = time.perf_counter()
    try:
        for name, arguments in entries:
            bar.set_postfix_str(name)
            files = {kind: folder / f"{name}{suffix}" for kind, suffix in
                     (("output", ".ply"), ("picture", ".png"), ("page", ".html"))}
            argv = list(arguments) + ["-o", str(files["output"]), "--png", str(files["picture"]),
                                      "--html", str(files["page"]), "--quiet"]
            if device is not None:
                argv += ["--device", device]
            row = {"name": name, "command": "geosynth " + " ".join(argv), "seconds": 0.0, "summary": "",
                   "error": None, "page": files["page"].name, "picture": files["picture"].name}
            t0 = time.perf_counter()
            command = arguments[0] if arguments else "?"
            try:
                with staged_section():
                    errors = io.StringIO()
                    try:
                        with contextlib.redirect_stderr(errors):
                            args = build_parser().parse_args(argv)
                    except SystemExit:
                        raise ValueError(" ".join(errors.getvalue().split()) or "bad arguments") from None
                    args.argv = argv
                    row["command"] = _command_text(args)
                    command = args.command
                    code = args.func(args)
                    row["summary"] = getattr(args, "quality_summary", "") or ""
                    if code:
                        raise RuntimeError(f"exit code {code}")
            except Exception as exc:  # one entry's failure is shown on the index, not fatal
                row["error"] = f"{type(exc).__name__}: {_message(exc, command)}"
                row["page"] = row["picture"] = None
            row["seconds"] = time.perf_counter() - t0
            rows.append(row)
            bar.update(1)
    finally:
        bar.close()
    total = time.perf_counter() - t_all
    write_gallery_index(folder / "index.html", rows, title=title,
                        note=(note + " " if note else "") + f"{len(rows)} runs in {total:.0f} s.")
    return rows


def _cmd_gallery(args: argparse.Namespace) -> int:
    folder = Path(args.output)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"-o/--output {args.output!r} is a file; the gallery writes a folder of pages: give a "
                         "folder name (it is created).")
    from geosynth.io.viewer import HTML_SUFFIXES

    entries = gallery_entries(args.full)
    if args.only:
        known = {name for name, _ in entries}
        unknown = [n for n in args.only if n not in known]
        if unknown:
            raise ValueError(f"--only {' '.join(unknown)}: no such gallery entry; the entries: {', '.join(sorted(known))}.")
        entries = [(name, argv) for name, argv in entries if name in args.only]
    _check_outputs([(folder / "index.html", HTML_SUFFIXES, "the index in -o/--output")], [])
    _check_device(args.device)
    say = (lambda *a, **k: None) if args.quiet else print
    say(f"geosynth gallery: {len(entries)} runs ({'the README sizes' if args.full else 'small sizes'}) into {folder}")
    rows = run_gallery(folder, entries, device=args.device, progress=not args.quiet,
                       note=f"{'README sizes (--full)' if args.full else 'Small sizes'}, device {args.device or 'auto'}.")
    for r in rows:
        say(f"  {r['name']:<28} {r['seconds']:6.1f} s  " + (f"FAILED: {r['error']}" if r["error"] else r["summary"]))
    failed = sum(1 for r in rows if r["error"])
    say(f"index: {folder / 'index.html'} ({len(rows) - failed} of {len(rows)} runs succeeded; "
        f"{sum(r['seconds'] for r in rows):.0f} s)")
    return 0


# ------------------------------------------------------------------ relief (issue 34)


def _mask_arg(text: str | None):
    """--mask: None, an (r, g, b) vertex colour ("#rrggbb" or "r,g,b"), or a file of face indices
    (.txt, whitespace-separated, or .npy) as geosynth.relief.grow.grow_relief's mask."""
    import numpy as np

    if text is None:
        return None, None
    t = text.strip()
    if t.startswith("#") and len(t) == 7:
        try:
            return np.array([int(t[i:i + 2], 16) for i in (1, 3, 5)]), None
        except ValueError:
            pass
    parts = t.split(",")
    if len(parts) == 3 and all(p.strip().isdigit() for p in parts):
        rgb = np.array([int(p) for p in parts])
        if rgb.max() <= 255:
            return rgb, None
    from geosynth.io.files import check_input

    path = check_input(t, "--mask face list")
    try:
        ids = np.load(path) if path.suffix.lower() == ".npy" else np.loadtxt(path, dtype=np.int64, ndmin=1)
    except ValueError as exc:
        raise ValueError(f"--mask {t!r}: not a list of face indices ({exc}).") from None
    return np.asarray(ids, np.int64).reshape(-1), str(path)


def _cmd_relief(args: argparse.Namespace) -> int:
    from geosynth.io.files import check_input
    from geosynth.relief.examples import BUILTINS
    from geosynth.relief.shapes import SHAPES
    from geosynth.relief.write import RELIEF_SUFFIXES

    built_in_mesh = args.mesh in SHAPES and not Path(args.mesh).exists()  # a file of that name wins
    inputs = [] if built_in_mesh else [str(check_input(args.mesh, "mesh"))]
    named = Path(args.example)
    if args.example not in BUILTINS and not named.exists() and not named.suffix and len(named.parts) == 1:
        raise FileNotFoundError(f"example {args.example!r} is neither a built-in ({', '.join(BUILTINS)}) nor an "
                                "existing file.")
    if args.example not in BUILTINS or Path(args.example).exists():
        inputs.append(str(check_input(args.example, "example")))
    if args.colour:
        inputs.append(str(check_input(args.colour, "--colour image")))
    out = Path(args.output)
    png, png_what = _picture_path(args)
    _check_outputs([(out, RELIEF_SUFFIXES, "-o/--output"), (png, IMAGE_SUFFIXES, png_what)] + _html_outputs(args),
                   inputs)
    mask, mask_file = _mask_arg(args.mask)
    if mask_file:
        inputs.append(mask_file)
    if args.method == "synth":
        _check_device(args.device)

    import numpy as np

    from geosynth.io.files import write_image
    from geosynth.geometry.meshes import load_mesh
    from geosynth.relief.grow import grow_relief
    from geosynth.relief.quality import relief_picture
    from geosynth.relief.shapes import shape_mesh
    from geosynth.relief.write import write_relief

    say = (lambda *a, **k: None) if args.quiet else print
    mesh = shape_mesh(args.mesh) if built_in_mesh else load_mesh(args.mesh)
    if mask is not None and mask.shape != (3,):  # face indices -> a face selection
        if mask.size and (mask.min() < 0 or mask.max() >= len(mesh.faces)):
            raise ValueError(f"--mask: face indices must be in 0..{len(mesh.faces) - 1}.")
        sel = np.zeros(len(mesh.faces), bool)
        sel[mask] = True
        mask = sel
    say(f"geosynth relief: {args.mesh} ({len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces), example "
        f"{args.example}, method {args.method}, depth {args.depth if args.depth is not None else 'auto'}, scale "
        f"{args.scale:g}, resolution {args.resolution if args.resolution is not None else 'auto'}, seed {args.seed}, "
        f"device {args.device or 'auto'}")
    result = grow_relief(mesh, args.example, depth=args.depth, scale=args.scale, resolution=args.resolution,
                         method=args.method, mask=mask, colour=args.colour, field=args.field, seed=args.seed,
                         device=args.device, progress=not args.quiet, search=args.search, refine=args.refine,
                         coherence=args.coherence == "on", remesh=args.remesh)
    quality = list(result.lines())
    for line in quality:
        say(line)
    write_relief(out, result.vertices, result.faces, result.colours, inputs=inputs)
    say(f"written {out}: {len(result.vertices):,} vertices, {len(result.faces):,} faces"
        f"{', vertex colours' if result.colours is not None and out.suffix.lower() != '.stl' else ''}")
    write_image(png, relief_picture((mesh.vertices, mesh.faces), (result.vertices, result.faces), result.colours),
                inputs=inputs)
    say(f"picture: {png} (input, result, close-up)")
    if args.html:
        import trimesh

        grown = trimesh.Trimesh(result.vertices, result.faces, process=False,
                                vertex_colors=result.colours if result.colours is not None else None)
    else:
        mesh = grown = None
    _write_page(args, mesh, grown, ["input mesh", f"relief ({args.method})"], quality,
                _summary(quality, f"{args.method}: amplitude"), inputs, say)
    return 0


# ------------------------------------------------------------------ the parser


def build_parser() -> argparse.ArgumentParser:
    """The ``geosynth`` parser; every number is range-checked here (one-line errors, exit 2)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", help="show the traceback of an error instead of one line")
    common.add_argument("--verbose", action="store_true",
                        help="show the libraries' warnings (e.g. Warp's notice that no CUDA driver is present)")

    parser = _Parser(prog="geosynth", description="Example-based geometry synthesis.")
    parser.add_argument("--version", action="version", version=f"geosynth {geosynth.__version__}")
    parser.add_argument("--debug", dest="global_debug", action="store_true", help="as each command's --debug")
    parser.add_argument("--verbose", dest="global_verbose", action="store_true", help="as each command's --verbose")
    sub = parser.add_subparsers(dest="command", required=True)
    seed = dict(type=_int_type(0), default=0, help="seed of every random choice, an integer >= 0 (default 0)")
    device = dict(type=_device_type(), default=None, help="cpu, cuda[:N], opencl[:P:D] or auto (default)")

    p = sub.add_parser("devices", parents=[common], help="list the devices present")
    p.set_defaults(func=_cmd_devices)

    p = sub.add_parser("volume", parents=[common],
                       help="M1: synthesize a larger piece of geometry from an exemplar mesh")
    p.add_argument("exemplar", nargs="?", help="an exemplar mesh file (any format trimesh reads)")
    p.add_argument("--example", choices=list(EXEMPLARS), help="a built-in exemplar instead")
    p.add_argument("-o", "--output", required=True, help="the output mesh (.ply, .obj or .stl)")
    p.add_argument("--size", type=_int_type(8, each=True), nargs="+", default=[128], metavar="N",
                   help="target samples along x and y (z keeps the exemplar's thickness), or x y z; each >= 8 and a "
                        "multiple of 2^(levels-1) (default 128)")
    p.add_argument("--levels", type=_int_type(1, MAX_LEVELS), default=3,
                   help=f"resolution levels, 1 to {MAX_LEVELS} (default 3)")
    p.add_argument("--block", type=_int_type(2, power_of_two=True, each=True), nargs="+", default=None, metavar="B",
                   help="finest block size, or one per level (coarsest first); powers of two >= 2 (default: 16, "
                        "32 where the source resolution was doubled for thin features, or larger to hold a whole "
                        "separate element)")
    p.add_argument("--source-resolution", type=_int_type(8), default=None,
                   help="exemplar samples along its longest side, >= 8 (default: 64, or 128 when the exemplar's "
                        "thinnest features span under 3 samples at 64; the size then doubles too, keeping its world "
                        "extent)")
    p.add_argument("--tileable", action="store_true", help="make the output periodic (copies tile without seams)")
    p.add_argument("--method", choices=["auto", "optimize", "graphcut", "paper"], default="auto",
                   help="auto (default): graphcut for a slab, optimize otherwise and for a terrain (a relief "
                        "without flat ground) or tubes across the slab (the best structure measured); optimize: "
                        "texture optimization per level; graphcut: the paper's scan with "
                        "minimum-error cuts; paper: the paper's scan-order copying")
    p.add_argument("--search", choices=["cascade", "tree", "linear"], default="cascade",
                   help="exact block search: cascade of lower bounds (default, fastest), the paper's tree, or linear")
    p.add_argument("--lattice", choices=["auto", "yes", "no"], default="auto",
                   help="a slab's blocks come from source positions congruent to theirs modulo the exemplar's "
                        "lattice, so that linked rings close: auto (default: for a network of linked elements with a "
                        "lattice), yes (whenever the exemplar has one) or no")
    p.add_argument("--slab", choices=["auto", "yes", "no"], default="auto",
                   help="blocks through the exemplar's full thickness, grown across only: auto (default: when the "
                        "exemplar is at least 2.5x thinner along z than across: geosynth.volume.synthesis.SLAB_RATIO), yes or "
                        "no; the same choice with --tiles")
    p.add_argument("--smooth", type=_int_type(0, MAX_SMOOTH), default=10,
                   help=f"Taubin smoothing iterations, 0 to {MAX_SMOOTH} (default 10)")
    p.add_argument("--quality-samples", type=_int_type(0), default=100,
                   help="blocks per direction for the quality numbers, >= 0 (0: skip; default 100)")
    p.add_argument("--drop-degenerate", action="store_true",
                   help="drop the exemplar's zero-area faces instead of refusing the mesh")
    p.add_argument("--device", **device)
    p.add_argument("--seed", **seed)
    p.add_argument("--png", default=None, help="picture of exemplar and result, .png or .jpg "
                                               "(default: OUTPUT with .png)")
    p.add_argument("--html", default=None, metavar="FILE",
                   help="also write a page that shows the exemplar and the result in 3D, turnable with the mouse (self-contained: no network), .html")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_volume)
    # tiled synthesis on Dask (geosynth.volume.tiled)
    p.add_argument("--tiles", default=None, metavar="NXxNY",
                   help="synthesize in NX x NY tiles on Dask (two-phase schedule, same result with any workers)")
    p.add_argument("--workers", type=_int_type(1, 1024), default=None,
                   help="workers of the local Dask cluster started for --tiles, 1 to 1024 (default 2)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="a running Dask scheduler for --tiles (tcp://host:port; workers must share the file "
                        "system), or 'threads'")
    p.add_argument("--store", default=None, metavar="OUT.zarr", help="with --tiles: the field as a zarr store")
    p.add_argument("--tile-meshes", default=None, metavar="DIR", help="with --tiles: one PLY per tile in DIR")
    p.add_argument("--resume", action="store_true",
                   help="with --tiles: continue an interrupted run of the same command from the tile tasks it "
                        "finished (kept beside OUTPUT in .OUTPUT.geosynth-resume until a run succeeds); the "
                        "result is the uninterrupted run's, bit for bit")
    p.set_defaults(func=_cmd_volume_any)

    p = sub.add_parser("texture", parents=[common],
                       help="M3: colour a point model from a sample texture (parameterization, matching, hybrid)")
    p.add_argument("inputs", nargs="*", metavar="[MODEL] [TEXTURE]",
                   help="a point model (PLY point set, or a mesh to sample) and a texture image (PNG/JPEG)")
    p.add_argument("--example", choices=["sphere", "torus", "blob"], help="a built-in point model instead of MODEL")
    p.add_argument("--count", type=_int_type(16), default=20_000,
                   help="points of a built-in model or sampled from a mesh, >= 16 (default 20000)")
    p.add_argument("--texture-example", choices=["bricks", "checker", "noise"], help="a built-in texture instead of TEXTURE")
    p.add_argument("--texture-size", type=_int_type(8), default=64,
                   help="size of a built-in texture, >= 8 (bricks: a multiple of 16; checker: >= 24; default 64)")
    p.add_argument("-o", "--output", required=True, help="the coloured point set, .ply")
    p.add_argument("--method", choices=["param", "match", "hybrid"], default="hybrid", help="default hybrid")
    p.add_argument("-k", type=_int_type(3), default=25, help="neighbours per point, >= 3 and < the points (default 25)")
    p.add_argument("--levels", type=_int_type(1, MAX_LEVELS), default=1,
                   help=f"multiresolution levels of matching, 1 to {MAX_LEVELS} (default 1)")
    p.add_argument("--coherent", action="store_true", help="coherent matching (candidates near the neighbours' sources)")
    p.add_argument("--m", type=_int_type(1, 32), default=8,
                   help="texture supersampling of the texel search, 1 to 32 (default 8)")
    p.add_argument("--unit-scale", type=_float_type(0, inclusive=False), default=1.0,
                   help="one texel = this x the mean point spacing, > 0 (default 1)")
    p.add_argument("--random-orientation", action="store_true", help="random texture direction instead of the up vector (0, 1, 0)")
    p.add_argument("--tileable", action=argparse.BooleanOptionalAction, default=None,
                   help="the texture tiles (default: yes for built-ins, no for images)")
    p.add_argument("--threshold", type=_float_type(0, inclusive=False), default=1.6,
                   help="distortion threshold of the parameterization, > 0 (default 1.6)")
    p.add_argument("--pattern-size", type=_float_type(0, inclusive=False), default=None,
                   help="texture pattern size in texels (> 0), for the hybrid's gap widening")
    p.add_argument("--quality-samples", type=_int_type(0), default=200,
                   help="points whose neighbourhoods the quality numbers use, >= 0 (0: skip; default 200)")
    p.add_argument("--no-quality", action="store_true", help="skip the quality numbers")
    p.add_argument("--device", **device)
    p.add_argument("--seed", **seed)
    p.add_argument("--png", default=None, help="picture: the texture and the views, .png or .jpg "
                                               "(default: OUTPUT with .png)")
    p.add_argument("--html", default=None, metavar="FILE",
                   help="also write a page that shows the texture and the coloured model in 3D, turnable with the mouse (self-contained: no network), .html")
    p.add_argument("--views", type=_int_type(1, 4), default=3, help="views of the result in the picture, 1 to 4 (default 3)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_texture)

    p = sub.add_parser("field", parents=[common],
                       help="sample the signed distance of a mesh or an oriented point set on a grid")
    p.add_argument("input", nargs="?", help="a mesh (any format trimesh reads) or a PLY point set with normals")
    p.add_argument("--example", choices=MESH_EXAMPLES, help="a built-in mesh instead of INPUT")
    p.add_argument("-o", "--output", required=True, help="the field, .npz")
    p.add_argument("--resolution", type=_int_type(2), default=64, help="samples along the longest axis, >= 2 (default 64)")
    p.add_argument("--padding", type=_float_type(0, inclusive=True), default=0.1,
                   help="grid margin, a fraction (>= 0) of the largest extent (default 0.1)")
    p.add_argument("--band", type=_float_type(0, inclusive=False), default=None, help="clamp distances to [-W, W], W > 0")
    p.add_argument("--unsigned", action="store_true", help="unsigned distance (meshes)")
    p.add_argument("--drop-degenerate", action="store_true", help="drop zero-area faces instead of refusing the mesh")
    p.add_argument("--radius", type=_float_type(0, inclusive=False), default=None,
                   help="MLS Gaussian width for point sets, > 0 (default: from the spacing)")
    p.add_argument("--estimate-normals", action="store_true", help="estimate missing point normals")
    p.add_argument("--device", **device)
    p.add_argument("--png", default=None, help="picture of the slices, .png or .jpg (default: OUTPUT with .png)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_field)

    p = sub.add_parser("complete", parents=[common],
                       help="M4: complete the relief and colour of a partly captured surface")
    p.add_argument("input", nargs="?", help="the captured part: a mesh or a PLY point set (colours optional)")
    p.add_argument("--example", choices=["golf", "bark", "wave", "noise", "tower", "flat"],
                   help="a built-in capture instead of INPUT")
    p.add_argument("-o", "--output", required=True, help="the completed surface, .ply (mesh with colours)")
    p.add_argument("--fit", choices=["plane", "sphere", "cylinder"], default=None,
                   help="the underlying surface (default: chosen by residual; built-ins: their scene's)")
    p.add_argument("--window", type=_int_type(1, 12), default=None,
                   help="neighbourhood window W in edge rings, 1 to 12 and no wider than the capture (some captured "
                        "vertex W target spacings from its border; the run says how many) (default: chosen from the "
                        "relief's period, about 1.3 periods across, 3 to 5; the run says why)")
    p.add_argument("--rotations", type=_int_type(1, 64), default=None,
                   help="orientations tried about the normal, 1 to 64 (default: 1 for a directed relief on a plane or "
                        "cylinder, else 4; the run says why)")
    p.add_argument("--frames", choices=["paper", "fit"], default=None,
                   help="tangent frames the rotations start from: the paper's per-normal ones, or the fit's own "
                        "orientation (cylinder: around and along the axis; plane: its axes; sphere: along its "
                        "latitudes and meridians) "
                        "(default: fit with 1 rotation for a directed relief, else paper)")
    p.add_argument("--mu", type=_float_type(0, inclusive=True), default=None,
                   help="weight of shape against colour, 0 to 1 (1: relief only; default 0.5)")
    p.add_argument("--max-error", type=_max_error_type, default=0.1,
                   help="initial MaxErrThreshold on the normalized ssd, 6e-08 to 128 (the match scores' range); "
                        "raised 10%% after each boundary list without progress (default 0.1)")
    p.add_argument("--device", **device)
    p.add_argument("--seed", **seed)
    p.add_argument("--refine", type=_int_type(0, 8), default=None,
                   help="refinement passes after the growth, 0 to 8: every completed target matched again with "
                        "its whole window (our extension; default: 2 for a directed relief with sharp features, else 0)")
    p.add_argument("--spacing", choices=["minimum", "median"], default=None,
                   help="the targets' spacing: the capture's minimum edge length (the paper) or the median of its edges on "
                        "the fit (our option: targets as dense as the capture) (default: chosen from the capture: the median "
                        "for a regular sampling on a curved fit, else the minimum; period / 6 for a capture with over "
                        "12 samples on its relief's period)")
    p.add_argument("--search", choices=["auto", "exhaustive", "coherent"], default="auto",
                   help="FindMatches' candidates: every one (exhaustive, the paper; cost targets x candidates) or the "
                        "targets' neighbours' sources, 128 spread over the capture and those around the best (coherent, our option; linear in "
                        "the targets) (default auto: exhaustive while targets x candidates x rotations is under 4e7)")
    p.add_argument("--no-balance", action="store_true",
                   help="the paper's uniform pick among the matches within 1.1x the best (default: the "
                        "histogram-aware pick, our extension; see geosynth.completion.synthesis._Balance)")
    p.add_argument("--png", default=None, help="picture: captured, completed, completed part tinted; .png or .jpg "
                                               "(default: OUTPUT with .png)")
    p.add_argument("--html", default=None, metavar="FILE",
                   help="also write a page that shows the captured part and the completed surface in 3D, turnable with the mouse (self-contained: no network), .html")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_complete)

    p = sub.add_parser("relief", parents=[common],
                       help="issue 34: grow an example's relief (and colour) over a mesh, printable")
    p.add_argument("mesh", help="the mesh to texture (.ply, .obj, .stl, .off, .glb, .gltf), or a built-in: vase "
                                "(a body of revolution), knot (a (2, 3) torus knot)")
    p.add_argument("example", help="a built-in (knurl, bark, hammered, cobbles, scales, weave), a grey height image "
                                   "(white high), or a captured patch (a mesh or PLY point set)")
    p.add_argument("-o", "--output", required=True, help="the textured mesh: .stl, .ply, .obj, .glb or .3mf (colours "
                                                         "in all but .stl)")
    p.add_argument("--depth", type=_float_type(0, inclusive=True), default=None,
                   help="the relief's height range in mesh units (default: 1%% of the mesh's size for images and "
                        "built-ins; a captured patch's own)")
    p.add_argument("--scale", type=_float_type(0, inclusive=False), default=1.0,
                   help="multiplies the example's size (an image spans a quarter of the mesh's size) (default 1)")
    p.add_argument("--resolution", type=_float_type(0, inclusive=False), default=None,
                   help="the output mesh's longest edge, mesh units (default: 1.4 x the example's own spacing, at most "
                        "2x finer than the synthesis' mesh, which has about 6 vertices on the example's period)")
    p.add_argument("--method", choices=["synth", "project"], default="synth",
                   help="synth: grown on the surface (M4's growth, default); project: triplanar projection (the "
                        "baseline)")
    p.add_argument("--colour", default=None, help="an RGB image of the same size as a height-image example")
    p.add_argument("--mask", default=None,
                   help="parts kept bare: a vertex colour of the mesh ('#rrggbb' or 'r,g,b') or a file of face "
                        "indices (.txt or .npy)")
    p.add_argument("--field", choices=["auto", "axis", "principal"], default="auto",
                   help="the tangent field the example follows (default auto: a body of revolution's axis, else "
                        "smoothed principal directions)")
    p.add_argument("--search", choices=["auto", "exhaustive", "coherent"], default="auto",
                   help="FindMatches' candidates, as geosynth complete's --search (default auto)")
    p.add_argument("--refine", type=_int_type(0, 8), default=1,
                   help="passes after the growth matching every vertex again with its whole window, 0 to 8 (default 1)")
    p.add_argument("--coherence", choices=["on", "off"], default="on",
                   help="among the matches within 1.1x the best, prefer one continuing a neighbour's copy (default on)")
    p.add_argument("--remesh", choices=["auto", "yes", "no"], default="auto",
                   help="isotropic remesh before synthesis (default auto: when over 30%% of the area is in long "
                        "slivers, e.g. a trimesh cylinder's sides, or the mesh is coarser than the synthesis' spacing)")
    p.add_argument("--device", **device)
    p.add_argument("--seed", **seed)
    p.add_argument("--png", default=None, help="picture: input, result, close-up; .png or .jpg (default: OUTPUT "
                                               "with .png)")
    p.add_argument("--html", default=None, metavar="FILE",
                   help="also write a page that shows the input mesh and the result in 3D, turnable with the mouse (self-contained: no network), .html")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_relief)

    p = sub.add_parser("demo", parents=[common], help="nearest-block search on a generated field, on every device")
    p.add_argument("--device", type=_device_type(allow_all=True), default="all",
                   help="a device string, or 'all' (default) for every present device")
    p.add_argument("--size", type=_int_type(4, DEMO_MAX_SIZE), default=64,
                   help=f"source field size, 4 to {DEMO_MAX_SIZE} (default 64)")
    p.add_argument("--block", type=_int_type(2), default=16, help="block size, 2 to --size (default 16)")
    p.add_argument("--seed", **seed)
    p.add_argument("--repeat", type=_int_type(1, 1000), default=3,
                   help="timed repetitions per device, 1 to 1000 (best is shown; default 3)")
    p.add_argument("-o", "--output", default="demo_out", help="folder for the picture (default demo_out)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_demo)
    _add_pointtexture_parser(sub, common, seed, device)

    p = sub.add_parser("gallery", parents=[common],
                       help="run every built-in of every method; a viewer page per result and an index page")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="the gallery's folder (created): per run NAME.ply, NAME.png, NAME.html; and index.html")
    p.add_argument("--full", action="store_true", help="the README's sizes (default: small sizes, a few minutes)")
    p.add_argument("--only", nargs="+", default=None, metavar="NAME",
                   help="only these entries (e.g. volume-terrain complete-golf); default all")
    p.add_argument("--device", **device)
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_gallery)
    return parser


# ------------------------------------------------------------------ errors, signals, main

# What each command's memory can be lowered with, when an estimate names no option.
_MEMORY_FLAGS = {"volume": "--size or --source-resolution", "texture": "--count or --texture-size",
                 "field": "--resolution", "demo": "--size"}


class _Terminated(BaseException):
    """SIGTERM arrived (raised by main's handler, so that cleanups run)."""


# The signals main's handlers saw during this run: asked before the outputs are committed,
# so that an interrupt some library caught (an optional import's `except BaseException`)
# still stops the run.
_SIGNALS: list[int] = []


def _on_sigterm(signum, frame):  # pragma: no cover - exercised through a subprocess
    _SIGNALS.append(signal.SIGTERM)
    raise _Terminated()


def _on_sigint(signum, frame):  # pragma: no cover - exercised through a subprocess
    _SIGNALS.append(signal.SIGINT)
    raise KeyboardInterrupt


def _expected() -> tuple[type[BaseException], ...]:
    """The exception types bad input or a bad environment raise: one line, exit 2."""
    kinds: list[type[BaseException]] = [ValueError, TypeError, RuntimeError, OSError, MemoryError, ImportError]
    pil = sys.modules.get("PIL.Image")
    if pil is not None and hasattr(pil, "DecompressionBombError"):
        kinds.append(pil.DecompressionBombError)
    return tuple(kinds)


def _message(exc: BaseException, command: str) -> str:
    """One line saying what failed and how to fix it, in the command line's terms."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    if isinstance(exc, MemoryError):
        option = getattr(exc, "option", None)
        if option:
            # The library names its parameter ("lower size to at most ..."): say the flag.
            flag = "--" + str(option).replace("_", "-")
            text = f"{flag}: " + re.sub(rf"\b(lower|smallest) {re.escape(str(option))}\b", rf"\1 {flag}", text)
        elif command in _MEMORY_FLAGS:
            text = f"{text.rstrip('.')}; on the command line: lower {_MEMORY_FLAGS[command]}."
    for parameter, flag in _PARAMETER_FLAGS.get(command, []):
        text = re.sub(parameter, flag, text)
    return " ".join(text.split())  # one line


def main(argv: list[str] | None = None, *, early: Sequence[int] = ()) -> int:
    """Run the command line; returns the exit code (0 done, 1 a failed demo check or an
    unexpected internal error, 2 bad input, 130 Ctrl-C, 143 SIGTERM).

    ``early``: signals recorded before this module was loaded (:mod:`geosynth._launch`):
    the run ends at once, writing nothing."""
    in_main = threading.current_thread() is threading.main_thread()
    _SIGNALS.clear()
    previous = ({sig: signal.signal(sig, handler) for sig, handler in
                 ((signal.SIGINT, _on_sigint), (signal.SIGTERM, _on_sigterm))} if in_main else {})
    try:
        return _main(argv, list(early))
    except _Terminated:  # outside the command's own handling (parsing, loading a command's modules)
        return 143
    except KeyboardInterrupt:
        if argv is not None and ("--debug" in argv):
            raise
        print("geosynth: interrupted", file=sys.stderr)
        return 130
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def _main(argv, early: list[int]) -> int:
    """:func:`main` inside its signal handlers."""
    from geosynth.io.files import staged_outputs

    if early:  # interrupted while loading: nothing has been done
        if signal.SIGTERM in early:
            return 143
        print("geosynth: interrupted (while starting; nothing was written)", file=sys.stderr)
        return 130
    args = build_parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    debug = args.debug or args.global_debug
    loud = bool(args.verbose or args.global_verbose)
    if loud:
        set_verbose(True)  # the runtimes' own messages (geosynth.core.config); read when they load
    name = f"geosynth {args.command}"
    line = None
    try:
        with staged_outputs(interrupted=lambda: bool(_SIGNALS)):
            return args.func(args)
    except _Terminated:
        note = _interrupt_note(args)
        if note:
            print(f"{name}: terminated{note}", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        if signal.SIGTERM in _SIGNALS:  # a SIGTERM that a library caught, seen before the commit
            return 143
        if debug:
            raise
        code, line = 130, f"{name}: interrupted{_interrupt_note(args)}"
    except Exception as exc:
        if debug:
            raise
        if isinstance(exc, _expected()):
            code, line = 2, f"{name}: {_message(exc, args.command)}"
        else:
            code, line = 1, (f"{name}: unexpected {type(exc).__name__}: {_message(exc, args.command)} "
                             "(rerun with --debug for the traceback, and please report it)")
    finally:
        if loud:  # an in-process caller (a test, a notebook) gets its own setting back
            set_verbose(None)
    _close_progress_bars(interrupted=code == 130)
    sys.stdout.flush()
    print(line, file=sys.stderr)
    return code


def _interrupt_note(args: argparse.Namespace) -> str:
    """What an interrupted command left that a rerun can use (a tiled run's checkpoint), or ""."""
    note = getattr(args, "interrupt_note", None)
    try:
        return note() if note is not None else ""
    except OSError:
        return ""


def _close_progress_bars(interrupted: bool = False) -> None:
    """Close the bars an interrupted or failed run left open, so the message that follows
    starts on a line of its own (a bar's frame may outlive the exception). An interrupt
    inside a bar's constructor (after its first display, before it is returned) leaves
    no bar to close but an open line: after an interrupt the line is ended whenever a
    bar was ever made."""
    module = sys.modules.get("tqdm")
    bars = list(getattr(module.tqdm, "_instances", ())) if module is not None else []
    for bar in bars:
        bar.close()
    if bars or (interrupted and module is not None):  # a bar interrupted mid-write may not have ended its line
        sys.stderr.write("\n")

if __name__ == "__main__":
    sys.exit(main())
