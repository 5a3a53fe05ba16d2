"""How does a fine mesh get the relief the coarse synthesis chose? Each coarse vertex holds a place in
the example (fractional cells, column and row) and a rotation; a fine vertex lying in a coarse face
reads the example at each of the face's three corners' predictions (the corner's place plus the fine
vertex's offset from the corner in the corner's tangent frame, turned by the corner's rotation) and
blends the three bilinear samples with smooth weights (squared barycentric weights, normalized).

Where the three corners copied one coherent piece of the example the predictions agree and the fine
vertex gets the example's own relief at the example's own resolution; across a patch border (corners
from unrelated places) the blend runs over one coarse triangle and is continuous (on a coarse edge
only its two ends weigh, at a coarse vertex only that vertex), so the border does not step.

All vectorized NumPy on the host: a million fine vertices take seconds, and the same coarse decisions
give the same bits on every device.
"""

from __future__ import annotations

import math

import numpy as np

from geosynth.relief.examples import ReliefExample

__all__ = ["barycentric", "predicted_places", "sample", "transfer", "vertex_faces"]


def vertex_faces(faces: np.ndarray, face_source: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V,) int64: for each fine vertex, the coarse face it lies in: the source face of the fine face of
    lowest index that uses the vertex (any fine face using it lies in a coarse face holding it)."""
    f = np.asarray(faces, np.int64).ravel()
    src = np.repeat(np.asarray(face_source, np.int64), 3)
    order = np.argsort(f, kind="stable")
    f, src = f[order], src[order]
    first = np.ones(len(f), bool)
    first[1:] = f[1:] != f[:-1]
    out = np.full(n_vertices, -1, np.int64)
    out[f[first]] = src[first]
    return out


def barycentric(points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(N, 3) float64 barycentric weights of each point in its triangle (a, b, c), clipped to [0, 1]
    and summing to 1 (a degenerate triangle: all weight on its first corner)."""
    e0, e1, p = b - a, c - a, points - a
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (p * e0).sum(1), (p * e1).sum(1)
    den = d00 * d11 - d01 * d01
    bad = np.abs(den) <= 1e-30 * np.maximum(d00 * d11, 1e-300)
    den = np.where(bad, 1.0, den)
    y = (d11 * d20 - d01 * d21) / den
    z = (d00 * d21 - d01 * d20) / den
    w = np.clip(np.stack([1 - y - z, y, z], 1), 0.0, 1.0)
    w[bad] = (1.0, 0.0, 0.0)
    return w / np.maximum(w.sum(1, keepdims=True), 1e-300)


def predicted_places(points: np.ndarray, corners: np.ndarray, frames: np.ndarray, places: np.ndarray,
                     rotations: np.ndarray, n_rotations: int, spacing: float) -> np.ndarray:
    """(N, 2) float64: where in the example (column, row; fractional cells of ``spacing``) each point
    falls when the coarse vertex at ``corners`` (N, 3) with frame ``frames`` (N, 3, 3) (rows u, v, n),
    place ``places`` (N, 2) and rotation ``rotations`` (N,) (angle 2 pi r / R) continues its copy:
    the place plus the point's tangent offset turned by the rotation (the synthesis' own rule for a
    coherent continuation)."""
    d = np.asarray(points, np.float64) - corners
    dx = np.einsum("ij,ij->i", d, frames[:, 0])
    dy = np.einsum("ij,ij->i", d, frames[:, 1])
    angle = [2 * math.pi * r / n_rotations for r in range(n_rotations)]
    cos_r = np.array([math.cos(a) for a in angle])  # scalar libm: the same on every CPU
    sin_r = np.array([math.sin(a) for a in angle])
    for t in (cos_r, sin_r):
        near = np.abs(t - np.rint(t)) < 1e-12
        t[near] = np.rint(t[near])
    c, s = cos_r[rotations], sin_r[rotations]
    return places + np.stack([dx * c - dy * s, dx * s + dy * c], 1) / spacing


def sample(example: ReliefExample, place: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """((N,) bilinear heights, (N, 3) float64 bilinear colours or None) of the example at fractional
    cells ``place`` (column, row): wrapped when the example tiles, else clamped to its border."""
    h, w = example.shape
    x, y = place[:, 0], place[:, 1]
    if not example.periodic:
        x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    if example.periodic:
        xa, xb, ya, yb = x0 % w, (x0 + 1) % w, y0 % h, (y0 + 1) % h
    else:
        xa, xb = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
        ya, yb = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    w00, w01, w10, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    g = example.heights
    z = g[ya, xa] * w00 + g[ya, xb] * w01 + g[yb, xa] * w10 + g[yb, xb] * w11
    col = None
    if example.colours is not None:
        c = example.colours.astype(np.float64)
        col = (c[ya, xa] * w00[:, None] + c[ya, xb] * w01[:, None] + c[yb, xa] * w10[:, None]
               + c[yb, xb] * w11[:, None])
    return z, col


def transfer(example: ReliefExample, coarse_vertices: np.ndarray, coarse_faces: np.ndarray, frames: np.ndarray,
             places: np.ndarray, rotations: np.ndarray, n_rotations: int, place_spacing: float,
             fine_vertices: np.ndarray, fine_face: np.ndarray, *, chunk: int = 1 << 18
             ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """The relief of each fine vertex from the coarse synthesis (module docstring).

    Args:
        example: the example sampled (any spacing: its own full resolution is best).
        coarse_vertices: (Vc, 3) float64; coarse_faces: (Fc, 3) int64; frames: (Vc, 3, 3) tangent frames.
        places: (Vc, 2) float64 each coarse vertex's place (column, row) in cells of ``place_spacing``;
            rotations: (Vc,) int64 in [0, n_rotations).
        fine_vertices: (V, 3) float64 lying in the coarse faces; fine_face: (V,) int64 the coarse face of each.
        chunk: fine vertices per pass (bounds the temporaries' memory).

    Returns:
        ((V,) float64 heights, (V, 3) uint8 colours or None, (V, 2) float64 the place (in the example's
        own cells) of each fine vertex's heaviest corner's prediction, for the quality's patch borders).
    """
    cv = np.asarray(coarse_vertices, np.float64)
    cf = np.asarray(coarse_faces, np.int64)
    fv = np.asarray(fine_vertices, np.float64)
    n = len(fv)
    heights = np.zeros(n)
    colours = None if example.colours is None else np.zeros((n, 3), np.uint8)
    where = np.zeros((n, 2))
    ratio = place_spacing / example.spacing  # coarse cells -> the example's own cells
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        p = fv[lo:hi]
        corner = cf[np.asarray(fine_face[lo:hi], np.int64)]
        bary = barycentric(p, cv[corner[:, 0]], cv[corner[:, 1]], cv[corner[:, 2]])
        wts = bary * bary
        wts /= wts.sum(1, keepdims=True)
        acc = np.zeros(hi - lo)
        acc_c = None if colours is None else np.zeros((hi - lo, 3))
        heavy = np.argmax(bary, 1)
        for k in range(3):
            c = corner[:, k]
            pl = predicted_places(p, cv[c], frames[c], places[c], rotations[c], n_rotations, place_spacing) * ratio
            z, col = sample(example, pl)
            acc += wts[:, k] * z
            if acc_c is not None:
                acc_c += wts[:, k, None] * col
            sel = heavy == k
            where[lo:hi][sel] = pl[sel]
        heights[lo:hi] = acc
        if colours is not None:
            colours[lo:hi] = np.clip(np.rint(acc_c), 0, 255).astype(np.uint8)
    return heights, colours, where
