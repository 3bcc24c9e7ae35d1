"""The seabed terrain generator (mitsonar/scenes/terrain.py): watertight meshes, seeded statistics,
reproducibility, PLY that Mitsuba loads, one-line refusals."""
import math
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT


def terrain(**kw):
    from mitsonar.scenes.terrain import Terrain

    args = dict(size=(12.0, 8.0), resolution=0.05, depth=-5.0, slope=(0.03, -0.02), ripple_wavelength=0.6,
                ripple_height=0.04, ripple_direction=30.0, roughness=0.02, correlation_length=0.5,
                rocks=6, rock_radius=(0.2, 0.5), seed=7)
    args.update(kw)
    return Terrain(**args)


def directed_edges(faces):
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def test_closed_terrain_is_watertight_and_open_one_has_only_its_outline_open():
    closed = terrain(closed=True)
    V, F = closed.mesh()
    e = directed_edges(F)
    # Watertight and consistently oriented: every directed edge once, and its reverse once.
    assert len(np.unique(e, axis=0)) == len(e)
    fwd = {tuple(x) for x in e.tolist()}
    assert all((b, a) in fwd for a, b in fwd)
    # Outward normals: the divergence theorem gives the volume between the surface and the bottom.
    v0, v1, v2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    volume = np.einsum("ij,ij->i", v0, np.cross(v1, v2)).sum() / 6
    ny, nx = closed.shape
    z = closed.z - closed.bottom
    prism = closed.resolution ** 2 * (z[:-1, :-1] + z[:-1, 1:] + z[1:, 1:] + z[1:, :-1]).sum() / 4
    assert volume == pytest.approx(prism, rel=1e-3)   # two triangles per cell against the bilinear cell
    # height() is the grid at its vertices and bilinear between them.
    assert closed.height(closed.x[3], closed.y[5]) == pytest.approx(closed.z[5, 3], abs=1e-12)
    mid = closed.height((closed.x[3] + closed.x[4]) / 2, closed.y[5])
    assert mid == pytest.approx((closed.z[5, 3] + closed.z[5, 4]) / 2, abs=1e-12)
    # Open: the surface alone, normals up, open only along its rectangular outline.
    V, F = terrain().mesh()
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert np.all(n[:, 2] > 0)
    e = directed_edges(F)
    keys, counts = np.unique(np.sort(e, 1), axis=0, return_counts=True)
    assert set(counts.tolist()) == {1, 2}
    assert (counts == 1).sum() == 2 * (nx - 1) + 2 * (ny - 1)
    border = keys[counts == 1]
    on_edge = lambda p: (np.isclose(p[:, 0], V[:, 0].min()) | np.isclose(p[:, 0], V[:, 0].max())  # noqa: E731
                         | np.isclose(p[:, 1], V[:, 1].min()) | np.isclose(p[:, 1], V[:, 1].max()))
    assert on_edge(V[border[:, 0]]).all() and on_edge(V[border[:, 1]]).all()


def test_heights_follow_the_requested_statistics():
    t = terrain(size=(12.0, 12.0))
    X, Y = np.meshgrid(t.x, t.y)
    # Slope and depth: a least-squares plane through all heights (ripples, roughness and rocks
    # are nearly zero-mean over 12 m, so 5 % of the gradients and 2 cm of depth).
    A = np.stack([np.ones(X.size), X.ravel(), Y.ravel()], 1)
    c = np.linalg.lstsq(A, t.z.ravel() - t.components["rocks"].ravel(), rcond=None)[0]
    assert c[0] == pytest.approx(-5.0, abs=0.02)
    assert c[1] == pytest.approx(0.03, rel=0.05) and c[2] == pytest.approx(-0.02, rel=0.05)
    # Ripples: the spectrum of the detrended heights peaks at wavenumber 1 / 0.6 m along 30 deg,
    # with amplitude 0.04 m (rms 0.04 / sqrt 2).
    rest = t.z - t.components["plane"] - t.components["rocks"]
    spec = np.abs(np.fft.fft2(rest))
    spec[0, 0] = 0
    j, i = np.unravel_index(np.argmax(spec), spec.shape)
    ky, kx = np.fft.fftfreq(t.shape[0], t.resolution)[j], np.fft.fftfreq(t.shape[1], t.resolution)[i]
    assert math.hypot(kx, ky) == pytest.approx(1 / 0.6, rel=0.03)          # one FFT bin: 1/12 m^-1
    assert abs(math.degrees(math.atan2(ky, kx)) % 180 - 30.0) < 3.0
    ripple = t.components["ripples"]
    assert np.sqrt(np.mean(ripple ** 2)) == pytest.approx(0.04 / math.sqrt(2), rel=0.02)
    assert np.abs(ripple).max() <= 0.04 + 1e-12
    # Roughness: zero mean, rms exactly as asked; its correlation at one correlation length
    # (gaussian spectrum exp(-(pi l k)^2): correlation exp(-(d / l)^2 / 2)) about exp(-1/2).
    rough = t.components["roughness"]
    assert abs(rough.mean()) < 1e-12 and np.sqrt(np.mean(rough ** 2)) == pytest.approx(0.02, rel=1e-9)
    lag = int(round(0.5 / t.resolution))
    corr = np.mean(rough[:, :-lag] * rough[:, lag:]) / 0.02 ** 2
    assert corr == pytest.approx(math.exp(-0.5), abs=0.1)
    # Rocks: as many as asked, radii in range, each rising 0.6 r above the bed at its centre.
    assert len(t.rock_radii) == 6 and np.all((t.rock_radii >= 0.2) & (t.rock_radii <= 0.5))
    assert t.components["rocks"].max() <= 0.6 * 0.5 + 1e-12
    for (cx, cy), r in zip(t.rock_centres, t.rock_radii):
        top = t.components["rocks"][np.argmin(np.abs(t.y - cy)), np.argmin(np.abs(t.x - cx))]
        assert top == pytest.approx(0.6 * r, abs=0.6 * r * 0.1)


def test_same_seed_same_mesh_and_file_other_seed_other_mesh(tmp_path):
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    terrain(closed=True).write_ply(a)
    terrain(closed=True).write_ply(b)
    assert a.read_bytes() == b.read_bytes()
    assert not np.array_equal(terrain(seed=8).z, terrain().z)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary left


def test_ply_loads_in_a_scene_and_is_its_ground_truth(mitsonar_mod, tmp_path):
    from mitsonar.scenes.terrain import read_ply

    t = terrain(resolution=0.1, closed=True)
    path = tmp_path / "seabed.ply"
    t.write_ply(path)
    V, F = t.mesh()
    RV, RF = read_ply(path)
    np.testing.assert_allclose(RV, V, atol=1e-5)
    np.testing.assert_array_equal(RF, F)
    scene = mitsonar_mod.load_scene(
        '<scene version="3.0.0"><integrator type="sonar_tof"/><sensor type="sonar"/>'
        f'<shape type="ply"><string name="filename" value="{path}"/>'
        '<bsdf type="acoustic"><string name="preset" value="seabed_sand"/></bsdf></shape></scene>')
    MV, MF = mitsonar_mod.scene_mesh(scene)
    assert MF.shape == F.shape
    np.testing.assert_allclose(MV, V, atol=1e-5)   # float32 in the file
    np.testing.assert_array_equal(MF, F)


@pytest.mark.parametrize("kw, message", [
    ({"size": (0.0, 5.0)}, "terrain 'size': 0.0 is not allowed (a number > 0)"),
    ({"size": (5.0, -1.0)}, "terrain 'size': -1.0 is not allowed (a number > 0)"),
    ({"resolution": 0.0}, "terrain 'resolution': 0.0 is not allowed (a number > 0)"),
    ({"resolution": 20.0}, "terrain 'resolution': 20.0 is not allowed (a grid spacing > 0 and <= the smaller side, 8 m)"),
    ({"resolution": 0.003}, "terrain 'resolution': 0.003 is not allowed (a grid spacing >= about 0.00346 m for "
                            "a 12 x 8 m terrain: at most 8000000 vertices)"),
    ({"rocks": -1}, "terrain 'rocks': -1 is not allowed (a count >= 0)"),
    ({"ripple_wavelength": 0}, "terrain 'ripple_wavelength': 0 is not allowed (a number > 0)"),
])
def test_bad_input_is_one_line_naming_the_parameter(kw, message):
    with pytest.raises(ValueError) as err:
        terrain(**kw)
    assert str(err.value) == message


def test_command_writes_a_ply_and_refuses_bad_input_in_one_line(tmp_path):
    out = tmp_path / "t.ply"
    run = lambda *a: subprocess.run([sys.executable, "-m", "mitsonar.scenes.terrain", str(out), *a],  # noqa: E731
                                    capture_output=True, text=True, cwd=ROOT)
    ok = run("--size", "4", "3", "--resolution", "0.1", "--ripple-height", "0.05", "--seed", "2")
    assert ok.returncode == 0 and "1271 vertices, 2400 triangles" in ok.stdout
    assert out.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    bad = run("--resolution", "-1")
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr == "mitsonar.scenes.terrain: terrain 'resolution': -1.0 is not allowed (a number > 0)\n"
