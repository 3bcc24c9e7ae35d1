"""Tritech Micron driver on pyserial: `MicronSonar`, and `record` (drive a head, log its bytes).

``MicronSonar(port_or_url)`` opens the port (``serial.serial_for_url``: a device path,
``socket://host:port``, ``rfc2217://``, ``loop://`` ...), runs the SeaNet start-up sequence
and then serves scanlines (`MicronSonar.pings`) and whole scans (`MicronSonar.scan`) as
`mitsonar.scan.Scan` objects, assembled by `mitsonar.devices.micron.assembler.ScanAssembler` (bearing and
pose conventions there).

Start-up (reference section 5): mtReBoot -> wait for mtAlive "centred, not motoring, no
config sent" -> mtSendVersion / mtVersionData -> mtSendBBUser / mtBBUserData (DST heads then
send FPGA messages) -> wait for mtAlive "config sent" -> mtHeadCommand -> wait for mtAlive
with NoParams clear. Then one mtSendData per mtHeadData.

Where the rest went (importable from here for one release, with a DeprecationWarning):
`mitsonar.devices.rawlog` (``RawLogWriter``, ``read_log``, ``LOG_MAGIC``, ``LogDamageWarning``, ``RX``,
``TX``, ``POSE``), `mitsonar.devices.micron.assembler` (``ScanAssembler``, ``beam_rotation``),
`mitsonar.devices.recording` (``replay``).
"""
from __future__ import annotations

import time
from collections import Counter, deque

from mitsonar.devices.micron.assembler import ScanAssembler as _ScanAssembler, check_pose
from mitsonar.devices.micron.passive import record_passive
from mitsonar.devices.recording import record_driven
from mitsonar.scan import Scan
from mitsonar.devices.micron.seanet.constants import DEFAULT_NIBBLE_ORDER
from mitsonar.devices.micron.seanet.messages import (Alive, BBUserData, HeadCommand, HeadData, ReBoot, SendBBUser, SendData,
                              SendVersion, VersionData)
from mitsonar.devices.micron.seanet.settings import HeadSettings, ping_problem
from mitsonar.devices.micron.seanet.stream import StreamParser, encode
# open_serial stays importable from here (it was, and tests patch it here); the line is opened
# through it in mitsonar.devices.transports.LineDriver.
from mitsonar.devices.transports import LineDriver, SonarError, SonarTimeout, open_serial  # noqa: F401

__all__ = ["SonarError", "SonarTimeout", "MicronSonar", "record"]


class MicronSonar(LineDriver):
    """A Tritech Micron (or other SeaNet imaging head) on a serial port.

    Parameters
    ----------
    ==============  ==========================================================================
    port_or_url     device path or pyserial URL (``socket://host:port``, ``loop://``, ...), or an
                    already open pyserial-like object (read/write/in_waiting/timeout)
    baudrate        115200 (the Micron's default)
    settings        `HeadSettings` (default: 12 m, 500 bins, 1.8 deg steps, continuous, 8-bit)
    pose            4x4 world-from-head mounting (beam frame at bearing 0); can be reassigned
                    while running, each ping takes the pose current when it arrives
    timeout         s: longest the head may go without a usable scanline (or a start-up step
                    without its answer) before `SonarTimeout`; covers recovery (default 30)
    ping_timeout    s to wait for each reply before asking again (default: 2x the expected
                    step time + 0.5 s)
    retries         re-sends of a request before the driver re-configures the head (default 3)
    reboot          send mtReBoot first (default True); False attaches to a running head
    boot_timeout    s to wait for the head to come back after mtReBoot (default 30)
    nibble_order    4-bit order, ``"low_first"`` (default) or ``"high_first"``
    revisit         complete full turns from later turns when pings are lost (default True)
    max_turns       bound on that revisiting (default 3)
    log             path or `RawLogWriter`: every byte in and out is logged (``record``)
    start           run the start-up sequence now (default True)
    ==============  ==========================================================================

    Use as a context manager, or call `close`. ``stats`` counts requests, timeouts, re-sent
    parameters and recoveries; ``parser`` (a `StreamParser`) counts dropped bytes;
    ``version``, ``bbuser``, ``dst``, ``last_alive`` hold what the head reported.
    """

    def __init__(self, port_or_url, baudrate: int = 115200, settings: HeadSettings | None = None,
                 pose=None, timeout: float = 30.0, *, ping_timeout: float | None = None,
                 retries: int = 3, reboot: bool = True, boot_timeout: float = 30.0,
                 nibble_order: str = DEFAULT_NIBBLE_ORDER, revisit: bool = True,
                 max_turns: int = 3, log=None, start: bool = True):
        if settings is None:
            settings = HeadSettings()
        if not isinstance(settings, HeadSettings):
            raise TypeError(f"settings must be a HeadSettings, got {type(settings).__name__}")
        self._init_line(settings, baudrate, pose, timeout, ping_timeout, retries, boot_timeout=boot_timeout)
        self.boot_timeout = float(boot_timeout)
        self.revisit = revisit
        self.max_turns = max_turns
        self.parser = StreamParser(nibble_order=nibble_order)
        self.stats: Counter = Counter()
        self.version: VersionData | None = None
        self.bbuser: BBUserData | None = None
        self.dst = False
        self.last_alive: Alive | None = None
        self.last_ping_time: float | None = None
        self._inbox: deque = deque()
        self._stash: deque = deque()
        self._command: HeadCommand | None = None
        self._configured = False
        self._outstanding = 0
        self._sent_at = 0.0
        self._params_sent_at = -1e9
        self._dropped_at_send = 0
        self._assembler: _ScanAssembler | None = None
        self._attach(port_or_url, log, (lambda: self.start(reboot=reboot)) if start else None)

    def _expected_step_time(self) -> float:
        return self._settings.expected_step_time(self.baudrate)

    _check_pose = staticmethod(check_pose)

    def _log_meta(self) -> dict:
        return {"format": "mitsonar seanet raw log", "port": str(self.port),
                "baudrate": self.baudrate, "sound_speed": self._settings.sound_speed,
                "nibble_order": self.parser.nibble_order, "settings": self._settings.as_dict(),
                "pose": self._pose.tolist(), "revisit": self.revisit, "max_turns": self.max_turns,
                "passive": False}

    # ---- port ----
    def _write(self, msg) -> None:
        self._send_bytes(encode(msg), msg.name)

    def _seen(self, msgs: list) -> None:
        for m in msgs:
            if isinstance(m, Alive):
                self.last_alive = m

    def _aside(self, m) -> None:
        """A message nobody waits for now: keep usable scanlines, for replay's sake too."""
        if isinstance(m, HeadData):
            self._outstanding = max(0, self._outstanding - 1)
            # Same rule as replay: usable once parameters were sent and the line matches them.
            if self._command is not None and ping_problem(m, self._command) is None:
                self._stash.append(m)

    def _wait(self, pred, timeout: float, what: str, deadline: float | None = None):
        end = time.monotonic() + timeout
        if deadline is not None:
            end = min(end, deadline)
        while True:
            m = self._poll(end)
            if m is None:
                raise SonarTimeout(f"{self.port}: no {what} within {timeout:g} s")
            if pred(m):
                return m
            self._aside(m)

    def _request(self, msg, reply_type, what: str, deadline: float | None = None):
        last = None
        for _ in range(self.retries + 1):
            self._write(msg)
            try:
                return self._wait(lambda m: isinstance(m, reply_type), self.ping_timeout, what, deadline)
            except SonarTimeout as e:
                last = e
                self.stats["request timeouts"] += 1
                if deadline is not None and time.monotonic() >= deadline:
                    break
        raise SonarTimeout(f"{last} ({self.retries + 1} requests)")

    # ---- start-up ----
    def start(self, reboot: bool = True) -> None:
        """Run the start-up sequence (reboot, alive, version, BB user, parameters)."""
        self._configured = False
        if reboot:
            try:
                self._ser.reset_input_buffer()
            except Exception:
                pass
            self.parser.reset()
            self._inbox.clear()
            self._write(ReBoot())
            self._wait(lambda m: isinstance(m, Alive) and m.centred and not m.motoring and not m.sent_cfg,
                       self.boot_timeout, "mtAlive of a centred, idle head after mtReBoot")
        self._configure(time.monotonic() + self.timeout)

    def _configure(self, deadline: float) -> None:
        self._configured = False
        self._outstanding = 0
        self.version = self._request(SendVersion(), VersionData, "mtVersionData", deadline)
        self.bbuser = self._request(SendBBUser(), BBUserData, "mtBBUserData", deadline)
        self.dst = self.bbuser.is_dst
        try:
            # Heads send mtAlive about once a second; a head that never sets SentCfg only
            # costs this short wait.
            self._wait(lambda m: isinstance(m, Alive) and m.sent_cfg, min(self.timeout, 5.0),
                       "mtAlive with SentCfg", deadline)
        except SonarTimeout:
            self.stats["no SentCfg alive"] += 1     # send the parameters anyway
        last = None
        for _ in range(self.retries + 1):
            self._send_params()
            try:
                self._wait(lambda m: isinstance(m, Alive) and not m.no_params, self.timeout,
                           "mtAlive accepting the parameters", deadline)
                self._configured = True
                return
            except SonarTimeout as e:
                last = e
                if time.monotonic() >= deadline:
                    break
        raise SonarTimeout(f"{self.port}: the head did not accept the parameters ({last})")

    def _send_params(self) -> None:
        self._command = self._settings.head_command(dst=self.dst)
        self._write(self._command)
        self._params_sent_at = time.monotonic()
        self._outstanding = 0

    def reconfigure(self, settings: HeadSettings) -> None:
        """Send new settings to the running head; scans in progress are dropped."""
        if not isinstance(settings, HeadSettings):
            raise TypeError(f"settings must be a HeadSettings, got {type(settings).__name__}")
        self._settings = settings
        self._assembler = None
        self._stash.clear()
        self._configure(time.monotonic() + self.timeout)

    def _recover(self, reason: str, deadline: float) -> None:
        self.stats["recoveries"] += 1
        last = None
        while time.monotonic() < deadline:
            try:
                self._configure(deadline)
                return
            except SonarTimeout as e:
                last = e
        raise SonarTimeout(f"{self.port}: {reason}; could not re-configure the head within "
                           f"{self.timeout:g} s ({last})")

    # ---- data ----
    def read_ping(self) -> HeadData:
        """The next usable scanline (requests it, retries, recovers as needed)."""
        if not self._configured:
            raise SonarError("the head is not configured: call start()")
        deadline = time.monotonic() + self.timeout
        failures = 0
        last_problem = None
        while True:
            if self._stash:
                return self._got(self._stash.popleft())
            now = time.monotonic()
            if now >= deadline:
                why = f" (last scanline: {last_problem})" if last_problem else ""
                raise SonarTimeout(f"{self.port}: no usable mtHeadData for {self.timeout:g} s{why}")
            if self._outstanding <= 0:
                self._write(SendData())
                self._outstanding, self._sent_at = 1, now
                self._dropped_at_send = self.parser.dropped
            m = self._poll(min(self._sent_at + self.ping_timeout, deadline))
            if m is None:
                self.stats["ping timeouts"] += 1
                self._outstanding = 0
                failures += 1
                if failures > self.retries:
                    failures = 0
                    self._recover(f"no mtHeadData after {self.retries + 1} requests", deadline)
                continue
            if not isinstance(m, HeadData) and self._outstanding > 0 and self.parser.dropped > self._dropped_at_send:
                # A damaged packet went by and something else followed it: the reply we wait
                # for was most likely the damaged one, so ask again without waiting it out.
                self.stats["early re-requests"] += 1
                self._outstanding = 0
            if isinstance(m, Alive):
                if m.no_params:
                    # Only a reset head forgets its parameters: start it again.
                    self._recover("the head lost its parameters (reset?)", deadline)
                continue
            if not isinstance(m, HeadData):
                continue
            self._outstanding = max(0, self._outstanding - 1)
            problem = ping_problem(m, self._command)
            if problem is None:
                return self._got(m)
            self.stats["bad pings"] += 1
            last_problem = problem
            if self._params_sent_at <= self._sent_at:
                # The head had our parameters when it made this line and still complains
                # (motor lost sync, reset, other settings): send them again. Lines already
                # in flight after a re-send are only skipped.
                self.stats["parameters re-sent"] += 1
                self._send_params()

    def _got(self, m: HeadData) -> HeadData:
        self.stats["pings"] += 1
        self.last_ping_time = time.time()
        return m

    def _scan_assembler(self) -> _ScanAssembler:
        if self._assembler is None:
            self._assembler = _ScanAssembler(self._settings.sound_speed, revisit=self.revisit,
                                            max_turns=self.max_turns, settings=self._settings)
        return self._assembler

    def _head_meta(self) -> dict:
        out = {"dst": bool(self.dst)}
        if self.version is not None:
            out["head_serial"] = int(self.version.serial)
            out["head_software"] = int(self.version.software_version)
        return out

    def scan(self) -> Scan:
        """One full turn (continuous) or one sector sweep as a `Scan` (see `ScanAssembler`)."""
        return super().scan()


def record(port, path, seconds: float | None = None, *, scans: int | None = None,
           pings: int | None = None, baudrate: int = 115200, settings: HeadSettings | None = None,
           passive: bool = False, pose=None, **sonar_kwargs) -> dict:
    """Record the raw byte stream of a head into a raw log (format: `mitsonar.devices.rawlog`).

    Parameters
    ----------
    ========  =================================================================
    port      device path or pyserial URL
    path      log file to write
    seconds   stop after this long (None: until scans/pings or Ctrl-C)
    scans     drive the head and stop after this many `MicronSonar.scan` results
    pings     drive the head and stop after this many scanlines
    baudrate  115200
    settings  `HeadSettings` for the head (driven mode)
    passive   only listen (a tap on the head's transmit line); needs ``seconds``
    pose      head mounting stored in the log
    ========  =================================================================

    Extra keyword arguments go to `MicronSonar` (``timeout`` and ``boot_timeout`` bound how
    long a silent head is waited for). Returns counts (bytes in/out, pings, scans; driven:
    ``bytes_dropped``, received bytes that formed no whole packet).

    The log is written under a temporary name in the same folder and renamed to ``path`` at the
    end, also after Ctrl-C or an error once the head has sent a packet (the error then names the
    log). A recording without any packet from the head leaves no file and raises `SonarTimeout`
    "no bytes from the head on PORT in N s" (`mitsonar.devices.recording.finish_recording`).
    """
    if passive and seconds is None:
        raise ValueError("record: passive recording needs seconds")
    for name, v in (("seconds", seconds), ("scans", scans), ("pings", pings)):
        if v is not None and not (isinstance(v, (int, float)) and v > 0):
            raise ValueError(f"record: {name} must be positive, got {v!r}")
    settings = settings or HeadSettings()
    if passive:
        return record_passive(port, path, seconds, baudrate=baudrate, settings=settings, pose=pose)
    reboot = sonar_kwargs.pop("reboot", True)
    with MicronSonar(port, baudrate, settings, pose, start=False, **sonar_kwargs) as sonar:
        return record_driven(sonar, path, seconds, scans, pings, lambda: sonar.start(reboot=reboot))


# Names that lived here before the driver was split from the log format, the scan assembly
# and the replay: importable from here for one release, with a warning naming the new home.
_MOVED = {"RawLogWriter": "rawlog", "read_log": "rawlog", "LOG_MAGIC": "rawlog",
          "LogDamageWarning": "rawlog", "RX": "rawlog", "TX": "rawlog", "POSE": "rawlog",
          "ScanAssembler": "assembler", "beam_rotation": "assembler", "replay": "recording"}


def __getattr__(name):
    if name in _MOVED:
        import warnings

        from mitsonar.devices import rawlog, recording
        from mitsonar.devices.micron import assembler
        home = {"rawlog": rawlog, "assembler": assembler, "recording": recording}[_MOVED[name]]
        warnings.warn(f"mitsonar.devices.micron.driver.{name} moved to {home.__name__}: import it from "
                      f"there (the old path goes in the next release)", DeprecationWarning, stacklevel=2)
        return getattr(home, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
