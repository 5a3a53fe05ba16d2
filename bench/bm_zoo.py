"""Every method with its defaults on every zoo member (issue #32): one table, one contact sheet
per method.

Each member's file (bench/zoo.py) goes through the command line exactly as a user's file would
(`geosynth volume FILE`, `geosynth pointtexture FILE`, `geosynth complete FILE`, no other
option but the output, the device and the seed), then the benchmark measures the result
itself, from the files, independently of what the command printed:

- volume: the exemplar's and the output's distance fields at one world spacing ->
  :func:`geosynth.volume.features.element_features` (element diameter, height, tube
  thickness, top-surface period, share of whole elements), ratios output / exemplar; the
  block distance against random tiling as the command printed it (< 1 beats random).
- pointtexture: heights above the exemplar's base plane, gridded ->
  :func:`geosynth.completion.spectrum.relief_spectrum` (amplitude, dominant period) of exemplar
  and output; the patch-field distance against random pasting as printed.
- complete: the relief over the zoo surface's own (u, v) (plane x, y; cylinder arc length and
  height; sphere near its equator) of the captured and the completed parts -> amplitude,
  period, orientation; the colour histogram intersection completed vs captured.

Writes bench/out/zoo/zoo.md (the table, with the command), bench/out/zoo/<method>.png (each
member's own picture, exemplar and result side by side, one row per member) and the outputs.

Usage: python bench/bm_zoo.py [--quick] [--devices opencl:0:0] [--methods volume,pointtexture,complete]
       [--count 12] [--out FILE]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import finish, parse_args, start  # noqa: E402
from zoo import METHODS, Member, zoo  # noqa: E402

TOLERANCE = 0.15  # the target: feature size and amplitude within 15% of the exemplar's


def _run(args: list[str], timeout: float) -> tuple[int, str, float]:
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, "-m", "geosynth", *args], capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout + p.stderr, time.perf_counter() - t0
    except subprocess.TimeoutExpired as e:
        return 124, (e.stdout or "") if isinstance(e.stdout, str) else "", time.perf_counter() - t0


def _float(pattern: str, text: str) -> float:
    m = re.search(pattern, text)
    return float(m.group(1)) if m else math.nan


# ------------------------------------------------------------------ measures


def _field(mesh, spacing: float):
    from geosynth.geometry.meshes import mesh_distance

    extent = float(np.max(mesh.bounds[1] - mesh.bounds[0]))
    resolution = max(8, int(math.ceil(extent / spacing)))
    return mesh_distance(mesh, resolution=resolution, padding=0.05)


RELIEF_FAMILIES = ("bumps", "cobbles", "terrain")  # one connected slab with a relief on top
TUBE_FAMILIES = ("tubes",)  # elements that run across the footprint: their size is the thickness
MEASURE_SAMPLES = 160  # samples across the exemplar's longest side where a volume is measured
# tubes stay connected: the output's tubes run at least an exemplar's length between breaks
# (geosynth.volume.features.tube_connection == 1; the volume share across, used before, fell as the output
# grew and rewarded tubes fused into a network)


def same_scale_picture(exemplar, output, path: Path, read_as=None) -> None:
    """Exemplar beside a piece of the output of the exemplar's own footprint (the elements
    when they are smaller than half the window, else the faces, whose centre lies in the window around the
    output's centre), so that both render at one
    scale: the command's own picture frames a larger output smaller, which makes every
    feature look shrunk. ``read_as``: the exemplar as M1 reads it (the surface of its signed
    distance, a trimesh), drawn instead of the input mesh: parts concatenated, not unioned,
    draw as surfaces crossing each other where M1 reads one solid (the zoo's linked tori
    intersect, and M1 is given rings fused at every crossing)."""
    import trimesh

    from geosynth.io.files import write_image
    from geosynth.io.pictures import render_mesh, side_by_side

    half = (exemplar.bounds[1] - exemplar.bounds[0])[:2] / 2
    centre = output.bounds.mean(axis=0)[:2]
    parts = output.split(only_watertight=False)
    small = len(parts) > 1 and np.median([np.max(p.extents[:2]) for p in parts]) <= np.min(half)
    def window(mesh):
        inside = np.all(np.abs(mesh.triangles_center[:, :2] - centre) <= half, axis=1)
        return mesh.submesh([np.nonzero(inside)[0]], append=True) if inside.any() else None

    if small:  # separate elements: the whole ones whose centre is in the window (a cut would read as broken);
        # a part larger than the window (a network beside specks of debris) is cut to it, not drawn whole
        keep = [p if np.max(p.extents[:2]) <= 2 * np.min(half) else window(p) for p in parts
                if np.all(np.abs(p.bounds.mean(axis=0)[:2] - centre) <= half)]
        keep = [p for p in keep if p is not None]
        piece = trimesh.util.concatenate(keep) if keep else output
    else:
        piece = window(output) or output
    shown = exemplar if read_as is None else read_as
    write_image(path, side_by_side([render_mesh(shown), render_mesh(piece)],
                                   labels=["exemplar" if read_as is None else "exemplar, as M1 reads it (its union)",
                                           "output: a piece of the exemplar's size"]))


def measure_volume(member: Member, exemplar: Path, output: Path, printed: str) -> dict:
    """Feature ratios output / exemplar (measured as a relief for the slab families, as
    separate elements for the others) and the block distance against random."""
    from geosynth.geometry.meshes import load_mesh
    from geosynth.volume.features import compare_features, element_features

    from geosynth.geometry.surface import field_to_mesh

    a, b = load_mesh(exemplar), load_mesh(output)
    # one world spacing for both, fine enough that tilted rings nearly touching stay apart
    # (at 96 samples across, the knit's tori fused in the measure and read as broken)
    spacing = float(np.max(a.bounds[1] - a.bounds[0])) / MEASURE_SAMPLES
    fa, fb = _field(a, spacing), _field(b, spacing)
    same_scale_picture(a, b, output.parent.parent / "pictures" / f"{member.name}-same-scale.png",
                       read_as=field_to_mesh(fa))
    relief = member.family in RELIEF_FAMILIES
    ea = element_features(fa.values, float(fa.spacing[0]), slab=relief)
    eb = element_features(fb.values, float(fb.spacing[0]), slab=relief)
    r = compare_features(ea, eb)
    synth = _float(r"\n\s*synthesis\s.*?mean\s+([\d.]+)", printed)
    rand = _float(r"\n\s*random tiling\s.*?mean\s+([\d.]+)", printed)
    # no whole element in the exemplar (rings linked into one network, as tubes across are) -> read as tubes,
    # whose size is their thickness: a network's equivalent-sphere diameter is its box's
    kind = "relief" if ea.relief else "tubes" if member.family in TUBE_FAMILIES or not ea.sizes else "elements"
    size = {"relief": r["period"], "tubes": r["thickness"], "elements": r["diameter"]}[kind]
    return {"kind": kind, "size": size, "height": r["height"], "thickness": r["thickness"], "whole": r["whole"],
            "spanning": r["spanning"], "connected": r["connected"], "whole_exemplar": ea.whole_fraction,
            "loops": r["loops"], "period": r["period"],
            "vs_random": synth / rand if rand else math.nan}


def _grid(uv: np.ndarray, h: np.ndarray, spacing: float):
    """The heights on a grid (:func:`geosynth.completion.spectrum.heights_on_grid`), cropped to
    the largest connected piece: a capture in two strips (a plane missing a band) has a
    spectrum whose peaks are split by the gap's own (lobes at 1 / the strips' distance)."""
    from scipy import ndimage

    from geosynth.completion.spectrum import heights_on_grid

    grid, mask = heights_on_grid(uv - uv.min(0), h, spacing)
    labels, n = ndimage.label(mask)
    if n > 1:
        largest = 1 + int(np.argmax(np.bincount(labels.ravel())[1:]))
        rows, cols = np.nonzero(labels == largest)
        box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
        keep = labels[box] == largest
        grid, mask = np.where(keep, grid[box], np.nan), keep
    return grid, mask


def _split_scales(grid: np.ndarray, mask: np.ndarray, spacing: float, sigma: float):
    """(detail, base): the heights less their Gaussian average over ``sigma`` (world units;
    normalized over the mask, so the border is not pulled down), and that average."""
    from scipy.ndimage import gaussian_filter

    z, m = np.where(mask, grid, 0.0), mask.astype(np.float64)
    s = sigma / spacing
    base = gaussian_filter(z, s, mode="constant") / np.maximum(gaussian_filter(m, s, mode="constant"), 1e-9)
    return np.where(mask, grid - base, np.nan), np.where(mask, base, np.nan)


def correlation_length(grid: np.ndarray, mask: np.ndarray, spacing: float) -> float:
    """:func:`geosynth.completion.spectrum.correlation_length` (an isotropic relief's element size)."""
    from geosynth.completion.spectrum import correlation_length as measure

    return measure(grid, spacing, mask)


def compare_reliefs(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], spacing: float) -> dict:
    """Relief ``b`` (grid, mask) against the exemplar's ``a`` at one spacing.

    The exemplar's dominant period P (:func:`geosynth.completion.spectrum.relief_spectrum`) sets
    the scale: both reliefs are split into detail (less their Gaussian average over P) and
    base. ``size``: detail period ratio (an isotropic exemplar, anisotropy < 0.5: the
    correlation length's ratio instead); ``height``: detail amplitude ratio; ``base``: the
    base's standard deviation over the detail amplitude, output minus exemplar (a relief
    whose plate undulates, which a person sees as fading or sinking features); ``angle_diff``:
    degrees between the detail's directions. Without the split a slow undulation of the
    output's plate wins the spectrum peak and reads as features 6x too large (seen on the zoo).
    """
    from geosynth.completion.spectrum import relief_spectrum

    period = relief_spectrum(a[0], spacing, a[1]).period
    out = {}
    parts = []
    for grid, mask in (a, b):
        detail, base = _split_scales(grid, mask, spacing, period)
        parts.append((relief_spectrum(detail, spacing, mask), float(np.nanstd(base)),
                      correlation_length(detail, mask, spacing)))
    (ra, ba, la), (rb, bb, lb) = parts
    out["size"] = rb.period / ra.period if ra.anisotropy >= 0.5 else lb / la
    out["height"] = rb.amplitude / ra.amplitude
    out["base"] = bb / rb.amplitude - ba / ra.amplitude
    d = abs(math.degrees(rb.angle - ra.angle)) % 180
    out["angle_diff"] = min(d, 180 - d)
    out["anisotropy"] = ra.anisotropy
    return out


def _gap(uv: np.ndarray, h: np.ndarray, region: np.ndarray, threshold: float, period: float) -> float:
    """95th percentile, over the bare points of ``region``, of the distance to the nearest bump
    point (height >= ``threshold``) of the whole surface, in periods: how wide its bare patches are."""
    from scipy.spatial import cKDTree

    bumps = h >= threshold
    bare = region & ~bumps
    if bumps.sum() == 0 or bare.sum() == 0:
        return math.nan
    d, _ = cKDTree(uv[bumps]).query(uv[bare])
    return float(np.percentile(d, 95)) / period


def bump_gaps(member: Member, uv: np.ndarray, h: np.ndarray, done: np.ndarray, usable: np.ndarray) -> float:
    """How wide the completed part's bare patches are against the truth's over the same part
    (:func:`_gap`: 1 = as the generator made them; bumps grown into chains leave wider ones).
    The truth is the zoo member's whole surface (``zoo.capture_surface(whole=True)``); a bump is
    a point above the midpoint of the captured heights' 5th and 99.5th percentiles."""
    from scipy.spatial import cKDTree

    from zoo import capture_surface

    truth = capture_surface(member, whole=True)[0]
    uv_t, h_t, usable_t = _surface_uv(member, truth)
    captured = h[~done & usable]
    lo, hi = np.percentile(captured, [5, 99.5])
    threshold = 0.5 * (lo + hi)
    # the truth's points in the completed part: those whose nearest output point was completed
    _, nearest = cKDTree(uv[usable]).query(uv_t[usable_t])
    region_t = np.zeros(len(uv_t), bool)
    region_t[np.flatnonzero(usable_t)] = done[usable][nearest]
    period = float(member.params["period"])
    ours = _gap(uv[usable], h[usable], (done & usable)[usable], threshold, period)
    theirs = _gap(uv_t[usable_t], h_t[usable_t], region_t[usable_t], threshold, period)
    return ours / theirs if theirs > 0 else math.nan


def _points(path: Path) -> np.ndarray:
    from geosynth.geometry.pointsets import read_geometry

    g = read_geometry(path)
    return np.asarray(g.vertices if hasattr(g, "vertices") else g.positions, np.float64)


def measure_points(member: Member, exemplar: Path, output: Path, printed: str) -> dict:
    """The output's relief against the exemplar's (:func:`compare_reliefs`, heights above
    z = 0), and the patch-field distance against random pasting as printed."""
    a, b = _points(exemplar), _points(output)
    spacing = member.params["width"] / 150
    row = compare_reliefs(_grid(a[:, :2], a[:, 2], spacing), _grid(b[:, :2], b[:, 2], spacing), spacing)
    if not member.family.startswith("ridges"):
        row["angle_diff"] = math.nan
    m = re.search(r"patch-field distance.*?mean ([\d.]+) vs ([\d.]+)", printed)
    row["vs_random"] = float(m.group(1)) / float(m.group(2)) if m else math.nan
    return row


def _surface_uv(member: Member, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(uv, h, usable) of positions on a zoo capture's surface, in its own frame."""
    s = member.params["surface"]
    if s == "plane":
        return pos[:, :2], pos[:, 2], np.ones(len(pos), bool)
    if s == "cylinder":
        r = np.hypot(pos[:, 0], pos[:, 1])
        return np.column_stack([np.mod(np.arctan2(pos[:, 1], pos[:, 0]), 2 * np.pi), pos[:, 2]]), r - 1, np.ones(len(pos), bool)
    r = np.linalg.norm(pos, axis=1)
    polar = np.arccos(np.clip(pos[:, 2] / r, -1, 1))
    lon = np.mod(np.arctan2(pos[:, 1], pos[:, 0]), 2 * np.pi)
    # azimuth and polar angle (arc lengths at the equator) in a band about it: their scale
    # depends on the latitude only, alike for the captured and the completed side (azimuth x
    # sin(polar) would shear features more the further they lie from azimuth 0)
    return np.column_stack([lon, polar]), r - 1, np.abs(polar - np.pi / 2) < 0.45


def _histogram(c: np.ndarray) -> np.ndarray:
    q = (np.asarray(c)[:, :3].astype(np.int64) // 32)
    h = np.bincount(q[:, 0] * 64 + q[:, 1] * 8 + q[:, 2], minlength=512).astype(float)
    return h / max(h.sum(), 1)


def measure_complete(member: Member, output: Path, capture: Path | None = None) -> dict:
    """Relief amplitude / period / orientation of the completed part against the captured
    part, colour histogram intersection, and whether colour came through.

    The colours are compared with the capture file's own (``capture``; else the output's
    uncompleted vertices): the output's uncompleted part also holds the oversampling's new
    vertices, whose colours are Gaussian-weighted averages of their neighbours (the paper's
    Sec. 4), colours between the stripes' that the capture never shows and the completion,
    which copies the capture's own vertices, never makes (a ridged sphere: 0.58 against
    the capture's own, the completion 0.97, so that a faithful completion read as 0.67)."""
    import plyfile

    v = plyfile.PlyData.read(str(output))["vertex"].data
    pos = np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64)
    done = v["completed"].astype(bool) if "completed" in v.dtype.names else np.zeros(len(pos), bool)
    uv, h, usable = _surface_uv(member, pos)
    parts = [("captured", ~done & usable), ("completed", done & usable)]
    for key, sel in parts:
        if sel.sum() < 50:
            return {"error": f"{key}: {int(sel.sum())} usable vertices"}
    # one grid no finer than either part's samples: a grid finer than the completion's targets
    # (spaced by the automatic choice) reads the interpolation's dimples as the relief's period
    from scipy.spatial import cKDTree

    spacing = max([member.params["spacing"]] + [float(np.median(cKDTree(uv[sel]).query(uv[sel], k=2)[0][:, 1]))
                                                for _, sel in parts])
    grids = [_grid(uv[sel], h[sel], spacing) for _, sel in parts]
    out = compare_reliefs(grids[0], grids[1], spacing)
    if member.params["relief"] != "ridges":
        out["angle_diff"] = math.nan
    if member.params["relief"] == "bumps":
        out["gaps"] = bump_gaps(member, uv, h, done, usable)
    out["colour_in"] = bool(member.params["coloured"])
    out["colour_out"] = "red" in v.dtype.names
    if out["colour_in"] and out["colour_out"]:
        c = np.column_stack([v["red"], v["green"], v["blue"]])
        ref = c[~done]
        if capture is not None:
            from geosynth.completion.prep import as_capture
            from geosynth.geometry.pointsets import read_geometry

            cap = as_capture(read_geometry(capture))
            if cap.colors is not None:
                ref = cap.colors
        out["colour_hist"] = float(np.minimum(_histogram(ref), _histogram(c[done])).sum())
    return out


# ------------------------------------------------------------------ runs


def run_member(member: Member, folder: Path, device: str, quick: bool, timeout: float,
               measure_only: bool = False) -> dict:
    """Run one member's command (``measure_only``: take the output, log and time a previous
    run left in ``folder``) and measure its result; the row of the table."""
    if measure_only:
        return measure_member(member, folder)
    src = member.write(folder / "inputs")
    out = folder / "outputs" / f"{member.name}.ply"
    png = folder / "pictures" / f"{member.name}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    png.parent.mkdir(parents=True, exist_ok=True)
    extra = {"volume": ["--size", "64"] if quick else [], "pointtexture": [], "complete": []}[member.method]
    args = [member.method, str(src), "-o", str(out), "--png", str(png), "--device", device, "--seed", "1", *extra]
    rc, text, seconds = _run(args, timeout)
    row = {"member": member.name, "family": member.family, "writer": member.params["writer"], "rc": rc,
           "seconds": seconds, "command": "geosynth " + " ".join(args)}
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    (folder / "logs" / f"{member.name}.txt").write_text(text)
    (folder / "logs" / f"{member.name}.json").write_text(json.dumps(row))
    return measure_member(member, folder, row, text)


def measure_member(member: Member, folder: Path, row: dict | None = None, text: str | None = None) -> dict:
    """The row of a run whose files are in ``folder`` (its log's json when ``row`` is None),
    measured against the input file the run read (written when the folder has none)."""
    src = folder / "inputs" / f"{member.name}{member.suffix}"
    if not src.exists():
        src = member.write(folder / "inputs")
    out = folder / "outputs" / f"{member.name}.ply"
    png = folder / "pictures" / f"{member.name}.png"
    if row is None:
        log = folder / "logs" / f"{member.name}.json"
        if not log.exists():
            return {"member": member.name, "family": member.family, "writer": member.params["writer"], "rc": -1,
                    "seconds": math.nan, "error": f"no previous run in {folder}"}
        row = json.loads(log.read_text())
        text = (folder / "logs" / f"{member.name}.txt").read_text()
    row = dict(row)
    if row["rc"] != 0:
        row["error"] = text.strip().splitlines()[-1] if text.strip() else f"exit {row['rc']}"
        return row
    try:
        if member.method == "volume":
            row.update(measure_volume(member, src, out, text))
            png = png.with_name(f"{member.name}-same-scale.png")
        elif member.method == "pointtexture":
            row.update(measure_points(member, src, out, text))
        else:
            row.update(measure_complete(member, out, src))
    except Exception as exc:  # a measure that fails is a row, not the end of the run
        row["error"] = f"measure: {type(exc).__name__}: {exc}"
    row["png"] = str(png)
    return row


def _within(x) -> bool:
    return isinstance(x, float) and math.isfinite(x) and abs(x - 1) <= TOLERANCE


def verdict(row: dict) -> bool:
    """The issue's per-member target: size and height within 15%, better than random (where
    printed), separate elements >= 80% whole, tubes as connected as the exemplar's, colour kept;
    ridges' orientation within 10 degrees."""
    if "error" in row:
        return False
    ok = _within(row.get("size")) and _within(row.get("height"))
    if math.isfinite(row.get("vs_random", math.nan)):
        ok &= row["vs_random"] < 1
    if row.get("kind") == "elements":  # separate elements: >= 80% of the output's are whole copies
        ok &= row.get("whole", 0) >= 0.8
    if row.get("kind") == "tubes":  # tubes stay connected: no more breaks than one an exemplar's length;
        # a network (linked rings: loops) keeps its lattice's spacing. Its loops per area are printed but
        # judge nothing: the exemplar's border rings miss the partners they would link with (the linked knit
        # 14 holds 2.64 loops per unit area, the same lattice over 8 x 8 cells 3.6), and the count of rings
        # fused at near-touching crossings jumps with how the grid meets them (the same lattice at one
        # spacing over 4, 5, 6, 8 cells: 25, 41, 193, 121 loops)
        ok &= row.get("connected", 0) >= 1.0
        if math.isfinite(row.get("loops", math.nan)):
            ok &= _within(row.get("period", math.nan))
    if row.get("colour_in"):
        ok &= bool(row.get("colour_out")) and row.get("colour_hist", 0) >= 0.8
    if math.isfinite(row.get("angle_diff", math.nan)):
        ok &= row["angle_diff"] <= 10
    if math.isfinite(row.get("gaps", math.nan)):  # bumps: bare patches no wider than the truth's
        ok &= row["gaps"] <= 1 + TOLERANCE
    return bool(ok)


def contact_sheet(rows: list[dict], path: Path, width: int = 1400) -> None:
    """Each member's own picture (exemplar and result) scaled to ``width``, one per row,
    with its name and verdict above it."""
    from PIL import Image, ImageDraw

    tiles = []
    for r in rows:
        label = f"{r['member']} ({r['writer']}): " + ("OK" if verdict(r) else "MISSED") + (
            f" - {r['error']}" if "error" in r else "")
        if "png" in r and Path(r["png"]).exists():
            im = Image.open(r["png"]).convert("RGB")
            im = im.resize((width, max(1, round(im.height * width / im.width))))
        else:
            im = Image.new("RGB", (width, 60), "white")
        tile = Image.new("RGB", (width, im.height + 28), "white")
        tile.paste(im, (0, 28))
        ImageDraw.Draw(tile).text((8, 6), label[:200], fill=(0, 0, 0))
        tiles.append(tile)
    sheet = Image.new("RGB", (width, sum(t.height for t in tiles)), "white")
    y = 0
    for t in tiles:
        sheet.paste(t, (0, y))
        y += t.height
    sheet.save(path)


def _fmt(x, spec=".2f") -> str:
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return format(x, spec) if math.isfinite(x) else "-"
    return "-" if x is None else str(x)


def table(method: str, rows: list[dict]) -> list[str]:
    cols = {"volume": ["kind", "size", "height", "thickness", "whole", "spanning", "connected", "loops", "period",
                       "vs_random"],
            "pointtexture": ["size", "height", "base", "angle_diff", "vs_random"],
            "complete": ["size", "height", "base", "gaps", "angle_diff", "colour_in", "colour_out", "colour_hist"]}[method]
    lines = [f"| member | writer | {' | '.join(cols)} | time s | target met |",
             "|" + "---|" * (len(cols) + 4)]
    for r in rows:
        cells = [_fmt(r.get(c)) for c in cols] if "error" not in r else [r["error"][:80]] + [""] * (len(cols) - 1)
        lines.append(f"| {r['member']} | {r['writer']} | {' | '.join(cells)} | {r['seconds']:.1f} | "
                     f"{'yes' if verdict(r) else 'no'} |")
    met = sum(verdict(r) for r in rows)
    lines.append(f"\n{method}: target met on {met} of {len(rows)} members ({met / max(1, len(rows)):.0%}; "
                 "the issue asks for 90%).")
    return lines


def _options(parser) -> None:
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated, default every method")
    parser.add_argument("--count", type=int, default=12, help="members per method (default 12)")
    parser.add_argument("--first", type=int, default=0, help="skip the first members")
    parser.add_argument("--seed", type=int, default=0, help="the zoo's seed (default 0)")
    parser.add_argument("--timeout", type=float, default=900, help="seconds per run (default 900)")
    parser.add_argument("--folder", default="bench/out/zoo", help="inputs, outputs, pictures, logs, contact sheets")
    parser.add_argument("--measure-only", action="store_true",
                        help="measure the outputs a previous run left in --folder again (a changed measure)")


def options(argv=None):
    return parse_args(__doc__, argv, extras=_options, default_out="bench/out/zoo/zoo.md",
                      quick="3 members per method, volume at --size 64 (a smoke run)")


def main(argv=None) -> int:
    args = options(argv)
    devices = start(args)
    device = devices[0]
    count = 3 if args.quick else args.count
    folder = Path(args.folder)
    report = [f"Command: `python bench/bm_zoo.py {' '.join(argv if argv is not None else sys.argv[1:])}`; "
              f"{time.strftime('%Y-%m-%d %H:%M')}; every run on {device}, seed 1. Ratios are output / exemplar "
              f"(1 = kept; the target is within {TOLERANCE:.0%}); vs_random < 1 beats the random baseline.", ""]
    for method in args.methods.split(","):
        rows = []
        for member in zoo(method, args.first + count, args.seed)[args.first:]:
            row = run_member(member, folder, device, args.quick, args.timeout, args.measure_only)
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k not in ("command", "png")}), flush=True)
        report += [f"## {method}", ""] + table(method, rows) + [""]
        contact_sheet(rows, folder / f"{method}.png")
        report.append(f"Contact sheet: {folder / (method + '.png')}\n")
    return finish("\n".join(report), args, title="# bm_zoo: every method's defaults on the zoo (#32)")


if __name__ == "__main__":
    raise SystemExit(main())
