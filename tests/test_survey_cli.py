"""``mitsonar survey`` (issue 18, part 4): scans, trajectory and pictures written; a bad trajectory
file is one line naming the file, the line and the field, with a non-zero exit and no output."""
import os

import numpy as np
import pytest
from conftest import SCENES

from mitsonar.cli import main

BOX = os.path.join(SCENES, "box.xml")


def test_survey_writes_scans_trajectory_and_pictures(tmp_path, capsys):
    import mitsonar

    out = tmp_path / "out"
    rc = main(["survey", BOX, "--lawnmower", "-1", "1", "-1", "1", "--spacing", "1", "--speed", "0.2",
               "--depth", "0", "--spp", "16", "--max-scans", "2", "-q", "-o", str(out)])
    assert rc == 0
    names = sorted(os.listdir(out))
    assert names == ["scan_00000.npz", "scan_00000_world.png", "scan_00001.npz", "track.png", "trajectory.tum"]
    traj = mitsonar.Trajectory.from_tum(out / "trajectory.tum")
    scan = mitsonar.load_scan(out / "scan_00001.npz")
    mount = mitsonar.load_scene(BOX).sensors()[0].to_world_np
    from mitsonar.scan import bearing_rotation

    t = scan.meta.start_time + scan.times
    np.testing.assert_allclose(scan.poses, traj.at(t) @ mount @ bearing_rotation(scan.bearings), atol=1e-12)
    assert "wrote 2 scans" in capsys.readouterr().out
    # a second survey into the same folder would mix two surveys: refused
    assert main(["survey", BOX, "--trajectory", str(out / "trajectory.tum"), "-q", "-o", str(out)]) == 1
    assert capsys.readouterr().err.strip() == (f"mitsonar: error: -o {out}: already holds scan_00000.npz and 4 more "
                                               "of its outputs; --force to overwrite")


@pytest.mark.parametrize("content, words", [
    ("0 0 0 0 0 0 0 1\n0.5 1 2\n", ":2: 3 fields, expected 8"),
    ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", ":3: field 'timestamp'"),
    ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0.6 0.6\n", ":2: field 'qx qy qz qw'"),
    ("0 0 0 0 0 0 0 1\n1 0 nan 0 0 0 0 1\n", ":2: field 'ty'"),
])
def test_bad_trajectory_file_is_one_line_and_writes_nothing(tmp_path, capsys, content, words):
    track = tmp_path / "track.tum"
    track.write_text(content)
    out = tmp_path / "out"
    assert main(["survey", BOX, "--trajectory", str(track), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mitsonar: error: {track}{words}") and "\n" not in err
    assert not out.exists()


def test_survey_argument_mistakes(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["survey", BOX, "-o", str(out)]) == 1
    assert "exactly one of --trajectory FILE or --lawnmower" in capsys.readouterr().err
    assert main(["survey", BOX, "--lawnmower", "0", "0", "5", "5", "-o", str(out)]) == 1
    assert "exactly one of --depth or --altitude" in capsys.readouterr().err
    track = tmp_path / "short.tum"
    track.write_text("0 0 0 0 0 0 0 1\n2 1 0 0 0 0 0 1\n")
    assert main(["survey", BOX, "--trajectory", str(track), "-o", str(out)]) == 1
    assert "one scan takes" in capsys.readouterr().err
    assert not out.exists()
