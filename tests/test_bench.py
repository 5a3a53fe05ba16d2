"""The benchmarks and `make gpu-check` stay runnable: every bench/bm_*.py imports and
parses its command line through the shared harness (no timing here), reports are
written whole, steps are stopped at their limit, and gpu-check refuses a machine
with no CUDA device in one line."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = sorted(p.stem for p in (ROOT / "bench").glob("bm_*.py"))


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(f"_bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def harness():
    return _load(ROOT / "bench" / "harness.py")


def test_every_benchmark_is_found():
    assert {"bm_fields", "bm_main", "bm_scoring", "bm_texture", "bm_volume"} <= set(BENCHMARKS)


@pytest.mark.parametrize("name", BENCHMARKS)
def test_benchmark_parses_the_shared_options(name, capsys):
    module = _load(ROOT / "bench" / f"{name}.py")
    args = module.options(["--quick", "--devices", "cpu,opencl:0:0", "--out", "x.md"])
    assert args.quick is True
    assert args.devices == ["cpu", "opencl:0:0"]
    assert args.out == "x.md"
    defaults = module.options([])
    assert defaults.quick is False and defaults.devices is None
    with pytest.raises(SystemExit) as exit_info:
        module.options(["--help"])
    assert exit_info.value.code == 0
    assert "--quick" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:  # a malformed device is refused before any work
        module.options(["--devices", "gpu7"])
    assert exit_info.value.code == 2
    assert "Malformed device 'gpu7'" in capsys.readouterr().err


def test_benchmark_extras():
    volume = _load(ROOT / "bench" / "bm_volume.py")
    assert volume.options(["--cases", "64,128"]).cases == {64, 128}
    with pytest.raises(SystemExit):
        volume.options(["--cases", "64,big"])
    texture = _load(ROOT / "bench" / "bm_texture.py")
    args = texture.options(["--scale", "0.1"])
    assert args.scale == 0.1 and args.out.endswith("bm_texture.md")
    assert all(case[3] == texture.QUICK_POINTS for case in texture.QUICK_CASES)


def test_finish_writes_the_report(harness, tmp_path, capsys):
    args = harness.parse_args("doc", ["--devices", "cpu", "--quick", "--out", str(tmp_path / "r.md")], quick="q")
    assert harness.finish("| a |\n", args, title="# T") == 0
    text = (tmp_path / "r.md").read_text()
    assert text.startswith("# T\n\nMachine: ")
    assert "Devices: cpu (--quick" in text and text.endswith("| a |\n")
    assert [p.name for p in tmp_path.iterdir()] == ["r.md"]  # no temporary file left
    assert "written" in capsys.readouterr().out


def test_run_step_reports_status_and_stops_at_the_limit(harness, tmp_path):
    ok = harness.run_step("ok", [sys.executable, "-c", "print('hi')"], timeout=30, log=tmp_path / "ok.log")
    assert ok.status == "ok" and (tmp_path / "ok.log").read_text() == "hi\n"
    bad = harness.run_step("bad", [sys.executable, "-c", "raise SystemExit(3)"], timeout=30, log=tmp_path / "bad.log")
    assert bad.status == "failed (exit 3)"
    slow = harness.run_step("slow", [sys.executable, "-c", "import time; time.sleep(60)"], timeout=1,
                            log=tmp_path / "slow.log")
    assert slow.status == "timed out after 1 s" and slow.seconds < 10
    table = harness.steps_table([ok, bad, slow], tmp_path)
    assert "| bad | failed (exit 3) |" in table and "| slow.log |" in table


def test_gpu_check_refuses_a_machine_without_cuda():
    gpu_check = _load(ROOT / "tools" / "gpu_check.py")
    with pytest.raises(gpu_check.CheckError, match="^gpu-check: no CUDA device present"):
        gpu_check.check_devices(["cuda", "cpu"], ["cpu", "opencl:0:0"], "--test-devices")
    with pytest.raises(gpu_check.CheckError, match="cuda:1 is not present"):
        gpu_check.check_devices(["cuda:1"], ["cpu", "cuda:0"], "--test-devices")
    gpu_check.check_devices(["cuda", "cpu", "opencl:0:0"], ["cpu", "cuda:0", "opencl:0:0"], "--bench-devices")


@pytest.mark.skipif(any(d.startswith("cuda") for d in __import__("geosynth").devices()), reason="a CUDA device is present")
def test_gpu_check_exits_with_one_line_without_cuda():
    run = subprocess.run([sys.executable, str(ROOT / "tools" / "gpu_check.py")], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert run.returncode == 2
    assert run.stdout == ""
    assert run.stderr.count("\n") == 1 and run.stderr.startswith("gpu-check: no CUDA device present")
