"""The backend operations of each kernel family, declared once.

One abstract class per family (mesh, points, texel, growth, pyramid, cascade; the SSD
primitives are declared on :class:`geosynth._backends.base.Backend`). The Warp mixin
(``warp_<family>.py``) and the OpenCL mixin (``opencl_<family>.py``) subclass it, with
the same parameter names in the same order (tests/test_backend_interfaces.py checks).
Nothing here validates: the public functions that call these operations do.

Arrays that travel together are a frozen dataclass of DeviceArrays (:class:`ArrayGroup`):
its fields are declared in the order of the kernel's arguments, and
:meth:`ArrayGroup.buffers` is the only place that turns a group into launch arguments,
on both backends. Shapes below are the logical ones; the kernels index every array flat.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields

import numpy as np

from geosynth.core.arrays import DeviceArray


@dataclass(frozen=True)
class ArrayGroup:
    """Device arrays passed to a kernel together, fields in the kernel's argument order."""

    def arrays(self) -> list[DeviceArray]:
        """The DeviceArrays, in field order."""
        return [getattr(self, f.name) for f in fields(self)]

    def buffers(self) -> list:
        """The backend buffers (``DeviceArray.data``), in field order: the launch arguments."""
        return [a.data for a in self.arrays()]

    def to_host(self, backend) -> dict[str, np.ndarray]:
        """Every array copied to the host with one synchronization, by field name."""
        return dict(zip((f.name for f in fields(self)), backend.to_host_all(self.arrays())))


# ------------------------------------------------------------------ mesh distance (kernels/sdf_mesh.*)


@dataclass(frozen=True)
class MeshArrays(ArrayGroup):
    """A prepared mesh (geosynth.geometry.meshes.MeshBVH) on a device, flat, in kernel order.

    Attributes:
        sbox: (nodes * 8,) float32 search boxes.
        child: (nodes * 2,) int32 child / leaf triangle ranges.
        tri_lanes: (F * 32,) float32 triangles in the distance kernels' lane layout.
        tris: (F * 9,) float32 triangle corners.
        dipole: (nodes * 8,) float32 winding-number dipoles.
    """

    sbox: DeviceArray
    child: DeviceArray
    tri_lanes: DeviceArray
    tris: DeviceArray
    dipole: DeviceArray

    @classmethod
    def upload(cls, bvh, backend) -> MeshArrays:
        f32, i32 = np.float32, np.int32
        return cls(*(backend.to_device(np.ascontiguousarray(getattr(bvh, name), dt).reshape(-1))
                     for name, dt in (("sbox", f32), ("child", i32), ("tri_lanes", f32), ("tris", f32),
                                      ("dipole", f32))))


class MeshOps(ABC):
    """Distance to a triangle mesh at points and on grids (float32, world units)."""

    def mesh_handle(self, bvh) -> MeshArrays:
        """The device arrays of a prepared mesh (geosynth.geometry.meshes.MeshBVH), uploaded once
        per mesh and device (kept in ``bvh.device_cache``)."""
        handle = bvh.device_cache.get(self.name)
        if handle is None:
            handle = bvh.device_cache[self.name] = MeshArrays.upload(bvh, self)
        return handle

    @abstractmethod
    def mesh_distance_points(self, mesh: MeshArrays, points: DeviceArray, n: int, signed: bool, band: float,
                             out: DeviceArray) -> None:
        """out (n,) float32 <- the distance (negative inside when ``signed``) at points
        (n * 3,) float32 xyz. Pass the points in a spatial order: each search starts from
        the previous point's closest triangle. ``band``: distances beyond it may be
        reported as any value beyond it (inf: exact everywhere)."""

    @abstractmethod
    def mesh_distance_grid(self, mesh: MeshArrays, origin: np.ndarray, spacing: np.ndarray,
                           shape: tuple[int, int, int], signed: bool, band: float, out: DeviceArray) -> None:
        """out (nz * ny * nx,) float32 <- the distance at origin + spacing * (i, j, k),
        shape = (nx, ny, nz); origin, spacing: (3,) float32 world units; band as above."""


# ------------------------------------------------------------------ point-set distance (kernels/sdf_points.*)


class PointsOps(ABC):
    """MLS signed distance to an oriented point set (float32, world units)."""

    @abstractmethod
    def mls_project(
        self, pn: DeviceArray, cell_start: DeviceArray, grid_origin: tuple[float, float, float], inv_cell: float,
        grid_dims: tuple[int, int, int], inv_h2: float, reach: float, tol: float, max_iter: int,
        queries: DeviceArray | None, lattice: tuple | None, m: int, dist: DeviceArray, grad: DeviceArray,
        proj: DeviceArray | None, residual: DeviceArray | None = None,
    ) -> None:
        """MLS signed distance, gradient and (optionally) projection of m query points.

        Args:
            pn: (n * 8,) float32, the points sorted by cell, interleaved with normals.
            cell_start: (nx * ny * nz + 1,) int32, first point of each cell.
            grid_origin: (x, y, z) of the cell grid; inv_cell: 1 / cell size;
                grid_dims: (nx, ny, nz) cell counts.
            inv_h2: 1 / h^2 (h: the kernel radius); reach: the weights' cut-off distance;
                tol: |f| at which a projection stops; max_iter: most projection steps.
            queries: (m * 3,) float32 xyz, or None for the lattice.
            lattice: ((ox, oy, oz), (sx, sy, sz), (qx, qy)) origin, spacing and the counts
                along x and y (x fastest) when queries is None.
            m: query count.
            dist: (m,) float32 out; grad: (m * 3,) float32 out; proj: (m * 3,) float32
                out, or None for no projection.
            residual: (m,) float32 out, f at the projection (the size of one more step;
                +reach where no point is within reach of it; where the projection stopped
                at ``|f| <= tol`` or at a fixed point, that last step's f), or None.

        A projection stops early at a fixed point (a step that leaves its bits unchanged):
        the result is that of every max_iter step, bit for bit.
        """


# ------------------------------------------------------------------ texel search (kernels/texel.*)


class TexelOps(ABC):
    """The batched M3 texel search: eq. 5 against every texel (uint8 data, uint32 scores)."""

    @abstractmethod
    def texel_search(self, grid: DeviceArray, n: int, width: int, row_step: int, col_step: int, base0: int,
                     qstart: DeviceArray, offsets: DeviceArray, values: DeviceArray, nq: int,
                     scores: DeviceArray, best_idx: DeviceArray, best_score: DeviceArray) -> None:
        """Eq. 5 of ``nq`` queries against every texel, then each query's best texel.

        Args:
            grid: flat uint8, the padded supersampled texture.
            n, width: texel count and texels per row; row_step, col_step, base0: flat
                index of texel (ty, tx) is base0 + ty * row_step + tx * col_step.
            qstart: (nq + 1,) int32 first entry of each query; offsets (E,) int32 flat
                offsets from the texel's index and values (E,) uint8: the queries' entries.
            scores: (>= nq * n,) uint32 out (query-major); best_idx (nq,) int32 out (the
                lowest index of the minimum) and best_score (nq,) uint32 out.
        """


# ------------------------------------------------------------------ M3 growth (kernels/growth.*)
# Every growth kernel runs in one thread (the paper's sequential order). n points, k
# neighbours each; b = growth_buckets(k) priority levels of the queues.


@dataclass(frozen=True)
class GrowthInputs(ArrayGroup):
    """grow_patches' model. pos, nrm: (n * 3,) float64 positions and unit normals; nb:
    (n * k,) int32 neighbour table (self excluded); order: (n,) int32 seed order; dirs:
    (3,) or (n * 3,) float64 seed-frame directions (one for all, or one per point)."""

    pos: DeviceArray
    nrm: DeviceArray
    nb: DeviceArray
    order: DeviceArray
    dirs: DeviceArray


@dataclass(frozen=True)
class GrowthOutputs(ArrayGroup):
    """grow_patches' results. state, patch: (n,) int32 (PATCH/GAP, patch index or -1);
    uv: (n * 2,) float64 texels; fn, fs, ft: (n * 3,) float64 frames (NaN for gap
    points); distortion: (n,) float64; seeds: (n,) int32, the first counts[0] used;
    counts: (1,) int32 patches."""

    state: DeviceArray
    patch: DeviceArray
    uv: DeviceArray
    fn: DeviceArray
    fs: DeviceArray
    ft: DeviceArray
    distortion: DeviceArray
    seeds: DeviceArray
    counts: DeviceArray

    @classmethod
    def allocate(cls, backend, n: int) -> GrowthOutputs:
        f64, i32 = np.float64, np.int32
        return cls(*(backend.empty(shape, dt) for shape, dt in
                     (((n,), i32), ((n,), i32), ((n, 2), f64), ((n, 3), f64), ((n, 3), f64), ((n, 3), f64),
                      ((n,), f64), ((n,), i32), ((1,), i32))))


@dataclass(frozen=True)
class GrowthScratch(ArrayGroup):
    """grow_patches' scratch: key, slot, next, prev, touched (n,) int32; head, tail (b,)
    int32; terms (k * 12,) float64."""

    key: DeviceArray
    slot: DeviceArray
    next: DeviceArray
    prev: DeviceArray
    touched: DeviceArray
    head: DeviceArray
    tail: DeviceArray
    terms: DeviceArray

    @classmethod
    def allocate(cls, backend, n: int, k: int, n_buckets: int) -> GrowthScratch:
        i32 = np.int32
        return cls(*(backend.empty((n,), i32) for _ in range(5)), backend.empty((n_buckets,), i32),
                   backend.empty((n_buckets,), i32), backend.empty((k * 12,), np.float64))


@dataclass(frozen=True)
class BlendInputs(ArrayGroup):
    """blend_gaps' model: pos, nrm (n * 3,) float64; nb (n * k,) int32; state (n,) int32."""

    pos: DeviceArray
    nrm: DeviceArray
    nb: DeviceArray
    state: DeviceArray


@dataclass(frozen=True)
class PatchFrames(ArrayGroup):
    """Each point's patch: patch (n,) int32 (-1: none), uv (n * 2,) float64 texels, frames
    fn, fs, ft (n * 3,) float64. blend_gaps reads and overwrites them (joined gap points)."""

    patch: DeviceArray
    uv: DeviceArray
    fn: DeviceArray
    fs: DeviceArray
    ft: DeviceArray


@dataclass(frozen=True)
class BlendOutputs(ArrayGroup):
    """blend_gaps' results: colours (n * 3,) float64 RGB; coloured (n,) int32 0/1."""

    colours: DeviceArray
    coloured: DeviceArray

    @classmethod
    def allocate(cls, backend, n: int) -> BlendOutputs:
        return cls(backend.empty((n, 3), np.float64), backend.empty((n,), np.int32))


@dataclass(frozen=True)
class BlendScratch(ArrayGroup):
    """blend_gaps' scratch: key, slot, next, prev (n,) int32; head, tail (b,) int32; terms
    (k * 16,) float64."""

    key: DeviceArray
    slot: DeviceArray
    next: DeviceArray
    prev: DeviceArray
    head: DeviceArray
    tail: DeviceArray
    terms: DeviceArray

    @classmethod
    def allocate(cls, backend, n: int, k: int, n_buckets: int) -> BlendScratch:
        i32 = np.int32
        return cls(*(backend.empty((n,), i32) for _ in range(4)), backend.empty((n_buckets,), i32),
                   backend.empty((n_buckets,), i32), backend.empty((k * 16,), np.float64))


@dataclass(frozen=True)
class MatchInputs(ArrayGroup):
    """match_coherent's level: pos, nrm, s_axis, t_axis (n * 3,) float64 (positions, unit
    normals, texture x and y directions); nb (n * k,) int32."""

    pos: DeviceArray
    nrm: DeviceArray
    s_axis: DeviceArray
    t_axis: DeviceArray
    nb: DeviceArray


@dataclass(frozen=True)
class MatchState(ArrayGroup):
    """match_coherent's in/out: coloured (n,) int32 0/1; colours (n * 3,) uint8; source
    (n,) int32 texel each coloured point came from (-1: none)."""

    coloured: DeviceArray
    colours: DeviceArray
    source: DeviceArray


@dataclass(frozen=True)
class MatchScratch(ArrayGroup):
    """match_coherent's scratch: key, slot, next, prev (n,) int32; head, tail (b,) int32;
    rel (k,) int32; vals (k * 3,) uint8; cand (k,) int32."""

    key: DeviceArray
    slot: DeviceArray
    next: DeviceArray
    prev: DeviceArray
    head: DeviceArray
    tail: DeviceArray
    rel: DeviceArray
    vals: DeviceArray
    cand: DeviceArray

    @classmethod
    def allocate(cls, backend, n: int, k: int, n_buckets: int) -> MatchScratch:
        i32 = np.int32
        return cls(*(backend.empty((n,), i32) for _ in range(4)), backend.empty((n_buckets,), i32),
                   backend.empty((n_buckets,), i32), backend.empty((k,), i32), backend.empty((k * 3,), np.uint8),
                   backend.empty((k,), i32))


class GrowthOps(ABC):
    """The M3 patch growth, gap blending and coherent matching, each one kernel launch
    in one thread (kernels/growth.py defines the rules and the queue's tie order)."""

    @abstractmethod
    def grow_patches(self, n: int, k: int, inputs: GrowthInputs, dir_step: int, unit: float,
                     weights: tuple[float, float, float, float], threshold: float, max_patch: float,
                     n_buckets: int, outputs: GrowthOutputs, scratch: GrowthScratch) -> None:
        """Grow every patch of a point model into ``outputs``.

        Args:
            dir_step: 0 for one seed direction (dirs (3,)), 1 for one per point.
            unit: world length of a texel; weights: (w1, w2, w3, w4) of eqs. 2-4;
                threshold: the distortion bound; max_patch: largest patch extent in
                texels (<= 0: unbounded); n_buckets: priority levels of the queue.
        """

    @abstractmethod
    def blend_gaps(self, n: int, k: int, inputs: BlendInputs, unit: float, tex: DeviceArray, h: int, w: int,
                   wrap: int, offsets: DeviceArray, n_buckets: int, frames: PatchFrames, outputs: BlendOutputs,
                   scratch: BlendScratch) -> None:
        """Colour the patch points, then blend the gap points into ``outputs``.

        Args:
            unit: world length of a texel; tex: (h * w * 3,) uint8 RGB texture; wrap: 1
                for periodic lookups, 0 clamped; offsets: (patches * 2,) float64 texel
                offset (x, y) of each patch; n_buckets: priority levels of the queue.
            frames: read, and overwritten where a gap point joins a patch.
        """

    @abstractmethod
    def match_coherent(self, n: int, k: int, inputs: MatchInputs, unit: float, grid: DeviceArray, xp: int, pad: int,
                       m: int, h: int, w: int, tileable: int, subtexel: int, shifts1: DeviceArray, n_shift1: int,
                       ring: int, order: DeviceArray, rand_texel: DeviceArray, n_buckets: int, state: MatchState,
                       scratch: MatchScratch) -> None:
        """Coherent neighbourhood matching of one level: colour every uncoloured point.

        Args:
            unit: world length of a texel; grid: flat uint8 padded supersampled texture,
                xp pixels per row, pad pixels of padding, m the supersampling factor,
                h x w texels; tileable, subtexel, ring: 0 or 1.
            shifts1: (n_shift1 * 2,) int32 first refinement shifts (dy, dx).
            order: (n,) int32 order of the points taken when none is queued; rand_texel:
                (n,) int32 the texel a point with no coloured neighbour takes.
            n_buckets: priority levels of the queue; state: read and updated in place.
        """


# ------------------------------------------------------------------ M1 block pyramids (kernels/pyramid.*)
# Layout (kernels/pyramid.py): ``sums`` holds one slab of total = Z * Y * X uint32 entries
# per cell size c = 2^k; entry p of slab k is the exact sum of the uint8 field over the
# c^3 cube whose lowest corner is p (0 where the cube leaves the field).


class PyramidOps(ABC):
    """The block pyramid of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 4.1-4.3:
    cell sums, their rounded means, level distances and hashes (exact integer arithmetic)."""

    @abstractmethod
    def pyramid_empty(self, shape: tuple[int, ...], dtype: np.dtype) -> DeviceArray:
        """An uninitialised device array; int64 and uint64 (distances, hashes) included."""

    @abstractmethod
    def pyramid_read(self, array: DeviceArray, count: int) -> np.ndarray:
        """The first ``count`` entries of a flat device array, as a host copy (a sync)."""

    @abstractmethod
    def pyramid_read_all(self, array: DeviceArray) -> np.ndarray:
        """Every entry of a device array (any dtype, shape kept), as a host copy (a sync)."""

    @abstractmethod
    def pyramid_write(self, array: DeviceArray, host: np.ndarray) -> None:
        """Copy a host array (same dtype) into the start of an existing device array."""

    @abstractmethod
    def pyramid_init(self, field: DeviceArray, sums: DeviceArray, total: int) -> None:
        """sums[:total] (uint32) <- field (total,) uint8 widened: the cell size 1 slab."""

    @abstractmethod
    def pyramid_double(self, sums: DeviceArray, src_off: int, dst_off: int, c: int, nz: int, ny: int,
                       nx: int) -> None:
        """The slab at dst_off <- sums of 2c-cubes from the cell size c slab at src_off
        (0 where a 2c-cube leaves the (nz, ny, nx) field)."""

    @abstractmethod
    def pyramid_quantize(self, sums: DeviceArray, off: int, lc: int, total: int, out: DeviceArray) -> None:
        """out (total,) uint8 <- the means of the cell size 2^lc slab at ``off``, rounded half up."""

    @abstractmethod
    def pyramid_compare(self, sums: DeviceArray, total: int, ny: int, nx: int, log_block: int,
                        node_base: DeviceArray, node_code: DeviceArray, ids: DeviceArray, first: int, count: int,
                        query: DeviceArray, query_off: DeviceArray, out: DeviceArray) -> None:
        """out[:count] (int64) <- the integer level distance D of the tree nodes
        ids[first:first + count] (int32) against a query. node_base: (nodes,) int32 flat
        origin of each node's representative block; node_code: (nodes,) int32 level * 2 +
        kind (0 exact sums, 1 the interval of sums its rounded means allow); query: int32
        cell sums level after level, level l starting at query_off[l - 1] ((L + 1,) int32);
        log_block = log2(block side)."""

    @abstractmethod
    def pyramid_hash_init(self, sums: DeviceArray, off: int, lc: int, quantized: int, total: int,
                          out: DeviceArray) -> None:
        """out (total,) uint64 <- per-position hash seeds (value + 1) of the slab at ``off``
        (cell size 2^lc): exact sums, or their rounded means when ``quantized`` is 1."""

    @abstractmethod
    def pyramid_hash_step(self, src: DeviceArray, dst: DeviceArray, total: int, stride: int, mult: int) -> None:
        """dst[p] (uint64) <- src[p] + mult * src[p + stride] (mod 2^64), 0 where p + stride
        is past ``total``: one doubling of a linear polynomial hash."""

    @abstractmethod
    def pyramid_pair_equal(self, sums: DeviceArray, total: int, ny: int, nx: int, lc: int, n: int, quantized: int,
                           base_a: DeviceArray, base_b: DeviceArray, count: int, out: DeviceArray) -> None:
        """out[t] (int32) <- 1 where the n^3 cells of size 2^lc (sums, or rounded means when
        ``quantized``) of the blocks at flat origins base_a[t] and base_b[t] are all equal,
        else 0, for t < count (verifies the groups that hashes propose)."""


# ------------------------------------------------------------------ M1 fused cascade search (kernels/cascade.*)


class CascadeOps(ABC):
    """The exact nearest block by lower bounds refined cell by cell (Lagae, Dumont and
    Dutré, "Geometry Synthesis", Sec. 4.2, eq. 2, over every block of the source)."""

    @abstractmethod
    def cascade_search(self, field: DeviceArray, coarse: DeviceArray, coarse_norm: DeviceArray, fine: DeviceArray,
                       lx: int, ly: int, lz: int, sy: int, sz: int, n: int, offsets: DeviceArray,
                       query_terms: DeviceArray, inv_c: float, inv_f: float, queries: DeviceArray, rows: int,
                       items: int, n_queries: int, margin: float, slack: float, best_all: DeviceArray,
                       out: DeviceArray) -> None:
        """A batch of queries against every block of the lattice (lx, ly, lz) with flat row
        / slab strides sy, sz, in one launch of ``items * n_queries`` work-items: work-item
        g serves query q = g // items and scans lattice rows [t * rows, (t + 1) * rows),
        t = g - q * items.

        Args:
            field: (Z * Y * X,) uint8 source; coarse, coarse_norm: (Z * Y * X,) float32
                sums and centred norms of the (n/2)^3 cube at every position; fine:
                (Z * Y * X,) float32 sums of the (n/4)^3 cube.
            n: block side; offsets: (72,) int32, the 8 coarse then the 64 fine cell
                offsets (grouped by coarse cell) from a block's origin.
            query_terms: (n_queries * 80,) float32, per query its 8 coarse sums, 8 coarse
                centred norms, 64 fine sums; inv_c = 1 / (n/2)^3, inv_f = 1 / (n/4)^3;
                queries: (n_queries * n^3,) uint8.
            margin, slack: a block is dropped when its bound exceeds best * margin + slack
                (float32 rounding allowance: the answer stays exact).
            best_all: (n_queries,) int32 in/out, per query the best SSD found by any of
                its items (start: a threshold or INT32_MAX).
            out: (n_queries * items * 3,) int32, per work-item its best SSD, that block's
                lattice index (-1: none within the threshold) and the count of blocks it
                scored exactly.
        """


# ------------------------------------------------------------------ M4 FindMatches (kernels/relief.*)
# Breckon and Fisher, "3D Surface Relief and Colour Completion", Sec. 3, 6 and Appendix A.
# Integer positions (quanta), frames (FRAME_ONE = 2^14 scale) and colours; the arithmetic
# is geosynth.completion.matching's (and docs/relief_match.md's).


@dataclass(frozen=True)
class ReliefIndexArrays(ArrayGroup):
    """The triangulation FindMatches searches, V vertices, all int32, flat.

    Attributes:
        base: (V * 3,) base positions v - D(v), quanta.
        frame: (V * 9,) rows u, v, n of each vertex's frame, FRAME_ONE scale.
        pos: (V * 3,) full positions base + D, quanta (updated as targets get textured).
        colour: (V * 3,) RGB 0..255 (updated).
        usable: (V,) 0/1 may be a partner or a closest-triangle corner (the samples;
            with partners="textured" also the textured targets, updated).
        adj_start: (V + 1,) first neighbour of each vertex in adj; adj: (A,) vertex ids.
        fan_start: (V + 1,) first triangle of each vertex in fan; fan: (F * 2,) the other
            two corners of each triangle around a vertex.
        samples: (S,) vertex id of each candidate sample.
        stencil: (n_cells * S,) where a partner walk starts, cell-major (neighbouring
            work-items read neighbouring entries): the vertex nearest each point of a
            (2K+1)^2 grid in the sample's tangent plane.
    """

    base: DeviceArray
    frame: DeviceArray
    pos: DeviceArray
    colour: DeviceArray
    usable: DeviceArray
    adj_start: DeviceArray
    adj: DeviceArray
    fan_start: DeviceArray
    fan: DeviceArray
    samples: DeviceArray
    stencil: DeviceArray


@dataclass(frozen=True)
class ReliefQueryArrays(ArrayGroup):
    """A batch of Q target neighbourhoods, E entries in all (R rotations).

    Attributes:
        qstart: (Q + 1,) int32 first entry of each query.
        rel: (E * R * 6,) int32 per entry and rotation: moved-base coefficients (3) and
            displacement coefficients (3) on the candidate's frame rows, quanta.
        chain: (E,) int32 1: the partner walk starts at the previous entry's partner, 0: at
            the candidate (where cell is -1).
        cell: (E * R,) int32 the stencil cell the walk starts at, -1: none.
        qcolour: (E * 3,) int32 RGB 0..255; qweight: (E,) int32 weights.
        ks, kc: (Q,) float64 code coefficients of the shape and colour sums.
        limit: (Q,) int64 a running code above it stops as OVER.
    """

    qstart: DeviceArray
    rel: DeviceArray
    chain: DeviceArray
    cell: DeviceArray
    qcolour: DeviceArray
    qweight: DeviceArray
    ks: DeviceArray
    kc: DeviceArray
    limit: DeviceArray


class ReliefOps(ABC):
    """M4's FindMatches: every query against every candidate sample and rotation (one
    work-item per triple), and the scattered updates of texturing."""

    @abstractmethod
    def relief_scores(self, index: ReliefIndexArrays, queries: ReliefQueryArrays, cand: DeviceArray, n_cand: int,
                      cand_stride: int, n_query: int, rotations: int, n_samples: int, out: DeviceArray) -> None:
        """out (n_query * n_cand * rotations,) uint32 <- the code of query q against
        candidate sample index.samples[cand[q * cand_stride + c]] (cand: int32 sample
        slots, (n_cand,) shared by every query with cand_stride 0, or (n_query * n_cand,)
        one row per query with cand_stride n_cand; a slot -1 is no candidate: OVER) at
        rotation r, at (q * n_cand + c) * rotations + r: a score code, OVER or INVALID
        (geosynth.completion.matching); n_samples: S, the stencil's row length."""

    @abstractmethod
    def relief_update(self, ids: DeviceArray, pos: DeviceArray, colour: DeviceArray, n: int, mark: int,
                      index: ReliefIndexArrays) -> None:
        """Vertices ids (n,) int32 get textured: index.pos <- pos (n * 3,) int32,
        index.colour <- colour (n * 3,) int32, and index.usable <- 1 when mark is 1."""
