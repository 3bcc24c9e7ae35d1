"""Multibeam soundings as a Kongsberg ``.kmall`` file of ``#MRZ`` datagrams (multibeam raw range and
depth), the structures of Kongsberg's EMdgmFormat.h (``EMdgmHeader``, ``EMdgmMpartition``,
``EMdgmMbody``, ``EMdgmMRZ_pingInfo``, ``EMdgmMRZ_txSectorInfo``, ``EMdgmMRZ_rxInfo``,
``EMdgmMRZ_sounding``), datagram version 0; read by pykmall (the kmall reader of UNH CCOM/NOAA),
Qimera, CARIS and MB-System read the format.

    from mitsonar.export.kmall import write_kmall
    write_kmall("soundings.kmall", run.soundings, trajectory, frame, n_beams=256, sound_speed=1500.0)

One ``#MRZ`` per ping (the soundings' ``ping``), ``numSoundingsMaxMain`` = ``n_beams`` soundings
in beam order; a beam without a detection has ``detectionType`` 2 (rejected) and zeros. The
vessel reference point is the vehicle's position on ``trajectory`` at the ping's time
(``latitude_deg``/``longitude_deg`` through ``frame``, ``ellipsoidHeightReRefPoint_m`` its height,
``headingVessel_deg`` from true north); each sounding's ``x_reRefPoint_m`` (forward along the
heading), ``y_reRefPoint_m`` (starboard) and ``z_reRefPoint_m`` (down) are its offsets in the
surface coordinate system (grid metres turned by the grid heading: the grid's scale factor, about
4e-4 in UTM, is not removed), ``deltaLatitude_deg``/``deltaLongitude_deg`` its lat/lon minus the
reference point's; ``z_waterLevelReRefPoint_m`` is the reference point's z, so that depth below
z = 0 is ``z_reRefPoint_m - z_waterLevelReRefPoint_m``. ``twoWayTravelTime_sec`` = 2 range / c,
``beamAngleReRx_deg`` the beam angle (port +, as the soundings have it), ``reflectivity1_dB``
the echo level (dB), ``detectionUncertaintyVer_m`` the predicted depth sigma when given. Times:
``start`` + the ping time, seconds of the Unix epoch. No seabed image samples, no water column.
"""
from __future__ import annotations

import math
import struct

import numpy as np

from mitsonar._files import replacing

HEADER = struct.Struct("<I4sBBHII")          # EMdgmHeader
PARTITION = struct.Struct("<HH")             # EMdgmMpartition
BODY = struct.Struct("<HH8B")                # EMdgmMbody
PING_INFO = struct.Struct("<HHf6BH11f2h2BHI3f2Hf2H6f4B" + "ddf")   # EMdgmMRZ_pingInfo, version 0
TX_SECTOR = struct.Struct("<4B7f2BH")        # EMdgmMRZ_txSectorInfo, version 0
RX_INFO = struct.Struct("<4H4f4H")           # EMdgmMRZ_rxInfo
SOUNDING = struct.Struct("<H8BH6f2H18f4H")   # EMdgmMRZ_sounding
assert (HEADER.size, BODY.size, PING_INFO.size, TX_SECTOR.size, RX_INFO.size, SOUNDING.size) == \
    (20, 12, 144, 36, 32, 120)
REJECTED = 2


def write_kmall(path, soundings, trajectory, frame, *, n_beams, sound_speed, start=0.0, uncertainty=None,
                echo_sounder_id=0, frequency=0.0) -> int:
    """Write one ``#MRZ`` per ping of ``soundings`` (`SOUNDING_DTYPE`) to ``path`` (under a
    temporary name, renamed at the end). Returns the number of datagrams."""
    pings = np.unique(soundings["ping"])
    if len(soundings) and int(soundings["beam"].max()) >= n_beams:
        raise ValueError(f"write_kmall 'n_beams': {n_beams} is not allowed (more than the largest beam index, "
                         f"{int(soundings['beam'].max())})")
    with replacing(path) as tmp, open(tmp, "wb") as f:
        for ping in pings:
            rows = np.flatnonzero(soundings["ping"] == ping)
            f.write(_mrz(soundings, rows, int(ping), trajectory, frame, n_beams, sound_speed, start,
                         None if uncertainty is None else np.asarray(uncertainty)[rows], echo_sounder_id, frequency))
    return len(pings)


def _mrz(s, rows, ping, trajectory, frame, n_beams, c, start, sigma, echo_sounder_id, frequency) -> bytes:
    t = float(s["time"][rows].min())
    lo, hi = trajectory.span
    pose = trajectory.at(min(max(t, lo), hi))
    ref = pose[:3, 3]
    fwd = pose[:3, 0]
    grid_yaw = math.atan2(fwd[1], fwd[0])                # from grid east, counter-clockwise
    heading = float(frame.true_heading(ref[0], ref[1], fwd[0], fwd[1]))
    rlon, rlat = frame.to_lonlat(ref[0], ref[1])
    slon, slat = frame.to_lonlat(s["x"][rows], s["y"][rows])
    dx, dy = s["x"][rows] - ref[0], s["y"][rows] - ref[1]
    along = dx * math.cos(grid_yaw) + dy * math.sin(grid_yaw)
    port = -dx * math.sin(grid_yaw) + dy * math.cos(grid_yaw)
    down = ref[2] - s["z"][rows]
    by_beam = {int(b): i for i, b in enumerate(s["beam"][rows])}
    body = []
    valid = 0
    for beam in range(n_beams):
        i = by_beam.get(beam)
        if i is None:
            body.append(SOUNDING.pack(beam, 0, REJECTED, 0, 0, 0, 0, 0, 0, 0, *([0.0] * 6), 0, 0, *([0.0] * 18),
                                      0, 0, 0, 0))
            continue
        valid += 1
        r = s[rows[i]]
        floats = [0.0] * 18
        floats[2] = float(r["intensity"])                 # reflectivity1_dB
        floats[8] = float(r["angle"])                     # beamAngleReRx_deg
        floats[10] = 2.0 * float(r["range"]) / c          # twoWayTravelTime_sec
        floats[12] = float(slat[i] - rlat)                # deltaLatitude_deg
        floats[13] = float(slon[i] - rlon)                # deltaLongitude_deg
        floats[14], floats[15], floats[16] = float(down[i]), float(-port[i]), float(along[i])   # z, y, x re ref point
        six = [0.0] * 6
        if sigma is not None:
            six[2] = float(sigma[i])                      # detectionUncertaintyVer_m
        body.append(SOUNDING.pack(beam, 0, 0, 1, 0, 0, 0, 0, 0, 0, *six, 0, 0, *floats, 0, 0, 0, 0))
    when = float(start) + t
    sec = int(math.floor(when))
    nsec = min(999_999_999, int(round((when - sec) * 1e9)))
    info = [0] * 45
    info[0] = PING_INFO.size
    info[10] = float(frequency)                           # frequencyMode_Hz
    info[33], info[34] = 1, TX_SECTOR.size                # numTxSectors, numBytesPerTxSector
    info[35], info[36] = heading, float(c)                # headingVessel_deg, soundSpeedAtTxDepth_mPerSec
    info[37], info[38] = float(-ref[2]), float(ref[2])    # txTransducerDepth_m, z_waterLevelReRefPoint_m
    info += [float(rlat), float(rlon), float(frame.height + ref[2])]
    parts = [PARTITION.pack(1, 1), BODY.pack(BODY.size, ping % 65536, 1, 0, 1, 0, 0, 0, 1, 0),
             PING_INFO.pack(*info), TX_SECTOR.pack(0, 0, 0, 0, 0.0, 0.0, 0.0, 0.0, float(frequency), 0.0, 0.0, 0, 0, 0),
             RX_INFO.pack(RX_INFO.size, n_beams, valid, SOUNDING.size, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0),
             *body]
    payload = b"".join(parts)
    size = HEADER.size + len(payload) + 4
    return HEADER.pack(size, b"#MRZ", 0, 0, echo_sounder_id, sec, nsec) + payload + struct.pack("<I", size)
