"""Candidate SSD scoring: every present backend against NumPy and faiss, in one run.

Cases:
- dense (N, D) = (1,000,000, 64), (200,000, 512), (30,000, 4,096), with 1 and 64
  queries, float32 and uint8;
- gather: all 117,649 16^3 blocks of a 64^3 uint8 field, one query block;
- gather: a 128 x 128 x 3 texture supersampled x8, 25 offsets, all 16,384 texels.

geosynth rows time the call with candidates already on the device (uploaded once, as
the methods do) and, for single queries, the argmin on the device too; peers get their
preprocessing (faiss index build, NumPy norms, window unpacking) untimed as well.

Usage: python bench/bm_scoring.py [--quick] [--devices cpu,opencl:0:0] [--out FILE]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import Row, finish, parse_args, start, table, time_call  # noqa: E402

import geosynth  # noqa: E402
from geosynth.compute.scoring import GatherScorer  # noqa: E402

try:
    import faiss

    FAISS_ERROR = None
except Exception as exc:  # optional peer
    faiss, FAISS_ERROR = None, exc


def dense_rows(devices, n, d, b, dtype, rng, slow_peers: bool) -> list[Row]:
    case = f"dense {np.dtype(dtype).name} N={n:,} D={d} B={b}"
    if dtype == np.uint8:
        x = rng.integers(0, 256, (n, d), dtype=np.uint8)
        q = rng.integers(0, 256, (b, d), dtype=np.uint8)
    else:
        x = rng.random((n, d), dtype=np.float32)
        q = rng.random((b, d), dtype=np.float32)
    elements, nbytes = float(n) * d * b, float(x.nbytes)
    rows = []
    print(f"  {case}", flush=True)

    for dev in devices:
        xd = geosynth.to_device(x, dev)
        backend = geosynth.get_backend(dev)
        if b == 1:
            def run(xd=xd):
                return geosynth.argmin(geosynth.score_dense(xd, q[0], keep_on_device=True))
            note = "scores + argmin on device"
        else:
            def run(xd=xd, backend=backend):
                geosynth.score_dense(xd, q, keep_on_device=True)
                backend.synchronize()
            note = f"all {b} x N scores, kept on device"
        slow = dev == "cpu" and elements > 1e9  # Warp's CPU backend is single-threaded
        t = time_call(run, min_time=0 if slow else 0.3, warmup=1, max_repeats=1 if slow else 50)
        rows.append(Row(case, f"geosynth {dev}", t, elements, nbytes, False, note))

    # NumPy, direct: one pass per query (uint8 via a precomputed int32 copy).
    xi = x.astype(np.int32) if dtype == np.uint8 else x
    qi = q.astype(np.int32) if dtype == np.uint8 else q

    def numpy_direct():
        for j in range(b):
            diff = xi - qi[j]
            np.einsum("ij,ij->i", diff, diff)

    if b == 1 or slow_peers:
        rows.append(Row(case, "numpy direct", time_call(numpy_direct, min_time=0 if b > 1 else 0.3, warmup=0 if b > 1 else 1),
                        elements, nbytes, True, "int32 copy for uint8" if dtype == np.uint8 else ""))

    # NumPy, GEMM identity ||x||^2 - 2 x.q + ||q||^2 (float32; inexact for large uint8 sums).
    xf, qf = x.astype(np.float32), q.astype(np.float32)
    xn = np.einsum("ij,ij->i", xf, xf)

    def numpy_gemm():
        return xn[None, :] - 2.0 * (qf @ xf.T) + np.einsum("ij,ij->i", qf, qf)[:, None]

    rows.append(Row(case, "numpy gemm", time_call(numpy_gemm, min_time=0.3), elements, nbytes, True, "norms precomputed"))

    if faiss is not None:
        if dtype == np.uint8:
            index = faiss.IndexScalarQuantizer(d, faiss.ScalarQuantizer.QT_8bit)
            index.train(xf)
            label = "faiss SQ8 (k=1)"
        else:
            index = faiss.IndexFlatL2(d)
            label = "faiss IndexFlatL2 (k=1)"
        index.add(xf)
        rows.append(Row(case, label, time_call(lambda: index.search(qf, 1), min_time=0.3), elements, nbytes, True, "top-1 only"))
        del index
    return rows


def block_offsets(size: int) -> np.ndarray:
    return np.stack(np.meshgrid(*[np.arange(size)] * 3, indexing="ij"), -1).reshape(-1, 3)


def gather_blocks_rows(devices, rng, size=64, block=16) -> list[Row]:
    case = f"gather uint8 {size}^3 field, all {block}^3 blocks"
    print(f"  {case}", flush=True)
    from geosynth.volume.examples import spheres_field
    from geosynth.volume.synthesis import quantize_field

    field = quantize_field(spheres_field(size, count=40, seed=1), band=4.0)
    off = block_offsets(block)
    origin = rng.integers(0, size - block + 1, 3)
    vals = field[tuple((origin + off).T)]
    ncand = (size - block + 1) ** 3
    elements, nbytes = float(ncand) * len(off), float(ncand) * len(off)  # bytes of the virtual windows
    rows = []
    for dev in devices:
        gd = geosynth.to_device(field, dev)

        def run(gd=gd):
            return geosynth.argmin(geosynth.score_gather(gd, off, vals, keep_on_device=True))

        rows.append(Row(case, f"geosynth {dev}", time_call(run, min_time=0.3), elements, nbytes, False, "scores + argmin on device"))

    windows = np.lib.stride_tricks.sliding_window_view(field, (block,) * 3)  # a view, no copy
    q32 = vals.reshape((block,) * 3).astype(np.int32)

    def numpy_slabs():
        out = np.empty((size - block + 1,) * 3, np.int64)
        for z in range(size - block + 1):
            diff = windows[z].astype(np.int32) - q32
            out[z] = np.einsum("abijk,abijk->ab", diff, diff)
        return int(np.argmin(out))

    rows.append(Row(case, "numpy (sliding windows, z-slabs)", time_call(numpy_slabs, min_time=0, warmup=0),
                    elements, nbytes, True, "argmin included"))
    if faiss is not None:
        unpacked = np.ascontiguousarray(windows.reshape(-1, block**3)).astype(np.float32)  # 1.9 GB, untimed
        qf = vals.astype(np.float32)[None, :]
        for label, index in (("faiss IndexFlatL2 (k=1)", faiss.IndexFlatL2(block**3)),
                             ("faiss SQ8 (k=1)", faiss.IndexScalarQuantizer(block**3, faiss.ScalarQuantizer.QT_8bit))):
            if not index.is_trained:
                index.train(unpacked[::16])
            index.add(unpacked)
            rows.append(Row(case, label, time_call(lambda: index.search(qf, 1), min_time=0.3), elements, nbytes, True,
                            "windows unpacked beforehand (untimed)"))
            del index
        del unpacked
    return rows


def gather_texture_rows(devices, rng, size=128, factor=8, k=25) -> list[Row]:
    case = f"gather float32 {size}x{size}x3 texture x{factor}, {k} offsets, all texels"
    print(f"  {case}", flush=True)
    texture = rng.random((size, size, 3), dtype=np.float32)
    big = np.ascontiguousarray(np.repeat(np.repeat(texture, factor, 0), factor, 1))
    off = rng.integers(-3 * factor, 3 * factor + 1, (k, 2))
    vals = rng.random((k, 3), dtype=np.float32)
    ncand = size * size
    elements, nbytes = float(ncand) * k * 3, float(ncand) * k * 3 * 4
    rows = []
    for dev in devices:
        bd = geosynth.to_device(big, dev)
        # Like the faiss index below, the scorer (offsets uploaded, the strided lattice's
        # polyphase copy of the texture) is built before timing; one-shot score_gather
        # calls, which rebuild it (the copy itself stays cached with bd), are timed too.
        scorer = GatherScorer(bd, off, stride=factor, wrap=True)

        def run(scorer=scorer):
            return geosynth.argmin(scorer(vals, keep_on_device=True))

        def run_once(bd=bd):
            return geosynth.argmin(geosynth.score_gather(bd, off, vals, stride=factor, wrap=True, keep_on_device=True))

        rows.append(Row(case, f"geosynth {dev}", time_call(run, min_time=0.3), elements, nbytes, False,
                        "periodic texture on device, GatherScorer built beforehand (untimed); scores + argmin"))
        rows.append(Row(case, f"geosynth {dev} (score_gather)", time_call(run_once, min_time=0.3), elements, nbytes, False,
                        "one-shot call: scorer set-up timed too; scores + argmin"))
    ys, xs = np.meshgrid(np.arange(size) * factor, np.arange(size) * factor, indexing="ij")
    ys, xs = ys.reshape(-1), xs.reshape(-1)
    h, w = big.shape[:2]

    def numpy_gather():
        acc = np.zeros(ncand, np.float32)
        for (dy, dx), v in zip(off, vals):
            diff = big[(ys + dy) % h, (xs + dx) % w] - v
            acc += np.einsum("ij,ij->i", diff, diff)
        return int(np.argmin(acc))

    rows.append(Row(case, "numpy (fancy indexing)", time_call(numpy_gather, min_time=0.3), elements, nbytes, True, "argmin included"))
    if faiss is not None:
        feats = np.stack([big[(ys + dy) % h, (xs + dx) % w] for dy, dx in off], 1).reshape(ncand, -1)
        index = faiss.IndexFlatL2(feats.shape[1])
        index.add(np.ascontiguousarray(feats))
        qf = vals.reshape(1, -1)
        rows.append(Row(case, "faiss IndexFlatL2 (k=1)", time_call(lambda: index.search(qf, 1), min_time=0.3), elements, nbytes,
                        True, "neighbourhoods unpacked beforehand (untimed)"))
    return rows


def options(argv=None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    return parse_args(__doc__, argv, quick="small sizes, for a smoke run", extras=lambda p: p.add_argument(
        "--no-slow-peers", action="store_true", help="skip NumPy direct for 64-query batches"))


def main(argv=None) -> int:
    args = options(argv)
    devices = start(args)
    rng = np.random.default_rng(0)
    print(f"'auto' resolves to: {geosynth.get_backend('auto').name}")
    if faiss is None:
        print(f"faiss is not available ({FAISS_ERROR}); its rows are left out. `make bench` installs faiss-cpu.")

    shapes = [(1_000_000, 64), (200_000, 512), (30_000, 4096)]
    if args.quick:
        shapes = [(20_000, 64), (4_000, 512), (600, 4096)]
    rows: list[Row] = []
    for dtype in (np.float32, np.uint8):
        for n, d in shapes:
            for b in (1, 64):
                rows += dense_rows(devices, n, d, b, dtype, rng, slow_peers=not args.no_slow_peers)
    rows += gather_blocks_rows(devices, rng, size=32 if args.quick else 64, block=8 if args.quick else 16)
    rows += gather_texture_rows(devices, rng, size=32 if args.quick else 128)
    return finish(table(rows), args)


if __name__ == "__main__":
    sys.exit(main())
