"""Triangle meshes: iso-surfaces of a sampled field (marching tetrahedra) and PLY / OBJ files."""
from __future__ import annotations

import os

import numpy as np

# cube corners (i, j, k offsets) and the 6 tetrahedra around the 0-6 diagonal
_CORNERS = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)])
_TETS = np.array([(0, 5, 1, 6), (0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6)])


def marching_tetrahedra(values: np.ndarray, axes, level: float):
    """Iso-surface ``values = level`` of a field sampled on the grid ``axes`` (3 1-D arrays).

    Returns (vertices (V, 3) float64, faces (F, 3) int64), vertices shared between faces, every
    face oriented with its normal towards lower values (out of the region above ``level``).
    """
    v = np.asarray(values, dtype=np.float64)
    nx, ny, nz = v.shape
    if min(nx, ny, nz) < 2:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    ax = [np.asarray(a, dtype=np.float64) for a in axes]
    above = v > level
    # cubes whose corners straddle the level
    c_any = np.zeros((nx - 1, ny - 1, nz - 1), dtype=bool)
    c_all = np.ones((nx - 1, ny - 1, nz - 1), dtype=bool)
    for di, dj, dk in _CORNERS:
        a = above[di:nx - 1 + di, dj:ny - 1 + dj, dk:nz - 1 + dk]
        c_any |= a
        c_all &= a
    ci, cj, ck = np.nonzero(c_any & ~c_all)
    if len(ci) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    # global node ids of the 4 corners of every tetrahedron of every straddling cube
    corner_ids = np.stack([((ci + di) * ny + (cj + dj)) * nz + (ck + dk) for di, dj, dk in _CORNERS], axis=1)
    tet_ids = corner_ids[:, _TETS].reshape(-1, 4)  # (6C, 4)
    flat = v.ravel()
    tv = flat[tet_ids]
    inside = tv > level
    n_in = inside.sum(axis=1)
    sel = (n_in > 0) & (n_in < 4)
    tet_ids, tv, inside, n_in = tet_ids[sel], tv[sel], inside[sel], n_in[sel]
    order = np.argsort(~inside, axis=1, kind="stable")  # inside corners first
    ids = np.take_along_axis(tet_ids, order, axis=1)

    tris = []  # list of (T, 3, 2) edge endpoints
    m1 = n_in == 1
    if m1.any():
        a = ids[m1]
        tris.append(np.stack([np.stack([a[:, 0], a[:, k]], axis=1) for k in (1, 2, 3)], axis=1))
    m3 = n_in == 3
    if m3.any():
        a = ids[m3]
        tris.append(np.stack([np.stack([a[:, 3], a[:, k]], axis=1) for k in (0, 1, 2)], axis=1))
    m2 = n_in == 2
    if m2.any():
        a = ids[m2]
        e_ac = np.stack([a[:, 0], a[:, 2]], axis=1)
        e_ad = np.stack([a[:, 0], a[:, 3]], axis=1)
        e_bd = np.stack([a[:, 1], a[:, 3]], axis=1)
        e_bc = np.stack([a[:, 1], a[:, 2]], axis=1)
        tris.append(np.stack([e_ac, e_ad, e_bd], axis=1))
        tris.append(np.stack([e_ac, e_bd, e_bc], axis=1))
    edges = np.concatenate(tris)  # (T, 3, 2) node ids
    lo = np.minimum(edges[..., 0], edges[..., 1])
    hi = np.maximum(edges[..., 0], edges[..., 1])
    n_nodes = nx * ny * nz
    key = lo.astype(np.int64) * n_nodes + hi
    ukey, inv = np.unique(key.ravel(), return_inverse=True)
    faces = inv.reshape(-1, 3).astype(np.int64)
    e0, e1 = ukey // n_nodes, ukey % n_nodes

    def node_pos(ids_):
        k = ids_ % nz
        j = (ids_ // nz) % ny
        i = ids_ // (ny * nz)
        return np.stack([ax[0][i], ax[1][j], ax[2][k]], axis=1)

    f0, f1 = flat[e0], flat[e1]
    t = np.clip((level - f0) / np.where(f1 != f0, f1 - f0, 1.0), 0.0, 1.0)
    verts = node_pos(e0) + t[:, None] * (node_pos(e1) - node_pos(e0))
    # orient: normal towards lower values (against the field's rise across the face)
    p = verts[faces]
    nrm = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    up_dir = _field_rise(edges, flat, node_pos, level)
    flip = np.einsum("ij,ij->i", nrm, up_dir) > 0
    faces[flip] = faces[flip][:, ::-1]
    # drop degenerate faces (two corners interpolated onto the same point)
    good = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return verts, faces[good]


def _field_rise(edges, flat, node_pos, level):
    """Per face: direction from its edges' low-value ends to their high-value ends."""
    a, b = edges[..., 0].ravel(), edges[..., 1].ravel()
    pa, pb = node_pos(a), node_pos(b)
    va, vb = flat[a], flat[b]
    d = np.where((vb > va)[:, None], pb - pa, pa - pb)
    return d.reshape(-1, 3, 3).sum(axis=1)


def write_mesh(path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a triangle mesh as binary PLY (``.ply``) or Wavefront OBJ (``.obj``)."""
    # mitsonar writes its PLY files with mitsonar.geometry.ply; hilbertmap keeps this writer of its
    # own (the same binary_little_endian layout) because it must not import mitsonar.
    ext = os.path.splitext(str(path))[1].lower()
    V = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if ext == ".obj":
        with open(path, "w") as fh:
            fh.write("# hilbertmap surface\n")
            np.savetxt(fh, V, fmt="v %.6f %.6f %.6f")
            np.savetxt(fh, F + 1, fmt="f %d %d %d")
    elif ext == ".ply":
        header = ("ply\nformat binary_little_endian 1.0\ncomment hilbertmap surface\n"
                  f"element vertex {len(V)}\nproperty float x\nproperty float y\nproperty float z\n"
                  f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
        rec = np.zeros(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        rec["n"] = 3
        rec["i"] = F
        with open(path, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(V.astype("<f4").tobytes())
            fh.write(rec.tobytes())
    else:
        raise ValueError(f"hilbertmap: mesh files must end in .ply or .obj, not {path!r}")


def read_mesh(path):
    """Read a mesh written by :func:`write_mesh` (binary PLY of triangles, or OBJ)."""
    ext = os.path.splitext(str(path))[1].lower()
    if ext == ".obj":
        V, F = [], []
        with open(path) as fh:
            for line in fh:
                if line.startswith("v "):
                    V.append([float(x) for x in line.split()[1:4]])
                elif line.startswith("f "):
                    F.append([int(x.split("/")[0]) - 1 for x in line.split()[1:4]])
        return np.array(V, dtype=np.float64).reshape(-1, 3), np.array(F, dtype=np.int64).reshape(-1, 3)
    with open(path, "rb") as fh:
        raw = fh.read()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:end].decode("ascii").splitlines()
    nv = int(next(h for h in header if h.startswith("element vertex")).split()[-1])
    nf = int(next(h for h in header if h.startswith("element face")).split()[-1])
    V = np.frombuffer(raw, dtype="<f4", count=3 * nv, offset=end).reshape(nv, 3).astype(np.float64)
    rec = np.frombuffer(raw, dtype=[("n", "u1"), ("i", "<i4", (3,))], count=nf, offset=end + 12 * nv)
    return V, rec["i"].astype(np.int64)
