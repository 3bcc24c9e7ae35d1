"""Vehicle poses for a live head (`mitsonar.live.heads`): datagrams in, the pose at a ping's time out.

Datagrams (UDP, one JSON object each, at most `MAX_DATAGRAM` bytes, UTF-8)::

    {"t": 12.5, "position": [x, y, z], "orientation": [qx, qy, qz, qw]}
    {"object": "buoy", "position": [x, y, z], "orientation": [qx, qy, qz, qw]}

The first is the vehicle's pose in the world (x forward, y port, z up, as a
`mitsonar.geometry.trajectory.Trajectory` sample: the sensor's ``to_world`` is the mount in that
frame); ``t`` (seconds) is optional, on any clock consistent across datagrams, the arrival time
when absent. The second moves the scene shape with XML id ``object``: the transform is applied to
the shape as the scene file placed it. ``orientation`` is a Hamilton quaternion, scalar last;
one whose norm differs from 1 by more than `UNIT_TOLERANCE` is refused, others are normalised.
Every number must be finite; no other field is allowed. `parse_datagram` checks all of that and
raises `DatagramError` (its ``reason`` one of `REASONS`) for anything else: network input is
untrusted.

Every pose, whatever its source (these datagrams, MAVLink), is checked once more where it enters
the session, by `PoseBuffer.add` (`check_pose`): finite numbers, a unit quaternion, a position
within the buffer's ``bounds`` (``mitsonar live``: the scene's bounding box enlarged by
`BOUNDS_MARGIN` on every side; without a scene, ``|x|, |y|, |z| <= MAX_COORDINATE``), and a time
consistent with the sender's clock as estimated (below). A refused pose raises `DatagramError`
and changes nothing: no pose stored, the clock offset unmoved; the pose sources count it as
dropped, by reason (`PoseSource`). An ``object`` datagram's translation is an offset from the
shape's place in the scene file: it is held to ``MAX_COORDINATE``.

Clocks (`PoseBuffer`): a datagram sent at ``t`` on the sender's clock arrives at
``a = t + offset + delay`` on ours (``time.monotonic``), ``delay >= 0``. The offset is estimated
as the smallest ``a - t`` of the last `PoseBuffer.window` datagrams (the least delayed one), so a
ping fired at our time ``T`` uses the pose at ``T - offset`` on the sender's clock: interpolated
between the two poses that bracket it (position linearly, orientation by slerp, as
`Trajectory.at`), else the newest pose (held when the stream stops, or when in doubt).

A stamped pose whose ``a - t`` differs from the offset by more than `CLOCK_WINDOW` seconds (sent
more than that before, or at all after, the time its arrival implies: a wild or stale stamp) is
refused ("implausible time"), never moving the offset: one bad stamp cannot hide the good poses
that follow. If `CLOCK_RESYNC` stamped poses in a row are refused so and agree with each other
within `CLOCK_WINDOW`, the sender's clock has jumped (a restarted autopilot's boot time): the
buffer forgets its poses and its offset and starts over from the last of them
(`PoseBuffer.resyncs` counts these).
"""
from __future__ import annotations

import bisect
import json
import math
import sys
import threading
import time
from collections import Counter, deque

import numpy as np

from mitsonar.geometry.trajectory import matrix_to_quat, quat_to_matrix, slerp

__all__ = ["MAX_DATAGRAM", "UNIT_TOLERANCE", "REASONS", "MAX_COORDINATE", "BOUNDS_MARGIN", "CLOCK_WINDOW",
           "CLOCK_RESYNC", "DatagramError", "parse_datagram", "check_pose", "pose_matrix", "PoseBuffer",
           "TrajectoryReplay"]

#: the largest datagram taken, bytes (a pose is under 200)
MAX_DATAGRAM = 4096
#: how far ``|q|`` may be from 1 (then it is normalised)
UNIT_TOLERANCE = 1e-3
#: why a datagram was dropped (`DatagramError.reason`)
REASONS = ("too large", "not JSON", "not an object", "unknown field", "missing field", "wrong type",
           "not finite", "bad quaternion", "unknown object", "out of bounds", "implausible time")
#: metres: the largest coordinate of a position without other bounds (and of an object's offset)
MAX_COORDINATE = 1e5
#: metres the scene's bounding box is enlarged by on every side to bound the vehicle's positions
BOUNDS_MARGIN = 1000.0
#: seconds a stamped pose's ``arrival - t`` may differ from the clock offset (module doc)
CLOCK_WINDOW = 5.0
#: refused stamped poses in a row, consistent with each other, that restart the clock (module doc)
CLOCK_RESYNC = 5
_FIELDS = {"t", "position", "orientation", "object"}


class DatagramError(ValueError):
    """A dropped datagram or refused pose: ``reason`` (one of `REASONS`) and a sentence naming the
    field."""

    def __init__(self, reason: str, text: str):
        super().__init__(text)
        self.reason = reason


def _numbers(value, n: int, field: str) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == n
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise DatagramError("wrong type", f"'{field}' must be a list of {n} numbers")
    return np.array(value, dtype=np.float64)


def _finite(value, n: int, field: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (n,):
        raise DatagramError("wrong type", f"'{field}' must be {n} numbers")
    if not np.all(np.isfinite(a)):
        raise DatagramError("not finite", f"'{field}' holds a number that is not finite")
    return a


def check_pose(position, orientation, t=None, *, bounds=((-MAX_COORDINATE,) * 3, (MAX_COORDINATE,) * 3),
               names=("position", "orientation", "t")) -> tuple:
    """``(position (3,), unit quaternion (4,), t)`` of a pose, every field checked: finite numbers,
    ``orientation`` (``x, y, z, w``) of norm 1 within `UNIT_TOLERANCE` (then normalised),
    ``position`` within ``bounds`` (``(lo, hi)``, two 3-vectors; None: any finite position), ``t``
    None or a finite number. `DatagramError` naming the field (``names``: how the source calls
    them) for anything else."""
    p = _finite(position, 3, names[0])
    q = _finite(orientation, 4, names[1])
    norm = math.hypot(*q.tolist())      # no square overflows (1e200), unlike numpy's dot
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise DatagramError("bad quaternion", f"'{names[1]}' has norm {norm:.6g}, not 1 within {UNIT_TOLERANCE:g}")
    if t is not None:
        t = float(t)
        if not math.isfinite(t):
            raise DatagramError("not finite", f"'{names[2]}' is not finite")
    if bounds is not None:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
        if not (np.all(p >= lo) and np.all(p <= hi)):
            box = " x ".join(f"[{a:.6g}, {b:.6g}]" for a, b in zip(lo, hi))
            raise DatagramError("out of bounds", f"'{names[0]}' {_vector(p)} m is outside {box} m")
    return p, q / norm, t


def _vector(v) -> str:
    return "[" + ", ".join(f"{x:.6g}" for x in v) + "]"


def parse_datagram(data: bytes) -> dict:
    """One checked datagram: ``{"t": float | None, "position": (3,), "orientation": (4,) unit,
    "object": str | None}``; `DatagramError` for anything else (see the module's doc)."""
    if len(data) > MAX_DATAGRAM:
        raise DatagramError("too large", f"{len(data)} bytes (at most {MAX_DATAGRAM})")
    try:
        obj = json.loads(data.decode("utf-8"), parse_constant=_no_constant)
    except DatagramError:
        raise
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise DatagramError("not JSON", "not a UTF-8 JSON text") from None
    if not isinstance(obj, dict):
        raise DatagramError("not an object", f"a JSON {type(obj).__name__}, not an object")
    extra = sorted(set(obj) - _FIELDS)
    if extra:
        raise DatagramError("unknown field", f"unknown field {extra[0]!r} (allowed: t, position, "
                                             f"orientation, object)")
    for field in ("position", "orientation"):
        if field not in obj:
            raise DatagramError("missing field", f"no '{field}'")
    position = _numbers(obj["position"], 3, "position")
    q = _numbers(obj["orientation"], 4, "orientation")
    t = obj.get("t")
    if t is not None and (not isinstance(t, (int, float)) or isinstance(t, bool)):
        raise DatagramError("wrong type", "'t' must be a number of seconds")
    name = obj.get("object")
    if name is not None and not (isinstance(name, str) and 0 < len(name) <= 256):
        raise DatagramError("wrong type", "'object' must be a shape's id (a string)")
    # the numbers' checks (the bounds are the buffer's: `PoseBuffer.add`)
    position, q, t = check_pose(position, q, t, bounds=None)
    return {"t": t, "position": position, "orientation": q, "object": name}


def _no_constant(name):
    # json takes NaN, Infinity and -Infinity by default; they are no numbers of a pose
    raise DatagramError("not finite", f"{name} is not a finite number")


def pose_matrix(position, orientation) -> np.ndarray:
    """4x4 rigid transform of a position and a unit quaternion ``x, y, z, w``."""
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix(orientation)
    m[:3, 3] = position
    return m


class PoseBuffer:
    """The vehicle's recent poses, by the sender's time, and the clock offset (module doc).

    ``bounds``: ``(lo, hi)`` (two 3-vectors, metres) a position must lie in (default
    ``+-MAX_COORDINATE``); ``clock_window``, ``resync``: `CLOCK_WINDOW`, `CLOCK_RESYNC`.
    `add` is called by the receiving thread, `at` by the head's: both under one lock.
    """

    def __init__(self, size: int = 512, window: int = 256, *, bounds=None, clock_window: float = CLOCK_WINDOW,
                 resync: int = CLOCK_RESYNC):
        self.size = int(size)
        self.window = int(window)
        self.bounds = ((-MAX_COORDINATE,) * 3, (MAX_COORDINATE,) * 3) if bounds is None else \
            tuple(tuple(float(v) for v in b) for b in bounds)
        self.clock_window = float(clock_window)
        self.resync = int(resync)
        self.resyncs = 0            # times the sender's clock jumped and the buffer started over
        self._t: list = []          # sender times, increasing
        self._p: list = []          # (position (3,), quaternion (4,))
        self._lags: deque = deque(maxlen=self.window)
        self._doubted: list = []    # the lags of the stamped poses refused in a row (consistent ones)
        self._lock = threading.Lock()
        self.last_arrival: float | None = None

    def __len__(self) -> int:
        return len(self._t)

    @property
    def offset(self) -> float:
        """Our clock minus the sender's (the least ``arrival - t`` seen lately), 0 before any."""
        return min(self._lags) if self._lags else 0.0

    def add(self, position, orientation, t: float | None = None, arrival: float | None = None) -> None:
        """A pose sent at ``t`` (sender's clock; None: its arrival) that arrived at ``arrival``
        (our clock, default now); `DatagramError` if refused (`check_pose`, the clock's window:
        module doc), and then nothing changes."""
        position, orientation, t = check_pose(position, orientation, t, bounds=self.bounds)
        arrival = time.monotonic() if arrival is None else float(arrival)
        with self._lock:
            if t is None:
                t = arrival - self.offset
            else:
                self._check_time(t, arrival)
                self._lags.append(arrival - t)
            sample = (position, orientation)
            k = bisect.bisect_left(self._t, t)
            if k < len(self._t) and self._t[k] == t:
                self._p[k] = sample
            else:
                self._t.insert(k, t)
                self._p.insert(k, sample)
            if len(self._t) > self.size:
                del self._t[0], self._p[0]
            self.last_arrival = arrival

    def _check_time(self, t: float, arrival: float) -> None:
        """Refuse a stamp ``t`` off the estimated clock, or restart the clock (module doc); under the lock."""
        lag = arrival - t
        if not self._lags or abs(lag - self.offset) <= self.clock_window:
            self._doubted = []
            return
        if all(abs(lag - d) <= self.clock_window for d in self._doubted):
            self._doubted.append(lag)
        else:
            self._doubted = [lag]
        if len(self._doubted) >= self.resync:      # the sender's clock jumped: start over from this pose
            self._t.clear(), self._p.clear(), self._lags.clear()
            self._doubted = []
            self.resyncs += 1
            return
        expected = arrival - self.offset
        raise DatagramError("implausible time", f"'t' {t:.9g} s is {t - expected:+.3g} s off the sender's clock "
                                                f"as estimated ({expected:.9g} s at its arrival; allowed: within "
                                                f"{self.clock_window:g} s)")

    def at(self, now: float | None = None) -> np.ndarray | None:
        """4x4 vehicle pose at our time ``now`` (default now), None before any pose."""
        now = time.monotonic() if now is None else float(now)
        with self._lock:
            if not self._t:
                return None
            ts = now - self.offset
            k = bisect.bisect_right(self._t, ts)
            if k == 0 or k == len(self._t):
                p, q = self._p[-1]                # outside the poses received: the newest
                return pose_matrix(p, q)
            t0, t1 = self._t[k - 1], self._t[k]
            (p0, q0), (p1, q1) = self._p[k - 1], self._p[k]
        f = (ts - t0) / (t1 - t0)
        q = q0 if np.array_equal(q0, q1) else slerp(q0, q1, f)
        return pose_matrix(p0 + f * (p1 - p0), q)


class TrajectoryReplay:
    """A `Trajectory` replayed in real time from ``start`` (our clock): the pose at
    ``start_time + (now - start)``, its last pose held after its end (``ended`` says so)."""

    def __init__(self, trajectory, start: float | None = None):
        self.trajectory = trajectory
        self.t0, self.t1 = trajectory.span
        self.start = time.monotonic() if start is None else float(start)
        self.ended = False

    def at(self, now: float | None = None) -> np.ndarray:
        now = time.monotonic() if now is None else float(now)
        t = self.t0 + (now - self.start)
        if t >= self.t1:
            self.ended = True
        return self.trajectory.at(min(max(t, self.t0), self.t1))


class PoseSource:
    """A thread feeding a `PoseBuffer` until `stop`: subclasses read in ``_run`` (checking
    ``self._stop`` at least every 0.1 s) and release their input in ``_close``; each pose goes
    through `add` (or a refusal of their own through `drop`), which counts it: ``stats["poses"]``
    applied, ``stats["dropped"]`` refused, ``drops.counts`` by reason."""

    #: what the source's inputs are, in its warnings ("dropped a pose datagram: ...")
    what = "a pose datagram"

    def __init__(self, name: str, buffer=None, out=None):
        self.buffer = buffer
        self.out = sys.stderr if out is None else out
        self.drops = DropLog(self.out, what=self.what)
        self.stats: Counter = Counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self):
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        self._close()

    def add(self, position, orientation, t, arrival: float) -> bool:
        """Give a pose to the buffer (which checks it: `PoseBuffer.add`); False (counted, logged)
        if refused. Says once when the sender's clock jumped (the buffer started over)."""
        resyncs = self.buffer.resyncs
        try:
            self.buffer.add(position, orientation, t, arrival)
        except DatagramError as e:
            self.drop(e, arrival)
            return False
        if self.buffer.resyncs != resyncs:
            print(f"mitsonar live: warning: the sender's clock jumped ({self.buffer.resync} poses in a row off it, "
                  "consistent with each other): poses start over from the newest", file=self.out, flush=True)
        self.stats["poses"] += 1
        return True

    def drop(self, err: DatagramError, arrival: float | None = None) -> None:
        """Count and log an input refused with ``err``."""
        self.stats["dropped"] += 1
        self.drops.drop(err, arrival)

    def _run(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        pass


class DropLog:
    """Counts dropped datagrams by reason and prints at most one line per ``every`` seconds
    (the first of a burst at once, then how many more since)."""

    def __init__(self, out, every: float = 2.0, what: str = "a pose datagram"):
        self.out = out
        self.every = float(every)
        self.what = what
        self.counts: Counter = Counter()
        self._last = -math.inf
        self._since = 0

    def drop(self, err: DatagramError, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        self.counts[err.reason] += 1
        self._since += 1
        if now - self._last >= self.every:
            more = f" ({self._since - 1} more dropped since the last report)" if self._since > 1 else ""
            print(f"mitsonar live: warning: dropped {self.what}: {err}{more}", file=self.out, flush=True)
            self._last, self._since = now, 0


def quat_of(matrix) -> np.ndarray:
    """Unit quaternion ``x, y, z, w`` of a 4x4 transform's rotation."""
    return matrix_to_quat(np.asarray(matrix, np.float64)[:3, :3])
