"""How does a Warp device launch FindMatches? Breckon and Fisher, "3D Surface Relief and
Colour Completion", Sec. 3 and Appendix A.

Warp backend methods for M4's FindMatches (mixed into WarpBackend).

Implements geosynth._backends.interfaces.ReliefOps (the docstrings are there) with the
kernels of ``geosynth.kernels.relief``.
"""

from __future__ import annotations

from geosynth._backends.interfaces import ReliefIndexArrays, ReliefOps, ReliefQueryArrays
from geosynth.core.arrays import DeviceArray
from geosynth.kernels import relief as relief_kernels


class WarpReliefOps(ReliefOps):
    """Mixin: FindMatches on a Warp device."""

    def relief_scores(self, index: ReliefIndexArrays, queries: ReliefQueryArrays, cand: DeviceArray, n_cand: int,
                      cand_stride: int, n_query: int, rotations: int, n_samples: int, out: DeviceArray) -> None:
        self._launch(relief_kernels.relief_scores_kernel, (n_query, rotations, n_cand),
                     [*index.buffers(), *queries.buffers(), cand.data, n_cand, cand_stride, n_query, rotations, n_samples, out.data])

    def relief_update(self, ids: DeviceArray, pos: DeviceArray, colour: DeviceArray, n: int, mark: int,
                      index: ReliefIndexArrays) -> None:
        self._launch(relief_kernels.relief_update_kernel, n,
                     [ids.data, pos.data, colour.data, n, mark, index.pos.data, index.colour.data, index.usable.data])
