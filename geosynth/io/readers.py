"""What geometry does this file hold? Implements no paper section: the readers behind every
method's input.

Reading geometry files, for :func:`geosynth.geometry.pointsets.read_point_set`,
:func:`geosynth.geometry.pointsets.read_geometry` and :func:`geosynth.geometry.meshes.load_mesh`.

- PLY (ASCII, binary little- and big-endian; with or without normals, colours, faces)
  through plyfile.
- OBJ, STL, OFF, GLB/GLTF through trimesh, loaded with ``process=False`` so that
  nothing (NaN vertices, the faces that use them) is dropped before the checks here.

Every failure is a one-line ValueError that names the file and says what is wrong;
the callers check first that the file exists (:func:`geosynth.io.files.check_input`).
"""

from __future__ import annotations

import io
import os
import warnings
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

MESH_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")
_TEXT_FORMATS = {".obj": "obj", ".off": "off"}  # decoded here: trimesh needs charset_normalizer otherwise
_PLY_HINT = ("a complete PLY file (ASCII or binary) whose vertex element has x, y, z properties")
_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
# colour property groups (red, green, blue, alpha); the alpha is optional
_COLOR_NAMES = (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"),
                ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha"))
_COLOR_FIX = "store colours as uchar 0..255 or float 0..1, or drop the red, green, blue properties"
# float colours up to this far outside [0, 1] are rounding (clipped): half a step of uchar
_FLOAT_SLACK = 0.5 / 255
_FACE_LISTS = ("vertex_indices", "vertex_index")
# bytes of each PLY scalar type (the header check below)
_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
              "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def reason(exc: BaseException) -> str:
    """An exception's message on one line (its type's name when it has none), at most 240 characters."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 240 else text[:237] + "..."


def _name(p: Path) -> str:
    return repr(str(p))


@dataclass
class Geometry:
    """What a geometry file holds: (N, 3) float64 positions, (N, 3) float64 normals or
    None, (N, 3) uint8 RGB colours or None, (F, 3) int64 triangles or None (no faces),
    (N,) uint8 alpha or None (the file gave no alpha; always None without colours)."""

    positions: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    faces: np.ndarray | None = None
    alpha: np.ndarray | None = None


def read_any(p: Path, faces: bool = True) -> Geometry:
    """Read a geometry file by its extension: PLY through plyfile, the others through trimesh."""
    if p.suffix.lower() == ".ply":
        return read_ply(p, faces=faces)
    return read_with_trimesh(p)


# ------------------------------------------------------------------ PLY


def has_colours(p: Path) -> bool:
    """Whether a geometry file holds colours (vertex, face or texture), for the methods that
    cannot carry them to say so: a PLY file from its header alone (a vertex or face element
    with a red, r or diffuse_red property), the others read whole. A file that cannot be
    read says False here (its reader refuses it in its own words)."""
    try:
        if p.suffix.lower() == ".ply":
            with open(p, "rb") as fh:
                head = fh.read(1 << 16)
            element = None
            for line in head.split(b"end_header")[0].decode("ascii", "replace").splitlines():
                w = line.split()
                if len(w) >= 2 and w[0] == "element":
                    element = w[1]
                elif len(w) >= 3 and w[0] == "property" and element in ("vertex", "face") and \
                        w[-1] in ("red", "r", "diffuse_red"):
                    return True
            return False
        return read_any(p).colors is not None
    except (OSError, ValueError):
        return False


@dataclass
class _PlyElementHead:
    """One element of a PLY header: its name, declared count, the bytes of its scalar
    properties per record (binary), its list properties as (name, length bytes, item
    bytes), and its number of properties."""

    name: str
    count: int
    fixed: int = 0
    lists: list = dc_field(default_factory=list)
    props: int = 0


@dataclass
class _PlyHead:
    """A PLY header as far as the size checks need it: the format, the elements, and
    the byte offset at which the data begin."""

    fmt: str | None
    elements: list
    start: int

    def declared(self) -> str:
        return (", ".join(f"{e.count:,} {e.name}" for e in self.elements) + " records") if self.elements \
            else "no elements"


_HEADER_LIMIT = 1 << 24  # a header longer than 16 MiB is not one (plyfile then words the error)


def _ply_header(p: Path) -> _PlyHead | None:
    """The header of a PLY file, or None when it is not one this check understands
    (plyfile then words the error)."""
    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
        while b"end_header" not in head and len(head) < _HEADER_LIMIT:
            more = fh.read(1 << 16)
            if not more:
                break
            head += more
    end = head.find(b"end_header")
    nl = head.find(b"\n", end) if end >= 0 else -1
    if not head.startswith(b"ply") or nl < 0:
        return None
    fmt, elements = None, []
    for line in head[:end].decode("ascii", "replace").splitlines():
        w = line.split()
        if not w:
            continue
        if w[0] == "format" and len(w) >= 2:
            fmt = w[1]
        elif w[0] == "element" and len(w) == 3:
            if not w[2].isdigit():
                return None
            elements.append(_PlyElementHead(w[1], int(w[2])))
        elif w[0] == "property" and elements:
            e = elements[-1]
            if len(w) == 5 and w[1] == "list":
                size, item = _PLY_SIZES.get(w[2]), _PLY_SIZES.get(w[3])
                if size is None or item is None:
                    return None
                e.lists.append((w[4], size, item))
            elif len(w) == 3:
                size = _PLY_SIZES.get(w[1])
                if size is None:
                    return None
                e.fixed += size
            else:
                return None
            e.props += 1
    return _PlyHead(fmt, elements, nl + 1)


def _mismatch(p: Path, head: _PlyHead, declared: str, holds: str) -> ValueError:
    return ValueError(f"{_name(p)} is not a readable PLY file: its header declares {head.declared()} "
                      f"({declared}) but the file holds {holds}; correct the element counts in the header or "
                      "export the file again.")


def _ascii_data_lines(p: Path, start: int) -> tuple[int, bool]:
    """(lines, ended) of an ASCII PLY body: its lines up to its last non-blank character
    (trailing blank lines are not records), and whether that last line ends with a line
    break; read in chunks."""
    lines = count = 0
    ended = False
    with open(p, "rb") as fh:
        fh.seek(start)
        while chunk := fh.read(1 << 24):
            text = chunk.rstrip()
            if text:
                lines = count + text.count(b"\n") + 1
                ended = b"\n" in chunk[len(text):]
            else:
                ended = ended or b"\n" in chunk
            count += chunk.count(b"\n")
    return lines, ended


def _check_ply_size(p: Path, head: _PlyHead) -> None:
    """Refuse a file whose data do not match its header, before anything is parsed:
    ASCII files with more or fewer data lines than the declared records; binary files
    with fewer bytes than the header declares (before any memory is allocated for them:
    a corrupt count could ask for gigabytes), or, when every element has a fixed record
    size, any other size than the declared one. Binary files with list properties
    (faces) are checked exactly once parsed (:func:`_check_ply_lists`)."""
    body = os.path.getsize(p) - head.start
    if head.fmt == "ascii":
        need = sum(e.count for e in head.elements)
        lines, ended = _ascii_data_lines(p, head.start)
        if lines != need:
            raise _mismatch(p, head, f"{need:,} data line{'s' * (need != 1)}, one per record",
                            f"{lines:,} data line{'s' * (lines != 1)}, {_more_or_less(lines, need)}")
        if lines and not ended:  # a number cut short would read as another number
            raise _ply_error(p, f"its last data line (line {lines:,} after the header) has no line break at its end, "
                                "as if the file were cut inside its last record",
                             "if the file is complete, end it with a line break; else export it again")
        return
    # a list property holds its length at least
    need = sum(e.count * (e.fixed + sum(size for _, size, _ in e.lists)) for e in head.elements)
    exact = not any(e.lists for e in head.elements if e.count)
    if need > body or (exact and need != body):
        holds = f"{body:,} bytes after the header"
        records = [e for e in head.elements if e.count]
        if exact and len(records) == 1 and records[0].fixed and body % records[0].fixed == 0:
            e = records[0]
            holds += f", {body // e.fixed:,} {e.name} records"
        what = "truncated or its header is wrong" if need > body else "more data than the header declares"
        raise _mismatch(p, head, f"{'exactly' if exact else 'at least'} {need:,} bytes of binary data",
                        f"{holds} ({what})")


def _truncated(p: Path, head: _PlyHead, exc: BaseException) -> ValueError:
    """A binary file with list properties that ends before its declared records do."""
    need = sum(e.count * (e.fixed + sum(size for _, size, _ in e.lists)) for e in head.elements)
    body = os.path.getsize(p) - head.start
    return _mismatch(p, head, f"at least {need:,} bytes of binary data",
                     f"{body:,} bytes after the header, which end too early ({reason(exc)}: truncated, or its "
                     "header is wrong)")


def _more_or_less(have: int, need: int) -> str:
    return "fewer than declared: the file is truncated or its header is wrong" if have < need else \
        "more than declared: data after the declared records would be lost"


def _check_ply_lists(p: Path, head: _PlyHead, ply) -> None:
    """Binary files with list properties: refuse one whose parsed data do not end
    exactly at the end of the file (extra records or bytes beyond the declared ones)."""
    if head.fmt == "ascii" or not any(e.lists and e.count for e in head.elements):
        return
    used = 0
    for e in head.elements:
        used += e.count * e.fixed
        if not e.lists or not e.count:
            continue
        data = ply[e.name].data
        for name, size, item in e.lists:
            col = data[name]
            items = col.size if col.dtype != object else sum(len(a) for a in col)
            used += e.count * size + int(items) * item
    body = os.path.getsize(p) - head.start
    if used != body:
        raise _mismatch(p, head, f"{used:,} bytes of binary data, as its records' lists are long",
                        f"{body:,} bytes after the header ({_more_or_less(body, used).split(':')[0]})")


def _ply_error(p: Path, what: str, fix: str = f"give {_PLY_HINT}") -> ValueError:
    return ValueError(f"{_name(p)} is not a readable PLY file: {what}; {fix}.")


def read_ply(p: Path, faces: bool = True) -> Geometry:
    """Read a PLY file's vertices (positions, normals, colours) and, when ``faces``, its
    faces (polygons split into triangle fans).

    Raises:
        ValueError: the file is not a readable PLY file, lacks x, y, z, or has colours
            out of range or faces with fewer than 3 corners; the message names it.
    """
    from plyfile import PlyData

    try:
        header = _ply_header(p)
    except OSError as exc:
        raise _ply_error(p, reason(exc)) from exc
    known = {}
    if header is not None:
        try:
            _check_ply_size(p, header)
        except OSError as exc:
            raise _ply_error(p, reason(exc)) from exc
        # fixed-length triangle lists let plyfile map the faces instead of parsing them one by one
        known = {e.name: {lst: 3 for lst, _, _ in e.lists if lst in _FACE_LISTS} for e in header.elements
                 if e.name == "face" and e.lists}
    try:
        with warnings.catch_warnings():
            # an empty list in an ASCII file (a face with no corners) warns through NumPy; refused below
            warnings.filterwarnings("ignore", message="loadtxt: input contained no data")
            try:
                ply = PlyData.read(str(p), known_list_len=known)
            except Exception:
                if not known:
                    raise
                ply = PlyData.read(str(p))  # not all triangles: the slow path (and its error, if any)
    except Exception as exc:  # plyfile raises PlyParseError, ValueError, UnicodeDecodeError, MemoryError, ...
        if header is not None and header.fmt != "ascii" and "early end-of-file" in str(exc):
            raise _truncated(p, header, exc) from exc
        raise _ply_error(p, reason(exc)) from exc
    if header is not None:
        _check_ply_lists(p, header, ply)
    with np.errstate(invalid="ignore", over="ignore"):  # signalling NaNs, huge doubles: refused later
        return _ply_content(p, ply, faces)


def _ply_content(p: Path, ply, faces: bool) -> Geometry:
    names = [e.name for e in ply.elements]
    if "vertex" not in names:
        raise _ply_error(p, f"it has no vertex element (its elements: {', '.join(names) or 'none'})")
    vertex = ply["vertex"].data
    fields = vertex.dtype.names or ()

    def columns(group, kind):
        cols = [np.asarray(vertex[n]) for n in group]
        if any(c.dtype.kind not in "iuf" or c.ndim != 1 for c in cols):
            raise _ply_error(p, f"its vertex {kind} {', '.join(group)} must be numbers, not lists")
        return np.stack(cols, 1)

    missing = [c for c in "xyz" if c not in fields]
    if missing:
        have = ", ".join(fields) or "nothing"
        raise _ply_error(p, f"its vertex element lacks {', '.join(missing)} (it has: {have})")
    out = Geometry(columns("xyz", "positions").astype(np.float64))
    group = next((g for g in _NORMAL_NAMES if set(g) <= set(fields)), None)
    if group is not None:
        out.normals = columns(group, "normals").astype(np.float64)
    group = _color_group(p, fields, "vertex")
    if group is not None:
        rgba = _colors(p, columns(group, "colours"), "vertex", group)
        out.colors, out.alpha = rgba[:, :3], (rgba[:, 3] if rgba.shape[1] == 4 else None)
    has_faces = "face" in names and ply["face"].count > 0
    if faces and has_faces:
        out.faces = _ply_faces(p, ply["face"].data)
    elif has_faces:
        _face_range(p, ply["face"].data, len(vertex), not ply.text)
    fgroup = _color_group(p, ply["face"].data.dtype.names or (), "face") if has_faces else None
    # face colours only: each vertex the mean of its faces' (vertex colours, when given, are the ones used)
    if fgroup is not None and group is None:
        face = ply["face"].data
        fcol = _colors(p, np.stack([np.asarray(face[n]) for n in fgroup], 1), "face", fgroup)
        tri = out.faces if out.faces is not None else _ply_faces(p, face)
        if len(fcol) != len(tri):  # polygons were split into fans: repeat each polygon's colour
            fcol = np.repeat(fcol, _fan_counts(face), axis=0)
        rgba = _face_to_vertex(p, fcol, tri, len(vertex))
        out.colors, out.alpha = rgba[:, :3], (rgba[:, 3] if rgba.shape[1] == 4 else None)
    return out


def _color_group(p: Path, fields, element: str) -> tuple | None:
    """The colour properties of a PLY element: (red, green, blue) or (red, green, blue,
    alpha) names, None without colour; a group with some but not all of red, green and
    blue, or an alpha without them, is refused (half a colour cannot be used)."""
    have = set(fields)
    for group in _COLOR_NAMES:
        present = [n for n in group[:3] if n in have]
        if len(present) == 3:
            return group if group[3] in have else group[:3]
        if present and (len(group[0]) > 1 or group[3] in have):  # lone r/g/b/a may be other data
            missing = [n for n in group[:3] if n not in have]
            raise _ply_error(p, f"its {element} element has the colour properties {', '.join(present)} but not "
                                f"{', '.join(missing)}", "give all of red, green, blue or none of them")
    alone = [g[3] for g in _COLOR_NAMES if len(g[3]) > 1 and g[3] in have]
    if alone:
        raise _ply_error(p, f"its {element} element has {alone[0]} but no red, green, blue",
                         "give red, green, blue with it, or drop it")
    return None


def _fan_counts(face) -> np.ndarray:
    """Triangles per polygon of a PLY face element (as :func:`_ply_faces` splits them)."""
    name = next(n for n in _FACE_LISTS if n in (face.dtype.names or ()))
    col = face[name]
    if col.dtype != object:
        return np.ones(len(col), np.int64)
    return np.fromiter((len(a) for a in col), np.int64, len(col)) - 2


def _face_to_vertex(p: Path, fcol: np.ndarray, tri: np.ndarray, n: int) -> np.ndarray:
    """(n, C) uint8 vertex colours from (F, C) uint8 triangle colours: each vertex the mean
    of the colours of the triangles around it (as trimesh converts them); a vertex on no
    face has none, and is refused."""
    count = np.bincount(tri.reshape(-1), minlength=n)
    if (count == 0).any():
        lone = np.flatnonzero(count == 0)
        raise _ply_error(p, f"its colours are per face but {len(lone):,} vertices lie on no face (the first: vertex "
                            f"{lone[0]}), so they have no colour", "give vertex colours, or remove those vertices")
    sums = np.zeros((n, fcol.shape[1]), np.float64)
    for k in range(3):
        np.add.at(sums, tri[:, k], fcol.astype(np.float64))
    return np.clip(np.rint(sums / count[:, None]), 0, 255).astype(np.uint8)


def _face_range(p: Path, face, n: int, binary: bool) -> None:
    """A point set read from a mesh file: its faces are not used, but faces that name
    vertices the file lacks mean the file is corrupt (or its counts wrong), and its
    vertices are not to be trusted either. So do faces of fewer than 3 corners in a
    binary file: records read out of step with the data (a wrong vertex count) show
    as such lists (an ASCII file's empty face is a slip of its writer, and ignored)."""
    name = next((c for c in _FACE_LISTS if c in (face.dtype.names or ())), None)
    if name is None:
        return
    col = face[name]
    if col.dtype == object:
        parts = [np.asarray(a).reshape(-1) for a in col]
        lengths = np.fromiter((len(a) for a in parts), np.int64, len(parts))
        short = np.flatnonzero(lengths < 3)
        if binary and len(short):
            raise _ply_error(p, f"{len(short)} face(s) have fewer than 3 corners (the first: face {short[0]}, with "
                                f"{lengths[short[0]]}), as when its records are read out of step with its data",
                             "the header's counts or the faces are wrong: fix the file")
        flat = np.concatenate(parts) if parts else np.zeros(0, np.int64)
    else:
        flat = np.asarray(col).reshape(-1)
    if flat.size == 0 or flat.dtype.kind not in "iu":
        return
    lo, hi = int(flat.min()), int(flat.max())
    if lo < 0 or hi >= n:
        raise _ply_error(p, f"its faces refer to vertex {lo if lo < 0 else hi} but it has {n:,} vertices (indices "
                            f"0 to {n - 1:,})", "the header's counts or the faces are wrong: fix the file")


def _colors(p: Path, c: np.ndarray, element: str = "vertex", group=("red", "green", "blue")) -> np.ndarray:
    """(N, C) uint8 colours (C = 3 or 4, RGB[A]) from (N, C) numbers: integers 0..255 as
    they are; 16-bit ones (any value above 255) scaled by 1/257; floats in [0, 1] times 255
    (values within half a uchar step outside it are rounding, clipped); floats that are all
    whole numbers in 0..255 (some writers store uchar values as floats) as they are.
    Anything else (NaN, other floats beyond [0, 1], integers beyond 0..65535) is refused
    in one line naming the file, the element and the properties."""
    props = ", ".join(group)
    if c.size == 0:
        return c.astype(np.uint8)
    if c.dtype.kind == "f":
        c = c.astype(np.float64)
        if not np.isfinite(c).all():
            bad = int(np.argmax(~np.isfinite(c).all(1)))
            raise _ply_error(p, f"its {element} colours ({props}) contain NaN or inf (the first: {element} {bad})",
                             _COLOR_FIX)
        lo, hi = float(c.min()), float(c.max())
        if lo >= -_FLOAT_SLACK and hi <= 1 + _FLOAT_SLACK:
            return np.rint(np.clip(c, 0, 1) * 255.0).astype(np.uint8)
        if lo >= 0 and hi <= 255 and (c == np.rint(c)).all():
            return c.astype(np.uint8)
        raise _ply_error(p, f"its float {element} colours ({props}) lie in [{lo:.4g}, {hi:.4g}], neither in [0, 1] "
                            "nor whole numbers 0..255", _COLOR_FIX)
    lo, hi = int(c.min()), int(c.max())
    if c.dtype == np.uint16 and hi > 255:  # 16-bit colours (8-bit values stored as ushort stay as they are)
        return np.rint(c / 257.0).astype(np.uint8)
    if lo < 0 or hi > 255:
        raise _ply_error(p, f"its {element} colours ({props}) lie in {lo}..{hi}, not in 0..255", _COLOR_FIX)
    return c.astype(np.uint8)


def _ply_faces(p: Path, face) -> np.ndarray:
    """(F, 3) int64 triangles from a PLY face element (polygons as triangle fans)."""
    fields = face.dtype.names or ()
    name = next((n for n in _FACE_LISTS if n in fields), None)
    if name is None:
        raise _ply_error(p, f"its face element has no vertex_indices list (it has: {', '.join(fields)})")
    col = face[name]
    if col.dtype != object:  # mapped with a known length of 3
        tri = np.asarray(col)
        if tri.ndim != 2 or tri.dtype.kind not in "iu":
            raise _ply_error(p, f"its face {name} must be lists of integer vertex indices")
        return tri.astype(np.int64)
    lengths = np.fromiter((len(a) for a in col), np.int64, len(col))
    short = np.flatnonzero(lengths < 3)
    if len(short):
        raise _ply_error(p, f"{len(short)} face(s) have fewer than 3 corners (the first: face {short[0]}, "
                            f"with {lengths[short[0]]})", "remove those faces")
    flat = np.concatenate(list(col))
    if flat.dtype.kind not in "iu":
        raise _ply_error(p, f"its face {name} must be lists of integer vertex indices, not {flat.dtype}")
    flat = flat.astype(np.int64)
    if (lengths == 3).all():
        return flat.reshape(-1, 3)
    # triangle fans (c0, cj, cj+1), j = 1 .. L-2, in the faces' order
    ntri = lengths - 2
    start = np.cumsum(lengths) - lengths
    owner = np.repeat(np.arange(len(col)), ntri)
    j = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    s = start[owner]
    return np.stack([flat[s], flat[s + j], flat[s + j + 1]], 1)


# ------------------------------------------------------------------ trimesh formats


def read_with_trimesh(p: Path) -> Geometry:
    """Read an OBJ, STL, OFF, GLB or GLTF file with trimesh, without processing.

    Scenes are flattened (their transforms applied) and their meshes concatenated; a
    file without faces gives its vertices as positions.
    """
    import trimesh

    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"{_name(p)} has the extension {suffix or '(none)'}, not one of the geometry formats read "
                         f"here ({', '.join(MESH_SUFFIXES)}); convert it or rename it if it is one of them.")
    kind = suffix[1:].upper()
    if suffix == ".stl":
        try:
            raw = p.read_bytes()
        except OSError as exc:
            raise _stl_error(p, reason(exc)) from exc
        _check_stl(p, raw)
    try:
        with np.errstate(invalid="ignore", over="ignore"):  # NaN and huge values are refused later
            geom = _trimesh_load(trimesh, p, suffix)
        parts = list(geom.dump()) if isinstance(geom, trimesh.Scene) else [geom]
        meshes = [g for g in parts if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        # a mangled OBJ can parse into vertices of shape (N, 1) (a bit flip in "v x y z")
        shapes = [np.shape(g.vertices) for g in meshes or parts
                  if isinstance(g, (trimesh.Trimesh, trimesh.PointCloud)) and len(g.vertices)]
        if any(len(v) != 2 or v[1] != 3 for v in shapes):
            raise ValueError(f"its vertices have shape {shapes}, not (N, 3)")
        if meshes:
            colours = [_trimesh_colors(p, kind, g) for g in meshes]
            mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
            out = Geometry(np.asarray(mesh.vertices, np.float64), faces=np.asarray(mesh.faces, np.int64))
        else:
            clouds = [g for g in parts if isinstance(g, (trimesh.Trimesh, trimesh.PointCloud)) and len(g.vertices)]
            colours = [_trimesh_colors(p, kind, g) for g in clouds]
            points = [np.asarray(g.vertices, np.float64) for g in clouds]
            out = Geometry(np.concatenate(points)) if points else None
    except ValueError as exc:
        if str(exc).startswith(_name(p)):  # a colour refusal: already one line naming the file
            raise
        raise ValueError(f"{_name(p)} is not a readable {kind} file: {reason(exc)}; give a complete {kind} file."
                         ) from exc
    except Exception as exc:  # trimesh raises many kinds (IndexError, ValueError, KeyError, ...) on bad files
        raise ValueError(f"{_name(p)} is not a readable {kind} file: {reason(exc)}; give a complete {kind} file."
                         ) from exc
    if out is None:
        found = ", ".join(sorted({type(g).__name__ for g in parts})) or "nothing"
        raise ValueError(f"{_name(p)} holds no vertices: trimesh read no mesh or points from this {kind} file "
                         f"(it read: {found}).")
    if any(c is not None for c in colours):
        if any(c is None for c in colours):  # some parts coloured, some not: the others get none to copy
            raise ValueError(f"{_name(p)} has colours on {sum(c is not None for c in colours)} of its "
                             f"{len(colours)} parts and none on the others; colour every part or none.")
        rgba = np.concatenate(colours)
        out.colors = np.ascontiguousarray(rgba[:, :3])
        # trimesh always holds RGBA (255 where the file gave no alpha): kept where it says something
        out.alpha = np.ascontiguousarray(rgba[:, 3]) if (rgba[:, 3] != 255).any() else None
    return out


def _trimesh_colors(p: Path, kind: str, g) -> np.ndarray | None:
    """(N, 4) uint8 RGBA vertex colours of one trimesh mesh or point cloud, or None.

    Vertex colours (OBJ ``v x y z r g b``, GLB COLOR_0, PLY through trimesh) as they are;
    face colours as each vertex's mean of its faces' (trimesh's conversion); a texture
    (GLB baseColorTexture, OBJ map_Kd) sampled at each vertex's UV (trimesh's
    ``to_color``); a material's one colour without texture (an explicit base colour) as
    that colour everywhere; a default material (no texture, no colour given) is no colour.
    A texture whose vertices have no UV coordinates is refused in one line."""
    visual = getattr(g, "visual", None)
    vkind = getattr(visual, "kind", None)
    n = len(g.vertices)
    if not hasattr(g, "faces"):  # a trimesh.PointCloud (OBJ vertices without faces): its colours or none
        c = np.asarray(getattr(g, "colors", np.zeros((0, 4))))
        if c.size == 0:
            return None
        vkind = "points"
    elif vkind is None:
        return None
    if vkind == "points":
        pass
    elif vkind in ("vertex", "face"):
        c = np.asarray(visual.vertex_colors)
    elif vkind == "texture":
        material = getattr(visual, "material", None)
        image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
        if image is None:
            factor = getattr(material, "baseColorFactor", None)
            if factor is None and "kd" in (getattr(material, "kwargs", None) or {}):  # an OBJ material's Kd
                factor = getattr(material, "diffuse", None)
            if factor is None:
                return None  # a default material: no colour was given
            return np.tile(np.asarray(factor, np.uint8).reshape(-1)[:4], (n, 1))
        uv = getattr(visual, "uv", None)
        if uv is None or len(uv) != n:
            raise ValueError(f"{_name(p)} has a texture but {'no' if uv is None else len(uv)} UV coordinates for its "
                             f"{n:,} vertices, so its colours cannot be sampled; bake the texture into vertex "
                             "colours or give every vertex a UV.")
        c = np.asarray(visual.to_color().vertex_colors)
    else:  # pragma: no cover - trimesh has no other kinds
        raise ValueError(f"{_name(p)} has colours of a kind ({vkind}) not read here; store vertex colours.")
    if c.shape != (n, 4) or c.dtype != np.uint8:
        raise ValueError(f"{_name(p)} has {c.shape} {c.dtype} colours for its {n:,} vertices, not one RGBA "
                         f"colour per vertex; store one uchar RGB colour per vertex.")
    return c


def _trimesh_load(trimesh, p: Path, suffix: str):
    if suffix == ".stl":  # checked first (read_with_trimesh): read as it is
        return trimesh.load(io.BytesIO(p.read_bytes()), file_type="stl", process=False)
    if suffix not in _TEXT_FORMATS:
        return trimesh.load(str(p), process=False)
    raw = p.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # never fails; the parser judges the content
    if suffix == ".obj":
        _check_obj_colours(p, text)
    return trimesh.load(io.StringIO(text), file_type=_TEXT_FORMATS[suffix], process=False,
                        resolver=trimesh.resolvers.FilePathResolver(str(p)))


_OBJ_COLOR_FIX = "store colours after x y z as 0..1 or as whole numbers 0..255, or drop them"


def _check_obj_colours(p: Path, text: str) -> None:
    """Refuse OBJ vertex colours (``v x y z r g b``) that trimesh would drop or misread without
    a word: colours on some vertices but not others (trimesh drops them all), NaN (read as 0),
    or values neither in [0, 1] nor whole numbers 0..255 (the two ways writers store them)."""
    rows = [line.split("#", 1)[0].split() for line in text.splitlines() if line.startswith("v ")]
    words = np.fromiter((len(r) for r in rows), np.int64, len(rows))
    coloured = words >= 7  # "v", x, y, z, r, g, b
    if not coloured.any():
        return
    if not coloured.all():
        first = int(np.argmin(coloured))
        raise ValueError(f"{_name(p)} has colours (v x y z r g b) on {int(coloured.sum()):,} of its {len(rows):,} "
                         f"vertices and none on the others (the first: vertex {first + 1}); colour every vertex or "
                         "none.")
    try:
        c = np.array([r[4:7] for r in rows], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{_name(p)} has vertex colours (v x y z r g b) that are not numbers; fix the file.") from None
    if not np.isfinite(c).all():
        first = int(np.argmax(~np.isfinite(c).all(1)))
        raise ValueError(f"{_name(p)} has vertex colours (v x y z r g b) that are NaN or inf (the first: vertex "
                         f"{first + 1}); {_OBJ_COLOR_FIX}.")
    lo, hi = float(c.min()), float(c.max())
    if not (lo >= -_FLOAT_SLACK and hi <= 1 + _FLOAT_SLACK) and not (lo >= 0 and hi <= 255 and (c == np.rint(c)).all()):
        raise ValueError(f"{_name(p)} has vertex colours (v x y z r g b) in [{lo:.4g}, {hi:.4g}], neither in [0, 1] "
                         f"nor whole numbers 0..255; {_OBJ_COLOR_FIX}.")


_STL_WORDS = "solid, facet normal, outer loop, vertex, endloop, endfacet, endsolid"


def _stl_error(p: Path, what: str) -> ValueError:
    return ValueError(f"{_name(p)} is not a readable STL file: {what}; give a complete binary or ASCII STL file.")


def _check_stl(p: Path, raw: bytes) -> None:
    """Refuse an STL file that is neither a binary STL whose size matches its triangle
    count nor well-formed ASCII STL, saying what is wrong and where (trimesh's ASCII
    reader stops quietly at the first number it cannot read, and words undecodable
    bytes as a missing module)."""
    if len(raw) >= 84:
        count = int.from_bytes(raw[80:84], "little")
        if 84 + 50 * count == len(raw):
            return  # binary STL (even when its header begins with "solid")
        binary = (f"nor a binary STL (its header declares {count:,} triangles, {84 + 50 * count:,} bytes, but the "
                  f"file holds {len(raw):,})")
    else:
        binary = f"nor a binary STL (it holds {len(raw)} bytes, fewer than the 84 of a binary STL's header)"
    if not raw.lstrip()[:5].lower() == b"solid":
        raise _stl_error(p, f"it is neither an ASCII STL (it does not begin with 'solid') {binary}")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise _stl_error(p, f"not valid ASCII STL: line {line} holds a byte that is not text (0x{raw[exc.start]:02x} "
                            f"at column {column}), {binary}") from None

    def bad(n: int, what: str) -> ValueError:
        return _stl_error(p, f"not valid ASCII STL: line {n}: {what}")

    def numbers(n: int, words: list[str], start: int, line: str) -> None:
        try:
            [float(w) for w in words[start:]]
        except ValueError:
            raise bad(n, f"{' '.join(words[:start])!r} needs 3 numbers, found {line!r}") from None
        if len(words) - start != 3:
            raise bad(n, f"{' '.join(words[:start])!r} needs 3 numbers, found {len(words) - start} in {line!r}")

    lines = text.splitlines()
    cut = not text.endswith(("\n", "\r"))  # the last line has no line break
    state, corners, last = "out", 0, 0
    for n, line in enumerate(lines, 1):
        words = line.split()
        if not words:
            continue
        last = n
        key = words[0].lower()
        shown = line.strip() if len(line.strip()) <= 60 else line.strip()[:57] + "..."
        expected = {"out": "solid", "solid": "facet normal or endsolid", "facet": "outer loop",
                    "loop": "vertex or endloop", "endloop": "endfacet"}[state]
        if key == "solid" and state == "out":
            state = "solid"
        elif key == "endsolid" and state == "solid":
            state = "out"
        elif key == "facet" and state == "solid" and len(words) >= 2 and words[1].lower() == "normal":
            numbers(n, words, 2, shown)
            state = "facet"
        elif key == "outer" and state == "facet" and len(words) == 2 and words[1].lower() == "loop":
            state, corners = "loop", 0
        elif key == "vertex" and state == "loop":
            numbers(n, words, 1, shown)
            corners += 1
        elif key == "endloop" and state == "loop":
            if corners != 3:
                raise bad(n, f"a facet with {corners} vertices (an STL facet has 3)")
            state = "endloop"
        elif key == "endfacet" and state == "endloop":
            state = "solid"
        elif n == len(lines) and cut:
            raise bad(n, f"the file ends inside this line ({shown!r}), where {expected} was due (cut short?)")
        else:
            raise bad(n, f"expected {expected}, found {shown!r} (an ASCII STL holds only {_STL_WORDS} lines)")
    if state != "out":
        raise bad(last, f"the file ends inside a {'solid' if state == 'solid' else 'facet'}, without 'endsolid' "
                        "(cut short?)")


# ------------------------------------------------------------------ checks


def _first_bad(p: Path, rows: np.ndarray, one: str, many: str) -> None:
    bad = np.flatnonzero(~rows)
    if len(bad):
        raise ValueError(f"{_name(p)} has {len(bad)} {one if len(bad) == 1 else many} with NaN or inf coordinates "
                         f"(the first: index {bad[0]}, counting from 0); every one must be finite: fix or remove them.")


def _finite32(a: np.ndarray) -> np.ndarray:
    """float32 copy of ``a``; values beyond float32's range become inf (and are refused)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return np.ascontiguousarray(a, dtype=np.float32)


def checked_points(p: Path, g: Geometry) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 3) float32 positions and normals (or None), all finite; ValueError naming ``p`` otherwise."""
    if len(g.positions) == 0:
        raise ValueError(f"{_name(p)} holds no vertices: not a point set.")
    pos = _finite32(g.positions)
    _first_bad(p, np.isfinite(pos).all(1), "point", "points")
    normals = None
    if g.normals is not None:
        normals = _finite32(g.normals)
        _first_bad(p, np.isfinite(normals).all(1), "normal", "normals")
    return pos, normals


def checked_mesh(p: Path, g: Geometry):
    """A ``trimesh.Trimesh`` (float64 vertices, int64 faces, unprocessed) from what a file
    holds, after checking: faces present, every vertex finite, face indices in range."""
    import trimesh

    if g.faces is None or len(g.faces) == 0:
        raise ValueError(f"{_name(p)} holds no faces: it is a point set, not a mesh "
                         "(geosynth.geometry.pointsets.read_geometry reads either).")
    if len(g.positions) == 0:
        raise ValueError(f"{_name(p)} has faces but no vertices.")
    _first_bad(p, np.isfinite(_finite32(g.positions)).all(1), "vertex", "vertices")
    f = g.faces
    v_count = len(g.positions)
    out = np.flatnonzero(((f < 0) | (f >= v_count)).any(1))
    if len(out):
        raise ValueError(f"{_name(p)} has {len(out)} face(s) with vertex indices out of range [0, {v_count}) (the "
                         f"first: face {out[0]}, {f[out[0]].tolist()}); fix the file.")
    mesh = trimesh.Trimesh(vertices=g.positions, faces=f, process=False, validate=False)
    if g.colors is not None:
        if len(g.colors) != v_count:
            raise ValueError(f"{_name(p)} has {len(g.colors):,} colours for its {v_count:,} vertices; give one colour "
                             "per vertex.")
        alpha = np.full(v_count, 255, np.uint8) if g.alpha is None else g.alpha
        mesh.visual.vertex_colors = np.column_stack([g.colors, alpha])
        mesh.metadata["alpha_given"] = g.alpha is not None  # the file had an alpha: written back (as_capture)
    return mesh
