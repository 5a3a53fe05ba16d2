"""What does a result look like from every side? Implements no paper section: a page in
which a person turns the methods' inputs and outputs with the mouse.

:func:`write_viewer` writes one self-contained HTML file: two views side by side (the
exemplar or capture on the left, the result on the right), each a small hand-written
WebGL viewer (drag to orbit, wheel to zoom, double-click to reset, a "link cameras"
checkbox), the quality lines of the run and the command that made it printed under the
views. The models travel inside the page as one base64 block of binary buffers (float32
positions, int8 normals, uint8 colours, uint32 triangle indices), so the page needs no
server, no network and no file beside it; its Content-Security-Policy forbids every
request (no script, style, font or image is fetched). Meshes are shaded with the light
of :mod:`geosynth.io.pictures` (a key and a fill light fixed to the camera, ambient, a
soft highlight), vertex colours shown when present; point sets are drawn as round
splats, shaded by their normals when they have them.

A model larger than ``max_triangles`` (points: more than ``max_triangles`` points) is
decimated for viewing, by vertex clustering on a grid (NumPy; the same cells' vertices
merge into their mean), and the page says so: the full file written by the command
remains the real output.

The page exposes ``window.__geosynthTest`` (``ready``, ``error``, ``openMs``: the time
from navigation start to both views' first frame, ``rotate(dx, dy, view)``: the same
code path as a mouse drag, ``camera(view)``, ``frames``) for the browser tests.
"""

from __future__ import annotations

import base64
import html
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geosynth.io.files import atomic_write, check_output

__all__ = ["HTML_SUFFIXES", "ViewModel", "as_view_model", "decimate_mesh", "decode_payload", "gallery_index_html",
           "viewer_html", "write_gallery_index", "write_viewer"]

HTML_SUFFIXES = (".html", ".htm")
MESH_COLOUR = (172, 186, 212)  # pictures.MESH_COLOR: the same light steel blue as the PNGs
POINT_COLOUR = (150, 160, 180)


@dataclass
class ViewModel:
    """One model as the page draws it.

    Attributes:
        positions: (N, 3) float32.
        faces: (M, 3) uint32 triangle indices, or None for a point set.
        normals: (N, 3) float32 unit normals, or None (points drawn unlit).
        colours: (N, 3) uint8, or None (the default colour).
        note: what was done to it for viewing ("" when nothing), printed on the page.
        original: (vertices or points, triangles or 0) before decimation.
    """

    positions: np.ndarray
    faces: np.ndarray | None
    normals: np.ndarray | None
    colours: np.ndarray | None
    note: str = ""
    original: tuple[int, int] = (0, 0)

    @property
    def kind(self) -> str:
        return "points" if self.faces is None else "mesh"


def _vertex_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit; a vertex of no face gets +z)."""
    p = positions.astype(np.float64)
    tri = p[faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length: twice the area
    n = np.zeros_like(p)
    for k in range(3):
        np.add.at(n, faces[:, k], face_n)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 0, n / np.maximum(length, 1e-300), [0.0, 0.0, 1.0])
    return n.astype(np.float32)


def _cluster(positions: np.ndarray, faces: np.ndarray, colours: np.ndarray | None, cell: float):
    """Vertex clustering on a grid of ``cell``: each occupied cell's vertices become their
    mean (colours too); faces whose corners fall in fewer than three cells, and repeated
    faces, are dropped."""
    lo = positions.min(0)
    keys = np.floor((positions - lo) / cell).astype(np.int64)
    _, label, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    label = label.reshape(-1)
    count = len(counts)
    new_pos = np.zeros((count, 3))
    np.add.at(new_pos, label, positions)
    new_pos /= counts[:, None]
    new_col = None
    if colours is not None:
        acc = np.zeros((count, 3))
        np.add.at(acc, label, colours.astype(np.float64))
        new_col = np.clip(np.round(acc / counts[:, None]), 0, 255).astype(np.uint8)
    f = label[faces]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[keep]
    # one copy of each triangle (the same three cells in any rotation and orientation)
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    f = f[np.sort(first)]
    used = np.unique(f)
    remap = np.full(count, -1, np.int64)
    remap[used] = np.arange(len(used))
    return new_pos[used], remap[f], (None if new_col is None else new_col[used])


def decimate_mesh(positions: np.ndarray, faces: np.ndarray, colours: np.ndarray | None,
                  max_triangles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """At most ``max_triangles`` triangles by vertex clustering (NumPy), the cell grown
    from the size that the surface area predicts until the count fits.

    Returns:
        (positions (n, 3) float64, faces (m, 3) int64, colours (n, 3) uint8 or None).
    """
    positions = np.asarray(positions, np.float64)
    faces = np.asarray(faces, np.int64)
    if len(faces) <= max_triangles:
        return positions, faces, colours
    tri = positions[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    extent = float(np.ptp(positions, axis=0).max()) or 1.0
    # a regular triangulation of cell h has about 2 area / h^2 triangles
    cell = max(np.sqrt(2.0 * area / max_triangles), extent * 1e-6) if area > 0 else extent / 100
    for _ in range(60):
        p, f, c = _cluster(positions, faces, colours, cell)
        if len(f) <= max_triangles:
            return p, f, c
        cell *= 1.15
    raise RuntimeError(f"could not decimate {len(faces):,} triangles to {max_triangles:,}.")  # pragma: no cover


def as_view_model(model, max_triangles: int = 200_000) -> ViewModel:
    """What :func:`write_viewer` draws for one side.

    Args:
        model: a ``trimesh.Trimesh`` (vertex or face colours shown when present); an
            (N, 3) point array; a tuple ``(points, colours)`` or ``(points, colours,
            normals)`` with (N, 3) uint8 colours or None; or an object with
            ``positions`` and optional ``normals`` and ``colors`` (a PointSet) or
            ``points`` (a PointTexture).
        max_triangles: a mesh with more triangles (a point set with more points) is
            decimated (points: an even subsample) and the note says so.

    Raises:
        TypeError: another kind of object.
        ValueError: arrays of the wrong shape, empty, or not finite.
    """
    if max_triangles < 1:
        raise ValueError(f"max_triangles must be >= 1, got {max_triangles}.")
    faces = normals = colours = None
    if hasattr(model, "faces") and hasattr(model, "vertices"):  # a trimesh.Trimesh
        positions = np.asarray(model.vertices, np.float64)
        faces = np.asarray(model.faces, np.int64).reshape(-1, 3)
        visual = getattr(model, "visual", None)
        if getattr(visual, "kind", None) in ("vertex", "face"):
            colours = np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8)
        if not len(faces):
            faces = None  # a mesh file without faces: its vertices as points
    elif isinstance(model, tuple):
        positions = model[0]
        colours = model[1] if len(model) > 1 else None
        normals = model[2] if len(model) > 2 else None
    elif hasattr(model, "positions") or hasattr(model, "points"):
        positions = getattr(model, "positions", None)
        if positions is None:
            positions = model.points
        normals = getattr(model, "normals", None)
        colours = getattr(model, "colors", None)
    elif isinstance(model, np.ndarray) or isinstance(model, list):
        positions = model
    else:
        raise TypeError(f"a view takes a trimesh.Trimesh, an (N, 3) point array or (points, colours), "
                        f"got {type(model).__name__}.")
    positions = np.asarray(positions, np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or not len(positions):
        raise ValueError(f"a view's points must be a non-empty (N, 3) array, got shape {positions.shape}.")
    if not np.isfinite(positions).all():
        raise ValueError("a view's points hold NaN or inf.")
    for name, a in (("colours", colours), ("normals", normals)):
        if a is not None and np.shape(a) != positions.shape:
            raise ValueError(f"a view's {name} must be (N, 3) like its points {positions.shape}, got {np.shape(a)}.")
    if colours is not None:
        colours = np.asarray(colours)
        if colours.dtype != np.uint8:
            colours = np.clip(np.round(colours), 0, 255).astype(np.uint8)
    original = (len(positions), 0 if faces is None else len(faces))
    note = ""
    if faces is not None:
        if len(faces) > max_triangles:
            positions, faces, colours = decimate_mesh(positions, faces, colours, max_triangles)
            note = (f"decimated for viewing: {original[1]:,} triangles shown as {len(faces):,} (vertex clustering); "
                    "the written file holds the full result")
        normals = _vertex_normals(positions, faces)
    elif len(positions) > max_triangles:
        keep = np.linspace(0, len(positions) - 1, max_triangles).round().astype(np.int64)
        positions = positions[keep]
        colours = None if colours is None else colours[keep]
        normals = None if normals is None else np.asarray(normals)[keep]
        note = (f"decimated for viewing: {original[0]:,} points shown as {len(positions):,} (an even subsample); "
                "the written file holds the full result")
    if normals is not None:
        normals = np.asarray(normals, np.float64)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(length > 0, normals / np.maximum(length, 1e-300), [0.0, 0.0, 1.0]).astype(np.float32)
    return ViewModel(positions.astype(np.float32), None if faces is None else faces.astype(np.uint32),
                     normals, colours, note, original)


def _point_spacing(points: np.ndarray) -> float:
    """The median distance from a point to its nearest neighbour, on up to 4,000 points."""
    from scipy.spatial import cKDTree

    step = max(1, len(points) // 4000)
    sample = points[::step].astype(np.float64)
    if len(sample) < 2:
        return float(np.ptp(points, axis=0).max() or 1.0) / 100
    d, _ = cKDTree(points.astype(np.float64)).query(sample, k=2)
    spacing = float(np.median(d[:, 1]))
    return spacing * np.sqrt(step) if spacing > 0 else float(np.ptp(points, axis=0).max() or 1.0) / 100


def _pack(models: Sequence[ViewModel]) -> tuple[bytes, list[dict]]:
    """One binary block for every model and a header per model: each buffer's byte
    offset and length in the block (4-byte aligned)."""
    blob = bytearray()
    headers = []

    def add(array: np.ndarray) -> list[int]:
        while len(blob) % 4:
            blob.append(0)
        data = np.ascontiguousarray(array).tobytes()
        offset = len(blob)
        blob.extend(data)
        return [offset, len(data)]

    for m in models:
        lo, hi = m.positions.min(0).astype(np.float64), m.positions.max(0).astype(np.float64)
        header = {"kind": m.kind, "count": int(len(m.positions)),
                  "triangles": 0 if m.faces is None else int(len(m.faces)),
                  "low": lo.tolist(), "high": hi.tolist(), "note": m.note, "original": list(m.original),
                  "positions": add(m.positions.astype("<f4"))}
        if m.normals is not None:
            header["normals"] = add(np.clip(np.round(m.normals * 127), -127, 127).astype(np.int8))
        if m.colours is not None:
            header["colours"] = add(m.colours.astype(np.uint8))
        if m.faces is not None:
            header["indices"] = add(m.faces.astype("<u4"))
        else:
            header["spacing"] = _point_spacing(m.positions)
        headers.append(header)
    return bytes(blob), headers


def decode_payload(page: str) -> list[dict]:
    """The models a page written by :func:`write_viewer` holds, read back (for tests and
    tools): per model its header with ``positions`` (N, 3) float32, ``indices`` (M, 3)
    uint32 or None, ``colours`` (N, 3) uint8 or None, ``normals`` (N, 3) int8 or None."""
    import re

    head = re.search(r'<script type="application/json" id="gs-header">(.*?)</script>', page, re.S)
    data = re.search(r'<script type="application/octet-stream" id="gs-data">(.*?)</script>', page, re.S)
    if head is None or data is None:
        raise ValueError("not a geosynth viewer page: no gs-header / gs-data block.")
    blob = base64.b64decode("".join(data.group(1).split()))
    out = []
    for h in json.loads(head.group(1))["models"]:
        model = dict(h)
        for key, dtype in (("positions", "<f4"), ("normals", "i1"), ("colours", "u1"), ("indices", "<u4")):
            if key in h:
                off, length = h[key]
                model[key] = np.frombuffer(blob[off:off + length], dtype).reshape(-1, 3)
            else:
                model[key] = None
        out.append(model)
    return out


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:16px;color:#222;background:#fafafa}
h1{font-size:18px;margin:0 0 8px 0;font-weight:600}
.views{display:flex;gap:12px;flex-wrap:wrap}
.view{flex:1 1 420px;min-width:300px;background:#fff;border:1px solid #ccc;border-radius:4px;padding:6px}
.view .label{font-weight:600;font-size:14px;margin:2px 4px 6px 4px}
.view .info{font-size:12px;color:#555;margin:4px}
.view .note{font-size:12px;color:#a44;margin:4px}
canvas{width:100%;height:auto;aspect-ratio:4/3;display:block;cursor:grab;background:#fff;touch-action:none}
canvas:active{cursor:grabbing}
.controls{margin:10px 2px;font-size:13px;color:#333}
.controls .hint{color:#666;margin-left:16px}
pre{background:#fff;border:1px solid #ddd;border-radius:4px;padding:8px;font-size:12px;white-space:pre-wrap;
word-break:break-word;margin:6px 0}
h2{font-size:14px;margin:14px 0 2px 2px}
.error{color:#b00;font-weight:600}
"""

# The viewer, written for this page: one WebGL context per canvas, a turntable camera
# (azimuth about +z, elevation, distance) looking at the model's box centre, drawn again
# only when something changed.
_JS = r"""
(function(){
"use strict";
var T = window.__geosynthTest = {ready:false, error:null, openMs:null, frames:[], views:0, marks:{script:performance.now()}};
var LIGHT = [-0.45, 0.65, 0.62], FILL = [0.6, -0.25, 0.5];  // camera space (z toward the viewer)
var FOV = 30 * Math.PI / 180;
function norm3(v){var l=Math.hypot(v[0],v[1],v[2]);return [v[0]/l,v[1]/l,v[2]/l];}
LIGHT = norm3(LIGHT); FILL = norm3(FILL);
var HALF = norm3([LIGHT[0], LIGHT[1], LIGHT[2] + 1]);
var VS = [
"attribute vec3 aPos; attribute vec3 aNrm; attribute vec3 aCol;",
"uniform mat4 uMV; uniform mat4 uP; uniform mat3 uR; uniform float uPointScale;",
"varying vec3 vN; varying vec3 vCol; varying float vZ;",
"void main(){ vec4 p = uMV * vec4(aPos, 1.0); gl_Position = uP * p;",
"  vN = uR * aNrm; vCol = aCol; vZ = -p.z;",
"  gl_PointSize = clamp(uPointScale / max(-p.z, 1e-6), 1.5, 96.0); }"].join("\n");
var FS = [
"precision mediump float;",
"uniform vec3 uL; uniform vec3 uF; uniform vec3 uH; uniform float uLit; uniform float uPoints;",
"varying vec3 vN; varying vec3 vCol; varying float vZ;",
"void main(){",
"  if (uPoints > 0.5) { vec2 d = gl_PointCoord - vec2(0.5); if (dot(d, d) > 0.25) discard; }",
"  vec3 n = normalize(vN);",
"  if (uPoints > 0.5) { if (n.z < 0.0) n = -n; } else if (!gl_FrontFacing) n = -n;",
"  float diff = 0.18 + 0.72 * max(dot(n, uL), 0.0) + 0.22 * max(dot(n, uF), 0.0);",
"  float spec = 0.2 * pow(max(dot(n, uH), 0.0), 40.0);",
"  vec3 c = uLit > 0.5 ? vCol * diff + vec3(spec) : vCol * 0.95;",
"  gl_FragColor = vec4(min(c, vec3(1.0)), 1.0); }"].join("\n");

function b64bytes(text){
  var bin = atob(text), n = bin.length, out = new Uint8Array(n);
  for (var i = 0; i < n; i++) out[i] = bin.charCodeAt(i);
  return out;
}
function perspective(aspect, near, far){
  var f = 1 / Math.tan(FOV / 2), nf = 1 / (near - far);
  return new Float32Array([f/aspect,0,0,0, 0,f,0,0, 0,0,(far+near)*nf,-1, 0,0,2*far*near*nf,0]);
}
function compile(gl, type, src){
  var s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(s));
  return s;
}

function View(index, canvas, model, bytes){
  this.index = index; this.canvas = canvas; this.model = model;
  var lo = model.low, hi = model.high;
  this.centre = [(lo[0]+hi[0])/2, (lo[1]+hi[1])/2, (lo[2]+hi[2])/2];
  this.radius = Math.max(Math.hypot(hi[0]-lo[0], hi[1]-lo[1], hi[2]-lo[2]) / 2, 1e-9);
  this.reset();
  var gl = canvas.getContext("webgl", {antialias:true, preserveDrawingBuffer:true});
  if (!gl) throw new Error("WebGL is not available in this browser");
  this.gl = gl;
  if (model.indices && !gl.getExtension("OES_element_index_uint")) throw new Error("WebGL lacks 32-bit indices");
  var prog = gl.createProgram();
  gl.attachShader(prog, compile(gl, gl.VERTEX_SHADER, VS));
  gl.attachShader(prog, compile(gl, gl.FRAGMENT_SHADER, FS));
  gl.bindAttribLocation(prog, 0, "aPos"); gl.bindAttribLocation(prog, 1, "aNrm"); gl.bindAttribLocation(prog, 2, "aCol");
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("program: " + gl.getProgramInfoLog(prog));
  gl.useProgram(prog); this.prog = prog;
  this.u = {};
  var names = ["uMV","uP","uR","uPointScale","uL","uF","uH","uLit","uPoints"];
  for (var i = 0; i < names.length; i++) this.u[names[i]] = gl.getUniformLocation(prog, names[i]);
  function buffer(target, range, Kind){
    var b = gl.createBuffer(); gl.bindBuffer(target, b);
    gl.bufferData(target, new Kind(bytes.buffer, range[0], range[1] / Kind.BYTES_PER_ELEMENT), gl.STATIC_DRAW);
    return b;
  }
  buffer(gl.ARRAY_BUFFER, model.positions, Float32Array);
  gl.enableVertexAttribArray(0); gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 0, 0);
  if (model.normals) {
    buffer(gl.ARRAY_BUFFER, model.normals, Int8Array);
    gl.enableVertexAttribArray(1); gl.vertexAttribPointer(1, 3, gl.BYTE, true, 0, 0);
  } else { gl.disableVertexAttribArray(1); gl.vertexAttrib3f(1, 0, 0, 1); }
  if (model.colours) {
    buffer(gl.ARRAY_BUFFER, model.colours, Uint8Array);
    gl.enableVertexAttribArray(2); gl.vertexAttribPointer(2, 3, gl.UNSIGNED_BYTE, true, 0, 0);
  } else {
    var c = model.kind === "mesh" ? MESH : POINT;
    gl.disableVertexAttribArray(2); gl.vertexAttrib3f(2, c[0]/255, c[1]/255, c[2]/255);
  }
  if (model.indices) buffer(gl.ELEMENT_ARRAY_BUFFER, model.indices, Uint32Array);
  gl.uniform3fv(this.u.uL, LIGHT); gl.uniform3fv(this.u.uF, FILL); gl.uniform3fv(this.u.uH, HALF);
  gl.uniform1f(this.u.uLit, model.kind === "mesh" || model.normals ? 1 : 0);
  gl.uniform1f(this.u.uPoints, model.kind === "points" ? 1 : 0);
  gl.enable(gl.DEPTH_TEST);
  gl.clearColor(1, 1, 1, 1);
  this.pending = false;
  T.frames[index] = 0;
}
View.prototype.reset = function(){ this.az = -60; this.el = 30; this.zoom = 1; };
View.prototype.camera = function(){ return {azimuth:this.az, elevation:this.el, zoom:this.zoom}; };
View.prototype.setCamera = function(c){ this.az = c.azimuth; this.el = c.elevation; this.zoom = c.zoom; this.request(); };
View.prototype.request = function(){
  if (this.pending) return;
  this.pending = true;
  var self = this;
  requestAnimationFrame(function(){ self.pending = false; self.draw(); });
};
View.prototype.draw = function(){
  var gl = this.gl, canvas = this.canvas;
  var ratio = window.devicePixelRatio || 1;
  var w = Math.max(1, Math.round(canvas.clientWidth * ratio)), h = Math.max(1, Math.round(canvas.clientHeight * ratio));
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  gl.viewport(0, 0, w, h);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  var aspect = w / h;
  // distance: the bounding sphere fills the narrower of the two fields of view
  var half = Math.min(FOV / 2, Math.atan(Math.tan(FOV / 2) * aspect));
  var dist = this.radius / Math.sin(half) * 0.95 / this.zoom;
  var az = this.az * Math.PI / 180, el = this.el * Math.PI / 180;
  var toEye = [Math.cos(el)*Math.cos(az), Math.cos(el)*Math.sin(az), Math.sin(el)];
  var fwd = [-toEye[0], -toEye[1], -toEye[2]];
  var up = Math.abs(toEye[2]) < 0.999 ? [0,0,1] : [0,1,0];
  var right = norm3([fwd[1]*up[2]-fwd[2]*up[1], fwd[2]*up[0]-fwd[0]*up[2], fwd[0]*up[1]-fwd[1]*up[0]]);
  var cup = [right[1]*fwd[2]-right[2]*fwd[1], right[2]*fwd[0]-right[0]*fwd[2], right[0]*fwd[1]-right[1]*fwd[0]];
  var c = this.centre, eye = [c[0]+toEye[0]*dist, c[1]+toEye[1]*dist, c[2]+toEye[2]*dist];
  var R = [right, cup, toEye];  // rows: camera x, y, z (z toward the viewer)
  var t = [0, 0, 0];
  for (var i = 0; i < 3; i++) t[i] = -(R[i][0]*eye[0] + R[i][1]*eye[1] + R[i][2]*eye[2]);
  var mv = new Float32Array([R[0][0],R[1][0],R[2][0],0, R[0][1],R[1][1],R[2][1],0, R[0][2],R[1][2],R[2][2],0, t[0],t[1],t[2],1]);
  var rot = new Float32Array([R[0][0],R[1][0],R[2][0], R[0][1],R[1][1],R[2][1], R[0][2],R[1][2],R[2][2]]);
  var near = Math.max(dist - this.radius * 1.5, dist * 1e-3), far = dist + this.radius * 1.5;
  gl.uniformMatrix4fv(this.u.uMV, false, mv);
  gl.uniformMatrix4fv(this.u.uP, false, perspective(aspect, near, far));
  gl.uniformMatrix3fv(this.u.uR, false, rot);
  var m = this.model;
  if (m.kind === "points") {
    var focal = h / 2 / Math.tan(FOV / 2);  // pixels per unit at distance 1
    gl.uniform1f(this.u.uPointScale, 2.4 * m.spacing * focal);
    gl.drawArrays(gl.POINTS, 0, m.count);
  } else {
    gl.drawElements(gl.TRIANGLES, m.triangles * 3, gl.UNSIGNED_INT, 0);
  }
  T.frames[this.index] = (T.frames[this.index] || 0) + 1;
  frameDone();
};
View.prototype.rotate = function(dx, dy){
  this.az -= dx * 0.4;
  this.el = Math.max(-89, Math.min(89, this.el + dy * 0.4));
  this.request();
};
View.prototype.zoomBy = function(f){ this.zoom = Math.max(0.05, Math.min(50, this.zoom * f)); this.request(); };

var views = [], linkBox = null;
function frameDone(){
  if (T.openMs === null && views.length && views.every(function(v){ return T.frames[v.index] > 0; })) {
    T.openMs = performance.now(); T.ready = true;
  }
}
function linked(source){
  if (!linkBox || !linkBox.checked) return;
  var c = source.camera();
  views.forEach(function(v){ if (v !== source) v.setCamera(c); });
}
function attach(v){
  var canvas = v.canvas, last = null;
  canvas.addEventListener("pointerdown", function(e){
    last = [e.clientX, e.clientY];
    if (canvas.setPointerCapture) try { canvas.setPointerCapture(e.pointerId); } catch (err) {}
    e.preventDefault();
  });
  canvas.addEventListener("pointermove", function(e){
    if (!last) return;
    v.rotate(e.clientX - last[0], e.clientY - last[1]); last = [e.clientX, e.clientY]; linked(v);
  });
  function end(){ last = null; }
  canvas.addEventListener("pointerup", end); canvas.addEventListener("pointercancel", end);
  canvas.addEventListener("wheel", function(e){
    e.preventDefault(); v.zoomBy(Math.exp(-e.deltaY * 0.0015)); linked(v);
  }, {passive:false});
  canvas.addEventListener("dblclick", function(){ v.reset(); v.request(); linked(v); });
}

var MESH = [0,0,0], POINT = [0,0,0];
function start(){
  try {
    var header = JSON.parse(document.getElementById("gs-header").textContent);
    MESH = header.meshColour; POINT = header.pointColour;
    var bytes = b64bytes(document.getElementById("gs-data").textContent);
    T.marks.decoded = performance.now();
    linkBox = document.getElementById("gs-link");
    var canvases = document.querySelectorAll("canvas.gs-view");
    T.views = canvases.length;
    for (var i = 0; i < canvases.length; i++) {
      var v = new View(i, canvases[i], header.models[i], bytes);
      views.push(v); attach(v);
    }
    if (header.sameScale) {  // frame the larger model in both: the same world scale side by side
      var largest = Math.max.apply(null, views.map(function(v){ return v.radius; }));
      views.forEach(function(v){ v.radius = largest; });
    }
    T.marks.uploaded = performance.now();
    linkBox.addEventListener("change", function(){ if (linkBox.checked && views.length) linked(views[0]); });
    window.addEventListener("resize", function(){ views.forEach(function(v){ v.request(); }); });
    views.forEach(function(v){ v.request(); });
  } catch (err) {
    T.error = String(err && err.message || err);
    var box = document.getElementById("gs-error");
    box.textContent = "The 3D views could not start: " + T.error + ". The pictures of this run are in its PNG.";
  }
}
T.rotate = function(dx, dy, index){ var v = views[index || 0]; v.rotate(dx, dy); linked(v); };
T.zoom = function(f, index){ var v = views[index || 0]; v.zoomBy(f); linked(v); };
T.camera = function(index){ return views[index || 0].camera(); };
T.link = function(on){ linkBox.checked = !!on; if (on) linked(views[0]); };
if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start); else start();
})();
"""


def _describe(m: ViewModel) -> str:
    if m.kind == "mesh":
        return f"mesh: {m.original[0]:,} vertices, {m.original[1]:,} triangles" + (", vertex colours" if m.colours is not None else "")
    return (f"point set: {m.original[0]:,} points" + (", normals" if m.normals is not None else ", no normals")
            + (", colours" if m.colours is not None else ""))


def viewer_html(left, right, *, labels: Sequence[str], quality_lines: Sequence[str], command: str,
                max_triangles: int = 200_000, link_cameras: bool = False, title: str | None = None,
                same_scale: bool = False) -> str:
    """The page :func:`write_viewer` writes, as text (nothing is written)."""
    if len(labels) != 2:
        raise ValueError(f"labels must name the two views (left, right), got {len(labels)}.")
    models = [as_view_model(left, max_triangles), as_view_model(right, max_triangles)]
    blob, headers = _pack(models)
    header = json.dumps({"models": headers, "meshColour": list(MESH_COLOUR), "pointColour": list(POINT_COLOUR),
                         "sameScale": bool(same_scale)},
                        separators=(",", ":")).replace("</", "<\\/")
    payload = base64.b64encode(blob).decode("ascii")
    e = html.escape
    title = title or f"geosynth: {labels[1]}"
    notes = [m.note for m in models if m.note]
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        # no request of any kind: no script, style, font, image or connection from anywhere
        '<meta http-equiv="Content-Security-Policy" content="default-src \'none\'; script-src \'unsafe-inline\'; '
        'style-src \'unsafe-inline\'; img-src data:">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{e(title)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>{e(title)}</h1>",
    ]
    if notes:
        parts.append('<p class="note" id="gs-decimated">' + "<br>".join(
            f"{e(label)}: {e(m.note)}." for m, label in zip(models, labels) if m.note) + "</p>")
    parts.append('<p class="error" id="gs-error"></p>')
    parts.append('<div class="views">')
    for i, (m, label) in enumerate(zip(models, labels)):
        parts.append(f'<div class="view"><div class="label">{e(label)}</div>'
                     f'<canvas class="gs-view" id="gs-view-{i}" width="640" height="480"></canvas>'
                     f'<div class="info">{e(_describe(m))}'
                     + (f' (shown decimated: {m.kind == "mesh" and int(len(m.faces)) or len(m.positions):,} '
                        f'{"triangles" if m.kind == "mesh" else "points"})' if m.note else "") + "</div></div>")
    parts.append("</div>")
    parts.append('<div class="controls"><label><input type="checkbox" id="gs-link"'
                 + (" checked" if link_cameras else "") + "> link cameras</label>"
                 '<span class="hint">drag: turn &middot; wheel: zoom &middot; double-click: reset</span></div>')
    parts.append("<h2>Quality</h2>")
    parts.append(f'<pre id="gs-quality">{e(chr(10).join(quality_lines)) or "(no quality numbers for this run)"}</pre>')
    parts.append("<h2>Command</h2>")
    parts.append(f'<pre id="gs-command">{e(command)}</pre>')
    parts.append(f'<script type="application/json" id="gs-header">{header}</script>')
    parts.append(f'<script type="application/octet-stream" id="gs-data">{payload}</script>')
    parts.append(f"<script>{_JS}</script>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_viewer(path: str | os.PathLike, left, right, *, labels: Sequence[str], quality_lines: Sequence[str],
                 command: str, max_triangles: int = 200_000, link_cameras: bool = False,
                 title: str | None = None, same_scale: bool = False,
                 inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Write the self-contained viewer page of ``left`` (the exemplar or capture) and
    ``right`` (the result), atomically.

    Args:
        path: the page, .html or .htm; never an input of the run.
        left, right: a ``trimesh.Trimesh`` (vertex colours shown when present), an (N, 3)
            point array, ``(points, colours[, normals])`` or a point set object
            (:func:`as_view_model`).
        labels: the two views' captions.
        quality_lines: the run's quality numbers, printed under the views.
        command: the command line that made the result, printed under them.
        max_triangles: larger models are decimated for viewing (the page says so).
        link_cameras: the "link cameras" box starts checked.
        title: the page's heading (default: "geosynth: " + the right label).
        same_scale: both views frame the larger model's bounding sphere, so that the two are
            drawn at the same world scale (an exemplar beside a larger synthesized piece);
            default: each view frames its own model.
        inputs: files the page must never replace.

    Returns:
        The path written.

    Raises:
        ValueError: a bad path (:func:`geosynth.io.files.check_output`), bad arrays.
        TypeError: a model of another kind.
    """
    out = check_output(path, inputs=inputs, suffixes=HTML_SUFFIXES, what="--html")
    text = viewer_html(left, right, labels=labels, quality_lines=quality_lines, command=command,
                       max_triangles=max_triangles, link_cameras=link_cameras, title=title, same_scale=same_scale)

    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)

    return atomic_write(out, write, inputs=inputs)


_INDEX_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:16px;color:#222;background:#fafafa}
h1{font-size:20px;margin:0 0 6px 0}
p{font-size:13px;color:#444;margin:4px 0 12px 0}
table{border-collapse:collapse;width:100%;background:#fff}
td,th{border:1px solid #ddd;padding:6px;vertical-align:top;font-size:13px;text-align:left}
th{background:#f0f0f0}
td.thumb{width:340px}
td.thumb img{max-width:330px;max-height:200px;display:block}
td.time{white-space:nowrap;text-align:right}
code{font-size:12px;word-break:break-word}
.failed{color:#b00;font-weight:600}
"""


def gallery_index_html(rows: Sequence[dict], *, title: str, note: str = "") -> str:
    """The gallery's index page, as text.

    Args:
        rows: one per run, in order: ``name``, ``command``, ``seconds``, ``summary`` (the
            quality line), ``error`` (None, or the one-line failure), ``page`` and
            ``picture`` (file names beside the index, or None when not written).
        title: the heading.
        note: a line under it (how the gallery was run, its total time).
    """
    e = html.escape
    ok = sum(1 for r in rows if not r.get("error"))
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f"<title>{e(title)}</title><style>{_INDEX_CSS}</style></head><body>",
           f"<h1>{e(title)}</h1>",
           f"<p>{e(note)} {ok} of {len(rows)} runs succeeded. Each picture opens the run's page "
           "(the models in 3D: drag to turn, wheel to zoom).</p>",
           '<table id="gallery"><tr><th>picture</th><th>run</th><th>time</th><th>quality</th></tr>']
    for r in rows:
        if r.get("error"):
            thumb = '<span class="failed">failed</span>'
            quality = f'<span class="failed">{e(r["error"])}</span>'
        else:
            img = (f'<img src="{e(r["picture"])}" alt="{e(r["name"])}" loading="lazy">' if r.get("picture")
                   else "(no picture)")
            thumb = f'<a href="{e(r["page"])}">{img}</a>' if r.get("page") else img
            quality = e(r.get("summary") or "(no quality numbers)")
        name = (f'<a href="{e(r["page"])}">{e(r["name"])}</a>' if r.get("page") and not r.get("error")
                else e(r["name"]))
        out.append(f'<tr class="entry" data-name="{e(r["name"])}" data-status="{"failed" if r.get("error") else "ok"}">'
                   f'<td class="thumb">{thumb}</td><td><b>{name}</b><br><code>{e(r["command"])}</code></td>'
                   f'<td class="time">{r["seconds"]:.1f} s</td><td>{quality}</td></tr>')
    out.append("</table></body></html>")
    return "\n".join(out) + "\n"


def write_gallery_index(path: str | os.PathLike, rows: Sequence[dict], *, title: str, note: str = "") -> Path:
    """Write :func:`gallery_index_html` to ``path`` (.html), atomically."""
    out = check_output(path, suffixes=HTML_SUFFIXES, what="the gallery's index")
    text = gallery_index_html(rows, title=title, note=note)

    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)

    return atomic_write(out, write)
