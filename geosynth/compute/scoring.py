"""How far is every candidate from a query? The linear search of Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.3, and eq. 5 of Zhang, Qiu and Kaufman, "Fast Hybrid Approach
for Texturing Point Models", Sec. 4.

Candidate SSD scoring: every candidate against a query, on any device.

Two forms:

- :func:`score_dense`: candidates and queries as rows of equal length (D).
- :func:`score_gather`: candidates are windows of a 2D or 3D grid, gathered in the
  kernel (never unpacked into memory); the query is K integer offsets with their
  values. A full block (M1), a masked overlap window (M2) and an irregular
  neighbourhood on a supersampled texture (M3, eq. 5) are all of this form.

Scores are float32 for float data and uint32 for uint8 data. uint8 data is scored in
integer arithmetic, exact and identical on every device.
"""

from __future__ import annotations

from collections.abc import Sequence

import functools

import numpy as np

from geosynth.compute import checks as _checks
from geosynth.core.arrays import DeviceArray

__all__ = ["GatherScorer", "candidate_origins", "lattice_shape", "score_dense", "score_gather"]

_INT32_LIMIT = 2**31 - 1024  # flat indices stay int32 in the kernels


def _upload(backend, array):
    return array if isinstance(array, DeviceArray) else backend.to_device(array)


def _score_dtype(data_dtype) -> np.dtype:
    return np.dtype(np.uint32) if np.dtype(data_dtype) == np.uint8 else np.dtype(np.float32)


def score_dense(
    candidates: np.ndarray | DeviceArray,
    queries: np.ndarray | DeviceArray,
    weights: np.ndarray | None = None,
    *,
    device: str | None = None,
    keep_on_device: bool = False,
) -> np.ndarray | DeviceArray:
    """Weighted sum of squared differences of every query against every candidate.

    ``scores[q, i] = sum_k weights[k] * (candidates[i, k] - queries[q, k]) ** 2``

    Args:
        candidates: (N, D) float32 or uint8 array (other floats are converted), or a
            DeviceArray made by :func:`geosynth.to_device` to reuse across calls.
        queries: (B, D) or (D,) array of the same dtype as ``candidates``.
        weights: optional (D,) non-negative weights; float for float data, integers
            for uint8 data.
        device: a device string (see :mod:`geosynth.compute.backend`); None means the device
            of a DeviceArray input, else ``"auto"``.
        keep_on_device: return a DeviceArray instead of a NumPy array, for
            selection on the device.

    Returns:
        (B, N) scores, or (N,) when ``queries`` is 1-D: float32 for float data,
        uint32 for uint8 data (exact).

    Raises:
        TypeError: unsupported dtype, or dtypes that do not match.
        ValueError: wrong shapes, empty inputs, NaN/inf, negative weights, a uint8
            score range beyond uint32, float data whose scores could overflow float32
            (``(max - min)^2 * total weight`` above half of float32's largest value, over
            both inputs' values; DeviceArray inputs are checked by their recorded range).
        RuntimeError: the device is absent, or inputs on different devices.
    """
    candidates = _checks.as_data("candidates", candidates, (2,))
    n, d = candidates.shape
    if n == 0:
        raise ValueError("candidates is empty: the candidate set must hold at least one row.")
    if d == 0:
        raise ValueError("candidates has rows of length 0: D must be at least 1.")
    queries = _checks.same_kind("queries", queries, "candidates", candidates)
    single = queries.ndim == 1
    if single:
        queries = _as_row(queries)
    if queries.ndim != 2 or queries.shape[1] != d:
        raise ValueError(f"queries must have shape (B, {d}) or ({d},) to match candidates (N, {d}), got {queries.shape}.")
    b = queries.shape[0]
    if b == 0:
        raise ValueError("queries is empty: pass at least one query row.")
    q_range = _checks.finite_range("queries", queries)
    c_range = _checks.finite_range("candidates", candidates)
    w = None if weights is None else _checks.as_weights("weights", weights, d, candidates.dtype)
    if candidates.dtype == np.uint8:
        _checks.check_uint32_range(d if w is None else int(w.astype(np.uint64).sum()), "this query")
    else:
        _checks.check_float_scores("candidates and queries", c_range, q_range,
                                   d if w is None else float(w.astype(np.float64).sum()))
    if n * d > _INT32_LIMIT or n * b > _INT32_LIMIT:
        raise ValueError(f"candidates ({n} x {d}) or scores ({b} x {n}) exceed 2^31 elements; split the call.")

    backend = _checks.resolve_backend(device, candidates, queries)
    out = backend.empty((b, n), _score_dtype(candidates.dtype))
    backend.ssd_dense(
        _upload(backend, candidates), _upload(backend, queries),
        None if w is None else backend.to_device(w), n, d, b, out,
    )
    if single:
        out.shape = (n,)
    return out if keep_on_device else out.numpy()


def _as_row(queries):
    """A 1-D query as one row (B = 1); a DeviceArray is viewed, not copied."""
    if not isinstance(queries, DeviceArray):
        return queries.reshape(1, -1)
    row = DeviceArray(queries.data, queries.backend, (1,) + queries.shape, queries.dtype)
    row._stats = queries.known_stats()
    return row


def _as_offsets(offsets) -> np.ndarray:
    off = np.asarray(offsets)
    if off.ndim != 2 or off.shape[1] not in (2, 3):
        raise ValueError(f"offsets must have shape (K, 2) or (K, 3) (integer grid offsets), got {off.shape}.")
    if off.shape[0] == 0:
        raise ValueError("offsets is empty: the query needs at least one offset.")
    if off.dtype.kind not in "iu":
        if off.dtype.kind == "f" and np.all(np.isfinite(off)) and np.all(off == np.round(off)):
            off = off.astype(np.int64)
        else:
            raise TypeError(f"offsets must be integers, got dtype {off.dtype}.")
    return off.astype(np.int64)


def _as_stride(stride, nd: int) -> np.ndarray:
    s = np.broadcast_to(np.asarray(stride), (nd,)) if np.ndim(stride) == 0 else np.asarray(stride)
    if s.shape != (nd,) or s.dtype.kind not in "iu" or (s < 1).any():
        raise ValueError(f"stride must be a positive integer or {nd} positive integers, got {stride!r}.")
    return s.astype(np.int64)


def _spatial_shape(name: str, shape: tuple[int, ...], nd: int) -> tuple[tuple[int, ...], int]:
    """Split a grid shape into its nd spatial sizes and its channel count."""
    if len(shape) == nd:
        return tuple(shape), 1
    if len(shape) == nd + 1:
        return tuple(shape[:nd]), int(shape[nd])
    raise ValueError(
        f"{name} must have {nd} dimensions (or {nd + 1} with channels last) to match {nd}-D offsets, got shape {shape}."
    )


def lattice_shape(
    grid_shape: Sequence[int], offsets: np.ndarray, stride: int | Sequence[int] = 1, wrap: bool = False
) -> tuple[int, ...]:
    """Shape of the lattice of candidate origins that :func:`score_gather` scores.

    Args:
        grid_shape: the grid's spatial shape ((Y, X) or (Z, Y, X)).
        offsets: (K, nd) integer offsets of the query.
        stride: step between candidate origins, one int or one per axis.
        wrap: periodic grid; every position (on the stride) is then a candidate.

    Returns:
        One count per axis; the candidates are its raster (C-order) enumeration.
    """
    off = _as_offsets(offsets)
    nd = off.shape[1]
    dims = np.asarray(grid_shape[:nd], np.int64)
    step = _as_stride(stride, nd)
    if wrap:
        return tuple(int(v) for v in -(-dims // step))
    lo, hi = -off.min(axis=0), dims - 1 - off.max(axis=0)
    return tuple(int(v) for v in np.where(hi >= lo, (hi - lo) // step + 1, 0))


def candidate_origins(
    grid_shape: Sequence[int], offsets: np.ndarray, stride: int | Sequence[int] = 1, wrap: bool = False
) -> np.ndarray:
    """The (N, nd) int64 origins of the lattice candidates, in score order.

    Same arguments as :func:`lattice_shape`; ``origins[i]`` is the grid position
    whose window ``scores[i]`` measures.
    """
    off = _as_offsets(offsets)
    nd = off.shape[1]
    step = _as_stride(stride, nd)
    counts = lattice_shape(grid_shape, off, step, wrap)
    lo = np.zeros(nd, np.int64) if wrap else -off.min(axis=0)
    axes = [lo[a] + step[a] * np.arange(counts[a]) for a in range(nd)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.reshape(-1) for m in mesh], axis=1)


def score_gather(
    grid: np.ndarray | DeviceArray,
    offsets: np.ndarray,
    values: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    origins: np.ndarray | None = None,
    stride: int | Sequence[int] = 1,
    wrap: bool = False,
    threshold: float | None = None,
    device: str | None = None,
    keep_on_device: bool = False,
) -> np.ndarray | DeviceArray:
    """SSD of one query, given as offsets and values, against windows of a grid.

    ``scores[c] = sum_k weights[k] * sum_ch (grid[origin_c + offsets[k], ch] - values[k, ch]) ** 2``

    The windows are read in the kernel; nothing is unpacked into memory. For many
    queries with the same offsets, :class:`GatherScorer` checks and uploads the
    grid, offsets and weights once.

    Args:
        grid: (Y, X[, C]) or (Z, Y, X[, C]) float32 or uint8 array (the number of
            columns of ``offsets`` says whether it is 2D or 3D; one more axis is
            channels), or a DeviceArray of it.
        offsets: (K, 2) or (K, 3) integer offsets from a candidate's origin, in grid
            axis order ((dy, dx) or (dz, dy, dx)); may be negative.
        values: (K, C) or, for one channel, (K,) query values, same dtype as ``grid``.
        weights: optional (K,) non-negative weights, one per offset (all channels).
        origins: optional (N, nd) integer candidate origins. Default: every origin
            whose window lies inside the grid (every origin when ``wrap``), on the
            lattice with ``stride``, in raster order (see :func:`candidate_origins`).
        stride: step between lattice origins; one int or one per axis. Lattices with
            a stride above 1 or several channels are scored on a polyphase copy of the
            grid (one plane per channel and residue modulo the stride), so
            that neighbouring candidates read neighbouring memory; for a DeviceArray
            grid the copy is made once per layout and cached with it.
        threshold: optional early exit for nearest-window searches: a candidate whose
            partial sum passes ``threshold`` may stop there, so every score above it
            means only "above the threshold"; scores at or below it are exact. With a
            threshold at or above the minimum (e.g. the score of any one candidate),
            :func:`geosynth.argmin` of the result is the exact argmin. Put the most
            telling offsets first: the sums are checked every 256 entries.
        wrap: treat the grid as periodic (tileable): windows wrap around its faces.
            The grid is padded periodically by the reach of the offsets (for a
            DeviceArray grid, once per padding, then cached with it).
        device: a device string; None means the device of a DeviceArray input, else
            ``"auto"``.
        keep_on_device: return a DeviceArray for selection on the device.

    Returns:
        (N,) scores, float32 for float data, uint32 (exact) for uint8 data.

    Raises:
        TypeError: unsupported or mismatched dtypes, non-integer offsets or origins.
        ValueError: wrong shapes, NaN/inf, no valid candidate, an origin whose
            window reaches outside the grid, a uint8 score range beyond uint32, float
            data whose scores could overflow float32 (``(max - min)^2 * total weight *
            channels`` above half of float32's largest value, over grid and values).
        RuntimeError: the device is absent, or inputs on different devices.
    """
    scorer = GatherScorer(grid, offsets, weights, stride=stride, wrap=wrap, device=device)
    return scorer(values, origins=origins, threshold=threshold, keep_on_device=keep_on_device)


def offset_run(flat: np.ndarray) -> int:
    """The longest run length L in (64, 32, 16) such that the flat offsets are runs of L
    consecutive indices (a block's x rows), else 0."""
    for run in (64, 32, 16):
        if flat.size and flat.size % run == 0:
            rows = flat.reshape(-1, run).astype(np.int64)
            if np.array_equal(rows - rows[:, :1], np.broadcast_to(np.arange(run), rows.shape)):
                return run
    return 0


class GatherScorer:
    """:func:`score_gather` with the grid, offsets and weights checked and uploaded once.

    ``GatherScorer(grid, offsets, weights, stride=, wrap=, device=)(values, origins=,
    threshold=, keep_on_device=)`` returns exactly what ``score_gather`` with the same
    arguments returns; each call only checks and uploads the query values and the
    origins. Searches that score many queries (M1 block matching, the M3 texel search)
    keep one per source and offset set.

    Args:
        grid, offsets, weights, stride, wrap, device: as for :func:`score_gather`.

    Attributes:
        lattice: the candidate lattice's shape when no origins are given.
        backend: the backend that runs the kernel.

    Example:
        >>> import numpy as np
        >>> g = np.arange(16, dtype=np.float32).reshape(4, 4)
        >>> scorer = GatherScorer(g, [[0, 0], [0, 1]], device="cpu")
        >>> scorer(np.array([5, 6], np.float32), origins=np.array([[1, 1], [0, 0]]))
        array([ 0., 50.], dtype=float32)
    """

    def __init__(self, grid: np.ndarray | DeviceArray, offsets: np.ndarray, weights: np.ndarray | None = None, *,
                 stride: int | Sequence[int] = 1, wrap: bool = False, device: str | None = None):
        off = _as_offsets(offsets)
        k, nd = off.shape
        grid = _checks.as_data("grid", grid, (nd, nd + 1))
        dims, channels = _spatial_shape("grid", grid.shape, nd)
        if min(dims) < 1 or channels < 1:
            raise ValueError(f"grid is empty (shape {grid.shape}).")
        self._grid_dtype = grid.dtype
        self._k, self._nd, self._channels = k, nd, channels
        self._grid_range = _checks.finite_range("grid", grid)
        w = None if weights is None else _checks.as_weights("weights", weights, k, grid.dtype)
        self._total_weight = (k if w is None else float(w.astype(np.float64).sum())) * channels
        if grid.dtype == np.uint8:
            total = k * channels if w is None else int(w.astype(np.uint64).sum()) * channels
            _checks.check_uint32_range(total, "this query")
        step = _as_stride(stride, nd)

        # Geometry in padded 3D: (Z, Y, X) with Z = 1 for 2D grids.
        self._dims = np.asarray(dims, np.int64)
        self._wrap = bool(wrap)
        pad_lo = np.maximum(0, -off.min(axis=0)) if wrap else np.zeros(nd, np.int64)
        pad_hi = np.maximum(0, off.max(axis=0)) if wrap else np.zeros(nd, np.int64)
        self._pad = None
        if wrap:
            self._pad = tuple((int(a), int(b)) for a, b in zip(pad_lo, pad_hi)) + (((0, 0),) if grid.ndim == nd + 1 else ())
        padded = self._dims + pad_lo + pad_hi
        if int(np.prod(padded)) * channels > _INT32_LIMIT:
            raise ValueError(f"grid of {int(np.prod(padded)) * channels} elements exceeds 2^31; split it.")
        full = np.concatenate([np.ones(3 - nd, np.int64), padded])  # (Z, Y, X)
        elem_strides = np.array([full[1] * full[2], full[2], 1], np.int64) * channels  # flat step per axis
        self._strides = elem_strides[3 - nd:]
        flat_off = (off @ self._strides)[:, None] + np.arange(channels)[None, :]  # (K, C)
        self._pad_lo = pad_lo
        self._reach = (off.min(axis=0), off.max(axis=0))

        self.lattice = lattice_shape(dims, off, step, wrap)
        self._lattice_error = None
        if min(self.lattice) == 0:
            self._lattice_error = (
                f"no valid candidate: the offsets span {tuple(int(v) for v in off.max(0) - off.min(0) + 1)} "
                f"but the grid is only {tuple(dims)}; use a larger grid, smaller offsets or wrap=True."
            )
        lo = pad_lo if wrap else -off.min(axis=0)
        lattice3 = np.concatenate([np.ones(3 - nd, np.int64), np.asarray(self.lattice, np.int64)])  # (nz, ny, nx)
        step3 = np.concatenate([np.ones(3 - nd, np.int64), step])
        self._lattice_steps = tuple(int(v) for v in (step3 * elem_strides)[::-1])  # (x, y, z)
        self._lattice_base0 = int(lo @ self._strides)
        self._lattice_xyz = (int(lattice3[2]), int(lattice3[1]), int(lattice3[0]))

        self.backend = _checks.resolve_backend(device, grid)
        self._source = grid  # padded (wrap) and uploaded on the first call that reads it
        self._grid = None
        self._flat_off_host = flat_off.reshape(-1).astype(np.int32)
        self._flat_off = None
        self._run = offset_run(self._flat_off_host) if w is None else 0  # explicit bases: 16-lane loads
        self._weights = None if w is None else self.backend.to_device(np.repeat(w, channels))
        # Strided or multi-channel lattices read a polyphase copy (see _polyphase_layout).
        self._poly = None
        self._poly_args = None
        if self._lattice_error is None and (channels > 1 or (step > 1).any()):
            self._poly_args = (off, step, -off.min(axis=0) if not wrap else np.zeros(nd, np.int64))

    def __call__(self, values: np.ndarray, *, origins: np.ndarray | None = None, threshold: float | None = None,
                 keep_on_device: bool = False) -> np.ndarray | DeviceArray:
        """Scores of one query (see :func:`score_gather` for the arguments and result)."""
        vals, thr = self._check_query(values, threshold)
        if origins is None:
            if self._lattice_error:
                raise ValueError(self._lattice_error)
            return self._launch(vals, thr, None, keep_on_device)
        return self._launch(vals, thr, self.flat_bases(origins), keep_on_device)

    def flat_bases(self, origins: np.ndarray) -> np.ndarray:
        """Checked flat grid indices of candidate origins, for :meth:`score_bases`.

        Args:
            origins: (N, nd) integer origins, as for :func:`score_gather`.

        Returns:
            (N,) int32 flat indices into this scorer's (padded) grid.

        Raises:
            ValueError, TypeError: as :func:`score_gather` for bad origins.
        """
        nd = self._nd
        org = np.asarray(origins)
        if org.ndim != 2 or org.shape[1] != nd:
            raise ValueError(f"origins must have shape (N, {nd}), got {org.shape}.")
        if org.shape[0] == 0:
            raise ValueError("origins is empty: the candidate set must hold at least one origin.")
        if org.dtype.kind not in "iu":
            raise TypeError(f"origins must be integers, got dtype {org.dtype}.")
        org = org.astype(np.int64)
        if self._wrap:
            org = np.mod(org, self._dims) + self._pad_lo
        else:
            reach_lo, reach_hi = org + self._reach[0], org + self._reach[1]
            bad = np.flatnonzero((reach_lo < 0).any(axis=1) | (reach_hi >= self._dims).any(axis=1))
            if bad.size:
                i = int(bad[0])
                raise ValueError(
                    f"offsets reach outside the grid {tuple(int(v) for v in self._dims)} for {bad.size} candidate "
                    f"origin(s), first origins[{i}] = {tuple(int(v) for v in org[i])}; drop them or use wrap=True."
                )
        return (org @ self._strides).astype(np.int32)

    def lattice_bases(self, indices: np.ndarray) -> np.ndarray:
        """Flat grid indices of lattice candidates, for :meth:`score_bases`.

        Args:
            indices: (N,) integer indices into the candidate lattice (C order, as the
                scores of a call without origins are laid out), each in
                ``[0, prod(lattice))``.

        Returns:
            (N,) int32 flat indices into this scorer's (padded) grid.
        """
        idx = np.asarray(indices).reshape(-1)
        nx, ny, nz = self._lattice_xyz
        if idx.size and (idx.min() < 0 or idx.max() >= nx * ny * nz):
            raise ValueError(f"indices must lie in [0, {nx * ny * nz}), the candidate lattice {self.lattice}.")
        # int32 throughout (lattice and grid stay below 2^31): 5-9x faster than int64 in NumPy
        idx = idx.astype(np.int32, copy=False)
        sx, sy, sz = (np.int32(v) for v in self._lattice_steps)
        q = idx // np.int32(nx)
        z = q // np.int32(ny)
        x, y = idx - q * np.int32(nx), q - z * np.int32(ny)
        return np.int32(self._lattice_base0) + z * sz + y * sy + x * sx

    def score_bases(self, values: np.ndarray, bases: np.ndarray, *, threshold: float | None = None,
                    keep_on_device: bool = False) -> np.ndarray | DeviceArray:
        """Scores at candidates given by flat indices from :meth:`flat_bases` or
        :meth:`lattice_bases`.

        The bases are not checked again: searches that score subsets of one candidate
        set many times (M1's cascade) convert the origins once and index the result.

        Args:
            values: as for :meth:`__call__`.
            bases: (N,) int32, N >= 1, made by :meth:`flat_bases` or :meth:`lattice_bases`.
            threshold, keep_on_device: as for :func:`score_gather`.

        Returns:
            (N,) scores, as :meth:`__call__` with the matching origins returns.
        """
        vals, thr = self._check_query(values, threshold)
        bases = np.ascontiguousarray(bases, np.int32)
        if bases.ndim != 1 or bases.size == 0:
            raise ValueError(f"bases must be a non-empty 1-D array, got shape {bases.shape}.")
        return self._launch(vals, thr, bases, keep_on_device)

    def _check_query(self, values, threshold):
        """The query values (host array) and the threshold as a one-element array or None."""
        k, channels = self._k, self._channels
        vals = _checks.same_kind("values", values, "grid", self._source)
        if isinstance(vals, DeviceArray):
            raise TypeError("values must be a host array (it is small and uploaded per call).")
        if vals.shape not in ((k, channels),) + (((k,),) if channels == 1 else ()):
            want = f"({k}, {channels})" + (f" or ({k},)" if channels == 1 else "")
            raise ValueError(f"values must have shape {want} to match {k} offsets and {channels} channel(s), got {vals.shape}.")
        vals_range = _checks.finite_range("values", vals)
        if vals_range is not None:
            _checks.check_float_scores("grid and values", self._grid_range, vals_range, self._total_weight)
        thr = None
        if threshold is not None:
            if not (np.isscalar(threshold) and np.isfinite(threshold) and threshold >= 0):
                raise ValueError(f"threshold must be a finite number >= 0, got {threshold!r}.")
            if self._grid_dtype == np.uint8:
                thr = np.array([min(int(np.floor(threshold)), _checks.UINT32_MAX)], np.uint32)
            else:
                thr = np.array([threshold], np.float32)
                if float(thr[0]) < float(threshold):  # never below the caller's bound
                    thr[0] = np.nextafter(thr[0], np.float32(np.inf))
        return vals, thr

    def _launch(self, vals, thr, bases, keep_on_device):
        """One kernel launch: the lattice (bases None) or explicit flat bases."""
        if bases is None:
            lattice, steps, base0 = self._lattice_xyz, self._lattice_steps, self._lattice_base0
            n = int(np.prod(self.lattice))
        else:
            n = bases.shape[0]
            lattice, steps, base0 = (n, 1, 1), (0, 0, 0), 0
        backend = self.backend
        out = backend.empty((n,), _score_dtype(self._grid_dtype))
        if bases is None and self._poly_args is not None:
            grid, flat_off, lattice, steps, base0 = self._polyphase()
        else:
            grid, flat_off = self._regular()
        backend.ssd_gather(
            grid, None if bases is None else backend.to_device(bases),
            lattice, steps, base0, flat_off,
            backend.to_device(np.ascontiguousarray(vals.reshape(-1))), self._weights,
            self._k * self._channels, None if thr is None else backend.to_device(thr), out,
            run=self._run if bases is not None else 0,
        )
        return out if keep_on_device else out.numpy()

    def _regular(self):
        """The grid (periodically padded for wrap) and flat offsets on the device, made once."""
        if self._grid is None:
            grid, pad = self._source, self._pad
            if pad is not None:
                if isinstance(grid, DeviceArray):  # padded once per padding, then cached with the grid
                    grid = grid.derived(("wrap", pad), lambda host: np.pad(host, pad, mode="wrap"))
                else:
                    grid = np.pad(grid, pad, mode="wrap")
            self._grid = _upload(self.backend, grid)
            self._flat_off = self.backend.to_device(self._flat_off_host)
        return self._grid, self._flat_off

    def _polyphase(self):
        """The lattice problem on the polyphase copy of the grid, made once and cached."""
        if self._poly is None:
            source = self._source
            off, step, lo = self._poly_args
            key = ("polyphase", tuple(int(v) for v in step), tuple(int(v) for v in lo), self._wrap,
                   tuple(self.lattice), tuple(int(v) for v in off.min(0)), tuple(int(v) for v in off.max(0)))
            make = functools.partial(_polyphase_layout, nd=self._nd, channels=self._channels, step=step, lo=lo,
                                     lattice=self.lattice, omin=off.min(0), omax=off.max(0), wrap=self._wrap)
            planes, strides = make(None)[1]
            size = int(np.prod(step)) * planes * self._channels
            if size > _INT32_LIMIT:
                raise ValueError(f"the strided lattice's copy of the grid ({size} elements) exceeds 2^31; split the grid.")
            if isinstance(source, DeviceArray):  # made once per layout, then cached with the grid
                grid = source.derived(key, lambda host: make(host)[0])
            else:
                grid = self.backend.to_device(make(source)[0])
            q = np.floor_divide(off, step) - np.floor_divide(off.min(0), step)  # (K, nd) index within a plane
            r = np.mod(off, step)  # (K, nd) plane of the residue
            plane = np.ravel_multi_index(tuple(r.T), tuple(int(v) for v in step))
            flat = plane * planes + q @ strides
            channel_plane = int(np.prod(step)) * planes
            flat_off = (flat[:, None] + channel_plane * np.arange(self._channels)[None, :]).reshape(-1).astype(np.int32)
            full = np.concatenate([np.ones(3 - self._nd, np.int64), np.asarray(self.lattice, np.int64)])
            st = np.concatenate([np.zeros(3 - self._nd, np.int64), strides])
            lattice = (int(full[2]), int(full[1]), int(full[0]))
            steps = (1, int(st[1]), int(st[0]))
            self._poly = (grid, self.backend.to_device(flat_off), lattice, steps, 0)
        return self._poly


def _polyphase_layout(host, *, nd, channels, step, lo, lattice, omin, omax, wrap):
    """Reorder a grid so that a strided lattice reads contiguous rows.

    For each channel and each residue r of the position modulo the stride (per axis),
    a plane holds ``grid[lo + step * (i + floor(omin / step)) + r]`` at index i
    (wrapped for periodic grids, clamped where no candidate reads). A candidate c with
    offset d then reads plane ``d mod step`` at ``c + floor(d / step) - floor(omin /
    step)``: neighbouring candidates read neighbouring elements, for every offset and
    channel, which the 16-wide gather kernel loads as vectors.

    Args:
        host: (spatial..., [C]) grid, or None to get only the geometry.
        channels: C (1 for a grid without a channel axis).
        step, lo, lattice, omin, omax: (nd,) stride, first origin, lattice shape and
            the offsets' per-axis minimum and maximum.

    Returns:
        (array of shape (C, step..., n...) or None, (elements per plane, (nd,) element
        strides of the index within a plane)).
    """
    step = np.asarray(step, np.int64)
    q_lo, q_hi = np.floor_divide(omin, step), np.floor_divide(omax, step)
    n = np.asarray(lattice, np.int64) + q_hi - q_lo
    strides = np.ones(nd, np.int64)
    for a in range(nd - 2, -1, -1):
        strides[a] = strides[a + 1] * n[a + 1]
    geometry = (int(np.prod(n)), strides)
    if host is None:
        return None, geometry
    dims = host.shape[:nd]
    index = []
    for a in range(nd):
        pos = lo[a] + step[a] * (np.arange(n[a])[None, :] + q_lo[a]) + np.arange(step[a])[:, None]  # (s, n)
        index.append(np.mod(pos, dims[a]) if wrap else np.clip(pos, 0, dims[a] - 1))
    picked = host[np.ix_(*[p.reshape(-1) for p in index])]  # (s0*n0, s1*n1, ..., [C])
    picked = picked.reshape(sum(([int(step[a]), int(n[a])] for a in range(nd)), []) + [channels])
    order = [2 * nd] + [2 * a for a in range(nd)] + [2 * a + 1 for a in range(nd)]
    return np.ascontiguousarray(picked.transpose(order)), geometry
