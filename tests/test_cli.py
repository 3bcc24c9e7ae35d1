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
    assert scan.intensity.shape == (200, 500) and scan.meta.spp == 128 and scan.meta.seed == 5
    assert scan.electronics.gain == 30
    # The file holds exactly what the library renders with the same arguments.
    same = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=128, seed=5, electronics={"gain": 30})
    np.testing.assert_array_equal(scan.intensity, same.intensity)
    np.testing.assert_array_equal(scan.data, same.data)
    w, h = png_size(png)
    assert w > 300 and h > 300
    for kind in ("polar", "cartesian", "ascan"):
        out = tmp_path / f"{kind}.png"
        proc = run("plot", str(exr), "-o", str(out), "--picture", kind, "--scene", BOX, "--db")
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
    (["plot", "{tmp}/scan.npz", "-o", "{tmp}/a.png", "--picture", "ascan", "--ping", "999"], "--ping 999"),
    # Checked before the render: outputs, options, seeds.
    (["render", BOX, "-o", "{tmp}/dir.exr"], "output '{tmp}/dir.exr' is a directory"),
    (["render", BOX, "-o", "{tmp}/a.exr", "--seed", "4294967296"], "--seed 4294967296: not allowed (a whole number from 0 to 4294967295)"),
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


# ----------------------------------------------------------------------------- side-scan pictures
SIDESCAN = os.path.join(SCENES, "wreck_sidescan.xml")
HARBOUR = os.path.join(SCENES, "harbour.xml")
HARBOUR_TRACK = os.path.join(SCENES, "harbour_survey.tum")


@pytest.fixture(scope="module")
def sidescan_npz(tmp_path_factory):
    import mitsonar

    path = tmp_path_factory.mktemp("ss") / "ss.npz"
    mitsonar.render_scan(mitsonar.load_scene(SIDESCAN), spp=2).save(str(path))
    return str(path)


def test_plot_of_a_sidescan_scan_is_a_waterfall_and_refuses_fans(tmp_path, sidescan_npz, capsys):
    from mitsonar.cli.main import PICTURES, main, picture_for

    assert picture_for("sidescan") == "waterfall" and picture_for("mechanical") == "polar"
    assert main(["plot", sidescan_npz, "-o", str(tmp_path / "w.png")]) == 0
    png_size(tmp_path / "w.png")
    assert main(["plot", sidescan_npz, "-o", str(tmp_path / "a.png"), "--picture", "ascan", "--ping", "300"]) == 0
    capsys.readouterr()
    for kind in ("polar", "cartesian"):   # every row on bearing 0, or a bow-tie: refused in one line
        assert main(["plot", sidescan_npz, "-o", str(tmp_path / f"{kind}.png"), "--picture", kind]) == 1
        err = capsys.readouterr().err.strip()
        assert err == (f"mitsonar: error: --picture {kind}: not for a sidescan scan "
                       f"(allowed for sidescan: waterfall, ascan)")
        assert not (tmp_path / f"{kind}.png").exists()
    assert PICTURES["mechanical"] == ("polar", "cartesian", "ascan")


def test_sidescan_titles_count_pings_per_side(sidescan_npz):
    import mitsonar
    from mitsonar.products.plots import _settings_line, plot_ascan, rows_text

    scan = mitsonar.load_scan(sidescan_npz)
    assert scan.n_pings == 500 and rows_text(scan) == "250 pings per side"
    assert _settings_line(scan).startswith("sidescan, 250 pings per side x ")
    title = plot_ascan(scan, 300).axes[0].get_title()
    assert title.startswith("ping 50 of the starboard channel\n")


def test_title_numbers_have_sensible_precision(mitsonar_mod):
    from mitsonar.products.plots import _settings_line, fmt, plot_ascan

    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=1, electronics={"gain": 27.8095})
    scan.bearings[0] = np.radians(0.254899)
    title = plot_ascan(scan, 0).axes[0].get_title()
    assert title.startswith("ping 0, bearing 0.25 deg\n"), title
    assert "gain 27.8 dB" in _settings_line(scan)
    assert (fmt(12.0), fmt(0.5), fmt(-0.001), fmt(27.8095, 1)) == ("12", "0.5", "0", "27.8")


# ----------------------------------------------------------------------------- --sensor
def test_render_sensor_by_id_and_index(tmp_path, capsys):
    import mitsonar
    from mitsonar.cli import main

    assert main(["render", HARBOUR, "-o", str(tmp_path / "m.npz"), "--spp", "1", "-q", "--sensor", "multibeam"]) == 0
    assert main(["render", HARBOUR, "-o", str(tmp_path / "s.npz"), "--spp", "1", "-q", "--sensor", "0"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert mitsonar.load_scan(str(tmp_path / "m.npz")).kind == "multibeam"
    assert mitsonar.load_scan(str(tmp_path / "s.npz")).kind == "mechanical"


@pytest.mark.parametrize("value, why", [("5", "--sensor 5: no sensor of that index"),
                                        ("sidescan", "--sensor 'sidescan': no sensor of that id")])
def test_bad_sensor_lists_the_scenes_sensors_before_rendering(tmp_path, value, why):
    proc = run("render", HARBOUR, "-o", str(tmp_path / "a.npz"), "--spp", "1", "-q", "--sensor", value)
    assert proc.returncode == 1
    assert_one_line_error(proc, f"harbour.xml: {why}; its sensors: 0 'sonar' (mechanical), "
                                "1 'multibeam' (multibeam)")
    assert not (tmp_path / "a.npz").exists()


def test_survey_of_a_two_sonar_scene_warns_once(tmp_path):
    out = tmp_path / "sv"
    proc = run("survey", HARBOUR, "--trajectory", HARBOUR_TRACK, "-o", str(out), "--spp", "1", "--max-scans", "2",
               "-q")
    assert proc.returncode == 0, proc.stderr
    warnings = [ln for ln in proc.stderr.splitlines() if "sonar sensors" in ln]
    assert warnings == ["mitsonar: warning: harbour.xml has 2 sonar sensors (0 'sonar' (mechanical), "
                        "1 'multibeam' (multibeam)); rendering 0 'sonar' (choose with --sensor ID|INDEX)"]
    proc = run("survey", HARBOUR, "--trajectory", HARBOUR_TRACK, "-o", str(out), "--spp", "1", "--max-scans", "1",
               "-q", "--sensor", "multibeam", "--force")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    import mitsonar

    assert sorted(f for f in os.listdir(out) if f.startswith("scan_")) == ["scan_00000.npz"]   # --force: replaced
    assert mitsonar.load_scan(str(out / "scan_00000.npz")).kind == "multibeam"


# ----------------------------------------------------------------------------- existing outputs, exit codes
def test_an_existing_output_is_refused_and_force_overwrites_it(tmp_path, mitsonar_mod):
    scan = tmp_path / "s.npz"
    mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=1).save(str(scan))
    png = tmp_path / "p.png"
    png.write_bytes(b"old")
    proc = run("plot", str(scan), "-o", str(png))
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr.splitlines() == [f"mitsonar: error: -o {png}: exists; --force to overwrite"]
    assert png.read_bytes() == b"old"
    proc = run("plot", str(scan), "-o", str(png), "--force")
    assert proc.returncode == 0 and proc.stderr == ""
    png_size(png)
    before = scan.read_bytes()
    proc = run("render", BOX, "-o", str(tmp_path / "new.npz"), "--plot", str(png), "--spp", "1", "-q")
    assert proc.returncode == 1
    assert proc.stderr.splitlines() == [f"mitsonar: error: --plot {png}: exists; --force to overwrite"]
    assert not (tmp_path / "new.npz").exists() and scan.read_bytes() == before
    for command in (["render", BOX, "-o", "x.npz"], ["plot", "x.npz", "-o", "x.png"], ["demo"], ["record", "P", "-o", "x"],
                    ["replay", "l", "-o", "x.npz"], ["map", "x.npz", "-o", "m.npz"], ["survey", BOX, "-o", "x"],
                    ["bathymetry", BOX, "-o", "x"], ["export", "x.npz"], ["levels", BOX], ["live", BOX]):
        assert "--force" in run(*command, "--help").stdout, command


@pytest.mark.parametrize("args, code", [
    (["render", BOX], 2),                                    # argparse: -o missing
    (["plot", "x.npz", "-o", "x.png", "--picture", "fan"], 2),  # argparse: not a choice
    (["render", BOX, "-o", "{tmp}/a.npz", "--spp", "0"], 1),  # validation
    (["map", BOX, "-o", "{tmp}/m.npz", "--inducing", "0"], 1),
    (["map", BOX, "-o", "{tmp}/m.txt"], 1),
    (["survey", BOX, "-o", "{tmp}/s", "--lawnmower", "0", "1", "0", "1", "--depth", "1", "--max-scans", "0"], 1),
    (["bathymetry", BOX, "-o", "{tmp}/b", "--lawnmower", "0", "1", "0", "1", "--depth", "1", "--sensor", "0",
      "--beams", "8"], 1),
])
def test_argparse_errors_exit_2_validation_errors_exit_1(tmp_path, args, code):
    proc = run(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert proc.returncode == code, proc.stderr
    assert "Traceback" not in proc.stderr and "error: " in proc.stderr.strip().splitlines()[-1]


# ----------------------------------------------------------------------------- messages
def test_count_flags_are_named_with_their_real_limits(tmp_path, capsys):
    from mitsonar.cli import main

    assert main(["render", BOX, "-o", str(tmp_path / "a.npz"), "--spp", "4000000000"]) == 1
    assert capsys.readouterr().err.strip() == (
        "mitsonar: error: --spp 4000000000: not allowed (a whole number of paths per ping from 1 to 2147483647)")
    assert main(["survey", BOX, "-o", str(tmp_path / "s"), "--lawnmower", "0", "1", "0", "1", "--depth", "1",
                 "--max-scans", "0"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("mitsonar: error: --max-scans 0: not allowed (a whole number of scans from 1 to")
    assert "render_" not in err and not (tmp_path / "s").exists()


def test_render_scan_states_the_spp_limit(mitsonar_mod):
    with pytest.raises(ValueError, match="from 1 to 2147483647"):
        mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=4_000_000_000)


def test_compare_names_every_sonar_integrator():
    from mitsonar.jobs.compare import CompareError
    from mitsonar.jobs.compare.integrators import load_integrator

    with pytest.raises(CompareError, match="use one of sonar_bdpt, sonar_mlt, sonar_tof"):
        load_integrator("path")


def test_trajectory_errors_print_plain_numbers(tmp_path, mitsonar_mod):
    track = tmp_path / "t.tum"
    track.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n")
    with pytest.raises(ValueError) as err:
        mitsonar_mod.Trajectory.from_tum(str(track))
    assert str(err.value) == (f"{track}:3: field 'timestamp': 1.0 is not after the previous 1.0 "
                              "(times must increase strictly)")
    track.write_text("0 0 0 inf 0 0 0 1\n")
    with pytest.raises(ValueError, match=r"field 'tz': inf is not allowed"):
        mitsonar_mod.Trajectory.from_tum(str(track))


def test_dataset_config_errors_name_the_file_and_line(tmp_path):
    from mitsonar.jobs.dataset import DatasetError, read_config

    bad = tmp_path / "bad.yaml"
    bad.write_text("seed: 1\nsamples: [3\nspp: 4\n")
    with pytest.raises(DatasetError) as err:
        read_config(str(bad))
    assert str(err.value).startswith(f"dataset config {str(bad)!r} line 3, column 4: expected ',' or ']'")
    text = open(os.path.join(ROOT, "examples", "dataset_small.yaml")).read().replace("n_bins: 200", "n_bins: -5")
    cfg = tmp_path / "sonar.yaml"
    cfg.write_text(text.replace("../scenes_xml", SCENES))
    line = text.splitlines().index("  n_bins: -5") + 1
    with pytest.raises(DatasetError) as err:
        read_config(str(cfg))
    assert str(err.value) == f"dataset config 'sonar.n_bins' ({cfg} line {line}): -5 is not allowed (1 to 65536)"


def test_survey_scene_errors_name_the_file_and_line(tmp_path):
    from mitsonar.scenes.sea_surface import load_survey_scene

    bad = tmp_path / "bad.xml"
    text = open(BOX).read()
    bad.write_text(text.replace('name="n_bins" value="500"', 'name="n_bins" value="-5"'))
    with pytest.raises(ValueError) as err:      # Mitsuba's line of the file: the sensor's element
        load_survey_scene(str(bad), surface=True)
    assert f"{bad} (line 30, col 6): sonar 'n_bins': -5" in str(err.value) and "string" not in str(err.value)


def test_failed_bathymetry_leaves_no_empty_folder(tmp_path):
    out = tmp_path / "new" / "bathy"
    proc = run("bathymetry", os.path.join(SCENES, "rocky_slope.xml"), "--trajectory",
               os.path.join(SCENES, "rocky_slope_survey.tum"), "--range-max", "2", "--max-scans", "1", "--spp", "2",
               "-q", "-o", str(out))
    assert_one_line_error(proc, "no bottom in range")
    assert not (tmp_path / "new").exists()


def test_virtual_sonar_and_bathymetry_take_a_sensor(tmp_path):
    import json

    proc = run("virtual-sonar", HARBOUR, "--sensor", "multibeam", "--spp", "1", "--seconds", "1")
    assert proc.returncode == 1, proc.stderr      # refused before the render: SeaNet heads are mechanical
    assert "a SeaNet head is mechanically scanned; a 'multibeam' scan" in proc.stderr
    assert "rendered" not in proc.stdout
    out = tmp_path / "b"
    proc = run("bathymetry", HARBOUR, "--trajectory", HARBOUR_TRACK, "--sensor", "multibeam", "--max-scans", "1",
               "--spp", "2", "-q", "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "errors.json").read_text())
    assert summary["sensor"] == "multibeam" and summary["preset"] is None and summary["sonar"]["beams"] == 128


# ----------------------------------------------------------------------------- --version, a folder as a scene
def test_version_prints_the_package_version(capsys):
    from mitsonar._version import __version__
    from mitsonar.cli import main

    with pytest.raises(SystemExit) as exit:
        main(["--version"])
    assert exit.value.code == 0
    assert capsys.readouterr().out == f"mitsonar {__version__}\n"


@pytest.mark.parametrize("command", [["render", "{dir}", "-o", "{dir}/a.npz"], ["levels", "{dir}"],
                                     ["survey", "{dir}", "-o", "{dir}/s", "--lawnmower", "0", "1", "0", "1",
                                      "--depth", "1"]])
def test_a_folder_given_as_the_scene_is_called_a_folder(tmp_path, capsys, command):
    from mitsonar.cli import main

    assert main([a.format(dir=tmp_path) for a in command]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "does not exist" not in err and "no such file" not in err, err
    assert f"{tmp_path}" in err and "is a directory; expected a scene XML file" in err, err
    assert sorted(os.listdir(tmp_path)) == []
