"""`mitsonar compare`'s rough edges: nothing left behind on failure, timing that a busy machine
does not fool (tested with fake clocks, never with timing thresholds), the asked and achieved
seconds side by side, and a progress bar only on a terminal."""
import io
import json
import os
import subprocess
import sys

import pytest

from conftest import ROOT
from test_compare import small_scene_xml


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "small.xml"
    path.write_text(small_scene_xml())
    return str(path)


def run_cli(*args, cwd=ROOT):
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "mitsonar.cli", *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=600)


# ------------------------------------------------------------------ 1. nothing left behind
def test_unknown_integrator_leaves_no_output_folder(small_scene, tmp_path):
    proc = run_cli("compare", small_scene, "--integrators", "sonar_tof,bogus", "-o", "ycmp", cwd=tmp_path)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "integrator 'bogus' is not available" in lines[0], proc.stderr
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("args, message", [
    (["--integrators", "sonar_tof,bogus"], "integrator 'bogus' is not available"),
    (["--param", "sonar_tof.max_depth=-2"], "integrator 'sonar_tof'"),
    (["--param", "sonar_mlt.chains=8", "--integrators", "sonar_tof"], "--param for 'sonar_mlt'"),
    (["--budget", "1,nope"], "'nope' is not a positive number of seconds"),
    (["--region", "far=8:3"], "--region 'far=8:3'"),
    (["--repeats", "0"], "--repeats 0"),
])
def test_bad_input_creates_nothing(small_scene, tmp_path, capsys, args, message):
    from mitsonar.cli import main

    out = tmp_path / "a" / "b" / "cmp"
    assert main(["compare", small_scene, "-o", str(out), *args]) != 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mitsonar: error:") and message in lines[0], lines
    assert os.listdir(tmp_path) == []


def test_output_under_a_file_is_refused_before_rendering(small_scene, tmp_path, capsys):
    from mitsonar.cli import main

    (tmp_path / "file.txt").write_text("x")
    assert main(["compare", small_scene, "-o", str(tmp_path / "file.txt" / "cmp")]) != 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "cannot create the output folder" in lines[0], lines
    assert sorted(os.listdir(tmp_path)) == ["file.txt"]


QUICK = dict(reference_spp=4096, seed=5, repeats=1, calibration_seconds=0.01, plots=False)


def test_a_run_that_fails_removes_the_folder_it_created(small_scene, tmp_path, monkeypatch):
    from mitsonar.jobs.compare import engine

    def boom(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(engine, "render_reference", boom)
    with pytest.raises(RuntimeError, match="boom"):
        engine.compare(small_scene, "sonar_tof", (0.01,), str(tmp_path / "new" / "cmp"), **QUICK)
    assert os.listdir(tmp_path) == []


def test_a_run_that_fails_in_an_existing_folder_leaves_no_partial_files(small_scene, tmp_path, monkeypatch):
    from mitsonar.jobs.compare import engine

    out = tmp_path / "cmp"
    out.mkdir()
    (out / "mine.txt").write_text("keep me")

    def boom(result, path):
        open(path, "wb").write(b"half a picture")
        raise RuntimeError("boom")

    monkeypatch.setattr(engine, "plot_convergence", boom)
    with pytest.raises(RuntimeError, match="boom"):
        engine.compare(small_scene, "sonar_tof", (0.01,), str(out), **{**QUICK, "plots": True})
    names = sorted(os.listdir(out))
    # The user's file stays, the finished reference cache stays; no results, no temporary files.
    assert names[0] == "mine.txt" and len(names) == 2 and names[1].startswith("reference_"), names
    assert names[1].endswith("_spp4096.npz")


def test_results_are_written_under_temporary_names_then_renamed(small_scene, tmp_path, monkeypatch):
    from mitsonar.jobs.compare import engine
    from mitsonar.jobs.compare.output import OutputFolder

    seen = []
    real = OutputFolder.commit

    def commit(self):
        seen.extend(sorted(os.listdir(self.path)))
        real(self)

    monkeypatch.setattr(OutputFolder, "commit", commit)
    out = tmp_path / "cmp"
    result = engine.compare(small_scene, "sonar_tof", (0.01,), str(out), **QUICK)
    staged = [n for n in seen if not n.startswith("reference_")]
    assert len(staged) == 2 and all(n.startswith(".") and ".partial" in n for n in staged), seen
    assert sorted(os.listdir(out)) == sorted(["compare.json", "renders.npz",
                                              os.path.basename(result["reference"]["file"])])


# ------------------------------------------------------------------ 2. timing on a busy machine
class FakeMachine:
    """A render whose time is ``spp * per_spp`` seconds on a fake clock; the first render at
    ``slow_spp`` is slowed ``factor`` times, as by another process on the machine."""

    def __init__(self, per_spp=1e-5, slow_spp=None, factor=4.0):
        self.now, self.per_spp, self.slow_spp, self.factor, self.spps = 0.0, per_spp, slow_spp, factor, []

    def clock(self):
        return self.now

    def render(self, spp):
        slowed = spp == self.slow_spp and spp not in self.spps
        self.now += spp * self.per_spp * (self.factor if slowed else 1.0)
        self.spps.append(spp)


def test_calibration_takes_the_median_of_several_timings(mitsonar_mod):
    from mitsonar.jobs.compare import calibrate, plan_spp

    clean = FakeMachine()
    largest = max(p[0] for p in calibrate(clean.render, 0.05, start_spp=256, clock=clean.clock)["points"])
    busy = FakeMachine(slow_spp=largest)
    cal = calibrate(busy.render, 0.05, start_spp=256, clock=busy.clock)
    spps = sorted({p[0] for p in cal["points"]})
    assert spps[-1] == largest
    assert sum(p[0] == spps[-1] for p in cal["points"]) == 3 and sum(p[0] == spps[-2] for p in cal["points"]) == 3
    true_spp = 1.0 / 1e-5
    assert plan_spp(cal["points"], 1.0) == pytest.approx(true_spp, rel=0.02)
    # One timing each (the former calibration) lets the slowed render set the plan.
    once = FakeMachine(slow_spp=largest)
    one = calibrate(once.render, 0.05, start_spp=256, clock=once.clock, tries=1)
    assert plan_spp(one["points"], 1.0) < 0.5 * true_spp


def test_a_larger_budget_never_plans_about_the_same_spp(mitsonar_mod):
    from mitsonar.jobs.compare.budget import BETA_RANGE, plan_spp, search_spp

    # Timings where one slowed render at 20000 spp says it takes 1 s (it takes 0.2 s).
    timings = [[10000, 0.1], [20000, 1.0]]
    tried = []

    def timed(spp):
        tried.append(spp)
        return None, spp * 1e-5, 0, 0.0, 1

    assert plan_spp(timings, 1.0) == 20000  # the plan alone believes the slowed render
    found = search_spp(timed, 1.0, timings, previous=(0.5, 50000))
    assert tried[0] == int(50000 * 2 ** (1 / BETA_RANGE[1]))
    assert found["spp"] > 50000 and found["attempts"][-1] == [found["spp"], found["spp"] * 1e-5]


def fake_run(label, budget, took):
    return {"integrator": label, "budget_s": budget, "seconds_mean": took, "spp": 1000, "rel_l2": 0.1,
            "rel_l1": 0.05}


def test_runs_off_their_budget_get_one_warning_line():
    from mitsonar.jobs.compare import budget_warning, off_budget

    runs = [fake_run("sonar_tof", 1.0, 1.19), fake_run("sonar_tof", 2.0, 2.5), fake_run("sonar_mlt", 1.0, 0.75),
            fake_run("sonar_mlt", 2.0, 1.7)]
    assert [(r["integrator"], r["budget_s"]) for r in off_budget(runs)] == [("sonar_tof", 2.0), ("sonar_mlt", 1.0)]
    line = budget_warning(runs)
    assert "\n" not in line and "20 %" in line
    assert "sonar_tof asked 2 s took 2.5 s" in line and "sonar_mlt asked 1 s took 0.75 s" in line
    assert budget_warning(runs[:1]) is None


def test_printed_report_shows_asked_and_achieved_seconds():
    from mitsonar.cli.compare import report

    result = {"reference": {"integrator": "sonar_tof", "spp": 4096, "self_rel_l2": 0.01, "from_cache": True},
              "runs": [fake_run("sonar_tof", 1.0, 1.05), fake_run("sonar_mlt", 1.0, 1.6)],
              "warnings": ["something"], "files": {"json": "cmp/compare.json"}}
    lines = report(result).splitlines()
    assert "asked s" in lines[1] and "took s" in lines[1]
    assert lines[1].index("asked s") < lines[1].index("took s")
    assert lines[2].split()[:3] == ["sonar_tof", "1", "1.05"] and not lines[2].endswith("*")
    assert lines[3].split()[:3] == ["sonar_mlt", "1", "1.6"] and lines[3].endswith("*")
    assert any(ln.startswith("* took more than 20 %") for ln in lines)
    assert "warning: something" in lines and lines[-1] == "wrote cmp/compare.json"


def test_json_reports_asked_and_achieved_seconds(small_scene, tmp_path):
    from mitsonar.jobs.compare import compare

    result = compare(small_scene, "sonar_tof", (0.01,), str(tmp_path / "cmp"), **QUICK)
    run = json.loads((tmp_path / "cmp" / "compare.json").read_text())["runs"][0]
    assert run["budget_s"] == 0.01 and run["seconds_mean"] > 0
    assert run["seconds_vs_budget"] == pytest.approx(run["seconds_mean"] / 0.01)
    off = any("off their time budget" in w for w in result["warnings"])
    assert off == (abs(run["seconds_vs_budget"] - 1) > 0.2)


# ------------------------------------------------------------------ 3. progress of the reference
class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_reference_progress_bar_only_on_a_terminal(small_scene, monkeypatch, mitsonar_mod):
    from mitsonar.jobs.compare.reference import render_reference
    from mitsonar.sim.scene import sonar_of

    scene = mitsonar_mod.load_scene(small_scene)
    sensor = sonar_of(scene, 0)
    for stream, progress, drawn in ((Terminal(), True, True), (io.StringIO(), True, False),
                                    (Terminal(), False, False)):
        monkeypatch.setattr(sys, "stderr", stream)
        hist, _, info = render_reference(scene, sensor, 4096, 0, 3, progress=progress)
        monkeypatch.undo()
        assert hist.shape == (4, 100) and info["spp"] == 4096
        assert ("reference" in stream.getvalue()) == drawn, stream.getvalue()


def test_cli_output_has_no_progress_bar_when_not_on_a_terminal(small_scene, tmp_path):
    proc = run_cli("compare", small_scene, "--integrators", "sonar_tof", "--budget", "0.01", "--reference-spp",
                   "8192", "--repeats", "1", "--calibration-seconds", "0.01", "--no-plots", "-o", str(tmp_path / "c"))
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr and "spp/s" not in proc.stderr and "it/s" not in proc.stderr
    assert "asked s" in proc.stdout and "took s" in proc.stdout


def test_a_failed_run_keeps_the_reference_it_rendered_into_a_new_folder(small_scene, tmp_path, monkeypatch):
    """Nothing is lost: the reference took most of the run's time, so a failure after it was cached
    leaves the new folder holding only that reference (no results, no temporary files)."""
    from mitsonar.jobs.compare import engine

    def boom(result, path):
        raise RuntimeError("boom")

    monkeypatch.setattr(engine, "plot_convergence", boom)
    out = tmp_path / "new" / "cmp"
    with pytest.raises(RuntimeError, match="boom"):
        engine.compare(small_scene, "sonar_tof", (0.01,), str(out), **{**QUICK, "plots": True})
    names = os.listdir(out)
    assert len(names) == 1 and names[0].startswith("reference_") and names[0].endswith("_spp4096.npz"), names
