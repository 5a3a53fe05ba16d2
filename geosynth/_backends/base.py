"""What do both backends do on the host around their kernels? Implements no paper section.

What both backends share: the host-side steps around their kernels.

A backend subclasses :class:`Backend` and implements the primitives, one per kernel
(same names and argument order as ``kernels/ssd.py`` / ``kernels/ssd.cl``) plus
memory transfer. The multi-pass operations built on them (argmin from partials,
selection by count + prefix + compact) are written once, here.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np

from geosynth.core.arrays import NONFINITE_SCORES, DeviceArray


class Backend(ABC):
    """One device. Methods take and return DeviceArrays of this backend.

    Attributes:
        name: canonical device string ("cpu", "cuda:0", "opencl:0:0").
        kind: "cpu", "cuda" or "opencl".
        partial_threads: how many threads the reductions use (argmin, selection).
        host_reduce_below: argmin reads fewer scores than this back and reduces them
            on the host (where memory is shared, one copy is cheaper than a launch).
        launch_work: sample comparisons worth one kernel launch and its host round
            trip (measured order of magnitude); searches that can split work into
            several small launches do so only when the work is well beyond it.
        bound_cells_per_side: M1's cascade search by default: its bound stages, as
            cells per block side, coarse to fine. (2, 4): 2^3 then 4^3 cell sums, the
            second only over the first's survivors (fewer comparisons: best where
            compute is scarce, Warp's one CPU thread); (4,): one 4^3-cell stage over
            every block (fewer launches and host steps: best on PoCL, measured).
        search_items: how many work-items M1's fused cascade search splits the
            lattice rows into: a few per core on a CPU (they share the best SSD found,
            so fewer, longer items prune more), one row each on a GPU.
    """

    name: str
    kind: str
    partial_threads: int = 1024
    host_reduce_below: int = 0
    launch_work: float = 1e5
    bound_cells_per_side: tuple[int, ...] = (2, 4)
    search_items: int = 1 << 16

    # -- memory -------------------------------------------------------------------
    @abstractmethod
    def to_device(self, array: np.ndarray) -> DeviceArray:
        """Copy a contiguous host array to the device."""

    @abstractmethod
    def empty(self, shape: tuple[int, ...], dtype: np.dtype) -> DeviceArray:
        """Allocate an uninitialised device array."""

    @abstractmethod
    def to_host(self, array: DeviceArray) -> np.ndarray:
        """Copy a device array to the host (a synchronization point)."""

    def to_host_all(self, arrays: Sequence[DeviceArray]) -> list[np.ndarray]:
        """Copy several device arrays to the host with one synchronization (where the backend can)."""
        return [self.to_host(a) for a in arrays]

    @abstractmethod
    def synchronize(self) -> None:
        """Wait until every launched kernel has finished."""

    # -- kernels (one method per kernel; no validation below the public API) -------
    @abstractmethod
    def ssd_dense(self, candidates: DeviceArray, queries: DeviceArray, weights: DeviceArray | None, n: int, d: int,
                  b: int, out: DeviceArray) -> None:
        """out (b * n,) <- weighted SSD of every query row against every candidate row.

        candidates: (n * d,) uint8 or float32 rows; queries: (b * d,) same dtype; weights:
        (d,) same dtype or None (all 1); out: uint32 for uint8 data (exact integer sums),
        float32 for float32 data; query-major (entry q * n + c).
        """

    @abstractmethod
    def ssd_gather(self, grid: DeviceArray, bases: DeviceArray | None, lattice: tuple[int, int, int],
                   steps: tuple[int, int, int], base0: int, offsets: DeviceArray, values: DeviceArray,
                   weights: DeviceArray | None, kc: int, threshold: DeviceArray | None, out: DeviceArray,
                   run: int = 0) -> None:
        """out (candidates,) <- SSD of the query entries at base(c) + offsets for every candidate c.

        grid: flat uint8 or float32; offsets: (kc,) int32 flat offsets from a candidate's
        base; values: (kc,) the query's entries (grid dtype); weights: (kc,) or None.
        ``bases`` is a DeviceArray of explicit int32 base indices or None for the lattice
        (nx, ny, nz) with flat steps (step_x, step_y, step_z) starting at base0.
        ``threshold``: None, or a (1,) DeviceArray of the score dtype above which a
        candidate may stop early and report any value above it.
        ``run``: 0, or the length (a multiple of 16 dividing 256) of the runs of
        consecutive flat offsets that the entries come in (a block's x rows); a hint a
        backend may use for explicit bases, never a change of the result.
        """

    @abstractmethod
    def argmin_partials(self, scores: DeviceArray, n: int, part_val: DeviceArray, part_idx: DeviceArray) -> None:
        """Per-thread minimum and its lowest index over a share of scores (n,): part_val
        (g,) scores' dtype, part_idx (g,) int32 (-1 for an empty share, -2 for a share
        holding a NaN or inf score); g = part_idx.size threads."""

    @abstractmethod
    def count_selected(self, scores: DeviceArray, n: int, chunk: int, thr: DeviceArray, mode: int,
                       counts: DeviceArray) -> None:
        """counts[t] (int32) <- how many scores in chunk t (entries [t * chunk, (t + 1) * chunk)
        of n) the threshold thr (1,) selects (mode: SELECT_* of geosynth.core.arrays)."""

    @abstractmethod
    def compact_selected(self, scores: DeviceArray, n: int, chunk: int, thr: DeviceArray, mode: int,
                         starts: DeviceArray, out_idx: DeviceArray) -> None:
        """out_idx (int32) <- the selected indices, ascending, chunk t written from starts[t]
        (the exclusive prefix sum of count_selected's counts)."""

    # -- host-side steps shared by both backends ------------------------------------
    def argmin(self, scores: DeviceArray) -> tuple[int, np.generic]:
        """Index of the smallest score (the lowest index on ties) and that score.

        Raises:
            ValueError: a float score is NaN or inf (no index is returned for them).
        """
        n = scores.size
        if n <= self.host_reduce_below:  # one read beats a kernel plus a read
            host = self.to_host(scores).reshape(-1)
            if host.dtype.kind == "f" and not np.isfinite(host).all():
                raise ValueError(NONFINITE_SCORES)
            i = int(np.argmin(host))  # the first minimum: the lowest index on ties
            return i, host[i]
        g = max(1, min(n, self.partial_threads))
        part_val = self.empty((g,), scores.dtype)
        part_idx = self.empty((g,), np.int32)
        self.argmin_partials(scores, n, part_val, part_idx)
        # sync: the orchestrator needs the index now; g values come back, not n.
        vals, idx = self.to_host_all((part_val, part_idx))
        if (idx == -2).any():  # a share saw a NaN or inf score
            raise ValueError(NONFINITE_SCORES)
        valid = idx >= 0
        vals, idx = vals[valid], idx[valid]
        best = vals.min()
        return int(idx[vals == best].min()), best

    def select(self, scores: DeviceArray, threshold, mode: int) -> np.ndarray:
        """Indices (int64, ascending) of the scores that ``threshold`` selects under ``mode``."""
        n = scores.size
        g = max(1, min(n, self.partial_threads))
        chunk = -(-n // g)
        thr = self.to_device(np.array([threshold], dtype=scores.dtype))
        counts = self.empty((g,), np.int32)
        self.count_selected(scores, n, chunk, thr, mode, counts)
        # sync: the prefix sum of g counts is done on the host.
        host_counts = self.to_host(counts).astype(np.int64)
        total = int(host_counts.sum())
        if total == 0:
            return np.zeros(0, np.int64)
        starts = np.zeros(g, np.int32)
        starts[1:] = np.cumsum(host_counts[:-1])
        out_idx = self.empty((total,), np.int32)
        self.compact_selected(scores, n, chunk, thr, mode, self.to_device(starts), out_idx)
        # sync: the selected indices are the answer.
        return self.to_host(out_idx).astype(np.int64)

    def count(self, scores: DeviceArray, threshold, mode: int) -> int:
        """How many scores ``threshold`` selects under ``mode``."""
        n = scores.size
        g = max(1, min(n, self.partial_threads))
        chunk = -(-n // g)
        counts = self.empty((g,), np.int32)
        thr = self.to_device(np.array([threshold], dtype=scores.dtype))
        self.count_selected(scores, n, chunk, thr, mode, counts)
        # sync: a single count decides the next bisection step.
        return int(self.to_host(counts).astype(np.int64).sum())

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"
