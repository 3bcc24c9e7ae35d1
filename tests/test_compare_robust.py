"""`mitsonar compare`'s rough edges: nothing left behind on failure."""
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
    from mitsonar.compare import engine

    def boom(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(engine, "render_reference", boom)
    with pytest.raises(RuntimeError, match="boom"):
        engine.compare(small_scene, "sonar_tof", (0.01,), str(tmp_path / "new" / "cmp"), **QUICK)
    assert os.listdir(tmp_path) == []


def test_a_run_that_fails_in_an_existing_folder_leaves_no_partial_files(small_scene, tmp_path, monkeypatch):
    from mitsonar.compare import engine

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
    from mitsonar.compare import engine
    from mitsonar.compare.output import OutputFolder

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
