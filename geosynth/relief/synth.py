"""How does the relief grow over the mesh's own surface? M4's surface growth (Breckon and Fisher,
"3D Surface Relief and Colour Completion", Sec. 3 and Appendix A: GrowSurface and FindMatches)
with the example as the capture and the refined mesh's vertices as the targets.

One triangulation holds both (the M4 kernels' :class:`geosynth.relief_match.ReliefIndex`):

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

M4's own growth helpers are reused by name (``geosynth.completion``'s classes, hint table and
batched FindMatches call), so that the two growths cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from geosynth.relief.examples import ReliefExample

__all__ = ["SynthResult", "WINDOW", "synthesize"]

WINDOW = 3  # W-ring neighbourhoods (37 vertices on a regular mesh; M4 chooses 3 to 5 from the period)
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
    """

    heights: np.ndarray
    colours: np.ndarray | None
    source: np.ndarray
    stats: dict


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
               search: str = "auto", progress: bool = True) -> SynthResult:
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

    Returns:
        :class:`SynthResult`.
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    from geosynth import completion as m4
    from geosynth import relief_match as rm
    from geosynth.relief_prep import ring_neighbourhoods

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
    w_t = np.full(nv, window, np.int64)
    sigmas = {w: (2 * w + 1) * s / 6.4 for w in range(1, window + 1)}  # M4's Gaussian (complete_surface)
    picked = np.full(ne + nv, -1, np.int64)
    heights = np.zeros(ne + nv)
    heights[:ne] = eh_flat
    colours = None if ecol is None else np.zeros((ne + nv, 3), np.uint8)
    if colours is not None:
        colours[:ne] = ecol.reshape(-1, 3)

    def copy(at: np.ndarray, src: np.ndarray) -> None:
        heights[at] = heights[src]
        picked[at] = src
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
        patch = np.concatenate([[ne + sv], ids[ptr[0]:ptr[1]]])
        rel = base[patch] - base[ne + sv]
        x = np.rint(rel @ fr[ne + sv, 0] / s).astype(np.int64)
        y = np.rint(rel @ fr[ne + sv, 1] / s).astype(np.int64)
        src = np.clip(ci + y, 0, hp - 1) * wp + np.clip(cj + x, 0, wp - 1)
        copy(patch, src)
        textured[patch] = True
        seeds.append(sv)

    rs = SimpleNamespace(n_samples=ne, n_vertices=ne + nv, adjacency=all_adj)  # what M4's hint table reads
    hints = m4._HintTable(rs, index) if m4.HINT_RINGS > 0 else None
    per_launch = max(1, min(m4._MAX_BATCH, m4._BATCH_CODES // max(1, len(candidates) * rotations)))
    accept_all = rm.CODE_CAP / rm.SCORE_ONE
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
                for cls in m4._classes(members, w_t, ring_ptr, ring_idx, ring_d, slot_of):
                    for start in range(0, len(cls), per_launch):
                        chunk = cls[start:start + per_launch]
                        got = m4._match_chunk(rs, index, rm, chunk, w_t, slot_of, ring_ptr, ring_idx, ring_d,
                                              sigmas, rotations, mu, accept_all, hints, picked, textured,
                                              m4.TOLERANCE, chosen)
                        stats["launches"] += 1
                        at, src = [], []
                        for t, m in zip(chunk, got):  # picks in list order, one draw per target
                            if len(m.sample) == 0:
                                stats["failed"] += 1
                                w_t[slot_of[t]] = max(1, w_t[slot_of[t]] - 1)
                                continue
                            j = int(rng.integers(len(m.sample)))
                            at.append(int(t))
                            src.append(int(m.sample[j]))
                        if at:
                            at_a = np.asarray(at, np.int64)
                            copy(at_a, np.asarray(src, np.int64))
                            textured[at_a] = True
                            if bar is not None:
                                bar.update(len(at_a))
            if int(textured.sum()) == before and not shrinkable:
                break  # no valid match even with 1-ring neighbourhoods: the rest stays bare (counted)
    finally:
        if bar is not None:
            bar.close()
    stats["unreached"] = int((~textured[ne:]).sum())
    src_cells = np.where(picked[ne:] >= 0, ecell.ravel()[np.maximum(picked[ne:], 0)], -1)
    return SynthResult(heights[ne:].copy(), None if colours is None else colours[ne:].copy(), src_cells, stats)
