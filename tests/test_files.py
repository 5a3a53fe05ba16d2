"""Files in and out: the readers (PLY through plyfile, meshes through trimesh unprocessed,
textures, fields) accept the files people have and turn every bad one into a one-line
error naming it; the output guard, atomic writes (also under SIGTERM and Ctrl-C) and
pictures by suffix (geosynth.io.files)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement

from geosynth.geometry.field import Field
from geosynth.geometry.meshes import load_mesh
from geosynth.geometry.pointsets import PointSet, read_geometry, read_point_set, write_point_set
from geosynth.io.files import atomic_write, check_input, check_output, note_input, write_image
from geosynth.texturing.models import load_point_model
from geosynth.texturing.textures import read_texture


def _cloud(n=60, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.standard_normal((n, 3)).astype(np.float32)
    nrm = p / np.linalg.norm(p, axis=1, keepdims=True)
    c = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    return p, nrm.astype(np.float32), c


def _write_ply(path, positions, normals=None, colors=None, *, encoding="binary_little_endian", faces=None,
               float_colors=False, extra=False, double=False):
    """A PLY file written with plyfile (independent of geosynth's writer)."""
    ft = "<f8" if double else "<f4"
    layout = [("x", ft), ("y", ft), ("z", ft)]
    if extra:
        layout.append(("quality", "<f4"))
    if normals is not None:
        layout += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if colors is not None:
        ct = "<f4" if float_colors else "u1"
        layout += [("red", ct), ("green", ct), ("blue", ct)]
        if extra:
            layout.append(("alpha", "u1"))
    v = np.zeros(len(positions), layout)
    for i, c in enumerate("xyz"):
        v[c] = positions[:, i]
    if normals is not None:
        for i, c in enumerate(("nx", "ny", "nz")):
            v[c] = normals[:, i]
    if colors is not None:
        for i, c in enumerate(("red", "green", "blue")):
            v[c] = colors[:, i] / 255.0 if float_colors else colors[:, i]
    elements = [PlyElement.describe(v, "vertex")]
    if faces is not None:
        f = np.empty(len(faces), [("vertex_indices", object)])
        f["vertex_indices"] = [np.asarray(face, np.int32) for face in faces]
        elements.append(PlyElement.describe(f, "face", len_types={"vertex_indices": "u1"},
                                            val_types={"vertex_indices": "i4"}))
    text = encoding == "ascii"
    order = {"ascii": "=", "binary_little_endian": "<", "binary_big_endian": ">"}[encoding]
    PlyData(elements, text=text, byte_order=order).write(str(path))
    return path


def _one_line_naming(exc: BaseException, path) -> None:
    msg = str(exc)
    assert os.path.basename(str(path)) in msg, msg
    assert "\n" not in msg, msg


# ------------------------------------------------------------------ PLY point sets


@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("with_normals", [False, True])
@pytest.mark.parametrize("colours", [None, "uchar", "float"])
def test_ply_point_sets_read_back_identically(tmp_path, encoding, with_normals, colours):
    p, n, c = _cloud()
    path = _write_ply(tmp_path / "a.ply", p, n if with_normals else None, None if colours is None else c,
                      encoding=encoding, float_colors=colours == "float", extra=True)
    assert f"format {encoding} 1.0".encode() in path.read_bytes()[:200]
    ps = read_point_set(path)
    assert ps.positions.dtype == np.float32 and ps.positions.shape == (60, 3)
    np.testing.assert_array_equal(ps.positions, p)
    if with_normals:
        np.testing.assert_array_equal(ps.normals, n)
    else:
        assert ps.normals is None
    if colours is None:
        assert ps.colors is None
    else:
        assert ps.colors.dtype == np.uint8
        np.testing.assert_array_equal(ps.colors, c)
    geom = read_geometry(path)  # no faces: the same point set
    assert isinstance(geom, PointSet) and np.array_equal(geom.positions, p)


def test_ascii_ply_with_normals_the_reported_file(tmp_path):
    # the user's file: 500 points, x y z nx ny nz, ASCII, written by hand (not by plyfile)
    p, n, _ = _cloud(500, seed=3)
    rows = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in np.hstack([p, n]))
    path = tmp_path / "scan.ply"
    path.write_text("ply\nformat ascii 1.0\ncomment by hand\nelement vertex 500\n"
                    + "".join(f"property float {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
                    + "end_header\n" + rows + "\n")
    ps = read_point_set(path)
    np.testing.assert_array_equal(ps.positions, p)
    np.testing.assert_array_equal(ps.normals, n)
    model = load_point_model(path)
    assert len(model) == 500 and np.array_equal(model.normals, n)


def _ascii_ply(path, props, rows):
    """An ASCII PLY written by hand: ``props`` is [(type, name)], ``rows`` the values."""
    head = "".join(f"property {t} {n}\n" for t, n in props)
    body = "".join(" ".join(str(v) for v in row) + "\n" for row in rows)
    path.write_text(f"ply\nformat ascii 1.0\nelement vertex {len(rows)}\n{head}end_header\n{body}")
    return path


def test_ply_other_property_names_and_colour_types(tmp_path):
    xyz = [("float", c) for c in "xyz"]
    pcl = _ascii_ply(tmp_path / "pcl.ply", xyz + [("float", f"normal_{c}") for c in "xyz"]
                     + [("uchar", c) for c in "rgb"], [[0, 0, 0, 0, 0, 1, 10, 20, 30], [1, 0, 0, 1, 0, 0, 0, 0, 255]])
    ps = read_point_set(pcl)
    np.testing.assert_array_equal(ps.normals, [[0, 0, 1], [1, 0, 0]])
    np.testing.assert_array_equal(ps.colors, [[10, 20, 30], [0, 0, 255]])
    rgb = [("float", c) for c in ("red", "green", "blue")]
    wide = _ascii_ply(tmp_path / "f255.ply", xyz + rgb, [[0, 0, 0, 0.0, 128.0, 255.0]])  # floats beyond 1: 0..255
    np.testing.assert_array_equal(read_point_set(wide).colors, [[0, 128, 255]])
    short = _ascii_ply(tmp_path / "u16.ply", xyz + [("ushort", c) for c in ("red", "green", "blue")],
                       [[0, 0, 0, 0, 257 * 128, 65535]])
    np.testing.assert_array_equal(read_point_set(short).colors, [[0, 128, 255]])
    for name, row in (("neg.ply", [0, 0, 0, -0.5, 0, 0]), ("over.ply", [0, 0, 0, 300.0, 0, 0]),
                      ("nan.ply", [0, 0, 0, "nan", 0, 0])):
        with pytest.raises(ValueError, match=rf"{name}' is not a readable PLY file: its .*vertex colours .*; "
                                             "store colours as uchar 0..255 or float 0..1"):
            read_point_set(_ascii_ply(tmp_path / name, xyz + rgb, [row]))
    nanormal = _ascii_ply(tmp_path / "nn.ply", xyz + [("float", c) for c in ("nx", "ny", "nz")],
                          [[0, 0, 0, 0, 0, 1], [1, 1, 1, "nan", 0, 0]])
    with pytest.raises(ValueError, match=r"nn.ply' has 1 normal with NaN or inf coordinates \(the first: index 1"):
        read_point_set(nanormal)


def test_ply_double_positions_and_faces_ignored_by_the_point_reader(tmp_path):
    p, _, _ = _cloud(10)
    path = _write_ply(tmp_path / "d.ply", p.astype(np.float64) + 0.1, double=True, faces=[[0, 1, 2], [2, 3, 4]])
    ps = read_point_set(path)
    np.testing.assert_array_equal(ps.positions, (p.astype(np.float64) + 0.1).astype(np.float32))
    # beyond float32's range is not finite as float32: refused
    big = p.astype(np.float64)
    big[4, 1] = 1e300
    with pytest.raises(ValueError, match=r"1 point with NaN or inf coordinates \(the first: index 4"):
        read_point_set(_write_ply(tmp_path / "big.ply", big, double=True))


def test_write_point_set_round_trip_binary_little_endian(tmp_path):
    p, n, c = _cloud(40)
    for k, (normals, colors, props) in enumerate([(None, None, ["x", "y", "z"]),
                                   (n, None, ["x", "y", "z", "nx", "ny", "nz"]),
                                   (n, c, ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]),
                                   (None, c, ["x", "y", "z", "red", "green", "blue"])]):
        out = write_point_set(tmp_path / f"w{k}.ply", PointSet(p, normals, colors))
        raw = PlyData.read(str(out))
        assert not raw.text and raw.byte_order == "<"
        vertex = raw["vertex"]
        assert [q.name for q in vertex.properties] == props
        assert {q.val_dtype for q in vertex.properties} <= {"f4", "u1"}
        back = read_point_set(out)
        assert np.array_equal(back.positions, p)
        assert (back.normals is None) == (normals is None) and (back.colors is None) == (colors is None)
        if normals is not None:
            assert np.array_equal(back.normals, n)
        if colors is not None:
            assert np.array_equal(back.colors, c)
        # read_point_set noted it as an input: the next write must go elsewhere
        with pytest.raises(ValueError, match="input"):
            write_point_set(out, back)
    assert not [f for f in os.listdir(tmp_path) if ".tmp" in f]


# ------------------------------------------------------------------ meshes


def _sphere():
    return trimesh.creation.icosphere(2)  # 162 vertices, 320 faces


@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_mesh_with_triangles_and_polygons(tmp_path, encoding):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1]], np.float32)
    faces = [[0, 1, 2], [0, 2, 3, 4], [1, 5, 4, 0, 3]]  # a triangle, a quad, a pentagon
    path = _write_ply(tmp_path / "m.ply", v, faces=faces, encoding=encoding)
    mesh = load_mesh(path)
    assert isinstance(mesh, trimesh.Trimesh)
    np.testing.assert_array_equal(mesh.vertices, v)
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [1, 5, 4], [1, 4, 0], [1, 0, 3]])
    geom = read_geometry(path)
    assert isinstance(geom, trimesh.Trimesh) and np.array_equal(geom.faces, mesh.faces)
    ps = read_point_set(path)  # the same file as a point set: its vertices
    np.testing.assert_array_equal(ps.positions, v)


def test_ply_triangle_mesh_matches_the_source(tmp_path):
    src = _sphere()
    path = _write_ply(tmp_path / "s.ply", src.vertices.astype(np.float32), faces=src.faces)
    mesh = load_mesh(path)
    assert mesh.vertices.shape == (162, 3) and mesh.faces.shape == (320, 3)
    np.testing.assert_array_equal(mesh.faces, src.faces)
    # trimesh's own PLY export (uchar/int face lists) reads too
    src.export(tmp_path / "t.ply")
    assert load_mesh(tmp_path / "t.ply").faces.shape == (320, 3)
    # a point model sampled from it (load_point_model reads through read_geometry)
    model = load_point_model(path, count=500)
    assert len(model) == 500 and np.allclose(np.linalg.norm(model.positions, axis=1), 1, atol=0.02)
    flat = _write_ply(tmp_path / "flat.ply", np.zeros((3, 3), np.float32), faces=[[0, 1, 2]])
    with pytest.raises(ValueError, match="zero total area"):
        load_point_model(flat, count=100)


@pytest.mark.parametrize("suffix,vertices", [(".obj", 162), (".stl", 960), (".off", 162), (".glb", 162)])
def test_trimesh_formats(tmp_path, suffix, vertices):
    src = _sphere()
    path = tmp_path / f"s{suffix}"
    src.export(path)
    mesh = load_mesh(path)
    assert mesh.vertices.shape == (vertices, 3) and mesh.faces.shape == (320, 3)  # STL: 3 vertices per face
    np.testing.assert_allclose(mesh.bounds, src.bounds, atol=1e-6)
    assert np.isclose(mesh.area, src.area, rtol=1e-6)
    assert isinstance(read_geometry(path), trimesh.Trimesh)


def test_obj_without_faces_is_a_point_set(tmp_path):
    path = tmp_path / "pts.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n")
    geom = read_geometry(path)
    assert isinstance(geom, PointSet) and geom.positions.shape == (4, 3)
    with pytest.raises(ValueError, match="'.*pts.obj' holds no faces: it is a point set"):
        load_mesh(path)


def test_obj_with_one_coordinate_per_vertex_is_refused(tmp_path):
    # trimesh parses "v 0.5" lines into (N, 1) vertices: a mangled OBJ (found by the fuzz test below)
    path = tmp_path / "one.obj"
    path.write_text("v 0.5\nv 1\nv 2\nf 1 2 3\n")
    for reader in (load_mesh, read_geometry):
        with pytest.raises(ValueError, match=r"one.obj' is not a readable OBJ file: its vertices have shape "
                                             r"\[\(3, 1\)\], not \(N, 3\)") as err:
            reader(path)
        _one_line_naming(err.value, path)


def test_nan_vertex_in_obj_is_refused_with_count_and_first_index(tmp_path):
    src = _sphere()
    lines = src.export(file_type="obj").splitlines()
    vertex_lines = [k for k, line in enumerate(lines) if line.startswith("v ")]
    lines[vertex_lines[5]] = "v nan 0 0"
    lines[vertex_lines[9]] = "v 0 inf 0"
    path = tmp_path / "nan.obj"
    path.write_text("\n".join(lines) + "\n")
    for reader in (load_mesh, read_geometry, load_point_model):
        with pytest.raises(ValueError, match=r"nan.obj' has 2 vertices with NaN or inf coordinates "
                                             r"\(the first: index 5, counting from 0\)") as err:
            reader(path)
        _one_line_naming(err.value, path)


def test_nan_vertex_in_ply_mesh_is_refused_with_count_and_first_index(tmp_path):
    src = _sphere()
    v = src.vertices.astype(np.float32)
    v[7] = np.nan
    for encoding in ("ascii", "binary_little_endian"):
        path = _write_ply(tmp_path / f"nan_{encoding}.ply", v, faces=src.faces, encoding=encoding)
        for reader in (load_mesh, read_geometry):
            with pytest.raises(ValueError, match=r"has 1 vertex with NaN or inf coordinates \(the first: index 7"):
                reader(path)
        with pytest.raises(ValueError, match=r"has 1 point with NaN or inf coordinates \(the first: index 7"):
            read_point_set(path)


def test_faces_out_of_range_and_short_faces(tmp_path):
    v = np.eye(3, dtype=np.float32)
    path = _write_ply(tmp_path / "oor.ply", v, faces=[[0, 1, 2], [0, 1, 7]])
    with pytest.raises(ValueError, match=r"1 face\(s\) with vertex indices out of range \[0, 3\) \(the first: face 1"):
        load_mesh(path)
    path = _write_ply(tmp_path / "short.ply", v, faces=[[0, 1, 2], [0, 1]])
    with pytest.raises(ValueError, match="fewer than 3 corners"):
        read_geometry(path)
    empty_list = tmp_path / "empty_list.ply"  # ASCII, a face with no corners
    empty_list.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                          "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                          "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n0\n")
    with pytest.raises(ValueError, match=r"1 face\(s\) have fewer than 3 corners \(the first: face 1, with 0\); "
                                         "remove those faces"):
        load_mesh(empty_list)
    assert len(read_point_set(empty_list)) == 3  # the vertices are fine
    obj = tmp_path / "oor.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    with pytest.raises(ValueError, match="oor.obj' is not a readable OBJ file"):
        load_mesh(obj)


def test_ply_errors_name_the_file(tmp_path):
    p, n, _ = _cloud(100)
    good = _write_ply(tmp_path / "good.ply", p, n)
    data = good.read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[: len(data) - 100])
    with pytest.raises(ValueError, match=r"cut.ply' is not a readable PLY file: its header declares 100 vertex "
                                         r"records \(exactly 2,400 bytes of binary data\) but the file holds 2,300 "
                                         r"bytes after the header \(truncated or its header is wrong\)"):
        read_point_set(cut)
    noxyz = tmp_path / "noxyz.ply"
    noxyz.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n")
    with pytest.raises(ValueError, match="noxyz.ply' is not a readable PLY file: its vertex element lacks x, y, z"):
        read_point_set(noxyz)
    nov = tmp_path / "nov.ply"
    nov.write_text("ply\nformat ascii 1.0\nelement point 1\nproperty float x\nend_header\n1\n")
    with pytest.raises(ValueError, match="nov.ply' is not a readable PLY file: it has no vertex element"):
        read_geometry(nov)
    zero = _write_ply(tmp_path / "zero.ply", np.zeros((0, 3), np.float32))
    with pytest.raises(ValueError, match="zero.ply' holds no vertices"):
        read_point_set(zero)
    obj = tmp_path / "x.obj"
    obj.write_text("v 0 0 0\n")
    with pytest.raises(ValueError, match="point sets are read from PLY files"):
        read_point_set(obj)
    txt = tmp_path / "x.txt"
    txt.write_text("v 0 0 0\n")
    with pytest.raises(ValueError, match=r"x.txt' has the extension .txt, not one of the geometry formats"):
        read_geometry(txt)


def _png(path):
    from PIL import Image

    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(path)
    return path


_READERS = [  # (reader, how its messages name the file, a good file of its kind)
    (read_point_set, "point set", lambda d: _write_ply(d / "ok.ply", _cloud()[0])),
    (read_geometry, "mesh or point-set", lambda d: _write_ply(d / "ok.ply", _cloud()[0])),
    (load_mesh, "mesh", lambda d: _sphere().export(d / "ok.obj") and d / "ok.obj"),
    (read_texture, "texture image", lambda d: _png(d / "ok.png")),
    (Field.load, "field", lambda d: Field(np.zeros((2, 2, 2), np.float32), 0, 1).save(d / "ok.npz")),
]


@pytest.mark.parametrize("reader,what,good", _READERS, ids=[r[1] for r in _READERS])
def test_every_reader_missing_folder_empty_garbage(tmp_path, reader, what, good):
    ok = good(tmp_path)
    reader(ok)
    with pytest.raises(ValueError, match="is an input file"):  # the reader noted it
        check_output(ok)
    suffix = ok.suffix
    missing = tmp_path / f"nope{suffix}"
    with pytest.raises(FileNotFoundError, match=f"^{what} file '{missing}' does not exist.$"):
        reader(missing)
    folder = tmp_path / f"folder{suffix}"
    folder.mkdir()
    with pytest.raises(ValueError, match=f"^{what} file '{folder}' is a folder"):
        reader(folder)
    empty = tmp_path / f"empty{suffix}"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match=f"^{what} file '{empty}' is empty"):
        reader(empty)
    garbage = tmp_path / f"garbage{suffix}"
    garbage.write_bytes(bytes(np.random.default_rng(1).integers(0, 256, 3000, dtype=np.uint8)))
    with pytest.raises(ValueError) as err:
        reader(garbage)
    _one_line_naming(err.value, garbage)
    assert "not a readable" in str(err.value) or "holds no" in str(err.value), str(err.value)
    with pytest.raises(ValueError, match="is an input file"):  # noted even though it could not be read
        check_output(garbage)


def test_the_reported_messages(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"^mesh or point-set file 'nope.ply' does not exist.$"):
        read_geometry("nope.ply")
    p, _, _ = _cloud(50)
    data = _write_ply(tmp_path / "c.ply", p).read_bytes()
    (tmp_path / "corrupt.ply").write_bytes(data[:-7])
    with pytest.raises(ValueError, match=r"^'corrupt.ply' is not a readable PLY file"):
        read_geometry("corrupt.ply")


def test_texture_limits_and_truncation(tmp_path):
    from PIL import Image

    Image.new("L", (20000, 20000)).save(tmp_path / "bomb.png")  # 400 Mpixel, a few hundred kB
    with pytest.raises(ValueError, match=r"bomb.png' has 400,000,000 pixels, more than Pillow's limit of "
                                         rf"{Image.MAX_IMAGE_PIXELS:,}"):
        read_texture(tmp_path / "bomb.png")
    Image.new("L", (10000, 10000)).save(tmp_path / "big.png")  # over the limit, under twice it
    with pytest.raises(ValueError, match=r"big.png' has 100,000,000 pixels \(10000 x 10000\)"):
        read_texture(tmp_path / "big.png")
    rgb = np.random.default_rng(0).integers(0, 256, (64, 64, 3)).astype(np.uint8)
    for suffix in (".png", ".jpg"):
        Image.fromarray(rgb).save(tmp_path / f"t{suffix}")
        data = (tmp_path / f"t{suffix}").read_bytes()
        (tmp_path / f"cut{suffix}").write_bytes(data[: len(data) // 2])
        with pytest.raises(ValueError, match=rf"^'.*cut{suffix}' is not a readable image: image file is truncated"):
            read_texture(tmp_path / f"cut{suffix}")


def test_field_load_errors(tmp_path):
    np.save(tmp_path / "one.npy", np.zeros(3))
    with pytest.raises(ValueError, match="one.npy' is not a geosynth field file: it holds one array"):
        Field.load(tmp_path / "one.npy")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="other.npz' is not a geosynth field: it lacks origin, spacing, values"):
        Field.load(tmp_path / "other.npz")
    np.savez(tmp_path / "shape.npz", values=np.zeros(3, np.float32), origin=np.zeros(3), spacing=np.ones(3))
    with pytest.raises(ValueError, match="shape.npz' is not a valid geosynth field: Field values must be"):
        Field.load(tmp_path / "shape.npz")
    good = Field(np.arange(27, dtype=np.float32).reshape(3, 3, 3), (1, 2, 3), 0.5).save(tmp_path / "f.npz")
    data = good.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cut.npz' is not a readable geosynth field file"):
        Field.load(tmp_path / "cut.npz")
    back = Field.load(good)
    assert np.array_equal(back.values, np.arange(27, dtype=np.float32).reshape(3, 3, 3))


# ------------------------------------------------------------------ PLY data that disagree with the header (issue 37)


def _recount(data: bytes, element: str, count: int) -> bytes:
    """The file with its header's count of ``element`` replaced by ``count``."""
    head, sep, body = data.partition(b"end_header")
    head = re.sub(rb"element " + element.encode() + rb" \d+", b"element %s %d" % (element.encode(), count), head)
    return head + sep + body


@pytest.mark.parametrize("encoding", ["binary_little_endian", "binary_big_endian"])
def test_binary_ply_with_more_records_than_its_header_is_refused(tmp_path, encoding):
    # the reported case: the header declares 500 vertices, the file holds 1,000 records
    p, _, _ = _cloud(1000)
    data = _write_ply(tmp_path / "full.ply", p, encoding=encoding).read_bytes()
    half = tmp_path / "half.ply"
    half.write_bytes(_recount(data, "vertex", 500))
    want = (r"^'[^']*half.ply' is not a readable PLY file: its header declares 500 vertex records \(exactly 6,000 "
            r"bytes of binary data\) but the file holds 12,000 bytes after the header, 1,000 vertex records \(more "
            r"data than the header declares\); correct the element counts in the header or export the file again.$")
    for reader in (read_point_set, read_geometry, load_mesh):
        with pytest.raises(ValueError, match=want):
            reader(half)
    extra = tmp_path / "extra.ply"
    extra.write_bytes(data + b"\0\0\0")  # bytes that are not a whole record
    with pytest.raises(ValueError, match=r"extra.ply' is not a readable PLY file: its header declares 1,000 vertex "
                                         r"records \(exactly 12,000 bytes of binary data\) but the file holds 12,003 "
                                         r"bytes after the header \(more data"):
        read_point_set(extra)
    more = tmp_path / "more.ply"
    more.write_bytes(_recount(data, "vertex", 1001))
    with pytest.raises(ValueError, match=r"more.ply' is not a readable PLY file: its header declares 1,001 vertex "
                                         r"records .* but the file holds 12,000 bytes after the header, 1,000 vertex "
                                         r"records \(truncated or its header is wrong\)"):
        read_point_set(more)
    assert np.array_equal(read_point_set(tmp_path / "full.ply").positions, p)  # the file itself reads whole


def test_ascii_ply_with_more_or_fewer_lines_than_its_header_is_refused(tmp_path):
    p, n, c = _cloud(40)
    data = _write_ply(tmp_path / "a.ply", p, n, c, encoding="ascii").read_bytes()
    cases = {"fewer.ply": (_recount(data, "vertex", 20), "declares 20 vertex records (20 data lines, one per "
                                                         "record) but the file holds 40 data lines, more than "
                                                         "declared: data after the declared records would be lost"),
             "more.ply": (_recount(data, "vertex", 41), "declares 41 vertex records (41 data lines, one per record) "
                                                        "but the file holds 40 data lines, fewer than declared: the "
                                                        "file is truncated or its header is wrong"),
             "cut.ply": (data[:data.rindex(b"\n", 0, len(data) - 1) + 1], "40 data lines, one per record) but the "
                                                                          "file holds 39 data lines, fewer")}
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        for reader in (read_point_set, read_geometry):
            with pytest.raises(ValueError, match=re.escape(f"{name}' is not a readable PLY file: its header {message}"
                                                           if "declares" in message else message)):
                reader(tmp_path / name)
    cut = tmp_path / "nolf.ply"  # cut inside the last number: "215" read as "21" unless refused
    cut.write_bytes(data[:-2])
    with pytest.raises(ValueError, match=r"^'[^']*nolf.ply' is not a readable PLY file: its last data line \(line 40 "
                                         r"after the header\) has no line break at its end, as if the file were cut "
                                         r"inside its last record; if the file is complete, end it with a line break"):
        read_point_set(cut)
    blank = tmp_path / "blank.ply"  # blank lines after the last record hold nothing: read as they are
    blank.write_bytes(data + b"\n  \r\n\n")
    back = read_point_set(blank)
    assert np.array_equal(back.positions, p) and np.array_equal(back.colors, c)


def test_binary_ply_mesh_whose_faces_disagree_with_the_header_is_refused(tmp_path):
    src = trimesh.creation.icosphere(1)  # 42 vertices, 80 triangles
    quads = [[0, 1, 2, 3], [3, 4, 5], [5, 6, 7, 8, 9]]
    tri = _write_ply(tmp_path / "tri.ply", src.vertices.astype(np.float32), faces=src.faces).read_bytes()
    poly = _write_ply(tmp_path / "poly.ply", src.vertices.astype(np.float32), faces=quads).read_bytes()
    assert len(load_mesh(tmp_path / "tri.ply").faces) == 80 and len(load_mesh(tmp_path / "poly.ply").faces) == 6
    cases = {
        "fewer_faces.ply": (_recount(tri, "face", 79), r"declares 42 vertex, 79 face records \(1,531 bytes of binary "
                                                       r"data, as its records' lists are long\) but the file holds "
                                                       r"1,544 bytes after the header \(more than declared\)"),
        "extra_bytes.ply": (poly + b"\x03", r"declares 42 vertex, 3 face records \(555 bytes .* but the file holds "
                                            r"556 bytes after the header \(more than declared\)"),
        "fewer_vertices.ply": (_recount(poly, "vertex", 41), r"declares 41 vertex, 3 face records"),
        "more_faces.ply": (_recount(poly, "face", 4), r"declares 42 vertex, 4 face records \(at least 508 bytes of "
                                                      r"binary data\) but the file holds 555 bytes after the header, "
                                                      r"which end too early \(.*early end-of-file: truncated"),
        "cut.ply": (tri[:-5], r"declares 42 vertex, 80 face records \(at least 584 bytes of binary data\) but the "
                              r"file holds 1,539 bytes after the header, which end too early"),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        for reader in (read_geometry, load_mesh, read_point_set):
            with pytest.raises(ValueError, match=f"^'[^']*{name}' is not a readable PLY file: its header {message}"):
                reader(tmp_path / name)


def _ply_sources(folder):
    p, n, c = _cloud(12, seed=3)
    src = trimesh.creation.icosphere(0)  # 12 vertices, 20 faces
    quads = [[0, 1, 2, 3], [3, 4, 5], [5, 6, 7, 8, 9]]
    files = {
        "ascii points": _write_ply(folder / "a.ply", p, n, c, encoding="ascii"),
        "binary points": _write_ply(folder / "b.ply", p, n, c, encoding="binary_big_endian"),
        "binary mesh": _write_ply(folder / "m.ply", src.vertices.astype(np.float32), faces=src.faces),
        "binary polygons": _write_ply(folder / "q.ply", p, faces=quads),
        "ascii polygons": _write_ply(folder / "r.ply", p, faces=quads, encoding="ascii"),
    }
    return {k: (v.read_bytes(), read_geometry(v)) for k, v in files.items()}


@pytest.fixture(scope="module")
def ply_sources(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ply_sources")
    return _Sources((folder, _ply_sources(folder)))


def _disagreements():
    recount = st.tuples(st.just("recount"), st.sampled_from(["vertex", "face"]),
                        st.integers(-12, 12).filter(lambda k: k != 0))
    extra = st.tuples(st.just("extra"), st.binary(min_size=1, max_size=40))
    cut = st.tuples(st.just("cut"), st.integers(1, 60))
    return st.one_of(recount, extra, cut)


def _disagree(data: bytes, change) -> bytes:
    kind, *arg = change
    if kind == "recount":
        element, delta = arg
        m = re.search(rb"element " + element.encode() + rb" (\d+)", data)
        return data if m is None else _recount(data, element, max(0, int(m.group(1)) + delta))
    if kind == "extra":
        return data + arg[0]
    head = data.index(b"end_header") + len(b"end_header\n")
    return data[:max(head, len(data) - arg[0])]


def _same(result, want) -> None:
    """A file that reads must give everything its source held: never a part of it."""
    assert type(result) is type(want)
    if isinstance(want, PointSet):
        assert np.array_equal(result.positions, want.positions)
        for a, b in ((result.normals, want.normals), (result.colors, want.colors)):
            assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))
    else:
        assert np.array_equal(result.vertices, want.vertices) and np.array_equal(result.faces, want.faces)


@pytest.mark.parametrize("source", ["ascii points", "binary points", "binary mesh", "binary polygons",
                                    "ascii polygons"])
@settings(max_examples=int(os.environ.get("GEOSYNTH_MANGLE_EXAMPLES", 40)), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(change=_disagreements())
def test_ply_headers_that_disagree_with_their_data_are_read_whole_or_refused(ply_sources, source, change):
    # a count larger or smaller than the data, bytes beyond the data, a truncated body:
    # the file reads as its source did (only blank lines after an ASCII body can), or is
    # refused in one line naming the file; never read in part, never a raw plyfile error
    folder, sources = ply_sources
    data, want = sources[source]
    path = folder / f"disagree {source.replace(' ', '_')}.ply"
    path.write_bytes(_disagree(data, change))
    readers = [read_geometry, read_point_set] + ([load_mesh] if isinstance(want, trimesh.Trimesh) else [])
    for reader in readers:
        try:
            result = reader(path)
        except ValueError as exc:
            _one_line_naming(exc, path)
        else:
            if reader is read_point_set and isinstance(want, trimesh.Trimesh):
                assert np.array_equal(result.positions, np.asarray(want.vertices, np.float32))
            else:
                _same(result, want)


# ------------------------------------------------------------------ STL files that are not (issue 37)


def test_a_corrupt_stl_is_refused_saying_what_is_wrong_with_it(tmp_path):
    # the reported file: ASCII STL with binary junk in a vertex line (was: "No module named 'charset_normalizer'")
    corrupt = tmp_path / "corrupt.stl"
    corrupt.write_bytes(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 \x89\xfe\x00\xc3junk\x01\n")
    with pytest.raises(ValueError, match=r"^'[^']*corrupt.stl' is not a readable STL file: not valid ASCII STL: line 4 "
                                         r"holds a byte that is not text \(0x89 at column 12\), nor a binary STL "
                                         r"\(it holds 59 bytes, fewer than the 84 of a binary STL's header\); give a "
                                         r"complete binary or ASCII STL file.$"):
        load_mesh(corrupt)
    box = trimesh.creation.box()
    text, binary = box.export(file_type="stl_ascii").encode(), box.export(file_type="stl")
    cases = {
        "word.stl": (text.replace(b"endloop", b"endlop", 1), "not valid ASCII STL: line 7: expected vertex or "
                     "endloop, found 'endlop' (an ASCII STL holds only solid, facet normal, outer loop, vertex, "
                     "endloop, endfacet, endsolid lines)"),
        "number.stl": (text.replace(b"vertex", b"vertex x", 1), "not valid ASCII STL: line 4: 'vertex' needs 3 "
                       "numbers, found 'vertex x -0.5 -0.5 0.5'"),
        "four.stl": (text.replace(b"endloop", b"vertex 0 0 0\nendloop", 1), "not valid ASCII STL: line 8: a facet "
                     "with 4 vertices (an STL facet has 3)"),
        "cut_text.stl": (text[:text.index(b"endfacet", len(text) // 2) + 1], "the file ends inside this line ('e'), "
                         "where endfacet was due (cut short?)"),
        "no_end.stl": (text[:text.rindex(b"endsolid")], "the file ends inside a solid, without 'endsolid'"),
        "cut_binary.stl": (binary[:-7], "it is neither an ASCII STL (it does not begin with 'solid') nor a binary "
                           "STL (its header declares 12 triangles, 684 bytes, but the file holds 677)"),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        for reader in (load_mesh, read_geometry):
            with pytest.raises(ValueError, match=f"^'[^']*{name}' is not a readable STL file: .*{re.escape(message)}"):
                reader(tmp_path / name)
    for name, content in (("text.stl", text), ("binary.stl", binary), ("solid.stl", b"solid" + binary[5:])):
        (tmp_path / name).write_bytes(content)  # a binary STL whose header begins with "solid" is binary
        assert np.array_equal(load_mesh(tmp_path / name).vertices[load_mesh(tmp_path / name).faces],
                              box.vertices[box.faces])


# ------------------------------------------------------------------ writers refuse NaN and inf (issue 37)


def test_every_writer_refuses_non_finite_values_before_creating_a_file(tmp_path):
    from geosynth.completion.synthesis import CompletedSurface, write_completion
    from geosynth.geometry.surface import save_mesh

    p, n, c = _cloud(300)
    p[7, 1], p[9] = np.nan, np.inf
    box = trimesh.creation.box()
    bad_box = trimesh.Trimesh(np.r_[box.vertices[:-1], [[np.nan, 0, 0]]], box.faces, process=False)
    grid = np.pad(np.full((2, 2, 2), np.nan, np.float32), 1)
    m = 5
    surface = CompletedSurface(np.zeros((m, 3), np.float32), np.full((m, 3), np.inf, np.float32), None,
                               np.array([[0, 1, 2]], np.int32), np.ones(m, bool), np.ones(m, bool), np.ones(m, bool),
                               None)
    cases = [
        (lambda: write_point_set(tmp_path / "p.ply", PointSet(p, n, c)),
         "p.ply': 4 of its 900 position coordinates are NaN or inf, in 2 points (the first: point 7, counting from "
         "0); nothing was written: remove those points or correct them first."),
        (lambda: write_point_set(tmp_path / "n.ply", PointSet(p[10:], np.where(n[10:] > 2, 0, np.nan))),
         "n.ply': 870 of its 870 normal coordinates are NaN or inf, in 290 points (the first: point 0"),
        (lambda: save_mesh(bad_box, tmp_path / "m.stl"),
         "m.stl': 1 of its 24 vertex coordinates is NaN or inf, in 1 vertex (the first: vertex 7, counting from 0); "
         "nothing was written: remove that vertex or correct it first."),
        (lambda: save_mesh(bad_box, tmp_path / "m.ply"), "m.ply': 1 of its 24 vertex coordinates is NaN or inf"),
        (lambda: Field(grid, [0, 0, 0], [1, 1, 1]).save(tmp_path / "f.npz"),
         "f.npz': 8 of its 64 field values are NaN or inf (the first: sample (z, y, x) = (1, 1, 1)); nothing was "
         "written: correct those values first."),
        (lambda: write_completion(tmp_path / "c.ply", surface),
         "c.ply': 15 of its 15 normal coordinates are NaN or inf, in 5 points (the first: point 0"),
    ]
    for write, message in cases:
        with pytest.raises(ValueError, match=r"^refusing to write '[^']*" + re.escape(message)):
            write()
    assert list(tmp_path.iterdir()) == []  # not even a temporary
    # finite data are written as before
    assert read_point_set(write_point_set(tmp_path / "ok.ply", PointSet(p[10:], n[10:]))).positions.shape == (290, 3)
    assert Field.load(Field(np.zeros((2, 2, 2), np.float32), [0, 0, 0], [1, 1, 1]).save(tmp_path / "ok.npz")).shape \
        == (2, 2, 2)


# ------------------------------------------------------------------ property test: mangled files


def _valid(result) -> None:
    if isinstance(result, PointSet):
        assert result.positions.dtype == np.float32 and result.positions.ndim == 2
        assert result.positions.shape[1] == 3 and len(result.positions) > 0
        assert np.isfinite(result.positions).all()
        if result.normals is not None:
            assert result.normals.shape == result.positions.shape and np.isfinite(result.normals).all()
        if result.colors is not None:
            assert result.colors.dtype == np.uint8 and result.colors.shape == result.positions.shape
    else:
        assert isinstance(result, trimesh.Trimesh)
        v, f = np.asarray(result.vertices), np.asarray(result.faces)
        assert v.ndim == 2 and v.shape[1] == 3 and np.isfinite(v.astype(np.float32)).all()
        assert f.ndim == 2 and f.shape[1] == 3 and len(f) > 0 and f.dtype.kind in "iu"
        assert f.min() >= 0 and f.max() < len(v)


def _sources(folder):
    p, n, c = _cloud(30, seed=5)
    src = trimesh.creation.icosphere(1)  # 42 vertices, 80 faces
    quads = [[0, 1, 2, 3], [3, 4, 5], [5, 6, 7, 8, 9]]
    return {
        "ascii point set": (_write_ply(folder / "a.ply", p, n, c, encoding="ascii").read_bytes(), ".ply"),
        "binary point set": (_write_ply(folder / "b.ply", p, n, c, encoding="binary_big_endian").read_bytes(), ".ply"),
        "binary mesh": (_write_ply(folder / "m.ply", src.vertices.astype(np.float32), faces=src.faces).read_bytes(),
                        ".ply"),
        "ascii mesh": (_write_ply(folder / "q.ply", p, faces=quads, encoding="ascii").read_bytes(), ".ply"),
        "obj": (src.export(file_type="obj").encode(), ".obj"),
        "ascii stl": (src.export(file_type="stl_ascii").encode(), ".stl"),
        "binary stl": (src.export(file_type="stl"), ".stl"),
    }


class _Sources(tuple):
    def __repr__(self):  # hypothesis prints the fixtures of a failing example: not the files' bytes
        return "<the source files>"


@pytest.fixture(scope="module")
def mangle_sources(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sources")
    return _Sources((folder, _sources(folder)))


def _mutations():
    cut = st.tuples(st.just("cut"), st.floats(0, 1))
    flips = st.tuples(st.just("flip"), st.lists(st.tuples(st.floats(0, 1), st.integers(0, 7)), min_size=1, max_size=4))
    return st.one_of(cut, flips)


def _mangle(data: bytes, mutation) -> bytes:
    kind, arg = mutation
    if kind == "cut":
        return data[: int(arg * len(data))]
    out = bytearray(data)
    for where, bit in arg:
        out[min(int(where * len(out)), len(out) - 1)] ^= 1 << bit
    return bytes(out)


@pytest.mark.parametrize("source", ["ascii point set", "binary point set", "binary mesh", "ascii mesh", "obj",
                                    "ascii stl", "binary stl"])
# GEOSYNTH_MANGLE_EXAMPLES=2000 for a longer hunt; 70 per source keeps the suite fast (~1 s in all)
@settings(max_examples=int(os.environ.get("GEOSYNTH_MANGLE_EXAMPLES", 70)), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mutation=_mutations())
def test_mangled_files_give_a_clear_error_or_a_valid_result(mangle_sources, source, mutation):
    folder, sources = mangle_sources
    data, suffix = sources[source]
    path = folder / f"mangled {source.replace(' ', '_')}{suffix}"
    path.write_bytes(_mangle(data, mutation))
    readers = [read_geometry, load_mesh] + ([read_point_set] if suffix == ".ply" else [])
    for reader in readers:
        try:
            result = reader(path)
        except (ValueError, FileNotFoundError) as exc:
            _one_line_naming(exc, path)
        else:
            _valid(result)


# ------------------------------------------------------------------ the output guard


def test_check_output_refusals(tmp_path):
    src = tmp_path / "in.ply"
    src.write_bytes(b"x")
    with pytest.raises(ValueError, match="is an input file"):
        check_output(src, inputs=[src])
    noted = tmp_path / "noted.ply"
    noted.write_bytes(b"x")
    check_output(noted)  # not an input yet
    note_input(noted)
    with pytest.raises(ValueError, match="is an input file"):
        check_output(noted)
    link = tmp_path / "link.ply"
    link.symlink_to(src)
    with pytest.raises(ValueError, match="link.ply' is an input file"):
        check_output(link, inputs=[src])
    (tmp_path / "sub").mkdir()
    with pytest.raises(ValueError, match="is an input file"):
        check_output(tmp_path / "sub" / ".." / "in.ply", inputs=[src])
    with pytest.raises(ValueError, match="is a folder"):
        check_output(tmp_path / "sub")
    with pytest.raises(ValueError, match="is a file, not a folder"):
        check_output(tmp_path / "in.ply" / "out.ply")
    with pytest.raises(ValueError, match=r"must end in \.png, \.jpg, \.jpeg; got \.gif"):
        check_output(tmp_path / "x.gif", suffixes=(".png", ".jpg", ".jpeg"))
    assert check_output(tmp_path / "new" / "deeper" / "out.ply") == tmp_path / "new" / "deeper" / "out.ply"


def test_check_output_refuses_an_input_a_reader_noted(tmp_path):
    path = write_point_set(tmp_path / "p.ply", PointSet(_cloud()[0]))
    check_output(path)
    read_point_set(path)
    with pytest.raises(ValueError, match="is an input file"):
        check_output(path)
    with pytest.raises(ValueError, match="is an input file"):
        check_output(tmp_path / "." / "p.ply")


def test_check_output_refuses_an_unwritable_folder(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):
            pytest.skip("this user (root) can write to a read-only folder anyway")
        with pytest.raises(ValueError, match="no write permission"):
            check_output(locked / "out.ply")
    finally:
        locked.chmod(0o700)


def test_check_input(tmp_path):
    f = tmp_path / "a.bin"
    f.write_bytes(b"1")
    assert check_input(f, "thing") == f
    with pytest.raises(FileNotFoundError, match="^thing file '.*b.bin' does not exist.$"):
        check_input(tmp_path / "b.bin", "thing")
    (tmp_path / "dangling").symlink_to(tmp_path / "gone")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        check_input(tmp_path / "dangling", "thing")


def test_atomic_write_keeps_the_old_file_when_the_writer_fails(tmp_path):
    out = tmp_path / "out.ply"
    out.write_bytes(b"old content")

    def failing(tmp):
        with open(tmp, "wb") as fh:
            fh.write(b"half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(out, failing)
    assert out.read_bytes() == b"old content"
    assert os.listdir(tmp_path) == ["out.ply"]
    atomic_write(out, lambda tmp: Path(tmp).write_bytes(b"new"))
    assert out.read_bytes() == b"new" and os.listdir(tmp_path) == ["out.ply"]


_INTERRUPTED = textwrap.dedent("""
    import signal, sys, time
    from geosynth.io.files import atomic_write
    signal.signal(signal.SIGINT, signal.default_int_handler)  # even when started with SIGINT ignored
    signal.signal(signal.SIGTERM, signal.SIG_DFL)

    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(b"partial")
        print("writing", flush=True)
        time.sleep(60)

    atomic_write(sys.argv[1], write)
""")


@pytest.mark.parametrize("sig,codes", [(signal.SIGTERM, (-15, 143)), (signal.SIGINT, (-2, 130))],
                         ids=["SIGTERM", "SIGINT"])
def test_atomic_write_interrupted_by_a_signal_leaves_no_trace(tmp_path, sig, codes):
    out = tmp_path / "out.ply"
    out.write_bytes(b"the old bytes")
    # One thread in the child: a signal sent to the process may be taken by any thread that does
    # not block it, and taken by OpenBLAS's worker (started by importing NumPy) it does not wake the
    # main thread's sleep, so the handler would run only when the sleep ends (1 run in ~15 under load)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-c", _INTERRUPTED, str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    try:
        assert proc.stdout.readline().strip() == b"writing"
        assert [f for f in os.listdir(tmp_path) if f.startswith(".out.ply.") and ".tmp" in f]  # mid-write
        proc.send_signal(sig)
        proc.wait(timeout=30)
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    assert proc.returncode in codes, (proc.returncode, err)
    assert os.listdir(tmp_path) == ["out.ply"]  # no .out.ply.*.tmp* left
    assert out.read_bytes() == b"the old bytes"


def test_write_image_by_suffix(tmp_path):
    img = np.random.default_rng(0).integers(0, 256, (16, 24, 3)).astype(np.uint8)
    assert write_image(tmp_path / "a.png", img).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert write_image(tmp_path / "a.jpg", img).read_bytes()[:3] == b"\xff\xd8\xff"
    assert write_image(tmp_path / "a.JPEG", img[:, :, 0]).read_bytes()[:3] == b"\xff\xd8\xff"
    np.testing.assert_array_equal(read_texture(tmp_path / "a.png"), img)
    for name in ("a.gif", "a.bmp", "noext"):
        with pytest.raises(ValueError, match="must end in .png, .jpg, .jpeg"):
            write_image(tmp_path / name, img)
    assert sorted(os.listdir(tmp_path)) == ["a.JPEG", "a.jpg", "a.png"]


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    # issue 31: after a SIGKILL during a write the hidden temporary stayed, and the next run kept it
    out = tmp_path / "out.ply"
    script = textwrap.dedent(f"""
        import time
        from geosynth.io.files import atomic_write
        def slow(tmp):
            open(tmp, "wb").write(b"partial")
            print("writing", flush=True)
            time.sleep(60)
        atomic_write({str(out)!r}, slow)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        proc.kill()  # SIGKILL: no cleanup can run
        proc.wait(timeout=30)
    finally:
        proc.kill()
    left = [p.name for p in tmp_path.iterdir()]
    assert len(left) == 1 and left[0].startswith(f".out.ply.geosynth-{proc.pid}-"), left
    # a live writer's temporary (this process, just written) must survive another run's cleanup
    from geosynth.io.files import temporary_path

    live = temporary_path(tmp_path / "out.ply", ".ply")
    live.write_bytes(b"still being written")
    atomic_write(out, lambda tmp: Path(tmp).write_bytes(b"done"))
    assert out.read_bytes() == b"done"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out.ply", live.name])
