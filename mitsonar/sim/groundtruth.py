"""Ground truth: a scene's surfaces as one triangle mesh, what maps are scored against."""
from __future__ import annotations

import numpy as np

from mitsonar.sim.scene import SceneError


def _sphere_mesh(n_lat=24, n_lon=48):
    lat = np.linspace(0, np.pi, n_lat + 1)
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    verts = [[0, 0, 1]]
    for t in lat[1:-1]:
        for p in lon:
            verts.append([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
    verts.append([0, 0, -1])
    faces = []
    for j in range(n_lon):
        faces.append([0, 1 + j, 1 + (j + 1) % n_lon])
    for i in range(n_lat - 2):
        a, b = 1 + i * n_lon, 1 + (i + 1) * n_lon
        for j in range(n_lon):
            j2 = (j + 1) % n_lon
            faces += [[a + j, b + j, b + j2], [a + j, b + j2, a + j2]]
    last = len(verts) - 1
    base = 1 + (n_lat - 2) * n_lon
    for j in range(n_lon):
        faces.append([base + j, last, base + (j + 1) % n_lon])
    return np.array(verts, float), np.array(faces, np.int64)


def _cylinder_mesh(n=64):
    """The open unit cylinder of Mitsuba's ``cylinder`` shape (radius 1, z from 0 to 1)."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t), np.zeros(n)], 1)
    v = np.concatenate([ring, ring + [0.0, 0.0, 1.0]])
    j = np.arange(n)
    k = (j + 1) % n
    f = np.concatenate([np.stack([j, k, n + k], 1), np.stack([j, n + k, n + j], 1)])
    return v, f


def _disk_mesh(n=64):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = np.concatenate([[[0, 0, 0]], np.stack([np.cos(t), np.sin(t), np.zeros(n)], 1)])
    f = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    return v, f


def scene_mesh(scene):
    """The scene's surfaces as one triangle mesh ``(vertices (V, 3) float64, faces (F, 3) int64)``.

    Meshes are taken as they are; rectangles, disks, spheres and (open) cylinders are triangulated (spheres with
    ~2300 triangles). This is the ground truth maps are scored against.
    """
    import mitsuba as mi

    verts, faces, offset = [], [], 0
    for shape in scene.shapes():
        name = shape.class_name() if hasattr(shape, "class_name") else type(shape).__name__
        if isinstance(shape, mi.Mesh):
            v = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
            f = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        else:
            params = mi.traverse(shape)
            key = next((k for k in params.keys() if k.endswith("to_world")), None)
            if key is None:
                raise SceneError(f"scene_mesh: cannot triangulate shape {shape.id()!r} ({name})")
            m = np.array(params[key].matrix, dtype=np.float64).reshape(4, 4)
            if name == "Rectangle":
                local = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
                lf = np.array([[0, 1, 2], [0, 2, 3]])
            elif name == "Sphere":
                local, lf = _sphere_mesh()
            elif name == "Disk":
                local, lf = _disk_mesh()
            elif name == "Cylinder":
                local, lf = _cylinder_mesh()
            else:
                raise SceneError(f"scene_mesh: cannot triangulate shape {shape.id()!r} of type {name}; "
                                 "use rectangle, disk, sphere, cylinder or a mesh")
            v = local @ m[:3, :3].T + m[:3, 3]
            f = lf
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(verts), np.concatenate(faces)
