"""A `Scan`'s ``data`` may be uint8, uint16 or uint32 (a 16- or 32-bit A/D's codes): every consumer
takes the wider codes as the same levels (plots, side-scan products, ROS 2 messages, live
pictures, the Oculus log, XTF) or, where the head sends bytes only (the Micron and Ping360
virtual heads), refuses them in one line."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mitsonar.geometry.frames import bearing_rotation, sidescan_rotation
from mitsonar.receiver.electronics import Electronics
from mitsonar.scan import Scan
from mitsonar.scan.model import data_as, data_bytes, require_bytes

WIDE = [(np.uint16, 257), (np.uint32, 16843009)]      # a byte b is the code b x this on that A/D


def levels(shape, seed=0):
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def wide(data, dtype):
    """The codes of a wider A/D for the bytes ``data``: the same levels, ``b x 257`` (16 bits),
    ``b x 16843009`` (32 bits)."""
    return data.astype(np.uint64).astype(dtype) * dtype(np.iinfo(dtype).max // 255)


def scan_of(data, kind="mechanical"):
    n, m = data.shape
    if kind == "sidescan":
        channel = np.repeat([0, 1], n // 2)
        poses = sidescan_rotation(channel, math.radians(10.0))
        poses[:, :3, 3] = np.c_[np.tile(np.arange(n // 2) * 0.3, 2), np.zeros(n), np.full(n, -8.0)]
        return Scan(intensity=np.zeros((n, m), np.float32), data=data, ranges=1.0 + (np.arange(m) + 0.5) * 0.5,
                    bearings=np.zeros(n), poses=poses, range_min=1.0, range_max=1.0 + 0.5 * m, kind="sidescan",
                    beamwidth_h=1.0, beamwidth_v=50.0, times=np.tile(np.arange(n // 2) * 0.2, 2),
                    meta={"side": "both", "frequency": 450e3, "ping_period": 0.2, "depression": 10.0},
                    electronics=Electronics(bit_depth=8 * data.itemsize).to_dict())
    step = 2 * math.pi / n if kind == "mechanical" else math.radians(1.0)
    b = (np.arange(n) - (0 if kind == "mechanical" else (n - 1) / 2)) * step
    return Scan(intensity=np.zeros((n, m), np.float32), data=data, ranges=(np.arange(m) + 0.5) * 0.1,
                bearings=b, poses=np.eye(4) @ bearing_rotation(b), range_min=0.0, range_max=m * 0.1, kind=kind,
                beamwidth_h=math.degrees(step), sound_speed=1500.0,
                electronics=Electronics(bit_depth=8 * data.itemsize).to_dict())


# ---- the helpers ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_wide_codes_are_the_same_levels_as_bytes(dtype, per_byte):
    b = np.arange(256, dtype=np.uint8)
    codes = wide(b, dtype)
    assert np.array_equal(codes.astype(np.uint64), b.astype(np.uint64) * per_byte)
    assert np.array_equal(data_bytes(codes), b) and data_bytes(codes).dtype == np.uint8
    assert np.array_equal(data_as(b, dtype), codes)
    # between the bytes' levels: to the nearest byte, halves up
    top = np.iinfo(dtype).max
    x = np.random.default_rng(1).random(1000)
    fine = np.round(x * top).astype(dtype)
    assert np.array_equal(data_bytes(fine), np.floor(x * 255 + 0.5).astype(np.uint8))
    assert scan_of(wide(levels((8, 5)), dtype)).data_full_scale == top


# ---- plots ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_a_fan_plot_of_wide_data_spans_its_codes(dtype, per_byte):
    from mitsonar.products.plots import plot_ascan, plot_polar
    data = levels((36, 10))
    data[0, 0] = 255
    scan = scan_of(wide(data, dtype))
    top = np.iinfo(dtype).max
    fig = plot_polar(scan, resolution=60)
    im = fig.axes[0].images[0]
    assert im.get_clim() == (0.0, top)
    assert fig.axes[-1].get_ylabel() == f"device output (0..{top})"
    e = Electronics().to_dict()
    im = plot_polar(scan, db=True, resolution=60).axes[0].images[0]
    lo, hi = e["ad_low"], e["ad_low"] + e["ad_span"]
    assert im.get_clim() == pytest.approx((lo, hi))
    assert np.nanmax(im.get_array()) == pytest.approx(hi)          # full scale at the A/D window's top
    ax2 = plot_ascan(scan, 0).axes[-1]
    assert ax2.get_ylim()[1] == pytest.approx(top * 260 / 255) and ax2.get_ylabel() == f"device output (0..{top})"


# ---- side-scan products ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_side_scan_products_of_wide_data_are_on_the_bytes_scale(dtype, per_byte):
    from mitsonar.products.mosaic import mosaic
    from mitsonar.products.sidescan import ground_range, waterfall
    data = levels((10, 40))
    narrow, wider = scan_of(data, "sidescan"), scan_of(wide(data, dtype), "sidescan")
    np.testing.assert_allclose(waterfall(wider), waterfall(narrow), rtol=1e-12, equal_nan=True)
    g8, gw = ground_range(narrow, altitude=8.0), ground_range(wider, altitude=8.0)
    np.testing.assert_allclose(gw.values, g8.values, rtol=1e-12, equal_nan=True)
    m8, mw = mosaic([narrow], 0.5, altitude=8.0), mosaic([wider], 0.5, altitude=8.0)
    np.testing.assert_allclose(mw.image, m8.image, rtol=1e-12, equal_nan=True)
    assert np.nanmax(mw.image) <= 255.0


# ---- ROS 2 messages (bags) ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_ros_images_of_wide_data_are_mono16_and_the_sonar_image_keeps_its_codes(dtype, per_byte):
    from mitsonar.export.ros import messages as M
    from mitsonar.export.ros.bag import check_scan
    data = levels((16, 12))
    data[3, 4] = 255
    scan = scan_of(wide(data, dtype), "multibeam")
    check_scan(scan)                                    # allowed: uint8, uint16, uint32
    w = M.waterfall(scan, 0)
    assert (w["encoding"], w["step"], w["is_bigendian"]) == ("mono16", 2 * 12, 0)
    np.testing.assert_array_equal(np.frombuffer(w["data"], "<u2").reshape(16, 12), wide(data, np.uint16))
    f = M.fan_image(scan, 0, size=50)
    assert f["encoding"] == "mono16"
    fan8 = M.fan_pixels(scan_of(data, "multibeam"), 50)
    np.testing.assert_array_equal(np.frombuffer(f["data"], "<u2").reshape(fan8.shape), wide(fan8, np.uint16))
    p = M.projected_image(scan, list(range(16)), 0)
    assert p["image"]["dtype"] == {np.uint16: 2, np.uint32: 4}[dtype]
    np.testing.assert_array_equal(np.frombuffer(p["image"]["data"], np.dtype(dtype).newbyteorder("<")),
                                  scan.data.T.ravel())
    pts, lv = M.detections(scan, 200)
    pts8, lv8 = M.detections(scan_of(data, "multibeam"), 200)
    np.testing.assert_allclose(lv, lv8) and np.testing.assert_allclose(pts, pts8)
    assert len(lv) and lv.max() == 255.0


# ---- live pictures and the Foxglove ping ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_live_pictures_of_wide_data_are_the_same_bytes(dtype, per_byte):
    import base64

    from mitsonar.live.outputs.messages import ping_message
    from mitsonar.live.outputs.pictures import Pictures
    # codes between the bytes' levels (a byte times 257 would wrap to itself modulo 256)
    x = np.random.default_rng(2).random((36, 10))
    data = np.floor(x * 255 + 0.5).astype(np.uint8)
    codes = np.round(x * np.iinfo(dtype).max).astype(dtype)
    for kind in ("mechanical", "multibeam"):
        narrow, wider = scan_of(data, kind), scan_of(codes, kind)
        a, b = Pictures(size=60).of(narrow), Pictures(size=60).of(wider)
        assert b.dtype == np.uint8 and a.any()
        np.testing.assert_array_equal(b, a)
    got = base64.b64decode(ping_message(0, wider)["intensities"])
    assert got == base64.b64decode(ping_message(0, narrow)["intensities"])


# ---- heads that send bytes only ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_the_micron_and_ping360_virtual_heads_refuse_wide_data_in_one_line(dtype, per_byte):
    from mitsonar.devices.micron.virtual import VirtualMicron
    from mitsonar.devices.ping360.virtual import VirtualPing360
    scan = scan_of(wide(levels((36, 10)), dtype))
    name = np.dtype(dtype).name
    with pytest.raises(ValueError, match=rf"^VirtualMicron 'data': '{name}' is not allowed \(a Micron sends 8- or "
                                         rf"4-bit samples: uint8 data.*bit_depth 8 \(or 4\), not {8 * scan.data.itemsize}\)$"):
        VirtualMicron(scan)
    with pytest.raises(ValueError, match=rf"^VirtualPing360 'data': '{name}' is not allowed \(a Ping360 sends 8-bit"):
        VirtualPing360(scan)
    VirtualPing360(scan_of(levels((36, 10))))            # bytes: served
    with pytest.raises(ValueError, match="'data'"):
        require_bytes(scan, "a head", "it sends bytes")


def test_a_micron_scan_source_of_wide_data_is_refused_and_counted():
    from mitsonar.devices.micron.seanet import HeadSettings
    from mitsonar.devices.micron.virtual import VirtualMicron
    head = VirtualMicron(lambda settings: scan_of(wide(levels((36, 10)), np.uint16)), realtime=False)
    head._accept(0.0, HeadSettings(range=1.0, n_bins=10).head_command())
    assert head.stats["scan source errors"] == 1 and head.scan is None
    assert "'data': 'uint16' is not allowed" in str(head.last_error)


# ---- the Oculus log ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_an_oculus_ping_of_wide_data_carries_its_codes(tmp_path, dtype, per_byte):
    from mitsonar.devices.oculus.logfile import read_log, scan_to_ping, write_log
    from mitsonar.devices.oculus.protocol import decode
    data = levels((256, 20))
    scan = scan_of(wide(data, dtype), "multibeam")
    p = scan_to_ping(scan)
    assert p.fire.data_bytes == np.dtype(dtype).itemsize and p.image.dtype == dtype
    back = decode(p.encode())
    np.testing.assert_array_equal(back.image, scan.data.T)
    path = write_log(tmp_path / "wide.oculus", [p])
    (_, (_, got)), = [(h, r) for h, recs in [read_log(path)] for r in recs]
    np.testing.assert_array_equal(got.image, scan.data.T)
    if dtype == np.uint32:
        with pytest.raises(ValueError, match="32-bit data .*version 2"):
            scan_to_ping(scan, version=1)


# ---- XTF ----

@pytest.mark.parametrize("dtype, per_byte", WIDE)
def test_xtf_of_wide_data_holds_its_codes(tmp_path, dtype, per_byte):
    pytest.importorskip("pyproj", reason="georeferencing needs pyproj (the geo extra)")
    pyxtf = pytest.importorskip("pyxtf", reason="pyxtf (the test extra) reads XTF")
    from mitsonar.export.xtf import XTFError, write_xtf
    from mitsonar.geometry.geodesy import GeoFrame
    frame = GeoFrame.make((52.0, 4.5, 0.0))
    scan = scan_of(wide(levels((10, 40)), dtype), "sidescan")
    path = tmp_path / "wide.xtf"
    assert write_xtf(path, [scan], frame) == 5
    fh, packets = pyxtf.xtf_read(str(path))
    assert fh.ChanInfo[0].BytesPerSample == np.dtype(dtype).itemsize
    for k, p in enumerate(packets[pyxtf.XTFHeaderType.sonar]):
        assert p.data[0].dtype == dtype
        np.testing.assert_array_equal(p.data[0], scan.data[k])
        np.testing.assert_array_equal(p.data[1], scan.data[5 + k])
    with pytest.raises(XTFError, match="the scans' data are .*uint8.*allowed: one type in a file"):
        write_xtf(tmp_path / "mixed.xtf", [scan, scan_of(levels((10, 40)), "sidescan")], frame)
    assert not (tmp_path / "mixed.xtf").exists()
