"""`mitsonar map` on a survey whose extent rules out the default mesh step (issue 37): it either
makes every output with a step that fits (and says which), or refuses before the fit with one
line and no file; its timing line covers every stage the user waited for."""
import math
import re

import numpy as np
import pytest

from hilbertmap import IncrementalHilbertMap
from hilbertmap.surfaces import fitting_resolution, grid_shape
from hilbertmap.testing import box_scan, moving_poses
from mitsonar import Scan
from mitsonar import cli
from mitsonar.cli import map as map_cli

DOWN = dict(boresight=(0.0, 0.0, -1.0), scan_axis=(0.0, 1.0, 0.0))


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """Two sweeps of a head carried along y over the box's floor, saved as `mitsonar survey` does."""
    folder = tmp_path_factory.mktemp("survey")
    for i in range(2):
        s = box_scan(moving_poses((0, -1 + i, 0), (0, i, 0), n_pings=60, **DOWN), n_pings=60,
                     bearing_step=6.0, rays=40, seed=i)
        Scan(intensity=s.intensity, data=s.data, ranges=s.ranges, bearings=s.bearings, poses=s.poses,
             range_min=s.range_min, range_max=s.range_max, beamwidth_h=s.beamwidth_h,
             beamwidth_v=s.beamwidth_v).save(str(folder / f"scan_{i:05d}.npz"))
    return folder


STAGES = r"([\d.]+) s \(read ([\d.]+), fit ([\d.]+), elevation ([\d.]+), mesh ([\d.]+), plot ([\d.]+), write ([\d.]+)\)"


def test_default_mesh_step_too_fine_for_the_survey_is_coarsened_and_said(survey, tmp_path, monkeypatch, capsys):
    # The default step (a quarter of the 0.15 m length-scale) over this survey's region seen is
    # millions of points: with a budget of 2e5 the command must pick a coarser step, not fail.
    monkeypatch.setattr(map_cli, "AUTO_MESH_POINTS", 200_000)
    out = {k: tmp_path / n for k, n in dict(o="m.npz", e="e.npz", p="p.png", m="m.ply").items()}
    rc = cli.main(["map", str(survey), "--incremental", "-o", str(out["o"]), "--elevation", str(out["e"]),
                   "--plot", str(out["p"]), "--mesh", str(out["m"]), "--elevation-resolution", "0.5"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert all(p.exists() for p in out.values())
    step = re.search(r"mesh grid step ([\d.]+) m \(the default 0.0375 m would need ([\d.e+]+) grid points",
                     captured.out)
    assert step, captured.out
    res, points = float(step.group(1)), float(step.group(2))
    hm = IncrementalHilbertMap.load(out["o"])
    lo, hi = hm.coverage_.bounds()
    assert points == pytest.approx(math.prod(grid_shape(0.0375, lo, hi)), rel=1e-2) and points > 200_000
    assert res == fitting_resolution(0.0375, lo, hi, 200_000)   # the finest two-digit step that fits
    # the time the user waited, split by stage: the stages add up to the total (to the rounding)
    t = re.search(STAGES, captured.out)
    assert t, captured.out
    total, parts = float(t.group(1)), [float(g) for g in t.groups()[1:]]
    assert sum(parts) <= total + 0.05 * len(parts) + 1e-9


def test_mesh_step_too_fine_for_the_survey_is_refused_before_the_fit(survey, tmp_path, monkeypatch, capsys):
    def no_fit(self, *a, **k):
        raise AssertionError("the map was fitted before the --resolution was refused")

    monkeypatch.setattr(IncrementalHilbertMap, "partial_fit", no_fit)
    rc = cli.main(["map", str(survey), "--incremental", "-o", str(tmp_path / "m.npz"), "--elevation",
                   str(tmp_path / "e.npz"), "--plot", str(tmp_path / "p.png"), "--mesh", str(tmp_path / "m.ply"),
                   "--resolution", "0.001"])
    captured = capsys.readouterr()
    assert rc == 1
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    m = re.search(r"--resolution 0.001 m: the scans reach ([\d.]+) x ([\d.]+) x ([\d.]+) m \(their positions \+- "
                  r"range_max\), a grid of [\d.e+]+ points \(at most 2e\+08\); use --resolution ([\d.]+) or coarser",
                  lines[0])
    assert m, lines[0]
    # the box: the pings' positions (y from -1 to 1) +- range_max 12 m
    assert [float(g) for g in m.groups()[:3]] == pytest.approx([24.0, 26.0, 24.0], abs=0.05)
    assert float(m.group(4)) > 0.001
    assert list(tmp_path.iterdir()) == []


def test_fitting_resolution_is_the_finest_two_digit_step_that_fits():
    lo, hi = np.zeros(3), np.array([10.0, 10.0, 10.0])
    assert fitting_resolution(0.5, lo, hi, 10 ** 6) == 0.5                 # 21^3 points: fits as it is
    r = fitting_resolution(0.01, lo, hi, 10 ** 6)                            # 1001^3 do not
    finer = r - 10.0 ** (math.floor(math.log10(r)) - 1)                     # one in the second digit
    assert math.prod(grid_shape(r, lo, hi)) <= 10 ** 6 < math.prod(grid_shape(finer, lo, hi))
    assert r == float(f"{r:.2g}")
