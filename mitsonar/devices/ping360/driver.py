"""Blue Robotics Ping360 driver: `Ping360Sonar`, and `record` (drive a head, log its bytes).

``Ping360Sonar(port_or_url)`` opens a serial port (a device path or any pyserial URL) or the
head's UDP port (``udp://192.168.2.2:12345``), checks that a ping-protocol device answers
(``general_request`` of ``protocol_version`` and ``device_information``), and then serves pings
(`Ping360Sonar.pings`: ``device_data`` messages) and whole scans (`Ping360Sonar.scan`) as
`mitsonar.scan.Scan` objects, assembled by `mitsonar.devices.ping360.head.Ping360Assembler` (bearing,
range and pose conventions there). Each ping is one ``transducer`` message with ``transmit = 1``
at the next angle of ``settings.angles`` and its ``device_data`` reply, as ``brping.Ping360
.transmitAngle`` does (ping-protocol ``ping360.json``). Messages and framing:
`mitsonar.devices.ping360.protocol`, on ``brping``'s own definitions.
"""
from __future__ import annotations

import time
from collections import Counter, deque

from mitsonar.devices.ping360.head import Ping360Assembler, Ping360Settings, check_pose, ping_problem
from mitsonar.devices.ping360.protocol import Message, StreamParser, encode, ids
from mitsonar.devices.recording import record_driven
from mitsonar.scan import Scan
from mitsonar.devices.transports import LineDriver, SonarError, SonarTimeout

__all__ = ["Ping360Sonar", "record", "SonarError", "SonarTimeout"]


class Ping360Sonar(LineDriver):
    """A Blue Robotics Ping360 on a serial port or UDP.

    ==============  ==========================================================================
    port_or_url     device path, pyserial URL, ``udp://HOST:PORT`` (the head's Ethernet port,
                    12345 by default), or an open pyserial-like object
    baudrate        115200
    settings        `Ping360Settings` (default: 12 m, 1200 samples, normal gain, 750 kHz, full
                    turns of 400 pings)
    pose            4x4 world-from-head mounting (beam frame at angle 0); can be reassigned,
                    each ping takes the pose current when it arrives
    timeout         s: longest the head may go without a usable ping before `SonarTimeout`
    ping_timeout    s to wait for one reply before asking again (default: 2x the expected
                    ping time + 0.5 s)
    retries         requests of one ping before `SonarTimeout` (default 3 re-sends)
    log             path or `RawLogWriter`: every byte in and out is logged (``record``)
    start           check the head now (default True)
    ==============  ==========================================================================

    ``stats`` counts requests, timeouts and refused pings; ``parser`` (a
    `mitsonar.devices.ping360.protocol.StreamParser`) the bytes dropped and why; ``protocol_version`` and
    ``device_information`` what the head reported. A ``nack`` of the head raises `SonarError`
    with its text.
    """

    def __init__(self, port_or_url, baudrate: int = 115200, settings: Ping360Settings | None = None,
                 pose=None, timeout: float = 10.0, *, ping_timeout: float | None = None,
                 retries: int = 3, log=None, start: bool = True):
        settings = Ping360Settings() if settings is None else settings
        if not isinstance(settings, Ping360Settings):
            raise TypeError(f"settings must be a Ping360Settings, got {type(settings).__name__}")
        self._init_line(settings, baudrate, pose, timeout, ping_timeout, retries)
        self.parser = StreamParser()
        self.stats: Counter = Counter()
        self.protocol_version: Message | None = None
        self.device_information: Message | None = None
        self.last_ping_time: float | None = None
        self._inbox: deque = deque()
        self._assembler = Ping360Assembler(settings)
        self._next = 0
        self._attach(port_or_url, log, self.start if start else None)

    def _expected_step_time(self) -> float:
        """Request and reply on the line, motor (0.1 s at most), pulse, listening."""
        s = self._settings
        wire = (24 + 24 + s.number_of_samples) * 10.0 / self.baudrate
        return s.ping_time() + s.transmit_duration * 1e-6 + wire + 0.1

    def _log_meta(self) -> dict:
        return {"format": "mitsonar ping360 raw log", "head": "ping360", "port": str(self.port),
                "baudrate": self.baudrate, "sound_speed": self._settings.sound_speed,
                "settings": self._settings.as_dict(), "pose": self._pose.tolist(), "passive": False}

    # ---- the line ----
    _check_pose = staticmethod(check_pose)

    def _write(self, msg: Message) -> None:
        msg.src, msg.dst = 255, 0        # the host's id, as brping's PingDevice.my_id
        self._send_bytes(encode(msg), msg.name)

    def _ask(self, msg: Message, accept, what: str) -> Message:
        """Send ``msg`` until ``accept(reply)`` holds (``retries`` re-sends); a ``nack`` of it fails."""
        end = time.monotonic() + self.timeout
        for attempt in range(self.retries + 1):
            self._write(msg)
            deadline = min(end, time.monotonic() + self.ping_timeout)
            while True:
                m = self._poll(deadline)
                if m is None:
                    break
                if m.message_id == ids["nack"] and m.nacked_id == msg.message_id:
                    text = bytes(m.nack_message).split(b"\0")[0].decode("ascii", "replace")
                    raise SonarError(f"{self.port}: the head refused {msg.name}: {text}")
                if accept(m):
                    return m
                self.stats["other messages"] += 1
            self.stats["request timeouts"] += 1
            if time.monotonic() >= end:
                break
        raise SonarTimeout(f"{self.port}: no {what} within {self.timeout:g} s "
                           f"({attempt + 1} requests)")

    def start(self) -> None:
        """Check that a ping-protocol head answers, and which (protocol version, device type).

        On a serial line it first sends a break and the byte ``'U'`` for the head's baud-rate
        detection, as ``brping.PingDevice.connect_serial`` does; they are line signals, not
        messages, and are not logged (so a replay finds no stray byte).
        """
        try:
            self._ser.reset_input_buffer()
        except Exception:
            pass
        if callable(getattr(self._ser, "send_break", None)):
            try:
                self._ser.send_break(0.01)
                self._ser.write(b"U")
            except Exception:        # a port without breaks (socket://, loop://): only the 'U'
                try:
                    self._ser.write(b"U")
                except Exception as e:
                    raise SonarError(f"{self.port}: write failed: {e}") from None
        for name in ("protocol_version", "device_information"):
            reply = self._ask(Message("general_request", requested_id=ids[name]),
                              lambda m, i=ids[name]: m.message_id == i, name)
            setattr(self, name, reply)
        if self.device_information.device_type not in (0, 2):
            raise SonarError(f"{self.port}: the device is not a Ping360 (device_type "
                             f"{self.device_information.device_type}; 2 is a Ping360)")

    def reconfigure(self, settings: Ping360Settings) -> None:
        """Use new settings from the next ping on; the scan in progress is dropped."""
        if not isinstance(settings, Ping360Settings):
            raise TypeError(f"settings must be a Ping360Settings, got {type(settings).__name__}")
        self._settings = settings
        self._assembler = Ping360Assembler(settings)
        self._next = 0

    # ---- data ----
    def read_ping(self) -> Message:
        """The next ping (``device_data``) at the next angle of the scan."""
        angle = self._settings.angles[self._next]
        cmd = Message("transducer", **self._settings.transducer(angle))

        def usable(m):
            if m.message_id != ids["device_data"]:
                return False
            problem = ping_problem(m, cmd)
            if problem is not None:
                self.stats["bad pings"] += 1
            return problem is None

        reply = self._ask(cmd, usable, f"device_data at angle {angle}")
        self._next = (self._next + 1) % len(self._settings.angles)
        self.stats["pings"] += 1
        self.last_ping_time = time.time()
        return reply

    def _scan_assembler(self) -> Ping360Assembler:
        return self._assembler

    def _head_meta(self) -> dict:
        d = self.device_information
        if d is None:
            return {}
        return {"head_firmware": f"{d.firmware_version_major}.{d.firmware_version_minor}.{d.firmware_version_patch}"}

    def scan(self) -> Scan:
        """One pass over ``settings.angles`` (a full turn or a sector) as a `Scan`."""
        return super().scan()


def record(port, path, seconds: float | None = None, *, scans: int | None = None,
           pings: int | None = None, baudrate: int = 115200, settings: Ping360Settings | None = None,
           pose=None, **sonar_kwargs) -> dict:
    """Drive a Ping360 and log every byte in and out (format `mitsonar.devices.rawlog`, ``head: ping360``).

    Stops after ``seconds``, ``scans`` (`Ping360Sonar.scan` results) or ``pings``, whichever
    comes first, or on Ctrl-C. The log is written under a temporary name and renamed at the end,
    also after Ctrl-C or an error once the head sent a whole message; a recording without one
    leaves no file and raises `SonarTimeout` (`mitsonar.devices.recording.finish_recording`). Extra
    keyword arguments go to `Ping360Sonar`. Returns ``{"bytes_rx", "bytes_tx", "pings", "scans",
    "bytes_dropped"}``.
    """
    for name, v in (("seconds", seconds), ("scans", scans), ("pings", pings)):
        if v is not None and not (isinstance(v, (int, float)) and v > 0):
            raise ValueError(f"record: {name} must be positive, got {v!r}")
    with Ping360Sonar(port, baudrate, settings, pose, start=False, **sonar_kwargs) as sonar:
        return record_driven(sonar, path, seconds, scans, pings, sonar.start, "ping-protocol")
