"""`mitsonar virtual-sonar --head ping360`, `record --head ping360`, `replay` of a Ping360 log:
end to end through a pty, one-line errors, options of the other head refused."""
from __future__ import annotations

import os

import numpy as np
import pytest

import mitsonar
from mitsonar.devices.ping360.head import Ping360Settings
from mitsonar.devices.ping360.virtual import VirtualPing360

from test_ping360 import synthetic_scan
from test_serial_cli import cli, one_error_line

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")

BOX = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes_xml", "box.xml")


def test_record_then_replay_cli(tmp_path, capsys):
    scan = synthetic_scan(n_pings=40, step_deg=-9.0, seed=3)
    log = tmp_path / "p360.bin"
    with VirtualPing360(scan, realtime=False) as vm:
        assert cli("record", vm.port, "--head", "ping360", "-o", log, "--scans", "2", "--range", "2.4",
                   "--n-bins", "200", "--step", "10", "--gain", "high", "--frequency", "800",
                   "--transmit-duration", "20") == 0
        assert vm.state["gain_setting"] == 2 and vm.state["transmit_frequency"] == 800
        assert vm.state["transmit_duration"] == 20
    assert "(80 pings) to" in capsys.readouterr().out
    assert cli("replay", log, "-o", tmp_path / "scan.npz", "--all") == 0
    for k in range(2):
        got = mitsonar.load_scan(str(tmp_path / f"scan_{k:03d}.npz"))
        assert np.array_equal(got.data, scan.data)
        np.testing.assert_allclose(got.bearings, scan.bearings, atol=1e-12)
        assert (got.beamwidth_h, got.beamwidth_v) == (2.0, 25.0)


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_virtual_sonar_cli_serves_a_ping360_that_brping_can_read(signame):
    """The printed port answers brping.Ping360 while the command serves; Ctrl-C (SIGINT) or a
    service manager's SIGTERM ends it cleanly (exit 0, no traceback).

    The command serves until it is interrupted, as a user runs it, not for a fixed number of
    seconds: a window of 3 s, which brping had to fit in, depended on the machine's load. It is
    started with SIGINT ignored, as a non-interactive shell starts a background job (`cmd &`):
    Python then installs no KeyboardInterrupt, and the head served on until killed (the suite
    run in the background hung here for 120 s)."""
    import contextlib
    import io
    import signal
    import subprocess
    import sys

    from brping import Ping360

    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    proc = subprocess.Popen([sys.executable, "-m", "mitsonar", "virtual-sonar", BOX, "--head", "ping360", "--spp",
                             "8", "--fast"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        lines = []
        for line in proc.stdout:  # ends (at EOF) if the command dies before serving
            lines.append(line)
            if "virtual Ping360 on" in line:
                break
        text = "".join(lines)
        assert "virtual Ping360 on /dev/" in text and "nearest rendered bearing" in text, (text, proc.stderr)
        port = text.split("virtual Ping360 on ")[1].split()[0]
        p = Ping360()
        with contextlib.redirect_stdout(io.StringIO()):
            p.connect_serial(port, 115200)
        try:
            assert p.initialize()
            assert p.set_number_of_samples(500) is not None and p.set_sample_period(1280) is not None
            assert len(p.transmitAngle(0).data) == 500
        finally:
            p.iodev.close()
        proc.send_signal(getattr(signal, signame))
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0 and "Traceback" not in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


@pytest.mark.parametrize("argv,message", [
    (["record", "/dev/null", "-o", "{tmp}/x.bin", "--head", "ping360", "--passive", "--seconds", "1"],
     "--passive is for --head micron, not ping360"),
    (["record", "/dev/null", "-o", "{tmp}/x.bin", "--gain", "high"], "--gain is for --head ping360, not micron"),
    (["record", "/dev/null", "-o", "{tmp}/x.bin", "--head", "ping360", "--step", "3"],
     "Ping360Settings 'step': 3 is not allowed (a divisor of 400"),
    (["record", "/dev/null", "-o", "{tmp}/x.bin", "--head", "ping360", "--n-bins", "100"],
     "Ping360Settings 'number_of_samples': 100 is not allowed (a whole number 200..1200 samples)"),
    (["record", "/dev/null", "-o", "{tmp}/x.bin", "--head", "ping360", "--transmit-duration", "5000"],
     "'transmit_duration': 5000 is not allowed"),
    (["record", "udp://127.0.0.1", "-o", "{tmp}/x.bin", "--head", "ping360"],
     "cannot open udp://127.0.0.1: needs a host and a port"),
    (["virtual-sonar", BOX, "--head", "ping360", "--no-dst"], "--no-dst is for --head micron, not ping360"),
    (["virtual-sonar", BOX, "--head", "ping360", "--port-url", "udp://10.0.0.1:0"], "loopback only"),
])
def test_errors_are_one_line(tmp_path, capsys, argv, message):
    name = argv[0]
    assert cli(*[a.replace("{tmp}", str(tmp_path)) for a in argv]) == 1
    assert message in one_error_line(capsys, name)
    assert not list(tmp_path.iterdir())


def test_record_from_a_silent_port_says_so_and_leaves_no_file(tmp_path, capsys):
    master, slave = os.openpty()
    try:
        assert cli("record", os.ttyname(slave), "--head", "ping360", "-o", tmp_path / "x.bin",
                   "--timeout", "0.3", "--pings", "1") == 1
    finally:
        os.close(master)
        os.close(slave)
    assert "no bytes from the head on" in one_error_line(capsys, "record")
    assert not list(tmp_path.iterdir())


def test_record_keeps_what_arrived_on_ctrl_c(tmp_path, capsys, monkeypatch):
    from mitsonar.devices.ping360 import driver as ping360
    scan = synthetic_scan(n_pings=40, step_deg=-9.0, seed=3)
    budget = iter(range(5))      # five pings, then the user presses Ctrl-C
    read = ping360.Ping360Sonar.read_ping

    def read_until_ctrl_c(self):
        if next(budget, None) is None:
            raise KeyboardInterrupt
        return read(self)

    monkeypatch.setattr(ping360.Ping360Sonar, "read_ping", read_until_ctrl_c)
    log = tmp_path / "p360.bin"
    with VirtualPing360(scan, realtime=False) as vm:
        assert cli("record", vm.port, "--head", "ping360", "-o", log, "--range", "2.4", "--n-bins", "200",
                   "--step", "10") == 0
    assert "(5 pings) to" in capsys.readouterr().out and log.is_file()
    assert cli("replay", log, "-o", tmp_path / "s.npz", "--partial") == 0
    got = mitsonar.load_scan(str(tmp_path / "s.npz"))
    assert np.array_equal(got.data[:5], scan.data[:5]) and got.meta.missing == list(range(5, 40))
    assert Ping360Settings(range=2.4, number_of_samples=200, step=10).angles == got.meta.angles
