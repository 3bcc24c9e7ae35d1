"""What a new user hit (issue "Rough edges"): head settings held to the head's ranges, `python -m
mitsonar`, a progress rate that means something, `info` on long lists, plot titles of real scans,
and plots that leave no half-written file."""
import os
import subprocess
import sys
import time

import pytest

from conftest import ROOT, scene_xml, sonar_xml
from test_cli import BOX, assert_one_line_error, cli_env, run


@pytest.mark.parametrize("setting, value", [("gain", "1000"), ("gain", "-500"), ("ad_low", "81"),
                                            ("ad_span", "0.1"), ("ad_span", "200")])
def test_set_outside_the_heads_range_is_refused_before_rendering(tmp_path, setting, value):
    out = tmp_path / "g.exr"
    proc = run("render", BOX, "-o", str(out), "--spp", "16", "--set", f"{setting}={value}")
    assert_one_line_error(proc, f"--set '{setting}': {value}")
    assert "the range of the head's" in proc.stderr and not out.exists()


def test_xml_and_render_scan_electronics_get_the_heads_range(mitsonar_mod):
    with pytest.raises(mitsonar_mod.SceneError, match=r"sonar 'gain': 90\.0 is not allowed \(0\.\.80 dB"):
        mitsonar_mod.load_scene(scene_xml(sonar_xml(gain=90.0)))
    scene = mitsonar_mod.load_scene(BOX)
    with pytest.raises(mitsonar_mod.SceneError, match=r"render_scan electronics 'ad_low': -3"):
        mitsonar_mod.render_scan(scene, spp=1, electronics={"ad_low": -3})
    # The edges are the head's own: 0 and 80 dB are settings a Micron takes.
    scan = mitsonar_mod.render_scan(scene, spp=1, electronics={"gain": 80, "ad_low": 0})
    assert scan.electronics.gain == 80 and scan.electronics.ad_low == 0


def test_the_electronics_class_keeps_the_simulator_ranges():
    from mitsonar.receiver.electronics import Electronics

    e = Electronics(ad_low=-24.0, ad_span=255.0)  # outside the head's window, allowed for studies
    assert e.ad_low == -24.0


def test_python_dash_m_mitsonar_runs_the_command_line():
    proc = subprocess.run([sys.executable, "-m", "mitsonar", "--help"], capture_output=True, text=True,
                          cwd=ROOT, env=cli_env(), timeout=120)
    assert proc.returncode == 0 and "usage: mitsonar" in proc.stdout


def test_progress_rate_is_spp_over_the_time_since_the_render_started():
    from mitsonar.cli.main import _Progress

    progress = _Progress()
    time.sleep(0.6)               # compiling and the first pass: the bar is not shown yet
    progress(4096, 65536)
    try:
        meter = progress.bar.format_dict
    finally:
        progress.close()
    # the rate tqdm shows (n over its elapsed time): 4096 spp in >= 0.6 s, below 6827 spp/s (a
    # rate over the moment since the bar appeared gave 2e9 spp/s)
    rate = meter["n"] / meter["elapsed"]
    assert meter["n"] == 4096 and rate < 4096 / 0.6


def test_info_summarises_long_lists(tmp_path, mitsonar_mod):
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=1)
    scan.meta.wire_bearings = list(range(0, 6400, 32))
    path = tmp_path / "s.npz"
    scan.save(path)
    proc = run("info", str(path))
    assert proc.returncode == 0, proc.stderr
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("meta.wire_bearings"))
    assert "200 values, 0 .. 6368 (0, 32, 64, ...)" in line and len(line) < 120


def test_real_scan_title_names_only_what_the_scan_records(mitsonar_mod):
    from mitsonar.products.plots import _settings_line

    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=1)
    assert "speckle rayleigh" in _settings_line(scan) and "TVG 20log" in _settings_line(scan)
    scan.electronics = {"bit_depth": 4, "gain": 20.0, "ad_low": 10.0, "ad_span": 30.0}
    scan.meta = {"source": "seanet", "log": "/data/harbour.bin"}
    title = _settings_line(scan)
    assert "speckle" not in title and "TVG" not in title
    assert "gain 20 dB, AD 10+30 dB, 4-bit" in title and "SeaNet head log harbour.bin" in title


def test_a_failed_plot_leaves_no_file(tmp_path, mitsonar_mod, monkeypatch):
    from matplotlib.figure import Figure

    from mitsonar.products import plots

    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=1)

    def broken(self, *a, **k):
        with open(a[0], "wb") as fh:
            fh.write(b"half a picture")
        raise RuntimeError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        plots.plot_polar(scan, tmp_path / "p.png")
    assert os.listdir(tmp_path) == []


def test_info_prints_a_ragged_list(tmp_path, mitsonar_mod):
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=1)
    scan.meta["spans"] = [[1, 2], [3]] * 6
    path = tmp_path / "s.npz"
    scan.save(path)
    proc = run("info", str(path))
    assert proc.returncode == 0, proc.stderr
    assert any(ln.startswith("meta.spans") and "12 values" in ln for ln in proc.stdout.splitlines())


def test_a_plot_into_a_missing_folder_names_the_users_path(tmp_path, mitsonar_mod):
    from mitsonar.products import plots

    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=1)
    with pytest.raises(OSError, match=r"missing/p\.png") as err:
        plots.plot_polar(scan, tmp_path / "missing" / "p.png")
    assert ".partial" not in str(err.value)


def test_the_quay_wall_has_a_ground_truth_mesh(mitsonar_mod):
    """Its piles are cylinders: the mesh holds them at their radius, from the seabed up."""
    import numpy as np

    from conftest import SCENES

    V, F = mitsonar_mod.scene_mesh(mitsonar_mod.load_scene(f"{SCENES}/quay_wall.xml"))
    pile = (np.abs(V[:, 0] - 6) < 0.5) & (np.abs(V[:, 1] + 3) < 0.5)
    np.testing.assert_allclose(np.hypot(V[pile, 0] - 6, V[pile, 1] + 3), 0.3, rtol=1e-6)  # float32 transform
    assert V[pile, 2].min() == pytest.approx(-3) and V[pile, 2].max() == pytest.approx(2)
    assert F.max() < len(V)
