"""Relief and colour grown from an example over any mesh, all steps in order:
:func:`grow_relief` (issue 34; the command ``geosynth relief``)."""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from geosynth.relief.examples import ReliefExample
from geosynth.relief.quality import QualityReport

__all__ = ["METHODS", "REMESH", "ReliefResult", "grow_relief"]

METHODS = ("synth", "project")
REMESH = ("auto", "yes", "no")
# refused above 4 kB a vertex; measured: peak RSS grows ~1 kB a vertex beyond ~100 MB (the vase, synth at
# 12k-30k vertices, projection at 235k)
_BYTES_PER_VERTEX = 4096
_BYTES_PER_FINE = 1536  # an output vertex beyond the synthesis' (transfer, normals, quality): 1.49 GB at 1.19M
_FINE = 8  # an example with more than 8 cells on its period is resampled to period / 6 (M4's rule, from 12)


@dataclass
class ReliefResult:
    """What :func:`grow_relief` made.

    Attributes:
        vertices: (V, 3) float64 displaced positions; faces: (F, 3) int64 (the refined mesh's).
        colours: (V, 3) uint8 vertex colours: the example's, else the input mesh's carried over, else None.
        base: (V, 3) float64 the refined, un-displaced positions; normals: (V, 3) float64 the smoothed
            normals the relief moved along.
        heights: (V,) float64 the displacement applied (after the mask and the clearance limit).
        example: the example at the mesh's spacing.
        method: "synth" or "project".
        quality: the result's :class:`~geosynth.relief.quality.QualityReport`; baseline: the
            projection's on the same mesh (method "synth" only, else None).
        settings: the output lines saying what was chosen and why; timings: seconds per step.
        input_watertight: whether the input was closed (the output is then closed too).
    """

    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray | None
    base: np.ndarray
    normals: np.ndarray
    heights: np.ndarray
    example: ReliefExample
    method: str
    quality: QualityReport
    baseline: QualityReport | None
    settings: list[str]
    timings: dict = field(default_factory=dict)
    input_watertight: bool = False
    limited: int = 0

    def to_mesh(self):
        """The result as a ``trimesh.Trimesh`` (vertex colours when there are any)."""
        import trimesh

        mesh = trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)
        if self.colours is not None:
            rgba = np.concatenate([self.colours, np.full((len(self.colours), 1), 255, np.uint8)], 1)
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=rgba)
        return mesh

    def lines(self) -> list[str]:
        """The run's report: settings, quality beside the baseline, timings."""
        out = list(self.settings)
        out.append(f"example: amplitude {self.quality.example_amplitude:.4g}, period {self.quality.example_period:.4g} "
                   f"(relief_spectrum of its grid); per region of the surface ({len(self.quality.amplitude)} k-means "
                   f"regions, heights on each one's tangent plane):")
        out.append(self.quality.line())
        if self.baseline is not None:
            out.append(self.baseline.line())
        out.append(f"{len(self.vertices):,} vertices, {len(self.faces):,} faces; {self.limited:,} vertices' relief "
                   f"limited by the clearance to the surface ahead; input "
                   f"{'closed' if self.input_watertight else 'open'}")
        out.append("timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in self.timings.items()))
        return out


def _median_edge(v: np.ndarray, f: np.ndarray) -> float:
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return float(np.median(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)))


def _three(x: float) -> float:
    """x rounded to 3 significant digits (a chosen length prints as it is used)."""
    return float(f"{x:.3g}")


def _as_mesh(mesh):
    import trimesh

    from geosynth.geometry.meshes import load_mesh

    if isinstance(mesh, (str, os.PathLike)):
        mesh = load_mesh(mesh)
    if not isinstance(mesh, trimesh.Trimesh):
        raise TypeError(f"mesh must be a trimesh.Trimesh or a mesh file, got {type(mesh).__name__}.")
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    if len(f) == 0:
        raise ValueError("the mesh has no faces.")
    if not np.isfinite(v).all():
        raise ValueError("the mesh has vertices with NaN or inf coordinates.")
    colours = None
    if getattr(mesh.visual, "kind", None) == "vertex":
        colours = np.asarray(mesh.visual.vertex_colors)[:, :3]
    return mesh, v, f, colours


def _merged(v: np.ndarray, f: np.ndarray):
    """(vertices, faces, inverse): coincident vertices merged (an STL stores a triangle soup: unmerged,
    its triangles would part when displaced), ``inverse`` (V0,) the merged vertex of each input vertex."""
    import trimesh

    unique, inverse = trimesh.grouping.unique_rows(v)
    order = np.argsort(unique, kind="stable")  # keep the first occurrences' order: deterministic ids
    rank = np.empty(len(unique), np.int64)
    rank[order] = np.arange(len(unique))
    inv = rank[inverse]
    return v[np.sort(unique)], inv[f], inv


def _check_number(name: str, value, *, positive: bool = True) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}.") from None
    if not math.isfinite(x) or (x <= 0 if positive else x < 0):
        raise ValueError(f"{name} must be {'> 0' if positive else '>= 0'}, got {value!r}.")
    return x


def grow_relief(mesh, example, *, depth: float | None = None, scale: float = 1.0, resolution: float | None = None,
                method: str = "synth", mask=None, colour=None, field: str = "auto", seed: int = 0,
                device: str | None = None, progress: bool = True, baseline: bool = True,
                search: str = "auto", refine: int = 1, coherence: bool = True, remesh: str = "auto") -> ReliefResult:
    """Grow an example's relief (and colour) over a mesh's surface (issue 34).

    Args:
        mesh: a ``trimesh.Trimesh`` or a mesh file (noted as an input: never overwritten).
        example: a built-in name (knurl, bark, hammered, cobbles, scales, weave), a grey height image
            (white high), a captured patch file (mesh or PLY point set), or a ReliefExample
            (:func:`geosynth.relief.examples.load_example`).
        depth: the relief's height range, mesh units (>= 0; default: 1% of the mesh's size for images
            and built-ins, as captured for a patch).
        scale: multiplies the example's lateral size (> 0; an image spans a quarter of the mesh's size).
        resolution: the output mesh's longest edge, mesh units (default: 1.4 x the example's own spacing,
            at most 2x finer than the synthesis'). The synthesis runs on a coarser mesh (longest edge 1.4 x
            the example's spacing, an example with over 8 cells on its period first resampled to period / 6,
            M4's rule) and each output vertex reads the example at the places it chose
            (:mod:`geosynth.relief.transfer`); a resolution coarser than that runs the synthesis at it.
        method: "synth" (synthesis on the surface, M4's growth) or "project" (triplanar projection).
        mask: None, (V0,) or (F0,) bools over the input's vertices or faces (True: bare), or an
            (r, g, b) vertex colour of the input marking the bare parts.
        colour: an RGB image of the same size as a height-image example, or None.
        field: the tangent field, "auto", "axis" or "principal" (:mod:`geosynth.relief.orient`).
        seed: every random choice (int >= 0); the same seed gives the same bytes on every device.
        device: a device string (geosynth.devices()) or None (auto).
        progress: a progress bar on stderr.
        baseline: with method "synth", also measure the projection on the same mesh.
        search: FindMatches' search, "auto", "exhaustive" or "coherent".
        coherence: among the matches within 1.1x the best, prefer one continuing a neighbour's copy
            (:func:`geosynth.relief.synth.synthesize`; default on: the output level continues each coarse
            vertex's place, so coherent places carry the example's features whole).
        remesh: "auto" (remesh isotropically to edges of the synthesis' spacing when over 30% of the area is
            in long slivers, e.g. a trimesh cylinder's sides, or the mesh's median edge is longer than that
            spacing), "yes" or "no" (:func:`geosynth.relief.refine.isotropic_remesh`); not with a
            mask or the mesh's own colours (they are carried by the input's faces).
        refine: re-matching passes after the growth (method "synth"; 0 to 8; default 1: on the vase's
            cobbles the mortar lines ran on instead of breaking into dots, at about 2x the time).

    Returns:
        :class:`ReliefResult`.

    Raises:
        FileNotFoundError, ValueError: one-line messages (missing files, bad numbers, unknown names).
        MemoryBudgetError: the refined mesh would not fit in memory (before it is made).
    """
    from geosynth.core.memory import MemoryBudgetError, available_memory, format_bytes
    from geosynth.relief import examples as ex_mod
    from geosynth.relief.orient import tangent_frames
    from geosynth.relief.project import project
    from geosynth.relief.quality import measure
    from geosynth.relief.refine import (CLEARANCE_SHARE, SLIVER_SHARE, adjacency, bare_weights, carried_colours,
                                        clearance, estimated_faces, isotropic_remesh, refine_mesh, sliver_share,
                                        smoothed_normals, subdivide_uniform)
    from geosynth.completion.spectrum import relief_spectrum

    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}.")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}.")
    scale = _check_number("scale", scale)
    if depth is not None:
        depth = _check_number("depth", depth, positive=False)
    if resolution is not None:
        resolution = _check_number("resolution", resolution)
    if remesh not in REMESH:
        raise ValueError(f"remesh must be one of {', '.join(REMESH)}, got {remesh!r}.")
    if not isinstance(refine, (int, np.integer)) or isinstance(refine, bool) or not 0 <= refine <= 8:
        raise ValueError(f"refine must be an integer from 0 to 8, got {refine!r}.")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    tm, v0, f0, in_colours = _as_mesh(mesh)
    size = float((v0.max(0) - v0.min(0)).max())
    ex = ex_mod.load_example(example, size=size, depth=depth, colour=colour, seed=int(seed)).scaled(scale)
    spec = relief_spectrum(ex.heights, ex.spacing)
    spacing, why = ex.spacing, "the example's own spacing"
    if math.isfinite(spec.period) and spec.period / ex.spacing > _FINE:
        spacing, why = _three(spec.period / 6), f"period {spec.period:.4g} / 6 (the example has " \
                                                f"{spec.period / ex.spacing:.0f} cells on its period)"
    coarse = _three(1.4 * spacing)  # the synthesis' level: about `spacing` between vertices
    c_why = f"1.4 x spacing {spacing:.4g}, {why}"
    if resolution is None:
        # the output: the example's own resolution (its features whole), at most 2x finer than the synthesis
        resolution = _three(max(1.4 * ex.spacing, coarse / 2))
        r_why = "1.4 x the example's own spacing" if 1.4 * ex.spacing >= coarse / 2 else "the synthesis' / 2"
        if resolution >= coarse:
            resolution, r_why = coarse, c_why
    else:
        r_why = "given"
    if method != "synth" or resolution >= coarse:
        coarse = resolution  # one level: the output is the synthesis' mesh (or the projection's)
    area = float(tm.area)
    n_est = estimated_faces(area, resolution) // 2 + len(v0)
    n_coarse = estimated_faces(area, coarse) // 2 + len(v0)
    two = resolution < coarse * 0.999  # two levels: the synthesis' mesh, then the output's
    need = n_coarse * _BYTES_PER_VERTEX + (n_est * _BYTES_PER_FINE if two else 0)
    avail = available_memory()
    if need > avail:
        fits = resolution * math.sqrt(need / avail)
        raise MemoryBudgetError(f"the refined mesh (about {n_est:,} vertices at resolution {resolution:.4g}) needs "
                                f"about {format_bytes(need)}, more than the {format_bytes(avail)} available; raise "
                                f"--resolution to at least {_three(fits * 1.01):.4g} or use a larger --scale.",
                                option="resolution", largest=None, estimate=need, available=avail)
    v0, f0, inverse = _merged(v0, f0)
    if len(v0) < len(inverse):
        if in_colours is not None:
            first = np.zeros(len(v0), np.int64)
            first[inverse[::-1]] = np.arange(len(inverse))[::-1]
            in_colours = in_colours[first]
        m = None if mask is None else np.asarray(mask)
        if m is not None and m.dtype == bool and m.shape == (len(inverse),) and len(inverse) != len(f0):
            merged_mask = np.zeros(len(v0), bool)
            np.logical_or.at(merged_mask, inverse, m)
            mask = merged_mask
    import trimesh

    watertight = bool(trimesh.Trimesh(v0, f0, process=False, validate=False).is_watertight)
    timings["load"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    remesh_note, remeshed = None, False
    share = sliver_share(v0, f0, coarse)
    # "auto": slivers, or a mesh coarser than the synthesis' spacing (bisection would refine it anyway, into
    # rows of edges between half and all of the resolution, longer one way than the other: on the knot the
    # cobbles' flat tops ran on along the tube; remeshed, every edge is about the spacing); a mesh finer than
    # that is kept (remeshing would smooth away its own detail)
    coarser = _median_edge(v0, f0) > coarse / 1.4
    if remesh == "yes" or (remesh == "auto" and (share > SLIVER_SHARE or coarser)):
        if mask is not None or in_colours is not None:
            remesh_note = (f"not remeshed ({100 * share:.0f}% of the area in slivers): a mask or the mesh's own "
                           f"colours are carried by the input's faces")
        else:
            u, g = isotropic_remesh(v0, f0, coarse / 1.4)
            closed = bool(trimesh.Trimesh(u, g, process=False, validate=False).is_watertight)
            if closed or not watertight:
                remesh_note = (f"remeshed isotropically ({100 * share:.0f}% of the area in slivers, median edge "
                               f"{_median_edge(v0, f0):.4g}; edges about "
                               f"{coarse / 1.4:.4g}, Botsch-Kobbelt): {len(v0):,} -> {len(u):,} vertices")
                v0, f0, remeshed = u, g, True
            else:
                remesh_note = "not remeshed: the remesher's output was not closed (the input is)"
    vc, fc, src_c = refine_mesh(v0, f0, coarse)
    adj_c = adjacency(fc, len(vc))
    normals_c = smoothed_normals(vc, fc, adj_c, rings=2)
    med_c = _median_edge(vc, fc)
    timings["refine"] = time.perf_counter() - t0
    settings = [f"example: {ex.note}; x{scale:g}; {ex.shape[1]} x {ex.shape[0]} cells of {ex.spacing:.4g}",
                f"mesh: {len(v0):,} vertices -> {len(vc):,} at resolution {coarse:.4g} ({c_why if two else r_why}), "
                f"median edge {med_c:.4g}; normals smoothed over 2 rings"]
    if remesh_note:
        settings.append(remesh_note)

    t0 = time.perf_counter()
    source = None
    ex_c = ex.resampled(med_c)
    if method == "synth":
        from geosynth.relief.synth import WINDOW, synthesize

        frames, how, rotations = tangent_frames(vc, normals_c, adj_c, field)
        res = synthesize(ex_c, vc, fc, adj_c, normals_c, frames, rotations, seed=int(seed), device=device,
                         search=search, progress=progress, refine=int(refine), coherence=bool(coherence))
        heights, colours, source = res.heights, res.colours, res.source
        st = res.stats
        settings.append(f"synthesis on {len(vc):,} vertices ({ex_c.shape[1]} x {ex_c.shape[0]} cells of "
                        f"{ex_c.spacing:.4g}): M4's growth, window {WINDOW} rings, R {rotations}, {st['search']} "
                        f"search, {st['seeds']} seed(s), {st['lists']} boundary lists, {refine} refinement pass(es) "
                        f"({st['refined']:,} vertices changed), {st['launches']} launches, "
                        f"{st['unreached']} unreached; device {device or 'auto'}, seed {seed}")
        settings.append(how)
    else:
        heights, colours = project(ex, vc, normals_c)
        settings.append("projection: triplanar, weights |n|^4 (the baseline)")
    timings[method] = time.perf_counter() - t0

    if two:  # the output level: the synthesis' places carried to a finer mesh
        from geosynth.relief.transfer import barycentric, transfer, vertex_faces

        t0 = time.perf_counter()
        # the remeshed synthesis' mesh is even: every face cut k x k (fast, regular); else bisection
        v, f, src_f = (subdivide_uniform if remeshed else refine_mesh)(vc, fc, resolution)
        src = src_c[src_f]
        vface = vertex_faces(f, src_f, len(v))
        corner = fc[vface]
        bary = barycentric(v, vc[corner[:, 0]], vc[corner[:, 1]], vc[corner[:, 2]])
        normals = np.einsum("vk,vkj->vj", bary, normals_c[corner])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        heights, colours, where = transfer(ex, vc, fc, frames, res.place, res.rotation, rotations, ex_c.spacing, v,
                                           vface)
        h_, w_ = ex.shape
        col_i, row_i = np.rint(where[:, 0]).astype(np.int64), np.rint(where[:, 1]).astype(np.int64)
        source = (row_i % h_) * w_ + (col_i % w_) if ex.periodic else \
            np.clip(row_i, 0, h_ - 1) * w_ + np.clip(col_i, 0, w_ - 1)
        med = _median_edge(v, f)
        ex_q = ex
        timings["transfer"] = time.perf_counter() - t0
        settings.append(f"output: {len(vc):,} -> {len(v):,} vertices at resolution {resolution:.4g} ({r_why}; "
                        f"{'each face cut evenly' if remeshed else 'bisection'}), "
                        f"median edge {med:.4g}; each reads the example at its coarse face's corners' places, "
                        f"blended (squared barycentric weights)")
    else:
        v, f, src, normals, med, ex_q, bary, corner = vc, fc, src_c, normals_c, med_c, ex_c, None, None
    if colours is None and in_colours is not None:  # the example has none: the mesh keeps its own
        colours = carried_colours(v0, f0, in_colours, v, f, src)
    weights = bare_weights(mask, f0, len(v0), in_colours, f, src, len(v))

    t0 = time.perf_counter()
    raw = heights * weights
    reach = max(ex.depth, 1e-12)
    limit_c = CLEARANCE_SHARE * clearance(vc, normals_c, reach, coarse)
    if bary is None:
        limit = limit_c
    else:  # the smallest clearance of the corners that weigh (continuous along the coarse edges)
        limit = np.where(bary > 1e-9, limit_c[corner], np.inf).min(1)
    applied = np.minimum(raw, limit)
    limited = int((applied < raw - 1e-12 * reach).sum())
    out_v = v + applied[:, None] * normals
    timings["displace"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    active = weights > 0
    quality = measure(method, ex_q, v, normals, raw, med, f, source, seed=int(seed), active=active)
    base_q = None
    if method == "synth" and baseline:
        hp, _ = project(ex, v, normals)
        base_q = measure("project", ex_q, v, normals, hp * weights, med, f, None, seed=int(seed), active=active)
    timings["quality"] = time.perf_counter() - t0
    return ReliefResult(out_v, f, colours, v, normals, applied, ex_q, method, quality, base_q, settings, timings,
                        watertight, limited)
