"""Multibeam soundings as Kongsberg .kmall #MRZ datagrams (`mitsonar.export.kmall`), read back by
pykmall (UNH CCOM / NOAA's reader of the format)."""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pyproj", reason="georeferencing needs pyproj (the geo extra)")
kmall_mod = pytest.importorskip("KMALL.kmall", reason="pykmall (the test extra) reads .kmall")

from mitsonar.geometry.geodesy import GeoFrame  # noqa: E402
from mitsonar.geometry.trajectory import Trajectory  # noqa: E402


def _read_mrz(path):
    k = kmall_mod.kmall(str(path))
    k.index_file()
    out = []
    for offset, kind in zip(k.msgoffset, k.msgtype):
        assert kind == str(b"#MRZ")
        k.FID.seek(offset)
        out.append(k.read_EMdgmMRZ())
    k.closeFile()
    return out


def test_kmall_mrz_read_back_by_pykmall(tmp_path):
    from mitsonar.export.kmall import write_kmall
    from mitsonar.products.bathymetry import SOUNDING_DTYPE

    frame = GeoFrame.make((52.0, 4.5, 1.0))
    yaw = math.radians(30.0)                              # grid heading 60 deg
    times = np.array([0.0, 10.0])
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[:, :2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    poses[:, :3, 3] = [[0.0, 0.0, -3.0], [20 * math.cos(yaw), 20 * math.sin(yaw), -3.0]]
    track = Trajectory(times, poses)
    n_beams = 8
    s = np.zeros(2 * 6, SOUNDING_DTYPE)                   # two pings, beams 0..5 detected (6, 7 not)
    s["ping"], s["beam"] = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    s["time"] = np.repeat([1.0, 2.0], 6)
    across = np.tile(np.linspace(-5, 5, 6), 2)            # m to port
    ref = np.array([track.at(t)[:3, 3] for t in s["time"]])
    s["x"] = ref[:, 0] - across * math.sin(yaw)
    s["y"] = ref[:, 1] + across * math.cos(yaw)
    s["z"] = -12.0 - 0.1 * np.arange(12)
    s["range"], s["angle"] = np.hypot(across, 9.0), np.degrees(np.arctan2(across, 9.0))
    s["intensity"] = -30.0 - np.arange(12)
    sigma = np.full(12, 0.05)
    assert write_kmall(tmp_path / "s.kmall", s, track, frame, n_beams=n_beams, sound_speed=1500.0, start=1.7e9,
                       uncertainty=sigma) == 2
    dgs = _read_mrz(tmp_path / "s.kmall")
    assert len(dgs) == 2
    for p, dg in enumerate(dgs):
        rows = slice(6 * p, 6 * p + 6)
        assert dg["header"]["dgmType"] == b"#MRZ" and dg["cmnPart"]["pingCnt"] == p
        assert dg["header"]["dgtime"] == pytest.approx(1.7e9 + s["time"][6 * p], abs=1e-6)
        info = dg["pingInfo"]
        lon, lat = frame.to_lonlat(ref[6 * p, 0], ref[6 * p, 1])
        assert info["latitude_deg"] == pytest.approx(float(lat), abs=1e-9)
        assert info["longitude_deg"] == pytest.approx(float(lon), abs=1e-9)
        assert info["headingVessel_deg"] == pytest.approx(float(frame.true_heading(0, 0, math.cos(yaw), math.sin(yaw))),
                                                          abs=0.01)
        assert dg["rxInfo"]["numSoundingsMaxMain"] == n_beams and dg["rxInfo"]["numSoundingsValidMain"] == 6
        snd = dg["sounding"]
        assert snd["detectionType"] == [0] * 6 + [2] * 2
        depth = np.array(snd["z_reRefPoint_m"][:6]) - info["z_waterLevelReRefPoint_m"]
        assert np.allclose(depth, -s["z"][rows], atol=1e-4)
        assert np.allclose(snd["y_reRefPoint_m"][:6], -across[rows], atol=1e-4)     # starboard +
        assert np.allclose(snd["x_reRefPoint_m"][:6], 0.0, atol=1e-4)
        assert np.allclose(snd["twoWayTravelTime_sec"][:6], 2 * s["range"][rows] / 1500.0, rtol=1e-6)
        assert np.allclose(snd["detectionUncertaintyVer_m"][:6], 0.05)
        slon, slat = frame.to_lonlat(s["x"][rows], s["y"][rows])
        assert np.allclose(info["latitude_deg"] + np.array(snd["deltaLatitude_deg"][:6]), slat, atol=1e-7)
        assert np.allclose(info["longitude_deg"] + np.array(snd["deltaLongitude_deg"][:6]), slon, atol=1e-7)
