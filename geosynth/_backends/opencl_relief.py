"""How does an OpenCL device launch FindMatches? Breckon and Fisher, "3D Surface Relief and
Colour Completion", Sec. 3 and Appendix A.

OpenCL backend methods for M4's FindMatches (mixed into OpenCLBackend).

Implements geosynth._backends.interfaces.ReliefOps (the docstrings are there) with the
kernels of ``kernels/relief.cl``.
"""

from __future__ import annotations

import numpy as np

from geosynth._backends.interfaces import ReliefIndexArrays, ReliefOps, ReliefQueryArrays
from geosynth.core.arrays import DeviceArray

_LOCAL = 64  # work-items per group; always explicit (see opencl_backend._LOCAL_1D)


class OpenCLReliefOps(ReliefOps):
    """Mixin: FindMatches on an OpenCL device."""

    def relief_scores(self, index: ReliefIndexArrays, queries: ReliefQueryArrays, cand: DeviceArray, n_cand: int,
                      cand_stride: int, n_query: int, rotations: int, n_samples: int, out: DeviceArray) -> None:
        i32 = np.int32
        k = self._kernel("relief", "relief_scores", np.float64)
        g = n_cand * rotations
        k(self.queue, (-(-g // _LOCAL) * _LOCAL, n_query), (_LOCAL, 1), *index.buffers(), *queries.buffers(),
          cand.data, i32(n_cand), i32(cand_stride), i32(n_query), i32(rotations), i32(n_samples), out.data)

    def relief_update(self, ids: DeviceArray, pos: DeviceArray, colour: DeviceArray, n: int, mark: int,
                      index: ReliefIndexArrays) -> None:
        i32 = np.int32
        k = self._kernel("relief", "relief_update", np.float64)
        k(self.queue, (-(-n // _LOCAL) * _LOCAL,), (_LOCAL,), ids.data, pos.data, colour.data, i32(n), i32(mark),
          index.pos.data, index.colour.data, index.usable.data)
