"""How does a Warp device launch the M3 growth kernel? Zhang, Qiu and Kaufman, "Fast Hybrid
Approach for Texturing Point Models", Sec. 3.2-3.4 and 4.2.

Warp backend methods for the M3 patch growth (mixed into WarpBackend).

Launches the kernel of ``geosynth.kernels.growth``; see there for the definitions.
"""

from __future__ import annotations

import warp as wp

from geosynth.kernels import growth as growth_kernels


class WarpGrowthOps:
    """Mixin: the sequential patch growth on a Warp device."""

    def grow_patches(self, n, k, inputs, dir_step, unit, weights, threshold, max_patch, n_buckets, outputs, scratch) -> None:
        """Grow every patch of a point model in one thread (kernels/growth.py).

        Args:
            n, k: points and neighbours per point.
            inputs: DeviceArrays pos (n*3 float64), nrm (n*3 float64), nb (n*k int32),
                order (n int32), dirs (3 or n*3 float64): the seed frames' directions.
            dir_step: 0 for one direction, 1 for one per point.
            unit: world length of a texel; weights: (w1, w2, w3, w4); threshold: the
                distortion bound; max_patch: largest patch extent in texels (<= 0: none);
                n_buckets: priority levels of the queue.
            outputs: DeviceArrays state, patch (n int32), uv (n*2), fn, fs, ft (n*3),
                distortion (n) float64, seeds (n int32), counts (1 int32).
            scratch: DeviceArrays key, slot, next, prev, touched (n int32), head, tail
                (n_buckets int32), terms (k*12 float64).
        """
        f64 = wp.float64
        self._launch(growth_kernels.grow_patches_kernel, 1,
                     [n, k, *(a.data for a in inputs), dir_step, f64(unit), *(f64(w) for w in weights), f64(threshold),
                      f64(max_patch), n_buckets, *(a.data for a in outputs), *(a.data for a in scratch)])

    def blend_gaps(self, n, k, inputs, unit, tex, h, w, wrap, offsets, n_buckets, in_out, outputs, scratch) -> None:
        """Colour the patch points, then blend the gap points in one thread (kernels/growth.py).

        Args:
            n, k: points and neighbours per point.
            inputs: DeviceArrays pos, nrm (n*3 float64), nb (n*k int32), state (n int32).
            unit: world length of a texel; tex: (h*w*3,) uint8 DeviceArray; wrap: 1 for
                periodic lookups; offsets: (patches*2,) float64 DeviceArray; n_buckets:
                priority levels of the queue.
            in_out: DeviceArrays patch (n int32), uv (n*2), fn, fs, ft (n*3 float64).
            outputs: DeviceArrays colours (n*3 float64), coloured (n int32).
            scratch: DeviceArrays key, slot, next, prev (n int32), head, tail (n_buckets
                int32), terms (k*16 float64).
        """
        self._launch(growth_kernels.blend_gaps_kernel, 1,
                     [n, k, *(a.data for a in inputs), wp.float64(unit), tex.data, h, w, wrap, offsets.data,
                      n_buckets, *(a.data for a in in_out), *(a.data for a in outputs),
                      *(a.data for a in scratch)])

    def match_coherent(self, n, k, inputs, unit, grid, xp, pad, m, h, w, tileable, subtexel, shifts1, n_shift1, ring,
                       order, rand_texel, n_buckets, in_out, scratch) -> None:
        """Coherent neighbourhood matching of one level in one thread (kernels/growth.py).

        Args:
            n, k: points and neighbours per point.
            inputs: DeviceArrays pos, nrm, s_axis, t_axis (n*3 float64), nb (n*k int32).
            unit: world length of a texel; grid: flat uint8 DeviceArray, the padded
                supersampled texture, xp pixels per row, pad pixels of padding, m the
                supersampling factor, h x w texels; tileable, subtexel: 0 or 1.
            shifts1: (n_shift1*2,) int32 DeviceArray, the first refinement shifts; ring: 0 or 1.
            order: (n,) int32 and rand_texel (n,) int32 DeviceArrays; n_buckets: priority levels.
            in_out: DeviceArrays coloured (n int32), colours (n*3 uint8), source (n int32).
            scratch: DeviceArrays key, slot, next, prev (n int32), head, tail (n_buckets
                int32), rel (k int32), vals (k*3 uint8), cand (k int32).
        """
        self._launch(growth_kernels.match_coherent_kernel, 1,
                     [n, k, *(a.data for a in inputs), wp.float64(unit), grid.data, xp, pad, m, h, w, tileable,
                      subtexel, shifts1.data, n_shift1, ring, order.data, rand_texel.data, n_buckets,
                      *(a.data for a in in_out), *(a.data for a in scratch)])
