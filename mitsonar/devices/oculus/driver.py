"""Blueprint Subsea Oculus driver: `discover` (the status broadcast), `OculusSonar` (fire, receive,
assemble `mitsonar.scan.Scan` frames, reconnect), and `record` (drive a head, log its bytes).

As liboculus does (``lib/StatusRx.cpp``: a UDP socket bound to port 52102 taking datagrams of
``sizeof(OculusStatusMsg)``; ``lib/DataRx.cpp``: a TCP connection to port 52100 of the address
the status carries, one fire message, then ping results as the head streams them), the driver
sends one simple fire message (`fire_message`) with a ping rate; the head then streams simple
ping results at that rate until told otherwise. Each result becomes a Scan of kind
``multibeam`` (`mitsonar.devices.oculus.head.ping_to_scan`).

A dropped connection is reconnected (``reconnects`` times, the fire message sent again);
bytes that form no message, and malformed or oversized messages, are dropped by the stream
parser and said in one line on ``out`` (stderr) naming the field; a head that sends no ping
within ``timeout`` after the fire message raises `SonarTimeout` saying so (an Oculus refuses a
fire message it cannot use by not pinging).
"""
from __future__ import annotations

import socket
import sys
import time
from collections import Counter, deque

from mitsonar.devices.oculus.head import ping_to_scan
from mitsonar.devices.oculus.protocol import (FLAG, STATUS_SIZE, TCP_PORT, UDP_PORT, FireMessage, OculusError,
                                              PingResult, StatusMessage, StreamParser)
from mitsonar.devices.recording import check_pose, record_driven
from mitsonar.devices.transports import SonarError, SonarTimeout

__all__ = ["discover", "fire_message", "OculusSonar", "record", "record_oculus", "SonarError", "SonarTimeout"]

#: pingRate codes by Hz (`mitsonar.devices.oculus.protocol.PING_RATE_HZ`)
RATE_CODES = {10: 0, 15: 1, 40: 2, 5: 3, 2: 4, 0: 5}


def fire_message(*, mode: int = 1, rate: float = 10, range: float = 10.0, gain: float = 50.0,  # noqa: A002
                 gamma: int = 255, speed_of_sound: float = 0.0, salinity: float = 35.0, data_bits: int = 8,
                 gains: bool = True, beams: int = 256, version: int = 2) -> FireMessage:
    """A simple fire message from engineering units (range in metres; ``rate`` 2, 5, 10, 15, 40
    Hz or 0 for standby; ``data_bits`` 8, 16 or 32 (32: version 2 only); ``beams`` 256 or 512)."""
    if rate not in RATE_CODES:
        raise ValueError(f"fire_message: rate {rate!r} is not allowed (2, 5, 10, 15, 40 Hz or 0 for standby)")
    if data_bits not in (8, 16, 32) or (data_bits == 32 and version != 2):
        raise ValueError(f"fire_message: data_bits {data_bits!r} is not allowed (8, 16; 32 with version 2)")
    if beams not in (256, 512):
        raise ValueError(f"fire_message: beams {beams!r} is not allowed (256 or 512)")
    flags = FLAG["range_as_meters"] | FLAG["simple_return"]
    flags |= FLAG["data_16bit"] if data_bits == 16 else 0
    flags |= FLAG["send_gain"] if gains else 0
    flags |= FLAG["512_beams"] if beams == 512 else 0
    return FireMessage(master_mode=mode, ping_rate=RATE_CODES[rate], gamma=gamma, flags=flags, range=float(range),
                       gain=float(gain), speed_of_sound=float(speed_of_sound), salinity=float(salinity),
                       ext_flags=0x200 if data_bits == 32 else 0, version=version)


def discover(timeout: float = 5.0, udp_port: int = UDP_PORT, bind: str = "") -> tuple[StatusMessage, str]:
    """Wait for an Oculus status broadcast on ``udp_port``: ``(status, sender address)``.

    Datagrams of another size, or that do not decode, are skipped. `SonarTimeout` after
    ``timeout`` s without one."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    if hasattr(socket, "SO_REUSEPORT"):
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    try:
        s.bind((bind, udp_port))
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise SonarTimeout(f"no Oculus status on udp port {udp_port} within {timeout:g} s")
            s.settimeout(left)
            try:
                data, addr = s.recvfrom(4096)
            except socket.timeout:
                continue
            if len(data) != STATUS_SIZE:
                continue
            try:
                return StatusMessage.decode(data), addr[0]
            except OculusError:
                continue
    finally:
        s.close()


class OculusSonar:
    """An Oculus on TCP.

    ==============  ==========================================================================
    host            the head's address; None: `discover` it (the status's ``ipAddr``)
    tcp_port        52100
    fire            the `FireMessage` to send (default `fire_message()`: 10 Hz, 10 m, 8-bit)
    pose            4x4 world-from-head mounting; each frame takes the pose current then
    timeout         s: longest wait for a ping before `SonarTimeout`
    reconnects      how many times a dropped connection is opened again (default 3)
    log             path or `mitsonar.devices.rawlog.RawLogWriter`: every byte in and out
    udp_port        52102, for `discover`
    out             where one-line problems go (default stderr; None: nowhere)
    start           connect and fire now (default True)
    ==============  ==========================================================================

    ``stats`` counts pings, reconnects and dropped messages; ``parser`` the bytes dropped and why;
    ``status`` the status message of discovery (None if ``host`` was given); ``last_raw`` the
    bytes of the last ping result read (as the head sent them).
    """

    def __init__(self, host: str | None = None, tcp_port: int = TCP_PORT, fire: FireMessage | None = None,
                 pose=None, timeout: float = 5.0, *, reconnects: int = 3, log=None, udp_port: int = UDP_PORT,
                 out=sys.stderr, start: bool = True):
        self.host = host
        self.tcp_port = int(tcp_port)
        self.fire = fire_message() if fire is None else fire
        if not isinstance(self.fire, FireMessage):
            raise TypeError(f"fire must be a FireMessage, got {type(self.fire).__name__}")
        self.pose = check_pose(pose)
        self.timeout = float(timeout)
        self.reconnects = int(reconnects)
        self.udp_port = udp_port
        self.out = out
        self.parser = StreamParser()
        self.stats: Counter = Counter()
        self.status: StatusMessage | None = None
        self._sock = None
        self._inbox: deque = deque()
        self.last_raw: bytes | None = None      # the bytes of the last ping result read
        self._log = None
        if log is not None:
            from mitsonar.devices.rawlog import RawLogWriter
            self._log = log if isinstance(log, RawLogWriter) else RawLogWriter(log, self._log_meta())
        self._own_log = log is not None and not hasattr(log, "rx")
        if start:
            self.start()

    @property
    def port(self) -> str:
        return f"tcp://{self.host}:{self.tcp_port}" if self.host else f"udp port {self.udp_port} (discovery)"

    def _log_meta(self) -> dict:
        return {"format": "mitsonar oculus raw log", "head": "oculus", "port": self.port,
                "fire": {k: v for k, v in self.fire.__dict__.items() if k != "reserved"},
                "pose": self.pose.tolist(), "passive": False}

    def _say(self, line: str) -> None:
        if self.out is not None:
            print(line, file=self.out, flush=True)

    # ---- the connection ----
    def start(self) -> None:
        """Find the head (if no host), connect, and send the fire message."""
        if self.host is None:
            self.status, sender = discover(self.timeout, self.udp_port)
            self.host = self.status.ip if self.status.ip != "0.0.0.0" else sender
        self._connect()

    def _connect(self) -> None:
        try:
            self._sock = socket.create_connection((self.host, self.tcp_port), timeout=self.timeout)
        except OSError as e:
            raise SonarError(f"{self.port}: cannot connect ({e.strerror or e})") from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.send(self.fire)

    def send(self, fire: FireMessage) -> None:
        """Send a (new) fire message; the head streams with it from then on."""
        data = fire.encode()
        try:
            self._sock.sendall(data)
        except OSError as e:
            raise SonarError(f"{self.port}: write failed ({e.strerror or e})") from None
        self.fire = fire
        self.stats["bytes out"] += len(data)
        if self._log is not None:
            self._log.tx(data)
        self.stats["fire messages"] += 1

    def _reconnect(self, why: str) -> None:
        if self.stats["reconnects"] >= self.reconnects:
            raise SonarError(f"{self.port}: {why}; gave up after {self.reconnects} reconnects")
        self.stats["reconnects"] += 1
        self._say(f"{self.port}: {why}; reconnecting ({self.stats['reconnects']} of {self.reconnects})")
        self._close_sock()
        self.parser.flush()
        end = time.monotonic() + self.timeout
        while True:
            try:
                self._connect()
                return
            except SonarError:
                if time.monotonic() >= end:
                    raise
                time.sleep(0.1)

    def _close_sock(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    def close(self) -> None:
        self._close_sock()
        if self._log is not None and self._own_log:
            self._log.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---- data ----
    def read_ping(self) -> PingResult:
        """The next simple ping result the head streams."""
        end = time.monotonic() + self.timeout
        while not self._inbox:
            left = end - time.monotonic()
            if left <= 0:
                raise SonarTimeout(f"{self.port}: no ping result within {self.timeout:g} s of the fire message "
                                   f"(an Oculus does not ping for a fire message it refuses: range "
                                   f"{self.fire.range:g}, mode {self.fire.master_mode}, rate code {self.fire.ping_rate})")
            if self._sock is None:
                self._reconnect("not connected")
            self._sock.settimeout(min(left, 0.5))
            try:
                data = self._sock.recv(1 << 20)
            except socket.timeout:
                continue
            except OSError as e:
                self._reconnect(f"connection lost ({e.strerror or e})")
                continue
            if not data:
                self._reconnect("the head closed the connection")
                continue
            self.stats["bytes in"] += len(data)
            if self._log is not None:
                self._log.rx(data)
            refused, dropped = self.parser.refused, self.parser.dropped
            for m, raw in zip(self.parser.feed(data), self.parser.raw):
                if isinstance(m, PingResult):
                    self._inbox.append((m, raw))
                else:
                    self.stats["other messages"] += 1
            if self.parser.refused > refused:
                self.stats["malformed messages"] += self.parser.refused - refused
                self._say(f"{self.port}: dropped a malformed message ({self.parser.last_problem})")
            elif self.parser.dropped > dropped:
                self._say(f"{self.port}: dropped {self.parser.dropped - dropped} bytes that form no Oculus message")
        self.stats["pings"] += 1
        m, self.last_raw = self._inbox.popleft()
        return m

    def scan(self):
        """The next ping as a multibeam `Scan` (the pose current now; start time the wall clock)."""
        p = self.read_ping()
        s = ping_to_scan(p, self.pose, time.time(), {"port": self.port})
        return s


def record(host, path, seconds: float | None = None, *, pings: int | None = None, tcp_port: int = TCP_PORT,
           fire: FireMessage | None = None, pose=None, **sonar_kwargs) -> dict:
    """Drive an Oculus and log every byte in and out (`mitsonar.devices.rawlog`, ``head: oculus``),
    until ``seconds`` or ``pings``; the log is kept only if a whole message came
    (`mitsonar.devices.recording.finish_recording`). Returns the counts of
    `mitsonar.devices.recording.record_driven`."""
    for name, v in (("seconds", seconds), ("pings", pings)):
        if v is not None and not (isinstance(v, (int, float)) and v > 0):
            raise ValueError(f"record: {name} must be positive, got {v!r}")
    sonar = OculusSonar(host, tcp_port, fire, pose, start=False, **sonar_kwargs)
    try:
        return record_driven(sonar, path, seconds, None, pings, sonar.start, "Oculus")
    finally:
        sonar.close()


def record_oculus(host, path, seconds: float | None = None, *, pings: int | None = None, tcp_port: int = TCP_PORT,
                  fire: FireMessage | None = None, **sonar_kwargs) -> dict:
    """Drive an Oculus and write its ping results, as the head sent them, to a ``.oculus`` log
    (version 1, `mitsonar.devices.oculus.logfile.OculusLogWriter`), until ``seconds`` or
    ``pings`` or Ctrl-C. The log is written under a temporary name and renamed at the end; a
    recording without a ping leaves no file and raises the `SonarError` (or `SonarTimeout`)
    that ended it. Returns the counts of `record`."""
    from mitsonar.devices.oculus.logfile import OculusLogWriter
    for name, v in (("seconds", seconds), ("pings", pings)):
        if v is not None and not (isinstance(v, (int, float)) and v > 0):
            raise ValueError(f"record: {name} must be positive, got {v!r}")
    sonar = OculusSonar(host, tcp_port, fire, start=False, **sonar_kwargs)
    writer = OculusLogWriter(path)
    end = None if seconds is None else time.monotonic() + seconds
    error = None
    try:
        sonar.start()
        while end is None or time.monotonic() < end:
            sonar.read_ping()
            writer.add(sonar.last_raw, time.time())
            if pings is not None and writer.items >= pings:
                break
    except KeyboardInterrupt:
        pass
    except (SonarError, OSError) as e:
        error = e
    finally:
        sonar.close()
    if writer.items == 0:
        writer.discard()
        raise error if error is not None else SonarTimeout(f"{sonar.port}: no ping result to record")
    writer.close()
    if error is not None:
        raise type(error)(f"{error}; the log keeps the {writer.items} pings received before: {path}") from None
    return {"bytes_rx": sonar.stats["bytes in"], "bytes_tx": sonar.stats["bytes out"], "pings": writer.items,
            "scans": 0, "bytes_dropped": int(sonar.parser.dropped)}
