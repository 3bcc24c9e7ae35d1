"""`mitsonar live` in real time: paths fitted to a budget (no recompilation), the error
estimate against a high-path reference, per-ping records (latency to the bytes written),
multibeam frames at their period with late ones skipped and counted, and the reliability
items (no pose yet said once, clients reconnecting, records complete after SIGTERM)."""
from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import signal
import socket
import time

import numpy as np
import pytest
from conftest import subcommand_runner

from mitsonar.live.poses import PoseBuffer
from mitsonar.live.realtime import SPP_LADDER, ErrorModel, PathBudget, PingLog, WireClock
from test_live import live_process

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOX = os.path.join(ROOT, "scenes_xml", "box.xml")
BOX_FLS = os.path.join(ROOT, "scenes_xml", "box_fls.xml")      # a 256-beam multibeam in the box


# ---------------------------------------------------------------- the budget

def test_the_ladder_is_few_sizes_that_use_fewer_pass_sizes_than_frozen_recordings_kept():
    from mitsonar.plugins.integrators import sonar_tof
    from mitsonar.plugins.integrators.paths import frozen_pass

    assert SPP_LADDER[0] == 16 and SPP_LADDER[-1] == 2 ** 22
    assert [n for n in SPP_LADDER if 64 <= n <= 256] == [64, 96, 128, 192, 256]
    b = PathBudget(1.0)
    assert b.quantise(100) == 96 and b.quantise(96) == 96 and b.quantise(3) == 16 and b.quantise(1e12) == 2 ** 22
    # the pass sizes (a pass: at most MAX_SPP_PER_PASS paths, or a power of two fewer per beam)
    tof, frozen = sonar_tof, frozen_pass
    for most in (tof.MAX_SPP_PER_PASS, tof.MAX_LANES_PER_PASS // 256):
        sizes = {min(n, most) for n in SPP_LADDER} | {n % most for n in SPP_LADDER if n > most and n % most}
        assert len(sizes) <= 25 < frozen.MAX_RECORDINGS, (most, sorted(sizes))


def test_paths_converge_to_fill_the_budget_with_a_fixed_cost():
    """t(n) = a + b n: the chosen paths converge to the ladder size under (0.8 B - a) / b,
    the fixed point of n' = 0.8 B n / t(n) (contraction a / (0.8 B) per ping)."""
    a, b, budget = 0.004, 2e-6, 0.05
    pb = PathBudget(budget, first=64)
    n = pb.next()
    assert n == 64
    for _ in range(60):
        pb.measured(n, a + b * n)
        n = pb.next()
    target = (0.8 * budget - a) / b                     # 18000 paths
    assert n == pb.quantise(target) or n == pb.quantise(target * 0.999), (n, target)
    # a tighter budget: fewer paths; a budget under the fixed cost: the smallest size
    assert pb.next(budget / 4) < n
    under = PathBudget(a / 2, first=64)
    n = under.next()
    for _ in range(10):
        under.measured(n, a + b * n)
        n = under.next()
    assert n == SPP_LADDER[0]
    with pytest.raises(ValueError, match="budget"):
        PathBudget(0.0)


@pytest.fixture(scope="module")
def box_scene():
    from mitsonar.live.heads import live_scene
    from mitsonar.sim.render import pick_sensor

    scene = live_scene(BOX)
    return scene, pick_sensor(scene)


def test_other_numbers_of_paths_launch_the_same_kernels(box_scene):
    """The budget may pick any ladder size: no size compiles new kernels; a size seen before
    replays its frozen pass (no new recording)."""
    from conftest import jit_kernels
    from mitsonar.live.heads import PingRenderer

    from mitsonar.plugins.integrators.paths import frozen_pass

    frozen = frozen_pass
    # start with no recordings: earlier tests' recordings could fill MAX_RECORDINGS mid-test,
    # and the clear it triggers would be counted as new recordings below
    frozen.clear()
    scene, sonar = box_scene
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=16, out=io.StringIO(), calibration=0)
    r.render(0.0)
    r.render(0.2)    # the bearing's speckle field (two kernels of its own) computed once, then cached
    kernels = []
    sizes = (16, 96, 1024, 96 * 1024)            # the last: a pass of 2**16 and one of 2**15
    for n in sizes:
        r.spp = n
        kernels.append(sorted(set(jit_kernels(r.render, 0.2)[0])))
    assert kernels[0] and all(k == kernels[0] for k in kernels), kernels
    recorded = []
    for _ in range(2):          # (outside jit_kernels: its kernel history makes other recordings)
        for n in sizes:
            r.spp = n
            r.render(0.3)
        recorded.append(len(frozen._alive))
    assert recorded[1] == recorded[0], recorded


def test_a_tight_budget_renders_fewer_paths_than_a_loose_one(box_scene):
    from mitsonar.live.heads import PingRenderer

    scene, sonar = box_scene
    paths = {}
    for name, budget in (("tight", 1e-6), ("loose", 1.0)):
        r = PingRenderer(scene, sonar, PoseBuffer(), spp=None, budget=budget, out=io.StringIO(), calibration=0)
        r.warm()                # the time per path of a 64-path render: t64 / 64
        r.render(0.1)
        paths[name] = r.last_record["paths"]
        assert r.last_record["budget_ms"] == pytest.approx(budget * 1e3)
    # 0.8 x budget x 64 / t64 paths: the smallest size for 1 us on any machine (t64 > 3.2 us),
    # more for 1 s on any machine where 64 paths take less than 3.2 s
    assert paths["tight"] == SPP_LADDER[0] and paths["loose"] > paths["tight"], paths


def test_the_error_estimate_is_within_a_factor_two_of_the_measured_error(box_scene):
    """The estimate (the table measured at 16, 64, ... 4096 paths at the mount, interpolated)
    against the error of renders at other sizes measured against a 2**18-path reference: within
    a factor 2 at 32 and 128 paths (interpolated), 3 at 16384 (extrapolated as 1/sqrt(n))."""
    from mitsonar.live.heads import PingRenderer
    from mitsonar.sim.render import render_scan

    scene, sonar = box_scene
    r = PingRenderer(scene, sonar, None, spp=64, seed=3, calibration=8, out=io.StringIO())
    r.warm()
    assert sorted(r.error.table) == [16, 64, 256, 1024, 4096]
    ref = render_scan(scene, spp=2 ** 18, seed=999, pose=r.mount, sensor=sonar).intensity
    for n, factor in ((32, 2.0), (128, 2.0), (16384, 3.0)):
        errs = [ErrorModel.relative_error(render_scan(scene, spp=n, seed=100 + i, pose=r.mount, sensor=sonar).intensity,
                                          ref) for i in range(6)]
        measured = math.sqrt(np.mean(np.square(errs)))
        est = r.error(n)
        assert measured / factor <= est <= measured * factor, (n, est, measured)


def test_the_error_table_interpolates_log_log_and_falls_as_one_over_root_n_beyond():
    m = ErrorModel({16: 0.4, 64: 0.1})
    assert m(16) == 0.4 and m(8) == 0.4
    assert m(32) == pytest.approx(0.2, rel=1e-12)          # sqrt(0.4 * 0.1)
    assert m(256) == pytest.approx(0.05, rel=1e-12)
    assert math.isnan(ErrorModel()(100))
    rows = [[1.0, 3.0], [3.0, 1.0]]                        # mean [2, 2], var [2, 2]
    assert ErrorModel.spread(rows) == pytest.approx(math.sqrt(4.0 / 8.0))
    assert math.isnan(ErrorModel.spread([[0.0, 0.0], [0.0, 0.0]]))


# ---------------------------------------------------------------- records

@pytest.mark.parametrize("ext", ["csv", "jsonl"])
def test_records_are_written_under_a_temporary_name_and_renamed_on_close(tmp_path, ext):
    path = tmp_path / f"pings.{ext}"
    log = PingLog(path)
    for k in range(3):
        log.add({"ping": k, "t": 1.5 + k, "pose_time": 10.0 + k, "bearing": None if k == 2 else 0.5 * k,
                 "paths": 64 * (k + 1), "error": float("nan") if k == 1 else 0.1, "render_ms": 3.0,
                 "latency_ms": 4.0 + k, "budget_ms": 46.0})
    assert not path.exists() and (tmp_path / f"pings.{ext}.part").exists()
    log.close()
    log.close()
    assert path.exists() and not (tmp_path / f"pings.{ext}.part").exists()
    if ext == "csv":
        rows = list(csv.DictReader(path.open()))
        assert [r["paths"] for r in rows] == ["64", "128", "192"] and rows[1]["error"] == "" and rows[2]["bearing"] == ""
    else:
        rows = [json.loads(line) for line in path.open()]
        assert [r["latency_ms"] for r in rows] == [4.0, 5.0, 6.0] and rows[1]["error"] is None
    assert log.percentiles("latency_ms") == pytest.approx([5.0, 5.9, 5.98])
    assert "latency ms p50 5.0" in log.summary()
    (tmp_path / "dir.csv").mkdir()           # os.replace onto it would fail only when the session ends
    for bad, why in ((tmp_path / "x.txt", "ending in .csv or .jsonl"), (tmp_path / "no" / "x.csv", "does not exist"),
                     (tmp_path / "dir.csv", "is a folder")):
        with pytest.raises(ValueError, match=why):
            PingLog(bad)


def test_the_wire_clock_stamps_a_reply_when_its_last_byte_is_written():
    clock, done = WireClock(), []
    clock.queue(10)                                  # an earlier message
    clock.queue(100, lambda t: done.append(("a", t)))
    clock.queue(5, lambda t: done.append(("b", t)))
    clock.wrote(50, 1.0)
    assert done == []
    clock.wrote(60, 2.0)                             # 110 bytes: a's last byte
    assert done == [("a", 2.0)]
    clock.wrote(5, 3.0)
    assert done == [("a", 2.0), ("b", 3.0)]
    clock.queue(7, lambda t: done.append(("lost", t)))
    clock.resync()                                   # the head dropped its output
    clock.queue(3, lambda t: done.append(("c", t)))
    clock.wrote(3, 4.0)
    assert done[-1] == ("c", 4.0) and len(done) == 3


def test_live_ping360_records_each_reply_with_its_latency_to_the_bytes(box_scene):
    """Through Blue Robotics' client: one record per reply, the latency at least the render
    (the pose time is before the render, the bytes after it), the budget the head's ping time."""
    brping = pytest.importorskip("brping")
    from mitsonar.live.heads import LivePing360, PingRenderer

    scene, sonar = box_scene
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=None, out=io.StringIO(), calibration=2)
    with LivePing360(r, "udp://127.0.0.1:0", realtime=False) as head:
        p = brping.Ping360()
        host, port = head.port[len("udp://"):].rsplit(":", 1)
        with contextlib.redirect_stdout(io.StringIO()):
            p.connect_udp(host, int(port))
        assert p.initialize()
        n, period = 600, 1067
        assert p.set_number_of_samples(n) is not None and p.set_sample_period(period) is not None
        for a in range(5):
            assert p.transmitAngle(a) is not None
        p.iodev.close()
        for _ in range(100):             # the last reply's record: after its write
            if r.log.count >= 5:
                break
            time.sleep(0.02)
    recs = list(r.log.records)
    assert [x["ping"] for x in recs] == [0, 1, 2, 3, 4]
    listen = n * period * 25e-9
    for x in recs:
        assert x["latency_ms"] >= x["render_ms"] > 0
        assert x["budget_ms"] == pytest.approx((listen + 32e-6 + 0.0005) * 1e3)
        assert x["paths"] in SPP_LADDER and x["error"] > 0


def test_the_live_micron_renders_at_the_request_and_records_each_scanline(box_scene):
    """The SeaNet driver's scanlines: each rendered when its mtSendData arrives, from the pose
    at that time (so its bytes, which the timing model sends a ping period after the request,
    come at least a period after the pose time), one record per scanline, budget = its period."""
    from mitsonar.live.heads import LiveMicron, PingRenderer
    from mitsonar.devices.micron.driver import MicronSonar
    from mitsonar.devices.micron.seanet import HeadSettings

    if not hasattr(os, "openpty"):
        pytest.skip("needs pseudo-terminals")
    scene, sonar = box_scene
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=64, out=io.StringIO(), calibration=2)
    settings = HeadSettings(range=12.0, n_bins=500)
    with LiveMicron(r, realtime=True) as vm:
        with MicronSonar(vm.port, settings=settings, timeout=20) as driver:
            for _ in range(4):
                driver.read_ping()
        for _ in range(100):
            if r.log.count >= 4:
                break
            time.sleep(0.02)
        period = vm.ping_period()
    recs = list(r.log.records)
    assert len(recs) >= 4 and all(x["latency_ms"] >= max(x["render_ms"], x["budget_ms"]) for x in recs), recs
    s = vm.settings
    assert period == pytest.approx(18 * 10 / 115200 + s.n_bins * s.sampling_interval + vm.motor_time)
    assert all(x["budget_ms"] == pytest.approx(period * 1e3) for x in recs)


# ---------------------------------------------------------------- multibeam frames

def test_multibeam_frames_come_at_the_ping_period_and_late_ones_are_skipped_and_counted():
    from mitsonar.live.framing import FrameLoop
    from mitsonar.live.heads import PingRenderer, live_scene
    from mitsonar.sim.render import pick_sensor

    scene = live_scene(BOX_FLS)
    sonar = pick_sensor(scene)
    assert sonar.sonar_kind.transmit_fan and sonar.n_pings == 256      # the fan is kept whole
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=16, out=io.StringIO(), calibration=0)
    r.warm()
    got, rate = [], 8.0
    period = 1.0 / rate

    def consumer(t_ns, vehicle, mount, scan):
        got.append((t_ns, scan.n_pings, vehicle.copy(), mount))
        if len(got) == 2:               # a slow consumer: frame 1 keeps the loop 2.5 periods
            time.sleep(2.5 * period)

    def broken(*_):
        raise RuntimeError("a consumer that fails")

    r.poses.add([1.0, 0.5, 0.0], [0, 0, 0, 1])
    loop = FrameLoop(r, rate, on_frame=[broken, consumer], out=io.StringIO())
    loop.start()
    time.sleep(1.6)
    for _ in range(600):                # a slow machine: until a frame after the slow one
        if len(got) >= 3:
            break
        time.sleep(0.1)
    stopping = time.monotonic()
    loop.stop()
    stopped = time.monotonic()
    frames, skipped = loop.stats["frames"], loop.stats["late frames skipped"]
    assert frames == len(got) == r.log.count and loop.stats["consumer errors"] == frames
    # every frame's time is on the grid t0 + k / rate; the skipped ones are the missing k
    ks = [(t - got[0][0]) * 1e-9 / period for t, *_ in got]
    assert all(abs(k - round(k)) < 1e-3 for k in ks)
    assert round(ks[-1]) + 1 == frames + skipped == loop.due
    # frame 1's consumer held the loop 2.5 periods: at least the next frame was more than a
    # period late when the loop looked again
    assert skipped >= 1 and round(ks[2]) - round(ks[1]) >= 2
    # the frames due during the run: at most one per period until the loop stopped, at least
    # those due when the last frame began (at most the longest frame, render and consumers and
    # lateness, before the stop)
    longest = max(x["latency_ms"] for x in r.log.records) * 1e-3
    assert math.floor((stopping - loop_t0(loop) - longest) * rate) <= loop.due
    assert loop.due <= math.floor((stopped - loop_t0(loop)) * rate) + 1
    assert all(n == 256 for _, n, _, _ in got)
    np.testing.assert_allclose(got[-1][2][:3, 3], [1.0, 0.5, 0.0])
    np.testing.assert_array_equal(got[-1][3], r.mount)
    assert [x["ping"] for x in r.log.records] == [round(k) for k in ks]
    assert r.log.skipped == skipped


def loop_t0(loop):
    return loop.t0


def test_live_multibeam_without_head_publishes_frames_and_records_them_after_sigterm(tmp_path):
    records = tmp_path / "frames.jsonl"
    proc, text = live_process(BOX_FLS, "--ping-rate", "5", "--spp", "16", "--records", str(records))
    try:
        assert "live multibeam sonar at 5 Hz" in text, (text, proc.stderr)
        proc.send_signal(signal.SIGUSR1)
        assert "pings rendered" in proc.stdout.readline()
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert "frames published of" in out
    published = int(out.split(" frames published of")[0].rsplit(" ", 1)[1])
    rows = [json.loads(line) for line in records.open()]
    assert len(rows) == published >= 1 and not (tmp_path / "frames.jsonl.part").exists()
    assert all(r["paths"] == 16 and r["bearing"] is None and r["latency_ms"] > 0 for r in rows)


def test_bad_real_time_options_are_one_line_before_the_scene_loads(capsys, tmp_path):
    from mitsonar.cli import live as live_cli
    from test_serial_cli import one_error_line

    cli = subcommand_runner(live_cli)

    assert cli("live", BOX, "--spp", "64", "--budget-ms", "20") == 1
    assert "give one" in one_error_line(capsys, "live")
    assert cli("live", BOX, "--records", tmp_path / "x.txt") == 1
    assert "ending in .csv or .jsonl" in one_error_line(capsys, "live")
    assert cli("live", BOX, "--head", "ping360", "--ping-rate", "10") == 1
    assert "--ping-rate is for multibeam frames" in one_error_line(capsys, "live")
    assert cli("live", BOX_FLS, "--port-url", "udp://127.0.0.1:0") == 1
    assert "--port-url is for a head" in one_error_line(capsys, "live")
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- reliability

def test_no_pose_yet_pings_from_the_origin_and_says_so_once(box_scene):
    from mitsonar.live.heads import PingRenderer

    scene, sonar = box_scene
    out = io.StringIO()
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=16, out=out, calibration=0)
    for k in range(3):
        r.render(0.1 * k)
        np.testing.assert_array_equal(r.last_vehicle, np.eye(4))
    assert out.getvalue().count("no vehicle pose yet") == 1


def test_ping360_clients_connect_drop_and_reconnect(box_scene):
    """Three clients one after the other (each its own UDP port), the second leaving in the
    middle of a request: each later client is answered."""
    from mitsonar.live.heads import LivePing360, PingRenderer
    from mitsonar.devices.ping360.protocol import Message, StreamParser, encode

    scene, sonar = box_scene
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=16, out=io.StringIO(), calibration=0)

    def ping(port, angle, wait=True):
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        tx.settimeout(30)
        tx.sendto(encode(Message("transducer", mode=1, gain_setting=1, angle=angle, transmit_duration=32,
                                 sample_period=80, transmit_frequency=740, number_of_samples=200,
                                 transmit=1)), ("127.0.0.1", port))
        got = None
        parser = StreamParser()
        while wait and got is None:
            for m in parser.feed(tx.recv(65536)):
                if m.name == "device_data":
                    got = m.angle
        tx.close()
        return got

    with LivePing360(r, "udp://127.0.0.1:0", realtime=False) as head:
        port = int(head.port.rsplit(":", 1)[1])
        assert ping(port, 10) == 10
        ping(port, 20, wait=False)          # gone before its answer
        assert ping(port, 30) == 30
        assert head.last_error is None and head.stats["internal errors"] == 0


def test_the_micron_driver_reconnects_to_the_live_head(box_scene):
    from mitsonar.live.heads import LiveMicron, PingRenderer
    from mitsonar.devices.micron.driver import MicronSonar
    from mitsonar.devices.micron.seanet import HeadSettings

    if not hasattr(os, "openpty"):
        pytest.skip("needs pseudo-terminals")
    scene, sonar = box_scene
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=16, out=io.StringIO(), calibration=0)
    settings = HeadSettings(range=12.0, n_bins=500)
    with LiveMicron(r, realtime=False) as vm:
        for _ in range(2):                  # connect, read, drop; and again
            with MicronSonar(vm.port, settings=settings, timeout=20) as driver:
                assert driver.read_ping().bearing is not None
        assert vm.stats["internal errors"] == 0



def test_the_log_keeps_a_fixed_ring_for_its_percentiles():
    """Memory stays flat: the percentiles are over the newest ``keep`` pings, held in a ring
    allocated once; the record dicts kept are the newest 256."""
    log = PingLog(keep=100)
    ring = log._ring
    for k in range(1000):
        log.add({"ping": k, "latency_ms": float(k), "paths": 16, "error": 0.1, "render_ms": 1.0})
    assert log._ring is ring and ring.shape[0] == 100 and len(log.records) == 256 and log.count == 1000
    assert log.percentiles("latency_ms", (0, 100)) == [900.0, 999.0]


def _cli(*argv):
    from mitsonar.cli import live as live_cli

    return subcommand_runner(live_cli)(*argv)


def test_ping_rate_for_a_scene_without_a_multibeam_is_refused_not_ignored(capsys, tmp_path):
    from test_serial_cli import one_error_line

    # no --head: the scene's mechanical sonar becomes a head, which has no frames to rate
    assert _cli("live", BOX, "--ping-rate", "10", "--seconds", "0.1", "--records", tmp_path / "r.csv") == 1
    assert "--ping-rate is for multibeam frames" in one_error_line(capsys, "live")
    assert not list(tmp_path.iterdir())


def test_records_discard_leaves_no_file(tmp_path):
    log = PingLog(tmp_path / "r.jsonl")
    log.add({"ping": 0, "paths": 16})
    log.discard()
    log.close()
    assert not list(tmp_path.iterdir())


def test_a_session_that_fails_to_start_leaves_no_records_file(capsys, tmp_path):
    pytest.importorskip("pymavlink")
    from test_serial_cli import one_error_line

    # 203.0.113.1 (TEST-NET-3) is no address of this machine: the MAVLink port cannot open, after
    # the scene loaded and the records file was opened
    assert _cli("live", BOX, "--spp", "16", "--seconds", "0.1", "--mavlink", "udpin:203.0.113.1:14550",
                "--records", tmp_path / "r.csv") != 0
    capsys.readouterr()
    assert not list(tmp_path.iterdir())


def test_two_threads_sharing_a_renderer_render_distinct_pings_and_read_their_own_records(box_scene):
    """A frame loop and a head may render with one `PingRenderer` at once: each ping takes its own
    number (its seed), and ``last_record`` is the calling thread's. Both threads are held at the
    renderer's lock until both are there (a barrier, not a timing): before the fix, both had read
    the ping count (0) before taking it."""
    import threading

    from mitsonar.live.heads import PingRenderer

    scene, sonar = box_scene
    r = PingRenderer(scene, sonar, PoseBuffer(), spp=16, out=io.StringIO(), calibration=0)
    barrier = threading.Barrier(2)

    class Gate:
        def __init__(self, lock):
            self.lock = lock

        def __enter__(self):
            barrier.wait(60)
            return self.lock.__enter__()

        def __exit__(self, *exc):
            return self.lock.__exit__(*exc)

    r.lock = Gate(r.lock)
    seen = {}

    def ping(bearing):
        r.render(bearing)
        seen[bearing] = r.last_record

    threads = [threading.Thread(target=ping, args=(b,)) for b in (0.25, 0.5)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert sorted(rec["ping"] for rec in seen.values()) == [0, 1]
    assert all(rec["bearing"] == b for b, rec in seen.items())
    assert r.stats["pings"] == 2


def test_the_live_banner_names_a_multibeam_once_when_its_id_is_its_kind(tmp_path):
    """Issue 56: harbour.xml's multibeam (id "multibeam") was announced as "live multibeam
    multibeam"; the id is said only when it adds something (box_fls's "sonar" still is)."""
    with open(BOX_FLS, encoding="utf-8") as fh:
        xml = fh.read()
    assert '<sensor type="sonar" id="sonar">' in xml
    scene = tmp_path / "fls_multibeam.xml"
    scene.write_text(xml.replace('<sensor type="sonar" id="sonar">', '<sensor type="sonar" id="multibeam">'),
                     encoding="utf-8")
    proc, text = live_process(str(scene), "--ping-rate", "5", "--spp", "16", "--seconds", "0.2")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    banner = [line for line in text.splitlines() if line.startswith("live ")]
    assert banner == ["live multibeam at 5 Hz"], (text, err)
