"""Where are a field's blocks, and what are the sums of its cubes?

The block lattice that both M1 searches (:mod:`geosynth.tree_search`,
:mod:`geosynth.cascade_search`) share: a block's sample offsets, every block's origin in
block-index order, and exact sums over every cube of a field, the cell sums of the
lower bound (eq. 2) of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 4.2 (block
similarity).
"""

from __future__ import annotations

import numpy as np

from geosynth.scoring import candidate_origins

__all__ = ["block_offsets", "block_origins", "box_sums"]


def block_offsets(block: int) -> np.ndarray:
    """(N^3, 3) int64 offsets (dz, dy, dx) of a block's samples, raster order."""
    ax = np.arange(block)
    return np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)


def block_origins(shape, block: int) -> np.ndarray:
    """(B, 3) int64 origins of every block of a field, in block-index order.

    The same as ``geosynth.scoring.candidate_origins(shape, block_offsets(block))``:
    raster order, z slowest.
    """
    return candidate_origins(tuple(shape), block_offsets(block))



def box_sums(field: np.ndarray, cell: int) -> np.ndarray:
    """Exact sums over every ``cell``^3 cube of a field.

    Args:
        field: (Z, Y, X) integer array.
        cell: cube side c >= 1.

    Returns:
        (Z - c + 1, Y - c + 1, X - c + 1) int64; ``out[p] = field[p : p + c].sum()``.
    """
    p = np.zeros(tuple(s + 1 for s in field.shape), np.int64)
    p[1:, 1:, 1:] = np.asarray(field, np.int64).cumsum(0).cumsum(1).cumsum(2)
    c = int(cell)
    return (p[c:, c:, c:] - p[:-c, c:, c:] - p[c:, :-c, c:] - p[c:, c:, :-c]
            + p[:-c, :-c, c:] + p[:-c, c:, :-c] + p[c:, :-c, :-c] - p[:-c, :-c, :-c])
