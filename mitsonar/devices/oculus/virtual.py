"""A virtual Oculus M-series head: a status broadcast on UDP and a TCP port answering fire
messages with simple ping results rendered from a multibeam scan.

``VirtualOculus(scan)`` is the head of one model (`mitsonar.presets.oculus`, default the
M1200d). It binds ``host`` (127.0.0.1 by default; loopback only unless asked) on TCP
``tcp_port`` (52100) and sends an ``OculusStatusMsg`` carrying ``host`` as its address every
``status_period`` s to ``host``:``udp_port`` (52102), as a real head broadcasts it on its
network. Several clients may connect at once; each has its own stream:

===============================  ========================================================
a simple fire message (v1, v2)   the head takes its settings: ``masterMode`` picks the
                                 frequency mode (frequency, aperture, vertical beam width,
                                 largest range of the model), ``pingRate`` the stream
                                 (2, 5, 10, 15 or 40 Hz; standby: none), ``flags`` the
                                 units of ``range`` (bit 0: metres, else percent of the
                                 mode's largest range), 16-bit samples (bit 1), per-row
                                 gains (bit 2) and 512 beams (bit 6, else 256); version 2
                                 ``extFlags`` 0x200 asks for 32-bit samples. The head then
                                 sends a simple ping result of the same version at that
                                 rate until the next fire message
a field out of range             refused (``stats["refused"]``, ``last_problem`` names the
                                 field and the allowed values); the stream goes on with the
                                 settings before
a malformed, oversized message   refused and counted (``stats["refused"]``); the client
                                 stays connected, the head stays up
===============================  ========================================================

Each ping (`VirtualOculus.ping`) comes from a scan (`VirtualOculus.scan_for`): with ``frames``
(`mitsonar.devices.oculus.scenes.SceneFrames`, what ``virtual-sonar SCENE --head oculus``
uses), the scene rendered at the fire message's geometry (the mode's aperture, frequency and beam
widths, the beam count, the range); else the scan given (ping k: scan k of a list, in turn).
The beams are the head's own bearing table
(`mitsonar.presets.oculus.bearing_table` of the mode's aperture); beam k takes the row of
the scan whose bearing is nearest (within half the scan's row spacing there; zeros outside the
scan's fan). The range lines are ``range_resolution = bin width x c_used / c_scan`` apart (the
scan's bins at the scan's sound speed), ``n_ranges = round(range / range_resolution)``; line i
takes the scan bin holding the range ``(i + 1/2) x range_resolution x c_scan / c_used`` (a
different speed of sound stretches the image as it would a real head's), zeros past the scan.
``speedOfSound`` 0 means the head's own: `mitsonar.acoustics.seawater.sound_speed` of the
water's temperature, the fire message's salinity and the head's depth below ``surface_z``.

Levels: ``gainPercent`` g is the receiver gain: 100 % the scan's own, g % ``20 log10(g/100)`` dB
on it (`VirtualOculus.received`: a rendered scan through its receiver chain again, a scan of
bytes moved on its A/D scale); ``gammaCorrection`` G applies ``T (x/T)^(G/255)`` (G 0 or
255: none) to the codes x of full scale T. 8-bit samples are the scan's bytes; 16- and 32-bit
ones the same levels through a wider A/D: a rendered scan's receiver chain again at ``bit_depth``
16 or 32 (`mitsonar.receiver.electronics.Electronics`: ``round((2^bits - 1) x)`` of the A/D
window's fraction x, so the 8-bit byte is the 16-bit code / 257 up to rounding); a log's codes
on the width asked (its bytes times 257 and 16843009: it has no finer levels; its 16- or 32-bit
codes as they are, or on the other width's scale). The per-row gain sent (flag bit 2)
is g/100 (the amplitude gain) as a float32. So at gain 100 and gamma 255 the 8-bit image is the
scan's bytes.

``heading``, ``pitch``, ``roll`` (version 2 results) come from the head's pose in the scan (world x
east, y north, z up: heading clockwise from north of the boresight, pitch its elevation, roll the
tilt of the fan's axis towards starboard), ``temperature`` from ``water`` (deg C),
``pressure`` (bar, gauge) from the head's depth ``surface_z - z`` (``water``: a scene's own,
`scene_water`, with ``virtual-sonar SCENE`` and ``live``).

Timing (``realtime=True``): a stream's pings are ``max(1 / rate, 2 range / c)`` apart on the
head's own clock, from the fire message on (slot k at ``k x period``, as a real head keeps its
rate: a ping sent late does not delay the next slot); a slot missed by a whole period (a ping
that took longer than that) is skipped and counted, not caught up in a burst
(`VirtualOculus._slot`). ``realtime=False`` sends each ping as soon as the last one is written.
"""
from __future__ import annotations

import math
import selectors
import socket
import sys
import threading
import time
from collections import Counter, deque

import numpy as np

import mitsonar.presets.oculus as presets
from mitsonar.devices.oculus.protocol import (FLAG, PING_RATE_HZ, TCP_PORT, UDP_PORT, FireMessage, OculusError,
                                              PingResult, StatusMessage, StreamParser)
from mitsonar.scan import Scan

__all__ = ["VirtualOculus", "attitude", "check_fire", "serve", "parse_tcp_url"]

#: a fire message is 89 bytes at most: anything much larger is no message for the head
MAX_INCOMING_PAYLOAD = 1024
#: how much a slow client may have waiting before pings for it are skipped
MAX_BACKLOG = 8 << 20


def parse_tcp_url(url: str | None, default_host: str = "127.0.0.1", default_port: int = 52100) -> tuple[str, int]:
    """``tcp://HOST:PORT`` (or ``HOST:PORT``, ``HOST``, or None for the defaults) as ``(host,
    port)``; ValueError naming the URL and the allowed form."""
    if url is None:
        return default_host, default_port
    text = url[len("tcp://"):] if url.startswith("tcp://") else url
    if ":" not in text and text:
        return text, default_port
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"--port-url {url!r} is not allowed for an Oculus (tcp://HOST:PORT, port 0..65535)")
    return host, int(port)


def attitude(pose) -> tuple[float, float, float]:
    """``(heading, pitch, roll)`` in degrees of a beam frame (4x4, ``[:3, 2]`` boresight,
    ``[:3, 1]`` the fan's axis) in a world with x east, y north, z up."""
    p = np.asarray(pose, np.float64)
    b, s = p[:3, 2], p[:3, 1]
    heading = math.degrees(math.atan2(b[0], b[1])) % 360.0
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, b[2]))))
    r = np.cross(b, [0.0, 0.0, 1.0])
    n = np.linalg.norm(r)
    if n < 1e-9:
        return heading, pitch, 0.0
    r /= n
    u = np.cross(r, b)
    return heading, pitch, math.degrees(math.atan2(float(s @ r), float(s @ u)))


def check_fire(fire: FireMessage, model) -> str | None:
    """None, or one line naming the fire message's field that the head refuses and what it allows."""
    if fire.master_mode not in model.modes:
        return f"simple fire 'masterMode': {fire.master_mode} is not allowed (1 low or 2 high frequency)"
    if fire.ping_rate not in PING_RATE_HZ:
        return f"simple fire 'pingRate': {fire.ping_rate} is not allowed (0..5: 10, 15, 40, 5, 2 Hz, standby)"
    mode = model.mode(fire.master_mode)
    r = _range(fire, mode)
    if not (math.isfinite(r) and presets.MIN_RANGE <= r <= mode.max_range):
        return (f"simple fire 'range': {fire.range!r} {'m' if fire.flags & FLAG['range_as_meters'] else '%'} "
                f"is not allowed ({presets.MIN_RANGE:g}..{mode.max_range:g} m for the {model.name} in mode "
                f"{fire.master_mode})")
    if not (math.isfinite(fire.gain) and 0 <= fire.gain <= 100):
        return f"simple fire 'gainPercent': {fire.gain!r} is not allowed (0..100)"
    if not (fire.speed_of_sound == 0 or (math.isfinite(fire.speed_of_sound) and 1300 <= fire.speed_of_sound <= 1800)):
        return f"simple fire 'speedOfSound': {fire.speed_of_sound!r} is not allowed (0: from salinity, or 1300..1800 m/s)"
    if not (math.isfinite(fire.salinity) and 0 <= fire.salinity <= 50):
        return f"simple fire 'salinity': {fire.salinity!r} is not allowed (0..50 ppt)"
    return None


def _range(fire: FireMessage, mode) -> float:
    if fire.flags & FLAG["range_as_meters"]:
        return float(fire.range)
    return float(fire.range) / 100.0 * mode.max_range


class _Client:
    def __init__(self, sock, addr):
        self.sock, self.addr = sock, addr
        self.parser = StreamParser(MAX_INCOMING_PAYLOAD)
        self.out = bytearray()
        self.written = 0                # bytes sent to the client so far
        self.ends: deque = deque()      # (self.written at a ping's last byte, its ping id), in order
        self.fire: FireMessage | None = None
        self.due = 0.0


class VirtualOculus:
    """A simulated Oculus on TCP and UDP (see the module's text).

    ===============  ========================================================================
    scan             the multibeam `Scan` to serve, or a list of them (a log: ping k is
                     scan ``k mod len(scans)``)
    model            ``"M750d"``, ``"M1200d"`` (default), ``"M3000d"`` or a part number
    host             address to bind and to carry in the status (default 127.0.0.1)
    tcp_port         52100 (0: any free port; `tcp_port` then says which)
    udp_port         52102: where the status goes (None: no status broadcast)
    status_period    s between status messages (default 1)
    realtime         True: pings at the fire message's rate; False: as fast as written
    water            ``{"temperature": deg C, "surface_z": m}`` (default 10 and 0, the
                     sensor's defaults; `scene_water` reads a scene sensor's): the head's
                     temperature, and its depth ``surface_z - z``
    device_id        the head's ``srcDeviceId`` and ``deviceId`` (default 1)
    frames           ``frames(mode, n_beams, range) -> Scan``: the scan of each fire
                     message's geometry (`mitsonar.devices.oculus.scenes.SceneFrames`);
                     None: the scans given
    clock            seconds, the head's clock of its ping slots (default ``time.monotonic``)
    ===============  ========================================================================

    ``stats`` counts clients, messages, pings and refusals; ``last_problem`` is the last refusal.
    """

    def __init__(self, scan: Scan, *, model="M1200d", host: str = "127.0.0.1", tcp_port: int = TCP_PORT,
                 udp_port: int | None = UDP_PORT, status_period: float = 1.0, realtime: bool = True,
                 water: dict | None = None, device_id: int = 1, frames=None, clock=time.monotonic):
        scans = list(scan) if isinstance(scan, (list, tuple)) else [scan]
        if not scans:
            raise ValueError("VirtualOculus: no scan to serve")
        for s in scans:
            if not isinstance(s, Scan):
                raise TypeError(f"scan must be a Scan or a list of them, got {type(s).__name__}")
            if not s.sonar_kind.fan_frame:
                raise ValueError(f"VirtualOculus: a {s.kind} scan has no Oculus pings to serve "
                                 f"(an Oculus is a multibeam head)")
        for name, port in (("tcp_port", tcp_port), ("udp_port", udp_port)):
            if port is not None and not (isinstance(port, int) and 0 <= port <= 65535):
                raise ValueError(f"VirtualOculus: {name} = {port!r} is not allowed (0..65535)")
        self.scans = scans
        self.scan = scans[0]
        self.frames = frames
        self.model = presets.model(model)
        self.host = host
        self.tcp_port = tcp_port
        self.udp_port = udp_port
        self.status_period = float(status_period)
        self.realtime = bool(realtime)
        self.water = {"temperature": 10.0, "surface_z": 0.0, **(water or {})}
        from mitsonar.acoustics.seawater import MACKENZIE_RANGE
        lo, hi = MACKENZIE_RANGE["temperature"]
        t = self.water["temperature"]
        if not (isinstance(t, (int, float)) and lo <= t <= hi):
            raise ValueError(f"VirtualOculus: water temperature {t!r} is not allowed ({lo:g}..{hi:g} deg C)")
        z = self.water["surface_z"]
        if not (isinstance(z, (int, float)) and math.isfinite(z)):
            raise ValueError(f"VirtualOculus: water surface_z {z!r} is not allowed (a finite world z, m)")
        self.device_id = int(device_id)
        self.stats: Counter = Counter()
        self.last_problem: str | None = None
        self.last_error: BaseException | None = None
        self._clients: dict = {}
        self._cache: dict = {}
        self._thread = None
        self._stop = threading.Event()
        self._clock = clock
        self._t0 = clock()
        self._fans: dict = {}
        self._drop_all = threading.Event()

    def _fan(self, scan: Scan):
        """``scan``'s rows sorted by bearing, the bearings, and half the row spacing at each."""
        if id(scan) not in self._fans:
            if len(self._fans) > 32:
                self._fans.clear()
            b = np.asarray(scan.bearings, np.float64)
            order = np.argsort(b)
            b = b[order]
            gaps = np.diff(b)
            half = np.zeros(len(b))
            if len(b) > 1:
                half = np.maximum(np.r_[gaps[0], gaps], np.r_[gaps, gaps[-1]]) / 2
            self._fans[id(scan)] = (scan, order, b, half)      # the scan kept: its id stays its own
        return self._fans[id(scan)][1:]

    def scan_for(self, fire: FireMessage, ping_id: int = 0) -> Scan:
        """The scan ping ``ping_id`` of ``fire`` is taken from: ``frames(mode, n_beams, range)``
        (a scene rendered at the fire message's geometry) if given, else scan ``ping_id mod
        len(scans)``."""
        if self.frames is not None:
            return self.frames(*self.geometry_of(fire))
        return self.scans[ping_id % len(self.scans)]

    def geometry_of(self, fire: FireMessage) -> tuple:
        """``(mode, n_beams, range m)`` a fire message asks for (`mitsonar.presets.oculus.Mode`)."""
        mode = self.model.mode(fire.master_mode)
        return mode, fire.n_beams, _range(fire, mode)

    # ---- pings ----
    def sound_speed(self, fire: FireMessage) -> float:
        """The speed of sound the head uses: the fire message's, or (speedOfSound 0) Mackenzie's
        (`mitsonar.acoustics.seawater.sound_speed`) at the water's temperature, the message's
        salinity and the head's depth. The equation is linear in salinity: outside its 25..40 ppt
        (fresh water, 0 ppt, is what liboculus asks by default) it is continued along that line,
        from its values at the nearest end and one ppt inside."""
        if fire.speed_of_sound:
            return float(fire.speed_of_sound)
        from mitsonar.acoustics.seawater import MACKENZIE_RANGE, sound_speed
        depth = self.depth(self.head_pose(self.scans[0]))
        t = float(self.water["temperature"])
        lo, hi = MACKENZIE_RANGE["salinity"]
        s = float(fire.salinity)
        if lo <= s <= hi:
            return float(sound_speed(t, s, depth))
        end = lo if s < lo else hi
        inside = end + (1.0 if s < lo else -1.0)
        c_end, c_in = float(sound_speed(t, end, depth)), float(sound_speed(t, inside, depth))
        return c_end + (s - end) * (c_end - c_in) / (end - inside)

    def depth(self, pose) -> float:
        """m below the water's surface (``surface_z``) of a head at ``pose``; 0 above it."""
        return max(0.0, float(self.water["surface_z"]) - float(pose[2, 3]))

    @staticmethod
    def head_pose(scan: Scan) -> np.ndarray:
        """The head's pose (its boresight at bearing 0) in ``scan``: row 0's pose turned back by
        row 0's bearing (`mitsonar.geometry.frames.bearing_rotation`)."""
        from mitsonar.geometry.frames import bearing_rotation
        if not scan.n_pings:
            return np.eye(4)
        return scan.poses[0] @ bearing_rotation(-float(scan.bearings[0]))

    def ping(self, fire: FireMessage, ping_id: int = 0, now: float = 0.0) -> PingResult:
        """The simple ping result the head sends for ``fire`` (checked with `check_fire`) as its
        ping ``ping_id``, from `scan_for`."""
        problem = check_fire(fire, self.model)
        if problem:
            raise OculusError(problem)
        mode = self.model.mode(fire.master_mode)
        c = self.sound_speed(fire)
        scan = self.scan_for(fire, ping_id)
        image, bearings, res = self._image(fire, mode, c, scan)
        pose = self.head_pose(scan)
        heading, pitch, roll = attitude(pose)
        depth = self.depth(pose)
        gains = np.full(image.shape[0], fire.gain / 100.0, np.float32) if fire.send_gain else None
        return PingResult(fire, image, bearings, res, gains=gains, ping_id=ping_id, status=0,
                          frequency=mode.frequency, temperature=float(self.water["temperature"]),
                          pressure=depth * 1025.0 * 9.80665 / 1e5, heading=heading, pitch=pitch, roll=roll,
                          speed_of_sound_used=c, ping_start_time=now, src=self.device_id)

    def _image(self, fire, mode, c, scan):
        key = (fire.master_mode, _range(fire, mode), fire.n_beams, c, fire.gain, fire.gamma, fire.data_bytes,
               id(scan))
        if key in self._cache and self._cache[key][0] is scan:
            return self._cache[key][1]
        rows_of, fan_b, fan_half = self._fan(scan)
        bearings = presets.bearing_table(mode.aperture, fire.n_beams)
        stretch = c / scan.sound_speed
        res = scan.bin_width * stretch
        n_r = max(1, min(65535, int(round(key[1] / res))))
        if n_r > 4096:                       # keep the image a real head's size: coarser lines
            n_r, res = 4096, key[1] / 4096
        from mitsonar.receiver.devicechain import AD_CODES
        bits = 8 * fire.data_bytes
        top, _, dtype = AD_CODES[bits]
        level = np.zeros((n_r, fire.n_beams), np.float64)
        if scan.n_pings:
            want = np.radians(bearings / 100.0)
            k = np.clip(np.searchsorted(fan_b, want), 1, max(1, len(fan_b) - 1)) if len(fan_b) > 1 \
                else np.zeros(len(want), int)
            if len(fan_b) > 1:
                k = np.where(np.abs(fan_b[k - 1] - want) <= np.abs(fan_b[k] - want), k - 1, k)
            inside = np.abs(fan_b[k] - want) <= fan_half[k] + 1e-12
            r_scan = (np.arange(n_r) + 0.5) * res / stretch
            idx = np.floor((r_scan - scan.range_min) / scan.bin_width + 1e-9).astype(np.int64)
            ok = (idx >= 0) & (idx < scan.n_bins)
            rows = self.received(scan, fire.gain, bits)[rows_of[k]].astype(np.float64)      # (n_beams, n_bins)
            level[np.ix_(ok, inside)] = rows[inside][:, idx[ok]].T
        if fire.gamma not in (0, 255):
            level = top * (level / top) ** (fire.gamma / 255.0)
        image = np.round(level).astype(dtype)
        out = (image, bearings, float(res))
        if len(self._cache) > 32:
            self._cache.clear()
        self._cache[key] = (scan, out)
        return out

    def received(self, scan: Scan, gain_percent: float, bits: int = 8) -> np.ndarray:
        """``scan``'s codes from a ``bits``-bit A/D (8: bytes, uint8; 16, 32: uint16, uint32) at
        the receiver gain ``gain_percent`` asks for: 100 % is the scan's own gain; g % is
        ``20 log10(g / 100)`` dB on it (50 %: -6 dB), within the head's 0..80 dB
        (`mitsonar.receiver.electronics.HEAD_LIMITS`; 0 %: the least). A rendered scan (with
        intensity) goes through its receiver chain again at that gain and A/D width
        (`mitsonar.receiver.electronics.apply_to_scan`, the same noise seed: its 8-bit codes are
        its bytes at 100 %); a scan of codes only (a log) has them moved by that many dB on its
        A/D scale (``ad_span``) and scaled to the width asked (a byte b is ``257 b`` at 16 bits)."""
        from mitsonar.receiver.devicechain import AD_CODES
        from mitsonar.receiver.electronics import HEAD_LIMITS, Electronics, apply_to_scan
        top, _, dtype = AD_CODES[bits]
        if gain_percent == 100.0 and scan.data.dtype == dtype:
            return scan.data
        key = ("received", id(scan), float(gain_percent), bits)
        if key in self._cache and self._cache[key][0] is scan:
            return self._cache[key][1]
        e = Electronics.from_dict(scan.electronics.to_dict())
        lo, hi = HEAD_LIMITS["gain"]
        db = 20.0 * math.log10(gain_percent / 100.0) if gain_percent > 0 else -math.inf
        if np.any(scan.intensity):
            gain = e.gain if gain_percent == 100.0 else float(np.clip(e.gain + db, lo, hi))
            out = apply_to_scan(scan, scan.electronics.replace(gain=gain, bit_depth=bits)).data
        else:
            shift = 0.0 if gain_percent == 100.0 else max(db, lo - e.gain) * top / e.ad_span
            codes = scan.data.astype(np.float64) * (top / np.iinfo(scan.data.dtype).max)
            out = np.clip(np.floor(codes + shift + 0.5), 0, top).astype(dtype)
        self._cache[key] = (scan, out)
        return out

    def period(self, fire: FireMessage) -> float:
        """Seconds between the pings of a stream fired with ``fire`` (inf in standby)."""
        rate = PING_RATE_HZ[fire.ping_rate]
        if rate == 0:
            return math.inf
        if not self.realtime:
            return 0.0
        mode = self.model.mode(fire.master_mode)
        return max(1.0 / rate, 2.0 * _range(fire, mode) / self.sound_speed(fire))

    # ---- the network ----
    def status(self) -> StatusMessage:
        connected = next(iter(self._clients.values())).addr[0] if self._clients else "0.0.0.0"
        return StatusMessage(device_id=self.device_id, part_number=self.model.part_number, ip=self.host,
                             connected_ip=connected, src=self.device_id,
                             temperatures=(float(self.water["temperature"]),) * 8)

    def start(self) -> tuple[str, int]:
        """Bind the ports and start serving; returns ``(host, tcp_port)``."""
        if self._thread is not None:
            return self.host, self.tcp_port
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            srv.bind((self.host, self.tcp_port))
        except OSError as e:
            srv.close()
            raise OSError(f"virtual Oculus: cannot listen on tcp://{self.host}:{self.tcp_port}: {e.strerror or e}") from None
        srv.listen(8)
        srv.setblocking(False)
        self.tcp_port = srv.getsockname()[1]
        self._server = srv
        self._udp = None
        if self.udp_port is not None:
            self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._udp.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self._sel = selectors.DefaultSelector()
        self._sel.register(srv, selectors.EVENT_READ, None)
        self._stop.clear()
        self._next_status = self._clock()
        self._thread = threading.Thread(target=self._run, name="VirtualOculus", daemon=True)
        self._thread.start()
        return self.host, self.tcp_port

    @property
    def port(self) -> str:
        return f"tcp://{self.host}:{self.tcp_port}"

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
            for c in list(self._clients.values()):
                c.sock.close()
            self._clients.clear()
            self._server.close()
            if self._udp is not None:
                self._udp.close()
            self._sel.close()

    close = stop

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._tick()
            except Exception as e:          # the head stays up; the user or test sees last_error
                self.last_error = e
                self.stats["internal errors"] += 1
                time.sleep(0.01)

    def drop_clients(self) -> None:
        """Close every client's connection (a fault, for tests of a driver's reconnect)."""
        self._drop_all.set()

    def _tick(self) -> None:
        now = self._clock()
        if self._drop_all.is_set():
            self._drop_all.clear()
            for c in list(self._clients.values()):
                self._drop(c)
        if self._udp is not None and now >= self._next_status:
            try:
                self._udp.sendto(self.status().encode(), (self.host, self.udp_port))
                self.stats["status sent"] += 1
            except OSError:
                self.stats["status not sent"] += 1
            self._next_status = now + self.status_period
        for c in list(self._clients.values()):
            now = self._clock()             # another client's ping may have taken time
            if c.fire is not None and now >= c.due:
                self._slot(c, now)
        now = self._clock()                 # the pings took time: wait from now, not from the tick's start
        wait = self._next_status - now if self._udp is not None else 0.05
        for c in self._clients.values():
            if c.fire is not None:
                wait = min(wait, c.due - now)
        for key, events in self._sel.select(max(0.0, min(wait, 0.05))):
            if key.data is None:
                self._accept()
            else:
                c = key.data
                if events & selectors.EVENT_READ:
                    self._read(c)
                if events & selectors.EVENT_WRITE and c.sock.fileno() >= 0:
                    self._flush(c)

    def _accept(self) -> None:
        try:
            sock, addr = self._server.accept()
        except BlockingIOError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        c = _Client(sock, addr)
        self._clients[sock.fileno()] = c
        self._sel.register(sock, selectors.EVENT_READ, c)
        self.stats["clients"] += 1

    def _drop(self, c: _Client) -> None:
        self._clients.pop(c.sock.fileno(), None)
        try:
            self._sel.unregister(c.sock)
        except (KeyError, ValueError):
            pass
        c.sock.close()
        self.stats["clients gone"] += 1
        while c.ends:
            self.delivered(c.ends.popleft()[1], None)

    def delivered(self, ping_id: int, t: float | None) -> None:
        """Ping ``ping_id``'s last byte was written to its client at ``t`` (the head's clock), or
        never (``t`` None: the client went first). Nothing here; `mitsonar.live.heads.LiveOculus`
        logs the ping's latency."""

    def _read(self, c: _Client) -> None:
        try:
            data = c.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(c)
            return
        dropped = c.parser.dropped
        messages = c.parser.feed(data)
        refusals = list(c.parser.refusals)
        for k, m in enumerate(messages + [None]):
            while refusals and refusals[0][0] == k:        # in the order they came
                self.stats["refused"] += 1
                self.last_problem = refusals.pop(0)[1]
            if m is not None:
                self._on_message(c, m)
        self.stats["bytes dropped"] += c.parser.dropped - dropped

    def _on_message(self, c: _Client, m) -> None:
        if not isinstance(m, FireMessage):
            self.stats[f"ignored {type(m).__name__}"] += 1
            return
        self.stats["fire messages"] += 1
        problem = check_fire(m, self.model)
        if problem:
            self.stats["refused"] += 1
            self.last_problem = problem
            return
        c.fire = m
        # the first ping at once, then at the rate; standby (pingRate 5): none, until the next fire message
        c.due = self._clock() if PING_RATE_HZ[m.ping_rate] else math.inf

    def _slot(self, c: _Client, now: float) -> None:
        """Client ``c``'s ping slot ``c.due`` has come (at ``now``): ping, and the next slot one
        period on, on the head's own clock (``due += period``: a ping sent late does not delay
        the ones after it). A slot missed by a whole period or more (a ping that took longer than
        the period, a stalled process) is skipped and counted (``stats["pings skipped (late)"]``),
        not caught up in a burst; a slot while the client has ``MAX_BACKLOG`` bytes waiting is
        skipped and counted (``stats["pings skipped (client behind)"]``)."""
        period = self.period(c.fire)
        late = now - c.due
        if 0.0 < period < math.inf and late >= period:
            missed = int(late // period)
            self.stats["pings skipped (late)"] += missed
            c.due += missed * period
        if len(c.out) < MAX_BACKLOG:
            self._send_ping(c, now)
        else:
            self.stats["pings skipped (client behind)"] += 1
        c.due += period

    def _send_ping(self, c: _Client, now: float) -> None:
        pid = self.stats["pings"]
        try:
            data = self.ping(c.fire, pid, now - self._t0).encode()
        except ValueError as e:          # a ping this head cannot make: said, the stream stopped
            self.stats["refused"] += 1
            self.last_problem = f"ping {pid}: {e}"
            c.fire = None
            return
        self.stats["pings"] += 1
        c.out += data
        c.ends.append((c.written + len(c.out), pid))
        self._flush(c)

    def _flush(self, c: _Client) -> None:
        if c.out:
            try:
                n = c.sock.send(c.out)
                del c.out[:n]
                c.written += n
                if c.ends and c.ends[0][0] <= c.written:
                    t = self._clock()
                    while c.ends and c.ends[0][0] <= c.written:
                        self.delivered(c.ends.popleft()[1], t)
            except BlockingIOError:
                pass
            except OSError:
                self._drop(c)
                return
        try:
            self._sel.modify(c.sock, selectors.EVENT_READ | (selectors.EVENT_WRITE if c.out else 0), c)
        except (KeyError, ValueError):
            pass

    def serve(self, seconds: float | None = None, out=None, label: str = "virtual Oculus") -> int:
        """Run in the foreground: print ``LABEL on tcp://HOST:PORT (status on udp://...)``, serve
        until ``seconds``, Ctrl-C or SIGTERM (`mitsonar.devices.transports.serve_in_foreground`),
        then print what was served."""
        from mitsonar.devices.transports import serve_in_foreground

        out = sys.stdout if out is None else out

        def banner():
            status = f" (status on udp://{self.host}:{self.udp_port})" if self.udp_port is not None else ""
            return f"{label} {self.model.name} on {self.port}{status}"

        serve_in_foreground(self, seconds, banner, out)
        print(f"{label}: {self.summary()}", file=out, flush=True)
        return 0

    def summary(self) -> str:
        """``N pings to M client(s), K message(s) refused, L pings skipped (late), B pings skipped
        (client behind)``: what the head served, and the ping slots it skipped (`_slot`): late ones
        when it could not make its pings at the rate asked, the others when a client read too
        slowly (what ``virtual-sonar`` and ``mitsonar live`` print at the end)."""
        st = self.stats
        return (f"{st['pings']} pings to {st['clients']} client(s), {st['refused']} message(s) refused, "
                f"{st['pings skipped (late)']} pings skipped (late), "
                f"{st['pings skipped (client behind)']} pings skipped (client behind)")


def serve(scan: Scan, seconds: float | None = None, *, out=None, **kwargs) -> int:
    """Run a `VirtualOculus` in the foreground (keyword arguments go to it)."""
    return VirtualOculus(scan, **kwargs).serve(seconds, out)


def scene_water(sensor) -> dict:
    """``{"temperature", "surface_z"}`` of a scene's ``sonar`` sensor (its ``water``, the XML's
    ``temperature`` and ``surface_z`` with ``auto`` water; the sensor's defaults otherwise), for
    `VirtualOculus`'s ``water``."""
    from mitsonar.plugins.water import WATER_DEFAULTS
    water = getattr(sensor, "water", None) or WATER_DEFAULTS
    return {"temperature": float(water["temperature"]), "surface_z": float(water["surface_z"])}
