"""How does the relief grow over the mesh's own surface? M4's surface growth (Breckon and Fisher,
"3D Surface Relief and Colour Completion", Sec. 3 and Appendix A: GrowSurface and FindMatches)
with the example as the capture and the refined mesh's vertices as the targets.

One triangulation holds both (the M4 kernels' :class:`geosynth.completion.matching.ReliefIndex`):

- the example's cells (wrapped by ``window + 2`` cells on every side when it tiles) as a regular
  grid of samples on a plane set beside the mesh: base = the cell's position, normal up, frame
  (x, y, up), displacement = height x up, the cell's colour. Every example vertex is a partner
  (``partners=ids``); the candidates are the cells at least ``window + 1`` cells inside its border
  (all the original cells of a tiling example), so that every candidate has a whole neighbourhood;
- the mesh's vertices: base = the vertex, normal = the smoothed normal, frame = the tangent field
  (:mod:`geosynth.relief.orient`), displacement 0 until textured; its edges as the triangulation.

Growth (as :func:`geosynth.completion.complete_surface` grows from the capture's border): a seed
per connected component (a vertex drawn with the seed, its ``window``-ring given the heights of
a drawn place of the example laid along its frame), then boundary lists: untextured vertices with a
textured edge neighbour, by decreasing textured count in their W-ring, split into classes of
vertices outside each other's windows (one launch each, the same result as one at a time);
FindMatches' matches within 1.1x the best over every candidate x R rotations (the M4 kernels, the
same integer codes on every device), one drawn with the seeded generator; the target copies that
sample's height (along its own normal) and colour. Every match is accepted (MaxErrThreshold off:
the example always holds a whole neighbourhood, so a rejected target would only wait for the same
candidates), which keeps one pass per list. Same seed, same bytes on every device.

The growth's steps follow :func:`geosynth.completion.complete_surface`'s (its public constants:
the 1.1x tolerance, the coherent search's 128 probes and 4 best); the coherence hints are simpler
here, because the example is a regular grid: the candidates within 2 cells (rows and columns) of
the cells the target's textured neighbours copied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geosynth.relief.examples import ReliefExample

__all__ = ["SynthResult", "WINDOW", "synthesize"]

HINT_CELLS = 2  # coherence hints: the candidates within 2 rows and columns of a neighbour's source cell
REACH = 1.5  # W-rings are cut at 1.5 (W + 1) cells (edges reach 1.4 cells: an even mesh loses none; see _within)
WINDOW = 3  # W-ring neighbourhoods (37 vertices on a regular mesh; M4 chooses 3 to 5 from the period)
_MAX_BATCH = 64  # targets per launch at most (as M4's growth)
_BATCH_CODES = 1 << 25  # codes (Q x S x R) one launch may hold at most
MU_COLOUR = 0.7  # shape weight with colours: a printed relief is judged by its shape first


@dataclass
class SynthResult:
    """The synthesis' result on the mesh.

    Attributes:
        heights: (V,) float64 heights along the normals, world units (0 where unreached).
        colours: (V, 3) uint8 or None.
        source: (V,) int64 the example cell (row-major index into the example's grid) each vertex
            copied, -1 where unreached.
        stats: lists, launches, seeds, unreached count, search and its reason.
        place: (V, 2) float64 each vertex's place in the example (column, row; fractional cells of the
            example's grid, unpadded), what :func:`geosynth.relief.transfer.transfer` continues.
        rotation: (V,) int64 the rotation each vertex's copy was matched at (angle 2 pi r / R).
    """

    heights: np.ndarray
    colours: np.ndarray | None
    source: np.ndarray
    stats: dict
    place: np.ndarray | None = None
    rotation: np.ndarray | None = None


def _grid_faces(h: int, w: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(h - 1), np.arange(w - 1), indexing="ij")
    a = (i * w + j).ravel()
    b, c, d = a + 1, a + w + 1, a + w
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)


def _padded(example: ReliefExample, pad: int):
    """(heights (Hp, Wp), colours or None, cell (Hp, Wp) row-major index of the original cell each
    padded cell shows, candidate mask (Hp, Wp))."""
    h, w = example.shape
    if example.periodic:
        iy = np.arange(-pad, h + pad) % h
        ix = np.arange(-pad, w + pad) % w
        yy, xx = np.meshgrid(iy, ix, indexing="ij")
        inner = np.zeros(yy.shape, bool)
        inner[pad:pad + h, pad:pad + w] = True
    else:
        yy, xx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        inner = np.zeros((h, w), bool)
        inner[pad:h - pad, pad:w - pad] = True
        if not inner.any():
            raise ValueError(f"the example is {w} x {h} cells at the mesh's spacing, too small for neighbourhoods of "
                             f"{pad - 1} rings; give a larger example or a finer --resolution.")
    heights = example.heights[yy, xx]
    colours = None if example.colours is None else example.colours[yy, xx]
    return heights, colours, (yy * w + xx), inner


class _FlatQueries:
    """M4's FindMatches calls with each target's neighbourhood laid flat on its tangent plane.

    The M4 kernels move a target's neighbours (their base positions relative to the target, in its
    frame) into a candidate's frame. In M4 samples and targets lie on one fitted surface, so both
    neighbourhoods bend alike; here the example is a plane and the mesh is curved, and a W-ring of
    radius W s on a surface of radius R sags by (W s)^2 / 2R below the tangent plane: on a unit
    sphere with s = 0.16 and W = 3, 0.115, six times a 0.02-deep relief, and the matches copied
    the tops whose surroundings looked lowest (the relief's amplitude came out 54% low). So the
    moved base's normal component (``rel[..., 2]``, the same for every rotation) is set to 0:
    each neighbour keeps its tangent-plane offset and its height; host arithmetic on the integer
    queries, so every device still gets the same input. ``find_matches`` is M4's own."""

    def __init__(self, rm):
        self.find_matches = rm.find_matches
        self._queries = rm.neighbourhood_queries

    def neighbourhood_queries(self, *args, **kwargs):
        import dataclasses

        q = self._queries(*args, **kwargs)
        rel = q.rel.copy()
        rel[..., 2] = 0
        return dataclasses.replace(q, rel=rel)


class _Classes:
    """Greedy colouring, in id order, of targets none of which lies in another's window: a class is
    scored in one launch with the same result as one target at a time (as M4's growth does)."""

    @staticmethod
    def split(members: np.ndarray, w_t, ring_ptr, ring_idx, ring_d, slot_of) -> list[np.ndarray]:
        colour: dict[int, int] = {}
        classes: list[list[int]] = []
        for t in np.sort(members).tolist():
            k = slot_of[t]
            lo, hi = ring_ptr[k], ring_ptr[k + 1]
            banned = set()
            for a, d in zip(ring_idx[lo:hi].tolist(), ring_d[lo:hi].tolist()):
                c = colour.get(a)
                if c is not None and d <= max(w_t[k], w_t[slot_of[a]]):
                    banned.add(c)
            c = 0
            while c in banned:
                c += 1
            colour[t] = c
            if c == len(classes):
                classes.append([])
            classes[c].append(t)
        return [np.asarray(c, np.int64) for c in classes]


class _GridHints:
    """Coherence hints on the example's grid (Ashikhmin's idea, as M4's growth uses it): a target
    next to a vertex that copied cell x likely matches near x. Only a tighter pruning limit for
    the exhaustive search (never a different match); the coherent search picks among them."""

    def __init__(self, shape: tuple[int, int], candidates: np.ndarray, n_example: int, adj_all):
        self.h, self.w = shape
        self.slot = np.full(n_example, -1, np.int64)
        self.slot[candidates] = np.arange(len(candidates))
        self.candidates = candidates
        self.n = n_example
        self.adj = adj_all
        d = np.arange(-HINT_CELLS, HINT_CELLS + 1)
        dy, dx = np.meshgrid(d, d, indexing="ij")
        self.dy, self.dx = dy.ravel(), dx.ravel()

    def _near(self, row: np.ndarray, cells: np.ndarray, n_rows: int) -> np.ndarray:
        """(n_rows, k) int64 candidate slots within HINT_CELLS of each cells[i] for row[i], each once, ascending,
        padded with -1."""
        r = cells[:, None] // self.w + self.dy[None, :]
        c = cells[:, None] % self.w + self.dx[None, :]
        ok = (r >= 0) & (r < self.h) & (c >= 0) & (c < self.w)
        slots = np.where(ok, self.slot[np.clip(r * self.w + c, 0, self.n - 1)], -1)
        pairs = np.stack([np.repeat(row, slots.shape[1]), slots.ravel()], 1)
        pairs = np.unique(pairs[pairs[:, 1] >= 0], axis=0)
        if len(pairs) == 0:
            return np.full((n_rows, 0), -1, np.int64)
        counts = np.bincount(pairs[:, 0], minlength=n_rows)
        col = np.arange(len(pairs)) - np.repeat(np.cumsum(counts) - counts, counts)
        grid = np.full((n_rows, int(counts.max())), -1, np.int64)
        grid[pairs[:, 0], col] = pairs[:, 1]
        return grid

    def for_targets(self, chunk: np.ndarray, picked: np.ndarray, textured: np.ndarray) -> np.ndarray | None:
        indptr, indices = self.adj
        deg = indptr[chunk + 1] - indptr[chunk]
        row = np.repeat(np.arange(len(chunk)), deg)
        nb = indices[np.repeat(indptr[chunk] - np.cumsum(deg) + deg, deg) + np.arange(int(deg.sum()))]
        src = picked[nb]
        keep = textured[nb] & (src >= 0)
        return None if not keep.any() else self._near(row[keep], src[keep], len(chunk))

    def around(self, index, best: np.ndarray) -> np.ndarray:  # index: match_chunk's signature (unused here)
        q, m = best.shape
        row = np.repeat(np.arange(q), m)
        flat = best.reshape(-1)
        keep = flat >= 0
        if not keep.any():
            return np.full((q, 0), -1, np.int64)
        return self._near(row[keep], self.candidates[flat[keep]], q)


def _match(index, flat, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d, sigmas, rotations, mu, err, hints,
           picked, textured, search):
    """FindMatches for a chunk of one class, one launch per window size; matches in chunk order:
    :func:`geosynth.completion.synthesis.match_chunk` with the flattened queries (no hint probes)."""
    from geosynth.completion import synthesis as m4

    return m4.match_chunk(None, index, flat, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d, sigmas, rotations, mu,
                          err, hints=hints, picked=picked, textured=textured, tolerance=m4.TOLERANCE, search=search,
                          hint_probes=())


def _within(ptr, idx, ring, rows, base, reach: float):
    """The W-ring lists (CSR ptr, idx, ring) without the entries farther than ``reach`` from their row's
    vertex. Refining a sliver by bisection (a cylinder's side faces, as tall as the cylinder) leaves fans:
    an input vertex joined by edges to vertices all along the old long edge, so a 1-ring can span the
    whole height, and such neighbourhoods were matched as if they were a few cells across (a cylinder's
    cobbles came out as streaks and bands)."""
    own = np.repeat(rows, np.diff(ptr))
    keep = np.linalg.norm(base[idx] - base[own], axis=1) <= reach
    counts = np.add.reduceat(keep.astype(np.int64), ptr[:-1]) if len(idx) else np.zeros(len(rows), np.int64)
    counts[np.diff(ptr) == 0] = 0
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), idx[keep], ring[keep]


def _counts(textured: np.ndarray, slots: np.ndarray, ring_ptr, ring_idx, ring_d, w_t) -> np.ndarray:
    """(len(slots),) textured vertices in each slot's W_t-ring (vectorized over the rows)."""
    lo, hi = ring_ptr[slots], ring_ptr[slots + 1]
    n = hi - lo
    at = np.repeat(lo - np.cumsum(n) + n, n) + np.arange(int(n.sum()))
    row = np.repeat(np.arange(len(slots)), n)
    ok = textured[ring_idx[at]] & (ring_d[at] <= w_t[slots][row])
    return np.bincount(row[ok], minlength=len(slots)).astype(np.int64)


def synthesize(example: ReliefExample, vertices: np.ndarray, faces: np.ndarray, adj, normals: np.ndarray,
               frames: np.ndarray, rotations: int, *, window: int = WINDOW, seed: int = 0, device: str | None = None,
               search: str = "auto", progress: bool = True, refine: int = 0, coherence: bool = False) -> SynthResult:
    """Grow the example's relief and colour over a mesh (module docstring; the paper's Appendix A).

    Args:
        example: the relief at the mesh's spacing (its cells about as far apart as the mesh's edges).
        vertices: (V, 3) float64 refined mesh; faces: (F, 3) int64; adj: its edges' CSR
            (indptr (V+1,), indices), int64.
        normals: (V, 3) unit float64 smoothed normals; frames: (V, 3, 3) float64 rows u, v, n (n = the
            normal) from :func:`geosynth.relief.orient.tangent_frames`.
        rotations: R, the turns about the normal tried (angles 2 pi r / R).
        window: W, the neighbourhoods' edge rings (>= 1).
        seed: the seed of every draw (seeds' places and the picks among matches).
        device: a device string (geosynth.devices()) or None (auto).
        search: "auto", "exhaustive" or "coherent" (:func:`geosynth.completion.choose_search`).
        progress: a tqdm bar over the vertices.
        refine: passes after the growth that match every vertex again against its whole window, textured
            on every side by then (M4's ``refine``, Wei and Levoy's two-pass idea), in the growth's
            class order, with the same pick rule.
        coherence: prefer, among the matches within 1.1x the best, one that continues a neighbour's
            copy (an experiment, off by default: on a flat box the cobbles looked no better than with the
            paper's uniform draw, on the vase and the knot they came out stretched along the growth).

    Returns:
        :class:`SynthResult`.
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    from geosynth.completion import synthesis as m4
    from geosynth.completion import matching as rm
    from geosynth.completion.prep import ring_neighbourhoods

    v = np.asarray(vertices, np.float64)
    nv = len(v)
    rng = np.random.default_rng(int(seed))
    pad = window + 2
    eh, ecol, ecell, inner = _padded(example, pad)
    hp, wp = eh.shape
    ne = hp * wp
    s = example.spacing
    # the example's plane beside the mesh (its partner walks and stencils never reach the mesh)
    lo, hi = v.min(0), v.max(0)
    corner = np.array([hi[0] + 4 * pad * s + 0.1 * (hi - lo).max(), lo[1], lo[2]])
    yy, xx = np.meshgrid(np.arange(hp), np.arange(wp), indexing="ij")
    ebase = corner + np.stack([xx.ravel() * s, yy.ravel() * s, np.zeros(ne)], 1)
    eh_flat = eh.ravel()
    up = np.tile([0.0, 0.0, 1.0], (ne, 1))
    base = np.concatenate([ebase, v])
    nrm = np.concatenate([up, normals])
    fr = np.concatenate([np.tile(np.eye(3), (ne, 1, 1)), frames])
    disp = np.zeros_like(base)
    disp[:ne, 2] = eh_flat
    textured = np.zeros(ne + nv, bool)
    textured[:ne] = True
    tris = np.concatenate([_grid_faces(hp, wp), np.asarray(faces, np.int64) + ne])
    cols01 = None
    if ecol is not None:
        cols01 = np.zeros((ne + nv, 3))
        cols01[:ne] = ecol.reshape(-1, 3) / 255.0
    mu = 1.0 if ecol is None else MU_COLOUR
    candidates = np.flatnonzero(inner.ravel())
    index = rm.ReliefIndex.build(base, nrm, disp, textured, tris, candidates, colours=cols01,
                                 partners=np.arange(ne), frames=fr, device=device or "auto")
    chosen, why = m4.choose_search(search, nv, len(candidates), rotations)

    # one CSR over both parts (the example's grid and the mesh's edges)
    indptr, indices = adj
    grid_e = _grid_faces(hp, wp)
    ge = np.concatenate([grid_e[:, [0, 1]], grid_e[:, [1, 2]], grid_e[:, [2, 0]]])
    a_e = sparse.csr_matrix((np.ones(2 * len(ge), np.int8), (np.concatenate([ge[:, 0], ge[:, 1]]),
                                                             np.concatenate([ge[:, 1], ge[:, 0]]))), shape=(ne, ne))
    a_e.sum_duplicates()
    a_m = sparse.csr_matrix((np.ones(len(indices), np.int8), indices, indptr), shape=(nv, nv))
    a_all = sparse.block_diag([a_e, a_m], format="csr")
    a_all.sort_indices()
    all_adj = (a_all.indptr.astype(np.int64), a_all.indices.astype(np.int64))

    targets = np.arange(ne, ne + nv, dtype=np.int64)
    slot_of = np.full(ne + nv, -1, np.int64)
    slot_of[targets] = np.arange(nv)
    ring_ptr, ring_idx, ring_d = ring_neighbourhoods(all_adj, targets, window)
    ring_ptr, ring_idx, ring_d = _within(ring_ptr, ring_idx, ring_d, targets, base, REACH * (window + 1) * s)
    w_t = np.full(nv, window, np.int64)
    sigmas = {w: (2 * w + 1) * s / 6.4 for w in range(1, window + 1)}  # M4's Gaussian (complete_surface)
    picked = np.full(ne + nv, -1, np.int64)
    heights = np.zeros(ne + nv)
    heights[:ne] = eh_flat
    colours = None if ecol is None else np.zeros((ne + nv, 3), np.uint8)
    if colours is not None:
        colours[:ne] = ecol.reshape(-1, 3)

    picked_rot = np.zeros(ne + nv, np.int64)
    angle = 2 * np.pi * np.arange(rotations) / rotations
    cos_r = np.array([math.cos(a) for a in angle.tolist()])  # scalar libm: the same on every CPU
    sin_r = np.array([math.sin(a) for a in angle.tolist()])
    cos_r[np.abs(cos_r - np.rint(cos_r)) < 1e-12] = np.rint(cos_r[np.abs(cos_r - np.rint(cos_r)) < 1e-12])
    sin_r[np.abs(sin_r - np.rint(sin_r)) < 1e-12] = np.rint(sin_r[np.abs(sin_r - np.rint(sin_r)) < 1e-12])
    inner_flat = inner.ravel()
    a_ptr, a_idx = all_adj

    # each copied vertex's place in the example, in fractional cells (column, row): a coherent copy
    # continues its neighbour's place by the exact offset, so that the rounding to cells does not add up
    # (a mesh edge of 0.45 cells rounded to 0 copied a cell twice, and the cobbles stretched along a tube)
    place = np.zeros((ne + nv, 2))
    place[:ne] = np.stack([np.arange(ne) % wp, np.arange(ne) // wp], 1)

    def coherent(t: int):
        """(cells (k,), rotations (k,), places (k, 2)): the continuations of t's textured edge
        neighbours' copies: the place at t's offset from the neighbour (in t's frame, turned by the
        neighbour's rotation) from the neighbour's place (Ashikhmin's coherent candidates)."""
        nb = a_idx[a_ptr[t]:a_ptr[t + 1]]
        nb = nb[textured[nb] & (picked[nb] >= 0)]
        if len(nb) == 0:
            return None
        d = base[t] - base[nb]
        # the offset in each neighbour's own frame (its rotation maps that frame to the example's): a line
        # field's frames (R = 2) may turn by 180 degrees from one vertex to the next, and the offset read in
        # t's frame then pointed back through the example (the place never advanced)
        dx, dy = np.einsum("ij,ij->i", d, fr[nb, 0]), np.einsum("ij,ij->i", d, fr[nb, 1])
        r = picked_rot[nb]
        pl = place[nb] + np.stack([(dx * cos_r[r] - dy * sin_r[r]) / s, (dx * sin_r[r] + dy * cos_r[r]) / s], 1)
        col, row = np.rint(pl[:, 0]).astype(np.int64), np.rint(pl[:, 1]).astype(np.int64)
        cell = row * wp + col
        ok = (row >= 0) & (row < hp) & (col >= 0) & (col < wp)
        ok[ok] = inner_flat[cell[ok]]
        return (cell[ok], r[ok], pl[ok]) if ok.any() else None

    def choose(t: int, m) -> tuple[int, np.ndarray]:
        """(the match t copies, its place): among the matches within 1.1x the best, the coherent one with
        the lowest code when there is one (so that features are copied whole and end where the
        example's end: with the paper's uniform draw, the flat tops of the cobbles ran on along a
        knot's tube), placed at the mean of the continuations that name it; else the paper's seeded
        uniform draw, placed at its cell."""
        if coherence:
            got = coherent(int(t))
            if got is not None:
                cells, rots, pls = got
                pairs = set(zip(cells.tolist(), rots.tolist()))
                hit = [k for k in range(len(m.sample)) if (int(m.sample[k]), int(m.rotation[k])) in pairs]
                if hit:
                    k = min(hit, key=lambda k: (int(m.code[k]), k))
                    same = (cells == m.sample[k]) & (rots == m.rotation[k])
                    return k, pls[same].mean(0)
        k = int(rng.integers(len(m.sample)))
        return k, place[int(m.sample[k])]

    def copy(at: np.ndarray, src: np.ndarray, rot: np.ndarray | None = None, where: np.ndarray | None = None) -> None:
        heights[at] = heights[src]
        picked[at] = src
        picked_rot[at] = 0 if rot is None else rot
        place[at] = place[src] if where is None else where
        col = None
        if colours is not None:
            colours[at] = colours[src]
            col = colours[at] / 255.0
        index.update(at, heights[at][:, None] * nrm[at], col)

    # seeds: one per connected component, its W-ring laid from a drawn place of the example
    n_comp, label = connected_components(a_m, directed=False)
    seeds = []
    inner_cells = np.flatnonzero(inner.ravel())
    for c in range(n_comp):
        members = np.flatnonzero(label == c)
        sv = int(members[rng.integers(len(members))])
        at0 = int(inner_cells[rng.integers(len(inner_cells))])
        ci, cj = divmod(at0, wp)
        ptr, ids, _ = ring_neighbourhoods(all_adj, np.array([ne + sv]), window)
        ids = ids[ptr[0]:ptr[1]]
        ids = ids[np.linalg.norm(base[ids] - base[ne + sv], axis=1) <= REACH * (window + 1) * s]
        patch = np.concatenate([[ne + sv], ids])
        rel = base[patch] - base[ne + sv]
        x = np.rint(rel @ fr[ne + sv, 0] / s).astype(np.int64)
        y = np.rint(rel @ fr[ne + sv, 1] / s).astype(np.int64)
        src = np.clip(ci + y, 0, hp - 1) * wp + np.clip(cj + x, 0, wp - 1)
        copy(patch, src)
        textured[patch] = True
        seeds.append(sv)

    hints = _GridHints((hp, wp), candidates, ne, all_adj)
    per_launch = max(1, min(_MAX_BATCH, _BATCH_CODES // max(1, len(candidates) * rotations)))
    accept_all = rm.CODE_CAP / rm.SCORE_ONE
    flat = _FlatQueries(rm)
    stats = dict(lists=0, launches=0, seeds=len(seeds), failed=0, search=chosen, search_why=why)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=nv, initial=int(textured[ne:].sum()), unit="vertex", desc="relief", leave=False)
    a_all_f = a_all.astype(np.int32)
    try:
        while True:
            left = targets[~textured[targets]]
            if len(left) == 0:
                break
            has = (a_all_f[left] @ textured.astype(np.int32)) > 0
            boundary = left[has]
            if len(boundary) == 0:
                break  # the rest is unreachable (cannot happen: every component has a seed)
            stats["lists"] += 1
            before = int(textured.sum())
            shrinkable = bool((w_t[slot_of[boundary]] > 1).any())
            counts = _counts(textured, slot_of[boundary], ring_ptr, ring_idx, ring_d, w_t)
            for level in np.unique(counts)[::-1]:
                members = boundary[counts == level]
                for cls in _Classes.split(members, w_t, ring_ptr, ring_idx, ring_d, slot_of):
                    for start in range(0, len(cls), per_launch):
                        chunk = cls[start:start + per_launch]
                        got = _match(index, flat, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d, sigmas,
                                     rotations, mu, accept_all, hints, picked, textured, chosen)
                        stats["launches"] += 1
                        at, src, rot, where = [], [], [], []
                        for t, m in zip(chunk, got):  # picks in list order, one draw per target
                            if len(m.sample) == 0:
                                stats["failed"] += 1
                                w_t[slot_of[t]] = max(1, w_t[slot_of[t]] - 1)
                                continue
                            j, pl = choose(t, m)
                            at.append(int(t))
                            src.append(int(m.sample[j]))
                            rot.append(int(m.rotation[j]))
                            where.append(pl)
                        if at:
                            at_a = np.asarray(at, np.int64)
                            copy(at_a, np.asarray(src, np.int64), np.asarray(rot, np.int64), np.asarray(where))
                            textured[at_a] = True
                            if bar is not None:
                                bar.update(len(at_a))
            if int(textured.sum()) == before and not shrinkable:
                break  # no valid match even with 1-ring neighbourhoods: the rest stays bare (counted)
    finally:
        if bar is not None:
            bar.close()
    stats["refined"] = 0
    for _ in range(int(refine)):
        todo = targets[textured[targets]]
        for cls in _Classes.split(todo, w_t, ring_ptr, ring_idx, ring_d, slot_of):
            for start in range(0, len(cls), per_launch):
                chunk = cls[start:start + per_launch]
                got = _match(index, flat, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d, sigmas, rotations, mu,
                             accept_all, hints, picked, textured, chosen)
                stats["launches"] += 1
                at, src, rot, where = [], [], [], []
                for t, m in zip(chunk, got):
                    if len(m.sample):
                        j, pl = choose(t, m)
                        stats["refined"] += int(m.sample[j] != picked[t])
                        at.append(int(t))
                        src.append(int(m.sample[j]))
                        rot.append(int(m.rotation[j]))
                        where.append(pl)
                if at:
                    copy(np.asarray(at, np.int64), np.asarray(src, np.int64), np.asarray(rot, np.int64),
                         np.asarray(where))
    stats["unreached"] = int((~textured[ne:]).sum())
    src_cells = np.where(picked[ne:] >= 0, ecell.ravel()[np.maximum(picked[ne:], 0)], -1)
    out_place = place[ne:] - (pad if example.periodic else 0)
    return SynthResult(heights[ne:].copy(), None if colours is None else colours[ne:].copy(), src_cells, stats,
                       out_place, picked_rot[ne:].copy())
