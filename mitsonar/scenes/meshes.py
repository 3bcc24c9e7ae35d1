"""Meshes a robot's world is made of (STL, OBJ, Collada DAE, glTF/GLB, PLY) as triangles in
metres, Z up: what `mitsonar.scenes.sdf` writes as PLY for Mitsuba.

    from mitsonar.scenes.meshes import load_mesh
    vertices, faces = load_mesh("hull.dae")        # (V, 3) float64 metres Z-up, (F, 3) int64

The files are read by trimesh (pycollada for DAE), a maintained reader of all four formats that
keeps a file's node transforms (its scene graph is flattened into one mesh). Units and axes, as
Gazebo takes them (Gazebo's world is Z up, in metres):

* STL, OBJ and PLY hold bare numbers: metres, Z up, times ``scale`` (``--scale`` for a model
  drawn in millimetres: 0.001);
* Collada says its unit (``<asset><unit meter="...">``) and up axis (``<up_axis>``, Y_UP when
  absent, as the Collada 1.4 specification says); both are applied (trimesh reads neither);
* glTF is Y up in metres by its specification; it is turned Z up as Blender and Gazebo do,
  ``(x, y, z) -> (x, -z, y)``.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from mitsonar._checks import first_line

FORMATS = (".stl", ".obj", ".dae", ".gltf", ".glb", ".ply")
#: Y up -> Z up (a +90 deg turn about x) and X up -> Z up (-90 deg about y).
Y_UP = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
X_UP = np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])


class MeshError(ValueError):
    """A mesh file that cannot be used: one line naming it."""


def _trimesh(path):
    try:
        import trimesh
    except ImportError:
        raise MeshError(f"{path}: reading meshes needs trimesh: pip install 'mitsonar[world]'") from None
    return trimesh


def collada_units(path):
    """``(metres per unit, axis matrix to Z up)`` of a Collada file's ``<asset>``."""
    meter, up = 1.0, "Y_UP"
    try:
        for _, el in ET.iterparse(path, events=("end",)):
            tag = el.tag.rsplit("}", 1)[-1]
            if tag == "unit" and el.get("meter"):
                meter = float(el.get("meter"))
            elif tag == "up_axis" and el.text:
                up = el.text.strip().upper()
            elif tag == "asset":
                break
    except (ET.ParseError, ValueError) as exc:
        raise MeshError(f"{path}: not a readable Collada file ({exc})") from None
    axes = {"Y_UP": Y_UP, "Z_UP": np.eye(3), "X_UP": X_UP}
    if up not in axes:
        raise MeshError(f"{path}: <up_axis> {up!r} is not allowed (X_UP, Y_UP or Z_UP)")
    return meter, axes[up]


def load_mesh(path, scale=1.0):
    """``(vertices (V, 3) float64, faces (F, 3) int64)`` of a mesh file in metres, Z up (see the
    module docstring); ``scale`` multiplies STL, OBJ and PLY coordinates."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise MeshError(f"{path}: unknown mesh format {ext or '(none)'!r} (allowed: {', '.join(FORMATS)})")
    if not os.path.isfile(path):
        raise MeshError(f"{path}: no such mesh file")
    trimesh = _trimesh(path)
    if ext == ".dae":
        try:
            import collada  # noqa: F401
        except ImportError:
            raise MeshError(f"{path}: reading Collada needs pycollada: pip install 'mitsonar[world]'") from None
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh and its readers raise many kinds
        raise MeshError(f"{path}: not a readable {ext[1:].upper()} mesh ({first_line(exc)})") from None
    vertices = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), np.float64)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), np.int64)
    if len(faces) == 0:
        raise MeshError(f"{path}: holds no triangles")
    if ext == ".dae":
        meter, axes = collada_units(path)
        vertices = meter * vertices @ axes.T
    elif ext in (".gltf", ".glb"):
        vertices = vertices @ Y_UP.T
    else:
        vertices = float(scale) * vertices
    return vertices, faces
