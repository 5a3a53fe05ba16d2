"""How close is a synthesized field to its exemplar, and does it keep the exemplar's
structure? Implements no paper section: our quality numbers for Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 6 (results).

Quality numbers: how close a synthesized field is to the exemplar.

- :func:`bidirectional_block_distance`: neighbourhood likeness (mean nearest-block
  SSD, both ways) on the uint8 codes.
- Structure metrics, which see what a person sees:

  * :func:`element_wholeness` for exemplars made of separate pieces (rings, balls):
    the share of the output's solid that sits in whole pieces;
  * :func:`surface_structure` for one-surface exemplars (terrain, slabs): debris,
    slopes and overhangs;
  * :func:`structure_report` picks one of the two (or is told which), and
    :func:`format_structure` writes the result as one line.

Inputs of the structure metrics are signed distance fields, negative inside: a
:class:`~geosynth.geometry.field.Field` (its spacing is used) or a (Z, Y, X) float array with a
``spacing``. Fields rather than meshes because the synthesis has both sides as fields
(``GeometryResult.exemplar_field`` and ``GeometryResult.volume.field``), elements and
overhangs are defined on samples, and the mesh needed for area-weighted slopes and
debris is made here the same way for both sides (marching cubes without smoothing,
:func:`geosynth.geometry.surface.field_to_mesh`), so neither side is favoured by its meshing.
"""

from __future__ import annotations

import gc
from dataclasses import dataclass

import numpy as np

from geosynth.geometry.field import Field

__all__ = [
    "ELEMENT_VOLUME_TOLERANCE", "SLOPE_W1_SCALE", "ExemplarStructure", "bidirectional_block_distance",
    "element_wholeness", "exemplar_structure", "format_structure", "pick_refinement", "structure_kind",
    "structure_report", "surface_structure",
]

ELEMENT_VOLUME_TOLERANCE = 0.35  # an output core is whole when its volume is within 35% of an exemplar core's
SLOPE_W1_SCALE = 0.25  # slopes score = 1 - W1 / 0.25, clipped to [0, 1]
ELEMENTS_LARGEST_SHARE = 0.9  # auto kind: "elements" when the largest exemplar core holds less than this
MAX_REFINEMENT = 4
MAX_REFINED_SAMPLES = 2**25  # per field; caps the refinement of large fields (32 Mi samples, 128 MiB float32)
# Peak bytes per refined sample while cores are labelled (the float64 zoom, its float32
# copy, the core mask and the int32 labels): the refinement also stays within the memory
# available (geosynth.core.memory), so the quality numbers never refuse a run that fits.
REFINED_SAMPLE_BYTES = 32


def _refined_sample_cap() -> int:
    from geosynth.core.memory import available_memory

    return int(min(MAX_REFINED_SAMPLES, available_memory() // (2 * REFINED_SAMPLE_BYTES)))


def bidirectional_block_distance(
    exemplar: np.ndarray,
    output: np.ndarray,
    block,
    *,
    samples: int = 200,
    seed: int | None = 0,
    device: str | None = None,
) -> dict:
    """Mean nearest-block distance between two uint8 volumes, both ways.

    For ``samples`` random blocks of the output, the exact nearest block of the
    exemplar; for ``samples`` random blocks of the exemplar, the exact nearest block of
    the output; distances are SSD / block samples (squared uint8 units per sample).

    Args:
        exemplar, output: (Z, Y, X) uint8 volumes, each at least ``block`` per side.
        block: block size N, or a slab's block (bz, by, bx).
        samples: blocks drawn from each side (all of them when fewer exist).
        seed: seed of the Generator that draws them.
        device: device of the gather kernel.

    Returns:
        {"output_to_exemplar": float, "exemplar_to_output": float, "mean": float}.
    """
    from geosynth.volume.blocks import block_shape
    from geosynth.volume.cascade import CascadeSearch

    bz, by, bx = sides = block_shape(block)
    for name, v in (("exemplar", exemplar), ("output", output)):
        if v.dtype != np.uint8 or v.ndim != 3 or any(n < b for n, b in zip(v.shape, sides)):
            raise ValueError(f"{name} must be a uint8 (Z, Y, X) volume of at least {block} per side, got {v.dtype} {v.shape}.")
    rng = np.random.default_rng(seed)

    def one_way(queries_from: np.ndarray, search_in: np.ndarray) -> float:
        counts = [s - b + 1 for s, b in zip(queries_from.shape, sides)]
        total = int(np.prod(counts))
        picks = rng.choice(total, size=min(samples, total), replace=False)
        search = CascadeSearch(search_in, block, device=device)  # exact nearest block
        dists = []
        for idx in picks:
            z, y, x = np.unravel_index(idx, counts)
            _, ssd = search.nearest(queries_from[z:z + bz, y:y + by, x:x + bx])
            dists.append(ssd / (bz * by * bx))
        return float(np.mean(dists))

    a = one_way(output, exemplar)
    b = one_way(exemplar, output)
    return {"output_to_exemplar": a, "exemplar_to_output": b, "mean": (a + b) / 2}


# ------------------------------------------------------------------ inputs


def _distance(name: str, value, spacing) -> tuple[np.ndarray, np.ndarray]:
    """(Z, Y, X) float32 distances and (x, y, z) float64 spacing from a Field or an array."""
    if isinstance(value, Field):
        values, sp = value.values, value.spacing
    else:
        values = np.asarray(value)
        sp = np.asarray(spacing, np.float64)
        sp = np.full(3, float(sp)) if sp.ndim == 0 else sp
        if sp.shape != (3,) or not np.isfinite(sp).all() or (sp <= 0).any():
            raise ValueError(f"spacing must be a number > 0 or three of them (x, y, z), got {spacing!r}.")
    if values.ndim != 3 or min(values.shape) < 2:
        raise ValueError(f"{name} must be a scalar (Z, Y, X) distance field with at least 2 samples per axis, "
                         f"got shape {values.shape}.")
    if not np.issubdtype(values.dtype, np.floating):
        raise TypeError(f"{name} must hold float signed distances (negative inside), got {values.dtype}; "
                        "dequantize uint8 codes first (geosynth.volume.synthesis.dequantize_field).")
    values = np.asarray(values, np.float32)
    if not np.isfinite(values).all():
        raise ValueError(f"{name} has {int((~np.isfinite(values)).sum())} NaN or infinite values; "
                         "the structure metrics need a distance at every sample.")
    return values, np.asarray(sp, np.float64)


def _periodic_axes(periodic) -> tuple[bool, bool, bool]:
    """Per (Z, Y, X) axis: does the output wrap around?"""
    if isinstance(periodic, (bool, np.bool_)):
        return (bool(periodic),) * 3
    p = tuple(bool(v) for v in periodic)
    if len(p) != 3:
        raise ValueError(f"periodic must be a bool or three of them (z, y, x), got {periodic!r}.")
    return p


# ------------------------------------------------------------------ elements


def _refine(values: np.ndarray, factor: int, periodic=(False, False, False)) -> np.ndarray:
    """Trilinear resampling by an integer factor: coarse sample k lands on fine sample factor * k.

    A non-periodic axis of n samples becomes (n - 1) * factor + 1; a periodic one
    becomes n * factor (its last cell, from sample n - 1 back to sample 0, is filled too).
    """
    from scipy import ndimage

    if factor == 1:
        return values
    pad = [(0, 1) if p else (0, 0) for p in periodic]
    v = np.pad(values, pad, mode="wrap") if any(periodic) else values
    out_shape = [(n - 1) * factor + 1 for n in v.shape]
    fine = ndimage.zoom(v, [o / n for o, n in zip(out_shape, v.shape)], order=1, mode="nearest", grid_mode=False)
    if fine.shape != tuple(out_shape):  # zoom rounds the shape from the factors; it must give the exact one
        raise RuntimeError(f"resampling gave shape {fine.shape}, expected {tuple(out_shape)}.")
    if any(periodic):
        fine = fine[tuple(slice(0, n * factor) if p else slice(None) for n, p in zip(values.shape, periodic))]
    return fine


class _Cores:
    """The 6-connected cores of a mask: volumes, which are cut by the box, Euler numbers on demand.

    Along a periodic axis the mask is padded by ``margin`` samples of its own wrap on
    both sides and labelled there: each piece then appears whole at least once; the
    copy whose first sample lies in the original box is kept, and a piece reaching the
    padded faces (longer than the margin, or wrapping onto itself) counts as cut; one
    that spans the padded box (wraps onto itself) is kept once, as cut.
    """

    def __init__(self, mask: np.ndarray, periodic=(False, False, False), margin=(0, 0, 0)):
        from scipy import ndimage

        margin = [int(min(m, n)) if p else 0 for m, n, p in zip(margin, mask.shape, periodic)]
        if any(margin):
            mask = np.pad(mask, [(m, m) for m in margin], mode="wrap")
        labels, count = ndimage.label(mask)  # default structure: 6-connectivity in 3D
        self.labels = labels
        counts = np.bincount(labels.ravel(), minlength=count + 1)[1:]
        self.slices = ndimage.find_objects(labels)
        cut = np.zeros(count, bool)
        for axis in range(3):  # every face of the (padded) box
            for face in (0, -1):
                hit = np.unique(np.take(labels, face, axis=axis))
                cut[hit[hit > 0] - 1] = True
        keep = np.ones(count, bool)
        for axis, m in enumerate(margin):
            if m:  # one copy of each piece: the one that starts inside the original box
                start = np.array([s[axis].start for s in self.slices], np.int64)
                stop = np.array([s[axis].stop for s in self.slices], np.int64)
                spans = (start == 0) & (stop == mask.shape[axis])  # wraps onto itself: one label, kept (as cut)
                keep &= ((start >= m) & (start < mask.shape[axis] - m)) | spans
        self.index = np.flatnonzero(keep)  # label - 1 of the cores kept
        self.counts = counts[self.index]
        self.cut = cut[self.index]
        self.extent = np.array([[s.stop - s.start for s in self.slices[i]] for i in self.index], np.int64).reshape(-1, 3)

    def __len__(self) -> int:
        return len(self.index)

    def euler(self, k: int) -> int:
        """Euler number of core k (6-connected foreground, 26-connected background)."""
        from skimage.measure import euler_number

        i = self.index[k]
        crop = np.pad(self.labels[self.slices[i]] == i + 1, 1)
        return int(euler_number(crop, connectivity=1))


def _exemplar_cores(values: np.ndarray, threshold: float, factor: int) -> _Cores:
    return _Cores(_refine(values, factor) < -threshold)


def _signature(cores: _Cores) -> tuple:
    """What the refinement must keep stable: the cores and their Euler numbers."""
    return len(cores), tuple(sorted(cores.euler(k) for k in range(len(cores))))


def pick_refinement(values: np.ndarray, threshold: float, *, max_factor: int = MAX_REFINEMENT,
                    max_samples: int = MAX_REFINED_SAMPLES) -> int:
    """The grid fineness of the elements metric: an integer refinement of the exemplar's grid.

    The rule: label the cores (samples with distance < -``threshold``) at factors
    1, 2, 3, ... (trilinear resampling, coarse sample k on fine sample factor * k) and
    stop at the first factor whose cores -- their number and their Euler numbers --
    are the same as at the next factor: refining further no longer joins fragments of a
    thin piece (a wire whose core is under a sample thick breaks into bits on a coarse
    grid) nor closes broken rings, so the cores come out one per piece. The threshold
    is a distance in world units and does not shrink with the factor, so refining does
    not join pieces that the coarse grid kept apart. Stops at ``max_factor``, or at the
    last factor whose grid has at most ``max_samples`` samples.

    Args:
        values: (Z, Y, X) float32 exemplar distances (world units, negative inside).
        threshold: the core depth, world units, > 0.
        max_factor: the largest factor tried, >= 1.
        max_samples: the largest refined grid, in samples.

    Returns:
        The factor, an int in [1, max_factor].
    """
    return _refinement_and_cores(values, threshold, max_factor, max_samples)[0]


def _refinement_and_cores(values: np.ndarray, threshold: float, max_factor: int = MAX_REFINEMENT,
                          max_samples: int = MAX_REFINED_SAMPLES) -> tuple[int, _Cores]:
    """:func:`pick_refinement`'s factor and the exemplar's cores at that factor (labelled on the way)."""
    def fits(f: int) -> bool:
        return int(np.prod([(n - 1) * f + 1 for n in values.shape])) <= max_samples

    factor = 1
    cores = _exemplar_cores(values, threshold, 1)
    previous = _signature(cores)
    while factor < max_factor and fits(factor + 1):
        finer = _exemplar_cores(values, threshold, factor + 1)
        current = _signature(finer)
        if current == previous:
            return factor, cores
        factor, previous, cores = factor + 1, current, finer
    return factor, cores


def _element_scores(ex_values, ex_spacing, out_values, out_spacing, periodic, factor=None, ex_cores=None) -> dict:
    h = float(ex_spacing.max())
    threshold = 0.5 * h  # half a sample of the exemplar's grid, in world units
    if factor is None:
        factor = pick_refinement(ex_values, threshold, max_samples=_refined_sample_cap())
    picked = factor

    def out_factor_of(f: int) -> int:
        return max(1, int(round(f * float(out_spacing.max()) / h)))

    cap = _refined_sample_cap()
    while factor > 1 and np.prod([(n - 1) * out_factor_of(factor) + 1 for n in out_values.shape]) > cap:
        factor -= 1  # the output is too large for that grid: both sides go coarser together
    if ex_cores is None or factor != picked:
        ex_cores = _exemplar_cores(ex_values, threshold, factor)
    ex_cell = float(np.prod(ex_spacing)) / factor**3
    ex_volume = ex_cores.counts * ex_cell
    ex_euler = np.array([ex_cores.euler(k) if not ex_cores.cut[k] else 0 for k in range(len(ex_cores))], np.int64)
    reference = ~ex_cores.cut

    out_factor = out_factor_of(factor)
    per = _periodic_axes(periodic)
    fine_spacing = out_spacing / out_factor
    # a margin that holds the longest exemplar core, in the output's fine samples
    longest = ex_cores.extent.max(0)[::-1] if len(ex_cores) else np.zeros(3)
    margin_zyx = np.ceil(longest * (ex_spacing / factor) / fine_spacing)[::-1].astype(int) + 2
    out_cores = _Cores(_refine(out_values, out_factor, per) < -threshold, per, margin_zyx)
    volume = out_cores.counts * float(np.prod(fine_spacing))

    result = {"score": float("nan"), "exemplar_cores": len(ex_cores), "reference_cores": int(reference.sum()),
              "output_cores": len(out_cores), "whole_cores": 0, "cut_left_out": 0, "merged_cut": 0,
              "factor": int(factor), "threshold": threshold}
    notes = []
    if factor != picked:
        notes.append(f"the output is too large for the refinement the exemplar needs ({picked}); "
                     f"refined by {factor} only, so thin pieces may come out broken")
    # a cut core larger than any exemplar piece could be is a merge, not a piece cut short: it counts, as not whole
    largest = float(ex_volume.max()) * (1 + ELEMENT_VOLUME_TOLERANCE) if len(ex_cores) else 0.0
    merged = out_cores.cut & (volume > largest)
    counted = ~out_cores.cut | merged
    result["cut_left_out"] = int((out_cores.cut & ~merged).sum())
    result["merged_cut"] = int(merged.sum())
    if not len(ex_cores):
        notes.append("the exemplar has no core (no sample half a sample inside): no piece to compare with")
    elif not reference.any():
        notes.append("every exemplar core is cut by the exemplar's box: no whole piece to compare with")
    if notes:
        result["note"] = "; ".join(notes)
    if not reference.any():
        return result
    ref_volume, ref_euler = ex_volume[reference], ex_euler[reference]
    whole = np.zeros(len(out_cores), bool)
    for k in np.flatnonzero(~out_cores.cut):
        near = np.abs(volume[k] - ref_volume) <= ELEMENT_VOLUME_TOLERANCE * ref_volume
        if near.any():  # Euler numbers only for the cores whose volume already fits
            whole[k] = bool(np.isin(out_cores.euler(k), ref_euler[near]))
    total = float(volume[counted].sum())
    result["whole_cores"] = int(whole.sum())
    result["score"] = float(volume[whole].sum() / total) if total > 0 else 0.0
    return result


def element_wholeness(exemplar_distance, output_distance, spacing=1.0, *, periodic=False) -> dict:
    """Share of the output's solid that sits in whole pieces of the exemplar's kind.

    The solid's cores are the samples more than half a sample (of the exemplar's
    grid, its largest spacing; a world distance, the same for both sides) inside,
    labelled 6-connected on a grid refined by the factor of :func:`pick_refinement`, so
    that the exemplar's cores come out one per piece. A core cut by its box (touching
    a face) is incomplete: cut exemplar cores are left out of the reference set, cut
    output cores are left out of the score, except a cut core larger than 1.35 times
    the largest exemplar core, which can only be pieces merged together (it counts, as
    not whole). An output core is whole when its Euler number matches that of an
    exemplar reference core whose volume is within 35% of its own.

    Args:
        exemplar_distance, output_distance: signed distances, negative inside: each a
            :class:`~geosynth.geometry.field.Field` (its spacing is used) or a (Z, Y, X) float
            array in world units of ``spacing`` (1.0: units of samples).
        spacing: sample spacing of array inputs, a number or (x, y, z), > 0.
        periodic: the output wraps around (a tileable synthesis): a bool or one per
            (z, y, x) axis; a piece crossing a periodic face is then whole, not cut.

    Returns:
        dict: ``score`` (float in [0, 1]: output core volume in whole cores / output
        core volume counted; 1 = every piece whole; 0 when no output core counts; NaN
        when the exemplar has no uncut core, with a ``note``), ``exemplar_cores``, ``reference_cores`` (the uncut
        ones), ``output_cores``, ``whole_cores``, ``cut_left_out``, ``merged_cut``
        (ints), ``factor`` (the refinement, int), ``threshold`` (the core depth,
        world units) and, when something limits the result, a ``note`` (str). The
        refinement is lowered for both sides when the refined output would exceed
        ``MAX_REFINED_SAMPLES`` samples (the note says so).

    Raises:
        ValueError, TypeError: a field that is not (Z, Y, X) float with at least 2
            samples per axis, NaN values, a bad spacing or periodic.
    """
    ex, ex_sp = _distance("exemplar_distance", exemplar_distance, spacing)
    out, out_sp = _distance("output_distance", output_distance, spacing)
    return _element_scores(ex, ex_sp, out, out_sp, periodic)


# ------------------------------------------------------------------ one surface


def _surface(values: np.ndarray, spacing: np.ndarray, up_axis: int) -> dict:
    """Up components, areas and component labels of the faces of a field's zero surface.

    Marching cubes with the box closed (so a slab's top and bottom are one piece
    through the caps at the box's sides); the cap faces lie outside the samples and are
    left out of every area.
    """
    import trimesh

    from geosynth.geometry.surface import field_to_mesh

    mesh = field_to_mesh(Field(values, np.zeros(3), spacing), level=0.0, close=True)
    centre = mesh.triangles_center / spacing  # fractional (x, y, z) sample indices
    last = np.array(values.shape[::-1], np.float64) - 1
    real = ((centre >= 0) & (centre <= last)).all(1)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    area = np.where(real, mesh.area_faces, 0.0)
    out = {"up": mesh.face_normals[real, 2 - up_axis], "area": area[real],
           "component_area": np.bincount(labels, weights=area)}
    # a Trimesh and its caches form reference cycles: free them now, not at the next
    # collection, so the output's mesh does not come on top of the exemplar's
    del mesh, centre, labels
    gc.collect()
    return out


def _debris(surface: dict) -> float:
    comp = surface["component_area"]
    total = float(comp.sum())
    return float(1 - comp.max() / total) if total > 0 else 0.0


def _crossings(values: np.ndarray, up_axis: int) -> np.ndarray:
    inside = values < 0
    return np.count_nonzero(np.diff(inside, axis=up_axis), axis=up_axis)


def _surface_scores(ex, ex_sp, out, out_sp, up_axis) -> dict:
    from scipy.stats import wasserstein_distance

    sides = {}
    for name, v, sp in (("exemplar", ex, ex_sp), ("output", out, out_sp)):
        try:
            sides[name] = _surface(v, sp, up_axis)
        except ValueError as err:  # field_to_mesh: no surface
            raise ValueError(f"{name}: {err}") from None
    w1 = float(wasserstein_distance(sides["exemplar"]["up"], sides["output"]["up"],
                                    sides["exemplar"]["area"], sides["output"]["area"]))
    ex_count, out_count = _crossings(ex, up_axis), _crossings(out, up_axis)
    usual = int(np.bincount(ex_count.ravel()).argmax())
    return {
        "debris": {"exemplar": _debris(sides["exemplar"]), "output": _debris(sides["output"])},
        "pieces": {"exemplar": int((sides["exemplar"]["component_area"] > 0).sum()),
                   "output": int((sides["output"]["component_area"] > 0).sum())},
        "slopes": {"w1": w1, "score": float(np.clip(1 - w1 / SLOPE_W1_SCALE, 0, 1))},
        "overhangs": {"usual_count": usual, "exemplar": float(np.mean(ex_count > usual)),
                      "output": float(np.mean(out_count > usual))},
    }


def surface_structure(exemplar, output, up_axis: int = 0, spacing=1.0) -> dict:
    """Debris, slopes and overhangs of a one-surface output (terrain, slabs) against its exemplar.

    Both zero surfaces are meshed the same way (marching cubes, no smoothing, the box
    closed and its caps left out of the areas). Every other face counts, a slab's flat
    bottom too; the box is never taken as periodic.

    - debris: the share of surface area outside the largest connected piece of the
      surface (mesh components by shared edges, ``trimesh.graph``); 0 for one piece.
    - slopes: W1 (``scipy.stats.wasserstein_distance``) between the area-weighted
      distributions of the face normal's up component, exemplar vs output, in [0, 2];
      its score is ``1 - W1 / 0.25`` clipped to [0, 1]. A surface whose share ``s`` of
      area turned from flat to vertical is at W1 = s.
    - overhangs: along the up axis each column of samples crosses the surface some
      number of times (sign changes of the distance); the exemplar's usual count is its
      most common one, and the overhang share of a field is the share of its columns
      that cross more often than that. Reported for both, so that the output's share
      can be compared with the exemplar's.

    Args:
        exemplar, output: signed distances, negative inside: each a
            :class:`~geosynth.geometry.field.Field` or a (Z, Y, X) float array in units of
            ``spacing``.
        up_axis: the array axis that points up (0: Z, the built-in exemplars' up).
        spacing: sample spacing of array inputs, a number or (x, y, z), > 0.

    Returns:
        dict: ``debris`` {"exemplar", "output"} (floats in [0, 1]), ``pieces``
        {"exemplar", "output"} (surface components, ints), ``slopes`` {"w1", "score"}
        (floats), ``overhangs`` {"usual_count": int, "exemplar", "output"} (shares of
        columns in [0, 1]).

    Raises:
        ValueError, TypeError: bad fields (see :func:`element_wholeness`), an up_axis
            not in 0..2, a field with no surface (all inside or all outside).
    """
    if up_axis not in (0, 1, 2):
        raise ValueError(f"up_axis must be 0, 1 or 2 (an axis of the (Z, Y, X) array), got {up_axis!r}.")
    ex, ex_sp = _distance("exemplar", exemplar, spacing)
    out, out_sp = _distance("output", output, spacing)
    return _surface_scores(ex, ex_sp, out, out_sp, up_axis)


# ------------------------------------------------------------------ both


@dataclass(frozen=True)
class ExemplarStructure:
    """What the structure metrics need of an exemplar, worked out once
    (:func:`exemplar_structure`): pass it to :func:`structure_report` in place of the
    exemplar's field to score several outputs against one exemplar.

    Attributes:
        values: (Z, Y, X) float32 distances, world units, negative inside.
        spacing: (x, y, z) float64 sample spacing.
        threshold: the core depth, world units (half the largest spacing).
        factor: :func:`pick_refinement`'s grid refinement.
        kind: "elements" or "surface" (:func:`structure_kind`'s rule).
    """

    values: np.ndarray
    spacing: np.ndarray
    threshold: float
    factor: int
    cores: "_Cores"

    @property
    def kind(self) -> str:
        return _kind_of(self.cores)


def exemplar_structure(exemplar_field, *, spacing=1.0) -> ExemplarStructure:
    """The exemplar's cores on the grid of :func:`pick_refinement`, labelled once.

    Args:
        exemplar_field: signed distances, negative inside (a Field, or an array with
            ``spacing``).
    """
    ex, ex_sp = _distance("exemplar_field", exemplar_field, spacing)
    threshold = 0.5 * float(ex_sp.max())
    factor, cores = _refinement_and_cores(ex, threshold)
    return ExemplarStructure(ex, ex_sp, threshold, factor, cores)


def structure_kind(exemplar_field, *, spacing=1.0) -> str:
    """Which structure metrics fit an exemplar: "elements" when its cores (on the grid of
    :func:`pick_refinement`) number more than one and the largest holds less than 90% of
    their volume (separate pieces: rings, balls), else "surface" (terrain, slabs).

    Args:
        exemplar_field: signed distances, negative inside (a Field, or an array with
            ``spacing``), or an :class:`ExemplarStructure`.
    """
    if isinstance(exemplar_field, ExemplarStructure):
        return exemplar_field.kind
    return exemplar_structure(exemplar_field, spacing=spacing).kind


def _kind_of(cores: _Cores) -> str:
    many = len(cores) > 1 and cores.counts.max() < ELEMENTS_LARGEST_SHARE * cores.counts.sum()
    return "elements" if many else "surface"


def structure_report(exemplar_field, output_field, kind: str = "auto", *, spacing=1.0, up_axis: int = 0,
                     periodic=False) -> dict:
    """The structure metrics that fit the exemplar, for printing beside the block distance.

    Args:
        exemplar_field, output_field: signed distances, negative inside (Fields, or
            arrays with ``spacing``), e.g. ``GeometryResult.exemplar_field`` and
            ``GeometryResult.volume.field``; the exemplar also as an
            :class:`ExemplarStructure` (its cores labelled once for many outputs).
        kind: "elements" (:func:`element_wholeness`), "surface"
            (:func:`surface_structure`) or "auto": :func:`structure_kind`.
        spacing: sample spacing of array inputs.
        up_axis: the up axis for "surface".
        periodic: the output wraps around, for "elements".

    Returns:
        {"kind": "elements" or "surface", "elements" or "surface": the metric's dict}.
    """
    if kind not in ("auto", "elements", "surface"):
        raise ValueError(f"kind must be 'auto', 'elements' or 'surface', got {kind!r}.")
    out, out_sp = _distance("output_field", output_field, spacing)
    factor = cores = None
    if isinstance(exemplar_field, ExemplarStructure):
        ex, ex_sp, factor, cores = (exemplar_field.values, exemplar_field.spacing, exemplar_field.factor,
                                    exemplar_field.cores)
    elif kind != "surface":
        structure = exemplar_structure(exemplar_field, spacing=spacing)
        ex, ex_sp, factor, cores = structure.values, structure.spacing, structure.factor, structure.cores
    else:
        ex, ex_sp = _distance("exemplar_field", exemplar_field, spacing)
    if kind == "auto":
        kind = _kind_of(cores)
    if kind == "elements":
        return {"kind": kind, "elements": _element_scores(ex, ex_sp, out, out_sp, periodic, factor, cores)}
    if up_axis not in (0, 1, 2):
        raise ValueError(f"up_axis must be 0, 1 or 2 (an axis of the (Z, Y, X) array), got {up_axis!r}.")
    return {"kind": kind, "surface": _surface_scores(ex, ex_sp, out, out_sp, up_axis)}


def format_structure(report: dict) -> str:
    """One line for a :func:`structure_report` result (shares in percent)."""
    if report["kind"] == "elements":
        e = report["elements"]
        score = "n/a" if np.isnan(e["score"]) else f"{e['score']:.2f}"
        return (f"elements {score} ({e['whole_cores']} of {e['output_cores']} cores whole, "
                f"{e['cut_left_out']} cut by the box left out, {e['merged_cut']} merged; "
                f"exemplar {e['exemplar_cores']} cores, {e['reference_cores']} uncut)")
    s = report["surface"]
    n = s["pieces"]["output"]
    return (f"debris {100 * s['debris']['output']:.1f}% in {n} piece{'' if n == 1 else 's'} "
            f"(exemplar {100 * s['debris']['exemplar']:.1f}% in {s['pieces']['exemplar']}), "
            f"slopes {s['slopes']['score']:.2f} (W1 {s['slopes']['w1']:.3f}), "
            f"overhangs {100 * s['overhangs']['output']:.1f}% (exemplar {100 * s['overhangs']['exemplar']:.1f}%)")
