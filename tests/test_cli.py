"""The command line: bad input is one line on stderr and exit code 2, before any work,
and never costs an input file; Ctrl-C and SIGTERM end a run quietly."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

import geosynth.cli as cli
from conftest import ONE_DEVICE
from geosynth.cli import main

TINY = ["--size", "16", "--levels", "1", "--block", "8", "--quality-samples", "0", "--quiet"]
V = ["--size", "32", "--levels", "2", "--block", "8", "--quality-samples", "0", "--quiet"]


def _png_header(width: int, height: int) -> bytes:
    """A PNG whose header claims width x height 1-bit grey pixels (one empty row of data):
    Pillow refuses it on open as a decompression bomb without reading the pixels."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0")) + chunk(b"IEND", b"")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """Inputs of every kind in one folder: meshes, a point set, a texture, a bomb, a folder."""
    import trimesh

    from geosynth.geometry.pointsets import write_point_set
    from geosynth.texturing.models import point_model
    from geosynth.texturing.textures import texture_example, write_texture

    d = tmp_path_factory.mktemp("cli")
    torus = trimesh.creation.torus(1.0, 0.3)
    torus.export(d / "rings.ply")
    trimesh.creation.box().export(d / "box.obj")
    # a torus with one zero-area face
    n = len(torus.vertices)
    v = np.vstack([torus.vertices, [[0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]]])
    f = np.vstack([torus.faces, [[n, n + 1, n + 2]]])
    trimesh.Trimesh(v, f, process=False).export(d / "degen.ply")
    write_point_set(d / "model.ply", point_model("torus", 400))
    write_point_set(d / "few.ply", point_model("sphere", 20))
    write_texture(d / "tex.png", texture_example("noise", 32))
    (d / "bomb.png").write_bytes(_png_header(20_000, 20_000))
    (d / "adir.ply").mkdir()
    (d / "afile").write_bytes(b"not a folder")
    (d / "link.ply").symlink_to(d / "rings.ply")
    (d / "out_link.png").symlink_to(d / "v.ply")  # an output that names another output
    return d


def _snapshot(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file() and not p.is_symlink()}


def _error_lines(err: str) -> list[str]:
    # Every line counts: Warp's missing-driver notice is held back without --verbose.
    return [line for line in err.splitlines() if line.strip()]


def _run_main(argv: list[str], capsys) -> tuple[int, str]:
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's errors
        rc = exc.code
    return rc, capsys.readouterr().err


def _run_process(argv: list[str], cwd: Path, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "geosynth.cli", *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=120, **kwargs)


# (argv, what the one line must say); {d} is the folder of the inputs.
CASES = {
    # outputs that would overwrite an input, or could not be written
    "volume --png is the input mesh": (["volume", "{d}/rings.ply", "--size", "64", "--levels", "2", "--block", "8",
                                        "--quiet", "-o", "{d}/v.ply", "--png", "{d}/rings.ply"], "--png"),
    "field --png is the input mesh": (["field", "{d}/box.obj", "-o", "{d}/f.npz", "--resolution", "32",
                                       "--png", "{d}/box.obj"], "--png"),
    "volume -o is the input": (["volume", "{d}/rings.ply", "-o", "{d}/rings.ply", *V], "input file"),
    "volume -o through ..": (["volume", "{d}/rings.ply", "-o", "{d}/nowhere/../rings.ply", *V], "input file"),
    "volume -o through a symlink": (["volume", "{d}/rings.ply", "-o", "{d}/link.ply", *V], "input file"),
    "texture --png is the texture": (["texture", "{d}/model.ply", "{d}/tex.png", "-o", "{d}/c.ply",
                                      "--png", "{d}/tex.png", "--quiet"], "input file"),
    "texture default picture is the texture": (["texture", "{d}/model.ply", "{d}/tex.png", "-o", "{d}/tex.ply",
                                                "--quiet"], "default --png"),
    "texture -o is the model": (["texture", "{d}/model.ply", "{d}/tex.png", "-o", "{d}/model.ply", "--quiet"],
                                "input file"),
    "field -o under a file": (["field", "{d}/box.obj", "-o", "{d}/afile/f.npz"], "is a file, not a folder"),
    "two outputs, one file": (["volume", "--example", "terrain", "-o", "{d}/v.ply", "--png", "{d}/out_link.png",
                               *V], "same file"),
    "--png with another picture suffix": (["volume", "--example", "terrain", "-o", "{d}/v.ply",
                                           "--png", "{d}/pic.gif", *V], ".png, .jpg, .jpeg"),
    "-o with a wrong suffix": (["field", "--example", "torus", "-o", "{d}/f.txt"], ".npz"),
    "-o is a folder": (["volume", "--example", "terrain", "-o", "{d}/adir.ply", *V], "is a folder"),
    "-o under a file": (["volume", "--example", "terrain", "-o", "{d}/afile/v.ply", *V], "is a file, not a folder"),
    "demo -o is a file": (["demo", "-o", "{d}/rings.ply", "--quiet"], "is a file"),
    "demo -o under a file": (["demo", "-o", "{d}/afile/out", "--quiet"], "is a file, not a folder"),
    "-o missing": (["volume", "--example", "terrain", *V], "the following arguments are required: -o/--output"),
    # missing or unreadable inputs
    "volume exemplar missing": (["volume", "{d}/nope.obj", "-o", "{d}/x.ply", *V], "EXEMPLAR"),
    "volume exemplar is a folder": (["volume", "{d}/adir.ply", "-o", "{d}/x.ply", *V], "is a folder"),
    "volume neither exemplar nor example": (["volume", "-o", "{d}/x.ply", *V], "--example"),
    "texture image missing": (["texture", "--example", "sphere", "{d}/nope.png", "-o", "{d}/t.ply"], "TEXTURE"),
    "texture model missing": (["texture", "{d}/nope.ply", "--texture-example", "noise", "-o", "{d}/t.ply"], "MODEL"),
    "field input missing": (["field", "{d}/nope.obj", "-o", "{d}/f.npz"], "INPUT"),
    "texture image a decompression bomb": (["texture", "--example", "sphere", "--count", "100", "-k", "8",
                                            "{d}/bomb.png", "-o", "{d}/t.ply", "--quiet", "--device", "{dev}"],
                                           ("pixels", "20000", "20,000")),
    # numbers out of range, named by their flag, with the allowed range
    "demo --repeat 0": (["demo", "--repeat", "0"], "--repeat: must be an integer from 1 to 1000, got 0"),
    "demo --size 2": (["demo", "--size", "2"], "--size: must be an integer from 4 to 256"),
    "demo --block 1": (["demo", "--block", "1"], "--block: must be an integer >= 2"),
    "demo --block > --size": (["demo", "--size", "16", "--block", "32"], "--block 32 is larger than --size 16"),
    "--seed -1": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--seed", "-1"], "--seed: must be an integer >= 0"),
    "--seed not a number": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply",
                             "--seed", "x"], "--seed: must be an integer >= 0, got 'x'"),
    "--quality-samples -3": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--quality-samples", "-3"],
                             "--quality-samples: must be an integer >= 0"),
    "--size 32 0 32": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--size", "32", "0", "32"],
                       "--size: each number must be an integer >= 8, got 0"),
    "--size two numbers": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--size", "32", "32"],
                           "three (x y z), got 2: 32 32"),
    "--size not a multiple, in x y z": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--levels", "3",
                                         "--size", "30", "32", "64"], "--size 30 32 64: with --levels 3 every number "
                                                                      "must be a multiple of 2^(levels-1) = 4; try "
                                                                      "--size 32 32 64"),
    "--size smaller than --block": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--levels", "1",
                                     "--size", "64", "8", "64", "--block", "16"], "larger than --size 64 8 64 along y"),
    "--levels 0": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--levels", "0"],
                   "--levels: must be an integer from 1 to 8, got 0"),
    "--levels 9": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply",
                    "--levels", "9"], "--levels: must be an integer from 1 to 8"),
    "--block not a power of two": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--block", "12"],
                                   "--block: each number must be a power of two >= 2, got 12"),
    "--block count": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--levels", "3", "--block", "8", "8"],
                      "one per level"),
    "--source-resolution 4": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--source-resolution", "4"],
                              "--source-resolution: must be an integer >= 8"),
    "--source-resolution < --block": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--source-resolution",
                                       "8", "--block", "16"], "--source-resolution 8 is smaller than the finest block"),
    "--smooth -1": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--smooth", "-1"],
                    "--smooth: must be an integer from 0 to 1000"),
    "--count 10": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply", "--count", "10"],
                   "--count: must be an integer >= 16"),
    "--texture-size 4": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply",
                          "--texture-size", "4"], "--texture-size: must be an integer >= 8"),
    "--texture-size bricks 20": (["texture", "--example", "sphere", "--texture-example", "bricks", "-o", "{d}/t.ply",
                                  "--texture-size", "20"], "multiples of 16"),
    "--texture-size checker 16": (["texture", "--example", "sphere", "--texture-example", "checker", "-o",
                                   "{d}/t.ply", "--texture-size", "16"], "at least 24"),
    "--texture-size smaller than -k": (["texture", "--example", "sphere", "--texture-example", "noise", "-o",
                                        "{d}/t.ply", "--texture-size", "16", "-k", "25", "--levels", "3"],
                                       "--texture-size 16 is smaller than the neighbourhood of -k 25"),
    "-k 2": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply", "-k", "2"],
             "-k: must be an integer >= 3"),
    "-k >= --count": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply",
                       "--count", "20", "-k", "25"], "-k 25 needs more than 25 points but --count is 20"),
    "--m 0": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply", "--m", "0"],
              "--m: must be an integer from 1 to 32"),
    "--unit-scale 0": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply",
                        "--unit-scale", "0"], "--unit-scale: must be a finite number > 0"),
    "--threshold nan": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply",
                         "--threshold", "nan"], "--threshold: must be a finite number > 0"),
    "--pattern-size -1": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply",
                           "--pattern-size", "-1"], "--pattern-size: must be a finite number > 0"),
    "--views 5": (["texture", "--example", "sphere", "--texture-example", "noise", "-o", "{d}/t.ply", "--views", "5"],
                  "--views: must be an integer from 1 to 4"),
    "--resolution 1": (["field", "--example", "torus", "-o", "{d}/f.npz", "--resolution", "1"],
                       "--resolution: must be an integer >= 2"),
    "--padding -0.1": (["field", "--example", "torus", "-o", "{d}/f.npz", "--padding", "-0.1"],
                       "--padding: must be a finite number >= 0"),
    "--band 0": (["field", "--example", "torus", "-o", "{d}/f.npz", "--band", "0"], "--band: must be a finite number > 0"),
    "--radius inf": (["field", "--example", "torus", "-o", "{d}/f.npz", "--radius", "inf"],
                     "--radius: must be a finite number > 0"),
    "--device malformed": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--device", "gpu0"],
                           "--device: Malformed device"),
    "--device absent": (["field", "--example", "torus", "-o", "{d}/f.npz", "--device", "cuda:7"],
                        "--device cuda:7: Device 'cuda:7' is not present"),
    # failures found while working: named by the flag that fixes them
    "-k >= the file's points": (["texture", "{d}/few.ply", "--texture-example", "noise", "-o", "{d}/t.ply", "-k", "25",
                                 "--quiet", "--device", "{dev}"], "-k 25 needs more than 25 points"),
    "zero-area faces, volume": (["volume", "{d}/degen.ply", "-o", "{d}/x.ply", *TINY, "--device", "{dev}"],
                                "--drop-degenerate"),
    "zero-area faces, field": (["field", "{d}/degen.ply", "-o", "{d}/f.npz", "--resolution", "8", "--quiet",
                                "--device", "{dev}"], "--drop-degenerate"),
    "--size 100000": (["volume", "--example", "terrain", "-o", "{d}/x.ply", "--size", "100000", "--levels", "1",
                       "--block", "8", "--source-resolution", "16", "--quality-samples", "0", "--quiet",
                       "--device", "{dev}"], "--size"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_one_line(name, files, capsys):
    argv, says = CASES[name]
    argv = [a.replace("{d}", str(files)).replace("{dev}", ONE_DEVICE) for a in argv]
    before = _snapshot(files)
    rc, err = _run_main(argv, capsys)
    lines = _error_lines(err)
    assert rc == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"geosynth {argv[0]}: "), lines
    assert any(s in lines[0] for s in ((says,) if isinstance(says, str) else says)), lines[0]
    assert "Traceback" not in err
    assert _snapshot(files) == before  # no input touched, no output left behind


# The same through a real process: exit code, stderr and the input's bytes.
PROCESS_CASES = ["volume --png is the input mesh", "field --png is the input mesh", "volume exemplar missing",
                 "demo --repeat 0", "demo -o is a file", "--levels 0", "-o under a file", "--size 100000",
                 "texture image a decompression bomb"]


@pytest.mark.parametrize("name", PROCESS_CASES)
def test_bad_input_in_a_process(name, files):
    argv, says = CASES[name]
    argv = [a.replace("{d}", str(files)).replace("{dev}", ONE_DEVICE) for a in argv]
    before = _snapshot(files)
    res = _run_process(argv, files)
    lines = _error_lines(res.stderr)
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1, res.stderr
    assert any(s in lines[0] for s in ((says,) if isinstance(says, str) else says)), lines[0]
    assert "Traceback" not in res.stderr and "Warning" not in res.stderr
    assert _snapshot(files) == before


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root may write anywhere")
def test_unwritable_folder(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        rc, err = _run_main(["field", "--example", "torus", "-o", str(locked / "f.npz")], capsys)
    finally:
        locked.chmod(0o700)
    assert rc == 2 and len(_error_lines(err)) == 1 and "no write permission" in err


def test_debug_shows_the_traceback(files):
    argv = ["volume", str(files / "nope.obj"), "-o", str(files / "x.ply"), *V]
    quiet = _run_process(argv, files)
    assert quiet.returncode == 2 and "Traceback" not in quiet.stderr
    for extra in (argv + ["--debug"], ["--debug"] + argv):
        res = _run_process(extra, files)
        assert res.returncode != 0 and "Traceback" in res.stderr and "ValueError" in res.stderr, res.stderr


def test_memory_refusal_names_the_flag():
    from geosynth.core.memory import MemoryBudgetError, require

    with pytest.raises(MemoryBudgetError) as info:
        require(9 << 30, option="texture_size", value=4096, largest=512, what="a 4096^2 texture", available=1 << 30)
    text = cli._message(info.value, "texture")
    assert text.startswith("--texture-size: ") and "lower --texture-size to at most 512" in text
    assert "lower texture_size" not in text
    # a (z, y, x) size is shown in the user's x y z order
    with pytest.raises(MemoryBudgetError) as info:
        require(9 << 30, option="size", value=(16, 640, 1280), largest=(16, 64, 128), what="size 1280 x 640 x 16",
                available=1 << 30)
    assert "lower --size to at most 128 x 64 x 16 (x y z)" in cli._message(info.value, "volume")
    plain = cli._message(MemoryError("needs 9 GiB"), "field")
    assert "--resolution" in plain


def test_os_errors_unexpected_errors_and_multiline_messages(files, capsys, monkeypatch):
    def denied(args):
        raise PermissionError(13, "Permission denied", "/some/file.ply")

    monkeypatch.setattr(cli, "_cmd_devices", denied)
    rc, err = _run_main(["devices"], capsys)
    assert rc == 2 and err.strip() == "geosynth devices: /some/file.ply: Permission denied"

    def multiline(args):
        raise ValueError("first line\nsecond line")

    monkeypatch.setattr(cli, "_cmd_devices", multiline)
    rc, err = _run_main(["devices"], capsys)
    assert rc == 2 and err.strip() == "geosynth devices: first line second line"

    def bug(args):
        raise KeyError("oops")

    monkeypatch.setattr(cli, "_cmd_devices", bug)
    rc, err = _run_main(["devices"], capsys)
    assert rc == 1 and len(err.strip().splitlines()) == 1 and "KeyError" in err and "--debug" in err
    with pytest.raises(KeyError):
        main(["--debug", "devices"])


def test_keyboard_interrupt_exits_130(files, capsys, monkeypatch):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_cmd_volume", interrupted)
    rc, err = _run_main(["volume", "--example", "terrain", "-o", str(files / "x.ply"), *V], capsys)
    assert rc == 130 and err.strip() == "geosynth volume: interrupted"


def test_verbose_is_passed_to_the_library_not_the_environment(files, capsys, monkeypatch):
    """--verbose reaches geosynth.core.config for the run (the runtimes read it when they load) and
    is taken back after it; the environment is not touched."""
    from geosynth.core import config

    seen = {}

    def record(args):
        seen["v"] = config.verbose()
        seen["env"] = os.environ.get("GEOSYNTH_VERBOSE")
        return 0

    monkeypatch.delenv("GEOSYNTH_VERBOSE", raising=False)
    monkeypatch.setattr(cli, "_cmd_devices", record)
    assert main(["devices"]) == 0 and seen == {"v": False, "env": None}
    assert main(["devices", "--verbose"]) == 0 and seen == {"v": True, "env": None}
    assert not config.verbose()  # taken back
    assert main(["--verbose", "devices"]) == 0 and seen == {"v": True, "env": None}
    monkeypatch.setenv("GEOSYNTH_VERBOSE", "1")
    assert main(["devices"]) == 0 and seen["v"] is True  # the variable still works for every process
    for command in ("volume", "texture", "field", "demo", "devices"):
        assert "--verbose" in cli.build_parser()._subparsers._group_actions[0].choices[command].format_help()


LONG = ["volume", "--example", "terrain", "--size", "512", "--levels", "1", "--block", "8", "--source-resolution",
        "16", "--quality-samples", "0", "--search", "linear", "--method", "paper"]


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signals_end_a_run_quietly(sig, code, tmp_path, one_device):
    out = tmp_path / "long.ply"
    proc = subprocess.Popen([sys.executable, "-m", "geosynth.cli", *LONG, "--device", one_device, "-o", str(out)],
                            cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"},
                            # a shell's background job inherits SIGINT ignored; Python then keeps ignoring it
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # Signal once the synthesis is under way (its progress bar shows): earlier, the
        # interrupt can land in trimesh's optional imports, which catch BaseException.
        seen, deadline = "", time.monotonic() + 60
        while "block/s" not in seen and time.monotonic() < deadline and proc.poll() is None:
            seen += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
        assert "block/s" in seen, seen
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        err = seen + err
    finally:
        proc.kill()
    assert proc.returncode == code, [line for line in err.replace("\r", "\n").splitlines() if "/s]" not in line]
    assert "Traceback" not in err
    tail = [line for line in err.replace("\r", "\n").splitlines() if line.strip()][-1:]
    if sig == signal.SIGINT:
        assert tail == ["geosynth volume: interrupted"], err
    assert not out.exists() and not any(p.name.startswith(".long.ply") for p in tmp_path.iterdir())


def test_good_runs_write_what_they_say(tmp_path, capsys, one_device):
    from PIL import Image

    rc = main(["volume", "--example", "terrain", "-o", str(tmp_path / "v.ply"), "--png", str(tmp_path / "v.jpg"),
               "--source-resolution", "16", "--smooth", "0", "--device", one_device, *TINY])
    assert rc == 0
    assert (tmp_path / "v.ply").read_bytes().startswith(b"ply")
    assert Image.open(tmp_path / "v.jpg").format == "JPEG"
    rc = main(["demo", "--size", "16", "--block", "4", "--repeat", "1", "--device", one_device,
               "-o", str(tmp_path / "demo"), "--quiet"])
    assert rc == 0 and Image.open(tmp_path / "demo" / "nearest_block.png").format == "PNG"
    rc = main(["field", "--example", "torus", "-o", str(tmp_path / "f.npz"), "--resolution", "8", "--quiet",
               "--device", one_device])
    assert rc == 0 and np.load(tmp_path / "f.npz")["values"].shape[-1] >= 2
    assert _error_lines(capsys.readouterr().err) == []


def test_sigterm_while_writing_leaves_nothing(tmp_path, capsys, monkeypatch):
    from geosynth.io.files import atomic_write

    out = tmp_path / "v.ply"

    def terminated_while_writing(args):
        def write(tmp):
            Path(tmp).write_bytes(b"partial")
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(100):  # the handler raises at the next bytecode
                pass

        atomic_write(out, write)
        return 0

    monkeypatch.setattr(cli, "_cmd_volume", terminated_while_writing)
    before = signal.getsignal(signal.SIGTERM)
    rc, err = _run_main(["volume", "--example", "terrain", "-o", str(out), *V], capsys)
    assert rc == 143 and _error_lines(err) == []
    assert list(tmp_path.iterdir()) == []  # neither the output nor the temporary file
    assert signal.getsignal(signal.SIGTERM) == before  # main put the previous handler back


def test_sigint_at_any_moment_leaves_every_old_output_or_every_new_one(tmp_path, one_device):
    # issue 37: an interrupt during the imports was swallowed (exit 0, outputs replaced), and one
    # after the mesh was written left a new mesh beside the old picture. SIGINT from a parent
    # process at moments spread over a whole run, the first during the imports.
    argv = [sys.executable, "-m", "geosynth", "volume", "--example", "terrain", "-o", "k.ply", "--png", "k.png",
            "--size", "32", "--levels", "2", "--block", "4", "--source-resolution", "16", "--quality-samples", "0",
            "--smooth", "0", "--quiet", "--device", one_device]
    t0 = time.monotonic()
    subprocess.run(argv, cwd=tmp_path, check=True, capture_output=True, timeout=120)
    full = time.monotonic() - t0
    new = {name: (tmp_path / name).read_bytes() for name in ("k.ply", "k.png")}
    seen = []
    for moment in [0.05, 0.3] + [full * f for f in (0.45, 0.7, 0.9)]:
        for name in new:
            (tmp_path / name).write_bytes(b"old")
        proc = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        try:
            time.sleep(moment)
            sent = proc.poll() is None
            if sent:
                proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=120)
        finally:
            proc.kill()
        got = {name: (tmp_path / name).read_bytes() for name in new}
        state = "old" if all(v == b"old" for v in got.values()) else "new" if got == new else "mixed"
        seen.append((round(moment, 2), sent, proc.returncode, state))
        assert state != "mixed", seen
        if state == "old" and proc.returncode == 1 and "init_import_site" in err:
            pass  # so early (a loaded machine) that CPython's own start-up stopped, before any geosynth code
        elif state == "old":
            # (CPython prints "Exception ignored in" when the handler's KeyboardInterrupt lands in an
            # import lock's weakref callback; the run still stops at once with 130, outputs old)
            shown = err.split("Exception ignored in:")[0] if proc.returncode == 130 else err
            assert proc.returncode in (130, -signal.SIGINT) and "Traceback" not in shown, (seen, err)
        elif sent:  # the signal came after the commit: the run had finished, its outputs are whole
            assert proc.returncode in (0, 130, -signal.SIGINT), seen
        assert not [p.name for p in tmp_path.iterdir() if ".geosynth-" in p.name], seen
    assert sum(state == "old" for _, _, _, state in seen) >= 3, seen  # most moments fell inside the run


def test_one_rule_for_a_file_or_a_built_in(tmp_path):
    """Every command's input is a file or --example, exactly one, through one helper: a built-in's
    name given as the file means --example (where the command allows it), the file is checked."""
    from geosynth.cli import _file_or_example

    names = ("terrain", "rings")
    assert _file_or_example("terrain", None, names, "EXEMPLAR", "a mesh file") == (None, "terrain", [])
    with pytest.raises(ValueError, match="INPUT 'terrain' does not exist; give a mesh file, or --example NAME"):
        _file_or_example("terrain", None, names, "INPUT", "a mesh file", name_as_path=False)
    mesh = tmp_path / "terrain"  # a file of that name wins over the built-in
    mesh.write_bytes(b"ply\n")
    assert _file_or_example(str(mesh), None, names, "EXEMPLAR", "a mesh file") == (str(mesh), None, [str(mesh)])
    for path, example in ((None, None), (str(mesh), "rings")):
        with pytest.raises(ValueError, match=r"give an EXEMPLAR, a mesh file, or --example NAME \(one of terrain, "
                                             r"rings\), not both or neither\."):
            _file_or_example(path, example, names, "EXEMPLAR", "a mesh file")
    with pytest.raises(ValueError, match="is a folder"):
        _file_or_example(str(tmp_path), None, names, "EXEMPLAR", "a mesh file")
