"""How does an OpenCL device launch the fused cascade search? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.2 (eq. 2).

OpenCL backend methods for the fused M1 cascade search (mixed into OpenCLBackend).

Launches the kernel of ``kernels/cascade.cl`` (same arguments in the same order as
``WarpCascadeOps``); see there for the definitions.
"""

from __future__ import annotations

from geosynth._backends.interfaces import CascadeOps

import numpy as np

_LOCAL = 64  # work-items per group on a GPU (see opencl_backend._LOCAL_1D)


class OpenCLCascadeOps(CascadeOps):
    """Mixin: the fused cascade search on an OpenCL device."""

    def cascade_search(self, field, coarse, coarse_norm, fine, lx, ly, lz, sy, sz, n, offsets, query_terms, inv_c,
                       inv_f, queries, rows, items, n_queries, margin, slack, best_all, out) -> None:
        local = 1 if self.is_cpu else _LOCAL  # one work-group per item on a CPU: the items balance the cores
        self._kernel("cascade", "cascade_search", np.uint8)(
            self.queue, (-(-(items * n_queries) // local) * local,), (local,), field.data, coarse.data,
            coarse_norm.data, fine.data, lx, ly, lz, sy, sz, n, offsets.data, query_terms.data, inv_c, inv_f,
            queries.data, rows, items, n_queries, margin, slack, best_all.data, out.data,
        )
