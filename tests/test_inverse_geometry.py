"""Geometry gradients (issue "Inverse problems", part 1): the scan's derivative with respect to a
mesh's vertex positions, through the echoes' ranges and incidence angles (plugins/integrators/paths/path_replay.py).

Closed-form checks on a flat mesh (no facet edge changes its normal jump): lifting the mesh by s
is the head sinking by s, and turning the mesh about an axis through the head is the head turning
the other way, path for path (the same rays, the same echoes); both also match finite differences.
"""
import os

import numpy as np
import pytest

from conftest import acoustic_xml, example, frame_matrix, scene_xml, sonar_xml

SPP = 1 << 14
SEED, SEED_GRAD = 3, 11
N_BINS, N_PINGS = 60, 3


def grid_ply(path, heights, half=4.0):
    """A height map as a PLY mesh: ``heights`` (n, n) at x, y in [-half, half], two triangles a cell
    (written by the seabed example's ``write_ply``)."""
    n = heights.shape[0]
    xs = np.linspace(-half, half, n)
    X, Y = np.meshgrid(xs, xs, indexing="xy")
    V = np.stack([X.ravel(), Y.ravel(), heights.ravel()], 1).astype(np.float32)
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            faces += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    example("recover_seabed").write_ply(path, V, np.asarray(faces, np.uint32))
    return V


def mesh_scene(mitsonar, path, face_normals=True):
    head = sonar_xml(frame_matrix((0.4, 0.0, -1.0), (0.0, 1.0, 0.0)), n_pings=N_PINGS, n_bins=N_BINS, range_min=1.0,
                     range_max=4.0, bearing_step=8.0, beamwidth_h=20.0, beamwidth_v=20.0)
    head = head.replace('type="sonar"', 'type="sonar" id="head"')
    shape = (f'<shape type="ply" id="seabed"><string name="filename" value="{path}"/>'
             f'<boolean name="face_normals" value="{"true" if face_normals else "false"}"/>'
             + acoustic_xml(0.5, 0.3, 10.0) + "</shape>")
    integrator = '<integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'
    return mitsonar.load_scene(scene_xml(head, shape, integrator=integrator))


def weights():
    return (np.tile(np.linspace(1.0, 2.0, N_BINS), (N_PINGS, 1)) * np.arange(1, N_PINGS + 1)[:, None]).ravel()


def derivative(sc, key, make, mode="backward"):
    """d(sum(weights * scan))/dv at v = 0 with the parameter ``key`` set to ``make(v)``."""
    import drjit as dr
    import mitsuba as mi

    p = mi.traverse(sc)
    x = mi.Float(0.0)
    dr.enable_grad(x)
    p[key] = make(x)
    p.update()
    loss = dr.sum(mi.render(sc, p, spp=SPP, seed=SEED, seed_grad=SEED_GRAD).array * mi.Float(weights()))
    if mode == "backward":
        dr.backward(loss)
        g = float(dr.grad(x)[0])
    else:
        dr.forward(x)
        g = float(dr.grad(loss)[0])
    p[key] = make(mi.Float(0.0))
    p.update()
    return g


def finite_difference(sc, key, make, h):
    import mitsuba as mi

    p = mi.traverse(sc)

    def f(v):
        p[key] = make(mi.Float(v))
        p.update()
        return float(np.asarray(mi.render(sc, spp=SPP, seed=SEED_GRAD)).ravel() @ weights())

    out = (f(h) - f(-h)) / (2 * h)
    p[key] = make(mi.Float(0.0))
    p.update()
    return out


@pytest.fixture(scope="module")
def flat(mitsonar_mod, tmp_path_factory):
    import mitsuba as mi

    path = os.path.join(tmp_path_factory.mktemp("mesh"), "flat.ply")
    V = grid_ply(path, np.full((9, 9), -2.0))
    sc = mesh_scene(mitsonar_mod, path)
    return sc, mi.Float(V.ravel()), V


def test_lifting_the_mesh_is_sinking_the_head(flat):
    import mitsuba as mi

    sc, V0, V = flat
    up = np.zeros_like(V)
    up[:, 2] = 1.0
    lift = lambda x: V0 + x * mi.Float(up.ravel())  # noqa: E731
    base = mi.Transform4f(mi.traverse(sc)["head.to_world"])
    sink = lambda x: mi.Transform4f().translate(mi.Vector3f(0.0, 0.0, -x)) @ base  # noqa: E731
    g_mesh = derivative(sc, "seabed.vertex_positions", lift)
    g_head = derivative(sc, "head.to_world", sink)
    assert g_mesh == pytest.approx(g_head, rel=1e-4)
    assert derivative(sc, "seabed.vertex_positions", lift, "forward") == pytest.approx(g_mesh, rel=1e-4)
    assert g_mesh == pytest.approx(finite_difference(sc, "seabed.vertex_positions", lift, 0.02), rel=0.03)


def test_turning_the_mesh_is_turning_the_head_back(flat):
    """A rotation of the mesh by a about world y through the head: the facet normal turns (the
    incidence angle, through the BSDF's diffuse and specular lobes) and the points move."""
    import mitsuba as mi

    sc, V0, V = flat
    turn = np.zeros_like(V)
    turn[:, 0], turn[:, 2] = V[:, 2], -V[:, 0]  # d/da of R_y(a) v at a = 0
    rot = lambda x: V0 + x * mi.Float(turn.ravel())  # noqa: E731
    base = mi.Transform4f(mi.traverse(sc)["head.to_world"])
    back = lambda x: mi.Transform4f().rotate(mi.Vector3f(0, 1, 0), -x * 180.0 / np.pi) @ base  # noqa: E731
    g_mesh = derivative(sc, "seabed.vertex_positions", rot)
    g_head = derivative(sc, "head.to_world", back)
    assert abs(g_mesh) > 0
    assert g_mesh == pytest.approx(g_head, rel=1e-3)
    assert g_mesh == pytest.approx(finite_difference(sc, "seabed.vertex_positions", rot, 0.02), rel=0.03)


def test_primal_is_unchanged_by_vertex_gradients(flat):
    import drjit as dr
    import mitsuba as mi

    sc, V0, V = flat
    plain = np.asarray(mi.render(sc, spp=4096, seed=SEED))
    p = mi.traverse(sc)
    dr.enable_grad(p["seabed.vertex_positions"])
    p.update()
    np.testing.assert_array_equal(np.asarray(mi.render(sc, p, spp=4096, seed=SEED)), plain)
    p["seabed.vertex_positions"] = V0
    p.update()


def test_vertex_normals_are_refused_in_one_line(mitsonar_mod, tmp_path):
    import drjit as dr
    import mitsuba as mi

    path = os.path.join(tmp_path, "smooth.ply")
    grid_ply(path, np.full((5, 5), -2.0))
    sc = mesh_scene(mitsonar_mod, path, face_normals=False)
    p = mi.traverse(sc)
    dr.enable_grad(p["seabed.vertex_positions"])
    p.update()
    img = mi.render(sc, p, spp=16)
    with pytest.raises(ValueError, match=r"sonar_tof: mesh 'seabed' has vertex normals; its vertex positions are "
                                         r"differentiated with face normals only"):
        dr.backward(dr.sum(img.array))
