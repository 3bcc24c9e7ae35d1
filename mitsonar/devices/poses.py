"""Vehicle poses for a live head (`mitsonar.devices.live`): datagrams in, the pose at a ping's time out.

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

Clocks (`PoseBuffer`): a datagram sent at ``t`` on the sender's clock arrives at
``a = t + offset + delay`` on ours (``time.monotonic``), ``delay >= 0``. The offset is estimated
as the smallest ``a - t`` of the last `PoseBuffer.window` datagrams (the least delayed one), so a
ping fired at our time ``T`` uses the pose at ``T - offset`` on the sender's clock: interpolated
between the two poses that bracket it (position linearly, orientation by slerp, as
`Trajectory.at`), else the newest pose (held when the stream stops, or when in doubt).
"""
from __future__ import annotations

import bisect
import json
import math
import threading
import time
from collections import Counter, deque

import numpy as np

from mitsonar.geometry.trajectory import matrix_to_quat, quat_to_matrix, slerp

__all__ = ["MAX_DATAGRAM", "UNIT_TOLERANCE", "REASONS", "DatagramError", "parse_datagram", "pose_matrix",
           "PoseBuffer", "TrajectoryReplay"]

#: the largest datagram taken, bytes (a pose is under 200)
MAX_DATAGRAM = 4096
#: how far ``|q|`` may be from 1 (then it is normalised)
UNIT_TOLERANCE = 1e-3
#: why a datagram was dropped (`DatagramError.reason`)
REASONS = ("too large", "not JSON", "not an object", "unknown field", "missing field", "wrong type",
           "not finite", "bad quaternion", "unknown object")
_FIELDS = {"t", "position", "orientation", "object"}


class DatagramError(ValueError):
    """A dropped datagram: ``reason`` (one of `REASONS`) and a sentence naming the field."""

    def __init__(self, reason: str, text: str):
        super().__init__(text)
        self.reason = reason


def _numbers(value, n: int, field: str) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == n
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise DatagramError("wrong type", f"'{field}' must be a list of {n} numbers")
    a = np.array(value, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise DatagramError("not finite", f"'{field}' holds a number that is not finite")
    return a


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
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise DatagramError("bad quaternion", f"'orientation' has norm {norm:.6g}, not 1 within {UNIT_TOLERANCE:g}")
    t = obj.get("t")
    if t is not None:
        if not isinstance(t, (int, float)) or isinstance(t, bool):
            raise DatagramError("wrong type", "'t' must be a number of seconds")
        t = float(t)
        if not math.isfinite(t):
            raise DatagramError("not finite", "'t' is not finite")
    name = obj.get("object")
    if name is not None and not (isinstance(name, str) and 0 < len(name) <= 256):
        raise DatagramError("wrong type", "'object' must be a shape's id (a string)")
    return {"t": t, "position": position, "orientation": q / norm, "object": name}


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

    `add` is called by the receiving thread, `at` by the head's: both under one lock.
    """

    def __init__(self, size: int = 512, window: int = 256):
        self.size = int(size)
        self.window = int(window)
        self._t: list = []          # sender times, increasing
        self._p: list = []          # (position (3,), quaternion (4,))
        self._lags: deque = deque(maxlen=self.window)
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
        (our clock, default now)."""
        arrival = time.monotonic() if arrival is None else float(arrival)
        with self._lock:
            if t is None:
                t = arrival - self.offset
            else:
                self._lags.append(arrival - float(t))
            t = float(t)
            sample = (np.asarray(position, np.float64), np.asarray(orientation, np.float64))
            k = bisect.bisect_left(self._t, t)
            if k < len(self._t) and self._t[k] == t:
                self._p[k] = sample
            else:
                self._t.insert(k, t)
                self._p.insert(k, sample)
            if len(self._t) > self.size:
                del self._t[0], self._p[0]
            self.last_arrival = arrival

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
    ``self._stop`` at least every 0.1 s) and release their input in ``_close``."""

    def __init__(self, name: str):
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

    def _run(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        pass


class DropLog:
    """Counts dropped datagrams by reason and prints at most one line per ``every`` seconds
    (the first of a burst at once, then how many more since)."""

    def __init__(self, out, every: float = 2.0):
        self.out = out
        self.every = float(every)
        self.counts: Counter = Counter()
        self._last = -math.inf
        self._since = 0

    def drop(self, err: DatagramError, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        self.counts[err.reason] += 1
        self._since += 1
        if now - self._last >= self.every:
            more = f" ({self._since - 1} more dropped since the last report)" if self._since > 1 else ""
            print(f"mitsonar live: warning: dropped a pose datagram: {err}{more}", file=self.out, flush=True)
            self._last, self._since = now, 0


def quat_of(matrix) -> np.ndarray:
    """Unit quaternion ``x, y, z, w`` of a 4x4 transform's rotation."""
    return matrix_to_quat(np.asarray(matrix, np.float64)[:3, :3])
