"""Binary little-endian PLY files (Turk 1994; the ``binary_little_endian 1.0`` format that Mitsuba,
MeshLab, CloudCompare and Open3D read): one ``vertex`` element of scalar properties, and optionally
one ``face`` element of triangles (``property list uchar int vertex_indices``).

The one writer and reader of mitsonar's PLY files: seabed meshes (`mitsonar.scenes.terrain`) and
bathymetric point clouds (`mitsonar.products.soundings`). Files are written under a temporary name and
renamed onto the path when complete (`mitsonar._files.replacing`).

Vertex properties are written as ``float``, ``double``, ``int`` or ``uchar`` only: the types every
common reader keeps (Open3D's point-cloud reader drops ``ushort``/``uint`` attributes; PCL and
CloudCompare map them inconsistently). An unsigned 16- or 32-bit field is written as ``int`` (its
values must fit in int32); `read_ply` still reads the ``ushort``/``uint`` of older files.
"""
from __future__ import annotations

import numpy as np

from mitsonar._files import replacing

#: numpy type (little-endian) -> PLY scalar type name, as written.
TYPES = {"<f4": "float", "<f8": "double", "|u1": "uchar", "<i4": "int"}
#: Types written as another (signed: what readers keep), their values checked to fit.
WIDENED = {"<u2": "<i4", "<u4": "<i4"}
#: Every type `read_ply` reads (files written before the unsigned fields became ``int``).
READ_TYPES = {**TYPES, "<u2": "ushort", "<u4": "uint"}
_FACE = np.dtype([("n", "u1"), ("i", "<i4", (3,))])


def write_ply(path, vertices, faces=None, comment=None) -> None:
    """Write ``vertices`` (a structured array whose fields, in order, are the vertex properties;
    types from `TYPES`, or uint16/uint32 written as ``int``: `WIDENED`) and optionally ``faces`` ((n, 3) vertex indices: triangles) to ``path``.
    ``comment``: one header comment line."""
    vertices = np.asarray(vertices)
    names = vertices.dtype.names or ()
    header = ["ply", "format binary_little_endian 1.0"]
    if comment:
        header.append(f"comment {comment}")
    header.append(f"element vertex {len(vertices)}")
    written = []
    for n in names:
        t = vertices.dtype.fields[n][0].newbyteorder("<").str
        if t in WIDENED:
            if len(vertices) and int(vertices[n].max()) > np.iinfo(np.int32).max:
                raise ValueError(f"ply: vertex property {n!r} holds {int(vertices[n].max())}, over the int32 "
                                 "range the file's 'int' type holds")
            t = WIDENED[t]
        if t not in TYPES:
            raise ValueError(f"ply: vertex property {n!r} of type {t} is not one of "
                             f"{', '.join(list(TYPES) + list(WIDENED))}")
        header.append(f"property {TYPES[t]} {n}")
        written.append((n, t))
    rows = None
    if faces is not None:
        rows = np.empty(len(faces), _FACE)
        rows["n"], rows["i"] = 3, faces
        header += [f"element face {len(rows)}", "property list uchar int vertex_indices"]
    header += ["end_header", ""]
    data = vertices.astype(written)
    with replacing(path) as tmp, open(tmp, "wb") as f:
        f.write("\n".join(header).encode("ascii"))
        f.write(data.tobytes())
        if rows is not None:
            f.write(rows.tobytes())


def read_ply(path):
    """Read back a PLY written by `write_ply`: ``(vertices, faces)``, ``vertices`` a structured
    array of the vertex properties, ``faces`` (n, 3) int64 or None without a face element."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").split("\n")
    back = {v: k for k, v in READ_TYPES.items()}
    n_vertices, n_faces, props, element = 0, None, [], None
    for ln in lines:
        words = ln.split()
        if ln.startswith("element vertex"):
            element, n_vertices = "vertex", int(words[-1])
        elif ln.startswith("element face"):
            element, n_faces = "face", int(words[-1])
        elif ln.startswith("property ") and element == "vertex":
            props.append((words[2], back[words[1]]))
    dt = np.dtype(props)
    vertices = np.frombuffer(data, dt, n_vertices, end).copy()
    if n_faces is None:
        return vertices, None
    rows = np.frombuffer(data, _FACE, n_faces, end + n_vertices * dt.itemsize)
    return vertices, rows["i"].astype(np.int64)
