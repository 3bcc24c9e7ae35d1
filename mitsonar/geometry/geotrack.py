"""Trajectories given in latitude and longitude: a CSV table or NMEA 0183 GGA/VTG sentences, turned
into a `Trajectory` in the world grid of a `mitsonar.geometry.geodesy.GeoFrame`.

    track = read_geo_trajectory("track.csv", frame)     # or "track.nmea"

CSV: a header line naming the columns ``time`` (s), ``lat``, ``lon`` (WGS 84 deg), ``depth`` (m
below the origin's height, positive down) and optionally ``heading`` (deg clockwise from true
north); other columns are ignored. NMEA: ``$--GGA`` sentences (UTC time of day, latitude, longitude,
altitude above the geoid: ``z = altitude - height``) and ``$--VTG`` (course over ground, true, deg:
the heading of the GGA fix before it); other sentences are skipped; a sentence whose checksum is
wrong is refused. Times of day that go backwards roll over midnight (+86400 s).

Without a heading the vehicle faces along its track (the direction to the next fix; the last fix
keeps the one before). A true heading becomes a direction in the grid by projecting the point 1 m
along the geodesic at that azimuth (pyproj), so the meridian convergence is accounted for.
"""
from __future__ import annotations

import csv
import math
import os

import numpy as np

from mitsonar.geometry.geodesy import GeoError, check_origin
from mitsonar.geometry.trajectory import Trajectory

EXTENSIONS = (".csv", ".nmea")
CSV_COLUMNS = "time, lat, lon, depth (and optionally heading)"


def is_geo_trajectory(path) -> bool:
    """True for a file name this module reads (``.csv``, ``.nmea``)."""
    return os.path.splitext(os.fspath(path))[1].lower() in EXTENSIONS


def read_geo_trajectory(path, frame) -> Trajectory:
    """The `Trajectory` of a lat/lon ``path`` (``.csv`` or ``.nmea``) in ``frame``'s world grid."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".csv":
        t, lat, lon, z, heading = _read_csv(path)
    elif ext == ".nmea":
        t, lat, lon, z, heading = _read_nmea(path, frame.height)
    else:
        raise GeoError(f"{path}: not a lat/lon trajectory (allowed: {', '.join(EXTENSIONS)})")
    if len(t) < 1:
        raise GeoError(f"{path}: no positions (a lat/lon trajectory needs at least one)")
    x, y = frame.from_lonlat(lon, lat)
    yaw = _yaws(frame, x, y, lat, lon, heading)
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    c, s = np.cos(yaw), np.sin(yaw)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -s, s, c
    poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3] = x, y, z
    return Trajectory(t, poses, _source=path)


def _yaws(frame, x, y, lat, lon, heading):
    """Grid yaw (rad from grid east, counter-clockwise) per fix: from the true ``heading`` where
    finite, else along the track."""
    import pyproj

    n = len(x)
    yaw = np.zeros(n)
    if n > 1:
        dx, dy = np.diff(x), np.diff(y)
        along = np.arctan2(dy, dx)
        yaw[:-1], yaw[-1] = along, along[-1]
    ok = np.isfinite(heading)
    if ok.any():
        lon1, lat1, _ = pyproj.Geod(ellps="WGS84").fwd(lon[ok], lat[ok], heading[ok], np.ones(ok.sum()))
        x1, y1 = frame.from_lonlat(lon1, lat1)
        yaw[ok] = np.arctan2(np.asarray(y1) - y[ok], np.asarray(x1) - x[ok])
    return yaw


def _read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise GeoError(f"{path}: empty (a header line: {CSV_COLUMNS})")
    head = [h.strip().lower() for h in rows[0]]
    missing = [c for c in ("time", "lat", "lon", "depth") if c not in head]
    if missing:
        raise GeoError(f"{path}: line 1: no column {missing[0]!r} (allowed header: {CSV_COLUMNS})")
    cols = {c: head.index(c) for c in ("time", "lat", "lon", "depth", "heading") if c in head}
    out = {c: [] for c in cols}
    for i, row in enumerate(rows[1:], start=2):
        if not row or all(not v.strip() for v in row):
            continue
        for c, k in cols.items():
            try:
                v = float(row[k])
            except (IndexError, ValueError):
                raise GeoError(f"{path}: line {i}: {c} {row[k] if k < len(row) else ''!r} is not a number "
                               f"(columns: {CSV_COLUMNS})") from None
            out[c].append(v)
        check_origin((out["lat"][-1], out["lon"][-1]), f"{path}: line {i}: lat lon")
    heading = np.array(out["heading"], np.float64) if "heading" in out else np.full(len(out["time"]), np.nan)
    return (np.array(out["time"], np.float64), np.array(out["lat"]), np.array(out["lon"]),
            -np.array(out["depth"], np.float64), heading)


def _degrees(value, hemi, width, path, line):
    """NMEA ``dddmm.mmmm`` and N/S/E/W as signed degrees."""
    try:
        deg = int(value[:width]) + float(value[width:]) / 60.0
    except ValueError:
        raise GeoError(f"{path}: line {line}: {value!r} is not an NMEA angle (ddmm.mmmm / dddmm.mmmm)") from None
    if hemi not in ("N", "S", "E", "W"):
        raise GeoError(f"{path}: line {line}: hemisphere {hemi!r} is not allowed (N, S, E or W)")
    return -deg if hemi in ("S", "W") else deg


def _read_nmea(path, height):
    t, lat, lon, z, heading = [], [], [], [], []
    day = 0.0
    with open(path, errors="replace") as f:
        for i, line in enumerate(f, start=1):
            line = line.strip()
            if not line.startswith("$"):
                continue
            body, _, check = line[1:].partition("*")
            if check:
                total = 0
                for ch in body:
                    total ^= ord(ch)
                if check[:2].upper() != f"{total:02X}":
                    raise GeoError(f"{path}: line {i}: checksum {check[:2]!r} is wrong (the sentence's is {total:02X})")
            fields = body.split(",")
            sentence = fields[0][2:]
            if sentence == "GGA" and len(fields) > 9 and fields[2] and fields[4]:
                hh, mm, ss = int(fields[1][0:2]), int(fields[1][2:4]), float(fields[1][4:])
                tod = 3600 * hh + 60 * mm + ss
                if t and tod + day < t[-1]:
                    day += 86400.0
                t.append(tod + day)
                lat.append(_degrees(fields[2], fields[3], 2, path, i))
                lon.append(_degrees(fields[4], fields[5], 3, path, i))
                check_origin((lat[-1], lon[-1]), f"{path}: line {i}: lat lon")
                z.append((float(fields[9]) if fields[9] else height) - height)
                heading.append(math.nan)
            elif sentence == "VTG" and len(fields) > 1 and fields[1] and heading:
                heading[-1] = float(fields[1])
    return np.array(t), np.array(lat), np.array(lon), np.array(z), np.array(heading, np.float64)
