"""M1 beyond one process: how is a large volume synthesized tile by tile on Dask, with the
same answer whatever the number of workers?

:func:`synthesize_volume_tiled` runs the M1 synthesis of :func:`geosynth.volume.synthesis.synthesize_volume`
(texture optimization per level, Kwatra, Essa, Bobick and Kwatra, "Texture Optimization
for Example-based Synthesis", SIGGRAPH 2005, or the scan, with graphcut pasting on a
slab, on the multiresolution block pyramid of Lagae, Dumont and Dutre, "Geometry
Synthesis", Sec. 5.2; the untiled synthesis's choices,
:func:`geosynth.volume.synthesis.choose_volume_settings`) as a task graph on
``dask.distributed``: the tiles, margins and the two-phase (checkerboard) schedule of
:mod:`geosynth.volume.tiles`; phase B tiles are constrained syntheses
(:func:`geosynth.volume.optimize.optimize_level` with ``fixed``, or the scan with the given
samples kept and the scan run away from them) against their phase-A neighbours' results.

- The engine: a ``LocalCluster`` by default (``workers`` processes of one thread), any
  running scheduler by address (``scheduler="tcp://..."``), an existing
  ``distributed.Client``, or Dask's threaded scheduler (``scheduler="threads"``). The
  exemplar's pyramid is scattered to every worker once; each worker builds each level's
  search (the exemplar on its device) once and keeps it for all its tiles.
- Each tile of each level is one task. Its inputs are crops: the samples of the coarser
  level that its upsampling reads and, in phase B, the parts of its margins that lie in
  phase-A neighbours' cores. A crop runs where its tile's result lies, so only margins
  travel between workers. Levels run one after another; the results of a level stay on
  the workers until the next level has read them.
- Output that need not fit in one process: a zarr store (the finest level's tile cores
  are its chunks; ``zarr.open_array(path)[...]`` or ``dask.array.from_zarr(path)``
  read it), per-tile meshes (marching cubes over the tile's core and one sample of its
  +x / +y neighbours, capped only at the target's faces, so neighbouring tiles'
  vertices coincide exactly along shared borders), one merged mesh when it fits in
  memory, and the field in memory when asked and it fits; anything that does not fit is
  refused before the run starts, with the estimate.
- Random draws come from (seed, level, tile index) (:func:`geosynth.volume.tiles.tile_rng`);
  every vote and cut runs in a fixed order, so the result depends only on the seed and
  the tiling: not on the number of workers, the engine, nor the order tasks finish in.
  One tile is exactly :func:`geosynth.volume.synthesis.synthesize_volume`'s result.
- Interruption: with ``checkpoint``, every tile and corner task's result is saved there
  as it finishes (atomically, by the worker); a run stopped by Ctrl-C, SIGTERM or a lost
  machine is continued with ``resume=True``, which loads the saved results instead of
  computing them again and gives the uninterrupted run's bits (the results depend only on
  the seed and the tiling). Outputs (store, tile meshes) are written to temporaries and
  moved into place only when the whole run has succeeded.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
import uuid
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from geosynth.core.config import TILE_LOCK, TILE_MATCHERS
from geosynth.core.constants import M1_DEFAULT_BLOCK
from geosynth.volume.options import TileOptions, VolumeOptions, parse_tiles, volume_options
from geosynth.volume.tiles import PHASE_A, PHASE_B, PHASE_C, Region, TileGrid, assemble, tile_rng, upsample_window

__all__ = ["TiledResult", "exemplar_source", "parse_tiles", "seam_report", "synthesize_volume_tiled", "tile_bytes", "tile_grid",
           "tile_task_bytes", "corner_task_bytes", "kept_bytes", "WORKER_RUNTIME_BYTES"]

# How long a scheduler given by address may take to answer before the run is refused.
CONNECT_TIMEOUT_S = 5.0
# Marching-cubes faces per target sample, from the exemplar's own faces per sample: the
# synthesis roughens the surface (measured 1.0-1.4x on the built-in terrain and chainmail).
FACES_GROWTH = 1.5
# Peak bytes per face of a mesh held and merged on the client (vertices, faces and the
# vertex de-duplication; geosynth.volume.synthesis measures 96-105 B per face for marching cubes).
MERGE_FACE_BYTES = 160
# Per sample of a tile's region, alive through its task: the uint8 target, the given
# mask and the fixed crops (phase B), the assembled coarser window (1/8).
_TILE_SAMPLE_BYTES = 4
# The trilinear x2 upsampling of the coarser crops (float32 passes, their taps and the
# rounded result: geosynth.volume.synthesis's 15 B per sample).
_UPSAMPLE_SAMPLE_BYTES = 15
# A task's Python objects, the crops' lists, the info dict.
_TASK_BYTES = 256 << 10
# A worker process before any tile: Python, NumPy, SciPy, Dask's worker, geosynth and the
# device runtime with its kernels. Measured (VmHWM of a LocalCluster worker after one
# small tile): 115 MiB on PoCL, 223 MiB on Warp CPU.
WORKER_RUNTIME_BYTES = 256 << 20


# ------------------------------------------------------------------ what every task reads


@dataclass
class _Exemplar:
    """The exemplar's pyramid and the run's parameters: scattered to every worker once."""

    sources: list  # uint8 (Z, Y, X) per level, coarsest first
    blocks: list  # per level: N, or a slab's (Z_l, N, N) (TileGrid.block_shape)
    caps: list
    device: str | None
    search: str
    seed: int
    key: str  # digest of the sources and parameters: the worker's search cache key
    method: str = "optimize"  # geosynth.volume.synthesis.METHODS: texture optimization or the scan (graphcut, paper)
    lattices: list | None = None  # per level: a slab scan's (2, 2) lattice vectors or None (synthesis.level_lattice)


def _matcher(ex: _Exemplar, level: int):
    from geosynth.volume.synthesis import Matcher

    k = (ex.key, level)
    if k not in TILE_MATCHERS:
        for old in [c for c in TILE_MATCHERS if c[0] != ex.key]:  # one exemplar at a time
            del TILE_MATCHERS[old]
        TILE_MATCHERS[k] = Matcher(ex.sources[level], ex.blocks[level], ex.device, ex.search)
    return TILE_MATCHERS[k]


def _crop(result, core: Region, part: Region):
    """(part, samples of ``part``) from a tile result (core array, info)."""
    return part, np.ascontiguousarray(result[0][core.local(part)])


def _identity(obj):
    return obj


def _info(result) -> dict:
    return result[1]


def _synthesize(ex: _Exemplar, grid: TileGrid, level: int, target: np.ndarray, fixed, offset=(0, 0)) -> dict:
    """One level of ``ex.method`` on a tile's or corner's ``target`` (in place), ``fixed``
    samples given: texture optimization (:func:`geosynth.volume.optimize.optimize_level`) or the
    scan of synthesize_volume (graphcut, paper; ``offset``: the (y, x) of ``target``'s first
    sample in the level, for the exemplar's lattice). Returns its matches, iterations,
    mean_distance and stopped."""
    from geosynth.volume.optimize import level_final, level_sigma, level_stride, optimize_level

    source, b, matcher = ex.sources[level], ex.blocks[level], _matcher(ex, level)
    if ex.method != "optimize":
        from geosynth.volume.synthesis import synthesize_level

        count, mean = synthesize_level(source, target, b, matcher, False, None, False, "", False,
                                        cut=ex.method == "graphcut", fixed=fixed,
                                        lattice=ex.lattices[level] if ex.lattices else None, offset=offset)
        return {"matches": count, "iterations": 1, "mean_distance": mean, "stopped": "scan"}
    finest = level == grid.levels - 1
    return optimize_level(source, target, b, matcher, iterations=int(ex.caps[level]),
                          stride=level_stride(grid.blocks[level], finest), sigma=level_sigma(finest),
                          final=level_final(finest), fixed=fixed)


def _tile_task(ex: _Exemplar, grid: TileGrid, level: int, index: int, init: list, fixed: list):
    """Synthesize one tile of one level; returns (core (Z, rows, columns) uint8, info)."""
    from geosynth.volume.optimize import random_blocks

    start = time.time()
    with TILE_LOCK:
        t0 = time.perf_counter()
        region, core = grid.region(level, index), grid.core_region(level, index)
        shape = grid.level_shape(level)
        source, b = ex.sources[level], ex.blocks[level]
        if level == 0:
            rng = np.random.default_rng(ex.seed) if grid.whole(level) else tile_rng(ex.seed, level, index)
            if ex.method == "optimize":
                target = random_blocks(source, (shape[0],) + region.shape, b, rng, False)
            else:  # the scan starts from random source samples, as synthesize_volume's
                n = int(np.prod((shape[0],) + region.shape))
                target = source.reshape(-1)[rng.integers(0, source.size, size=n)].reshape((shape[0],) + region.shape)
        else:
            cbox = grid.upsample_source(level, index)
            prev = grid.level_shape(level - 1)
            window, covered = assemble(prev[0], cbox, init)
            if not covered.all():
                raise RuntimeError(f"tile {index} level {level + 1}: the coarser level's crops miss samples.")
            target = upsample_window(window, cbox, prev, region, shape)
        mask = None
        if fixed:
            target, mask = assemble(shape[0], region, fixed, fill=target)
        got = _synthesize(ex, grid, level, target, mask, (region.y0, region.x0))
        out = np.ascontiguousarray(target[region.local(core)])
        seconds = time.perf_counter() - t0
    info = {"level": level, "tile": index, "phase": grid.phase(index), "start": start, "end": time.time(),
            "seconds": seconds, "matches": got["matches"], "iterations": got["iterations"],
            "mean_distance": got["mean_distance"], "stopped": got["stopped"], "pid": os.getpid()}
    return out, info


def _corner_task(ex: _Exemplar, grid: TileGrid, level: int, k: int, pieces: list):
    """Phase C: re-synthesize the free square of corner ``k`` of ``level`` with the rest
    of its window (from the four tiles' final cores) fixed. Returns (free square's
    samples (Z, rows, columns) uint8, info). Draws nothing at random."""
    start = time.time()
    with TILE_LOCK:
        t0 = time.perf_counter()
        window, free = grid.corner_window(level, k), grid.corner_free(level, k)
        z = grid.level_shape(level)[0]
        target, covered = assemble(z, window, pieces)
        if not covered.all():
            raise RuntimeError(f"corner {k} level {level + 1}: the tiles' crops miss samples.")
        mask = np.ones(target.shape, bool)
        mask[window.local(free)] = False
        got = _synthesize(ex, grid, level, target, mask, (window.y0, window.x0))
        out = np.ascontiguousarray(target[window.local(free)])
        seconds = time.perf_counter() - t0
    info = {"level": level, "corner": k, "phase": PHASE_C, "start": start, "end": time.time(), "seconds": seconds,
            "matches": got["matches"], "iterations": got["iterations"], "mean_distance": got["mean_distance"],
            "stopped": got["stopped"], "pid": os.getpid()}
    return out, info


def _patched(result, core: Region, patches: list):
    """A tile result (core, info) with the corner squares' parts in its core written in."""
    out = result[0].copy()
    for part, values in patches:
        out[core.local(part)] = values
    return out, result[1]


def _corner_part(result, free: Region, part: Region):
    """(part, its samples) of a corner task's free square."""
    return part, np.ascontiguousarray(result[0][free.local(part)])


# ------------------------------------------------------------------ checkpoints (resume)

_MANIFEST = "manifest.json"


def _resumable(folder: str | None, name: str, task, *args):
    """``task(*args)``, its (samples, info) result saved in ``folder`` as ``name``.npz; or,
    when the folder already holds that result (an interrupted run's), the saved one
    (info["resumed"] set). A file that cannot be read is computed again."""
    if folder is None:
        return task(*args)
    path = os.path.join(folder, f"{name}.npz")
    if os.path.exists(path):
        try:
            with np.load(path, allow_pickle=False) as saved:
                info = dict(json.loads(str(saved["info"])), resumed=True)
                return np.ascontiguousarray(saved["samples"]), info
        except (OSError, ValueError, KeyError):
            pass  # a damaged file: the task runs again and replaces it
    samples, info = task(*args)
    from geosynth.io.files import atomic_write

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, samples=samples, info=json.dumps(info))

    atomic_write(path, write, stage=False)  # saved at once: an interrupted run's later resume reads it
    return samples, info


def _open_checkpoint(folder, key: str, resume: bool, inputs) -> tuple[str, int, int]:
    """Prepare the checkpoint folder of a run whose settings digest to ``key``: created
    when absent; an earlier run's results kept with ``resume`` (the same settings only),
    else discarded.

    Returns:
        (the folder's real path, saved results kept, saved results discarded).

    Raises:
        ValueError: the folder is an input or holds one, holds files that are not a
            checkpoint's, or (``resume``) holds the checkpoint of other settings.
    """
    from geosynth.io.files import check_output

    real = os.path.realpath(os.fspath(folder))
    manifest = os.path.join(real, _MANIFEST)
    if not os.path.isdir(real):
        check_output(real, inputs=inputs, what="checkpoint")
    else:
        from geosynth.io.files import noted_inputs

        for item in list(inputs or ()) + noted_inputs():
            if item is not None and os.path.realpath(os.fspath(item)).startswith(real + os.sep):
                raise ValueError(f"checkpoint {str(folder)!r} holds an input ({os.fspath(item)!r}); choose "
                                 "another output name.")
        if not os.path.exists(manifest) and os.listdir(real):
            raise ValueError(f"checkpoint {str(folder)!r} is a folder that holds no checkpoint; refusing to "
                             "replace it: move it away or choose another output name.")
    saved = 0
    if os.path.exists(manifest):
        try:
            with open(manifest) as f:
                same = json.load(f).get("key") == key
        except (OSError, ValueError, AttributeError):
            same = False
        saved = len([n for n in os.listdir(real) if n.endswith(".npz") and not n.startswith(".")])
        if resume and not same:
            raise ValueError(f"--resume: the checkpoint in {str(folder)!r} was made with other settings "
                             "(exemplar, size, tiles, levels, block, iterations, seed or search); give the "
                             "interrupted run's settings, or run without --resume to start again.")
        if resume:
            return real, saved, 0
    if os.path.isdir(real):
        shutil.rmtree(real)
    os.makedirs(real)
    from geosynth.io.files import atomic_write

    atomic_write(manifest, lambda tmp: Path(tmp).write_text(json.dumps({"key": key})), stage=False)
    return real, 0, saved


def _drop_if_empty(folder: str | None) -> None:
    """Remove a checkpoint folder that holds no task's result (a run refused or stopped early)."""
    if folder is not None and os.path.isdir(folder) and not any(n.endswith(".npz") for n in os.listdir(folder)):
        shutil.rmtree(folder, ignore_errors=True)


def _write_tile(store: str, result, core: Region) -> int:
    """Write a finest-level tile core into its chunk of the zarr array at ``store``."""
    import zarr

    arr = zarr.open_array(store, mode="r+")
    arr[:, core.y0:core.y1, core.x0:core.x1] = result[0]
    return int(result[0].nbytes)


def _tile_mesh(result, core: Region, extra: list, shape, spacing: float, band: float, path: str | None,
               keep: bool = True):
    """Marching cubes of a tile's core plus one sample of its +y / +x neighbours (the
    cells between the two tiles belong to this one), capped where the tile meets the
    target's faces; vertices in world units. With ``path``, writes a PLY there (when the
    tile has a surface). Returns (vertices (V, 3) float64, faces (F, 3) int64) with
    ``keep`` (the merged mesh is made from these, never from the files' rounded
    vertices), else the face count."""
    from skimage import measure

    from geosynth.geometry.surface import UINT8_LEVEL

    Z, Y, X = shape
    box = Region(core.y0, min(Y, core.y1 + 1), core.x0, min(X, core.x1 + 1))
    vol, covered = assemble(Z, box, [(core, result[0])] + list(extra))
    if not covered.all():
        raise RuntimeError("tile mesh: the neighbours' crops miss samples.")
    vol = vol.astype(np.float32)
    # cap (pad with outside values) only at the target's faces: z always, y / x where the tile ends the target
    pads = [(1, 1), (1 if box.y0 == 0 else 0, 1 if box.y1 == Y else 0), (1 if box.x0 == 0 else 0, 1 if box.x1 == X else 0)]
    vol = np.pad(vol, pads, mode="constant", constant_values=255.0)
    faces = np.zeros((0, 3), np.int64)
    verts = np.zeros((0, 3), np.float64)
    if vol.min() < UINT8_LEVEL < vol.max():
        v, f, _, _ = measure.marching_cubes(np.ascontiguousarray(vol), UINT8_LEVEL, gradient_direction="ascent",
                                            allow_degenerate=False)
        offset = np.array([-1, box.y0 - pads[1][0], box.x0 - pads[2][0]], np.float64)
        verts = (v.astype(np.float64) + offset)[:, ::-1] * float(spacing)  # (z, y, x) -> (x, y, z), world units
        faces = f.astype(np.int64)
    if path is not None and len(faces):
        import trimesh

        from geosynth.geometry.surface import save_mesh

        save_mesh(trimesh.Trimesh(vertices=verts, faces=faces, process=False), path)
    return (verts, faces) if keep else int(len(faces))


# ------------------------------------------------------------------ engines


class _Threads:
    """Dask's threaded scheduler: values come back into this process."""

    name = "threads"

    def __init__(self, workers: int):
        self.workers = int(workers)

    def scatter(self, obj):
        return obj

    def compute(self, graphs: list, bar=None) -> list:
        import dask
        from dask.callbacks import Callback

        class _Bar(Callback):
            def _posttask(self, key, result, dsk, state, id):
                name = key[0] if isinstance(key, tuple) else key
                if bar is not None and str(name).startswith("tile-"):
                    bar.update(1)

        with _Bar():
            return list(dask.compute(*graphs, scheduler="threads", num_workers=self.workers))

    def gather(self, values):
        return values

    runtime_bytes = 0  # the threads share this process, whose runtime is already in use

    def memory_limit(self) -> int:
        from geosynth.core.memory import available_memory

        return available_memory() // max(1, self.workers)

    def worker_count(self) -> int:
        return self.workers

    def transfers(self) -> int:
        return 0

    def peak_rss(self) -> dict:
        return {}

    def close(self):
        pass


class _Distributed:
    """A dask.distributed Client (a LocalCluster it started, or one given / reached by address)."""

    name = "distributed"

    def __init__(self, client, cluster=None):
        self.client, self.cluster = client, cluster

    def scatter(self, obj):
        # a task holding the data (not client.scatter): should every worker holding it die,
        # the scheduler can make it again from its spec; then one copy to every worker
        future = self.client.submit(_identity, obj, pure=False)
        distributed_wait = __import__("distributed").wait
        distributed_wait([future])
        self.client.replicate([future])
        return future

    def compute(self, graphs: list, bar=None) -> list:
        from distributed import as_completed

        futures = self.client.compute(graphs)
        if bar is not None:
            tiles = [f for f in futures if str(f.key).startswith(("tile-", "patch-", "cinfo-"))]
            for _ in as_completed(tiles):
                bar.update(1)
        from distributed import wait

        wait(futures)
        for f in futures:
            if f.status == "error":
                f.result()  # raises the task's exception here
        return futures

    def gather(self, futures):
        return self.client.gather(futures)

    runtime_bytes = WORKER_RUNTIME_BYTES

    def memory_limit(self) -> int:
        """The smallest worker memory limit, times Dask's terminate fraction (a worker
        above it is killed); what is available here when no worker has a limit."""
        import dask

        workers = self.client.scheduler_info(n_workers=-1)["workers"].values()
        limits = [int(w.get("memory_limit") or 0) for w in workers]
        from geosynth.core.memory import available_memory

        known = [v for v in limits if v > 0]
        if not known:
            return available_memory()
        fraction = dask.config.get("distributed.worker.memory.terminate", 0.95) or 1.0
        return int(min(known) * float(fraction))

    def worker_count(self) -> int:
        return max(1, len(self.client.scheduler_info(n_workers=-1)["workers"]))

    def transfers(self) -> int:
        def sent(dask_worker):
            return int(getattr(dask_worker, "transfer_outgoing_bytes_total", 0))

        return int(sum(self.client.run(sent).values()))

    def peak_rss(self) -> dict:
        from geosynth.core.memory import peak_resident_bytes

        pids = self.client.run(os.getpid)
        if len(set(pids.values())) < len(pids) or os.getpid() in pids.values():
            return {}  # workers share a process (processes=False): no per-worker figure
        return self.client.run(peak_resident_bytes)

    def close(self):
        if self.cluster is not None:
            self.client.close()
            self.cluster.close()


def _engine(scheduler, workers: int):
    """The engine for ``scheduler`` (None: a new LocalCluster of ``workers`` processes)."""
    if scheduler == "threads":
        return _Threads(workers)
    from distributed import Client

    if isinstance(scheduler, Client):
        return _Distributed(scheduler)
    if scheduler is None:
        import logging

        from distributed import LocalCluster

        # CRITICAL: a task's exception is raised again here, on the client, and reaches the
        # user as one line; the worker's own "Compute Failed" log (task, exception and
        # traceback, at ERROR) would print seven lines before it
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.CRITICAL)
        return _Distributed(Client(cluster), cluster)
    if not isinstance(scheduler, str) or "://" not in scheduler:
        raise ValueError(f"scheduler must be 'threads', a distributed.Client, None (a LocalCluster) or an address "
                         f"like tcp://host:8786, got {scheduler!r}.")
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise RuntimeError(f"scheduler {scheduler} does not answer within {CONNECT_TIMEOUT_S:g} s ({exc}); start it "
                           "(dask scheduler) or leave the scheduler out for a local cluster.") from None
    return _Distributed(client, cluster=None)


# ------------------------------------------------------------------ the result


@dataclass
class TiledResult:
    """What :func:`synthesize_volume_tiled` returns.

    Attributes:
        quantized: (Z, Y, X) uint8 field, or None when not gathered (see ``store``).
        store: the zarr store written (the uint8 field, chunks = tile cores), or None.
        mesh: the merged trimesh.Trimesh (world units), or None.
        tile_meshes: per-tile PLY paths written (tiles with no surface write none).
        source: the finest uint8 source the synthesis matched against.
        grid: the :class:`geosynth.volume.tiles.TileGrid`.
        band: the quantization band (samples); spacing: world size of a sample.
        levels: per level {"seconds" (wall), "tasks" (tiles), "graph_tasks" (tiles, crops
            and the small info tasks), "whole", "matches", "task_seconds" (summed),
            "mean_distance", "tiles" (each tile task's info)}, coarsest first.
        tasks: tile tasks run (all levels); bytes_moved: bytes sent between workers
            (0 on the threaded scheduler); peak_rss: worker address -> peak resident
            bytes (worker processes only); tile_estimate: estimated peak bytes of one
            tile task; memory_limit: the per-worker limit it was checked against.
        timings: seconds per stage.
        engine: "threads" or "distributed"; workers: how many.
        resumed: tile and corner tasks whose results were loaded from the checkpoint of
            an interrupted run instead of computed (0 without ``resume``).
        settings: the choices made from the input, the untiled synthesis's
            (:class:`geosynth.volume.synthesis.VolumeSettings`).
        lattice: the exemplar's lattice the scans followed
            (:class:`geosynth.volume.lattice.Lattice`), or None; lattice_text: its line
            ("" when none was looked for), as the untiled run's.
    """

    quantized: np.ndarray | None
    store: str | None
    mesh: object
    tile_meshes: list
    source: np.ndarray
    grid: TileGrid
    band: float
    spacing: float
    levels: list
    tasks: int
    bytes_moved: int
    peak_rss: dict
    tile_estimate: int
    memory_limit: int
    timings: dict = dc_field(default_factory=dict)
    engine: str = "distributed"
    workers: int = 0
    resumed: int = 0
    settings: object = None
    lattice: object = None
    lattice_text: str = ""

    def lines(self) -> list[str]:
        """The per-level timings and the run's figures, one line each."""
        from geosynth.core.memory import format_bytes

        out = []
        for i, lv in enumerate(self.levels):
            out.append(f"level {i + 1}: {'whole, 1 task' if lv['whole'] else str(lv['tasks']) + ' tiles'}, "
                       f"{lv['matches']:,} matches, {lv['seconds']:.2f} s wall ({lv['task_seconds']:.2f} s in tasks)")
        if self.resumed:
            out.append(f"resumed: {self.resumed} finished task(s) of the interrupted run loaded from its checkpoint")
        out.append(f"{self.tasks} tile tasks on {self.workers} {self.engine} workers, {format_bytes(self.bytes_moved)} "
                   f"moved between workers, one tile task needs about {format_bytes(self.tile_estimate)} "
                   f"(limit {format_bytes(self.memory_limit)} per worker)")
        if self.peak_rss:
            out.append("peak memory per worker: " + ", ".join(format_bytes(v) for v in self.peak_rss.values()))
        return out


# ------------------------------------------------------------------ estimates


def tile_task_bytes(grid: TileGrid, level: int, index: int) -> int:
    """Estimated peak bytes of one tile task (:func:`_tile_task`) beyond the exemplar and
    the level's search: per sample of the tile's region, the target, the given mask and
    the fixed crops (_TILE_SAMPLE_BYTES, alive throughout), plus the larger of the
    trilinear upsampling of the coarser crops (_UPSAMPLE_SAMPLE_BYTES, a finer level)
    and the texture optimization (:func:`geosynth.volume.optimize.memory_estimate`; phase B
    with its given samples), plus the core's copy returned. Measured against the traced
    peak of every task in tests/test_tiled_memory.py. The scans (graphcut, paper: a slab's
    default) need less and are not modelled: this bounds them (their traced peaks measured
    2.5-16x below it, chainmail and terrain, blocks 8 and 16), so a tiling is refused early
    rather than late."""
    from geosynth.volume.optimize import level_stride, memory_estimate

    r, c = grid.region(level, index), grid.core_region(level, index)
    z = grid.level_shape(level)[0]
    shape = (z,) + r.shape
    n = int(np.prod(shape))
    fixed = bool(grid.fixed_parts(level, index))
    optimize = memory_estimate(shape, grid.block_shape(level), level_stride(grid.blocks[level], level == grid.levels - 1),
                               fixed=fixed)
    upsample = _UPSAMPLE_SAMPLE_BYTES * n if level > 0 else 0
    return _TILE_SAMPLE_BYTES * n + max(optimize, upsample) + z * c.shape[0] * c.shape[1] + _TASK_BYTES


def corner_task_bytes(grid: TileGrid, level: int, k: int) -> int:
    """Estimated peak bytes of one corner task (:func:`_corner_task`, phase C) beyond the
    exemplar and the level's search: per sample of the corner's window, the assembled
    target, its coverage and fixed masks and the four tiles' crops (_TILE_SAMPLE_BYTES),
    plus the constrained texture optimization (:func:`geosynth.volume.optimize.memory_estimate`
    with given samples) and the free square's copy returned. A window is at most a tile's
    region across (2 h + 2 b <= the smallest core + b), so a corner task never needs more
    than the largest tile task; measured against the traced peak in
    tests/test_tiled_memory.py."""
    from geosynth.volume.optimize import level_stride, memory_estimate

    w, f = grid.corner_window(level, k), grid.corner_free(level, k)
    z = grid.level_shape(level)[0]
    shape = (z,) + w.shape
    n = int(np.prod(shape))
    optimize = memory_estimate(shape, grid.block_shape(level), level_stride(grid.blocks[level], level == grid.levels - 1),
                               fixed=True)
    return _TILE_SAMPLE_BYTES * n + optimize + z * f.shape[0] * f.shape[1] + _TASK_BYTES


def tile_bytes(grid: TileGrid, source_shape, search: str = "cascade", mesh: bool = False,
               faces_per_sample: float = 0.0, phases: int = 3) -> int:
    """Estimated peak bytes of one worker's tile work for ``grid``, beyond its runtime
    (:data:`WORKER_RUNTIME_BYTES`) and the results it keeps: the exemplar's pyramid, every
    level's search (a worker keeps them all: :func:`geosynth.volume.synthesis.matcher_bytes`, device
    buffers included) and the largest tile task of any level (:func:`tile_task_bytes`),
    or corner task with ``phases`` 3 (:func:`corner_task_bytes`); with ``mesh``, the
    tile's marching cubes too (:data:`MERGE_FACE_BYTES` per face)."""
    from geosynth.volume.synthesis import matcher_bytes

    shapes = [tuple(int(v) for v in source_shape)]
    for _ in range(grid.levels - 1):
        shapes.insert(0, tuple(v // 2 for v in shapes[0]))
    pyramid = sum(int(np.prod(s)) for s in shapes)
    searches = sum(matcher_bytes(shapes[level], grid.block_shape(level), search) for level in range(grid.levels))
    worst = 0
    for level in range(grid.levels):
        for t in grid.tasks(level):
            worst = max(worst, tile_task_bytes(grid, level, t))
        if phases == 3:
            for k in range(len(grid.corners(level))):
                worst = max(worst, corner_task_bytes(grid, level, k))
        if mesh and level == grid.levels - 1:
            z = grid.level_shape(level)[0]
            n = max(z * (c.shape[0] + 1) * (c.shape[1] + 1) for c in grid.cores(level).values())
            worst = max(worst, 10 * n + int(faces_per_sample * n * MERGE_FACE_BYTES))
    return pyramid + searches + worst


def kept_bytes(grid: TileGrid, workers: int) -> int:
    """Bytes of tile results a worker keeps until the end (every level's uint8 cores,
    should a worker die: see :func:`_run`), the cluster's total split evenly."""
    total = sum(int(np.prod(grid.level_shape(level))) for level in range(grid.levels))
    return -(-total // max(1, int(workers)))


def _faces_per_sample(source: np.ndarray) -> float:
    """Marching-cubes faces per sample of the target, from the exemplar's (x FACES_GROWTH)."""
    from skimage import measure

    from geosynth.geometry.surface import UINT8_LEVEL

    vol = np.pad(source.astype(np.float32), 1, constant_values=255.0)
    if not vol.min() < UINT8_LEVEL < vol.max():
        return 0.0
    _, f, _, _ = measure.marching_cubes(vol, UINT8_LEVEL, gradient_direction="ascent", allow_degenerate=False)
    return FACES_GROWTH * len(f) / source.size


# ------------------------------------------------------------------ checks


def tile_grid(source_shape, target_shape, tiles, levels: int, block, margin: int | None = None,
              coarse_whole: bool = True, slab: bool | None = None, search: str = "cascade",
              method: str = "auto") -> TileGrid:
    """The tiling of a synthesis from a source of ``source_shape`` to ``target_shape``
    (both (Z, Y, X); the target already a multiple of 2^(levels-1)): the untiled
    synthesis's choices (:func:`geosynth.volume.synthesis.choose_volume_settings`: slab or not, the
    blocks per level) and :meth:`TileGrid.make`. Needs the shapes only, so a tiling whose
    cores are smaller than a block plus the margin, or a search the tiles would refuse
    (``search="tree"`` with a slab's blocks), is refused before any field is computed or
    any worker starts.

    Raises:
        ValueError / TypeError: bad tiles, blocks that do not fit, cores too small, the
            tree search with a slab, a method the tiles do not run.
    """
    return _settings_and_grid(source_shape, target_shape, tiles, levels, block, margin, coarse_whole, slab, search,
                              method)[1]


def _settings_and_grid(source_shape, target_shape, tiles, levels: int, block, margin, coarse_whole: bool, slab,
                       search: str, method: str, band=None, iterations=None, terrain: bool = False):
    """(:class:`geosynth.volume.synthesis.VolumeSettings` of a tiled run, its :class:`TileGrid`)."""
    from geosynth.volume.synthesis import choose_volume_settings

    source_shape = tuple(int(v) for v in source_shape)
    target_shape = tuple(int(v) for v in target_shape)
    settings = choose_volume_settings(source_shape, target_shape, levels, block, slab=slab, method=method, band=band,
                                      iterations=iterations, tiled=True, terrain=terrain)
    if settings.slab and search == "tree":  # each tile's Matcher would refuse it on a worker, the cluster started
        raise ValueError("search='tree' takes cubic blocks only; this slab exemplar's blocks span its full thickness: "
                         "use search='cascade' or 'linear' (or slab=False).")
    grid = TileGrid.make(target_shape, parse_tiles(tiles), settings.blocks, margin, coarse_whole, settings.slab)
    return settings, grid


def tile_mesh_paths(folder: str | os.PathLike, tiles) -> list[Path]:
    """Every per-tile mesh a run with ``tiles`` ((nx, ny), "NXxNY" or a TileGrid) may write
    in ``folder``: tile_x{ix}_y{iy}.ply, x fastest."""
    nx, ny = tiles.tiles if isinstance(tiles, TileGrid) else parse_tiles(tiles)
    return [Path(folder) / f"tile_x{ix}_y{iy}.ply" for iy in range(ny) for ix in range(nx)]


def check_tile_mesh_path(path: str | os.PathLike, inputs) -> Path:
    """The output guard (:func:`geosynth.io.files.check_output`) for one tile mesh."""
    from geosynth.io.files import check_output

    return check_output(path, inputs=inputs, suffixes=(".ply",), what="tile mesh")


def _check_nesting(store: str | None, mesh_dir, checkpoint) -> None:
    """Refuse folders of one run that lie in one another: a store is replaced whole (what
    lies inside it would be lost), tile meshes or a checkpoint inside it would be too."""
    folders = [(what, os.path.realpath(os.fspath(p))) for what, p in
               (("store", store), ("tile_meshes", mesh_dir), ("checkpoint", checkpoint)) if p is not None]
    for i, (what_a, a) in enumerate(folders):
        for what_b, b in folders[i + 1:]:
            if a == b or b.startswith(a + os.sep) or a.startswith(b + os.sep):
                raise ValueError(f"{what_a} {a!r} and {what_b} {b!r} are the same folder or one lies inside the "
                                 "other; give each its own folder.")


def _check_store(store, inputs) -> str:
    """A zarr store path that is no input (nor holds one), and either absent or an older zarr store."""
    from geosynth.io.files import check_output

    from geosynth.io.files import noted_inputs

    real = os.path.realpath(os.fspath(store))
    p = Path(real)
    if p.exists() and p.is_dir():
        for item in list(inputs or ()) + noted_inputs():
            if item is not None and os.path.realpath(os.fspath(item)).startswith(real + os.sep):
                raise ValueError(f"store {str(store)!r} holds an input ({os.fspath(item)!r}); choose another path "
                                 "(inputs are never overwritten).")
        if not any((p / name).exists() for name in ("zarr.json", ".zarray", ".zgroup")):
            raise ValueError(f"store {str(store)!r} is a folder that holds no zarr store; refusing to replace it, "
                             "choose another path.")
        return real
    check_output(store, inputs=inputs, what="store")  # an input file, an unwritable folder: refused here
    if p.exists():
        raise ValueError(f"store {str(store)!r} is a file, not a zarr store; choose another path.")
    return real


def _publish(tmp: str, final: str) -> None:
    """Move a finished store from its temporary folder into place (replacing an older store)."""
    from geosynth.io.files import temporary_path

    old = None
    if os.path.exists(final):
        old = str(temporary_path(final))  # a kill before the rmtree below leaves it to the next run
        os.replace(final, old)
    os.replace(tmp, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


# ------------------------------------------------------------------ the entry point


def synthesize_volume_tiled(
    source: np.ndarray,
    size=128,
    tiles=(2, 2),
    *,
    levels: int = 3,
    block=16,
    seed: int | None = 0,
    device: str | None = None,
    search: str = "cascade",
    band: float | None = None,
    spacing: float = 1.0,
    iterations=None,
    workers: int = 2,
    scheduler=None,
    store: str | os.PathLike | None = None,
    gather: bool | None = None,
    mesh: bool = False,
    tile_meshes: str | os.PathLike | None = None,
    smooth: int = 0,
    inputs=(),
    margin: int | None = None,
    coarse_whole: bool = True,
    phases: int = 3,
    slab: bool | None = None,
    progress: bool = True,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
    method: str = "auto",
    lattice: bool | None = None,
    options: VolumeOptions | None = None,
) -> TiledResult:
    """Tiled M1 synthesis of a field larger than one process should hold, on Dask; the
    same bits whatever the engine and number of workers.

    Args:
        source, size, seed, device, spacing: as :func:`geosynth.volume.synthesis.synthesize_volume`.
        levels, block, search, band, iterations, slab, method, lattice, smooth: the settings, each
            documented and checked once in :class:`~geosynth.volume.options.VolumeOptions`, with
            the untiled run's choices made from the input
            (:func:`geosynth.volume.synthesis.choose_volume_settings`: ``result.settings``);
            tileable targets are not tiled. The scans (graphcut, paper) run each phase-B tile
            and corner window with its neighbours' samples given
            (``geosynth.volume.synthesis.synthesize_level``'s ``fixed``). ``smooth``: the merged
            mesh's.
        tiles, workers, margin, coarse_whole, phases: the tiling, documented and checked once
            in :class:`~geosynth.volume.options.TileOptions`.
        scheduler: None (a LocalCluster of ``workers`` one-thread processes, closed at
            the end), "threads" (Dask's threaded scheduler, this process), a
            ``distributed.Client``, or a scheduler address "tcp://host:port" (refused
            with a RuntimeError when it does not answer within 5 s, before anything is
            written). Workers of a remote cluster must see ``store`` and
            ``tile_meshes`` at the same paths (a shared file system).
        store: a zarr store (folder) for the finest field, chunks = tile cores, with
            attributes band, spacing, seed, tiles, blocks. Written to a temporary
            folder beside it and moved into place when complete.
        gather: return the field in memory (default: when no store is given); refused
            up front when it does not fit.
        mesh: merge the tiles' meshes into one (refused up front, with the estimate,
            when it does not fit in memory); ``smooth`` Taubin iterations on it.
        tile_meshes: a folder for one PLY per tile (tile_x{ix}_y{iy}.ply, world units),
            written to a temporary folder beside it and moved in when the run succeeds.
            Every tile's file name is checked against ``inputs`` before any work.
        inputs: files the run read (the store, meshes and checkpoint never replace them).
        progress: a progress bar over the tile tasks.
        checkpoint: a folder where each finished tile and corner task's result is saved
            (None: none). Removed when the run succeeds; after an interruption it holds
            the finished tasks. Without ``resume`` an earlier run's checkpoint there is
            discarded.
        resume: load the results saved in ``checkpoint`` by an interrupted run with the
            same settings (refused for other settings) instead of computing them; the
            result is the uninterrupted run's, bit for bit. No saved checkpoint: the run
            starts from the beginning (``TiledResult.resumed`` is 0).
        options: the settings as one :class:`~geosynth.volume.options.VolumeOptions` (its
            ``tiles`` the tiling; None: the defaults) instead of the keywords (then the keywords
            must keep their defaults).

    Returns:
        TiledResult.

    Raises:
        TypeError / ValueError: as synthesize_volume, plus bad tiles (tiles smaller
            than a block plus the margin), a bad scheduler, a store that is an input,
            a file or a folder holding no zarr store.
        RuntimeError: a scheduler address that does not answer.
        MemoryBudgetError: a tile task beyond a worker's memory limit (option "tiles",
            with the smallest square tiling that fits), or the gathered field or merged
            mesh beyond the memory available here.
    """
    from geosynth.core.options import keyword_defaults
    from geosynth.volume.synthesis import check_size, choose_lattice, source_levels, source_pyramid

    t_start = time.perf_counter()
    src = np.asarray(source)
    if src.ndim != 3 or src.size == 0:
        raise ValueError(f"source must be a non-empty (Z, Y, X) volume, got shape {src.shape}.")
    check_size(size)
    volume_given = dict(levels=levels, block=block, search=search, band=band, iterations=iterations, slab=slab,
                        method=method, lattice=lattice, smooth=smooth)
    tile_given = dict(tiles=tiles, workers=workers, margin=margin, coarse_whole=coarse_whole, phases=phases)
    given = {**volume_given, **tile_given}
    opts = volume_options(options, given, keyword_defaults(synthesize_volume_tiled, given),
                          lambda chosen: source_levels(src.shape, chosen["slab"]),
                          build=lambda: VolumeOptions(**volume_given, tiles=TileOptions(**tile_given)))
    req = _check_request(src, size, opts, seed=seed, device=device, progress=progress, spacing=spacing, mesh=mesh,
                         gather=gather, store=store, tile_meshes=tile_meshes, inputs=inputs, checkpoint=checkpoint,
                         resume=resume)
    sources = source_pyramid(src, req.settings.band, req.levels)
    found, lattice_line = choose_lattice(sources[-1], req.settings.band, opts.lattice,
                                         req.grid.slab and req.settings.method in ("paper", "graphcut"))
    faces_per_sample = _require_client_memory(req, sources[-1])
    ex, ckpt = _exemplar_for_workers(req, sources, seed, device, found)
    estimate = tile_bytes(req.grid, src.shape, req.search, mesh=req.wants_mesh, faces_per_sample=faces_per_sample,
                          phases=req.tiling.phases)
    timings = {"prepare": time.perf_counter() - t_start}

    t0 = time.perf_counter()
    try:
        engine = _engine(scheduler, req.tiling.workers)  # a silent scheduler is refused here, before anything is written
    except BaseException:
        _drop_if_empty(ckpt)
        raise
    tmp_store = tmp_meshes = None
    try:
        limit = _require_worker_memory(engine, req, estimate, src.shape, faces_per_sample)
        timings["engine start"] = time.perf_counter() - t0
        run = uuid.uuid4().hex[:10]
        moved0 = engine.transfers()
        ex_ref = engine.scatter(ex)  # held to the end: a lost worker's results are recomputed from it
        levels_info, finest, held = _run(engine, ex_ref, req.grid, run, progress, req.tiling.phases, ckpt)
        timings.update({f"level {i + 1}": lv["seconds"] for i, lv in enumerate(levels_info)})

        t0 = time.perf_counter()
        written = _finest_outputs(engine, req, finest, run, spacing, ex.seed)
        tmp_store, tmp_meshes = written.store, written.meshes
        quantized = _gathered_field(engine, req, finest) if req.gather else None
        merged = _merge(written.pieces, req.smooth) if req.mesh else None
        timings["outputs"] = time.perf_counter() - t0
        bytes_moved = engine.transfers() - moved0
        peak = engine.peak_rss()
        _publish_outputs(req, written, ckpt)
        tmp_store = tmp_meshes = None
    finally:
        for tmp in (tmp_store, tmp_meshes):
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
        _drop_if_empty(ckpt)
        engine.close()
    timings["total"] = time.perf_counter() - t_start
    return TiledResult(quantized, req.store, merged, written.tile_paths, sources[-1], req.grid, float(req.settings.band),
                       float(spacing), levels_info, sum(lv["tasks"] for lv in levels_info), bytes_moved, peak,
                       estimate, limit, timings, engine.name,
                       int(req.tiling.workers) if scheduler in (None, "threads") else
                       len(engine.client.scheduler_info(n_workers=-1)["workers"]),
                       sum(bool(i.get("resumed")) for lv in levels_info for i in lv["tiles"] + lv["corners"]),
                       req.settings, found, lattice_line)


# ------------------------------------------------------------------ the entry point's steps


@dataclass(frozen=True)
class _TiledRequest:
    """A tiled run as its checks (:func:`_check_request`) accepted it.

    Attributes:
        size: the size as given (named in memory refusals); target_shape: its (Z, Y, X).
        levels, search, block, smooth: the settings (``block`` and ``smooth`` defaults applied).
        tiling: the :class:`~geosynth.volume.options.TileOptions`.
        settings: the untiled synthesis's choices (:class:`geosynth.volume.synthesis.VolumeSettings`).
        grid: the :class:`TileGrid`.
        mesh, gather: merge one mesh; return the field in memory.
        store: the zarr store's real path, or None; mesh_dir: the tile meshes' folder, or None.
        checkpoint, resume, inputs: as given.
    """

    size: object
    target_shape: tuple
    levels: int
    search: str
    block: object
    smooth: int
    tiling: TileOptions
    settings: object
    grid: TileGrid
    mesh: bool
    gather: bool
    store: str | None
    mesh_dir: Path | None
    checkpoint: object
    resume: bool
    inputs: object

    @property
    def wants_mesh(self) -> bool:
        """Whether any mesh is made (merged, or one per tile)."""
        return self.mesh or self.mesh_dir is not None


def _check_request(src: np.ndarray, size, opts: VolumeOptions, *, seed, device, progress, spacing, mesh, gather, store,
                   tile_meshes, inputs, checkpoint, resume) -> _TiledRequest:
    """The checks, before any work: the run's arguments, the source and size, the untiled
    synthesis's choices and the tiling (:func:`_settings_and_grid`), and every output path
    (store, each tile's mesh, the checkpoint; none an input, none inside another)."""
    from geosynth.compute.checks import check_bool
    from geosynth.volume.synthesis import check_run, check_scale, check_source_and_size, optimizes_better

    if opts.tileable:
        raise ValueError("tileable targets are not tiled yet (the tiles' margins would wrap); use synthesize_volume.")
    tiling = opts.tiling
    block = M1_DEFAULT_BLOCK if opts.block is None else opts.block
    check_run(seed, device, progress)
    check_bool("mesh", mesh)
    check_scale("spacing", spacing, "the world size of one sample")
    _, target_shape = check_source_and_size(src, size, opts.levels)
    # the untiled synthesis's choices (slab, blocks, method, band, iterations), made by the same function
    settings, grid = _settings_and_grid(src.shape, target_shape, tiling.tiles, opts.levels, block, tiling.margin,
                                        tiling.coarse_whole, opts.slab, opts.search, opts.method, opts.band,
                                        opts.iterations, terrain=opts.method == "auto" and optimizes_better(src))
    check_bool("resume", resume)
    if resume and checkpoint is None:
        raise ValueError("resume needs the checkpoint folder of the interrupted run (checkpoint=...).")
    store_real = _check_store(store, inputs) if store is not None else None
    mesh_dir = None
    if tile_meshes is not None:
        mesh_dir = Path(tile_meshes)
        if mesh_dir.exists() and not mesh_dir.is_dir():
            raise ValueError(f"tile_meshes {str(tile_meshes)!r} is a file; give a folder.")
        for path in tile_mesh_paths(mesh_dir, grid):  # every tile's file, not only the first
            check_tile_mesh_path(path, inputs)
    _check_nesting(store_real, mesh_dir, checkpoint)
    return _TiledRequest(size, target_shape, opts.levels, opts.search, block, 0 if opts.smooth is None else opts.smooth,
                         tiling, settings, grid, mesh, store is None if gather is None else gather, store_real,
                         mesh_dir, checkpoint, resume, inputs)


def _require_client_memory(req: _TiledRequest, finest_source: np.ndarray) -> float:
    """Refuse, before any worker starts, a gathered field or merged mesh beyond the memory
    available here; returns the faces per target sample expected of the meshes (0 without)."""
    from geosynth.core.memory import available_memory, require

    target_shape = req.target_shape
    n_target = int(np.prod(target_shape))
    faces_per_sample = _faces_per_sample(finest_source) if req.wants_mesh else 0.0
    gather, mesh = req.gather, req.mesh
    client_need = (n_target if gather else 0) + (int(faces_per_sample * n_target * MERGE_FACE_BYTES) if mesh else 0)
    if client_need:
        what = "the gathered field" * bool(gather) + " and " * bool(gather and mesh) + "the merged mesh" * bool(mesh)
        require(client_need, option="size", value=req.size, available=available_memory(),
                what=f"{what} of {target_shape[2]:,} x {target_shape[1]:,} x {target_shape[0]:,} samples (x y z) "
                     "(write a store and tile meshes instead)")
    return faces_per_sample


def _exemplar_for_workers(req: _TiledRequest, sources: list, seed, device, found) -> tuple[_Exemplar, str | None]:
    """What every worker receives (the exemplar's levels, blocks, iteration caps, search,
    seed (None: drawn here) and each level's lattice vectors from ``found``, the exemplar's
    lattice or None), and the checkpoint folder opened for these settings (or None)."""
    from geosynth.volume.synthesis import level_lattice

    if seed is None:
        seed = int(np.random.SeedSequence().entropy % (2**63))
    grid, settings, tiling = req.grid, req.settings, req.tiling
    blocks, caps = list(grid.blocks), list(settings.iterations)
    lattices = [level_lattice(found, req.levels - 1 - level, sources[level].shape, grid.block_shape(level))
                for level in range(req.levels)]
    lattice_key = (() if found is None else
                   (tuple(None if v is None else tuple(map(float, v.reshape(-1))) for v in lattices),))
    exemplar_bytes = b"".join(s.tobytes() for s in sources)
    digest = hashlib.sha1(exemplar_bytes + repr((blocks, grid.slab, caps, device, req.search, int(seed),
                                                 settings.method) + lattice_key).encode()).hexdigest()
    ckpt = None
    if req.checkpoint is not None:  # the device is not part of the key: every device gives the same bits
        key = hashlib.sha1(exemplar_bytes + repr((blocks, grid.slab, caps, req.search, int(seed),
                                                  tuple(req.target_shape), tiling.tiles, tiling.margin,
                                                  tiling.coarse_whole, tiling.phases)
                                                 + ((settings.method,) if settings.method != "optimize" else ())
                                                 + lattice_key).encode()).hexdigest()
        ckpt, _, _ = _open_checkpoint(req.checkpoint, key, req.resume, req.inputs)
    ex = _Exemplar(sources, [grid.block_shape(level) for level in range(req.levels)], [int(c) for c in caps], device,
                   req.search, int(seed), digest, settings.method, lattices if found is not None else None)
    return ex, ckpt


def _require_worker_memory(engine, req: _TiledRequest, estimate: int, source_shape, faces_per_sample: float) -> int:
    """Refuse, before any tile runs, a tile task beyond a worker's memory limit (with its
    runtime and the results it keeps), naming the smallest square tiling that fits;
    returns the limit."""
    from geosynth.core.memory import MemoryBudgetError, format_bytes

    limit = engine.memory_limit()
    n_workers = engine.worker_count()
    grid, tiling = req.grid, req.tiling
    nx, ny = tiling.tiles

    def worker_need(g: TileGrid, tile_estimate: int) -> int:
        return tile_estimate + engine.runtime_bytes + kept_bytes(g, n_workers)

    need = worker_need(grid, estimate)
    if need > limit:
        fits = None
        for n in range(max(nx, ny) + 1, 257):
            try:
                g = TileGrid.make(req.target_shape, (n, n), list(grid.blocks), tiling.margin, tiling.coarse_whole,
                                  grid.slab)
            except ValueError:
                break
            if worker_need(g, tile_bytes(g, source_shape, req.search, req.wants_mesh, faces_per_sample,
                                         tiling.phases)) <= limit:
                fits = (n, n)
                break
        fix = (f"use at least {fits[0]}x{fits[1]} tiles" if fits else "no tiling of this size fits; use a "
               "smaller size or workers with more memory")
        raise MemoryBudgetError(
            f"tiles {nx}x{ny}: one tile task needs about {format_bytes(estimate)}, with the worker's runtime "
            f"({format_bytes(engine.runtime_bytes)}) and kept results ({format_bytes(kept_bytes(grid, n_workers))}) "
            f"{format_bytes(need)}, more than a worker's {format_bytes(limit)}; {fix}.", option="tiles",
            largest=fits, estimate=need, available=limit)
    return limit


@dataclass(frozen=True)
class _FinestOutputs:
    """What :func:`_finest_outputs` wrote: the store's and the tile meshes' temporary folders
    (None when not asked), the final paths of the tile meshes that hold a surface, and each
    tile's mesh piece for the merge (when ``mesh``)."""

    store: str | None
    meshes: Path | None
    tile_paths: list
    pieces: list


def _finest_outputs(engine, req: _TiledRequest, finest: dict, run: str, spacing: float, seed: int) -> _FinestOutputs:
    """The finest level's outputs, written by the workers beside the tiles' results: the
    zarr store (:func:`_store_tasks`) and the tile meshes (:func:`_mesh_tasks`), into
    temporary folders (removed again should this fail)."""
    from geosynth.io.files import remove_stale_temporaries, temporary_path

    graphs, kinds = [], []
    tmp_store = tmp_meshes = None
    try:
        if req.store is not None:
            os.makedirs(os.path.dirname(req.store), exist_ok=True)
            remove_stale_temporaries(req.store)
            tmp_store = str(temporary_path(req.store))
            os.mkdir(tmp_store)
            graphs += _store_tasks(req, finest, run, tmp_store, spacing, seed)
            kinds += [("write", t) for t in req.grid.cores(req.grid.levels - 1)]
        if req.wants_mesh:
            if req.mesh_dir is not None:  # filled by the tasks, moved into mesh_dir at the end
                req.mesh_dir.mkdir(parents=True, exist_ok=True)
                remove_stale_temporaries(req.mesh_dir / "tiles")
                tmp_meshes = temporary_path(req.mesh_dir / "tiles")
                tmp_meshes.mkdir()
            graphs += _mesh_tasks(req, finest, run, tmp_meshes, spacing)
            kinds += [("mesh", t) for t in req.grid.cores(req.grid.levels - 1)]
        outputs = engine.gather(engine.compute(graphs)) if graphs else []
    except BaseException:
        for tmp in (tmp_store, tmp_meshes):
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
        raise
    tile_paths, pieces = [], []
    for (kind, t), value in zip(kinds, outputs):
        if kind != "mesh":
            continue
        if req.mesh:
            pieces.append(value)
        if req.mesh_dir is not None and (len(value[1]) if req.mesh else value):
            ix, iy = req.grid.position(t)
            tile_paths.append(str(req.mesh_dir / f"tile_x{ix}_y{iy}.ply"))
    return _FinestOutputs(tmp_store, tmp_meshes, tile_paths, pieces)


def _store_tasks(req: _TiledRequest, finest: dict, run: str, folder: str, spacing: float, seed: int) -> list:
    """The zarr store in ``folder``: the finest field's array (one chunk a tile core, the run's
    settings as attributes) and one task a tile writing its core, in the cores' order."""
    import zarr
    from dask import delayed

    grid, target_shape = req.grid, req.target_shape
    Z, Y, X = target_shape
    chunks = (Z, min(Y, grid.core[0]), min(X, grid.core[1]))
    arr = zarr.open_array(folder, mode="w", shape=target_shape, chunks=chunks, dtype="uint8", fill_value=0)
    arr.attrs.update({"band": float(req.settings.band), "spacing": float(spacing), "seed": int(seed),
                      "tiles": list(req.tiling.tiles), "blocks": list(grid.blocks), "slab": grid.slab,
                      "levels": req.levels,
                      "what": "uint8 signed distance codes (geosynth.volume.synthesis.quantize_field), z y x"})
    return [delayed(_write_tile, pure=False)(folder, finest[t], c, dask_key_name=f"write-{run}-{t}")
            for t, c in grid.cores(grid.levels - 1).items()]


def _mesh_tasks(req: _TiledRequest, finest: dict, run: str, folder: Path | None, spacing: float) -> list:
    """One task a tile, in the cores' order: marching cubes over its core and one sample of
    its +x / +y neighbours (so that neighbouring tiles' vertices coincide), written to
    ``folder`` when given, its piece returned for the merge when ``req.mesh``."""
    from dask import delayed

    grid, target_shape = req.grid, req.target_shape
    _, Y, X = target_shape
    last = grid.levels - 1
    tasks = []
    for t, c in grid.cores(last).items():
        box = Region(c.y0, min(Y, c.y1 + 1), c.x0, min(X, c.x1 + 1))
        extra = [delayed(_crop, pure=False)(finest[u], grid.core_region(last, u), part,
                                            dask_key_name=f"meshcrop-{run}-{t}-{u}")
                 for u, part in grid.overlapping(last, box) if u != t]
        ix, iy = grid.position(t)
        path = None if folder is None else str(folder / f"tile_x{ix}_y{iy}.ply")
        tasks.append(delayed(_tile_mesh, pure=False)(finest[t], c, extra, target_shape, spacing, req.settings.band,
                                                     path, req.mesh, dask_key_name=f"mesh-{run}-{t}"))
    return tasks


def _gathered_field(engine, req: _TiledRequest, finest: dict) -> np.ndarray:
    """The finest level's field in memory, each tile's core in its place."""
    cores = req.grid.cores(req.grid.levels - 1)
    quantized = np.empty(req.target_shape, np.uint8)
    for t, value in zip(cores, engine.gather([finest[t] for t in cores])):
        c = cores[t]
        quantized[:, c.y0:c.y1, c.x0:c.x1] = value[0]
    return quantized


def _publish_outputs(req: _TiledRequest, written: _FinestOutputs, ckpt: str | None) -> None:
    """Every output is complete: move the store and the tile meshes into place together (with
    the command's other outputs, inside :func:`geosynth.io.files.staged_outputs`) and drop the
    checkpoint; should the command fail later, its abort removes them."""
    from geosynth.io.files import defer

    ready_store, ready_meshes = written.store, written.meshes

    def publish() -> None:
        if ready_store is not None:
            _publish(ready_store, req.store)
        if ready_meshes is not None:
            for name in sorted(os.listdir(ready_meshes)):
                os.replace(ready_meshes / name, req.mesh_dir / name)
            shutil.rmtree(ready_meshes, ignore_errors=True)
        if ckpt is not None:
            shutil.rmtree(ckpt, ignore_errors=True)

    def abort() -> None:
        for tmp in (ready_store, ready_meshes):
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)

    if not defer(publish, abort):
        publish()


def _run(engine, ex_ref, grid: TileGrid, run: str, progress: bool, phases: int, checkpoint: str | None = None):
    """Every level's tile tasks, level after level; returns (per-level info, the finest
    level's results by tile: futures or values, every level's results). A level's
    results are kept (on the workers) until the outputs are written: should a worker die,
    Dask recomputes what it held from them (coarser levels are 1/8 of a finer one each)."""
    from dask import delayed

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(len(grid.tasks(lv)) + (len(grid.corners(lv)) if phases == 3 else 0)
                             for lv in range(grid.levels)), desc="tiles", unit="tile",
                   dynamic_ncols=True)
    prev: dict = {}
    levels = []
    held = []
    try:
        for level in range(grid.levels):
            t0 = time.perf_counter()
            tasks: dict = {}
            order = grid.tasks(level)
            graph_tasks = len(order)  # the info tasks; tiles and crops are counted as they are made

            def phase(t):
                return PHASE_A if phases == 1 else grid.phase(t)

            for ph in (PHASE_A, PHASE_B):
                for t in [t for t in order if phase(t) == ph]:
                    init = []
                    if level > 0:
                        cbox = grid.upsample_source(level, t)
                        init = [delayed(_crop, pure=False)(prev[u], grid.core_region(level - 1, u), part,
                                                           dask_key_name=f"crop-{run}-{level}-{t}-{u}")
                                for u, part in grid.overlapping(level - 1, cbox)]
                    fixed = []
                    if phases >= 2:
                        fixed = [delayed(_crop, pure=False)(tasks[u], grid.core_region(level, u), part,
                                                            dask_key_name=f"fix-{run}-{level}-{t}-{u}")
                                 for u, part in grid.fixed_parts(level, t)]
                    tasks[t] = delayed(_resumable, pure=False)(checkpoint, f"L{level}-t{t}", _tile_task, ex_ref, grid,
                                                               level, t, init, fixed,
                                                               dask_key_name=f"tile-{run}-{level}-{t}")
                    graph_tasks += 1 + len(init) + len(fixed)
            corner_infos = []
            if phases == 3 and grid.corners(level):  # phase C: the corner windows, then their squares written in
                cores = grid.cores(level)
                patches: dict = {t: [] for t in order}
                for k in range(len(grid.corners(level))):
                    window, free = grid.corner_window(level, k), grid.corner_free(level, k)
                    pieces = [delayed(_crop, pure=False)(tasks[u], cores[u], part,
                                                         dask_key_name=f"cwin-{run}-{level}-{k}-{u}")
                              for u, part in grid.overlapping(level, window)]
                    corner = delayed(_resumable, pure=False)(checkpoint, f"L{level}-c{k}", _corner_task, ex_ref, grid,
                                                             level, k, pieces, dask_key_name=f"tile-{run}-{level}-c{k}")
                    corner_infos.append(delayed(_info, pure=False)(corner, dask_key_name=f"cinfo-{run}-{level}-{k}"))
                    graph_tasks += 2 + len(pieces)
                    for u, part in grid.overlapping(level, free):
                        patches[u].append(delayed(_corner_part, pure=False)(
                            corner, free, part, dask_key_name=f"cpart-{run}-{level}-{k}-{u}"))
                        graph_tasks += 1
                for t in order:
                    if patches[t]:
                        tasks[t] = delayed(_patched, pure=False)(tasks[t], cores[t], patches[t],
                                                                 dask_key_name=f"patch-{run}-{level}-{t}")
                        graph_tasks += 1
            infos = [delayed(_info, pure=False)(tasks[t], dask_key_name=f"info-{run}-{level}-{t}") for t in order]
            done = engine.compute([tasks[t] for t in order] + infos + corner_infos, bar=bar)
            results = dict(zip(order, done[:len(order)]))
            got = engine.gather(done[len(order):len(order) + len(infos)])
            got_c = engine.gather(done[len(order) + len(infos):]) if corner_infos else []
            levels.append({"seconds": time.perf_counter() - t0, "tasks": len(order), "whole": grid.whole(level),
                           "corner_tasks": len(got_c),
                           "matches": int(sum(i["matches"] for i in got + got_c)),
                           "task_seconds": float(sum(i["seconds"] for i in got + got_c)),
                           "mean_distance": float(np.mean([i["mean_distance"] for i in got])),
                           "graph_tasks": graph_tasks,
                           "tiles": got, "corners": got_c})
            held.append(results)  # every level stays known until the end: a lost result is recomputed from them
            prev = results
    finally:
        if bar is not None:
            bar.close()
    return levels, prev, held


def _merge(pieces, smooth: int):
    """One mesh from the tiles' (vertices, faces): coincident vertices (bit-equal along
    shared borders) merged, then ``smooth`` Taubin iterations."""
    import trimesh

    from geosynth.geometry.surface import smooth_mesh

    pieces = [(v, f) for v, f in pieces if len(f)]
    if not pieces:
        raise ValueError("no surface: no tile's field crosses the zero level.")
    offsets = np.cumsum([0] + [len(v) for v, _ in pieces])
    verts = np.concatenate([v for v, _ in pieces])
    faces = np.concatenate([f + o for (_, f), o in zip(pieces, offsets[:-1])])
    unique, inverse = np.unique(verts, axis=0, return_inverse=True)
    out = trimesh.Trimesh(vertices=unique, faces=inverse.reshape(-1)[faces], process=False)
    if smooth:
        out = smooth_mesh(out, smooth)
    return out


# ------------------------------------------------------------------ inputs and quality


def exemplar_source(exemplar, source_resolution: int = 64, levels: int = 3, seed: int | None = 0,
                    device: str | None = None, check=None, drop_degenerate: bool = False, field=None):
    """An exemplar mesh (a trimesh, a file or a built-in name) as the source of a
    synthesis, as :func:`geosynth.volume.synthesis.synthesize_geometry` makes it
    (:func:`geosynth.volume.synthesis.exemplar_distance`): its exact signed distance on
    :func:`geosynth.volume.synthesis.exemplar_grid`. ``check``: None, or a callable taking the
    source's (Z, Y, X) shape, called before the distance is computed (so that a tiling
    that cannot be is refused before the field's seconds: see :func:`tile_grid`).
    ``drop_degenerate``: drop the exemplar's zero-area faces instead of refusing it.
    ``field``: None, or the distance already computed on that grid (see
    :func:`geosynth.volume.synthesis.choose_settings`). Returns (float32 (Z, Y, X) distances in samples, spacing (world units per sample),
    the exemplar Field)."""
    from geosynth.geometry.meshes import check_mesh
    from geosynth.volume.examples import resolve_exemplar_mesh
    from geosynth.volume.synthesis import exemplar_distance

    m = resolve_exemplar_mesh(exemplar, seed)
    check_mesh(m, "exemplar", drop_degenerate=drop_degenerate)
    return exemplar_distance(m, source_resolution, levels, device=device, drop_degenerate=drop_degenerate,
                             before=check, field=field)


def seam_report(source: np.ndarray, field: np.ndarray, grid: TileGrid, block=None, *, stride: int = 2,
                device: str | None = None) -> dict:
    """Block distance at the seams against inside the tiles.

    ``block``: N (a cube), (bz, by, bx), or None: the finest level's block of ``grid``
    (a slab's spans the thickness, :meth:`TileGrid.block_shape`). For every block of
    ``field`` on a lattice of ``stride`` (x-y, from stride // 2) and bz (z), the
    exact nearest block of ``source`` (SSD / block^3, squared uint8 units per sample,
    :class:`geosynth.volume.cascade.CascadeSearch`); blocks whose x-y footprint crosses a
    border between two tile cores of the finest level are "seam", those within one core
    are "interior".

    The block distance is blind to a small step between two good halves, so the mean
    absolute difference of neighbouring samples across the borders ("step_seam") is given
    beside its mean between all other neighbouring columns and rows ("step_interior").

    Returns:
        {"seam": mean, "interior": mean, "ratio": seam / interior, "seam_blocks",
        "interior_blocks", "step_seam", "step_interior", "step_ratio"}.
    """
    from geosynth.volume.blocks import block_shape
    from geosynth.volume.cascade import CascadeSearch

    last = grid.levels - 1
    if block is None:
        block = grid.block_shape(last)
    bz, by, bx = block_shape(block)
    cores = list(grid.cores(last).values())
    ys = sorted({c.y0 for c in cores} - {0})
    xs = sorted({c.x0 for c in cores} - {0})
    search = CascadeSearch(np.ascontiguousarray(source), block, device=device)
    Z, Y, X = field.shape
    sums = {"seam": [], "interior": []}
    queries, kinds = [], []
    start = stride // 2  # an odd offset: with any stride some blocks straddle each border
    for z in range(0, Z - bz + 1, bz):
        for y in range(start, Y - by + 1, stride):
            for x in range(start, X - bx + 1, stride):
                crosses = any(y < e < y + by for e in ys) or any(x < e < x + bx for e in xs)
                queries.append(field[z:z + bz, y:y + by, x:x + bx])
                kinds.append("seam" if crosses else "interior")
    for lo in range(0, len(queries), 512):
        _, ssds, _ = search.nearest_batch(np.stack(queries[lo:lo + 512]), None)
        for kind, d in zip(kinds[lo:lo + 512], ssds):
            sums[kind].append(d / (bz * by * bx))
    seam, interior = float(np.mean(sums["seam"])), float(np.mean(sums["interior"]))
    # the step between neighbouring samples across a border against between any other two
    steps = {"seam": [], "interior": []}
    f = field.astype(np.int16)
    for axis, edges in ((1, set(ys)), (2, set(xs))):
        d = np.abs(np.diff(f, axis=axis)).mean(axis=tuple(a for a in range(3) if a != axis))  # d[i]: i -> i + 1
        for i, v in enumerate(d):
            steps["seam" if i + 1 in edges else "interior"].append(float(v))
    step_seam = float(np.mean(steps["seam"])) if steps["seam"] else 0.0
    step_in = float(np.mean(steps["interior"]))
    return {"seam": seam, "interior": interior, "ratio": seam / interior if interior else float("inf"),
            "seam_blocks": len(sums["seam"]), "interior_blocks": len(sums["interior"]),
            "step_seam": step_seam, "step_interior": step_in,
            "step_ratio": step_seam / step_in if step_in else float("inf")}
