"""What are a block's coarser levels, and how far apart are two blocks at a level? The block
pyramid and level distance of Lagae, Dumont and Dutré, "Geometry Synthesis", Sec. 4.1-4.2.

Block pyramids (M1): the global box-filtered pyramid of a quantized field, and the
level distance between a query block and candidate blocks.

A *block* is an N^3 cube of a (Z, Y, X) uint8 field, N a power of two; its origin is
its lowest corner. Its *block pyramid* has L = log2(N) + 1 levels: level l
(1 = coarsest) has n = 2^(l-1) cells per side of cell size c = N / n, each cell the
mean of c^3 samples; level L is the block itself. Blocks overlap, so levels are not
stored per block: one *global pyramid* holds, for every cell size c = 1, 2, 4, ..., N,
the c^3 box sums at every position of the field, and block p's level with cell size c
samples it at p + c * (i, j, k), (i, j, k) in [0, n)^3.

What is stored, on the device:

- ``sums``: the exact integer box sums (uint32), built by doubling
  (S_2c[p] = sum of the eight S_c[p + c * o], o in {0, 1}^3: the prefix-sum idea in
  its multiplicative form; every value is an exact integer <= 255 * N^3).
- the uint8 means the paper quantizes to (:meth:`BlockPyramid.means`), derived from
  the sums on demand: ``mean = floor((S + c^3 / 2) / c^3)``, i.e. the exact mean
  rounded half up (cell size 1: the field itself).

Level distance. The paper's eq. 1 at level l is dist_l = (1/n^3) * sum (B - B')^2
over the level's n^3 cell means. With exact means, eq. 2 (dist_l <= dist_{l+1}) holds;
with uint8-rounded means it does not, so the search never bounds with rounded means.
It uses the exact cell sums: for one cell of c^3 samples with sums Q (query) and S
(candidate), (Q - S)^2 / c^3 <= sum over the cell of the squared sample differences
(Cauchy-Schwarz), so

    LB_l = D_l / c^3,  D_l = sum over cells (Q - S)^2  (an exact integer)

is a lower bound of the full block SSD, and N^3 * dist_l = LB_l for exact means.
Since c^3 is a power of two, the search keeps every bound as an exact integer
(see :mod:`geosynth.volume.tree`).
"""

from __future__ import annotations

from dataclasses import dataclass, field as dc_field

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.core.arrays import DeviceArray

__all__ = [
    "BlockPyramid",
    "available_memory",
    "block_levels",
    "build_pyramid",
    "check_block",
    "check_block_shape",
    "compare_level",
    "level_shape",
    "query_arrays",
]

_INT32_LIMIT = 2**31 - 1024  # flat indices stay int32 in the kernels


def available_memory() -> int:
    """Bytes this process may still allocate (:func:`geosynth.core.memory.available_memory`:
    MemAvailable, the cgroup and RLIMIT_AS headroom, ``GEOSYNTH_MEMORY_LIMIT``).

    Tests monkeypatch this to check the refusal of oversized inputs.
    """
    from geosynth.core import memory

    return memory.available_memory()


def check_memory(estimate: int, what: str) -> None:
    """Refuse, before allocating, work whose memory estimate exceeds what is available.

    Raises:
        MemoryBudgetError (a MemoryError): with the estimate and the available memory in
            the message; its option is ``"block"`` (a smaller block or source helps).
    """
    from geosynth.core.memory import MemoryBudgetError

    avail = available_memory()
    if estimate > avail:
        raise MemoryBudgetError(
            f"{what} needs an estimated {estimate / 2**20:.1f} MiB but only {avail / 2**20:.1f} MiB of memory "
            "is available; use a smaller source field or block.",
            option="block", largest=None, estimate=estimate, available=avail,
        )


def check_block(block, shape: tuple[int, ...]) -> int:
    """Check that ``block`` is a power of two no larger than any side of ``shape``.

    Returns:
        log2(block).

    Raises:
        TypeError: block is not an integer.
        ValueError: block < 1, not a power of two, or larger than the field.
    """
    if isinstance(block, bool) or not isinstance(block, (int, np.integer)):
        raise TypeError(f"block must be an integer (a power of two), got {block!r}.")
    block = int(block)
    if block < 1 or block & (block - 1):
        raise ValueError(f"block must be a power of two (1, 2, 4, 8, ...), got {block}.")
    if any(block > s for s in shape):
        raise ValueError(f"block {block} is larger than the source field {tuple(shape)}: every side must be >= block.")
    return block.bit_length() - 1


def check_field(field) -> np.ndarray:
    """A (Z, Y, X) uint8 host array, contiguous, or a clear error."""
    if isinstance(field, DeviceArray):
        raise TypeError("field must be a host NumPy array (it is uploaded once).")
    if not isinstance(field, np.ndarray):
        field = np.asarray(field)
    if field.dtype != np.uint8:
        raise TypeError(
            f"field has dtype {field.dtype}: expected uint8 (quantize it first, e.g. with "
            "geosynth.volume.synthesis.quantize_field)."
        )
    if field.ndim != 3:
        raise ValueError(f"field must be a 3-D (Z, Y, X) array, got shape {field.shape}.")
    if min(field.shape) < 1:
        raise ValueError(f"field is empty (shape {field.shape}).")
    return np.ascontiguousarray(field)


def level_shape(block: int, level: int) -> tuple[int, int]:
    """(cells per side n, cell size c) of a block pyramid level (1 = coarsest)."""
    n = 1 << (level - 1)
    return n, block // n


def pyramid_bytes(shape: tuple[int, ...], block: int) -> int:
    """Device bytes of the global pyramid of a field: one uint32 slab per cell size."""
    return int(np.prod(shape)) * 4 * (block.bit_length())


@dataclass
class BlockPyramid:
    """The global pyramid of one field on one device (see the module docstring).

    Attributes:
        shape: the field's (Z, Y, X).
        block: the block size N.
        levels: L = log2(N) + 1.
        backend: the backend holding the arrays.
        field: the field as a DeviceArray (uint8).
        sums: (L * Z * Y * X,) uint32 DeviceArray; slab k holds the 2^k box sums.
    """

    shape: tuple[int, int, int]
    block: int
    levels: int
    backend: object
    field: DeviceArray
    sums: DeviceArray
    _means: dict = dc_field(default_factory=dict, repr=False)

    @property
    def total(self) -> int:
        """Entries per slab, Z * Y * X."""
        return int(np.prod(self.shape))

    def cell_sums(self, cell: int) -> np.ndarray:
        """Host copy of the exact c^3 box sums at every valid position.

        Returns:
            (Z - c + 1, Y - c + 1, X - c + 1) uint32.
        """
        k = self._cell_index(cell)
        # sync: the whole pyramid comes back once (tests, inspection).
        allsums = self.backend.pyramid_read_all(self.sums).reshape(self.levels, *self.shape)
        z, y, x = (s - cell + 1 for s in self.shape)
        return allsums[k, :z, :y, :x].copy()

    def means(self, cell: int) -> np.ndarray:
        """The box-filtered field of cell size ``cell`` quantized to uint8.

        ``mean = floor((S + c^3 / 2) / c^3)`` for the exact box sum S: the mean
        rounded half up; cell size 1 is the field itself.

        Returns:
            (Z - c + 1, Y - c + 1, X - c + 1) uint8.
        """
        k = self._cell_index(cell)
        if k not in self._means:
            out = self.backend.empty((self.total,), np.uint8)
            self.backend.pyramid_quantize(self.sums, k * self.total, k, self.total, out)
            # sync: the quantized slab is the answer.
            self._means[k] = out.numpy().reshape(self.shape)
        z, y, x = (s - cell + 1 for s in self.shape)
        return self._means[k][:z, :y, :x].copy()

    def _cell_index(self, cell: int) -> int:
        if isinstance(cell, bool) or not isinstance(cell, (int, np.integer)) or cell < 1 or cell & (cell - 1) or cell > self.block:
            raise ValueError(f"cell must be a power of two in [1, {self.block}], got {cell!r}.")
        return int(cell).bit_length() - 1


def build_pyramid(field: np.ndarray, block: int, *, device: str | None = None) -> BlockPyramid:
    """Build the global box-filtered pyramid of a quantized field on a device.

    Args:
        field: (Z, Y, X) uint8 array, the quantized source.
        block: the block size N, a power of two <= every side of ``field``.
        device: a device string (see :mod:`geosynth.compute.backend`); None means ``"auto"``.

    Returns:
        A :class:`BlockPyramid` whose arrays stay on the device.

    Raises:
        TypeError: field is not uint8, block is not an integer.
        ValueError: field not 3-D or empty, block not a power of two or larger than
            the field, a field beyond 2^31 pyramid entries.
        MemoryError: the pyramid would not fit in the available memory.

    Example:
        >>> import numpy as np
        >>> f = np.arange(64, dtype=np.uint8).reshape(4, 4, 4)
        >>> p = build_pyramid(f, 2, device="cpu")
        >>> int(p.cell_sums(2)[0, 0, 0]) == int(f[:2, :2, :2].sum())
        True
    """
    field = check_field(field)
    log_block = check_block(block, field.shape)
    levels = log_block + 1
    total = int(field.size)
    if total * levels > _INT32_LIMIT:
        raise ValueError(f"the pyramid of a {field.shape} field with block {block} exceeds 2^31 entries; use a smaller field.")
    check_memory(pyramid_bytes(field.shape, int(block)) + total, f"the block pyramid of a {field.shape} field (block {block})")
    backend = _checks.resolve_backend(device)
    dev_field = backend.to_device(field)
    sums = backend.empty((levels * total,), np.uint32)
    nz, ny, nx = field.shape
    backend.pyramid_init(dev_field, sums, total)
    for k in range(log_block):
        backend.pyramid_double(sums, k * total, (k + 1) * total, 1 << k, nz, ny, nx)
    return BlockPyramid(tuple(field.shape), int(block), levels, backend, dev_field, sums)


def block_levels(query: np.ndarray, block: int) -> list[np.ndarray]:
    """The exact cell sums of every level of one block, coarsest first.

    Args:
        query: (N, N, N) block (any integer dtype; uint8 for queries).
        block: N.

    Returns:
        L arrays; level l is (n, n, n) int64 with n = 2^(l-1).
    """
    q = np.asarray(query, np.int64)
    out = []
    for lev in range(1, block.bit_length() + 1):
        n, c = level_shape(block, lev)
        out.append(q.reshape(n, c, n, c, n, c).sum(axis=(1, 3, 5)))
    return out


def check_query(query, block) -> np.ndarray:
    """A uint8 query block of the block's shape (N: (N, N, N); or (bz, by, bx)), or a clear error."""
    if isinstance(query, DeviceArray):
        raise TypeError("query must be a host NumPy array.")
    query = np.asarray(query)
    if query.dtype != np.uint8:
        raise TypeError(f"query has dtype {query.dtype}: expected uint8, like the source field.")
    want = (int(block),) * 3 if np.ndim(block) == 0 else tuple(int(v) for v in block)
    if query.shape != want:
        raise ValueError(f"query must have shape {want} to match the block size, got {query.shape}.")
    return np.ascontiguousarray(query)


def check_block_shape(block, shape: tuple[int, ...]):
    """A cubic block N (checked by :func:`check_block`) or an anisotropic one (bz, by, bx)
    of positive integers, each no larger than that side of ``shape``.

    Returns:
        the int N for a cube (three equal sides included), else the (bz, by, bx) tuple.

    Raises:
        TypeError: a side is not an integer. ValueError: a side < 1 or larger than the field.
    """
    if np.ndim(block) == 0:
        check_block(block, shape)
        return int(block)
    sides = list(np.asarray(block, dtype=object).reshape(-1))
    if len(sides) != 3 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in sides):
        raise TypeError(f"block must be an integer or three of them (z, y, x), got {block!r}.")
    sides = tuple(int(v) for v in sides)
    if len(set(sides)) == 1:
        check_block(sides[0], shape)
        return sides[0]
    if min(sides) < 1:
        raise ValueError(f"block sides must be >= 1, got {sides}.")
    if any(b > s for b, s in zip(sides, shape)):
        raise ValueError(f"block {sides} is larger than the source field {tuple(shape)} along some axis.")
    return sides


def query_arrays(backend, query: np.ndarray, block: int) -> tuple[DeviceArray, DeviceArray]:
    """A query block's levels on a device, as the compare kernels read them.

    Args:
        backend: the Backend to upload to.
        query: (N, N, N) uint8 block, N = ``block``.
        block: the block size N (a power of two).

    Returns:
        (flat int32 DeviceArray of every level's samples, coarsest first; (L + 1,)
        int32 DeviceArray of each level's start in it).
    """
    lev = block_levels(query, block)
    flat = np.concatenate([a.reshape(-1) for a in lev]).astype(np.int32)
    off = np.zeros(len(lev) + 1, np.int32)
    off[1:] = np.cumsum([a.size for a in lev])
    return backend.to_device(flat), backend.to_device(off)


def compare_level(
    pyramid: BlockPyramid, query: np.ndarray, origins: np.ndarray, level: int, *, rounded: bool = False
) -> np.ndarray:
    """Integer level distance of a query block against a batch of candidate blocks.

    ``D[i] = sum over the n^3 cells of level l of (Q - S_i)^2`` with Q, S_i the exact
    cell sums of the query and of the block at ``origins[i]``; D / c^3 is a lower
    bound of the full block SSD and N^3 * dist_l (eq. 1 with exact means) equals it.
    With ``rounded=True`` the candidate is known only by its uint8-rounded means m:
    the difference is the distance of Q to the interval of sums that round to m
    (a lower bound of the exact form, used by the search tree's parent nodes).

    Args:
        pyramid: from :func:`build_pyramid`.
        query: (N, N, N) uint8 block.
        origins: (M, 3) integer block origins (z, y, x), each block inside the field.
        level: 1 (coarsest, one cell) .. L (the full block: D is the SSD).
        rounded: compare against the rounded means' intervals (level < L only).

    Returns:
        (M,) int64 D, exact.

    Raises:
        TypeError / ValueError: bad query, origins or level.
    """
    n_block = pyramid.block
    query = check_query(query, n_block)
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 1 <= level <= pyramid.levels:
        raise ValueError(f"level must be an integer in [1, {pyramid.levels}], got {level!r}.")
    if rounded and level == pyramid.levels:
        raise ValueError("rounded comparison is for coarse levels only; level L holds the samples themselves.")
    org = np.asarray(origins)
    if org.ndim != 2 or org.shape[1] != 3:
        raise ValueError(f"origins must have shape (M, 3), got {org.shape}.")
    if org.dtype.kind not in "iu":
        raise TypeError(f"origins must be integers, got dtype {org.dtype}.")
    org = org.astype(np.int64)
    hi = np.asarray(pyramid.shape) - n_block
    if ((org < 0) | (org > hi)).any():
        raise ValueError(f"origins must lie in [0, {tuple(int(v) for v in hi)}] so that every block is inside the field.")
    m = org.shape[0]
    if m == 0:
        return np.zeros(0, np.int64)
    backend = pyramid.backend
    _, ny, nx = pyramid.shape
    base = (org @ np.array([ny * nx, nx, 1], np.int64)).astype(np.int32)
    code = np.full(m, 2 * int(level) + int(rounded), np.int32)
    q, qoff = query_arrays(backend, query, n_block)
    out = backend.pyramid_empty((m,), np.int64)
    ids = backend.to_device(np.arange(m, dtype=np.int32))
    backend.pyramid_compare(
        pyramid.sums, pyramid.total, ny, nx, n_block.bit_length() - 1,
        backend.to_device(base), backend.to_device(code), ids, 0, m, q, qoff, out,
    )
    return backend.pyramid_read(out, m).astype(np.int64)
