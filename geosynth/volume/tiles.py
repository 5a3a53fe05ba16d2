"""How is a volume split into tiles and scheduled so that every seam is consistent?

Tiled M1 synthesis (texture optimization per level, Kwatra, Essa, Bobick and Kwatra,
"Texture Optimization for Example-based Synthesis", SIGGRAPH 2005, Sec. 3, run on the
multiresolution pyramid of Lagae, Dumont and Dutre, "Geometry Synthesis", Sec. 5.2) cuts
the target into tiles across x and y; z is never cut. This module is the geometry and the
schedule only: no synthesis, no engine (those are :mod:`geosynth.volume.tiled`).

- Tile cores partition each level's x-y plane: a regular grid of ``nx`` x ``ny`` cores,
  all of one size (a multiple of the level factor 2^(levels-1), so every coarser level
  halves them exactly) except the last along each axis, which takes the rest. The cores
  are the chunks of the output store.
- Each tile is synthesized over its core grown by a margin on every side (clipped to the
  target): at least the largest block of any level, in that level's samples, so every
  block that covers a core sample lies inside the tile's region.
- Two phases per level (a checkerboard, by the parity of ix + iy): phase A tiles are
  synthesized independently (their margins are context, thrown away); phase B tiles
  then synthesize their region with the parts that lie in phase-A cores fixed to the A
  results (constrained synthesis: those samples enter the matches and the vote but do
  not change). Every border between an A and a B core is thus synthesized once, by the
  B tile, against both sides.
- Two B tiles touch at a corner point (a diagonal): the samples near it are chosen by
  both B tiles independently (each saw its own version of the other's quadrant), so a
  third phase synthesizes a small window centred on every interior corner point (each
  has exactly one B-B diagonal) with everything around it fixed: a free square of
  half-width ``corner_half`` (at most the block) inside a fixed ring of one block, all
  four quadrants final from phases A and B. The free squares of neighbouring corners
  lie outside each other's windows, so the corner windows are independent of one
  another. The constrained synthesis draws nothing at random, so the result still
  depends on the seed and the tiling only.
- Random draws per tile come from a numpy SeedSequence of (seed, level, tile index), so
  a result depends on the seed and the tiling only, never on the number of workers or
  the order in which they finish.
- A coarse level whose whole x-y plane is no larger than one tile's region at the
  finest level runs whole, as one task: it fits where a tile fits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geosynth.core.interpolate import lerp_axis, linear_taps

__all__ = ["PHASE_A", "PHASE_B", "PHASE_C", "Region", "TileGrid", "assemble", "tile_rng", "upsample_window"]

PHASE_A, PHASE_B, PHASE_C = 0, 1, 2  # C: the corner windows (not a tile's phase)


@dataclass(frozen=True)
class Region:
    """A box of one level across y and x (z is always whole): rows [y0, y1), columns [x0, x1)."""

    y0: int
    y1: int
    x0: int
    x1: int

    @property
    def shape(self) -> tuple[int, int]:
        return (self.y1 - self.y0, self.x1 - self.x0)

    def intersect(self, other: "Region") -> "Region | None":
        r = Region(max(self.y0, other.y0), min(self.y1, other.y1), max(self.x0, other.x0), min(self.x1, other.x1))
        return r if r.y0 < r.y1 and r.x0 < r.x1 else None

    def local(self, inner: "Region") -> tuple[slice, slice, slice]:
        """Index of ``inner`` (a sub-box) within an array holding this region (Z, Y, X)."""
        return (slice(None), slice(inner.y0 - self.y0, inner.y1 - self.y0), slice(inner.x0 - self.x0, inner.x1 - self.x0))


def tile_rng(seed: int, level: int, index: int) -> np.random.Generator:
    """The Generator of tile ``index`` at ``level`` (0 = coarsest): SeedSequence((seed, level, index))."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(level), int(index)]))


@dataclass(frozen=True)
class TileGrid:
    """Tiles of a (Z, Y, X) target over ``levels`` levels.

    Attributes:
        shape: the finest level's (Z, Y, X).
        tiles: (nx, ny) tiles across x and y.
        blocks: block size per level, coarsest first.
        margin: margin per level (samples of that level), coarsest first.
        core: (cy, cx) finest-level core size (the last tile along an axis takes the rest).
        coarse_whole: run the levels that fit in one tile whole (False: tile every level
            whose cores still hold a block plus the margin).
        slab: the blocks span each level's full thickness along z (a slab exemplar,
            :func:`geosynth.volume.synthesis.is_slab`); ``blocks`` are then their sides across.
    """

    shape: tuple[int, int, int]
    tiles: tuple[int, int]
    blocks: tuple[int, ...]
    margin: tuple[int, ...]
    core: tuple[int, int]
    coarse_whole: bool = True
    slab: bool = False

    @classmethod
    def make(cls, shape, tiles, blocks, margin: int | None = None, coarse_whole: bool = True,
             slab: bool = False) -> "TileGrid":
        """The grid for a target ``shape`` (Z, Y, X), ``tiles`` (nx, ny) and the blocks
        per level (a slab's: their sides across); ``margin`` (samples at every level)
        defaults to the largest block.

        Raises:
            ValueError: a tile count below 1, more tiles than the target has level
                factors along an axis, or a tiled level whose cores are smaller than
                its block plus the margin (naming the largest tiling that fits).
        """
        shape = tuple(int(v) for v in shape)
        nx, ny = (int(v) for v in tiles)
        blocks = tuple(int(b) for b in blocks)
        levels = len(blocks)
        factor = 2 ** (levels - 1)
        if nx < 1 or ny < 1:
            raise ValueError(f"tiles must be at least 1 x 1, got {nx} x {ny}.")
        m = max(blocks) if margin is None else int(margin)
        if m < max(blocks):
            raise ValueError(f"margin must be at least the largest block ({max(blocks)}), got {m}.")
        core = []
        for n, count, axis in ((shape[1], ny, "y"), (shape[2], nx, "x")):
            c = -(-(-(-n // count)) // factor) * factor  # ceil(n / count), rounded up to the level factor
            if (count - 1) * c >= n:
                raise ValueError(f"tiles {nx}x{ny}: {count} tiles along {axis} cannot split {n} samples in cores of "
                                 f"multiples of 2^(levels-1) = {factor}; use fewer tiles.")
            core.append(c)
        grid = cls(shape, (nx, ny), blocks, (m,) * levels, (core[0], core[1]), bool(coarse_whole), bool(slab))
        grid._check()
        return grid

    # ---------------------------------------------------------------- geometry

    @property
    def levels(self) -> int:
        return len(self.blocks)

    @property
    def count(self) -> int:
        return self.tiles[0] * self.tiles[1]

    def scale(self, level: int) -> int:
        """Finest samples per sample of ``level``."""
        return 2 ** (self.levels - 1 - level)

    def level_shape(self, level: int) -> tuple[int, int, int]:
        return tuple(n // self.scale(level) for n in self.shape)

    def block_shape(self, level: int):
        """The block the synthesis of ``level`` matches: N (a cube) or, for a slab,
        (Z_l, N, N) with Z_l the level's thickness (:func:`geosynth.volume.synthesis.level_block_shapes`)."""
        from geosynth.volume.synthesis import level_block_shapes

        return level_block_shapes(self.shape, self.levels, list(self.blocks), self.slab)[level]

    def index(self, ix: int, iy: int) -> int:
        return iy * self.tiles[0] + ix

    def position(self, index: int) -> tuple[int, int]:
        """(ix, iy) of a tile index (row-major: x fastest)."""
        return index % self.tiles[0], index // self.tiles[0]

    def phase(self, index: int) -> int:
        ix, iy = self.position(index)
        return PHASE_A if (ix + iy) % 2 == 0 else PHASE_B

    def core_region(self, level: int, index: int) -> Region:
        """The core of tile ``index`` at ``level`` (the whole plane for a whole level)."""
        _, ny_, nx_ = self.level_shape(level)
        if self.whole(level):
            return Region(0, ny_, 0, nx_)
        s = self.scale(level)
        cy, cx = self.core[0] // s, self.core[1] // s
        ix, iy = self.position(index)
        return Region(iy * cy, min(ny_, (iy + 1) * cy), ix * cx, min(nx_, (ix + 1) * cx))

    def region(self, level: int, index: int) -> Region:
        """The core grown by the level's margin, clipped to the plane."""
        c = self.core_region(level, index)
        _, ny_, nx_ = self.level_shape(level)
        m = self.margin[level]
        return Region(max(0, c.y0 - m), min(ny_, c.y1 + m), max(0, c.x0 - m), min(nx_, c.x1 + m))

    def whole(self, level: int) -> bool:
        """Does ``level`` run as one task? Always with one tile; otherwise when coarse
        levels may run whole and its plane is no larger than a finest-level tile region."""
        if self.count == 1:
            return True
        if not self.coarse_whole or level == self.levels - 1:
            return False
        _, ny_, nx_ = self.level_shape(level)
        m = self.margin[-1]
        return ny_ * nx_ <= (self.core[0] + 2 * m) * (self.core[1] + 2 * m)

    def tasks(self, level: int) -> list[int]:
        """Tile indices synthesized at ``level``: [0] for a whole level."""
        return [0] if self.whole(level) else list(range(self.count))

    def cores(self, level: int) -> dict[int, Region]:
        return {t: self.core_region(level, t) for t in self.tasks(level)}

    def overlapping(self, level: int, box: Region) -> list[tuple[int, Region]]:
        """(tile, part of ``box`` in that tile's core) for every core of ``level`` that ``box`` meets."""
        out = []
        for t, c in self.cores(level).items():
            part = c.intersect(box)
            if part is not None:
                out.append((t, part))
        return out

    def fixed_parts(self, level: int, index: int) -> list[tuple[int, Region]]:
        """Phase B: (A tile, part of this tile's region in its core) to hold fixed."""
        if self.whole(level) or self.phase(index) == PHASE_A:
            return []
        return [(t, part) for t, part in self.overlapping(level, self.region(level, index))
                if t != index and self.phase(t) == PHASE_A]

    # ---------------------------------------------------------------- phase C: corner windows

    def corner_half(self, level: int) -> int:
        """Half-width of a corner window's free square at ``level``: the block, or less
        where the cores are small, so that a window (free square grown by one block)
        never reaches a neighbouring corner's free square: 2 h + b <= the smallest core."""
        b = self.blocks[level]
        smallest = min(min(c.shape) for c in self.cores(level).values())
        return max(1, min(b, (smallest - b) // 2))

    def corners(self, level: int) -> list[tuple[int, int]]:
        """The interior corner points (y, x) of ``level``'s cores (where four cores meet;
        every one has one B-B diagonal), row-major; none for a whole level."""
        if self.whole(level):
            return []
        cores = self.cores(level)
        ys = sorted({c.y0 for c in cores.values()} - {0})
        xs = sorted({c.x0 for c in cores.values()} - {0})
        return [(y, x) for y in ys for x in xs]

    def corner_free(self, level: int, k: int) -> Region:
        """The free square of corner ``k`` (half-width :meth:`corner_half`)."""
        y, x = self.corners(level)[k]
        h = self.corner_half(level)
        return Region(y - h, y + h, x - h, x + h)

    def corner_window(self, level: int, k: int) -> Region:
        """The window of corner ``k``: its free square grown by one block (the fixed
        ring, so every block that covers a free sample lies in the window), clipped."""
        f, b = self.corner_free(level, k), self.blocks[level]
        _, ny_, nx_ = self.level_shape(level)
        return Region(max(0, f.y0 - b), min(ny_, f.y1 + b), max(0, f.x0 - b), min(nx_, f.x1 + b))

    def upsample_source(self, level: int, index: int) -> Region:
        """The box of level ``level - 1`` whose samples the trilinear x2 upsampling of
        this tile's region reads (cell centres: fine i sits at coarse i / 2 - 1/4)."""
        r = self.region(level, index)
        _, ny_, nx_ = self.level_shape(level - 1)
        return Region(max(0, (r.y0 - 1) // 2), min(ny_, (r.y1 - 1) // 2 + 2),
                      max(0, (r.x0 - 1) // 2), min(nx_, (r.x1 - 1) // 2 + 2))

    def _check(self) -> None:
        nx, ny = self.tiles
        for level in range(self.levels):
            if self.whole(level):
                continue
            b, m = self.blocks[level], self.margin[level]
            for t in range(self.count):
                c = self.core_region(level, t)
                if min(c.shape) < b + m:
                    s = self.scale(level)
                    most = [max(1, n // s // (b + m)) for n in (self.shape[2], self.shape[1])]
                    raise ValueError(
                        f"tiles {nx}x{ny}: at level {level + 1} a tile core is {c.shape[1]} x {c.shape[0]} samples "
                        f"(x y), smaller than its block {b} plus the margin {m}; use at most "
                        f"{most[0]}x{most[1]} tiles, a larger size or a smaller block.")


def assemble(shape_z: int, box: Region, pieces, dtype=np.uint8, fill=None) -> tuple[np.ndarray, np.ndarray]:
    """An array for ``box`` (Z, box rows, box columns) from (Region, array) pieces that
    lie in it; returns (array, mask of the samples the pieces covered)."""
    out = np.zeros((shape_z,) + box.shape, dtype) if fill is None else fill
    mask = np.zeros((shape_z,) + box.shape, bool)
    for part, values in pieces:
        index = box.local(part)
        out[index] = values
        mask[index] = True
    return out, mask


def upsample_window(coarse: np.ndarray, coarse_box: Region, coarse_shape, fine_box: Region,
                    fine_shape) -> np.ndarray:
    """The samples of ``fine_box`` of :func:`geosynth.volume.synthesis.upsample` (non-periodic) of
    a level of ``coarse_shape``, from the window ``coarse`` holding ``coarse_box`` of it:
    bit for bit the same values as upsampling the whole level and cutting the box out
    (the same coordinates, taps, weights and float32 blends, in the same axis order).

    Args:
        coarse: (Z/2, rows, columns) uint8 window of the coarser level.
        coarse_box: where the window lies in that level (it must hold every tap).
        coarse_shape, fine_shape: (Z, Y, X) of the two whole levels.
        fine_box: the box of the finer level wanted.

    Returns:
        (Z, fine_box rows, fine_box columns) uint8.
    """
    out = coarse.astype(np.float32)
    spans = [(0, fine_shape[0], 0), (fine_box.y0, fine_box.y1, coarse_box.y0), (fine_box.x0, fine_box.x1, coarse_box.x0)]
    for axis, (a, b, c0) in enumerate(spans):
        n, m = int(fine_shape[axis]), int(coarse_shape[axis])
        pos = (np.arange(a, b) + 0.5) * m / n - 0.5  # volume.upsample's coordinates of the whole level
        i0, i1, t = linear_taps(pos, m, False, np.float32, clamp="taps")  # clamped at the level's faces
        i0, i1 = i0 - c0, i1 - c0
        if i0.min() < 0 or i1.max() >= out.shape[axis]:
            raise ValueError("upsample_window: the coarse window does not hold every tap.")
        out = lerp_axis(out, axis, (i0, i1, t))
    return np.clip(np.round(out), 0, 255).astype(np.uint8)
