"""`Trajectory`: timestamped vehicle poses in the world, interpolated at any ping's time.

A trajectory is ``N`` samples ``(t_i, T_i)``: times in seconds, strictly increasing, and rigid
4x4 transforms from the vehicle frame to the world (column vectors). The vehicle frame follows
ROS REP-103: x forward, y port (left), z up. A sonar mounted on the vehicle has its ``to_world``
(the mount) in that frame, so the world pose of a ping fired at time ``t`` is
``trajectory.at(t) @ mount @ (the ping's own rotation)``.

Interpolation between samples ``i`` and ``i + 1`` at ``f = (t - t_i) / (t_{i+1} - t_i)``:
position ``p_i + f (p_{i+1} - p_i)``; rotation the spherical linear interpolation of the unit
quaternions, ``slerp(q_i, q_{i+1}, f) = (sin((1-f) w) q_i + sin(f w) q_{i+1}) / sin(w)`` with
``cos w = |q_i . q_{i+1}|`` (the shorter arc). A time at a sample returns that sample's pose
exactly, and where two neighbouring samples share a rotation or a position it is kept exactly.
Outside ``[t_0, t_{N-1}]`` there is no pose: `at` raises `TrajectoryError`, it does not clamp.

Files: the TUM format (Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems",
IROS 2012; read and written by ``evo``), one sample per line, ``timestamp tx ty tz qx qy qz qw``
(Hamilton quaternion, scalar last), ``#`` comments. Generators: `straight`, `turn`, `lawnmower`,
and `with_drift` (a seeded random walk of position and heading, like dead-reckoning drift).
"""
from __future__ import annotations

import math
import os

import numpy as np

from mitsonar._files import replacing
from mitsonar.geometry.frames import check_rigid, check_rigid_stack

TUM_FIELDS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
UNIT_TOLERANCE = 1e-3   # |q| of a TUM line may differ from 1 by this much (then it is normalised)


class TrajectoryError(ValueError):
    """A trajectory, a trajectory file or a time that is not allowed; the message says which."""


# ---------------------------------------------------------------------------- quaternions
def quat_to_matrix(q) -> np.ndarray:
    """(..., 3, 3) rotation of unit quaternions (..., 4) ordered ``x, y, z, w`` (Hamilton)."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def matrix_to_quat(r) -> np.ndarray:
    """(..., 4) unit quaternions ``x, y, z, w`` with ``w >= 0`` of rotations (..., 3, 3)
    (Shepperd's method: the largest of ``w, x, y, z`` is found first, so no division is small)."""
    r = np.asarray(r, dtype=np.float64)
    m = r.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], tr], 1)
    pick = np.argmax(diag, 1)
    q = np.empty((len(m), 4))
    for k in range(4):
        s = pick == k
        if not s.any():
            continue
        a = m[s]
        if k == 3:
            w = 0.5 * np.sqrt(1 + tr[s])
            q[s] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / (4 * w), (a[:, 0, 2] - a[:, 2, 0]) / (4 * w),
                             (a[:, 1, 0] - a[:, 0, 1]) / (4 * w), w], 1)
            continue
        i, j, l = k, (k + 1) % 3, (k + 2) % 3
        v = 0.5 * np.sqrt(1 + a[:, i, i] - a[:, j, j] - a[:, l, l])
        out = np.empty((len(a), 4))
        out[:, i] = v
        out[:, j] = (a[:, j, i] + a[:, i, j]) / (4 * v)
        out[:, l] = (a[:, l, i] + a[:, i, l]) / (4 * v)
        out[:, 3] = (a[:, l, j] - a[:, j, l]) / (4 * v)
        q[s] = out
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    return q.reshape(r.shape[:-2] + (4,))


def slerp(q0, q1, f) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (..., 4) at fractions ``f`` (...,)."""
    q0, q1, f = np.asarray(q0, float), np.asarray(q1, float).copy(), np.asarray(f, float)[..., None]
    dot = np.sum(q0 * q1, -1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)              # the shorter arc
    dot = np.clip(np.abs(dot), -1.0, 1.0)
    w = np.arccos(dot)
    small = w < 1e-8                             # nearly equal: linear, then normalised
    sw = np.where(small, 1.0, np.sin(w))
    a = np.where(small, 1 - f, np.sin((1 - f) * w) / sw)
    b = np.where(small, f, np.sin(f * w) / sw)
    q = a * q0 + b * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def pose(position=(0.0, 0.0, 0.0), yaw=0.0) -> np.ndarray:
    """4x4 vehicle pose at ``position`` with heading ``yaw`` (radians, about world +z from +x)."""
    m = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = position
    return m


def _poses(positions, yaws) -> np.ndarray:
    positions, yaws = np.asarray(positions, float), np.asarray(yaws, float)
    m = np.zeros((len(yaws), 4, 4))
    c, s = np.cos(yaws), np.sin(yaws)
    m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1] = c, -s, s, c
    m[:, 2, 2] = m[:, 3, 3] = 1.0
    m[:, :3, 3] = positions
    return m


def _sample_times(duration, dt, t0):
    if not (math.isfinite(duration) and duration > 0):
        raise TrajectoryError(f"trajectory 'duration': {_plain(duration)} is not allowed (a time > 0 s)")
    if not (math.isfinite(dt) and dt > 0):
        raise TrajectoryError(f"trajectory 'dt': {_plain(dt)} is not allowed (a sample interval > 0 s)")
    n = max(1, int(math.ceil(duration / dt - 1e-9)))
    return t0 + np.linspace(0.0, duration, n + 1)


# ---------------------------------------------------------------------------- the class
class Trajectory:
    """Timestamped rigid vehicle poses; `at` interpolates them (module docstring for the math).

    Parameters
    ----------
    times : (N,) seconds, finite, strictly increasing (N >= 1)
    poses : (N, 4, 4) rigid transforms, vehicle frame (x forward, y port, z up) to world
    """

    def __init__(self, times, poses, *, _quats=None, _source="Trajectory"):
        t = np.array(times, dtype=np.float64)
        p = np.array(poses, dtype=np.float64)
        if t.ndim != 1 or t.size < 1:
            raise TrajectoryError(f"{_source} 'times': shape {t.shape} is not (N,) with N >= 1")
        if p.shape != (t.size, 4, 4):
            raise TrajectoryError(f"{_source} 'poses': shape {p.shape} is not (N, 4, 4) = {(t.size, 4, 4)}")
        if not np.isfinite(t).all():
            k = int(np.argmin(np.isfinite(t)))
            raise TrajectoryError(f"{_source} 'times': {_plain(t[k])} at index {k} is not allowed (finite values only)")
        steps = np.diff(t) <= 0
        if steps.any():
            k = int(np.argmax(steps)) + 1
            raise TrajectoryError(f"{_source} 'times': {_plain(t[k])} at index {k} is not after {_plain(t[k - 1])} "
                                  "(times must increase strictly)")
        try:
            check_rigid_stack(p, f"{_source} 'poses'")
        except ValueError as exc:
            raise TrajectoryError(str(exc).replace("; the beam frame is +z boresight, +y scan axis", "")) from None
        self.times, self.poses = t, p
        self.quaternions = matrix_to_quat(p[:, :3, :3]) if _quats is None else np.array(_quats, dtype=np.float64)
        self.times.flags.writeable = self.poses.flags.writeable = self.quaternions.flags.writeable = False

    # -------------------------------------------------------------- construction
    @classmethod
    def from_numpy(cls, array, source="Trajectory.from_numpy") -> "Trajectory":
        """From an (N, 8) array in TUM column order ``t, tx, ty, tz, qx, qy, qz, qw``."""
        a = np.asarray(array, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != 8:
            raise TrajectoryError(f"{source}: shape {a.shape} is not (N, 8) (t tx ty tz qx qy qz qw)")
        for row in range(len(a)):
            _check_row(a[row], a[row - 1, 0] if row else None, f"{source}: row {row}")
        q = a[:, 4:8] / np.linalg.norm(a[:, 4:8], axis=1, keepdims=True)
        m = np.tile(np.eye(4), (len(a), 1, 1))
        m[:, :3, :3] = quat_to_matrix(q)
        m[:, :3, 3] = a[:, 1:4]
        return cls(a[:, 0], m, _quats=q, _source=source)

    def to_numpy(self) -> np.ndarray:
        """(N, 8) array ``t, tx, ty, tz, qx, qy, qz, qw``."""
        return np.concatenate([self.times[:, None], self.poses[:, :3, 3], self.quaternions], 1)

    @classmethod
    def from_tum(cls, path) -> "Trajectory":
        """Read a TUM file. A malformed line, a time not after the previous one, a non-finite
        value or a quaternion whose norm is not 1 (within 1e-3) raises `TrajectoryError` naming the
        file, the line number and the field; a missing file raises it naming the file."""
        path = os.fspath(path)
        try:
            with open(path, encoding="utf-8") as fh:
                lines = fh.read().splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise TrajectoryError(f"{path}: cannot read the trajectory ({getattr(exc, 'strerror', None) or exc})") from None
        rows, previous = [], None
        for number, line in enumerate(lines, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            where = f"{path}:{number}"
            fields = text.replace(",", " ").split()
            if len(fields) != 8:
                raise TrajectoryError(f"{where}: {len(fields)} fields, expected 8 "
                                      f"({' '.join(TUM_FIELDS)})")
            values = []
            for name, value in zip(TUM_FIELDS, fields):
                try:
                    values.append(float(value))
                except ValueError:
                    raise TrajectoryError(f"{where}: field '{name}': {value!r} is not a number") from None
            _check_row(np.array(values), previous, where)
            rows.append(values)
            previous = values[0]
        if not rows:
            raise TrajectoryError(f"{path}: no poses (expected lines 'timestamp tx ty tz qx qy qz qw')")
        return cls.from_numpy(np.array(rows), source=path)

    def to_tum(self, path) -> None:
        """Write a TUM file (17 significant digits: `from_tum` reads back the same numbers),
        under a temporary name renamed at the end."""
        lines = ["# timestamp tx ty tz qx qy qz qw"]
        lines += [" ".join(f"{v:.17g}" for v in row) for row in self.to_numpy()]
        with replacing(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n")

    # -------------------------------------------------------------- generators
    @classmethod
    def straight(cls, duration, speed, start=None, dt=0.1, t0=0.0) -> "Trajectory":
        """Constant ``speed`` (m/s) along the vehicle's x axis for ``duration`` s from the pose
        ``start`` (4x4, default identity), sampled every ``dt`` s from time ``t0``."""
        return cls.turn(duration, speed, 0.0, start, dt, t0)

    @classmethod
    def turn(cls, duration, speed, yaw_rate, start=None, dt=0.1, t0=0.0) -> "Trajectory":
        """Constant ``speed`` (m/s) along the vehicle's x and constant ``yaw_rate`` (deg/s) about
        its z: in the start frame, ``x = v sin(w t) / w``, ``y = v (1 - cos(w t)) / w``, heading ``w t``
        (a circle of radius ``v / w``; a straight line when ``w = 0``)."""
        t = _sample_times(float(duration), float(dt), float(t0))
        s, w = float(speed), math.radians(float(yaw_rate))
        tau = t - t[0]
        if w == 0.0:
            x, y = s * tau, np.zeros_like(tau)
        else:
            x, y = s * np.sin(w * tau) / w, s * (1 - np.cos(w * tau)) / w
        local = _poses(np.stack([x, y, np.zeros_like(x)], 1), w * tau)
        start = np.eye(4) if start is None else check_rigid(start, "trajectory 'start'")
        return cls(t, start @ local)

    @classmethod
    def lawnmower(cls, x_min, x_max, y_min, y_max, spacing, speed, *, altitude=None, depth=None,
                  yaw_rate=20.0, dt=0.1, t0=0.0) -> "Trajectory":
        """A lawnmower survey of the world rectangle ``[x_min, x_max] x [y_min, y_max]``.

        Survey lines run along x at ``y_min + k * spacing`` (the last at ``y_max``; when the
        width is not a whole number of spacings the lines are spread evenly, at most ``spacing``
        apart), alternately forward and back, joined by legs along +y; the vehicle heads where it
        goes, turns on the spot at the corners at ``yaw_rate`` (deg/s) and moves at ``speed``
        (m/s). Height: ``z = altitude`` above a seabed at z = 0, or ``z = -depth`` below a
        surface at z = 0 (exactly one of them).
        """
        if (altitude is None) == (depth is None):
            raise TrajectoryError("lawnmower: give exactly one of 'altitude' (above z = 0) or 'depth' (below z = 0)")
        z = float(altitude) if altitude is not None else -float(depth)
        for name, v, ok, allowed in (("spacing", spacing, lambda v: v > 0, "a distance > 0 m"),
                                     ("speed", speed, lambda v: v > 0, "a speed > 0 m/s"),
                                     ("yaw_rate", yaw_rate, lambda v: v > 0, "a rate > 0 deg/s"),
                                     ("x_max", x_max, lambda v: v > x_min, f"> x_min = {x_min}"),
                                     ("y_max", y_max, lambda v: v >= y_min, f">= y_min = {y_min}"),
                                     ("altitude/depth", z, lambda v: True, "a finite height")):
            if not (isinstance(v, (int, float, np.number)) and math.isfinite(v) and ok(v)):
                raise TrajectoryError(f"lawnmower '{name}': {_plain(v)} is not allowed ({allowed})")
        width = y_max - y_min
        n_gaps = int(math.ceil(width / spacing - 1e-9))
        ys = y_min + np.arange(n_gaps + 1) * (width / n_gaps if n_gaps else 0.0)
        corners = []
        for k, y in enumerate(ys):
            xs = (x_min, x_max) if k % 2 == 0 else (x_max, x_min)
            corners += [(xs[0], y), (xs[1], y)]
        corners = np.array(corners, dtype=np.float64)
        times, positions, yaws = [0.0], [corners[0]], []
        yaw = 0.0
        for a, b in zip(corners[:-1], corners[1:]):
            length = float(np.hypot(*(b - a)))
            if length == 0:
                continue
            heading = math.atan2(b[1] - a[1], b[0] - a[0])
            if yaws:                                          # turn on the spot to the new heading
                turn = (heading - yaw + math.pi) % (2 * math.pi) - math.pi
                if turn != 0:
                    times.append(times[-1] + abs(math.degrees(turn)) / yaw_rate)
                    positions.append(a)
                    yaws.append(yaw)
                    yaw = yaw + turn
            else:
                yaw = heading
            yaws.append(yaw)
            times.append(times[-1] + length / speed)
            positions.append(b)
        yaws.append(yaw)
        knots = cls(np.array(times) + t0, _poses(np.column_stack([positions, np.full(len(positions), z)]), yaws))
        # Dense samples (every dt, plus every corner), so that drift and plots have a sample rate.
        t = np.union1d(_sample_times(knots.times[-1] - knots.times[0], dt, knots.times[0]), knots.times)
        return cls(t, knots.at(t))

    def with_drift(self, seed, position_sigma=0.05, yaw_sigma=0.5) -> "Trajectory":
        """This trajectory plus a seeded random walk, like a navigation solution drifting from the
        true track: at each sample the world position gains a Gaussian step of standard deviation
        ``position_sigma * sqrt(dt)`` m per axis and the heading ``yaw_sigma * sqrt(dt)`` deg (about
        world +z, through the vehicle's position), both starting at zero. The same seed gives the
        same trajectory, bit for bit."""
        rng = np.random.default_rng(seed)
        dt = np.diff(self.times, prepend=self.times[0])
        steps_p = rng.standard_normal((len(dt), 3)) * (float(position_sigma) * np.sqrt(dt))[:, None]
        steps_y = rng.standard_normal(len(dt)) * np.radians(float(yaw_sigma)) * np.sqrt(dt)
        offset, yaw = np.cumsum(steps_p, 0), np.cumsum(steps_y)
        rot = _poses(np.zeros((len(dt), 3)), yaw)
        out = rot @ self.poses
        out[:, :3, 3] = self.poses[:, :3, 3] + offset
        return Trajectory(self.times, out)

    # -------------------------------------------------------------- queries
    @property
    def span(self) -> tuple[float, float]:
        """(first, last) sample time in seconds."""
        return float(self.times[0]), float(self.times[-1])

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) world positions of the samples."""
        return self.poses[:, :3, 3]

    def __len__(self) -> int:
        return int(self.times.size)

    def __repr__(self) -> str:
        return f"Trajectory({len(self)} poses, {self.span[0]:g} .. {self.span[1]:g} s)"

    def covers(self, t0, t1) -> bool:
        """Whether ``[t0, t1]`` lies within the span."""
        return self.times[0] <= t0 and t1 <= self.times[-1]

    def at(self, t) -> np.ndarray:
        """Vehicle pose(s) at time(s) ``t`` (s): (4, 4) for a number, (..., 4, 4) for an array.

        A time outside the span raises `TrajectoryError` naming the time and the span."""
        t = np.asarray(t, dtype=np.float64)
        flat = t.reshape(-1)
        bad = ~np.isfinite(flat) | (flat < self.times[0]) | (flat > self.times[-1])
        if bad.any():
            v = flat[bad][0]
            raise TrajectoryError(f"Trajectory.at: t = {v:.9g} s is outside the trajectory's span "
                                  f"[{self.times[0]:.9g}, {self.times[-1]:.9g}] s")
        if len(self) == 1:
            return np.broadcast_to(self.poses[0], t.shape + (4, 4)).copy()
        i = np.clip(np.searchsorted(self.times, flat, side="right") - 1, 0, len(self) - 2)
        t0, t1 = self.times[i], self.times[i + 1]
        f = (flat - t0) / (t1 - t0)
        out = np.zeros((flat.size, 4, 4))
        out[:, 3, 3] = 1.0
        p0, p1 = self.poses[i, :3, 3], self.poses[i + 1, :3, 3]
        out[:, :3, 3] = p0 + f[:, None] * (p1 - p0)
        out[:, :3, :3] = quat_to_matrix(slerp(self.quaternions[i], self.quaternions[i + 1], f))
        same_r = (self.poses[i, :3, :3] == self.poses[i + 1, :3, :3]).all(axis=(1, 2))
        out[same_r, :3, :3] = self.poses[i[same_r], :3, :3]
        same_p = (p0 == p1).all(axis=1)
        out[same_p, :3, 3] = p0[same_p]
        for at_sample, j in ((flat == t0, i), (flat == t1, i + 1)):   # samples: exactly as given
            out[at_sample] = self.poses[j[at_sample]]
        return out.reshape(t.shape + (4, 4))


def _plain(value) -> str:
    """A number as a user wrote it: ``1.0``, ``inf``, ``1700000000.25`` (never ``np.float64(1.0)``)."""
    try:
        return repr(float(value))
    except (TypeError, ValueError):
        return repr(value)


def _check_row(row, previous, where):
    """One sample ``t tx ty tz qx qy qz qw``: finite, after ``previous`` (a time or None), unit q."""
    for name, value in zip(TUM_FIELDS, row):
        if not math.isfinite(value):
            raise TrajectoryError(f"{where}: field '{name}': {_plain(value)} is not allowed (finite numbers only)")
    if previous is not None and not row[0] > previous:
        raise TrajectoryError(f"{where}: field 'timestamp': {_plain(row[0])} is not after the previous "
                              f"{_plain(previous)} (times must increase strictly)")
    norm = float(np.linalg.norm(row[4:8]))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise TrajectoryError(f"{where}: field 'qx qy qz qw': norm {norm:.6g} is not allowed "
                              f"(a unit quaternion, norm 1 within {UNIT_TOLERANCE:g})")
