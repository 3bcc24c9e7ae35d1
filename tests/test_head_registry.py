"""Heads through `mitsonar.devices.registry`: adding a head is one folder's worth of code plus one
registry entry. A toy head defined here (a line-based text protocol, a driver on the project's
transports, a virtual head, an assembler) is registered, then served, recorded and replayed
through the command line in-process, without any other file knowing it."""
from __future__ import annotations

import os
import queue
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import asdict, dataclass

import numpy as np
import pytest

import mitsonar
from mitsonar.cli.main import main
from mitsonar.devices import registry
from mitsonar.devices.head import Head
from mitsonar.devices.rawlog import RawLogWriter
from mitsonar.devices.recording import check_pose
from mitsonar.devices.transports import LineDriver, ServedHead, SonarTimeout
from mitsonar.scan import Scan, bearing_rotation

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")

BOX = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes_xml", "box.xml")


# ---- the toy head: one "folder" of code ----
# Protocol, one ASCII line per message: host -> head "HELLO", "PING k"; head -> host
# "INFO n_pings n_bins range_min range_max" (floats as float.hex), "ECHO k bearing hexbytes".

def decode(line: bytes):
    """A message tuple, or None if ``line`` is no toy line."""
    try:
        p = line.decode("ascii").split()
        if p == ["HELLO"]:
            return ("HELLO",)
        if len(p) == 2 and p[0] == "PING":
            return ("PING", int(p[1]))
        if len(p) == 5 and p[0] == "INFO":
            return ("INFO", int(p[1]), int(p[2]), float.fromhex(p[3]), float.fromhex(p[4]))
        if len(p) == 4 and p[0] == "ECHO":
            return ("ECHO", int(p[1]), float.fromhex(p[2]), bytes.fromhex(p[3]))
    except ValueError:
        pass
    return None


class LineParser:
    """The toy codec's stream parser: whole lines in, messages out; others counted as dropped."""

    def __init__(self):
        self.buf, self.packets, self.dropped, self.drop_reasons = b"", 0, 0, Counter()

    def feed(self, data: bytes) -> list:
        self.buf += data
        out = []
        while b"\n" in self.buf:
            line, self.buf = self.buf.split(b"\n", 1)
            m = decode(line)
            if m is None:
                self.dropped += len(line) + 1
                self.drop_reasons["no toy line"] += len(line) + 1
            else:
                self.packets += 1
                out.append(m)
        return out

    def flush(self) -> list:
        if self.buf:
            self.dropped += len(self.buf)
            self.drop_reasons["line cut short"] += len(self.buf)
            self.buf = b""
        return []


@dataclass
class ToySettings:
    sound_speed: float = 1500.0

    def as_dict(self) -> dict:
        return asdict(self)


class ToyAssembler:
    """INFO starts a scan of n_pings rows; the scan is done when every ECHO row arrived."""

    def __init__(self, settings: ToySettings):
        self.settings, self.info, self.rows = settings, None, {}

    def add(self, m, pose=None, t=None):
        if m[0] == "INFO":
            self.info, self.rows = m, {}
            return None
        _, k, bearing, row = m
        self.rows[k] = (bearing, row, check_pose(pose))
        return self._build() if len(self.rows) == self.info[1] else None

    def finish(self):
        return self._build() if self.rows else None

    def _build(self) -> Scan:
        _, n, nb, r0, r1 = self.info
        data = np.zeros((n, nb), np.uint8)
        b = np.zeros(n)
        poses = np.tile(np.eye(4), (n, 1, 1))
        for k, (bearing, row, T) in self.rows.items():
            data[k], b[k], poses[k] = np.frombuffer(row, np.uint8), bearing, T
        self.rows = {}
        w = (r1 - r0) / nb
        return Scan(intensity=np.zeros((n, nb), np.float32), data=data, ranges=r0 + (np.arange(nb) + 0.5) * w,
                    bearings=b, poses=poses @ bearing_rotation(b), range_min=r0, range_max=r1,
                    sound_speed=self.settings.sound_speed, meta={"source": "toy"})


class ToySonar(LineDriver):
    """The toy driver: HELLO once, then PING k for k = 0, 1, ... n_pings - 1, 0, ..."""

    _check_pose = staticmethod(check_pose)

    def __init__(self, port_or_url, baudrate=115200, settings=None, pose=None, timeout=10.0, *,
                 ping_timeout=None, retries=0, log=None, start=True):
        self._init_line(settings or ToySettings(), baudrate, pose, timeout, ping_timeout, retries)
        self.parser, self.stats, self._inbox = LineParser(), Counter(), deque()
        self.info, self.last_ping_time, self._next, self._assembler = None, None, 0, None
        self._attach(port_or_url, log, self.start if start else None)

    def _expected_step_time(self) -> float:
        return 0.01

    def _log_meta(self) -> dict:
        return {"format": "toy raw log", "head": "toy", "port": str(self.port), "baudrate": self.baudrate,
                "settings": self._settings.as_dict(), "pose": self._pose.tolist()}

    def _ask(self, line: bytes, accept, what: str):
        self._send_bytes(line, what)
        deadline = time.monotonic() + self.timeout
        while (m := self._poll(deadline)) is not None:
            if accept(m):
                return m
        raise SonarTimeout(f"{self.port}: no {what} within {self.timeout:g} s")

    def start(self) -> None:
        self.info = self._ask(b"HELLO\n", lambda m: m[0] == "INFO", "INFO")
        self._assembler = ToyAssembler(self._settings)
        self._assembler.add(self.info)

    def read_ping(self):
        k = self._next
        m = self._ask(b"PING %d\n" % k, lambda m: m[0] == "ECHO" and m[1] == k, f"ECHO {k}")
        self._next = (k + 1) % self.info[1]
        self.stats["pings"] += 1
        self.last_ping_time = time.time()
        return m

    def _scan_assembler(self):
        return self._assembler

    def _head_meta(self) -> dict:
        return {}


SERVED = queue.Queue()      # the ports the virtual toy heads serve on
DONE = threading.Event()    # the test is done with them


class VirtualToy(ServedHead):
    def __init__(self, scan: Scan, port_url=None, *, baudrate=115200, realtime=True):
        self.scan, self.port_url, self.baudrate = scan, port_url, int(baudrate)
        self.stats, self.last_error, self._buf = Counter(), None, b""
        self._transport, self._thread, self._stop = None, None, threading.Event()

    def _tick(self) -> None:
        self._buf += self._transport.read(0.02)
        while b"\n" in self._buf:
            line, self._buf = self._buf.split(b"\n", 1)
            m = decode(line)
            s = self.scan
            if m == ("HELLO",):
                out = f"INFO {s.n_pings} {s.n_bins} {float(s.range_min).hex()} {float(s.range_max).hex()}\n"
            elif m is not None and m[0] == "PING" and 0 <= m[1] < s.n_pings:
                row = np.asarray(s.data[m[1]], np.uint8).tobytes().hex()
                out = f"ECHO {m[1]} {float(s.bearings[m[1]]).hex()} {row}\n"
            else:
                continue
            data = out.encode("ascii")
            while data:
                n = self._transport.write(data)
                data = data[n:]
                if not n:
                    time.sleep(0.001)

    def serve(self, seconds=None, out=None, label="virtual toy") -> int:
        """Like `ServedHead.serve`, but hands the port to the test and stops when it is done."""
        with self:
            print(f"{label} on {self.port}", file=out or sys.stdout, flush=True)
            SERVED.put(self.port)
            DONE.wait(seconds)
        return 0


class ToyHead(Head):
    name = "toy"
    description = "a line-based text head of the tests"
    log_tag = "toy"
    protocol = "toy-text"
    packet = "toy line"
    ping_word = "pings"
    serves = "toy pings"
    one_reply_per_command = True

    def parser(self):
        return LineParser()

    def driver(self):
        return ToySonar

    def virtual(self):
        return VirtualToy

    def assembler(self, settings):
        return ToyAssembler(settings)

    def is_command(self, m) -> bool:
        return m[0] in ("HELLO", "PING")

    def usable(self, m, command) -> bool:
        return ((command[0] == "HELLO" and m[0] == "INFO")
                or (command[0] == "PING" and m[0] == "ECHO" and m[1] == command[1]))

    def settings(self, args=None):
        return ToySettings(**({"sound_speed": args.sound_speed} if getattr(args, "sound_speed", None) else {}))

    def log_settings(self, meta, sound_speed, path):
        return ToySettings(**{**meta.get("settings", {}), **({"sound_speed": sound_speed} if sound_speed else {})})


@pytest.fixture
def toy():
    head = registry.register(ToyHead())
    DONE.clear()
    yield head
    DONE.set()
    registry.unregister("toy")


# ---- the tests ----

def test_a_toy_head_is_served_recorded_and_replayed_through_the_cli(toy, tmp_path, monkeypatch, capsys):
    """virtual-sonar --head toy renders the box and serves it; record --head toy drives it with
    the toy driver; replay finds the toy head by the log's tag and gives back the rendered scan."""
    rendered = []
    render = mitsonar.render_scan

    def keep(*args, **kwargs):
        rendered.append(render(*args, **kwargs))
        return rendered[-1]

    monkeypatch.setattr(mitsonar, "render_scan", keep)
    log, out = tmp_path / "toy.bin", tmp_path / "scan.npz"
    recorded = []

    def record():
        try:
            port = SERVED.get(timeout=300)
            recorded.append(main(["record", port, "--head", "toy", "-o", str(log), "--scans", "1",
                                  "--timeout", "20"]))
        finally:
            DONE.set()

    recorder = threading.Thread(target=record)
    recorder.start()
    try:
        assert main(["virtual-sonar", BOX, "--head", "toy", "--spp", "4", "--seed", "2", "--fast",
                     "--seconds", "300"]) == 0
    finally:
        DONE.set()
        recorder.join(60)
    assert recorded == [0]
    text = capsys.readouterr().out
    assert "virtual toy on /dev/" in text
    scan = rendered[0]
    assert f"({scan.n_pings} pings) to {log}" in text

    assert main(["replay", str(log), "-o", str(out)]) == 0
    assert f"scan 0 of 1 from {log} written to {out}" in capsys.readouterr().out
    got = mitsonar.load_scan(str(out))
    assert got.data.shape == scan.data.shape and np.array_equal(got.data, scan.data)
    assert np.array_equal(got.bearings, scan.bearings)
    assert (got.range_min, got.range_max) == (scan.range_min, scan.range_max)
    # the API sees the same head: replay() of the log is the toy's assembly
    assert mitsonar.replay(log)[0].meta.source == "toy"


def test_a_registered_head_is_a_head_choice_and_refuses_other_heads_options(toy, tmp_path, capsys):
    assert registry.names() == ("micron", "ping360", "oculus", "toy") and registry.get("toy") is toy
    assert main(["record", "/dev/null", "--head", "toy", "-o", str(tmp_path / "x.bin"), "--gain", "high"]) == 1
    assert capsys.readouterr().err.strip() == "mitsonar record: error: --gain is for --head ping360, not toy"
    assert not list(tmp_path.iterdir())


def test_without_registration_toy_is_no_head(capsys):
    with pytest.raises(SystemExit) as e:
        main(["record", "/dev/null", "--head", "toy", "-o", "x.bin"])
    assert e.value.code == 2
    assert "invalid choice: 'toy' (choose from 'micron', 'ping360', 'oculus')" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"^unknown head 'toy': known heads are micron, ping360, oculus$"):
        registry.get("toy")


def test_the_builtin_heads_come_from_their_folders():
    micron, ping360 = registry.get("micron"), registry.get("ping360")
    assert type(micron).__module__ == "mitsonar.devices.micron.registration"
    assert type(registry.get("oculus")).__module__ == "mitsonar.devices.oculus.registration"
    assert registry.for_log({"head": "oculus"}) is registry.get("oculus")
    assert type(ping360).__module__ == "mitsonar.devices.ping360.registration"
    assert registry.for_log({}) is micron and registry.for_log({"head": "ping360"}) is ping360
    assert micron.driver() is mitsonar.MicronSonar and ping360.driver() is mitsonar.Ping360Sonar
    assert micron.virtual() is mitsonar.VirtualMicron and ping360.virtual() is mitsonar.VirtualPing360
    from mitsonar.devices.micron.seanet.stream import StreamParser
    from mitsonar.devices.ping360.protocol import StreamParser as PingParser
    assert type(micron.parser()) is StreamParser and type(ping360.parser()) is PingParser


def test_register_refuses_a_taken_name_a_taken_log_tag_and_no_head():
    with pytest.raises(ValueError, match="head 'micron' is already registered"):
        registry.register(type("Twin", (ToyHead,), {"name": "micron"})())
    with pytest.raises(ValueError, match="head 'echo' writes the log tag 'ping360' of head 'ping360'"):
        registry.register(type("Echo", (ToyHead,), {"name": "echo", "log_tag": "ping360"})())
    with pytest.raises(TypeError, match="a str is no mitsonar.devices.head.Head"):
        registry.register("toy")
    assert registry.names() == ("micron", "ping360", "oculus")


def test_replay_of_a_log_of_an_unknown_head_says_so_in_one_line(tmp_path, capsys):
    """A log whose header names no registered head is refused, not read as SeaNet bytes."""
    log = tmp_path / "other.bin"
    with RawLogWriter(log, {"head": "sidescan9000"}) as w:
        w.rx(b"\x40" * 64)
    assert main(["replay", str(log), "-o", str(tmp_path / "s.npz")]) == 1
    assert capsys.readouterr().err.strip() == (
        f"mitsonar replay: error: {log}: the log's head 'sidescan9000' is none of the known heads "
        f"(micron, ping360, oculus)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.bin"]
