"""What an Oculus ping is as a `mitsonar.scan.Scan`: `ping_to_scan` and `OculusAssembler`.

One simple ping result is one multibeam frame: a Scan of kind ``multibeam`` whose rows are the
head's beams, at the head's own bearings (the result's bearing table, 0.01 degree), and whose
bins are its range lines: bin i is centred at ``(i + 1/2) x rangeResolution`` (window
``0 .. nRanges x rangeResolution``; bps_oculus's range table puts line i at
``(i + 1) x rangeResolution``, the line's far edge). ``data`` is the image transposed, its codes
kept: 8-bit samples as uint8, 16-bit as uint16, 32-bit as uint32, and the electronics'
``bit_depth`` says which (8, 16, 32); 24-bit samples (``dataSize`` 2, which no fire message asks
for) become uint32 on the 32-bit scale, ``round(code x (2^32 - 1) / (2^24 - 1))``
(`mitsonar.scan.model.data_as`'s rule: the same levels), ``bit_depth`` 32. Row k's pose is the
head's pose turned by bearing k about the fan's axis
(`mitsonar.geometry.frames.bearing_rotation`); the beam widths are the model's in the
result's frequency mode (`mitsonar.presets.oculus`), else 1 x 20 degrees.
"""
from __future__ import annotations

import numpy as np

from mitsonar.acoustics.water import SOUND_SPEED
import mitsonar.presets.oculus as presets
from mitsonar.devices.oculus.protocol import DATA_SIZE_BYTES, PingResult
from mitsonar.scan.model import data_as

__all__ = ["ping_to_scan", "OculusAssembler", "mode_of"]

#: bytes per sample -> the Scan's data type (24-bit samples go on the 32-bit scale)
_DTYPE = {1: np.uint8, 2: np.uint16, 3: np.uint32, 4: np.uint32}
_TOP24 = (1 << 24) - 1


def _codes(image, nbytes: int) -> np.ndarray:
    """A ping result's ``image`` of ``nbytes``-byte samples as the codes a `Scan` carries
    (uint8, uint16, uint32; 24-bit samples on the 32-bit scale)."""
    image = np.asarray(image)
    if nbytes == 3:
        return data_as(image, np.uint32, top=_TOP24)
    return image.astype(_DTYPE[nbytes], copy=False)


def mode_of(frequency: float, master_mode: int | None = None):
    """The preset mode at ``frequency`` Hz (within 5 %), of the first model that has it as
    ``master_mode`` (if given, else in any mode), or None."""
    found = None
    for m in presets.MODELS.values():
        for number, mode in m.modes.items():
            if abs(mode.frequency - frequency) <= 0.05 * mode.frequency:
                if master_mode is None or number == master_mode:
                    return mode
                found = found or mode
    return found


def ping_to_scan(ping: PingResult, pose=None, t: float = 0.0, meta: dict | None = None):
    """The `Scan` of one simple ping result, with the head at ``pose`` (4x4, default identity)
    at time ``t`` (s, ``meta['start_time']``)."""
    import mitsonar.kinds as kinds
    from mitsonar.geometry.frames import bearing_rotation
    from mitsonar.scan import ElectronicsSettings, Scan, ScanMeta

    pose = np.eye(4) if pose is None else np.asarray(pose, np.float64)
    image = np.asarray(ping.image)
    nbytes = DATA_SIZE_BYTES.get(ping.data_size, image.dtype.itemsize)
    data = _codes(image, nbytes).T.copy()
    n_b, n_r = data.shape
    res = float(ping.range_resolution)
    if not (np.isfinite(res) and res > 0):
        raise ValueError(f"ping {ping.ping_id}: rangeResolution {res!r} is not allowed (> 0 m)")
    bearings = np.radians(np.asarray(ping.bearings, np.float64) / 100.0)
    mode = mode_of(ping.frequency, ping.fire.master_mode)
    c = float(ping.speed_of_sound_used) if np.isfinite(ping.speed_of_sound_used) and \
        ping.speed_of_sound_used > 0 else SOUND_SPEED
    info = {"source": "oculus", "sweep": "sector", "start_time": float(t),
            "frequency": float(ping.frequency) if ping.frequency > 0 and np.isfinite(ping.frequency) else None,
            "oculus_ping_id": int(ping.ping_id), "oculus_gain_percent": float(ping.fire.gain),
            "oculus_master_mode": int(ping.fire.master_mode), "oculus_version": int(ping.version),
            **(meta or {})}
    return Scan(intensity=np.zeros((n_b, n_r), np.float32), data=data, ranges=(np.arange(n_r) + 0.5) * res,
                bearings=bearings, poses=pose @ bearing_rotation(bearings), range_min=0.0, range_max=n_r * res,
                beamwidth_h=mode.beamwidth_h if mode else 1.0, beamwidth_v=mode.beamwidth_v if mode else 20.0,
                kind=kinds.MULTIBEAM.name, sound_speed=c, times=np.zeros(n_b),
                electronics=ElectronicsSettings(bit_depth=8 * data.dtype.itemsize),
                meta=ScanMeta.from_dict({k: v for k, v in info.items() if v is not None}))


class OculusAssembler:
    """``add(ping_result, pose, t) -> Scan``: each simple ping result is a whole frame."""

    def __init__(self, settings=None):
        self.settings = settings

    def add(self, message, pose, t):
        if not isinstance(message, PingResult):
            return None
        return ping_to_scan(message, pose, t)

    def finish(self):
        return None
