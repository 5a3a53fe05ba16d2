"""What must M1's block pyramid and block searches return? Plain NumPy oracles of the block
pyramid and of the nearest-block searches of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 5.

These oracles are slow, obvious and never on a production path. Each takes the same arguments
as the operation it checks and returns the same result; float sums are accumulated in float64,
uint8 sums in exact integers.
"""

from __future__ import annotations

import numpy as np


def box_sums_naive(field: np.ndarray, cell: int) -> np.ndarray:
    """Same result as :meth:`geosynth.volume.pyramid.BlockPyramid.cell_sums`: the exact sum of
    every cell^3 cube of ``field``, (Z - c + 1, Y - c + 1, X - c + 1) int64."""
    from numpy.lib.stride_tricks import sliding_window_view

    return sliding_window_view(field.astype(np.int64), (cell,) * 3).sum(axis=(-3, -2, -1))


def box_means_naive(field: np.ndarray, cell: int) -> np.ndarray:
    """Same result as :meth:`geosynth.volume.pyramid.BlockPyramid.means`: the cube means
    rounded half up, computed in float64 then floor(mean + 1/2), as uint8."""
    return np.floor(box_sums_naive(field, cell) / float(cell) ** 3 + 0.5).astype(np.uint8)


def compare_level_naive(field: np.ndarray, query: np.ndarray, origins: np.ndarray, level: int,
                        rounded: bool = False) -> np.ndarray:
    """Same arguments and result as :func:`geosynth.volume.pyramid.compare_level` (without the
    pyramid): the level's cell sums by reshaping each block, then the integer D."""
    n_block = query.shape[0]
    n = 1 << (level - 1)
    c = n_block // n
    c3 = c ** 3

    def cells(b):
        return np.asarray(b, np.int64).reshape(n, c, n, c, n, c).sum(axis=(1, 3, 5))

    q = cells(query)
    out = []
    for z, y, x in np.asarray(origins, np.int64):
        s = cells(field[z:z + n_block, y:y + n_block, x:x + n_block])
        if rounded:
            m = np.floor(s / c3 + 0.5).astype(np.int64)
            lo = np.maximum(m * c3 - c3 // 2, 0)
            hi = np.minimum(m * c3 + c3 // 2 - 1, 255 * c3)
            d = np.where(q < lo, lo - q, np.where(q > hi, q - hi, 0))
        else:
            d = q - s
        out.append(int((d * d).sum()))
    return np.asarray(out, np.int64)


def nearest_block_naive(field: np.ndarray, query: np.ndarray) -> tuple[tuple[int, int, int], int]:
    """Same result as :meth:`geosynth.volume.tree.BlockSearch.nearest`: the SSD of the query
    against every block, the smallest, the lowest raster index on ties."""
    from numpy.lib.stride_tricks import sliding_window_view

    win = sliding_window_view(field.astype(np.int64), query.shape)  # a cube or a (bz, by, bx) box
    ssd = ((win - query.astype(np.int64)) ** 2).sum(axis=(-3, -2, -1))
    i = int(np.argmin(ssd.reshape(-1)))  # argmin returns the first minimum
    z, y, x = np.unravel_index(i, ssd.shape)
    return (int(z), int(y), int(x)), int(ssd.reshape(-1)[i])
