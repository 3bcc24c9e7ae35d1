"""Soundings as a LAS 1.4 point cloud (laspy; the ``geo`` extra) and as plain ``E,N,depth`` CSV,
in the projected CRS of a `mitsonar.geometry.geodesy.GeoFrame`.

    from mitsonar.export.las import write_las, write_csv
    write_las("soundings.las", run.soundings, frame, uncertainty=sigma)   # .laz needs lazrs
    write_csv("soundings.csv", run.soundings, frame)

LAS: point format 6, X/Y the easting/northing (``x + E0``, ``y + N0``), Z the elevation (``z +
height`` of the origin: positive up, the LAS convention), scaled by 1 mm; ``intensity`` the
sounding's echo level (dB) scaled linearly to 0..65535 (the survey's weakest 0, strongest 65535;
the dB value is kept in the extra bytes); the CRS as OGC WKT in the header's WKT VLR (``global_encoding`` WKT bit
set). Extra bytes per point: ``beam`` (uint16), ``ping`` (uint32), ``angle`` (float32, deg, port +),
``echo_intensity`` (float32, dB: 10 log10 of
the echo window's energy, `mitsonar.products.bathymetry.soundings`) and, when given, ``depth_uncertainty`` (float32, m, one
sigma: the predicted depth error of the sounding, `mitsonar.products.bathymetry.predicted_rms`).

CSV: a header line ``easting,northing,depth`` then one line per sounding, depth positive down
from the origin's height (``-z``), millimetres.

A 3D sonar's point cloud (`mitsonar.signals.volumetric.point_cloud`) goes to LAS 1.4 by
`write_point_cloud_las`.
"""
from __future__ import annotations

import os

import numpy as np

from mitsonar._files import replacing

EXTRA = (("beam", np.uint16, "receive beam index"), ("ping", np.uint32, "ping index"),
         ("angle", np.float32, "beam angle deg, port +"), ("echo_intensity", np.float32, "echo level, dB"))


def _laspy(what):
    try:
        import laspy
    except ImportError:
        raise ImportError(f"{what} needs laspy: pip install 'mitsonar[geo]'") from None
    return laspy


def write_las(path, soundings, frame, uncertainty=None) -> int:
    """Write ``soundings`` (a `SOUNDING_DTYPE` array) to ``path`` (``.las``; ``.laz`` compressed,
    which needs the lazrs backend) in ``frame``'s CRS; under a temporary name, renamed at the end.
    ``uncertainty``: one depth sigma per sounding (m), stored as ``depth_uncertainty``. Returns the
    number of points."""
    laspy = _laspy("LAS output")
    n = len(soundings)
    if uncertainty is not None:
        uncertainty = np.asarray(uncertainty, np.float32)
        if uncertainty.shape != (n,):
            raise ValueError(f"write_las 'uncertainty': shape {uncertainty.shape} is not allowed ({n} values, "
                             "one per sounding)")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    e, nn = frame.to_grid(soundings["x"], soundings["y"])
    z = np.asarray(soundings["z"], np.float64) + frame.height
    header.offsets = np.array([np.floor(e.min()) if n else frame.e0, np.floor(nn.min()) if n else frame.n0, 0.0])
    header.add_crs(frame.pyproj_crs)
    extras = [laspy.ExtraBytesParams(name=name, type=dtype, description=doc) for name, dtype, doc in EXTRA]
    if uncertainty is not None:
        extras.append(laspy.ExtraBytesParams(name="depth_uncertainty", type=np.float32,
                                             description="predicted depth sigma, m"))
    header.add_extra_dims(extras)
    las = laspy.LasData(header)
    las.x, las.y, las.z = e, nn, z
    level = np.asarray(soundings["intensity"], np.float64)
    ok = np.isfinite(level)
    lo, hi = (level[ok].min(), level[ok].max()) if ok.any() else (0.0, 0.0)
    scaled = (level - lo) / (hi - lo) if hi > lo else np.ones(n)
    las.intensity = np.round(np.clip(np.nan_to_num(scaled, nan=0.0), 0, 1) * 65535).astype(np.uint16)
    las.beam = soundings["beam"]
    las.ping = soundings["ping"]
    las.angle = soundings["angle"]
    las.echo_intensity = soundings["intensity"]
    if uncertainty is not None:
        las.depth_uncertainty = uncertainty
    suffix = os.path.splitext(os.fspath(path))[1]
    with replacing(path) as tmp:
        las.write(tmp, do_compress=suffix.lower() == ".laz")
    return n


def write_csv(path, soundings, frame) -> int:
    """``easting,northing,depth`` (m, mm resolution; depth = -z, positive down) per sounding."""
    e, n = frame.to_grid(soundings["x"], soundings["y"])
    d = -(np.asarray(soundings["z"], np.float64) + frame.height)
    with replacing(path) as tmp, open(tmp, "w") as f:
        f.write("easting,northing,depth\n")
        for row in zip(e, n, d):
            f.write("%.3f,%.3f,%.3f\n" % row)
    return len(e)


def write_point_cloud_las(path, points, frame=None) -> int:
    """Write a 3D sonar's point cloud (`mitsonar.signals.volumetric.point_cloud`) as LAS 1.4 (laspy;
    point format 6, 1 mm scale): X, Y, Z the world point (with a `GeoFrame`: its easting, northing
    and height added, its CRS in the header),
    ``intensity`` the point's intensity in dB scaled linearly to 0..65535 (the cloud's weakest 0,
    strongest 65535), extra bytes ``elevation_index``, ``azimuth_index`` (int32), ``range`` and
    ``intensity_linear`` (float32, the volume's units); ``.laz`` compressed. Returns the count."""
    from mitsonar.signals.volumetric import POINT_DTYPE

    pts = np.asarray(points)
    if pts.dtype != POINT_DTYPE:
        raise ValueError(f"write_point_cloud_las 'points': dtype {pts.dtype} is not allowed (point_cloud's POINT_DTYPE)")
    laspy = _laspy("LAS output")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    x, y, z = (pts[k].astype(np.float64) for k in ("x", "y", "z"))
    if frame is not None:
        x, y, z = x + frame.e0, y + frame.n0, z + frame.height
        header.add_crs(frame.pyproj_crs)
    header.offsets = np.array([np.floor(x.min()) if len(x) else 0.0, np.floor(y.min()) if len(y) else 0.0, 0.0])
    header.add_extra_dims([laspy.ExtraBytesParams(name="elevation_index", type=np.int32, description="beam row"),
                           laspy.ExtraBytesParams(name="azimuth_index", type=np.int32, description="beam column"),
                           laspy.ExtraBytesParams(name="range", type=np.float32, description="range, m"),
                           laspy.ExtraBytesParams(name="intensity_linear", type=np.float32,
                                                  description="intensity, volume units")])
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    with np.errstate(divide="ignore"):
        level = np.where(pts["intensity"] > 0, 10.0 * np.log10(np.maximum(pts["intensity"], 1e-300)), np.nan)
    ok = np.isfinite(level)
    lo, hi = (level[ok].min(), level[ok].max()) if ok.any() else (0.0, 0.0)
    scaled = (level - lo) / (hi - lo) if hi > lo else np.ones(len(pts))
    las.intensity = np.round(np.clip(np.nan_to_num(scaled, nan=0.0), 0, 1) * 65535).astype(np.uint16)
    las.elevation_index, las.azimuth_index = pts["elevation_index"], pts["azimuth_index"]
    las.range, las.intensity_linear = pts["range"], pts["intensity"]
    with replacing(path) as tmp:
        las.write(tmp, do_compress=os.path.splitext(os.fspath(path))[1].lower() == ".laz")
    return len(pts)
