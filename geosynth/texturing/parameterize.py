"""Which patch and texture coordinate does each point get? Zhang, Qiu and Kaufman, "Fast
Hybrid Approach for Texturing Point Models", Sec. 3 (point parameterization) and Appendix A.

M3 point parameterization (Zhang, Qiu and Kaufman, "Fast hybrid approach for texturing
point models", Sec. 3 and Appendix A): region growing of 2D patches over a point model
with bounded distortion, the texture mapped onto the patches, gap points blended.

Definitions (paper's notation):

- Points are *free*, *patch* or *gap*. A patch starts at a random free seed with the
  frame (N, S, T): N the seed's normal, T the up vector projected on the tangent plane
  (or a random tangent direction), S = T x N; the seed sits at q = (0, 0).
- The next candidate F is the free point with the most points of the current patch in
  its k-neighbourhood (a bucket priority queue: when a point joins, every free point
  in its k-neighbourhood gets +1).
- From each patch point P in N_k(F) with n_P . n_F > 0 (the rule against local
  self-intersections; P with |V0 . N_P| ~ 1 is skipped, Appendix A; an F with no such
  P stays free for a later patch), F gets
  ``V = F - P, V0 = V / |V|``, ``q_f = q_P + (V . S_P, V . T_P)`` rescaled to length
  |V|, ``N'_f = N_P - (V0 . N_P) V0``, ``N_f = N'_f / |N'_f|``,
  ``T_f = (V0 . T_P) V0 + (V0 . S_P) N_f x V0``, ``S_f = T_f x N_f``.
- F's position and frame are the averages weighted by ``w^l = unit / |F - P_l|`` (the
  inverse distance in unit lengths, so that the max terms below are scale-free; the
  averaged frame is re-orthonormalized). Distortions (eqs. 2-4), positions in unit
  lengths (texels):
  ``D_pos = w1 sum(w |q^l - q|) / sum(w) + max(w |q^l - q|)``,
  ``D_ori = w2 sum(w (2 - S^l.S - T^l.T)) / sum(w) + max(w (2 - S^l.S - T^l.T))``,
  ``D = w3 D_ori + w4 D_pos``; F becomes a patch point iff ``D <= threshold``, else a
  gap point. Defaults w1 = w2 = 1, w3 = 3, w4 = 2, threshold 1.6.
- Unit length (one texel) = the mean nearest-neighbour distance, times ``unit_scale``.
- Tileable textures: patches are unbounded and mapped at a random offset. Otherwise a
  patch may not grow beyond ``max_patch`` texels (bounding box of q; a point that would
  enlarge it past that becomes a gap point) and is mapped at a random offset inside
  the texture.
- Gap points, most patch neighbours first, take the 1/distance-weighted blend of the
  colours their patch neighbours map them to; a coloured gap point then counts as a
  patch point (of the patch with the largest weight among its neighbours).

The growth and the gap blending each run in one kernel launch (one work-item) in the
paper's sequential order; kernels/growth.py defines the queues' tie order (first in,
first out within a priority) and geosynth.texturing.reference has plain-Python twins.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from geosynth._backends.interfaces import (
    BlendInputs, BlendOutputs, BlendScratch, GrowthInputs, GrowthOutputs, GrowthScratch, PatchFrames,
)
from geosynth.geometry.pointsets import PointSet
from geosynth.texturing.textures import as_texture, sample_bilinear

__all__ = [
    "FREE", "GAP", "PATCH", "CheckedModel", "DeviceGrowth", "Parameterization", "as_model", "check_growth_options",
    "check_up", "colour_parameterization", "frames_from_up", "growth_inputs", "parameterize_points",
    "parameterize_with_device_arrays", "patch_offsets", "pick_batch", "propagate", "tangent_offsets",
]

FREE, PATCH, GAP = 0, 1, 2
DEFAULT_WEIGHTS = (1.0, 1.0, 3.0, 2.0)  # w1, w2, w3, w4 of eqs. 2-4 (paper, Sec. 3.2)
DEFAULT_THRESHOLD = 1.6
PARALLEL_LIMIT = 1 - 1e-9  # |V0 . N_P| at or above this: F lies along P's normal (Appendix A)


@dataclass
class Parameterization:
    """The patches of a point model.

    Attributes:
        state: (N,) int8: PATCH (1) or GAP (2) for every point after growth.
        patch: (N,) int32 patch index of patch points, -1 for gap points.
        uv: (N, 2) float64 patch coordinates (x along S, y along T) in texels; NaN for gap points.
        normal, s_axis, t_axis: (N, 3) float64 propagated frames (NaN for gap points).
        unit: world length of one texel.
        seeds: (P,) int64 seed point of every patch.
        distortion: (N,) float64 D(F) of every point when it was evaluated (0 for seeds,
            NaN for points with no usable patch neighbour).
        neighbours: (N, k) int32 k-nearest-neighbour table used (self excluded).
        distances: (N, k) float64 distances to them.
        seconds: wall time of the growth.
    """

    state: np.ndarray
    patch: np.ndarray
    uv: np.ndarray
    normal: np.ndarray
    s_axis: np.ndarray
    t_axis: np.ndarray
    unit: float
    seeds: np.ndarray
    distortion: np.ndarray
    neighbours: np.ndarray
    distances: np.ndarray
    seconds: float = 0.0

    @property
    def gap_fraction(self) -> float:
        """Fraction of the points that are gap points."""
        return float(np.mean(self.state == GAP))

    @property
    def patch_count(self) -> int:
        return int(len(self.seeds))


# ------------------------------------------------------------------ Appendix A, vectorized


def _cross(a, b):
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def propagate(f_pos, p_pos, p_uv, p_normal, p_s, p_t, unit: float):
    """Appendix A: position and frame of F seen from patch point P (broadcasting arrays).

    Args:
        f_pos: (..., 3) positions of the candidates F.
        p_pos, p_normal, p_s, p_t: (..., 3) position and frame of the patch points P.
        p_uv: (..., 2) patch coordinates of P (texels).
        unit: world length of a texel.

    Returns:
        (uv (..., 2), normal (..., 3), s (..., 3), t (..., 3), distance (...), ok (...)):
        ``ok`` is False where F coincides with P or lies along P's normal (then the
        other outputs are meaningless).
    """
    v = f_pos - p_pos
    dist = np.sqrt(_dot(v, v))
    v0 = v / np.maximum(dist, 1e-300)[..., None]
    along = _dot(v0, p_normal)
    ok = (dist > 0) & (np.abs(along) < PARALLEL_LIMIT)
    a, b = _dot(v, p_s), _dot(v, p_t)
    plane = np.sqrt(a * a + b * b)
    scale = np.where(ok, dist / np.maximum(plane, 1e-300), 0.0) / unit  # |F_p P| = |F P|, in texels
    uv = p_uv + np.stack([a * scale, b * scale], -1)
    n = p_normal - along[..., None] * v0
    n = n / np.maximum(np.sqrt(_dot(n, n)), 1e-300)[..., None]
    t = _dot(v0, p_t)[..., None] * v0 + _dot(v0, p_s)[..., None] * _cross(n, v0)
    s = _cross(t, n)
    return uv, n, s, t, dist, ok


def _orthonormal(n, t):
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)
    t = t - _dot(t, n)[..., None] * n
    t = t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-300)
    return n, _cross(t, n), t


# ------------------------------------------------------------------ frames


def check_up(up) -> np.ndarray | None:
    """The up vector as a (3,) float64 array (None stays None: random directions).

    Raises:
        ValueError: up is not a finite, non-zero 3-vector.
    """
    if up is None:
        return None
    u = np.asarray(up, np.float64)
    if u.shape != (3,) or not np.isfinite(u).all() or not np.abs(u).max() > 0:
        raise ValueError(f"up must be a non-zero 3-vector (x, y, z) or None, got {up!r}.")
    return u


def frames_from_up(normals: np.ndarray, up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Tangent frames from an up vector: T = up projected on the tangent plane, S = T x N.

    Where the up vector is (nearly) parallel to the normal, the x axis (or y) is used
    instead.

    Args:
        normals: (N, 3) unit normals.
        up: (3,) up vector.

    Returns:
        (S, T): two (N, 3) float64 unit tangent axes.

    Raises:
        ValueError: up is not a finite, non-zero 3-vector.
    """
    n = np.asarray(normals, np.float64)
    u = check_up(up)
    u = u / np.linalg.norm(u)
    t = u[None, :] - (n @ u)[:, None] * n
    small = np.linalg.norm(t, axis=1) < 1e-3
    if small.any():
        alt = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        t[small] = alt - (n[small] @ alt)[:, None] * n[small]
    _, s, t = _orthonormal(n, t)
    return s, t


def tangent_offsets(positions: np.ndarray, s_axis: np.ndarray, t_axis: np.ndarray, normals: np.ndarray,
                    centres: np.ndarray, others: np.ndarray, unit: float) -> np.ndarray:
    """Points mapped onto the tangent planes of centre points by the patch mapping of
    Appendix A, in texels (x along S, y along T): the irregular neighbourhood of Sec. 4
    when ``others`` are the centres' neighbours.

    Args:
        positions: (N, 3) float64 positions; normals, s_axis, t_axis: (N, 3) frames.
        centres: (M,) indices of the centre points.
        others: (M, J, 3) float64 positions to map, J per centre (any points: the
            centres' neighbours, or coarser points of a hierarchy).
        unit: world length of a texel.

    Returns:
        (M, J, 2) float64 offsets; a point along the centre's normal gets the plain
        projection (V . S, V . T) (length 0 if it coincides).
    """
    c = np.asarray(centres)
    p = np.asarray(positions, np.float64)
    zero = np.zeros((len(c), 1, 2))
    uv, _, _, _, _, ok = propagate(others, p[c][:, None], zero, normals[c][:, None], s_axis[c][:, None],
                                   t_axis[c][:, None], unit)
    v = others - p[c][:, None]
    plain = np.stack([_dot(v, s_axis[c][:, None]), _dot(v, t_axis[c][:, None])], -1) / unit
    return np.where(ok[..., None], uv, plain)


# ------------------------------------------------------------------ growth


class CheckedModel(NamedTuple):
    """A point model that :func:`as_model` has checked: (N, 3) float64 positions and
    unit normals. The M3 stages accept it in place of a PointSet (no second check)."""

    positions: np.ndarray
    normals: np.ndarray


def as_model(points) -> tuple[np.ndarray, np.ndarray]:
    """Check a point model for the M3 stages.

    Args:
        points: a PointSet with normals, or a :class:`CheckedModel` (returned as is).

    Returns:
        ((N, 3) float64 positions, (N, 3) float64 unit normals).

    Raises:
        TypeError: not a PointSet.
        ValueError: NaN or inf positions, no normals, zero-length or non-finite normals.
    """
    if isinstance(points, CheckedModel):
        return points.positions, points.normals
    if not isinstance(points, PointSet):
        raise TypeError(f"points must be a geosynth PointSet (positions and normals), got {type(points).__name__}.")
    p = points.positions.astype(np.float64)
    if not np.isfinite(p).all():
        bad = int(np.count_nonzero(~np.isfinite(p).all(1)))
        raise ValueError(f"points has {bad} position(s) with NaN or inf, first at index "
                         f"{int(np.flatnonzero(~np.isfinite(p).all(1))[0])}; remove them first.")
    if points.normals is None:
        raise ValueError("points has no normals; estimate them first (geosynth.geometry.pointsets.estimate_normals) "
                         "or load the model with geosynth.texturing.models.load_point_model, which does.")
    n = points.normals.astype(np.float64)
    length = np.linalg.norm(n, axis=1)
    if not np.isfinite(n).all() or (length < 1e-12).any():
        raise ValueError("points has zero-length or non-finite normals; re-estimate them (estimate_normals).")
    return p, n / length[:, None]


def check_k(k, n_points: int) -> int:
    """Check the neighbourhood size: an integer >= 3 and below the point count."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 3:
        raise ValueError(f"k (neighbours per point) must be an integer >= 3, got {k!r}.")
    if k >= n_points:
        raise ValueError(f"k = {k} needs more than {k} points; the model has {n_points}. Use a smaller k.")
    return int(k)


def mean_spacing(distances: np.ndarray) -> float:
    """Mean nearest-neighbour distance (the paper's unit length before scaling)."""
    d = float(np.mean(distances[:, 0]))
    if not d > 0:
        raise ValueError("all points coincide with their nearest neighbour (spacing 0): remove duplicate points.")
    return d


def pick_batch(cand: np.ndarray, neighbours: np.ndarray, blocked: np.ndarray, limit: int) -> np.ndarray:
    """Greedy: up to ``limit`` candidates in the given order, none in another's
    k-neighbourhood (in either direction). ``blocked`` is an all-False (N, 2) bool
    scratch array (column 0: a neighbour of a chosen point, column 1: chosen); it is
    all False again on return."""
    chosen: list[int] = []
    near, picked = blocked[:, 0], blocked[:, 1]
    for f in cand.tolist():
        nb = neighbours[f]
        if near[f] or picked[nb].any():
            continue
        chosen.append(f)
        near[nb] = True
        picked[f] = True
        if len(chosen) >= limit:
            break
    out = np.asarray(chosen, np.int64)
    near[neighbours[out].reshape(-1)] = False
    picked[out] = False
    return out


def check_growth_options(weights, threshold, unit_scale, max_patch) -> tuple[float, float, float, float]:
    """The growth's settings: the distortion weights (w1..w4, as floats), its bound, the
    texel scale and the largest patch, each refused in one line naming it."""
    w = tuple(float(x) for x in weights)
    if len(w) != 4 or not all(np.isfinite(x) and x >= 0 for x in w):
        raise ValueError(f"weights must be four numbers >= 0 (w1, w2, w3, w4), got {weights!r}.")
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be a number > 0, got {threshold!r}.")
    if not (np.isfinite(unit_scale) and unit_scale > 0):
        raise ValueError(f"unit_scale must be a number > 0, got {unit_scale!r}.")
    if max_patch is not None and not (np.isfinite(max_patch) and max_patch >= 1):
        raise ValueError(f"max_patch must be None or a size >= 1 texel, got {max_patch!r}.")
    return w


def growth_inputs(points: PointSet, k: int, *, unit_scale: float = 1.0, up=(0.0, 1.0, 0.0), seed=0,
                  neighbours: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Everything the growth needs besides the options: positions, unit normals, the
    k-neighbour table, the unit length, the seed order and every point's seed frame.

    Returns:
        dict with ``pos`` (N, 3) float64, ``nrm`` (N, 3) float64, ``dist`` (N, k) float64,
        ``nb`` (N, k) int32, ``unit`` float, ``order`` (N,) int64 (a seeded permutation:
        patches start at its first free point), ``dirs`` float64, the direction that a
        patch's seed frame starts from (kernels/growth.py): ``up`` as (1, 3), or (N, 3)
        random directions (one per point) when ``up`` is None.
    """
    from geosynth.texturing.models import knn_table

    p, nrm = as_model(points)
    n_pts = len(p)
    k = check_k(k, n_pts)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if neighbours is None:
        dist, nb = knn_table(p, k)
    else:
        dist, nb = neighbours
        if nb.shape != (n_pts, k):
            raise ValueError(f"neighbours must be ({n_pts}, {k}) tables, got {nb.shape}.")
    unit = mean_spacing(dist) * float(unit_scale)
    order = rng.permutation(n_pts)
    if up is not None:
        dirs = check_up(up).reshape(1, 3)
    else:
        dirs = rng.standard_normal((n_pts, 3))
    return dict(pos=p, nrm=nrm, dist=dist, nb=nb, unit=unit, order=order, dirs=dirs)


def parameterize_points(
    points: PointSet,
    k: int = 25,
    *,
    unit_scale: float = 1.0,
    up=(0.0, 1.0, 0.0),
    weights=DEFAULT_WEIGHTS,
    threshold: float = DEFAULT_THRESHOLD,
    max_patch: float | None = None,
    seed: int | np.random.Generator | None = 0,
    neighbours: tuple[np.ndarray, np.ndarray] | None = None,
    device: str | None = None,
) -> Parameterization:
    """Flatten a point model into 2D patches with bounded distortion (paper Sec. 3.2-3.3).

    The growth is the paper's sequential order, in one kernel launch (``kernels/growth``;
    the queue's tie order is defined there); :func:`geosynth.texturing.reference.parameterize_reference`
    is its plain-Python twin.

    Args:
        points: PointSet with positions and normals (N >= k + 1), or a CheckedModel.
        k: neighbours per point (>= 3).
        unit_scale: one texel = ``unit_scale`` x the mean nearest-neighbour distance.
        up: (3,) up vector for the seed frames, or None for a random tangent direction per patch.
        weights: (w1, w2, w3, w4) of eqs. 2-4.
        threshold: distortion bound; a candidate with ``D > threshold`` becomes a gap point.
        max_patch: None for unbounded patches (tileable textures), else the largest
            patch extent (bounding box of q) in texels.
        seed: int seed or Generator (patch seeds, random orientations).
        neighbours: optional precomputed (distances, indices) k-neighbour table.
        device: where the growth runs (a device string; None: "auto").

    Returns:
        :class:`Parameterization`.

    Raises:
        TypeError: points is not a PointSet.
        ValueError: no normals, NaN positions, k < 3 or >= N, bad weights/threshold.
        RuntimeError: the device is absent.
    """
    return parameterize_with_device_arrays(
        points, k, unit_scale=unit_scale, up=up, weights=weights, threshold=threshold, max_patch=max_patch,
        seed=seed, neighbours=neighbours, device=device)[0]


@dataclass(frozen=True)
class DeviceGrowth:
    """The device arrays a device growth leaves: what :func:`colour_parameterization` on
    the same device reads instead of uploading the host copies (measured: 2 ms of 16
    uploads on 16k points). The blending overwrites ``frames``: pass it once.

    Attributes:
        backend: the Backend that holds the arrays.
        model: pos, nrm, nb and state (see geosynth._backends.interfaces.BlendInputs).
        frames: patch, uv and the frames (see geosynth._backends.interfaces.PatchFrames).
    """

    backend: object
    model: BlendInputs
    frames: PatchFrames


def parameterize_with_device_arrays(
    points: PointSet,
    k: int = 25,
    *,
    unit_scale: float = 1.0,
    up=(0.0, 1.0, 0.0),
    weights=DEFAULT_WEIGHTS,
    threshold: float = DEFAULT_THRESHOLD,
    max_patch: float | None = None,
    seed: int | np.random.Generator | None = 0,
    neighbours: tuple[np.ndarray, np.ndarray] | None = None,
    device: str | None = None,
) -> tuple[Parameterization, DeviceGrowth]:
    """:func:`parameterize_points` (same arguments, checks and errors), also returning the
    growth's device arrays, for ``colour_parameterization(..., grown=)``.

    Returns:
        (:class:`Parameterization`, :class:`DeviceGrowth`).
    """
    from geosynth.compute.backend import get_backend

    t_start = time.perf_counter()
    w = check_growth_options(weights, threshold, unit_scale, max_patch)
    backend = get_backend(device or "auto")
    g = growth_inputs(points, k, unit_scale=unit_scale, up=up, seed=seed, neighbours=neighbours)
    n_pts, k = g["nb"].shape
    n_buckets = growth_buckets(k)
    f64, i32 = np.float64, np.int32
    inputs = GrowthInputs(*(backend.to_device(np.ascontiguousarray(g[name], dt)) for name, dt in
                            (("pos", f64), ("nrm", f64), ("nb", i32), ("order", i32), ("dirs", f64))))
    outputs = GrowthOutputs.allocate(backend, n_pts)
    backend.grow_patches(n_pts, k, inputs, int(len(g["dirs"]) > 1), g["unit"], w, float(threshold),
                         -1.0 if max_patch is None else float(max_patch), n_buckets, outputs,
                         GrowthScratch.allocate(backend, n_pts, k, n_buckets))
    host = outputs.to_host(backend)
    param = Parameterization(host["state"].astype(np.int8), host["patch"], host["uv"], host["fn"], host["fs"],
                             host["ft"], g["unit"], host["seeds"][:int(host["counts"][0])].astype(np.int64),
                             host["distortion"], g["nb"], g["dist"], seconds=time.perf_counter() - t_start)
    grown = DeviceGrowth(backend, BlendInputs(inputs.pos, inputs.nrm, inputs.nb, outputs.state),
                         PatchFrames(outputs.patch, outputs.uv, outputs.fn, outputs.fs, outputs.ft))
    return param, grown


def growth_buckets(k: int) -> int:
    """Priority levels of the growth queues: keys 1 .. 4k - 2 each have their own, larger
    keys share the top one (4k - 1)."""
    return 4 * int(k)


# ------------------------------------------------------------------ texturing (Sec. 3.4)


def patch_offsets(param: Parameterization, shape: tuple[int, int], tileable: bool,
                  rng: np.random.Generator) -> np.ndarray:
    """A random texel offset (x, y) per patch: anywhere for a tileable texture, else such
    that the patch's bounding box fits inside the texture (where it can).

    Returns:
        (P, 2) float64.
    """
    h, w = shape
    n_patch = param.patch_count
    if tileable:
        return rng.uniform(0, [w, h], (n_patch, 2))
    members = param.patch >= 0
    lo = np.full((n_patch, 2), np.inf)
    hi = np.full((n_patch, 2), -np.inf)
    np.minimum.at(lo, param.patch[members], param.uv[members])
    np.maximum.at(hi, param.patch[members], param.uv[members])
    room = np.maximum(np.array([w - 1, h - 1]) - (hi - lo), 0)
    return -lo + rng.uniform(0, 1, (n_patch, 2)) * room


def colour_parameterization(
    points: PointSet,
    param: Parameterization,
    texture: np.ndarray,
    *,
    tileable: bool = True,
    seed: int | np.random.Generator | None = 0,
    blend_gaps: bool = True,
    device: str | None = None,
    grown: DeviceGrowth | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map the texture onto the patches and blend the gap points (paper Sec. 3.4).

    Each patch gets a random texel offset (:func:`patch_offsets`). A patch point's colour
    is the bilinear texture value at its patch position plus the offset. Gap points, the
    one with the most coloured neighbours first, take the 1/distance-weighted blend of the
    colours that their coloured neighbours' patches map them to (Appendix A from each
    neighbour), then count as patch points (kernels/growth.py, ``blend_gaps``, gives the
    rules). Gap points with no coloured neighbour at all take a random texel.

    Args:
        points: the PointSet (or CheckedModel) that was parameterized.
        param: its :class:`Parameterization`.
        texture: (H, W, 3) uint8.
        tileable: wrap texture lookups (and place offsets anywhere).
        seed: int seed or Generator for the patch offsets.
        blend_gaps: colour the gap points (False leaves them uncoloured).
        device: where the blending runs (a device string; None: "auto").
        grown: the :class:`DeviceGrowth` that :func:`parameterize_with_device_arrays`
            returned with ``param``: on the same device its arrays stand in for uploads
            (and are overwritten: pass it once); None, or another device: uploads.

    Returns:
        (colours (N, 3) uint8, coloured (N,) bool, offsets (P, 2) float64 texel offset (x, y) per patch).
    """
    from geosynth.compute.backend import get_backend

    p, nrm = as_model(points)
    tex = as_texture(texture)
    h, wdt = tex.shape[:2]
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    offsets = patch_offsets(param, (h, wdt), tileable, rng)
    is_patch = param.state == PATCH
    if not blend_gaps:
        colours_f = np.zeros((len(p), 3))
        idx = np.flatnonzero(is_patch)
        at = param.uv[idx] + offsets[param.patch[idx]]
        colours_f[idx] = sample_bilinear(tex, at[:, 1], at[:, 0], tileable)
        return np.clip(np.rint(colours_f), 0, 255).astype(np.uint8), is_patch.copy(), offsets
    backend = get_backend(device or "auto")
    n_pts, k = param.neighbours.shape
    n_buckets = growth_buckets(k)
    f64, i32 = np.float64, np.int32
    up = backend.to_device
    if grown is not None and grown.backend is backend:
        model, frames = grown.model, grown.frames
    else:
        model = BlendInputs(up(p), up(nrm), up(param.neighbours.astype(i32, copy=False)), up(param.state.astype(i32)))
        frames = PatchFrames(up(param.patch.astype(i32)), up(param.uv), up(param.normal), up(param.s_axis),
                             up(param.t_axis))
    outputs = BlendOutputs.allocate(backend, n_pts)
    backend.blend_gaps(n_pts, k, model, param.unit, up(tex.reshape(-1)), h, wdt, int(tileable),
                       up(np.ascontiguousarray(offsets, f64).reshape(-1)), n_buckets, frames, outputs,
                       BlendScratch.allocate(backend, n_pts, k, n_buckets))
    host = outputs.to_host(backend)
    colours_f, coloured = host["colours"], host["coloured"]
    coloured = coloured.astype(bool)
    rest = np.flatnonzero(~coloured)  # gap points with no coloured neighbour at all
    if len(rest):
        colours_f[rest] = tex.reshape(-1, 3)[rng.integers(0, h * wdt, len(rest))]
        coloured[rest] = True
    return np.clip(np.rint(colours_f), 0, 255).astype(np.uint8), coloured, offsets
