"""Distance-field sampling: every present backend against pysdf, Open3D and mesh2sdf.

Cases: meshes a ~20k-face torus, a ~20k-face chainmail of linked tori and a
~200k-face torus; grids 64^3 and 128^3 over the bounds plus 10%. Reported: points/s,
the maximum error against the exact oracle (brute force over all faces, winding-number
sign) on a sample of the grid points, the sign errors there, and the ratio to the
fastest peer. Then point queries: mesh_distance(mesh, points) at the
64^3 grid's sample positions of the ~20k-face torus, once in grid order and once
shuffled, against pysdf on the same points; these rows give the median of repeated
calls and the spread (the machine is shared), and check that every device returns the
grid path's values bit for bit. Then MLS samples/s for a 100k-point set on a 64^3 grid.

geosynth rows time mesh_distance on a mesh already prepared (its BVH is built once per
mesh and cached; the build time is reported separately), peers their query call after
their own set-up, except mesh2sdf, whose one call does everything on its own grid.

Usage: python bench/bm_fields.py [--quick] [--devices cpu,opencl:0:0] [--out FILE]
"""

from __future__ import annotations

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import Row, finish, parse_args, start, table, time_call  # noqa: E402

from geosynth.geometry import reference  # noqa: E402
from geosynth.geometry.field import cubic_grid  # noqa: E402
from geosynth.geometry.meshes import mesh_distance, prepare_mesh  # noqa: E402
from geosynth.geometry.pointsets import pointset_distance  # noqa: E402
from geosynth.volume.examples import chainmail_mesh, torus_mesh  # noqa: E402


def _peer(name):
    try:
        if name == "pysdf":
            from pysdf import SDF

            return SDF, None
        if name == "open3d":
            import open3d

            return open3d, None
        if name == "mesh2sdf":
            import mesh2sdf

            return mesh2sdf, None
    except Exception as exc:  # optional peers
        return None, exc
    raise KeyError(name)


def error_stats(values: np.ndarray, exact: np.ndarray, tolerance: float) -> str:
    """Max abs error and sign errors (where the exact distance is beyond ``tolerance``)."""
    err = float(np.abs(values - exact).max())
    decisive = np.abs(exact) > tolerance
    signs = int(np.count_nonzero(np.sign(values[decisive]) != np.sign(exact[decisive])))
    return f"max err {err:.2e}, sign errors {signs}/{int(decisive.sum())}"


def mesh_rows(name, mesh, resolution, devices, rng, sample: int) -> list[Row]:
    case = f"{name} ({len(mesh.faces):,} faces), {resolution}^3 grid"
    print(f"  {case}", flush=True)
    grid = cubic_grid(mesh.bounds, resolution, 0.1)
    points = grid.points()
    n = len(points)
    pick = rng.choice(n, size=min(sample, n), replace=False)
    exact = reference.mesh_distance_naive(mesh, points[pick]).astype(np.float64)
    diag = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    tol = 1e-4 * diag
    rows = []
    for dev in devices:
        t0 = time.perf_counter()
        prepare_mesh(mesh)
        build = time.perf_counter() - t0
        values = mesh_distance(mesh, field=grid, device=dev).values.reshape(-1)
        t = time_call(lambda dev=dev: mesh_distance(mesh, field=grid, device=dev), min_time=0.5, warmup=0, max_repeats=3)
        rows.append(Row(case, f"geosynth {dev}", t, n, 0, False,
                        f"{error_stats(values[pick], exact, tol)}; BVH build {build:.2f} s (cached)"))

    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    sdf_cls, err = _peer("pysdf")
    if sdf_cls is not None:
        sdf = sdf_cls(v.astype(np.float32), f.astype(np.uint32))
        values = -np.asarray(sdf(points), np.float64)  # pysdf: positive inside
        t = time_call(lambda: sdf(points), min_time=0.5, warmup=0, max_repeats=3)
        rows.append(Row(case, "pysdf", t, n, 0, True, error_stats(values[pick], exact, tol)))
    o3d, err3 = _peer("open3d")
    if o3d is not None:
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
        q = o3d.core.Tensor(points)
        values = scene.compute_signed_distance(q).numpy().astype(np.float64)
        t = time_call(lambda: scene.compute_signed_distance(q), min_time=0.5, warmup=0, max_repeats=3)
        rows.append(Row(case, "open3d RaycastingScene", t, n, 0, True, error_stats(values[pick], exact, tol)))
    m2s, err4 = _peer("mesh2sdf")
    if m2s is not None:
        # mesh2sdf samples [-1, 1]^3 with `size` points per side: map our cubic grid onto it.
        centre = (grid.bounds[0] + grid.bounds[1]) / 2
        half = float((grid.bounds[1] - grid.bounds[0]).max()) / 2
        vn = ((v - centre) / half).astype(np.float32)
        size = resolution

        def run_m2s():
            return m2s.compute(vn, f, size=size, fix=False)

        vol = run_m2s()  # (size, size, size) indexed (x, y, z) on [-1, 1]^3 in mesh2sdf's convention
        t = time_call(run_m2s, min_time=0.5, warmup=0, max_repeats=3)
        lin = np.linspace(-1, 1, size)
        sample_pts = np.stack(np.meshgrid(lin, lin, lin, indexing="ij"), -1).reshape(-1, 3)
        sub = rng.choice(len(sample_pts), size=min(sample, len(sample_pts)), replace=False)
        world = sample_pts[sub] * half + centre
        ex = reference.mesh_distance_naive(mesh, world.astype(np.float32)).astype(np.float64)
        got = vol.reshape(-1)[sub].astype(np.float64) * half
        rows.append(Row(case, "mesh2sdf (its own grid)", t, size**3, 0, True, error_stats(got, ex, tol)))
    for peer, e in (("pysdf", err), ("open3d", err3), ("mesh2sdf", err4)):
        if e is not None and case.endswith("64^3 grid") and name == "torus":
            print(f"    {peer} unavailable ({type(e).__name__}: {e}); its rows are left out")
    return rows


def median_call(fn, repeats: int = 9) -> tuple[float, float, float]:
    """(median, min, max) wall seconds of ``fn()`` over ``repeats`` calls after one warm-up."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), min(times), max(times)


def point_query_rows(name, mesh, resolution, devices, rng, repeats: int) -> list[Row]:
    """mesh_distance at the grid's sample positions as points, grid order and shuffled."""
    grid = mesh_distance(mesh, field=cubic_grid(mesh.bounds, resolution, 0.1), device=devices[0])
    nz, ny, nx = grid.shape
    o, sp = grid.origin.astype(np.float32), grid.spacing.astype(np.float32)
    axes = [o[a] + sp[a] * np.arange(n, dtype=np.float32) for a, n in enumerate((nx, ny, nz))]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    points = np.stack([x, y, z], -1).reshape(-1, 3)  # the kernels' float32 sample positions
    want = grid.values.reshape(-1)
    perm = rng.permutation(len(points))
    sdf_cls, _ = _peer("pysdf")
    sdf = None
    if sdf_cls is not None:
        sdf = sdf_cls(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32))
    rows = []
    for order, pts, ref in (("grid order", points, want), ("shuffled", points[perm], want[perm])):
        case = f"{name} ({len(mesh.faces):,} faces), {len(pts):,} points ({resolution}^3 grid positions, {order})"
        print(f"  {case}", flush=True)
        for dev in devices:
            same = mesh_distance(mesh, pts, device=dev).tobytes() == ref.tobytes()
            med, lo, hi = median_call(lambda dev=dev, pts=pts: mesh_distance(mesh, pts, device=dev), repeats)
            rows.append(Row(case, f"geosynth {dev}", med, len(pts), 0, False,
                            f"median of {repeats}, spread {lo * 1e3:.1f}-{hi * 1e3:.1f} ms; "
                            f"{'bit-identical to' if same else 'DIFFERS from'} the grid path"))
        if sdf is not None:
            med, lo, hi = median_call(lambda pts=pts: sdf(pts), repeats)
            rows.append(Row(case, "pysdf", med, len(pts), 0, True,
                            f"median of {repeats}, spread {lo * 1e3:.1f}-{hi * 1e3:.1f} ms"))
    return rows


def mls_rows(devices, rng, count: int, resolution: int) -> list[Row]:
    import trimesh

    case = f"MLS point set ({count:,} points on a torus), {resolution}^3 grid"
    print(f"  {case}", flush=True)
    mesh = torus_mesh(1.0, 0.35, 256, 128)
    pts, face = trimesh.sample.sample_surface_even(mesh, count, seed=1) if hasattr(trimesh.sample, "sample_surface_even") else trimesh.sample.sample_surface(mesh, count)
    normals = mesh.face_normals[face]
    grid = cubic_grid(mesh.bounds, resolution, 0.1)
    rows = []
    for dev in devices:
        for far in ("nearest", "reach"):
            t = time_call(lambda dev=dev, far=far: pointset_distance(pts, normals, field=grid, far=far, device=dev),
                          min_time=0.5, warmup=1, max_repeats=3)
            rows.append(Row(case, f"geosynth {dev} (far={far})", t, int(np.prod(grid.shape)), 0, False,
                            "distance + gradient; default width"))
    return rows


def options(argv=None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    return parse_args(__doc__, argv, quick="small meshes and grids, for a smoke run")


def main(argv=None) -> int:
    args = options(argv)
    devices = start(args)
    rng = np.random.default_rng(0)

    if args.quick:
        meshes = [("torus", torus_mesh(1.0, 0.35, 40, 20)), ("chainmail", chainmail_mesh(2, major_sections=16, minor_sections=8))]
        grids, sample, mls = [24], 200, (5_000, 24)
    else:
        meshes = [("torus", torus_mesh(1.0, 0.35, 125, 80)), ("chainmail", chainmail_mesh()),
                  ("torus", torus_mesh(1.0, 0.35, 500, 200))]
        grids, sample, mls = [64, 128], 1000, (100_000, 64)
    rows: list[Row] = []
    for name, mesh in meshes:
        for res in grids:
            rows += mesh_rows(name, mesh, res, devices, rng, sample if len(mesh.faces) < 100_000 else sample // 4)
    rows += point_query_rows(*meshes[0], grids[0], devices, rng, 5 if args.quick else 9)
    rows += mls_rows(devices, rng, *mls)
    return finish(table(rows).replace("| elements/s |", "| points/s |"), args)


if __name__ == "__main__":
    sys.exit(main())
