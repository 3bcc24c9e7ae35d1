"""End-to-end tests of the `mitsonar` command line, run as a user would (subprocesses)."""
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, SCENES

BOX = os.path.join(SCENES, "box.xml")


def run(*args, cwd=None):
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "mitsonar.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=600)


def assert_one_line_error(proc, pattern):
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("mitsonar: error:")]
    assert len(lines) == 1, proc.stderr
    assert pattern in lines[0], lines[0]


def png_size(path):
    with open(path, "rb") as fh:
        head = fh.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def test_help_everywhere():
    for args in ([], ["render"], ["plot"], ["info"], ["demo"]):
        proc = run(*args, "--help")
        assert proc.returncode == 0 and "usage: mitsonar" in proc.stdout


def test_render_plot_info_round_trip(tmp_path, mitsonar_mod):
    exr, png = tmp_path / "scan.exr", tmp_path / "scan.png"
    proc = run("render", BOX, "-o", str(exr), "--spp", "128", "--seed", "5", "--plot", str(png),
               "--set", "gain=30")
    assert proc.returncode == 0, proc.stderr
    scan = mitsonar_mod.load_scan(str(exr))
    assert scan.intensity.shape == (200, 500) and scan.meta["spp"] == 128 and scan.meta["seed"] == 5
    assert scan.electronics["gain"] == 30
    # The file holds exactly what the library renders with the same arguments.
    same = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=128, seed=5, electronics={"gain": 30})
    np.testing.assert_array_equal(scan.intensity, same.intensity)
    np.testing.assert_array_equal(scan.data, same.data)
    w, h = png_size(png)
    assert w > 300 and h > 300
    for kind in ("polar", "cartesian", "ascan"):
        out = tmp_path / f"{kind}.png"
        proc = run("plot", str(exr), "-o", str(out), "--kind", kind, "--scene", BOX, "--db")
        assert proc.returncode == 0, proc.stderr
        png_size(out)
    proc = run("info", str(exr))
    assert proc.returncode == 0
    assert "pings" in proc.stdout and "200" in proc.stdout and "electronics.gain" in proc.stdout
    assert "meta.scene" in proc.stdout and "box.xml" in proc.stdout


@pytest.mark.parametrize("args, message", [
    (["render", "/nonexistent/scene.xml", "-o", "{tmp}/a.exr"], "does not exist"),
    (["render", BOX, "-o", "{tmp}/a.txt"], "extension must be one of .exr, .npz"),
    (["render", BOX, "-o", "{tmp}/a.exr", "--spp", "0"], "spp"),
    (["render", BOX, "-o", "{tmp}/a.exr", "--set", "gian=3"], "'gian' is not an electronics setting"),
    (["render", BOX, "-o", "{tmp}/a.exr", "--set", "tvg=35log"], "'tvg': '35log'"),
    (["--variant", "scalar_rgb", "render", BOX, "-o", "{tmp}/a.exr"], "variant 'scalar_rgb' is not supported"),
    (["info", "{tmp}/missing.exr"], "missing.exr"),
    (["plot", "{tmp}/garbage.exr", "-o", "{tmp}/a.png"], "garbage.exr"),
    (["plot", "{tmp}/scan.npz", "-o", "{tmp}/a.png", "--kind", "ascan", "--ping", "999"], "--ping 999"),
])
def test_bad_input_gives_one_clear_line(tmp_path, mitsonar_mod, args, message):
    (tmp_path / "garbage.exr").write_bytes(b"\x76\x2f\x31\x01 definitely not an EXR")
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=4)
    scan.save(str(tmp_path / "scan.npz"))
    proc = run(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert_one_line_error(proc, message)


def test_bad_scene_parameter_names_file_and_field(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text(open(BOX).read().replace('name="n_bins" value="500"', 'name="n_bins" value="-5"'))
    proc = run("render", str(bad), "-o", str(tmp_path / "a.exr"))
    assert_one_line_error(proc, "n_bins")
    assert "bad.xml" in proc.stderr


@pytest.mark.slow
def test_demo_writes_exr_and_pictures(tmp_path):
    proc = run("demo", "-o", str(tmp_path / "out"), "--spp", "256", "-q")
    assert proc.returncode == 0, proc.stderr
    for name in ("box", "intake", "box_fls"):
        assert (tmp_path / "out" / f"{name}.exr").stat().st_size > 10000
        for kind in ("polar", "cartesian", "ascan"):
            png_size(tmp_path / "out" / f"{name}_{kind}.png")
