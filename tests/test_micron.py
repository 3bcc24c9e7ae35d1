"""Micron driver against the virtual Micron through real pseudo-terminals; logs and replay.

Every test runs the virtual head with ``realtime=False`` and short timeouts; every blocking
call is bounded by a timeout, and the head's thread is joined with a timeout on exit.
"""
from __future__ import annotations

import math
import os
import threading
import time

import numpy as np
import pytest

from mitsonar.devices.micron.assembler import ScanAssembler, beam_rotation
from mitsonar.devices.micron.driver import MicronSonar, SonarError, SonarTimeout, record
from mitsonar.devices.rawlog import read_log
from mitsonar.devices.recording import replay
from mitsonar.scan import Scan
from mitsonar.devices.micron.seanet import HdCtrl, HeadData, HeadSettings, bearing_to_radians
from mitsonar.devices.micron.virtual import Faults, VirtualMicron

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")

FAST = dict(timeout=5.0, ping_timeout=0.25, boot_timeout=2.0)


def synthetic_scan(n_pings=200, n_bins=500, range_max=12.0, start_deg=0.0, step_deg=1.8, seed=1,
                   pose=None, bit_depth=8):
    """A Scan as the renderer would return it, with random device bytes (exact test data)."""
    rng = np.random.default_rng(seed)
    data = rng.integers(0, 256, (n_pings, n_bins), dtype=np.uint8)
    if bit_depth == 4:
        data = (data // 17 * 17).astype(np.uint8)
    bearings = np.radians(start_deg + np.arange(n_pings) * step_deg)
    T = np.eye(4) if pose is None else pose
    return Scan(intensity=rng.random((n_pings, n_bins)).astype(np.float32), data=data,
                ranges=(np.arange(n_bins) + 0.5) * range_max / n_bins, bearings=bearings,
                poses=T @ beam_rotation(bearings), range_min=0.0, range_max=range_max,
                electronics={"bit_depth": bit_depth})


MOUNT = np.array([[0.0, 0.0, 1.0, 1.5], [1.0, 0.0, 0.0, -2.0], [0.0, 1.0, 0.0, 0.25], [0, 0, 0, 1]])
SCAN = synthetic_scan(pose=MOUNT)


def assert_same_scan(got: Scan, want: Scan):
    assert got.n_pings == want.n_pings and got.n_bins == want.n_bins
    assert np.array_equal(got.data, want.data)                   # byte for byte
    np.testing.assert_allclose(got.bearings, want.bearings, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.poses, want.poses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.ranges, want.ranges, rtol=1e-12)
    assert got.range_min == want.range_min and got.range_max == pytest.approx(want.range_max, rel=1e-12)
    assert got.kind == "mechanical" and (got.beamwidth_h, got.beamwidth_v) == (3.0, 35.0)
    assert got.intensity.dtype == np.float32 and not got.intensity.any()
    assert got.meta.missing == []


def run_scan(scan, faults=None, n=1, vm_kw=None, **kw):
    settings = kw.pop("settings", None) or HeadSettings.from_scan(scan)
    with VirtualMicron(scan, realtime=False, faults=faults, **(vm_kw or {})) as vm:
        with MicronSonar(vm.port, settings=settings, pose=MOUNT, **{**FAST, **kw}) as sonar:
            scans = [sonar.scan() for _ in range(n)]
            return scans, sonar, vm


def test_full_turn_through_a_pty_is_byte_exact():
    (got,), sonar, vm = run_scan(SCAN)
    assert_same_scan(got, SCAN)
    assert got.meta.wire_bearings[:3] == [3200, 3168, 3136]        # stepping left from ahead
    assert got.meta.ad_interval == 50 and got.meta.step_size == 32
    assert sonar.dst and sonar.version.serial == vm.serial_number
    assert sonar.stats["pings"] == 200 and sonar.parser.dropped == 0
    assert vm.stats["scanlines"] == 200 and vm.stats["boots"] == 2   # power-on, mtReBoot


def test_gain_and_ad_window_round_trip_through_the_wire():
    # A received scan records the receiver settings of its reply headers, so asking the head for
    # "the settings of this scan" asks for the same bytes again.
    sent = HeadSettings.from_scan(SCAN, gain=20.0, ad_low=10.0, ad_span=30.0)
    assert (sent.igain, sent.ad_low_byte, sent.ad_span_byte) == (53, 32, 96)
    (got,), _, _ = run_scan(SCAN, settings=sent)
    assert got.electronics.gain == pytest.approx(53 * 80 / 210)
    again = HeadSettings.from_scan(got)
    assert (again.igain, again.ad_low_byte, again.ad_span_byte, again.bit_depth) == (53, 32, 96, 8)
    # a rendered scan's Electronics gain is what the head is asked for; out of the head's range is an error
    rendered = synthetic_scan()
    rendered.electronics.update(gain=28.0, ad_low=12.5, ad_span=24.0)
    assert (HeadSettings.from_scan(rendered).igain, HeadSettings.from_scan(rendered).ad_span_byte) == (74, 77)
    rendered.electronics.gain = 95.0
    with pytest.raises(ValueError, match="gain"):
        HeadSettings.from_scan(rendered)


def test_a_multibeam_scan_is_not_served_as_a_micron():
    fan = synthetic_scan(n_pings=64, start_deg=-30.0, step_deg=60 / 63)
    fan.kind = "multibeam"
    with pytest.raises(ValueError, match="kind must be 'mechanical'"):
        HeadSettings.from_scan(fan)
    with pytest.raises(ValueError, match="VirtualMicron.*kind must be 'mechanical'"):
        VirtualMicron(fan, realtime=False)


def test_consecutive_turns_and_pings_iterator():
    scans, sonar, _ = run_scan(SCAN, n=2)
    for s in scans:
        assert_same_scan(s, SCAN)


def test_pings_carry_wire_fields():
    with VirtualMicron(SCAN, realtime=False) as vm, \
            MicronSonar(vm.port, settings=HeadSettings.from_scan(SCAN), **FAST) as sonar:
        pings = list(sonar.pings(3))
    assert [p.bearing for p in pings] == [3200, 3168, 3136]
    assert all(isinstance(p, HeadData) and p.n_bins == 500 and p.ad_interval == 50 for p in pings)
    assert np.array_equal(pings[1].bins, SCAN.data[1])
    assert pings[0].bins.dtype == np.uint8


@pytest.mark.parametrize("faults,check", [
    (Faults(drop_pings=(3, 50, 51, 199)), lambda s, vm: s.parser.dropped > 0),
    (Faults(drop_probability=0.04, garbage_probability=0.05), lambda s, vm: s.parser.dropped > 0),
    (Faults(stall_at=40, stall_seconds=0.4), lambda s, vm: vm.stats["fault stalls"] == 1),
    (Faults(reboot_at=120), lambda s, vm: s.stats["recoveries"] >= 1 and vm.stats["boots"] == 3),
    (Faults(motor_error_at=10), lambda s, vm: s.stats["parameters re-sent"] >= 1),
], ids=["drop", "random-drop-garbage", "stall", "reboot", "motor-error"])
def test_driver_survives_faults_and_still_gets_the_exact_scan(faults, check):
    (got,), sonar, vm = run_scan(SCAN, faults)
    assert_same_scan(got, SCAN)
    assert check(sonar, vm), (dict(sonar.stats), dict(vm.stats))


def test_without_revisit_lost_pings_are_zero_and_listed():
    (got,), sonar, _ = run_scan(SCAN, Faults(drop_pings=(5,)), revisit=False)
    assert got.meta.missing == [5]
    assert not got.data[5].any()
    keep = np.arange(200) != 5
    assert np.array_equal(got.data[keep], SCAN.data[keep])


@pytest.mark.parametrize("order", ["low_first", "high_first"])
def test_four_bit_data(order):
    scan4 = synthetic_scan(bit_depth=4, seed=4)
    (got,), _, _ = run_scan(scan4, vm_kw={"nibble_order": order}, nibble_order=order)
    assert got.electronics.bit_depth == 4
    assert np.array_equal(got.data, scan4.data)


def test_nibble_order_mismatch_swaps_bin_pairs():
    scan4 = synthetic_scan(bit_depth=4, seed=4, n_bins=100)
    (got,), _, _ = run_scan(scan4, vm_kw={"nibble_order": "high_first"}, nibble_order="low_first")
    swapped = scan4.data.reshape(200, 50, 2)[:, :, ::-1].reshape(200, 100)
    assert np.array_equal(got.data, swapped)


def test_sector_sweeps_alternate_and_share_the_turning_ping():
    sector = synthetic_scan(n_pings=51, n_bins=200, range_max=10.0, start_deg=-45.0, seed=2, pose=MOUNT)
    settings = HeadSettings.from_scan(sector)
    assert not settings.continuous and (settings.left_limit, settings.right_limit) == (2400, 4000)
    scans, _, _ = run_scan(sector, n=3, settings=settings)
    for k, s in enumerate(scans):
        order = slice(None) if k % 2 == 0 else slice(None, None, -1)   # every other sweep goes back
        assert s.meta.sweep == "sector"
        assert np.array_equal(s.data[order], sector.data)
        np.testing.assert_allclose(s.bearings[order], sector.bearings, atol=1e-12)
        np.testing.assert_allclose(s.poses[order], sector.poses, atol=1e-12)
    # ADInterval rounds 104.17 to 104: the range window the head really used
    assert scans[0].range_max == pytest.approx(200 * 104 * 640e-9 * 750)


def test_scan_right_and_inverted_head():
    # Bearings decreasing (scan right) on an inverted head: the sign flips twice.
    want = synthetic_scan(step_deg=-1.8, seed=6)
    settings = HeadSettings.from_scan(want, invert=True)
    assert settings.invert and not settings.scan_right
    (got,), _, vm = run_scan(want, settings=settings)
    assert_same_scan(got, want.__class__(**{**want.__dict__, "poses": MOUNT @ beam_rotation(want.bearings)}))
    assert got.meta.hd_ctrl & HdCtrl.INVERT


def test_callable_scan_source_gets_the_settings():
    seen = []

    def source(settings):
        seen.append(settings)
        return synthetic_scan(n_bins=settings.n_bins, range_max=settings.range_max, seed=9)

    settings = HeadSettings(range=6.0, n_bins=250)
    with VirtualMicron(source, realtime=False) as vm, \
            MicronSonar(vm.port, settings=settings, **FAST) as sonar:
        got = sonar.scan()
    assert seen and seen[-1].n_bins == 250 and seen[-1].ad_interval == settings.ad_interval
    assert np.array_equal(got.data, synthetic_scan(n_bins=250, range_max=settings.range_max, seed=9).data)


def test_resampling_onto_other_bins_and_uncovered_bearings():
    # The head asks for half the bins over the same range and the scan covers only 90 deg.
    # 7.68 m over 200 bins is ADInterval 80 exactly: head bin i is centred on scan bin 2i+1.
    part = synthetic_scan(n_pings=50, n_bins=400, range_max=7.68, seed=3)
    settings = HeadSettings(range=7.68, n_bins=200)
    assert settings.ad_interval_exact == pytest.approx(80)
    with VirtualMicron(part, realtime=False) as vm, \
            MicronSonar(vm.port, settings=settings, **FAST) as sonar:
        got = sonar.scan()
    assert np.array_equal(got.data[:50], part.data[:, 1::2])     # bin centres fall on odd bins
    assert not got.data[50:].any()


def test_socket_url():
    with VirtualMicron(SCAN, "socket://127.0.0.1:0", realtime=False) as vm:
        assert vm.port.startswith("socket://127.0.0.1:") and not vm.port.endswith(":0")
        with MicronSonar(vm.port, settings=HeadSettings.from_scan(SCAN), pose=MOUNT, **FAST) as sonar:
            got = sonar.scan()
    assert_same_scan(got, SCAN)


# The head's faults (a reboot, dropped or garbled bytes, a recording stopped mid-packet) leave
# bytes that form no packet, depending on timing: replay warns of them (checked in the damage
# tests below); here only the scans matter.
@pytest.mark.filterwarnings("ignore::mitsonar.devices.rawlog.LogDamageWarning")
def test_record_then_replay_gives_the_same_scan(tmp_path):
    log = tmp_path / "log.bin"
    with VirtualMicron(SCAN, realtime=False, faults=Faults(drop_pings=(7,), reboot_at=150)) as vm:
        stats = record(vm.port, log, scans=1, settings=HeadSettings.from_scan(SCAN), pose=MOUNT, **FAST)
    assert stats["pings"] >= 200 and stats["bytes_rx"] > 200 * 545
    meta, records = read_log(log)
    assert meta["settings"]["n_bins"] == 500 and meta["sound_speed"] == 1500.0
    assert {k for _, k, _ in records} == {0, 1}
    scans = replay(log)
    assert len(scans) == 1
    assert_same_scan(scans[0], SCAN)
    assert replay(log, partial=True)[-1].meta.partial in (True, None)


# The head's faults (a reboot, dropped or garbled bytes, a recording stopped mid-packet) leave
# bytes that form no packet, depending on timing: replay warns of them (checked in the damage
# tests below); here only the scans matter.
@pytest.mark.filterwarnings("ignore::mitsonar.devices.rawlog.LogDamageWarning")
def test_replay_reproduces_the_driver_scans_under_faults(tmp_path):
    log = tmp_path / "log.bin"
    faults = Faults(drop_probability=0.03, garbage_probability=0.03, stall_at=260, stall_seconds=0.3)
    with VirtualMicron(SCAN, realtime=False, faults=faults, seed=11) as vm, \
            MicronSonar(vm.port, settings=HeadSettings.from_scan(SCAN), pose=MOUNT, log=log, **FAST) as sonar:
        live = [sonar.scan(), sonar.scan()]
    replayed = replay(log)
    assert len(replayed) == 2
    for a, b in zip(live, replayed):
        assert np.array_equal(a.data, b.data) and np.array_equal(a.bearings, b.bearings)
        assert np.array_equal(a.poses, b.poses) and a.meta.wire_bearings == b.meta.wire_bearings


def test_replay_uses_logged_pose_changes(tmp_path):
    log = tmp_path / "log.bin"
    moved = MOUNT.copy()
    moved[:3, 3] += [10.0, 0.0, 0.0]
    with VirtualMicron(SCAN, realtime=False) as vm, \
            MicronSonar(vm.port, settings=HeadSettings.from_scan(SCAN), pose=MOUNT, log=log, **FAST) as sonar:
        first = sonar.scan()
        sonar.pose = moved
        second = sonar.scan()
    a, b = replay(log)
    np.testing.assert_allclose(a.poses, first.poses)
    np.testing.assert_allclose(b.poses, second.poses)
    np.testing.assert_allclose(b.positions, np.broadcast_to(moved[:3, 3], (200, 3)))


# The head's faults (a reboot, dropped or garbled bytes, a recording stopped mid-packet) leave
# bytes that form no packet, depending on timing: replay warns of them (checked in the damage
# tests below); here only the scans matter.
@pytest.mark.filterwarnings("ignore::mitsonar.devices.rawlog.LogDamageWarning")
def test_passive_record_logs_what_the_head_sends(tmp_path):
    log = tmp_path / "tap.bin"
    with VirtualMicron(SCAN, realtime=False, alive_interval=0.02) as vm:
        stats = record(vm.port, log, 0.3, passive=True)
    meta, records = read_log(log)
    assert meta["passive"] and stats["bytes_rx"] > 0 and {k for _, k, _ in records} == {0}
    from mitsonar.devices.micron.seanet import Alive, StreamParser
    msgs = StreamParser().feed(b"".join(d for _, _, d in records))
    assert msgs and all(isinstance(m, Alive) for m in msgs)
    assert replay(log) == []


def test_read_log_rejects_other_files(tmp_path):
    bad = tmp_path / "x.bin"
    bad.write_bytes(b"not a log")
    with pytest.raises(ValueError, match="not a mitsonar raw log"):
        read_log(bad)


def test_silent_port_times_out_without_hanging():
    import pty
    master, slave = pty.openpty()
    try:
        path = os.ttyname(slave)
        t = time.monotonic()
        with pytest.raises(SonarTimeout, match="mtAlive"):
            MicronSonar(path, timeout=0.5, boot_timeout=0.3, ping_timeout=0.1)
        # the timeouts given were honoured, not the 30 s defaults (takes 0.3 s; the bound, half
        # a default, is no speed test and no load reaches it)
        assert time.monotonic() - t < 15
    finally:
        os.close(master)
        os.close(slave)


def test_stalled_for_good_raises_sonar_timeout():
    with VirtualMicron(SCAN, realtime=False, faults=Faults(stall_at=5, stall_seconds=60)) as vm, \
            MicronSonar(vm.port, settings=HeadSettings.from_scan(SCAN), timeout=1.0,
                        ping_timeout=0.1, boot_timeout=2.0) as sonar:
        t = time.monotonic()
        with pytest.raises(SonarTimeout):
            sonar.scan()
        # timeout=1.0 was honoured, not the 30 s default nor the head's 60 s stall (takes 1 s;
        # the bound, half the default, is no speed test)
        assert time.monotonic() - t < 15


def test_bad_port_and_closed_sonar():
    with pytest.raises(SonarError, match="cannot open"):
        MicronSonar("/dev/does-not-exist-mitsonar", timeout=0.5)
    # loop:// echoes our own commands: a URL without a file descriptor, and no head on it
    with pytest.raises(SonarTimeout):
        MicronSonar("loop://", timeout=0.5, boot_timeout=0.2, ping_timeout=0.1)
    with pytest.raises(TypeError, match="HeadSettings"):
        MicronSonar("loop://", settings={"range": 5})
    import mitsonar.devices.micron.seanet
    # The codec no longer re-exports the driver (that made seanet and micron import each other);
    # the old name says where the driver lives.
    with pytest.raises(AttributeError, match="import MicronSonar from mitsonar.devices.micron.driver"):
        mitsonar.devices.micron.seanet.MicronSonar
    with VirtualMicron(SCAN, realtime=False) as vm:
        sonar = MicronSonar(vm.port, settings=HeadSettings.from_scan(SCAN), **FAST)
        sonar.close()
        sonar.close()
        with pytest.raises(SonarError, match="closed"):
            sonar.read_ping()


def test_realtime_timing_model_is_not_faster_than_the_line():
    settings = HeadSettings(range=2.0, n_bins=100)
    scan = synthetic_scan(n_bins=100, range_max=2.0)
    with VirtualMicron(scan, realtime=True, boot_time=0.02, alive_interval=0.05) as vm, \
            MicronSonar(vm.port, settings=settings, timeout=5.0, boot_timeout=2.0) as sonar:
        t = time.monotonic()
        list(sonar.pings(5))
        per_ping = (time.monotonic() - t) / 5
    # request + 2R/c + reply transfer + motor; only a lower bound is safe on a busy machine
    assert per_ping >= 0.9 * settings.expected_step_time(115200)


def test_virtual_sonar_stops_promptly_and_threads_end():
    vm = VirtualMicron(SCAN, realtime=False)
    vm.start()
    vm.stop()
    vm.stop()
    assert not any(t.name == "VirtualMicron" and t.is_alive() for t in threading.enumerate())


# ---- assembler without a wire ---------------------------------------------------------------

def _ping(b, hd_ctrl=None, **kw):
    h = HeadSettings().hd_ctrl if hd_ctrl is None else hd_ctrl
    return HeadData.from_bins(np.full(10, b % 256, np.uint8), bearing=b, ad_interval=50, step_size=32,
                              hd_ctrl=h, **kw)


def test_assembler_direction_and_unwrapped_bearings():
    asm = ScanAssembler()
    out = None
    start = 100
    for k in range(200):                       # scan right: increasing wire bearing, wraps at 6400
        out = asm.add(_ping((start + 32 * k) % 6400)) or out
    assert out is not None and out.n_pings == 200
    steps = np.diff(out.bearings)
    np.testing.assert_allclose(steps, -math.radians(1.8))
    assert out.bearings[0] == pytest.approx(bearing_to_radians(start))
    assert out.range_max == pytest.approx(10 * 0.024)


def test_assembler_refuses_a_pose_that_is_not_rigid_where_it_comes_in():
    asm = ScanAssembler()
    with pytest.raises(ValueError, match=r"pose: must be a rigid transform"):
        asm.add(_ping(100), pose=np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=r"pose: entry \[0, 3\] is nan \(a pose must be finite\)"):
        asm.add(_ping(100), pose=np.array([[1, 0, 0, np.nan], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]))
    assert asm.add(_ping(100), pose=np.eye(4)) is None  # a good one is taken


def test_assembler_skips_motor_error_and_restarts_on_new_settings():
    asm = ScanAssembler()
    assert asm.add(_ping(3200, head_status=2)) is None
    asm.add(_ping(3200))
    asm.add(_ping(3168))
    other = HeadData.from_bins(np.zeros(10, np.uint8), bearing=3136, ad_interval=51, step_size=32,
                               hd_ctrl=HeadSettings().hd_ctrl)
    asm.add(other)
    assert asm.discarded == 1


# ---- damaged and truncated logs ------------------------------------------------------------

SMALL = synthetic_scan(n_bins=100, range_max=2.4, seed=4)


@pytest.fixture(scope="module")
def two_scan_log(tmp_path_factory):
    """A clean log of two full turns, the scans the driver returned, and the byte span of
    every record in the file."""
    import struct
    log = tmp_path_factory.mktemp("log") / "log.bin"
    with VirtualMicron(SMALL, realtime=False) as vm, \
            MicronSonar(vm.port, settings=HeadSettings.from_scan(SMALL), pose=MOUNT, log=log, **FAST) as sonar:
        live = [sonar.scan(), sonar.scan()]
    raw = log.read_bytes()
    pos = 24 + struct.unpack_from("<I", raw, 20)[0]
    spans = []
    while pos < len(raw):
        m = struct.unpack_from("<I", raw, pos + 9)[0]
        spans.append((pos, pos + 13 + m))
        pos += 13 + m
    return log, live, spans


def _damaged(tmp_path, log, data):
    out = tmp_path / "damaged.bin"
    out.write_bytes(data)
    return out


def test_clean_log_reads_without_warnings(two_scan_log):
    import warnings
    log, live, spans = two_scan_log
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        meta, records = read_log(log)
        scans = replay(log)
    assert "skipped" not in meta and len(records) == len(spans)
    assert [r[2] for r in records] == [log.read_bytes()[a + 13:b] for a, b in spans]
    assert len(scans) == 2 and all(np.array_equal(a.data, b.data) for a, b in zip(live, scans))


def test_read_log_resyncs_after_zeroed_bytes_and_keeps_the_rest(two_scan_log, tmp_path):
    from mitsonar.devices.rawlog import LogDamageWarning
    log, live, spans = two_scan_log
    raw = log.read_bytes()
    a, b = 5000, 5000 + (len(raw) - 5000) // 2 - 3000      # most of the first turn, as in the audit
    bad = _damaged(tmp_path, log, raw[:a] + bytes(b - a) + raw[b:])
    with pytest.warns(LogDamageWarning, match=r"damaged\.bin: skipped \d+ damaged bytes at \d+\.\.\d+") as rec:
        meta, records = read_log(bad)
    _, clean = read_log(log)
    (start, n, why), = meta["skipped"]
    # From the record the damage begins in (its end, if its header is intact) to the first
    # record after it (or the tail of its header, if only the front was zeroed).
    assert why == "damaged" and f"{start}..{start + n}" in str(rec[0].message)
    assert start in next((s, e) for s, e in spans if s <= a < e)
    assert b - 13 < start + n <= next(s for s, e in spans if s >= b)
    # Every record wholly after the damage is there, byte for byte and in order.
    after = [clean[i] for i, (s, e) in enumerate(spans) if s >= b]
    assert records[-len(after):] == after
    # ... and so is every record wholly before it.
    before = [clean[i] for i, (s, e) in enumerate(spans) if e <= a]
    assert records[:len(before)] == before
    with pytest.warns(LogDamageWarning):
        scans = replay(bad)
    assert len(scans) == 1 and np.array_equal(scans[0].data, live[1].data)   # the intact second turn


def _synthetic_log(path, n_pings=300):
    """A log as the driver writes it, with fixed times: the same bytes on every run."""
    import json
    import struct
    from mitsonar.devices.micron.seanet import HeadData, SendData, encode
    settings = HeadSettings.from_scan(SMALL)
    rng = np.random.default_rng(7)
    packets = [(1, encode(settings.head_command()))]
    for k in range(n_pings):
        packets.append((1, encode(SendData())))
        bins = rng.integers(0, 256, 100, dtype=np.uint8)
        packets.append((0, encode(HeadData.from_bins(bins, bearing=(3200 - 32 * k) % 6400, ad_interval=50,
                                                     step_size=32, hd_ctrl=int(settings.hd_ctrl)))))
    blob = json.dumps({"settings": settings.as_dict()}).encode()
    out = bytearray(struct.pack("<8sHHdI", b"MSNRLOG1", 1, 0, 0.0, len(blob)) + blob)
    spans = []
    for k, (kind, data) in enumerate(packets):
        spans.append((len(out), len(out) + 13 + len(data)))
        out += struct.pack("<dBI", 0.01 + 0.002 * k, kind, len(data)) + data
    path.write_bytes(bytes(out))
    return bytes(out), spans


@pytest.mark.parametrize("mode", ["zeros", "random", "deleted", "inserted"])
def test_read_log_loses_only_the_damaged_records(tmp_path, mode):
    import struct
    import warnings
    raw, spans = _synthetic_log(tmp_path / "clean.bin")
    _, clean = read_log(tmp_path / "clean.bin")
    assert len(clean) == len(spans)
    rng = np.random.default_rng(["zeros", "random", "deleted", "inserted"].index(mode))
    for _ in range(40):
        a = int(rng.integers(spans[0][0], len(raw) - 10))
        b = min(len(raw), a + int(rng.integers(1, 3000)))
        junk = rng.integers(0, 256, b - a, dtype=np.uint8).tobytes()
        data = {"zeros": raw[:a] + bytes(b - a) + raw[b:], "random": raw[:a] + junk + raw[b:],
                "deleted": raw[:a] + raw[b:], "inserted": raw[:a] + junk + raw[a:]}[mode]
        resume = a if mode == "inserted" else b
        if mode == "deleted":
            # Beyond what the format can tell: the cut record's length (as it now reads)
            # lands exactly on a later record, which reads as a clean log.
            s, e = next(sp for sp in spans if sp[0] <= a < sp[1])
            shifted = {x - (b - a) for x, _ in spans if x >= b}
            if s + 13 <= len(data) and s + 13 + struct.unpack_from("<I", data, s + 9)[0] in shifted:
                continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            meta, records = read_log(_damaged(tmp_path, None, data))
        want = [clean[i] for i, (s, e) in enumerate(spans) if e <= a or s >= resume]
        got = set(records)
        assert [r for r in want if r not in got] == [], (a, b, meta.get("skipped"))
        # At most the records the damage cut into come out changed (damage inside a payload
        # is for the SeaNet parser to find).
        assert len([r for r in records if r not in set(clean)]) <= 2


def test_read_log_reports_a_record_cut_short_at_the_end(two_scan_log, tmp_path):
    from mitsonar.devices.rawlog import LogDamageWarning
    log, live, spans = two_scan_log
    raw = log.read_bytes()
    k = next(k for k in range(len(spans) // 2, len(spans)) if spans[k][1] - spans[k][0] > 120)
    cut = spans[k][0] + 100                             # 87 bytes into a record's payload
    with pytest.warns(LogDamageWarning, match=rf"record cut short at the end: 100 bytes at {cut - 100}\.\.{cut} not read"):
        meta, records = read_log(_damaged(tmp_path, log, raw[:cut]))
    assert meta["skipped"] == [[cut - 100, 100, "record cut short at the end"]]
    assert len(records) == k


def test_read_log_header_only_and_empty_files(tmp_path):
    magic = tmp_path / "magic.bin"
    magic.write_bytes(b"MSNRLOG1")
    with pytest.raises(ValueError, match=r"magic\.bin: truncated log: 8 bytes, less than the 24-byte file header; no records"):
        read_log(magic)
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.bin: empty file, not a mitsonar raw log"):
        read_log(empty)


def test_raw_log_writer_only_writes_kinds_the_reader_knows(tmp_path):
    from mitsonar.devices.rawlog import RawLogWriter
    with RawLogWriter(tmp_path / "x.bin") as w:
        with pytest.raises(ValueError, match=r"record_type must be RX \(0\), TX \(1\) or POSE \(2\), got 7"):
            w.write(7, b"abc")


def test_replay_sound_speed_has_the_head_bounds(two_scan_log, tmp_path):
    log, live, spans = two_scan_log
    for c in (1e9, 100.0, float("nan")):
        with pytest.raises(ValueError, match=r"replay: sound_speed = .* is out of range: allowed 1300\.\.1800 m/s"):
            replay(log, sound_speed=c)
    assert replay(log, sound_speed=1300.0)[0].range_max == pytest.approx(2.4 * 1300 / 1500)


def test_replay_reports_bytes_that_form_no_packet(two_scan_log, tmp_path):
    from mitsonar.devices.rawlog import LogDamageWarning, RawLogWriter
    log, live, spans = two_scan_log
    meta, records = read_log(log)
    meta.pop("start_time")
    out = tmp_path / "garbled.bin"
    hit = next(k for k in range(len(records) // 2, len(records)) if records[k][1] == 0)
    with RawLogWriter(out, meta) as w:
        for k, (t, kind, data) in enumerate(records):
            w.write(kind, data[:9] + b"junk" + data[9:] if k == hit else data)
    with pytest.warns(LogDamageWarning, match=r"garbled\.bin: dropped \d+ bytes from the head that form no whole SeaNet packet \(.+: \d+"):
        replay(out)


def test_assembled_scan_has_its_ping_times():
    """A received scan's times are each row's reception time from the first row's; a row lost on
    the wire gets its neighbours' interpolation; no times at all leave zeros."""
    asm = ScanAssembler()
    out = None
    for k in range(200):
        if k == 57:
            continue                           # lost on the wire
        out = asm.add(_ping(100 + 32 * k), t=1000.0 + 0.05 * k) or out
    out = out or asm.finish()
    assert out.n_pings == 200 and 57 in out.meta.missing
    np.testing.assert_allclose(out.times, 0.05 * np.arange(200), atol=1e-9)
    assert out.meta.start_time == pytest.approx(1000.0)
    asm = ScanAssembler()
    plain = None
    for k in range(200):
        plain = asm.add(_ping(100 + 32 * k)) or plain
    np.testing.assert_array_equal((plain or asm.finish()).times, np.zeros(200))
