"""M2's element size (geosynth.pointtexture.element_size) and the patch size chosen from it (issue 32,
items 1 and 2): measured periods of relief nobody tuned for, the same choice for a built-in
and a file, --patch overriding, the output's element size and amplitude kept, the same
numbers on an SSE4 CPU."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geosynth.pointtexture.element_size import relief_scale
from geosynth.pointtexture.examples import point_texture_example
from geosynth.pointtexture.synthesis import PATCH_PERIODS, choose_patch, synthesize_point_texture
from geosynth.pointtexture.texture import PointTexture, read_point_texture, texture_from_points


def _relief(fn, n=150, width=1.5, pad=0.25, seed=0) -> PointTexture:
    """A jittered grid of points z = fn(x, y) over [0, width]^2 (B inside by ``pad``), normals
    from fn's central differences."""
    rng = np.random.default_rng(seed)
    u = (np.arange(n) + 0.5) * width / n
    x, y = np.meshgrid(u, u)
    xy = np.c_[x.ravel(), y.ravel()] + rng.uniform(-0.2, 0.2, (n * n, 2)) * width / n
    z = fn(xy[:, 0], xy[:, 1])
    e = 1e-4 * width
    dx = (fn(xy[:, 0] + e, xy[:, 1]) - fn(xy[:, 0] - e, xy[:, 1])) / (2 * e)
    dy = (fn(xy[:, 0], xy[:, 1] + e) - fn(xy[:, 0], xy[:, 1] - e)) / (2 * e)
    normals = np.c_[-dx, -dy, np.ones_like(dx)]
    return PointTexture(np.c_[xy, z], normals, [pad, pad, z.min()], [width - pad, width - pad, z.max()], name="relief")


def _ridges(period, degrees, amp=0.03):
    a = np.radians(degrees)
    return lambda x, y: amp * np.sin(2 * np.pi * (x * np.cos(a) + y * np.sin(a)) / period)


def _bumps(radius, spacing, seed, jitter=0.25):
    rng = np.random.default_rng(seed)
    k = np.arange(-1, int(1.5 / spacing) + 2)
    cx, cy = np.meshgrid(k, k)
    c = (np.c_[cx.ravel(), cy.ravel()] + 0.5 + rng.uniform(-jitter, jitter, (cx.size, 2))) * spacing

    def fn(x, y):
        d2 = (x[:, None] - c[:, 0]) ** 2 + (y[:, None] - c[:, 1]) ** 2
        return 0.05 * np.clip(1 - d2 / radius ** 2, 0, None).max(axis=1) ** 2  # smooth domes
    return fn


@pytest.mark.parametrize("period, degrees", [(0.12, 0), (0.2, 90), (0.16, 45), (0.28, 120)])
def test_ridges_period_found_at_any_orientation(period, degrees):
    rs = relief_scale(*_args(_relief(_ridges(period, degrees))))
    assert rs.peak and abs(rs.period / period - 1) < 0.1, rs
    assert abs(rs.angle - degrees) < 8 or abs(abs(rs.angle - degrees) - 180) < 8, rs
    assert abs(rs.amplitude / 0.06 - 1) < 0.05, rs  # 5-95% of a sine of amplitude 0.03: 2 x 0.03 x 0.988


@pytest.mark.parametrize("radius, spacing, seed", [(0.04, 0.12, 1), (0.07, 0.2, 2), (0.1, 0.3, 3)])
def test_bumps_spacing_found_over_seeds(radius, spacing, seed):
    rs = relief_scale(*_args(_relief(_bumps(radius, spacing, seed), seed=seed)))
    assert rs.peak and abs(rs.period / spacing - 1) < 0.15, rs


def test_a_slope_has_no_dominant_period():
    rs = relief_scale(*_args(_relief(lambda x, y: 0.1 * x + 0.02 * y)))
    assert not rs.peak and rs.period == pytest.approx(0.5, rel=0.02), rs


def _args(t):
    return t.points, t.box_min, t.box_max, t.spacing


def test_patch_follows_the_element_size():
    small, large = (choose_patch(_relief(_ridges(p, 30))) for p in (0.12, 0.24))
    assert small.patch == pytest.approx(PATCH_PERIODS * small.scale.period, abs=0.006)
    assert large.patch / small.patch == pytest.approx(2, rel=0.1)
    assert "dominant period" in small.line and f"patch {small.patch:.2f}" in small.line
    few = choose_patch(_relief(_ridges(0.6, 0)))  # under two periods across B: capped
    assert few.patch == 0.5 and "capped" in few.line
    tiny = choose_patch(_relief(_ridges(0.05, 0), n=220), resolution=24)  # 0.075 of B is 3 cells at 24
    assert round(tiny.patch * 23) >= 6 and "raised" in tiny.line


def test_a_file_gets_what_its_built_in_gets(tmp_path):
    """flowers written as a PLY and read back (another box B: 0.2 of the extent as padding)
    gets the same patch size in world units as the built-in, which has no setting of its own."""
    from geosynth.geometry.pointsets import PointSet, write_point_set

    t = point_texture_example("flowers", count=12_000)
    path = tmp_path / "flowers.ply"
    write_point_set(path, PointSet(t.points.astype(np.float32), t.normals.astype(np.float32)))
    f = read_point_texture(path)
    a, b = choose_patch(t), choose_patch(f)
    world_a = a.patch * float(t.extent[:2].min())
    world_b = b.patch * float(f.extent[:2].min())
    assert abs(world_b / world_a - 1) < 0.15, (a.line, b.line)


def test_the_run_says_its_patch_and_reports_element_size_and_amplitude_and_patch_overrides():
    tex = _relief(_bumps(0.06, 0.2, 4), n=80, seed=4)
    _, report, _ = synthesize_point_texture(tex, device="cpu", scale=1.2, resolution=24, quality=False)
    choice = choose_patch(tex, 24)
    assert report.lines()[0] == report.patch_choice == choice.line
    assert report.patch == round(choice.patch * float(tex.extent[:2].min()) / report.cell)
    (pe, ae, _), (po, ao, _) = report.relief["exemplar"], report.relief["output"]
    assert (pe, ae) == (choice.scale.period, choice.scale.amplitude) and 0.5 * pe <= po <= 2 * pe and ao > 0
    assert any(line.startswith("element size / relief amplitude") for line in report.lines())
    _, report, _ = synthesize_point_texture(tex, device="cpu", scale=1.2, patch=0.45, resolution=24, quality=False)
    assert report.patch_choice == "" and report.patch == round(0.45 * float(tex.extent[:2].min()) / report.cell)
    assert "exemplar" in report.relief and "output" in report.relief


@pytest.mark.parametrize("seed", range(3))
def test_an_output_is_measured_like_its_exemplar(seed):
    """The output's element size is measured over its extent at the exemplar's cell, within
    half to twice the exemplar's period: a larger sample of the same relief (another seed of
    its bumps) reads the same period and amplitude, so a ratio off 1 is the synthesis's."""
    ex = _relief(_bumps(0.06, 0.2, 4), n=80, seed=4)
    e = relief_scale(*_args(ex))
    big = _relief(_bumps(0.06, 0.2, 10 + seed), n=128, width=1.5 * 1.6, seed=seed)
    lo = big.box_min[:2]
    o = relief_scale(big.points, lo, lo + 1.6, ex.spacing, cell=e.cell[0], band=(0.5 * e.period, 2 * e.period))
    assert abs(o.period / e.period - 1) < 0.1 and abs(o.amplitude / e.amplitude - 1) < 0.1, (e, o)


def test_same_numbers_on_an_sse4_cpu():
    """The element size feeds the patch size, a decision: it must be the same on every CPU
    (tests/test_unchanged.py's SSE4 setting: NumPy's SIMD code held to SSE4)."""
    from test_unchanged import SSE4_ENV

    code = ("import sys; sys.path.insert(0, sys.argv[1]); import test_element_size as t; "
            "print(repr(t._fingerprint()))")
    root = Path(__file__).resolve().parent.parent
    env = dict(os.environ, **SSE4_ENV, PYTHONPATH=os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])))
    run = subprocess.run([sys.executable, "-c", code, str(Path(__file__).resolve().parent)], env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip().splitlines()[-1] == repr(_fingerprint())


def _fingerprint():
    out = []
    for name in ("flowers", "weave"):
        t = point_texture_example(name, count=8_000)
        rs = relief_scale(*_args(t))
        out.append((rs.period.hex(), rs.amplitude.hex(), choose_patch(t).patch))
    return out


def test_cli_says_the_patch_it_chose(tmp_path, capsys):
    """`geosynth pointtexture FILE` with no --patch: the header says "(automatic)" and the
    next line what was measured; the report has the element size line."""
    from geosynth.cli import main
    from geosynth.geometry.pointsets import PointSet, write_point_set

    tex = _relief(_ridges(0.2, 30), n=70)
    path = tmp_path / "ridges.ply"
    write_point_set(path, PointSet(tex.points.astype(np.float32), tex.normals.astype(np.float32)))
    code = main(["pointtexture", str(path), "-o", str(tmp_path / "out.ply"), "--scale", "1.2", "--resolution", "24",
                 "--no-quality", "--device", "cpu"])
    out = capsys.readouterr().out.splitlines()
    assert code == 0
    head = next(i for i, line in enumerate(out) if line.startswith("geosynth pointtexture:"))
    assert "(automatic)" in out[head] and out[head + 1].startswith("patch ") and "dominant period" in out[head + 1]
    assert any(line.startswith("element size / relief amplitude") for line in out)
