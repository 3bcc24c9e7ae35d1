"""End-to-end tests of the `mitsonar` command line, run as a user would (subprocesses)."""
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, SCENES

BOX = os.path.join(SCENES, "box.xml")


def cli_env(**extra):
    env = dict(os.environ, **extra)
    env.pop("MITSONAR_DEBUG", None)
    return env


def run(*args, cwd=None, **env):
    return subprocess.run([sys.executable, "-m", "mitsonar.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=cli_env(**env), timeout=600)


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
    # Checked before the render: outputs, options, seeds.
    (["render", BOX, "-o", "{tmp}/dir.exr"], "output '{tmp}/dir.exr' is a directory"),
    (["render", BOX, "-o", "{tmp}/a.exr", "--seed", "4294967296"], "'seed': 4294967296 is not allowed (a whole number from 0 to 4294967295)"),
    (["render", BOX, "-o", "{tmp}/a.exr", "--set", "gian=3"], "--set 'gian' is not an electronics setting (known: source_level"),
    (["demo", "-o", "{tmp}/garbage.exr/out"], "cannot create the output folder"),
    (["compare", BOX, "-o", "{tmp}/garbage.exr/cmp"], "cannot create the output folder"),
])
def test_bad_input_gives_one_clear_line(tmp_path, mitsonar_mod, args, message):
    (tmp_path / "garbage.exr").write_bytes(b"\x76\x2f\x31\x01 definitely not an EXR")
    (tmp_path / "dir.exr").mkdir()
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=4)
    scan.save(str(tmp_path / "scan.npz"))
    proc = run(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert_one_line_error(proc, message.replace("{tmp}", str(tmp_path)))
    assert not (tmp_path / "a.exr").exists()


def test_bad_scene_parameter_names_file_and_field(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text(open(BOX).read().replace('name="n_bins" value="500"', 'name="n_bins" value="-5"'))
    proc = run("render", str(bad), "-o", str(tmp_path / "a.exr"))
    assert_one_line_error(proc, "n_bins")
    assert "bad.xml" in proc.stderr
    # Only that line: no Mitsuba warning about a default film above it (Mitsuba logs to stdout).
    assert len(proc.stderr.strip().splitlines()) == 1 and "HDRFilm" not in proc.stdout, proc.stdout


def test_misspelled_parameter_gets_the_nearest_name_and_the_list(tmp_path):
    bad = tmp_path / "typo.xml"
    bad.write_text(open(BOX).read().replace('name="beamwidth_h"', 'name="beamwidht_h"'))
    proc = run("render", str(bad), "-o", str(tmp_path / "a.exr"))
    assert_one_line_error(proc, 'typo.xml')
    line = proc.stderr.strip().splitlines()[-1]
    assert 'the sensor "sonar" has no parameter "beamwidht_h" (did you mean "beamwidth_h"?)' in line
    assert "its parameters: kind, to_world, range_min" in line and "[parser.cpp" not in line


def test_scene_without_a_sonar_names_the_file(tmp_path):
    bad = tmp_path / "nosonar.xml"
    bad.write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    assert_one_line_error(run("render", str(bad), "-o", str(tmp_path / "a.exr")),
                          'nosonar.xml: needs a <sensor type="sonar"> (sensors found: none)')


def test_unknown_variant_from_the_environment_is_one_line(tmp_path):
    proc = run("render", BOX, "-o", str(tmp_path / "a.exr"), MITSONAR_VARIANT="bogus")
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        "mitsonar: error: variant 'bogus' is not supported (MITSONAR_VARIANT / --variant): use one of "
        "llvm_ad_mono, cuda_ad_mono or auto; sonar intensity is monochrome and needs a JIT variant"]


def test_a_scene_the_render_overrides_gets_a_one_line_warning(tmp_path):
    text = open(BOX).read()
    start, end = text.index("<integrator"), text.index("</integrator>") + len("</integrator>")
    scene = tmp_path / "pathint.xml"
    scene.write_text(text[:start] + '<integrator type="path"/>' + text[end:])
    proc = run("render", str(scene), "-o", str(tmp_path / "a.exr"), "--spp", "4", "-q")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "mitsonar: warning: pathint.xml: its integrator PathIntegrator is not a sonar integrator; "
        "rendering with sonar_tof"]


def test_info_into_a_closed_pipe_ends_quietly(tmp_path, mitsonar_mod):
    mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=4).save(str(tmp_path / "s.npz"))
    proc = subprocess.Popen([sys.executable, "-m", "mitsonar.cli", "info", str(tmp_path / "s.npz")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT, env=cli_env())
    proc.stdout.close()  # like `| head -0`: nobody reads
    err = proc.stderr.read().decode()
    proc.wait(timeout=600)
    assert err == "", err


@pytest.mark.slow
def test_demo_writes_exr_and_pictures(tmp_path):
    proc = run("demo", "-o", str(tmp_path / "out"), "--spp", "256", "-q")
    assert proc.returncode == 0, proc.stderr
    for name in ("box", "intake", "box_fls"):
        assert (tmp_path / "out" / f"{name}.exr").stat().st_size > 10000
        for kind in ("polar", "cartesian", "ascan"):
            png_size(tmp_path / "out" / f"{name}_{kind}.png")
