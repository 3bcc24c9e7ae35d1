"""A live head (``mitsonar live``): each ping a client asks for is rendered at its own time, from
the vehicle's pose at that time, and answered in the head's protocol.

Pieces:

* `live_scene` (`mitsonar.sim.scene`, beside `load_scene`: the virtual Oculus renders scenes too): the scene file loaded with its scanning sonars reduced to one ping at bearing 0
  (``n_pings`` 1, ``bearing_start`` 0), so that a ping costs one row's paths (a multibeam keeps
  its fan: `mitsonar.live.framing` renders its whole frames); a sensor's ``to_world`` is the
  mount on the vehicle (x forward, y port, z up).
* `PingRenderer`: ``render(bearing)`` renders that one row with `mitsonar.render_scan` at the
  pose ``vehicle(t) @ mount @ bearing_rotation(bearing)`` (`mitsonar.geometry.frames`), the
  vehicle's pose coming from a pose source's ``at(t)`` (`mitsonar.live.poses.PoseBuffer` or
  `mitsonar.live.poses.TrajectoryReplay`); before any pose, the mount at the origin (said
  once). The pose enters the kernels as data, not as a literal: after the first ping, later
  pings launch the same compiled kernels (no recompilation; tests/test_live.py checks it).
  Ping ``k`` renders with seed ``seed + k``, so a session is reproducible given its poses (and,
  with a budget instead of a fixed ``spp``, the paths each ping took: its record says).
  A ping's paths fit its time budget and its record (paths, estimated error, latency from the
  pose time to its last byte written) goes to a `mitsonar.live.realtime.PingLog`.
* `LiveMicron`, `LivePing360`: the virtual heads (`mitsonar.devices.micron.virtual`,
  `mitsonar.devices.ping360.virtual`) with their ``row`` rendering the requested bearing anew
  instead of looking it up in a pre-rendered scan; everything else (protocol, timing model,
  range resampling) is theirs. `LiveOculus`: the virtual Oculus
  (`mitsonar.devices.oculus.virtual`) rendering each ping's whole frame when it fires.
* `PoseReceiver`: a thread reading pose datagrams (`mitsonar.live.poses.parse_datagram`) on a
  loopback UDP port into a `PoseBuffer`; a bad datagram is counted and dropped, never fatal.
"""
from __future__ import annotations

import math
import select
import socket
import sys
import threading
import time
from collections import Counter, deque

import numpy as np

from mitsonar.live.poses import BOUNDS_MARGIN, DatagramError, PoseBuffer, PoseSource, parse_datagram
from mitsonar.geometry.frames import bearing_rotation
from mitsonar.sim.scene import live_scene, scene_folder, scene_kinds

__all__ = ["live_scene", "scene_kinds", "pose_bounds", "SceneObjects", "PingRenderer", "LiveMicron", "LivePing360",
           "LiveOculus", "LIVE_HEADS", "PoseReceiver",
           "pose_socket"]

_SEED_MAX = 2**31 - 1
_CALIBRATION_SEED = 1 << 30     # the error model's renders: seeds far from the pings'


def pose_bounds(scene, margin: float = BOUNDS_MARGIN):
    """``(lo, hi)``: the box a vehicle's position must lie in (`mitsonar.live.poses.PoseBuffer`),
    the scene's bounding box enlarged by ``margin`` metres on every side; None for a scene
    without a finite bounding box (the buffer's default bound then holds)."""
    bbox = scene.bbox()
    lo, hi = np.array(bbox.min, np.float64), np.array(bbox.max, np.float64)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
        return None
    return lo - margin, hi + margin


class SceneObjects:
    """Moves shapes of a scene by XML id without reloading it: ``move(id, T)`` puts the shape at
    ``T @`` (its placement in the scene file), through ``mi.traverse`` (the shape's ``to_world``,
    or a mesh's ``vertex_positions``). ``lock``: held while changing the scene (the renders')."""

    def __init__(self, scene, lock=None):
        import mitsuba as mi

        self.params = mi.traverse(scene)
        self.lock = lock if lock is not None else threading.Lock()
        self._original: dict = {}
        for key in self.params.keys():
            name, _, field = key.rpartition(".")
            if field == "to_world" and name and not self._is_sensor(scene, name):
                self._original[name] = ("to_world", np.array(self.params[key].matrix, np.float64).reshape(4, 4))
            elif field == "vertex_positions" and name and name not in self._original:
                self._original[name] = ("vertex_positions", np.array(self.params[key], np.float64).reshape(-1, 3))

    @staticmethod
    def _is_sensor(scene, name) -> bool:
        return any(s.id() == name for s in scene.sensors())

    @property
    def names(self) -> list:
        return sorted(self._original)

    def move(self, name: str, matrix) -> None:
        import mitsuba as mi

        if name not in self._original:
            shown = ", ".join(self.names[:8]) + (" ..." if len(self.names) > 8 else "")
            raise KeyError(f"no movable shape {name!r} in the scene (shapes: {shown or 'none'})")
        field, original = self._original[name]
        m = np.asarray(matrix, np.float64)
        with self.lock:
            if field == "to_world":
                self.params[f"{name}.to_world"] = mi.Transform4f(mi.Matrix4f(m @ original))
            else:
                moved = original @ m[:3, :3].T + m[:3, 3]
                self.params[f"{name}.vertex_positions"] = mi.Float(moved.ravel().astype(np.float32))
            self.params.update()


class PingRenderer:
    """Renders one ping at a bearing (or a whole frame) from the pose source's pose at the ping's
    time (module doc), with as many paths as fit its time budget (`mitsonar.live.realtime`).

    ``spp``: paths of every ping (fixed); None: each ping takes the paths that fit its budget
    (`mitsonar.live.realtime.PathBudget`), ``budget`` seconds (default: the one each `render`
    is given, the head's ping period). ``log``: a `mitsonar.live.realtime.PingLog` the
    records of finished pings go to (`finish`). ``stats``: pings rendered; ``latencies``:
    seconds of the last 1000 renders; ``last_pose``: the 4x4 pose (beam frame) of the last ping;
    ``last_vehicle``: the vehicle's pose then; ``last_record``: the record of the last ping (paths,
    estimated error, render time, ...); these three are the calling thread's own last ping's
    (a frame loop and a head may render with one renderer at once);
    ``error``: the scene's `mitsonar.live.realtime.ErrorModel` (measured by `warm`, with
    ``calibration`` renders at each of its numbers of paths).
    """

    def __init__(self, scene, sonar, poses=None, *, spp: int | None = 64, seed: int = 0, out=None,
                 budget: float | None = None, log=None, calibration: int = 8, outputs=None):
        from mitsonar.live.realtime import ErrorModel, PathBudget, PingLog

        self.scene, self.sonar = scene, sonar
        #: `mitsonar.live.outputs.LiveOutputs` (or any ``publish(t_ns, vehicle, mount, scan)``)
        #: given each ping (or frame) after it is rendered: its time (ns, Unix epoch), the
        #: vehicle's pose, the mount and the scan; None: none.
        self.outputs = outputs
        self.mount = np.array(sonar.to_world_np, dtype=np.float64)
        self.poses = poses
        self.spp = None if spp is None else int(spp)
        self.seed = int(seed)
        self.budget = None if budget is None else float(budget)
        self.paths = PathBudget(self.budget if self.budget is not None else 1.0)
        self.error = ErrorModel()
        self.calibration = int(calibration)
        self.log = PingLog() if log is None else log
        self.out = sys.stderr if out is None else out
        self.stats: Counter = Counter()
        self.latencies: deque = deque(maxlen=1000)
        self._mine = threading.local()
        self._shared = (None, None, None)       # last_pose, last_vehicle, last_record of any thread
        self.lock = threading.Lock()
        self._said_no_pose = False

    def vehicle(self, now: float) -> np.ndarray:
        pose = None if self.poses is None else self.poses.at(now)
        if pose is None:
            if not self._said_no_pose:
                self._said_no_pose = True
                print("mitsonar live: no vehicle pose yet: pinging from the mount at the origin",
                      file=self.out, flush=True)
            return np.eye(4)
        return pose

    def warm(self):
        """Render one ping from the mount at the origin, uncounted: compiles the kernels before a
        client asks; then measures the scene's error at a few numbers of paths there
        (`mitsonar.live.realtime.ErrorModel.measure`, ``calibration`` renders each; 0: no
        error estimate) and the time per path. Returns the first render's `Scan` (bearing 0)."""
        from mitsonar.live.realtime import ErrorModel
        from mitsonar.sim.render import render_scan

        paths = self.spp if self.spp is not None else self.paths.next()
        times = []

        def one(n, i):
            t0 = time.monotonic()
            seed = (self.seed + _CALIBRATION_SEED + 7919 * n + i) % _SEED_MAX
            scan = render_scan(self.scene, spp=n, seed=seed, pose=self.mount, sensor=self.sonar)
            times.append((n, time.monotonic() - t0))
            return scan.intensity

        with self.lock:
            first = render_scan(self.scene, spp=paths, seed=self.seed, pose=self.mount, sensor=self.sonar)
            if self.calibration >= 2:
                self.error = ErrorModel.measure(one, self.calibration)
            else:
                one(paths, 0)
        # the largest renders: the time per path least blurred by fixed costs; their median, not
        # the slowest (max over (n, t) pairs took the slowest repeat: the first at a new pass size
        # records the frozen pass, so the first budgeted pings started with too few paths)
        n = max(k for k, _ in times)
        self.paths.per_path = float(np.median([t for k, t in times if k == n])) / n
        return first

    def render(self, bearing: float | None, now: float | None = None, budget: float | None = None, sonar=None):
        """A one-row `Scan` of the ping at ``bearing`` (radians, the simulator's convention) fired
        at ``now`` (``time.monotonic``, default now); its ``bearings`` is ``[bearing]``.
        ``bearing`` None: the sensor's whole frame (every row) at the vehicle's pose.
        ``budget``: seconds this ping may take (the head's ping period), used when the renderer has
        no ``budget`` of its own (``--budget-ms``, which wins); ignored with a fixed ``spp``.
        ``sonar``: another sensor object of the same mount to render with (a head's geometry of the
        moment, `LiveOculus`); default the renderer's."""
        from mitsonar.sim.render import render_scan

        t0 = time.monotonic()
        now = t0 if now is None else now
        wall = time.time() - (t0 - now)
        vehicle = self.vehicle(now)
        pose = vehicle @ self.mount
        if bearing is not None:
            pose = pose @ bearing_rotation(float(bearing))
        budget = self.budget if self.budget is not None else budget
        paths = self.spp if self.spp is not None else self.paths.next(budget)
        with self.lock:         # the ping's number (its seed) is taken and counted in one step
            k = self.stats["pings"]
            self.stats["pings"] += 1
            t1 = time.monotonic()
            scan = render_scan(self.scene, spp=paths, seed=(self.seed + k) % _SEED_MAX, pose=pose,
                               sensor=self.sonar if sonar is None else sonar)
            spent = time.monotonic() - t1
            if self.spp is None:
                self.paths.measured(paths, spent)
            if bearing is not None:
                scan.bearings = np.array([float(bearing)])
            record = {"ping": k, "t": wall, "pose_time": now,
                      "bearing": None if bearing is None else float(bearing), "paths": int(paths),
                      "error": self.error(paths), "render_ms": spent * 1e3,
                      "budget_ms": None if budget is None else budget * 1e3}
            self._shared = self._mine.last = (pose, vehicle, record)
            self.latencies.append(time.monotonic() - t0)
            if self.outputs is not None:    # queued, in ping order: the outputs' thread sends it (LiveOutputs)
                self.outputs.publish(round(wall * 1e9), vehicle, self.mount, scan)
        return scan

    # What the calling thread rendered last (a frame loop and a head may share the renderer):
    # the pose, vehicle and record of its own last ping; another thread's if it rendered none.
    last_pose = property(lambda self: self._last(0))
    last_vehicle = property(lambda self: self._last(1))
    last_record = property(lambda self: self._last(2))

    def _last(self, i: int):
        mine = getattr(self._mine, "last", None)
        return (mine if mine is not None else self._shared)[i]

    def finish(self, record: dict, written: float | None = None) -> None:
        """``record``'s ping is out (its last byte written, or its frame published) at
        ``written`` (``time.monotonic``, default now): its latency from the pose time, logged."""
        written = time.monotonic() if written is None else written
        record["latency_ms"] = (written - record["pose_time"]) * 1e3
        self.log.add(record)

    def summary(self) -> str:
        n = self.stats["pings"]
        if not self.latencies:
            line = f"{n} pings rendered"
        else:
            lat = np.array(self.latencies) * 1e3
            line = (f"{n} pings rendered; render ms p50 {np.percentile(lat, 50):.1f}, "
                    f"p95 {np.percentile(lat, 95):.1f}, max {lat.max():.1f}")
        more = self.log.summary()
        return line + (f"; {more}" if more else "")


def _clocked(head) -> None:
    """Wrap ``head``'s port so that each write tells its `WireClock` (``head.clock``)."""
    transport = head._transport
    write = transport.write

    def clocked_write(data):
        n = write(data)
        head.clock.wrote(n or 0, time.monotonic())
        return n

    transport.write = clocked_write


def _micron():
    from mitsonar.devices.micron.seanet import bearing_to_radians
    from mitsonar.devices.micron.virtual import VirtualMicron
    from mitsonar.live.realtime import WireClock

    class LiveMicron(VirtualMicron):
        """A `VirtualMicron` whose scanline at wire bearing ``b`` is rendered when it fires: when
        the driver's mtSendData starts the ping (from the pose at that time, with the ping's time
        as budget: the request, the listening ``2R/c`` and the motor step), sent when the head's
        timing model says (or when rendered, if later)."""

        def __init__(self, renderer: PingRenderer, port_url=None, **kwargs):
            self.renderer = renderer
            self.clock = WireClock()
            self._pending = None            # (bearing, scan, record) rendered at the request
            self._record = None             # the record of the scanline being sent
            super().__init__(renderer.warm(), port_url, **kwargs)

        def _power_on(self) -> None:
            super()._power_on()
            _clocked(self)

        def _boot(self, now: float) -> None:
            super()._boot(now)
            self.clock.resync()

        def ping_period(self) -> float:
            """Seconds of one scanline: the request's transfer, the listening, the motor step."""
            s = self.settings
            return 18 * 10.0 / self.baudrate + s.n_bins * s.sampling_interval + self.motor_time

        def _request(self, now: float) -> None:
            fires = self.command is not None and not self._busy
            super()._request(now)
            if fires:
                b = self.bearing
                scan = self.renderer.render(bearing_to_radians(b, self.settings.invert), now, self.ping_period())
                self._pending = (b, scan, self.renderer.last_record)

        def _ping(self, now: float) -> None:
            super()._ping(now)
            self._record = None

        def _emit(self, now: float, data: bytes) -> None:
            stalled = now < self._stalled_until
            super()._emit(now, data)
            if not stalled:
                record, self._record = self._record, None
                done = None if record is None else (lambda t, r=record: self.renderer.finish(r, t))
                self.clock.queue(len(data), done)

        def row(self, bearing: int) -> np.ndarray:
            pending, self._pending = self._pending, None
            if pending is not None and pending[0] == bearing:
                _, self.scan, self._record = pending
            else:       # not rendered at its request (new parameters since): now
                self.scan = self.renderer.render(bearing_to_radians(bearing, self.settings.invert), None,
                                                 self.ping_period())
                self._record = self.renderer.last_record
            self._prepare_rows()
            return super().row(bearing)

    return LiveMicron


def _ping360():
    from mitsonar.devices.ping360.head import TICK, angle_to_radians
    from mitsonar.devices.ping360.protocol import ids
    from mitsonar.devices.ping360.virtual import VirtualPing360
    from mitsonar.live.realtime import WireClock

    class LivePing360(VirtualPing360):
        """A `VirtualPing360` whose samples at ``angle`` are rendered when it pings, with the
        ping's time as budget (the listening ``number_of_samples * sample_period * 25 ns``, the
        transmit pulse, the motor's step).

        Stale requests are coalesced: of the ping requests (``transducer`` with ``transmit``)
        waiting on the line together (a client that timed out and asked again while a ping
        rendered), only the newest is answered; the others are counted
        (``stats["stale requests skipped"]``), never answered late, where a client would take an
        old angle's reply for the new request's.
        """

        def _tick(self) -> None:
            msgs = []
            for _ in range(64):
                data = self._transport.read(0.0)
                if not data:
                    break
                msgs += self.parser.feed(data)
            pings = [i for i, m in enumerate(msgs) if m.message_id == ids["transducer"] and m.transmit]
            for i, m in enumerate(msgs):
                if pings and i in pings and i != pings[-1]:
                    self.stats["stale requests skipped"] += 1
                    continue
                self._on_message(m, time.monotonic())
            super()._tick()

        def __init__(self, renderer: PingRenderer, port_url=None, **kwargs):
            self.renderer = renderer
            self.clock = WireClock()
            self._record = None
            super().__init__(renderer.warm(), port_url, **kwargs)

        def _power_on(self) -> None:
            super()._power_on()
            _clocked(self)

        def _reset(self) -> None:
            super()._reset()
            if hasattr(self, "clock"):
                self.clock.resync()

        def _send(self, msg, now: float, busy: float = 0.0, ping: int | None = None) -> None:
            super()._send(msg, now, busy, ping)
            record, self._record = (self._record, None) if ping is not None else (None, self._record)
            done = None if record is None else (lambda t, r=record: self.renderer.finish(r, t))
            self.clock.queue(len(self._queue[-1][1]), done)

        def row(self, angle: int, sample_period: int, n: int, step: int = 1) -> bytes:
            rad = angle_to_radians(angle)
            period = n * sample_period * TICK + self.state["transmit_duration"] * 1e-6 + step * self.motor_time
            self.scan = self.renderer.render(rad, None, period)
            self._record = self.renderer.last_record
            self._b = np.array([rad % (2 * math.pi)])
            self._scan_step = 0.0
            return super().row(angle, sample_period, n, step)

    return LivePing360


def _oculus():
    from mitsonar.devices.oculus.virtual import VirtualOculus, parse_tcp_url

    class LiveOculus(VirtualOculus):
        """A `mitsonar.devices.oculus.virtual.VirtualOculus` whose every ping is a whole frame
        rendered when it fires, from the vehicle's pose then, with the stream's ping period as
        budget; protocol, bearing table, range lines and levels are the virtual head's.
        ``port_url`` is ``tcp://HOST:PORT`` (default 127.0.0.1:52100); the status goes to UDP
        ``status_port`` (52102) of HOST.

        Each ping renders the fire message's geometry (the mode's aperture, frequency and beam
        widths, 256 or 512 beams at the head's bearing table, the range asked): ``geometry(mode,
        n_beams, range)`` gives the sensor of that geometry (`mitsonar.devices.oculus.scenes.
        SceneFrames.sensor_at`, what ``mitsonar live --head oculus`` passes), which renders the
        scene as loaded (so moved shapes stay moved); without ``geometry``, the scene sensor's own
        fan and range. A ping's record (``--records``) is logged when its last byte is written
        (`delivered`): its latency runs from the ping's time to then."""

        def __init__(self, renderer: PingRenderer, port_url=None, *, baudrate=None, realtime: bool = True,
                     status_port: int | None = None, model: str | None = None, geometry=None):
            from mitsonar.devices.oculus.protocol import UDP_PORT
            self.renderer = renderer
            host, port = parse_tcp_url(port_url)
            from mitsonar.devices.oculus.virtual import scene_water
            self.geometry = geometry
            self._records = {}              # ping id -> its record, until its last byte is written
            super().__init__(renderer.warm(), model=model or "M1200d", host=host, tcp_port=port,
                             udp_port=UDP_PORT if status_port is None else status_port, realtime=realtime,
                             water=scene_water(renderer.sonar))

        def ping(self, fire, ping_id: int = 0, now: float = 0.0):
            period = self.period(fire)
            sonar = None
            if self.geometry is not None:
                sonar = self.geometry(*self.geometry_of(fire))
            self.scans = [self.renderer.render(None, None, period if 0 < period < math.inf else None, sonar)]
            self.scan = self.scans[0]
            self._fans.clear()
            self._cache.clear()
            record = self.renderer.last_record
            result = super().ping(fire, ping_id, now)
            self._records[ping_id] = record          # logged when its last byte is written (delivered)
            return result

        def delivered(self, ping_id: int, t) -> None:
            record = self._records.pop(ping_id, None)
            if record is not None and t is not None:
                self.renderer.finish(record, t)

    return LiveOculus


#: head name -> function returning its live class ``cls(renderer, port_url, **virtual kwargs)``
LIVE_HEADS = {"micron": _micron, "ping360": _ping360, "oculus": _oculus}


def LiveMicron(*args, **kwargs):  # noqa: N802 - a class made on first use (imports the codec)
    return _micron()(*args, **kwargs)


def LivePing360(*args, **kwargs):  # noqa: N802
    return _ping360()(*args, **kwargs)


def LiveOculus(*args, **kwargs):  # noqa: N802
    return _oculus()(*args, **kwargs)


def pose_socket(url: str) -> socket.socket:
    """A non-blocking UDP socket bound to ``udp://127.0.0.1:PORT`` (``udp://localhost:PORT``;
    port 0 picks one); ValueError naming the URL for anything else: poses come from this machine."""
    from urllib.parse import urlparse

    u = urlparse(url)
    try:
        port = u.port
    except ValueError:
        port = None
    if u.scheme != "udp" or port is None or u.hostname not in ("127.0.0.1", "localhost"):
        raise ValueError(f"--pose-url {url!r}: expected udp://127.0.0.1:PORT (poses are read on the loopback only)")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(("127.0.0.1", port))
    except OSError as e:
        sock.close()
        raise ValueError(f"--pose-url {url}: cannot bind ({e.strerror or e})") from None
    sock.setblocking(False)
    return sock


class PoseReceiver(PoseSource):
    """Reads pose datagrams on ``sock`` into ``buffer`` in a thread until `stop` (module doc).

    ``stats``: ``poses`` applied, ``objects`` moved, ``dropped`` in all; ``drops.counts`` by reason.
    ``objects``: callable ``(id, 4x4)`` moving a scene shape (None: object datagrams are dropped).
    """

    def __init__(self, sock, buffer: PoseBuffer, *, objects=None, out=None, stale_after: float = 2.0):
        self.sock, self.objects = sock, objects
        self.stale_after = float(stale_after)
        self._stale_said = False
        super().__init__("PoseReceiver", buffer, out)

    @property
    def url(self) -> str:
        return f"udp://127.0.0.1:{self.sock.getsockname()[1]}"

    def _close(self) -> None:
        self.sock.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([self.sock], [], [], 0.1)
                if r:
                    self._read()
                self._check_stale()
            except Exception as e:          # noqa: BLE001 - never let the receiver die
                self.stats["internal errors"] += 1
                print(f"mitsonar live: warning: pose receiver: {e}", file=self.out, flush=True)
                time.sleep(0.05)

    def _read(self) -> None:
        for _ in range(256):
            try:
                data, _ = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue
            self.handle(data, time.monotonic())

    def handle(self, data: bytes, arrival: float) -> bool:
        """Apply one datagram that arrived at ``arrival``; False (counted, logged) if dropped."""
        try:
            d = parse_datagram(data)
            if d["object"] is not None:
                if self.objects is None:
                    raise DatagramError("unknown field", "'object' datagrams are not supported here")
                from mitsonar.live.poses import check_pose, pose_matrix
                check_pose(d["position"], d["orientation"])     # an offset: held to MAX_COORDINATE
                try:
                    self.objects(d["object"], pose_matrix(d["position"], d["orientation"]))
                except (KeyError, ValueError) as e:
                    raise DatagramError("unknown object", str(e)) from None
                self.stats["objects"] += 1
                return True
        except DatagramError as e:
            self.drop(e, arrival)
            return False
        if not self.add(d["position"], d["orientation"], d["t"], arrival):
            return False
        self._stale_said = False
        return True

    def _check_stale(self) -> None:
        last = self.buffer.last_arrival
        if last is not None and not self._stale_said and time.monotonic() - last > self.stale_after:
            self._stale_said = True
            print(f"mitsonar live: warning: no pose for {self.stale_after:g} s: holding the last one",
                  file=self.out, flush=True)
