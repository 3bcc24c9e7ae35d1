"""Sonar frames: the bearing rotation of a beam frame, rigid-pose checks.

The lowest layer of mitsonar's geometry: the sensor plugin, the `Scan`, the trajectories and the
device drivers all build and check poses with these, and it imports nothing from mitsonar (numpy
only), so any layer may use it.
"""
from __future__ import annotations

import numpy as np

# The kinds of sonar head (the old ``KINDS``) are classes in `mitsonar.kinds`.

#: A side-scan head's ``side`` values, and the channel number of each side (``scan.channel``).
SIDES = ("port", "starboard", "both")
PORT, STARBOARD = 0, 1


def sidescan_rotation(channel, depression) -> np.ndarray:
    """4x4 rotation(s) from a side-scan head frame (x along track, y port, z up) to a channel's
    beam frame, for channel(s) 0 (port) or 1 (starboard) and a depression in radians.

    The beam frame's +z, the boresight, is the head's +y (port) or -y (starboard) turned down by
    ``depression`` about the head's x axis: ``(0, +-cos d, -sin d)``. Its +y (elevation, across
    the fan, ``beamwidth_v``) points to the steep, nadir side of the fan on both channels:
    ``(0, -+sin d, -cos d)``; its +x (azimuth, along the track, ``beamwidth_h``) is then forward
    for port and aft for starboard (a right-handed frame). So the two channels' patterns are mirror
    images across the vertical plane of the track, as on a real head.
    """
    ch = np.asarray(channel)
    d = np.asarray(depression, dtype=np.float64)
    shape = np.broadcast(ch, d).shape
    s = np.where(np.broadcast_to(ch, shape) == STARBOARD, -1.0, 1.0)     # +1 port, -1 starboard
    c, n = np.cos(np.broadcast_to(d, shape)), np.sin(np.broadcast_to(d, shape))
    m = np.zeros(shape + (4, 4))
    m[..., 0, 0] = s                                   # x: forward (port) / aft (starboard)
    m[..., 1, 1], m[..., 2, 1] = -s * n, -c            # y: towards nadir
    m[..., 1, 2], m[..., 2, 2] = s * c, -n             # z: boresight
    m[..., 3, 3] = 1.0
    return m


def bearing_rotation(bearing) -> np.ndarray:
    """4x4 rotation(s) of the beam frame for bearing(s) in radians: right-handed about the frame's
    +y (scan) axis, so +z (the boresight) turns towards +x. Ping k's pose is ``T @ R(b_k)``.

    The one definition of the bearing convention: the renderer, the SeaNet driver and the virtual
    sonar all build poses with it.
    """
    b = np.asarray(bearing, dtype=np.float64)
    c, s = np.cos(b), np.sin(b)
    m = np.zeros(b.shape + (4, 4))
    m[..., 0, 0] = c
    m[..., 0, 2] = s
    m[..., 2, 0] = -s
    m[..., 2, 2] = c
    m[..., 1, 1] = 1.0
    m[..., 3, 3] = 1.0
    return m


def elevation_rotation(elevation) -> np.ndarray:
    """4x4 rotation(s) of the beam frame for elevation(s) in radians: about the frame's +x axis,
    turning +z (the boresight) towards +y, so ``bearing_rotation(az) @ elevation_rotation(el)``
    points +z along ``(cos el sin az, sin el, cos el cos az)`` (a volumetric head's beam grid,
    `mitsonar.signals.volumetric.directions`)."""
    e = np.asarray(elevation, dtype=np.float64)
    c, s = np.cos(e), np.sin(e)
    m = np.zeros(e.shape + (4, 4))
    m[..., 0, 0] = 1.0
    m[..., 1, 1] = c
    m[..., 1, 2] = s
    m[..., 2, 1] = -s
    m[..., 2, 2] = c
    m[..., 3, 3] = 1.0
    return m


def _not_rigid(m: np.ndarray) -> np.ndarray:
    """Which of the finite (..., 4, 4) matrices are not rigid: rotation + translation, with the
    tolerances of ``np.allclose`` (a float32 rotation passes, a scale of 1.001 does not)."""
    r = m[..., :3, :3]
    gram = np.swapaxes(r, -1, -2) @ r
    eye = np.eye(3)
    return ((np.abs(gram - eye) > 1e-4 + 1e-5 * eye).any(axis=(-2, -1))
            | (np.abs(np.linalg.det(r) - 1) > 1e-4)
            | (np.abs(m[..., 3, :] - [0, 0, 0, 1]) > 1e-9 + 1e-5 * np.array([0, 0, 0, 1])).any(axis=-1))


def check_rigid(matrix, what="sonar 'to_world'"):
    """A beam frame must be a rotation plus translation: scaling would bend the beam.

    Needs no Mitsuba variant: scans from a serial head or a file are checked on machines that
    cannot render."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"{what}: expected a 4x4 matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        r, c = np.argwhere(~np.isfinite(m))[0]
        raise ValueError(f"{what}: entry [{r}, {c}] is {m[r, c]} (a pose must be finite)")
    if _not_rigid(m):
        raise ValueError(f"{what}: must be a rigid transform (rotation + translation, no scale, "
                         "shear or mirror); the beam frame is +z boresight, +y scan axis")
    return m


def check_rigid_stack(matrices, what) -> np.ndarray:
    """`check_rigid` for a stack (N, 4, 4) in one vectorised pass; the message names the first
    matrix refused as ``what[k]``."""
    m = np.asarray(matrices, dtype=np.float64)
    if m.ndim != 3 or m.shape[1:] != (4, 4):
        raise ValueError(f"{what}: expected (N, 4, 4) matrices, got shape {m.shape}")
    bad = ~np.isfinite(m).all(axis=(1, 2))
    bad[~bad] = _not_rigid(m[~bad])
    if bad.any():
        k = int(np.argmax(bad))
        check_rigid(m[k], f"{what}[{k}]")
    return m
