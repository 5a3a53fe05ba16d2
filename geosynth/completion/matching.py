"""Which captured sample's neighbourhood best matches a target's? Breckon and Fisher,
"3D Surface Relief and Colour Completion", Sec. 3 (FindMatches), Sec. 6 (the colour term)
and Appendix A.

FindMatches scores a target's textured neighbourhood against every candidate sample s at
R rotations about the normal: the neighbourhood is moved rigidly from the target's frame
into the frame of s' = s - D(s) (the paper's deterministic frames), each moved neighbour
is paired with the vertex whose base (surface-projected position v - D(v)) is nearest,
the match is valid only when every partner is textured, and

    ssd = mu * ssd_shape + (1 - mu) * ssd_colour,

ssd_shape = sum_j w_j min_{triangles around the partner} dist(p_j, triangle)^2 / sum w,
normalized by the largest displacement difference among the samples, squared;
ssd_colour = sum_j w_j |c_j - c(partner)|^2 / sum w, normalized by the colour range
(3 * 255^2). The scoring is the kernel family ``relief`` (kernels/relief.*).

Every quantity that feeds a decision is computed exactly, so that the same input gives the
same bits on every device: positions are quantized to a grid of ``ReliefIndex.quantum``
world units, frames to integers scaled by ``FRAME_ONE``, colours to 0..255, weights to
1..``WEIGHT_ONE``; partner searches and the point-triangle region tests are int64; a
squared distance is one correctly rounded double division of exact integers, truncated;
the score is an integer code, ``SCORE_ONE`` for an ssd of 1.0 (docs/relief_match.md has the whole
arithmetic). :func:`geosynth.completion.reference.relief_scores_reference` is the NumPy twin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geosynth.core.arrays import DeviceArray
from geosynth.core.exact import exp_fixed, norm3

FRAME_ONE = 1 << 14  # a unit frame component
SCORE_ONE = 1 << 24  # the code of an ssd of 1.0
CODE_CAP = 1 << 31  # codes clamp here
OVER = 0xFFFFFFFE  # the running code passed the query's limit: not a candidate
INVALID = 0xFFFFFFFF  # an untextured partner (or closest-triangle corner)
WEIGHT_ONE = 4096  # the largest weight of a query
CLAMP = 1 << 13  # |p - partner| components clamp here (quanta)
QUANTA_PER_LENGTH = 1 << 11  # quanta per max(longest edge, shape normalization)
MAX_WALK = 256  # most steps of one partner walk
STENCIL_K = 5  # walk-start stencil: (2K+1)^2 points a median edge apart in each sample's tangent plane
COLOUR_RANGE2 = 3 * 255 * 255


def paper_frames(normals: np.ndarray) -> np.ndarray:
    """The paper's deterministic frames (Sec. 3): for a normal n = (x, y, z), if |x| is
    the smallest component u = (0, -z, y), if |y|: u = (z, 0, -x), if |z|: u = (-y, x, 0)
    (ties: x before y before z); u normalized; v = n x u.

    Args:
        normals: (V, 3) unit normals (normalized here).

    Returns:
        (V, 3, 3) float64, rows u, v, n.
    """
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    n = n / norm3(n)[:, None]  # norm3: the same bits on every CPU (issue 40)
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    k = np.argmin(np.abs(n), axis=1)  # first minimum: x before y before z
    zero = np.zeros_like(x)
    u = np.where((k == 0)[:, None], np.stack([zero, -z, y], 1),
                 np.where((k == 1)[:, None], np.stack([z, zero, -x], 1), np.stack([-y, x, zero], 1)))
    u /= norm3(u)[:, None]
    v = np.cross(n, u)
    return np.stack([u, v, n], axis=1)


def _fail(name: str, problem: str, fix: str) -> None:
    raise ValueError(f"{name}: {problem}; {fix}")


def _float_array(name: str, a, shape_tail: tuple, n: int | None = None) -> np.ndarray:
    arr = np.asarray(a, np.float64)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail or (n is not None and arr.shape[0] != n):
        want = f"({n if n is not None else 'V'}{''.join(', ' + str(s) for s in shape_tail)})"
        _fail(name, f"shape {arr.shape}", f"pass an array of shape {want}")
    if not np.all(np.isfinite(arr)):
        _fail(name, f"{int((~np.isfinite(arr)).any(axis=tuple(range(1, arr.ndim))).sum())} rows are not finite",
              "remove or repair the NaN/inf entries")
    return arr


def _index_array(name: str, a, n_vertices: int, shape_tail: tuple = ()) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        _fail(name, f"shape {arr.shape}", f"pass integer vertex ids of shape (n{''.join(', ' + str(s) for s in shape_tail)})")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            _fail(name, "not integer vertex ids", "pass integer indices")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= n_vertices):
        _fail(name, f"ids outside 0..{n_vertices - 1} (min {arr.min()}, max {arr.max()})", "pass valid vertex ids")
    return arr


def _csr(keys: np.ndarray, values: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(start (n+1,) int32, values grouped by key, stable within a key)."""
    order = np.argsort(keys, kind="stable")
    start = np.zeros(n + 1, np.int64)
    np.add.at(start, keys + 1, 1)
    return np.cumsum(start).astype(np.int32), values[order]


@dataclass(frozen=True)
class _Host:
    """The index's host arrays (quantized), in the kernel's layout."""

    base: np.ndarray  # (V, 3) int64 quanta
    frame: np.ndarray  # (V, 3, 3) int64, FRAME_ONE scale
    pos: np.ndarray  # (V, 3) int64 quanta (base + D)
    colour: np.ndarray  # (V, 3) int64 0..255
    usable: np.ndarray  # (V,) bool: may be a partner or a closest-triangle corner
    adj_start: np.ndarray  # (V + 1,) int32
    adj: np.ndarray  # (A,) int32, sorted by id within a vertex
    fan_start: np.ndarray  # (V + 1,) int32
    fan: np.ndarray  # (F, 2) int32 the other two corners of each triangle around a vertex
    samples: np.ndarray  # (S,) int32 vertex ids
    stencil: np.ndarray  # (S, (2K+1)^2) int32 walk starts
    cell: float  # stencil spacing, world


class ReliefIndex:
    """Every vertex of the one triangulation, prepared for FindMatches on one device.

    Build with :meth:`build`; keep it for a whole completion and call :meth:`update` as
    targets get textured (only their entries are written on the device).

    Attributes:
        device: the device string.
        n_vertices: V.
        samples: (S,) int64 vertex ids of the candidate samples.
        quantum: world length of one position quantum.
        origin: (3,) float64 world position of quantum coordinates (0, 0, 0).
        shape_norm: world length normalizing ssd_shape (the largest displacement
            difference along the normals among the samples).
        frames: (V, 3, 3) float64 frames (rows u, v, n).
        base: (V, 3) float64 base positions; displacements: (V, 3) float64 (host copies).
        textured: (V,) bool host copy of the labels.
        host: the quantized host arrays (what the kernels see).
    """

    def __init__(self, device, backend, samples, quantum, origin, shape_norm, frames, base, displacements, host,
                 arrays, labels, partners):
        self.device = device
        self.labels = labels
        self.partners = partners
        self.backend = backend
        self.samples = samples
        self.quantum = quantum
        self.origin = origin
        self.shape_norm = shape_norm
        self.frames = frames
        self.base = base
        self.displacements = displacements
        self.host = host
        self.arrays = arrays
        self._cand: dict[int, tuple[np.ndarray, DeviceArray]] = {}

    @property
    def n_vertices(self) -> int:
        return len(self.base)

    @property
    def textured(self) -> np.ndarray:
        """(V,) bool: the current labels (neighbourhoods are made of textured vertices)."""
        return self.labels

    @property
    def shape_norm_q2(self) -> float:
        """shape_norm^2 in quanta^2."""
        return (self.shape_norm / self.quantum) ** 2

    @classmethod
    def build(cls, base, normals, displacements, textured, triangles, samples, *, colours=None,
              partners="samples", frames=None, device: str = "cpu") -> ReliefIndex:
        """Prepare and upload the triangulation for FindMatches.

        Args:
            base: (V, 3) base positions: s - D(s) for samples, the position on the fit for
                targets (world units).
            normals: (V, 3) unit fit normals at the bases (the frames are made from them).
            displacements: (V, 3) D, zero for untextured targets (world units).
            textured: (V,) bool labels.
            triangles: (T, 3) int vertex ids of the one triangulation (closed over seams).
            samples: (S,) int vertex ids of the candidate samples (textured).
            colours: (V, 3) RGB in [0, 1], or None (no colour: use mu = 1).
            partners: "samples" (the paper, Sec. 5 and Appendix A: a partner and the
                corners of its closest triangle must be samples), "textured" (also
                targets textured so far: the paper's "boot-strapped" variant), or (P,)
                int ids of textured vertices: a fixed set of usable partners apart from
                the candidates, e.g. every oversampled sample while only the capture's
                own vertices are candidates (:func:`geosynth.completion.synthesis.complete_surface`).
            frames: None (the paper's frames from ``normals``, :func:`paper_frames`) or
                (V, 3, 3) frames, rows u, v, n (e.g. the fit's own,
                :func:`geosynth.completion.fit.fit_frames`); n must be ``normals``' direction.
            device: a device string of geosynth.devices().

        Returns:
            The index, uploaded to ``device``.

        Raises:
            ValueError: shapes, NaN, ids out of range, untextured samples, an empty or
                degenerate triangulation.
        """
        from geosynth.compute.backend import get_backend

        base = _float_array("base", base, (3,))
        v = len(base)
        if v < 3:
            _fail("base", f"{v} vertices", "pass a triangulation of at least 3 vertices")
        normals = _float_array("normals", normals, (3,), v)
        lengths = norm3(normals)
        if np.any(lengths < 1e-12):
            _fail("normals", f"{int((lengths < 1e-12).sum())} zero normals", "pass unit normals of the fit")
        disp = _float_array("displacements", displacements, (3,), v)
        tex = np.asarray(textured)
        if tex.shape != (v,):
            _fail("textured", f"shape {tex.shape}", f"pass ({v},) booleans")
        tex = tex.astype(bool)
        partner_ids = None
        if isinstance(partners, str):
            if partners not in ("samples", "textured"):
                _fail("partners", f"{partners!r}", 'pass "samples", "textured" or an array of vertex ids')
        else:
            partner_ids = _index_array("partners", partners, v)
            if len(partner_ids) == 0 or not np.all(tex[partner_ids]):
                _fail("partners", "empty or not all textured", "pass the ids of textured vertices")
            partners = "fixed"
        tris = _index_array("triangles", triangles, v, (3,))
        if len(tris) == 0:
            _fail("triangles", "empty", "pass the triangulation of samples and targets")
        samples = _index_array("samples", samples, v)
        if len(samples) == 0:
            _fail("samples", "empty", "pass the captured samples' vertex ids")
        if not np.all(tex[samples]):
            _fail("samples", f"{int((~tex[samples]).sum())} samples are not textured", "label every sample textured")
        if colours is None:
            col = np.zeros((v, 3))
        else:
            col = _float_array("colours", colours, (3,), v)
            if col.min() < 0 or col.max() > 1:
                _fail("colours", f"values in [{col.min():.3g}, {col.max():.3g}]", "pass RGB in [0, 1]")
        if frames is None:
            frames = paper_frames(normals)
        else:
            frames = np.asarray(frames, dtype=np.float64)
            if frames.shape != (v, 3, 3) or not np.all(np.isfinite(frames)):
                _fail("frames", f"shape {frames.shape} or non-finite values", f"pass ({v}, 3, 3) finite frames or None")
            unit_n = normals / lengths[:, None]
            ortho = np.einsum("vij,vkj->vik", frames, frames) - np.eye(3)
            if np.abs(ortho).max() > 1e-6 or np.abs(frames[:, 2] - unit_n).max() > 1e-6:
                _fail("frames", "rows not orthonormal or n not the normal", "pass rows u, v, n with n = the unit normal")
        pos = base + disp
        heights = np.einsum("ij,ij->i", disp[samples], frames[samples, 2])
        shape_norm = float(heights.max() - heights.min())
        edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
        edge_len = max(float(np.abs(base[edges[:, 0]] - base[edges[:, 1]]).max()),
                       float(np.abs(pos[edges[:, 0]] - pos[edges[:, 1]]).max()))
        if edge_len <= 0:
            _fail("triangles", "every edge has zero length", "pass a triangulation with distinct vertices")
        quantum = max(edge_len, shape_norm) / QUANTA_PER_LENGTH
        shape_norm = max(shape_norm, quantum)
        origin = np.minimum(base.min(0), pos.min(0))
        extent = (np.maximum(base.max(0), pos.max(0)) - origin) / quantum
        if extent.max() >= 2 ** 29:
            _fail("base", f"the surface spans {extent.max():.3g} quanta of {quantum:.3g} (the longest edge / 2048)",
                  "the triangulation is too coarse for its extent: subdivide it")
        usable = tex.copy() if partners == "textured" else np.isin(np.arange(v), samples if partner_ids is None
                                                                   else partner_ids)
        host = cls._quantize(base, frames, pos, col, usable, tris, origin, quantum, samples)
        backend = get_backend(device)
        arrays = _upload_index(backend, host)
        return cls(device, backend, samples, quantum, origin, shape_norm, frames, base, disp.copy(), host, arrays,
                   tex.copy(), partners)

    @staticmethod
    def _quantize(base, frames, pos, col, usable, tris, origin, quantum, samples) -> _Host:
        v = len(base)
        bq = np.rint((base - origin) / quantum).astype(np.int64)
        pq = np.rint((pos - origin) / quantum).astype(np.int64)
        fq = np.rint(frames * FRAME_ONE).astype(np.int64)
        cq = np.clip(np.rint(col * 255), 0, 255).astype(np.int64)
        e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
        e = np.unique(np.sort(e, axis=1), axis=0)
        e = e[e[:, 0] != e[:, 1]]
        both = np.concatenate([e, e[:, ::-1]])
        both = both[np.lexsort((both[:, 1], both[:, 0]))]
        adj_start, adj = _csr(both[:, 0], both[:, 1], v)
        t = np.arange(len(tris))
        keys = np.concatenate([tris[:, 0], tris[:, 1], tris[:, 2]])
        pairs = np.concatenate([tris[:, [1, 2]], tris[:, [2, 0]], tris[:, [0, 1]]])
        tri_of = np.concatenate([t, t, t])
        order = np.lexsort((tri_of, keys))
        fan_start, _ = _csr(keys[order], pairs[order], v)
        fan = pairs[order]
        # walk starts (a hint only: any start gives a deterministic partner, the same on every device)
        from geosynth.core.neighbours import nearest

        cell = float(np.median(norm3(base[e[:, 0]] - base[e[:, 1]])))
        cell = cell if cell > 0 else quantum
        k = np.arange(-STENCIL_K, STENCIL_K + 1) * cell
        a, b = np.meshgrid(k, k, indexing="ij")
        pts = (base[samples, None, :] + a.reshape(1, -1, 1) * frames[samples, None, 0]
               + b.reshape(1, -1, 1) * frames[samples, None, 1])
        stencil = nearest(base, pts.reshape(-1, 3), 1)[1].reshape(len(samples), -1)
        return _Host(bq, fq, pq, cq, usable.copy(), adj_start, adj.astype(np.int32), fan_start, fan.astype(np.int32),
                     samples.astype(np.int32), stencil.astype(np.int32), cell)

    def update(self, ids, displacements, colours=None) -> None:
        """Label vertices textured with their new displacements (and colours).

        Args:
            ids: (n,) vertex ids.
            displacements: (n, 3) world displacements D.
            colours: (n, 3) RGB in [0, 1], or None (keep the stored colours).
        """
        ids = _index_array("ids", np.atleast_1d(ids), self.n_vertices)
        n = len(ids)
        d = _float_array("displacements", np.reshape(displacements, (-1, 3)), (3,), n)
        if colours is not None:
            c = _float_array("colours", np.reshape(colours, (-1, 3)), (3,), n)
            cq = np.clip(np.rint(c * 255), 0, 255).astype(np.int64)
        else:
            cq = self.host.colour[ids]
        pq = np.rint((self.base[ids] + d - self.origin) / self.quantum).astype(np.int64)
        if n == 0:
            return
        self.displacements[ids] = d
        self.host.pos[ids] = pq
        self.host.colour[ids] = cq
        self.labels[ids] = True
        mark = int(self.partners == "textured")
        if mark:
            self.host.usable[ids] = True
        b = self.backend
        b.relief_update(b.to_device(ids.astype(np.int32)), b.to_device(pq.astype(np.int32).reshape(-1)),
                        b.to_device(cq.astype(np.int32).reshape(-1)), n, mark, self.arrays)

    def transfer(self, samples, rotations, targets, n_rotations: int) -> np.ndarray:
        """The displacement each target takes from its match: D(s) in s's frame, rotated
        back by -2 pi r / R about the normal, expressed in t's frame (the inverse of the
        move FindMatches scores).

        Args:
            samples, rotations, targets: (n,) ints (vertex ids, rotation indices).
            n_rotations: R.

        Returns:
            (n, 3) float64 world displacements.
        """
        s = _index_array("samples", np.atleast_1d(samples), self.n_vertices)
        t = _index_array("targets", np.atleast_1d(targets), self.n_vertices)
        r = np.atleast_1d(np.asarray(rotations, np.int64))
        local = np.einsum("nij,nj->ni", self.frames[s], self.displacements[s])  # (du, dv, dn) in s's frame
        c, sn = _cos_sin(r, n_rotations)
        back = np.stack([c * local[:, 0] + sn * local[:, 1], -sn * local[:, 0] + c * local[:, 1], local[:, 2]], 1)
        return np.einsum("nji,nj->ni", self.frames[t], back)

    def candidates(self, stride: int) -> tuple[np.ndarray, DeviceArray]:
        """(slots (k,) int64 positions in samples, the same on the device as int32) of
        every ``stride``-th sample."""
        got = self._cand.get(stride)
        if got is None:
            slots = np.arange(0, len(self.samples), stride)
            got = self._cand[stride] = (slots, self.backend.to_device(slots.astype(np.int32)))
        return got


def _cos_sin(r: np.ndarray, n_rotations: int) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of 2 pi r / R, exact where they are 0 or +-1."""
    a = 2 * np.pi * np.asarray(r, np.float64) / n_rotations
    # the C library's scalar cos and sin, not NumPy's (AVX-512 has its own SIMD ones; issue 40)
    c = np.array([math.cos(x) for x in a.reshape(-1).tolist()]).reshape(a.shape)
    s = np.array([math.sin(x) for x in a.reshape(-1).tolist()]).reshape(a.shape)
    c = np.where(np.abs(c - np.rint(c)) < 1e-12, np.rint(c), c)
    s = np.where(np.abs(s - np.rint(s)) < 1e-12, np.rint(s), s)
    return c, s


def _upload_index(backend, host: _Host):
    from geosynth._backends.interfaces import ReliefIndexArrays

    i32 = np.int32
    up = backend.to_device
    return ReliefIndexArrays(
        base=up(host.base.astype(i32).reshape(-1)), frame=up(host.frame.astype(i32).reshape(-1)),
        pos=up(host.pos.astype(i32).reshape(-1)), colour=up(host.colour.astype(i32).reshape(-1)),
        usable=up(host.usable.astype(i32)), adj_start=up(host.adj_start), adj=up(host.adj),
        fan_start=up(host.fan_start), fan=up(host.fan.reshape(-1)), samples=up(host.samples),
        stencil=up(np.ascontiguousarray(host.stencil.T).reshape(-1)))


@dataclass(frozen=True)
class ReliefQueries:
    """A batch of target neighbourhoods, quantized (see :func:`neighbourhood_queries`).

    Attributes:
        targets: (Q,) int64 target vertex ids.
        qstart: (Q + 1,) int32 first entry of each query.
        entries: (E,) int64 neighbour vertex ids, by decreasing weight within a query.
        rel: (E, R, 6) int32 per rotation: the moved base's and the displacement's
            components in the candidate's frame (quanta).
        chain: (E,) int32 1: the partner walk starts at the previous entry's partner; 0: at s
            (where cell is -1).
        cell: (E, R) int32 stencil cell of the walk's start (-1: outside the stencil).
        colour: (E, 3) int32 0..255; weight: (E,) int32 1..WEIGHT_ONE.
        ks, kc: (Q,) float64 the code's coefficients (docs/relief_match.md).
        rotations: R; mu: shape weight; sigma: Gaussian sigma (world).
    """

    targets: np.ndarray
    qstart: np.ndarray
    entries: np.ndarray
    rel: np.ndarray
    chain: np.ndarray
    cell: np.ndarray
    colour: np.ndarray
    weight: np.ndarray
    ks: np.ndarray
    kc: np.ndarray
    rotations: int
    mu: float
    sigma: float

    @property
    def n_queries(self) -> int:
        return len(self.targets)


def neighbourhood_queries(index: ReliefIndex, targets, nbr_start, nbr, sigma: float, *, rotations: int = 4,
                          mu: float = 0.5) -> ReliefQueries:
    """The textured neighbourhoods of targets, ready to score (Breckon and Fisher, Sec. 3
    and Appendix A: Gaussian weights by distance to the target, the rigid move into a
    sample's frame at R rotations).

    Args:
        index: the triangulation.
        targets: (Q,) target vertex ids.
        nbr_start: (Q + 1,) int; the neighbourhood of targets[q] is
            nbr[nbr_start[q]:nbr_start[q + 1]] (its W-ring, any order; untextured
            vertices and the target itself are dropped here).
        nbr: (N,) int vertex ids.
        sigma: Gaussian sigma, world units (> 0).
        rotations: R >= 1 rotations about the normal (angles 2 pi r / R).
        mu: weight of the shape term in [0, 1] (1: relief only).

    Returns:
        The query batch.

    Raises:
        ValueError: bad shapes or ids, sigma <= 0, R < 1, mu outside [0, 1], a target with
            no textured neighbour.
    """
    v = index.n_vertices
    targets = _index_array("targets", np.atleast_1d(targets), v)
    nbr = _index_array("nbr", nbr, v)
    starts = np.asarray(nbr_start)
    if starts.shape != (len(targets) + 1,) or np.any(np.diff(starts) < 0) or starts[0] != 0 or starts[-1] != len(nbr):
        _fail("nbr_start", f"shape {starts.shape}", f"pass ({len(targets) + 1},) nondecreasing offsets from 0 to {len(nbr)}")
    if not (isinstance(sigma, (int, float, np.floating)) and math.isfinite(sigma) and sigma > 0):
        _fail("sigma", f"{sigma!r}", "pass a positive Gaussian sigma in world units")
    if not (isinstance(rotations, (int, np.integer)) and 1 <= rotations <= 64):
        _fail("rotations", f"{rotations!r}", "pass an integer from 1 to 64")
    if not (math.isfinite(mu) and 0.0 <= mu <= 1.0):
        _fail("mu", f"{mu!r}", "pass a shape weight in [0, 1]")
    q = index.quantum
    tex = index.textured
    c, s = _cos_sin(np.arange(rotations), rotations)
    side = 2 * STENCIL_K + 1
    nq = len(targets)
    if nq == 0:
        _fail("targets", "empty", "pass at least one target")
    # every query at once (one row per entry; qid its query): unique textured neighbours
    qid = np.repeat(np.arange(nq), np.diff(starts).astype(np.int64))
    nb = nbr.astype(np.int64)
    order = np.lexsort((nb, qid))
    qid, nb = qid[order], nb[order]
    first = np.ones(len(nb), bool)
    first[1:] = (qid[1:] != qid[:-1]) | (nb[1:] != nb[:-1])
    keep = first & tex[nb] & (nb != targets[qid])
    qid, nb = qid[keep], nb[keep]
    counts = np.bincount(qid, minlength=nq)
    if np.any(counts == 0):
        bad = int(targets[np.argmax(counts == 0)])
        _fail("targets", f"target {bad} has no textured neighbour", "score only boundary targets")
    qs = np.concatenate([[0], np.cumsum(counts)])
    t_of = targets[qid]
    rel_b = index.base[nb] - index.base[t_of]
    d2 = np.einsum("ij,ij->i", rel_b, rel_b)
    d2min = np.minimum.reduceat(d2, qs[:-1])
    # relative to the largest weight of the query; exp_fixed, not np.exp: AVX-512's rounds otherwise (issue 40)
    w = exp_fixed(-(d2 - d2min[qid]) / (2.0 * sigma * sigma))
    wi = np.maximum(1, np.rint(WEIGHT_ONE * w)).astype(np.int64)
    order = np.lexsort((nb, -wi, qid))  # by decreasing weight, ties by id, within a query
    qid, nb, rel_b, wi, t_of = qid[order], nb[order], rel_b[order], wi[order], t_of[order]
    f = index.frames[t_of]  # (E, 3, 3) rows u, v, n of the target's frame
    o = np.einsum("ekj,ej->ek", f, rel_b) / q  # (E, 3) in t's frame, quanta
    d = np.einsum("ekj,ej->ek", f, index.displacements[nb]) / q
    ro = np.stack([np.outer(o[:, 0], c) - np.outer(o[:, 1], s), np.outer(o[:, 0], s) + np.outer(o[:, 1], c),
                   np.repeat(o[:, 2:3], rotations, 1)], -1)  # (E, R, 3)
    rd = np.stack([np.outer(d[:, 0], c) - np.outer(d[:, 1], s), np.outer(d[:, 0], s) + np.outer(d[:, 1], c),
                   np.repeat(d[:, 2:3], rotations, 1)], -1)
    r6 = np.rint(np.concatenate([ro, rd], -1))
    big = np.abs(r6).max(axis=(1, 2))
    if np.any(big >= 2 ** 24):
        k = int(np.argmax(big >= 2 ** 24))
        _fail("nbr", f"target {int(t_of[k])}'s neighbourhood spans {big[k]:.3g} quanta",
              "pass a smaller window (the neighbourhood must stay within ~8000 edge lengths)")
    cu = np.rint(ro[..., 0] * q / index.host.cell).astype(np.int64)
    cv = np.rint(ro[..., 1] * q / index.host.cell).astype(np.int64)
    inside = (np.abs(cu) <= STENCIL_K) & (np.abs(cv) <= STENCIL_K)
    cells = np.where(inside, (cu + STENCIL_K) * side + cv + STENCIL_K, -1).astype(np.int32)
    chain = np.zeros(len(nb), np.int32)
    if len(nb) > 1:
        step = norm3(o[1:] - o[:-1])
        chain[1:] = (step < norm3(o[1:])) & (qid[1:] == qid[:-1])
    total = np.add.reduceat(wi, qs[:-1]).astype(np.float64)
    ks = mu * SCORE_ONE / (total * index.shape_norm_q2)
    kc = (1.0 - mu) * SCORE_ONE / (total * COLOUR_RANGE2)
    return ReliefQueries(targets=targets, qstart=qs.astype(np.int32), entries=nb, rel=r6.astype(np.int32),
                         chain=chain, cell=cells, colour=index.host.colour[nb].astype(np.int32),
                         weight=wi.astype(np.int32), ks=ks, kc=kc, rotations=int(rotations), mu=float(mu),
                         sigma=float(sigma))


def _upload_queries(backend, queries: ReliefQueries, limits: np.ndarray):
    from geosynth._backends.interfaces import ReliefQueryArrays

    up = backend.to_device
    return ReliefQueryArrays(
        qstart=up(queries.qstart), rel=up(np.ascontiguousarray(queries.rel, np.int32).reshape(-1)),
        chain=up(queries.chain), cell=up(np.ascontiguousarray(queries.cell).reshape(-1)), qcolour=up(queries.colour.reshape(-1)), qweight=up(queries.weight),
        ks=up(queries.ks), kc=up(queries.kc), limit=up(np.asarray(limits, np.int64)))


def _check_limits(limits, n: int) -> np.ndarray:
    if limits is None:
        return np.full(n, CODE_CAP, np.int64)
    lim = np.asarray(limits)
    if lim.shape != (n,) or not np.issubdtype(lim.dtype, np.integer):
        _fail("limits", f"shape {lim.shape}, dtype {lim.dtype}", f"pass ({n},) integer codes or None")
    return np.clip(lim.astype(np.int64), -1, CODE_CAP)


@dataclass(frozen=True)
class ReliefScores:
    """Codes of every (query, candidate, rotation).

    Attributes:
        codes: (Q, S, R) uint32 (SCORE_ONE = an ssd of 1.0; OVER, INVALID special).
    """

    codes: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(Q, S, R) bool: a real score (neither INVALID nor OVER)."""
        return self.codes < OVER

    @property
    def ssd(self) -> np.ndarray:
        """(Q, S, R) float64 normalized ssd, NaN where not valid."""
        return np.where(self.valid, self.codes.astype(np.float64) / SCORE_ONE, np.nan)


def _check_pair(index: ReliefIndex, queries: ReliefQueries) -> None:
    if not isinstance(index, ReliefIndex):
        _fail("index", f"a {type(index).__name__}", "pass a ReliefIndex")
    if not isinstance(queries, ReliefQueries):
        _fail("queries", f"a {type(queries).__name__}", "build them with neighbourhood_queries()")


def _launch(index: ReliefIndex, queries: ReliefQueries, cand: DeviceArray, n_cand: int,
            limits: np.ndarray, uploaded=None, checked: bool = False, rows: bool = False) -> np.ndarray:
    """(Q, n_cand, R) codes. ``cand``: (n_cand,) slots for every query, or with
    ``rows`` (Q * n_cand,) a row per query (-1: none, OVER). ``uploaded``: the
    queries' device arrays from an earlier launch of the same batch (only the limits are
    uploaded again); ``checked``: the memory check was made for at least this many
    candidates."""
    import dataclasses

    from geosynth.core.memory import require

    b = index.backend
    nq, r = queries.n_queries, queries.rotations
    if not checked:
        per_query = 3 * n_cand * r * 4  # the device codes, their host copy and one array the caller derives
        require(nq * per_query, option="queries", value=nq, largest_fn=lambda k: k * per_query,
                what=f"FindMatches codes of {nq} queries x {n_cand} samples x {r}")
    if uploaded is None:
        qa = _upload_queries(b, queries, limits)
    else:
        qa = dataclasses.replace(uploaded, limit=b.to_device(np.asarray(limits, np.int64)))
    out = b.empty((nq * n_cand * r,), np.uint32)
    b.relief_scores(index.arrays, qa, cand, n_cand, n_cand if rows else 0, nq, r, len(index.samples), out)
    return b.to_host(out).reshape(nq, n_cand, r), qa


def score(index: ReliefIndex, queries: ReliefQueries, limits=None, slots=None) -> ReliefScores:
    """FindMatches' scores of every query against candidate samples at every rotation.

    Args:
        index: the triangulation (its device runs the kernel).
        queries: from :func:`neighbourhood_queries` on this index.
        limits: None (full codes) or (Q,) integer codes: a running code above its query's
            limit stops as OVER.
        slots: None (every sample), (k,) int positions in index.samples for every query,
            or (Q, k) a row per query (-1: no candidate, scored OVER).

    Returns:
        :class:`ReliefScores`, codes (Q, S, R) in the order of ``index.samples``, or
        (Q, k, R) in the order of ``slots``.
    """
    _check_pair(index, queries)
    lim = _check_limits(limits, queries.n_queries)
    if slots is None:
        slots, cand = index.candidates(1)
        return ReliefScores(_launch(index, queries, cand, len(slots), lim)[0])
    rows = np.asarray(slots)
    if rows.ndim == 2:
        rows = _slot_rows("slots", rows, queries.n_queries, len(index.samples))
    else:
        rows = _index_array("slots", np.atleast_1d(rows), len(index.samples))
    if rows.shape[-1] == 0:
        return ReliefScores(np.zeros((queries.n_queries, 0, queries.rotations), np.uint32))
    cand = index.backend.to_device(rows.astype(np.int32).reshape(-1))
    return ReliefScores(_launch(index, queries, cand, rows.shape[-1], lim, rows=rows.ndim == 2)[0])


@dataclass(frozen=True)
class Matches:
    """One target's BestMatches (Appendix A), in the order of (slot, rotation).

    Attributes:
        sample: (k,) int64 vertex ids; slot: (k,) int64 positions in index.samples;
        rotation: (k,) int64; code: (k,) uint32; ssd: (k,) float64 (code / SCORE_ONE);
        accepted: (k,) bool (ssd below MaxErrThreshold); best: the smallest ssd (inf
        when no valid match is within the limit).
    """

    sample: np.ndarray
    slot: np.ndarray
    rotation: np.ndarray
    code: np.ndarray
    ssd: np.ndarray
    accepted: np.ndarray
    best: float


def _best(codes: np.ndarray) -> np.ndarray:
    """(Q,) int64 smallest real code of each query, -1 where none."""
    flat = codes.reshape(len(codes), -1)
    m = flat.min(axis=1).astype(np.int64)
    return np.where(m < OVER, m, -1)


def _slot_rows(name: str, a: np.ndarray, n_query: int, n_samples: int) -> np.ndarray:
    """(Q, k) int64 candidate slots a row per query, -1 for none (validated)."""
    if a.ndim != 2 or a.shape[0] != n_query or (a.size and not np.issubdtype(a.dtype, np.integer)):
        _fail(name, f"per-query slots of shape {a.shape}, dtype {a.dtype}",
              f"pass ({n_query}, k) integer positions in index.samples (-1: none), one row per query")
    a = a.astype(np.int64)
    if a.size and (a.min() < -1 or a.max() >= n_samples):
        _fail(name, f"slots outside -1..{n_samples - 1} (min {a.min()}, max {a.max()})",
              "pass positions in index.samples, or -1 for none")
    return a


def _hint_pass(hints, n_query: int, n_samples: int) -> np.ndarray | None:
    """find_matches' hints as one pass: (k,) int64 slots for every query, or (Q, k) a row
    per query (each row's slots first, then -1; trailing columns of -1 dropped); None
    when there is no slot."""
    if hints is None:
        return None
    arr = np.asarray(hints)
    if arr.ndim == 2:
        arr = _slot_rows("hints", arr, n_query, n_samples)
        width = int((arr >= 0).sum(axis=1).max()) if arr.size else 0
        return np.sort(arr, axis=1)[:, ::-1][:, :width] if width else None
    h = np.unique(_index_array("hints", np.atleast_1d(arr), n_samples))
    return h if len(h) else None


def find_matches(index: ReliefIndex, queries: ReliefQueries, max_err: float, tolerance: float = 1.1,
                 probes: tuple[int, ...] | None = None, hints=None, exhaustive: bool = True,
                 around=None, around_best: int = 8) -> list[Matches]:
    """The paper's BestMatches of each query: every (sample, rotation) whose ssd is within
    ``tolerance`` x the best (Breckon and Fisher, Appendix A), found with limits that
    prune nothing that could be selected or accepted.

    A code is selected when code <= floor(tolerance * best) and accepted when
    code < ceil(max_err * SCORE_ONE). Scores above floor(tolerance * (that - 1)) can
    neither, so they are the first limit; probe passes over every k-th sample (k in
    ``probes``) lower it to floor(tolerance * their best) before the full pass. ``hints``
    (candidate slots likely to match, e.g. next to the samples that textured the targets'
    neighbours: the coherence of Ashikhmin's synthesis) are scored first, so that the
    probes and the full pass start from a tight limit. Whatever the hints and probes, the
    result is the unpruned selection: a probe's best is never below the true best.

    Args:
        index, queries: as for :func:`score`.
        max_err: MaxErrThreshold (normalized ssd, > 0).
        tolerance: >= 1 (the paper: 1.1).
        probes: sample strides of the probe passes (default (256, 16) for S >= 4096, (8,)
            for S >= 256, none below; measured on 12,769 samples: 25-30% less work than
            (64, 8)).
        hints: None, (k,) int slots (positions in index.samples) scored on every query
            of the batch before the probes, or (Q, k) int slots a row per query (-1:
            none; each query scored against its own row only).
        exhaustive: True (the paper): the full pass over every sample decides. False (our
            option for large captures, :data:`geosynth.completion.synthesis.SEARCHES`): the
            selection is made among the hints and the probe strides only, with the same
            rules; no full pass. Needs hints or probes.
        around: with ``exhaustive=False``, None or a function from (Q, m) int64 slots (-1:
            none) to (Q, k) int64 slot rows (-1: none): the candidates near each query's
            ``around_best`` best slots found by the hints and probes, scored in one more pass
            before the selection (a coarse-to-fine search: the probes find the right region,
            this pass the best candidate in it).

    Returns:
        One :class:`Matches` per query; empty arrays when nothing can be accepted.
    """
    _check_pair(index, queries)
    if not (math.isfinite(max_err) and max_err > 0):
        _fail("max_err", f"{max_err!r}", "pass a positive MaxErrThreshold")
    if not (math.isfinite(tolerance) and tolerance >= 1):
        _fail("tolerance", f"{tolerance!r}", "pass a tolerance >= 1 (the paper: 1.1)")
    n_s = len(index.samples)
    if probes is None:
        probes = (256, 16) if n_s >= 4096 else (8,) if n_s >= 256 else ()
    accept = int(math.ceil(max_err * SCORE_ONE))
    nq = queries.n_queries
    lim = np.full(nq, min(int(math.floor(tolerance * (accept - 1))), CODE_CAP), np.int64)
    passes = []
    hinted = _hint_pass(hints, nq, n_s)
    if hinted is not None:
        passes.append((hinted, index.backend.to_device(hinted.astype(np.int32).reshape(-1)), hinted.ndim == 2))
    for stride in probes:
        slots, cand = index.candidates(stride)
        passes.append((slots, cand, False))
    if not exhaustive and not passes:
        _fail("exhaustive", "False without hints or probes", "pass hints or probe strides, or exhaustive=True")
    from geosynth.core.memory import require  # one memory check, for the largest pass

    widest = len(index.samples) if exhaustive else max(p[0].shape[-1] for p in passes)
    per_query = 3 * widest * queries.rotations * 4
    require(nq * per_query, option="queries", value=nq, largest_fn=lambda k: k * per_query,
            what=f"FindMatches codes of {nq} queries x {widest} samples x {queries.rotations}")
    qa = None
    scored = []  # (slots, codes) of every pass, for the selection without a full pass
    for pslots, pcand, by_row in passes:
        pc, qa = _launch(index, queries, pcand, pslots.shape[-1], lim, uploaded=qa, checked=True, rows=by_row)
        scored.append((pslots, pc))
        best = _best(pc)
        lim = np.where(best >= 0, np.minimum(lim, np.floor(tolerance * np.maximum(best, 0)).astype(np.int64)), lim)
    if exhaustive:
        slots, cand = index.candidates(1)
        codes, _ = _launch(index, queries, cand, len(slots), lim, uploaded=qa, checked=True)
        rows = [(slots, codes[i]) for i in range(nq)]
    else:
        rows = [_merged_row([(s[i] if s.ndim == 2 else s, c[i]) for s, c in scored]) for i in range(nq)]
        if around is not None and around_best > 0:
            best_slots = np.full((nq, around_best), -1, np.int64)
            for i, (sl, cs) in enumerate(rows):
                per_slot = cs.min(axis=1) if cs.size else cs.reshape(0)
                real = np.flatnonzero(per_slot < OVER)
                top = real[np.argsort(per_slot[real], kind="stable")[:around_best]]
                best_slots[i, :len(top)] = sl[top]
            near = _slot_rows("around's rows", np.asarray(around(best_slots)), nq, n_s)
            if near.shape[1] and (near >= 0).any():
                pc, qa = _launch(index, queries, index.backend.to_device(near.astype(np.int32).reshape(-1)),
                                 near.shape[1], lim, uploaded=qa, rows=True)
                rows = [_merged_row([rows[i], (near[i], pc[i])]) for i in range(nq)]
    out = []
    for i, (row_slots, codes) in enumerate(rows):
        bi = int(_best(codes[None])[0])
        if bi < 0 or bi >= accept:
            e = np.zeros(0, np.int64)
            out.append(Matches(e, e, e, np.zeros(0, np.uint32), np.zeros(0), np.zeros(0, bool),
                               bi / SCORE_ONE if bi >= 0 else math.inf))
            continue
        sel_s, sel_r = np.nonzero(codes <= math.floor(tolerance * bi))
        code = codes[sel_s, sel_r]
        sel = row_slots[sel_s].astype(np.int64)
        out.append(Matches(index.samples[sel], sel, sel_r.astype(np.int64), code,
                           code / SCORE_ONE, code < accept, bi / SCORE_ONE))
    return out


def _merged_row(parts: list) -> tuple[np.ndarray, np.ndarray]:
    """One query's (slots (k,), codes (k, R)) from its passes' (slots, codes) parts, each slot
    once, in slot order (a slot scored in two passes has the same code in both; -1 slots
    dropped)."""
    sl = np.concatenate([s for s, _ in parts])
    cs = np.concatenate([c for _, c in parts])
    keep = sl >= 0
    sl, first = np.unique(sl[keep], return_index=True)
    return sl, cs[keep][first]
