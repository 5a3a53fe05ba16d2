"""Which file? The textured mesh as STL, PLY, OBJ, GLB or 3MF by the extension (issue 34, item 3),
colours in PLY, GLB and 3MF (and OBJ's vertex colours), written atomically
(:func:`geosynth.io.files.atomic_write`) and never over an input (:func:`geosynth.io.files.check_output`).

trimesh writes STL, PLY, OBJ and GLB. Its 3MF writer needs lxml, which geosynth does not
depend on, so 3MF is written here with the standard library: the 3MF Core Specification's
package (``[Content_Types].xml``, ``_rels/.rels``, ``3D/3dmodel.model``) with the vertex colours as
a Materials Extension ``m:colorgroup`` and per-corner colour indices (p1, p2, p3) on each triangle.
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["RELIEF_SUFFIXES", "read_3mf", "write_relief"]

RELIEF_SUFFIXES = (".stl", ".ply", ".obj", ".glb", ".3mf")

_CONTENT_TYPES = ('<?xml version="1.0" encoding="UTF-8"?>\n'
                  '<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">'
                  '<Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>'
                  '<Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>'
                  '</Types>')
_RELS = ('<?xml version="1.0" encoding="UTF-8"?>\n'
         '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">'
         '<Relationship Target="/3D/3dmodel.model" Id="rel0" '
         'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')


def _model_3mf(vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray | None) -> bytes:
    out = io.StringIO()
    out.write('<?xml version="1.0" encoding="UTF-8"?>\n<model unit="millimeter" xml:lang="en-US" '
              'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02" '
              'xmlns:m="http://schemas.microsoft.com/3dmanufacturing/material/2015/02">\n<resources>\n')
    if colours is not None:
        out.write('<m:colorgroup id="1">\n')
        out.write("".join(f'<m:color color="#{r:02X}{g:02X}{b:02X}FF"/>\n' for r, g, b in colours.tolist()))
        out.write("</m:colorgroup>\n")
    pid = ' pid="1" pindex="0"' if colours is not None else ""
    out.write(f'<object id="2" type="model"{pid}>\n<mesh>\n<vertices>\n')
    out.write("".join(f'<vertex x="{x!r}" y="{y!r}" z="{z!r}"/>\n' for x, y, z in vertices.tolist()))
    out.write("</vertices>\n<triangles>\n")
    if colours is not None:
        out.write("".join(f'<triangle v1="{a}" v2="{b}" v3="{c}" pid="1" p1="{a}" p2="{b}" p3="{c}"/>\n'
                          for a, b, c in faces.tolist()))
    else:
        out.write("".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>\n' for a, b, c in faces.tolist()))
    out.write('</triangles>\n</mesh>\n</object>\n</resources>\n<build><item objectid="2"/></build>\n</model>\n')
    return out.getvalue().encode("utf-8")


def _bytes_3mf(vertices, faces, colours) -> bytes:
    buf = io.BytesIO()
    # fixed timestamps: the same mesh gives the same bytes
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for name, data in (("[Content_Types].xml", _CONTENT_TYPES.encode()), ("_rels/.rels", _RELS.encode()),
                           ("3D/3dmodel.model", _model_3mf(vertices, faces, colours))):
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, data)
    return buf.getvalue()


def read_3mf(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(vertices (V, 3) float64, faces (F, 3) int64, colours (V, 3) uint8 or None) of a 3MF file
    written by :func:`write_relief` (one object; colours per vertex from the triangles' p1..p3)."""
    import xml.etree.ElementTree as ET

    core = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"
    mat = "{http://schemas.microsoft.com/3dmanufacturing/material/2015/02}"
    with zipfile.ZipFile(path) as z:
        root = ET.fromstring(z.read("3D/3dmodel.model"))
    verts = np.array([[float(e.get(k)) for k in "xyz"] for e in root.iter(core + "vertex")], np.float64)
    tris = list(root.iter(core + "triangle"))
    faces = np.array([[int(e.get(k)) for k in ("v1", "v2", "v3")] for e in tris], np.int64)
    group = [e.get("color") for e in root.iter(mat + "color")]
    colours = None
    if group:
        colours = np.zeros((len(verts), 3), np.uint8)
        for e in tris:
            for vk, pk in (("v1", "p1"), ("v2", "p2"), ("v3", "p3")):
                c = group[int(e.get(pk))]
                colours[int(e.get(vk))] = [int(c[i:i + 2], 16) for i in (1, 3, 5)]
    return verts, faces, colours


def write_relief(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray | None = None,
                 *, inputs=()) -> Path:
    """Write the textured mesh, atomically, in the format its extension names.

    Args:
        path: .stl, .ply, .obj, .glb or .3mf (any case).
        vertices: (V, 3) float64 positions; faces: (F, 3) int triangles.
        colours: (V, 3) uint8 vertex colours or None (STL drops them).
        inputs: the run's input files: writing over one is refused.

    Returns:
        The path written.

    Raises:
        ValueError: another extension, an input as the output, NaN/inf vertices (before any file
        is created).
    """
    import trimesh

    from geosynth.io.files import atomic_write, check_finite_output, check_output

    out = check_output(path, inputs=inputs, suffixes=RELIEF_SUFFIXES, what="output")
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    check_finite_output(out, "vertex", vertex=v)
    kind = out.suffix.lower()[1:]
    if kind == "3mf":
        data = _bytes_3mf(v, f, colours)
    else:
        mesh = trimesh.Trimesh(v, f, process=False, validate=False)
        if colours is not None and kind != "stl":
            rgba = np.concatenate([colours, np.full((len(v), 1), 255, np.uint8)], 1)
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=rgba)
        data = mesh.export(file_type=kind)
        if isinstance(data, str):
            data = data.encode("utf-8")
    return atomic_write(out, lambda tmp: Path(tmp).write_bytes(data), inputs=tuple(inputs))
