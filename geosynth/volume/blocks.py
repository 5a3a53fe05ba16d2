"""Where are a field's blocks, and what are the sums of its cubes?

The block lattice that both M1 searches (:mod:`geosynth.volume.tree`,
:mod:`geosynth.volume.cascade`) share: a block's sample offsets, every block's origin in
block-index order, and exact sums over every cube of a field, the cell sums of the
lower bound (eq. 2) of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 4.2 (block
similarity).
"""

from __future__ import annotations

import numpy as np

from geosynth.compute.scoring import candidate_origins

__all__ = ["block_offsets", "block_origins", "block_shape", "box_sums"]


def block_shape(block) -> tuple[int, int, int]:
    """A block's (bz, by, bx) sides: one integer N is the cube (N, N, N); three are
    taken as given (an anisotropic block, e.g. a slab's: its full thickness along z)."""
    if np.ndim(block) == 0:
        n = int(block)
        return (n, n, n)
    sides = tuple(int(v) for v in np.asarray(block).reshape(-1))
    if len(sides) != 3:
        raise ValueError(f"a block shape has three sides (z, y, x), got {block!r}.")
    return sides


def block_offsets(block) -> np.ndarray:
    """(bz * by * bx, 3) int64 offsets (dz, dy, dx) of a block's samples, raster order;
    ``block`` is N (a cube) or (bz, by, bx)."""
    axes = [np.arange(n) for n in block_shape(block)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def block_origins(shape, block) -> np.ndarray:
    """(B, 3) int64 origins of every block of a field, in block-index order.

    The same as ``geosynth.compute.scoring.candidate_origins(shape, block_offsets(block))``:
    raster order, z slowest.
    """
    return candidate_origins(tuple(shape), block_offsets(block))



def box_sums(field: np.ndarray, cell) -> np.ndarray:
    """Exact sums over every cell of a field.

    Args:
        field: (Z, Y, X) integer array.
        cell: cube side c >= 1, or a box (cz, cy, cx).

    Returns:
        (Z - cz + 1, Y - cy + 1, X - cx + 1) int64; ``out[p] = field[p : p + c].sum()``.
    """
    p = np.zeros(tuple(s + 1 for s in field.shape), np.int64)
    p[1:, 1:, 1:] = np.asarray(field, np.int64).cumsum(0).cumsum(1).cumsum(2)
    a, b, c = block_shape(cell)
    return (p[a:, b:, c:] - p[:-a, b:, c:] - p[a:, :-b, c:] - p[a:, b:, :-c]
            + p[:-a, :-b, c:] + p[:-a, b:, :-c] + p[a:, :-b, :-c] - p[:-a, :-b, :-c])
