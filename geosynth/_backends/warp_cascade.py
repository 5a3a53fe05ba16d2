"""How does a Warp device launch the fused cascade search? Lagae, Dumont and Dutré,
"Geometry Synthesis", Sec. 4.2 (eq. 2).

Warp backend methods for the fused M1 cascade search (mixed into WarpBackend).

Launches the kernel of ``geosynth.kernels.cascade`` (same arguments in the same order
as ``OpenCLCascadeOps``); see there and kernels/cascade.cl for the definitions.
"""

from __future__ import annotations

from geosynth._backends.interfaces import CascadeOps

from geosynth.kernels import cascade as cascade_kernels


class WarpCascadeOps(CascadeOps):
    """Mixin: the fused cascade search on a Warp device."""

    def cascade_search(self, field, coarse, coarse_norm, fine, lx, ly, lz, sy, sz, n, offsets, query_terms, inv_c,
                       inv_f, queries, rows, items, n_queries, margin, slack, best_all, out) -> None:
        self._launch(
            cascade_kernels.cascade_search_kernel, items * n_queries,
            [field.data, coarse.data, coarse_norm.data, fine.data, lx, ly, lz, sy, sz, n, offsets.data,
             query_terms.data, inv_c, inv_f, queries.data, rows, items, n_queries, margin, slack, best_all.data,
             out.data],
        )
