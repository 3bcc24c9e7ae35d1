"""Analysis by synthesis for closed walls seen from inside (mitsonar.inverse.room)."""
from __future__ import annotations

import os
import tempfile

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOX = np.array([[5.0, -4.0], [5.0, 4.0], [-5.0, 4.0], [-5.0, -4.0]])  # scenes_xml/box.xml, counter-clockwise


def test_room_mesh_faces_the_water():
    from mitsonar.inverse.room import room_mesh

    V, F = room_mesh(BOX, -3.0, 14.0)
    assert V.shape == (4 * 4 + 4, 3) and F.shape == (4 * 2 + 2, 3)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = V[F].mean(axis=1)
    walls, floor = n[:8], n[8:]
    # every wall's normal points at the room's axis, horizontally; the floor's up
    inward = -c[:8, :2] / np.linalg.norm(c[:8, :2], axis=1, keepdims=True)
    assert np.allclose(walls[:, 2], 0, atol=1e-6)
    assert (np.einsum("ij,ij->i", walls[:, :2], inward) > 0.5).all()
    assert np.allclose(floor, [0, 0, 1], atol=1e-6)
    assert np.allclose(np.sort(np.unique(V[:, 2])), [-3.0, 14.0])


def test_polygon_from_points_finds_the_corners_that_a_rounded_cut_misses():
    """A rectangle's cut with its corners rounded by 0.3 m (as a map's ridge rounds them) and 1 cm
    noise: the fitted walls meet at the true corners."""
    from mitsonar.inverse.room import polygon_from_points

    rng = np.random.default_rng(0)
    r, X, Y = 0.3, 4.5, 3.5
    pts = []
    for t in np.linspace(0, 1, 400):  # the straight parts
        pts += [[-X + r + t * (2 * X - 2 * r), s * Y] for s in (-1, 1)]
        pts += [[s * X, -Y + r + t * (2 * Y - 2 * r)] for s in (-1, 1)]
    for cx, cy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):  # quarter circles inside each corner
        a = np.linspace(0, np.pi / 2, 40)
        pts += np.c_[cx * (X - r) + cx * r * np.cos(a), cy * (Y - r) + cy * r * np.sin(a)].tolist()
    P = np.asarray(pts) + rng.normal(0, 0.01, (len(pts), 2)) + [0.6, -0.4]
    C = polygon_from_points(P, (0.6, -0.4))
    assert len(C) == 4
    truth = np.array([[X, -Y], [X, Y], [-X, Y], [-X, -Y]]) + [0.6, -0.4]
    d = np.linalg.norm(C[:, None] - truth[None], axis=2).min(axis=1)
    assert d.max() < 0.02, C
    with pytest.raises(ValueError, match="polygon_from_points: points must be"):
        polygon_from_points(np.zeros((2, 2)), (0, 0))
    for bad in ((0.0,), (0.0, np.nan), [[0.0, 0.0]]):
        with pytest.raises(ValueError, match=r"^polygon_from_points: center must be a finite \(x, y\) or \(x, y, z\)"):
            polygon_from_points(P, bad)


def test_wall_points_lie_on_the_walls():
    from mitsonar.inverse.room import wall_points

    P = wall_points(BOX, -0.5, 0.5, 0.1)
    assert P.shape == ((2 * 80 + 2 * 100) * 11, 3)
    assert np.allclose(np.minimum(5 - np.abs(P[:, 0]), 4 - np.abs(P[:, 1])), 0, atol=1e-9)
    assert P[:, 2].min() == -0.5 and P[:, 2].max() == 0.5
    with pytest.raises(ValueError, match="counter-clockwise"):
        wall_points(BOX[::-1], -0.5, 0.5)


@pytest.fixture(scope="module")
def box_targets():
    import mitsonar
    from hilbertmap.testing import orthogonal_frames

    scene = mitsonar.load_scene(os.path.join(ROOT, "scenes_xml", "box.xml"))
    frames = orthogonal_frames()
    return frames, [mitsonar.render_scan(scene, spp=64, seed=j, pose=T, max_depth=1).intensity
                    for j, T in enumerate(frames)]


def _model(corners, floor, top=14.0):
    import mitsonar
    from mitsonar.inverse.driver import write_ply
    from mitsonar.inverse.room import room_mesh, room_xml

    with tempfile.TemporaryDirectory() as tmp:
        ply = os.path.join(tmp, "room.ply")
        write_ply(ply, *room_mesh(corners, floor, top))
        return mitsonar.load_scene(room_xml(ply))


def test_refine_room_moves_walls_03_m_off_onto_the_box(box_targets):
    """From walls 0.3 m inside the box and a floor 0.2 m high, the renderer's gradients bring the
    corners within 2 cm and the floor within 3 cm of the truth; the loss falls 10-fold."""
    from mitsonar.inverse.room import refine_room

    frames, targets = box_targets
    start = BOX * [(5 - 0.3) / 5, (4 - 0.3) / 4]
    res = refine_room(_model(start, -2.8), start, -2.8, frames, targets, top=14.0, spp=32, seed=0,
                      stages=((4.0, 20), (1.5, 20)))
    assert np.abs(res["corners"] - BOX).max() < 0.02, res["corners"]
    assert abs(res["floor"] + 3.0) < 0.03, res["floor"]
    assert res["loss_final"] < 0.1 * res["loss_start"]


def test_refine_room_is_deterministic_per_seed_and_refuses_bad_input(box_targets):
    from mitsonar.inverse.room import refine_room

    frames, targets = box_targets
    start = BOX * 0.95
    scene = _model(start, -2.9)
    run = [refine_room(scene, start, -2.9, frames, targets, top=14.0, spp=16, seed=s, stages=((4.0, 4),))
           for s in (3, 3, 4)]
    assert np.array_equal(run[0]["corners"], run[1]["corners"]) and run[0]["floor"] == run[1]["floor"]
    assert not np.array_equal(run[0]["corners"], run[2]["corners"])
    with pytest.raises(ValueError, match="one target per pose"):
        refine_room(scene, start, -2.9, frames, targets[:2], top=14.0)
    with pytest.raises(ValueError, match="counter-clockwise"):
        refine_room(scene, start[::-1], -2.9, frames, targets, top=14.0)
    with pytest.raises(ValueError, match="top must be above floor|below top"):
        refine_room(scene, start, 20.0, frames, targets, top=14.0)
    with pytest.raises(ValueError, match=r"^refine_room: targets\[1\] has shape \(10, 500\), the head 'head' renders "
                                         r"\(200, 500\) \(rows, bins\)$"):
        refine_room(scene, start, -2.9, frames, [targets[0], targets[1][:10]] + list(targets[2:]), top=14.0)
    with pytest.raises(ValueError, match="vertices, a room of 5 corners"):
        refine_room(scene, np.r_[start, [[5.0 * 0.95, -3.9]]][[0, 4, 1, 2, 3]], -2.9, frames, targets, top=14.0)


def test_room_feedback_refuses_scans_it_cannot_model_before_any_work():
    """A head carried along a line, or scans from two positions, in one line before any fit."""
    from hilbertmap.testing import box_scan, frame, moving_poses, orthogonal_frames
    from mitsonar.inverse.room import room_feedback

    moving = box_scan(moving_poses((0, 0, 0), (1, 0, 0), n_pings=20), n_pings=20, rays=10, seed=0)
    with pytest.raises(ValueError, match=r"scans\[0\] must be a mechanical scan from one fixed position"):
        room_feedback([moving], None)
    two = [box_scan(orthogonal_frames()[0], n_pings=20, rays=10, seed=0),
           box_scan(frame((1, 0, 0), (0, 0, 1), (1.0, 0, 0)), n_pings=20, rays=10, seed=1)]
    with pytest.raises(ValueError, match="one sonar position"):
        room_feedback(two, None)
    with pytest.raises(ValueError, match="at least one scan"):
        room_feedback([], None)
