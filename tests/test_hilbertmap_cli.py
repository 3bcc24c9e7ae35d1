"""`mitsonar map`: the command line of the mapper, run as a user would (subprocesses)."""
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT


def run(*args, cwd=None):
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "mitsonar.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=600)


def one_error_line(proc):
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.fixture(scope="module")
def scan_files(tmp_path_factory):
    from mitsonar import Scan

    from hilbertmap.testing import box_scan, orthogonal_frames

    folder = tmp_path_factory.mktemp("scans")
    paths = []
    for i, T in enumerate(orthogonal_frames()):
        s = box_scan(T, n_pings=40, bearing_step=9.0, seed=i, rays=100)
        scan = Scan(intensity=s.intensity, data=s.data, ranges=s.ranges, bearings=s.bearings, poses=s.poses,
                    range_min=s.range_min, range_max=s.range_max, beamwidth_h=s.beamwidth_h,
                    beamwidth_v=s.beamwidth_v)
        p = folder / f"scan{i}.npz"
        scan.save(str(p))
        paths.append(str(p))
    return paths


def test_map_help():
    proc = run("map", "--help")
    assert proc.returncode == 0 and "--inducing" in proc.stdout and "--mesh" in proc.stdout


def test_map_writes_map_mesh_and_plot(scan_files, tmp_path):
    out, mesh, plot = tmp_path / "map.npz", tmp_path / "map.ply", tmp_path / "slices.png"
    proc = run("map", *scan_files, "-o", str(out), "--inducing", "300", "--passes", "2",
               "--mesh", str(mesh), "--plot", str(plot), "--resolution", "0.2")
    assert proc.returncode == 0, proc.stderr
    assert out.exists() and mesh.exists() and plot.exists()
    from hilbertmap import HilbertMap, read_mesh

    hm = HilbertMap.load(out)
    assert len(hm.inducing_points_) == 300
    p = hm.predict_proba(np.array([[0.0, 0.0, -1.0], [5.0, 0.0, 0.0]]))
    assert p[0] < p[1]
    V, F = read_mesh(mesh)
    assert len(F) > 0


@pytest.mark.parametrize("args,expect", [
    (["missing.exr", "-o", "m.npz"], "no such file"),
    (["{scan}", "-o", "m.txt"], ".npz"),
    (["{scan}", "-o", "m.npz", "--inducing", "0"], "--inducing"),
    (["{scan}", "-o", "m.npz", "--mesh", "m.stl"], ".ply or .obj"),
    (["{bad}", "-o", "m.npz"], "cannot read the scan"),
])
def test_map_bad_input_one_line(scan_files, tmp_path, args, expect):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a scan")
    args = [a.format(scan=scan_files[0], bad=str(bad)) for a in args]
    proc = run("map", *args, cwd=str(tmp_path))
    line = one_error_line(proc)
    assert expect in line, line


def test_map_accepts_a_raw_seanet_log(tmp_path):
    """A log recorded from a (virtual) Micron maps like scan files do."""
    import subprocess
    import sys

    import mitsonar
    from mitsonar.devices.micron.driver import record
    from mitsonar.devices.micron.seanet import HeadSettings
    from mitsonar.devices.micron.virtual import VirtualMicron

    box = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes_xml", "box.xml")
    scan = mitsonar.render_scan(mitsonar.load_scene(box), spp=256, seed=1)
    log = tmp_path / "micron.bin"
    with VirtualMicron(scan, realtime=False) as vm:
        record(vm.port, str(log), scans=1, settings=HeadSettings.from_scan(scan), timeout=30)
    proc = subprocess.run([sys.executable, "-m", "mitsonar.cli", "map", str(log), "-o", str(tmp_path / "map.npz"),
                           "--inducing", "300"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "1 scan(s)" in proc.stdout and (tmp_path / "map.npz").stat().st_size > 0


@pytest.mark.parametrize("args,expect", [
    # refused before the Gram matrix (75 GiB for 1e5 points) is allocated, or the map degenerates
    (["--inducing", "100000000"], r"--inducing must be at most the number of training samples \(\d+ from these "
                                  r"scans\), not 100000000"),
    # a grid of 1e10 points would need terabytes: refused before the fit, with a resolution that fits
    (["--inducing", "100", "--mesh", "m.ply", "--resolution", "0.0005"],
     r"--resolution 0\.0005 m: the scans reach [\d.]+ x [\d.]+ x [\d.]+ m \(their positions \+- range_max\), "
     r"a grid of [\d.e+]+ points \(at most 2e\+08\); use --resolution [\d.]+ or coarser"),
])
def test_map_refuses_sizes_it_cannot_fit(scan_files, tmp_path, args, expect):
    import re

    proc = run("map", scan_files[0], "-o", "m.npz", *args, cwd=str(tmp_path))
    line = one_error_line(proc)
    assert re.search(expect, line), line
    assert "allocate" not in line
    assert not (tmp_path / "m.npz").exists()  # a failed run writes nothing


def test_map_names_a_log_without_a_complete_scan(tmp_path):
    """A log that stops before the head finished one sweep: the file is named, not `fit()`."""
    from mitsonar import Scan
    from mitsonar.devices.micron.driver import record
    from mitsonar.devices.micron.seanet import HeadSettings
    from mitsonar.devices.micron.virtual import VirtualMicron

    from hilbertmap.testing import box_scan, orthogonal_frames

    s = box_scan(orthogonal_frames()[0], n_pings=40, bearing_step=9.0, seed=0, rays=100)
    scan = Scan(intensity=s.intensity, data=s.data, ranges=s.ranges, bearings=s.bearings, poses=s.poses,
                range_min=s.range_min, range_max=s.range_max, beamwidth_h=s.beamwidth_h, beamwidth_v=s.beamwidth_v)
    log = tmp_path / "half.bin"
    with VirtualMicron(scan, realtime=False) as vm:
        record(vm.port, str(log), pings=5, settings=HeadSettings.from_scan(scan), timeout=30)
    line = one_error_line(run("map", str(log), "-o", str(tmp_path / "m.npz")))
    assert f"{log}: no complete scan in the log" in line, line


# ----------------------------------------------------------------------------- output paths
@pytest.mark.parametrize("args,expect", [
    (["-o", "nodir/m.npz"], "-o nodir/m.npz: the folder nodir does not exist"),
    (["-o", "m.npz", "--plot", "nodir/q.png"], "--plot nodir/q.png: the folder nodir does not exist"),
    (["-o", "m.npz", "--mesh", "nodir/m.ply"], "--mesh nodir/m.ply: the folder nodir does not exist"),
    (["-o", "adir.npz"], "-o adir.npz: is a folder, not a file name"),
    (["-o", "m.npz", "--mesh", "afile/m.ply"], "--mesh afile/m.ply: afile is not a folder"),
])
def test_map_checks_every_output_before_reading_scans(tmp_path, args, expect):
    """The scan is not even a scan: the output's problem is reported first, before any work."""
    (tmp_path / "bad.npz").write_bytes(b"not a scan")
    (tmp_path / "adir.npz").mkdir()
    (tmp_path / "afile").write_text("")
    before = sorted(os.listdir(tmp_path))
    line = one_error_line(run("map", "bad.npz", *args, cwd=str(tmp_path)))
    assert line == f"mitsonar map: error: {expect}", line
    assert sorted(os.listdir(tmp_path)) == before


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes anywhere")
def test_map_refuses_a_folder_it_cannot_write(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        line = one_error_line(run("map", "bad.npz", "-o", "ro/m.npz", cwd=str(tmp_path)))
    finally:
        ro.chmod(0o700)
    assert "-o ro/m.npz: cannot write in the folder ro" in line, line


@pytest.mark.parametrize("name,content,expect", [
    ("garbage.bin", b"\x00\x01garbage", "garbage.bin: not a raw SeaNet log (it does not start with the log header"),
    ("scan.txt", b"x", "scan.txt: map reads .exr or .npz scans, or .bin raw SeaNet logs, not .txt"),
])
def test_map_names_the_kinds_of_input_it_reads(tmp_path, name, content, expect):
    (tmp_path / name).write_bytes(content)
    line = one_error_line(run("map", name, "-o", "m.npz", cwd=str(tmp_path)))
    assert expect in line, line
    assert sorted(os.listdir(tmp_path)) == [name]


def _map_args(*argv):
    import argparse

    from mitsonar.cli.map import add_subcommands

    parser = argparse.ArgumentParser()
    add_subcommands(parser.add_subparsers())
    return parser.parse_args(["map", *argv])


def test_map_writes_all_outputs_or_none(scan_files, tmp_path, monkeypatch, capsys):
    """Outputs go under temporary names and are renamed at the end: a plot that fails after the
    map and the mesh were written leaves no file at all; a run that succeeds leaves exactly its
    outputs, with the permissions a plain open would give."""
    import hilbertmap.plots

    out = [str(tmp_path / n) for n in ("m.npz", "m.ply", "s.png")]
    args = _map_args(scan_files[0], "-o", out[0], "--mesh", out[1], "--plot", out[2], "--inducing", "100",
                     "--passes", "1", "--resolution", "0.3", "-q")      # -q: no progress bars on stderr

    def full_disk(*a, **k):
        raise OSError(28, "No space left on device")

    with monkeypatch.context() as m:
        m.setattr(hilbertmap.plots, "plot_slices", full_disk)
        assert args.func(args) != 0
    err = capsys.readouterr().err.strip()
    assert err == f"mitsonar map: error: --plot {out[2]}: No space left on device", err
    assert os.listdir(tmp_path) == []

    assert args.func(args) == 0
    assert sorted(os.listdir(tmp_path)) == ["m.npz", "m.ply", "s.png"]
    umask = os.umask(0)
    os.umask(umask)
    assert all((os.stat(p).st_mode & 0o777) == 0o666 & ~umask for p in out)


def test_map_output_check_reports_an_unwritable_folder(tmp_path, monkeypatch):
    """The same check in-process, for runs as root (who may write anywhere)."""
    from mitsonar.cli import map as map_cli

    monkeypatch.setattr(map_cli.os, "access", lambda path, mode: False)
    assert map_cli._output_problem("--plot", str(tmp_path / "q.png")) == \
        f"--plot {tmp_path / 'q.png'}: cannot write in the folder {tmp_path} (permission denied)"


# ----------------------------------------------------------------------------- progress, Ctrl-C

def test_map_reports_its_progress_on_stderr_and_nothing_with_quiet(scan_files, tmp_path, monkeypatch, capsys):
    """Issue 56: a fit of 15-170 s printed nothing. Each stage that takes over half a second has its
    bar (tqdm, on stderr): here the SGD's, counting the mini-batches of its 8 passes. The half
    second is set to 0 so that the bar does not depend on this machine's speed."""
    import re

    from mitsonar.cli import map as map_cli
    from mitsonar.cli.main import main

    monkeypatch.setattr(map_cli._FitProgress, "DELAY", 0.0)
    assert main(["map", *scan_files, "-o", str(tmp_path / "m.npz"), "--inducing", "300", "--passes", "8"]) == 0
    out, err = capsys.readouterr()
    counts = [(int(a), int(b)) for a, b in re.findall(r"map: SGD: +\d+%\|[^|]*\| *(\d+)/(\d+) \[", err)]
    assert counts and counts[0][1] % 8 == 0 and all(b == counts[0][1] for _, b in counts), err
    assert counts[-1][0] > counts[0][0] and "batch/s" in err, err
    assert "Traceback" not in err
    assert out.startswith("map: 3 scan(s)")
    assert main(["map", *scan_files, "-o", str(tmp_path / "m.npz"), "--inducing", "300", "--passes", "8", "-q",
                 "--force"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and out == "", err


def test_a_sigint_mid_fit_ends_map_with_130_and_writes_nothing(scan_files, tmp_path):
    """Ctrl-C during the SGD (1000 passes: the fit would run for minutes) ends the command with
    exit code 130 before the fit is done, no output left behind."""
    import re
    import signal
    import threading

    out = tmp_path / "m.npz"
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    proc = subprocess.Popen([sys.executable, "-m", "mitsonar.cli", "map", *scan_files, "-o", str(out), "--inducing",
                             "300", "--passes", "1000", "--plot", str(tmp_path / "s.png")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT, env=env)
    err = bytearray()
    in_sgd = threading.Event()

    def read():
        while chunk := os.read(proc.stderr.fileno(), 4096):
            err.extend(chunk)
            if any(int(n) > 0 for n in re.findall(rb"\| *(\d+)/\d+", err.split(b"map: SGD")[-1])) \
                    and b"map: SGD" in err:
                in_sgd.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert in_sgd.wait(300), bytes(err)        # a bound against hanging only
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=300)                     # stderr is the reader's alone (communicate would race it)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(10)
    stdout = proc.stdout.read()
    text = err.decode(errors="replace")
    assert proc.returncode == 130, text
    assert text.rstrip().endswith("mitsonar: interrupted") and "Traceback" not in text
    done, total = (int(x) for x in text.split("map: SGD")[-1].split("|")[2].split()[0].split("/"))
    assert 0 < done < total == 1000 * (total // 1000)       # stopped inside the passes
    assert stdout == b"" and os.listdir(tmp_path) == []


def test_ctrl_c_during_the_eigen_decomposition_acts_before_it_returns(monkeypatch):
    """The Gram matrix's eigen-decomposition is one LAPACK call (seconds to minutes): a Ctrl-C in the
    thread that made it acted only when it returned. It runs in a worker now, and the interrupt
    acts while it still runs. Here the call is held until released, SIGINT blocked in its thread
    as in native code that runs no Python handler."""
    import signal
    import threading

    from hilbertmap import HilbertMap
    from hilbertmap.testing import box_scan, orthogonal_frames

    scan = box_scan(orthogonal_frames()[0], n_pings=20, bearing_step=18.0, seed=0, rays=50)
    started, release, caught = threading.Event(), threading.Event(), threading.Event()
    real = np.linalg.eigh

    def held_eigh(G):
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            started.set()
            release.wait(120)
            return real(G)
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})

    def interrupt():
        started.wait(120)
        os.kill(os.getpid(), signal.SIGINT)
        caught.wait(60)         # a bound only: the old code waited here for the call to return
        release.set()

    monkeypatch.setattr(np.linalg, "eigh", held_eigh)
    threading.Thread(target=interrupt, daemon=True).start()
    released_first = None
    try:
        HilbertMap(n_inducing=40, n_passes=1, random_state=0).fit([scan])
    except KeyboardInterrupt:
        released_first = release.is_set()
        caught.set()
    assert released_first is False         # interrupted while the call was still held
