"""Vehicle poses from MAVLink (``mitsonar live --mavlink URL``): what ArduSub (SITL or a BlueROV2)
sends, read with ``pymavlink`` (the ``live`` extra; imported only when this module is used).

Messages: ``LOCAL_POSITION_NED`` (``x, y, z``: north, east, down of the EKF origin, metres) and
``ATTITUDE_QUATERNION`` (``q1..q4`` = ``w, x, y, z``, the rotation from the body frame, x forward,
y right, z down (FRD), to NED). Each one, once both have arrived, adds a pose to the
`mitsonar.live.poses.PoseBuffer` at ``time_boot_ms`` on the autopilot's clock (the buffer
estimates the offset to ours), made of it and the latest of the other. A message whose numbers
are not finite (or whose quaternion is not of norm 1) is dropped and its predecessor kept; a pose
the buffer refuses (out of its bounds, a ``time_boot_ms`` off the clock: `PoseBuffer.add`) is
dropped too; both counted by reason (``drops.counts``) in the session's summary.

Frames (`ned_to_enu`): mitsonar's world is ENU-like (z up) and its vehicle frame FLU (x forward,
y port, z up, REP-103), so

* position: ``(x, y, z)_ENU = (east, north, -down) = (y, x, -z)_NED``;
* rotation: ``R_ENU<-FLU = A R_NED<-FRD B`` with ``A = [[0,1,0],[1,0,0],[0,0,-1]]`` (NED -> ENU,
  its own inverse) and ``B = diag(1, -1, -1)`` (FLU -> FRD). A level vehicle facing north
  (``q = 1``) thus points its x to world +y (north), its y (port) to west; yaw 90 deg (east) points
  x to world +x.
"""
from __future__ import annotations

import time

import numpy as np

from mitsonar.live.poses import DatagramError, PoseSource, check_pose
from mitsonar.geometry.trajectory import matrix_to_quat, quat_to_matrix

__all__ = ["NED_TO_ENU", "FLU_TO_FRD", "ned_to_enu", "MavlinkReceiver"]

NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def ned_to_enu(position_ned, q_wxyz) -> tuple[np.ndarray, np.ndarray]:
    """(position ENU (3,), unit quaternion ``x, y, z, w`` of the FLU body in ENU) of a NED
    position and a MAVLink quaternion ``w, x, y, z`` (FRD body in NED); see the module doc."""
    p = NED_TO_ENU @ np.asarray(position_ned, np.float64)
    w, x, y, z = (float(v) for v in q_wxyz)
    q = np.array([x, y, z, w])
    q /= np.linalg.norm(q)
    r = NED_TO_ENU @ quat_to_matrix(q) @ FLU_TO_FRD
    return p, matrix_to_quat(r)


class MavlinkReceiver(PoseSource):
    """Reads ``url`` (a pymavlink connection string: ``udpin:127.0.0.1:14550``, a serial port,
    ...) in a thread into ``buffer`` until `stop`. ``stats``: messages used, ``poses`` added,
    ``dropped`` (messages with non-finite numbers or a quaternion not of norm 1, poses the buffer
    refused; ``drops.counts`` by reason)."""

    what = "a MAVLink message"

    def __init__(self, url: str, buffer, *, out=None):
        try:
            from pymavlink import mavutil
        except ImportError:
            raise ValueError("--mavlink needs the pymavlink package (pip install 'mitsonar[live]')") from None
        try:
            self.conn = mavutil.mavlink_connection(url, source_system=255)
        except Exception as e:      # noqa: BLE001 - pymavlink raises many kinds
            raise ValueError(f"--mavlink {url}: cannot open ({e})") from None
        self.url = url
        self._position = self._attitude = None
        super().__init__("MavlinkReceiver", buffer, out)

    @property
    def address(self) -> str:
        """Where it listens, for ``udpin:`` URLs ``udpin:HOST:PORT`` with the port bound."""
        sock = getattr(self.conn, "port", None)
        if hasattr(sock, "getsockname"):
            host, port = sock.getsockname()[:2]
            return f"udpin:{host}:{port}"
        return self.url

    def _close(self) -> None:
        try:
            self.conn.close()
        except Exception:           # noqa: BLE001
            pass

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                m = self.conn.recv_match(type=["LOCAL_POSITION_NED", "ATTITUDE_QUATERNION"], blocking=True,
                                         timeout=0.1)
                if m is not None:
                    self.handle(m, time.monotonic())
            except Exception as e:  # noqa: BLE001 - a bad message never stops the receiver
                self.stats["errors"] += 1
                if self.stats["errors"] == 1:
                    print(f"mitsonar live: warning: MAVLink: {e}", file=self.out, flush=True)
                time.sleep(0.01)

    def handle(self, m, arrival: float) -> bool:
        """Take one decoded message; True when it added a pose."""
        msg_type = m.get_type()
        try:        # each message's numbers checked as a pose's (`check_pose`), the other part neutral
            if msg_type == "LOCAL_POSITION_NED":
                self._position, _, _ = check_pose([m.x, m.y, m.z], [0, 0, 0, 1], bounds=None,
                                                  names=("LOCAL_POSITION_NED x, y, z", "", ""))
            elif msg_type == "ATTITUDE_QUATERNION":
                self._attitude = check_pose([0, 0, 0], [m.q1, m.q2, m.q3, m.q4], bounds=None,
                                            names=("", "ATTITUDE_QUATERNION q1..q4", ""))[1]
            else:
                return False
        except DatagramError as e:
            self.drop(e, arrival)
            return False
        self.stats[msg_type] += 1
        if self._position is None or self._attitude is None:
            return False
        p, q = ned_to_enu(self._position, self._attitude)
        return self.add(p, q, m.time_boot_ms * 1e-3, arrival)
