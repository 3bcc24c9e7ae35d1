"""Scan files: exact round trips through .exr and .npz, and clear errors for bad files."""
import dataclasses
import json
import math
import os
import zlib

import numpy as np
import OpenEXR
import pytest

from mitsonar.receiver.electronics import Electronics
from mitsonar.scan.io import ScanFileError, load_scan, save_scan
from mitsonar.scan import Scan


def make_scan(bit_depth=8, n_pings=7, n_bins=33, seed=0):
    rng = np.random.default_rng(seed)
    inten = (10.0 ** rng.uniform(-12, -2, (n_pings, n_bins))).astype(np.float32)
    inten[0, :4] = [0.0, np.finfo(np.float32).tiny, np.float32(1e-45), np.finfo(np.float32).max]
    if bit_depth == 8:
        data = rng.integers(0, 256, (n_pings, n_bins))
    else:
        data = 17 * rng.integers(0, 16, (n_pings, n_bins))
    ranges = 0.1 + (np.arange(n_bins) + 0.5) * (11.9 / n_bins)  # values float32 cannot hold
    bearings = np.radians(0.3 + 1.8 * np.arange(n_pings))
    poses = np.tile(np.eye(4), (n_pings, 1, 1))
    for k, b in enumerate(bearings):
        c, s = math.cos(b), math.sin(b)
        poses[k, :3, :3] = [[0.0, s, c], [0.0, -c, s], [1.0, 0.0, 0.0]]
        poses[k, :3, 3] = [0.1 * k, 1 / 3, -2.0 / 7]
    elec = {**Electronics(bit_depth=bit_depth, noise_floor=-math.inf).to_dict(), "seed": 12345}
    meta = {"scene": "box.xml", "seed": 0, "spp": 4096, "mitsonar_version": "0.1.0", "note": "ünïcode ✓",
            "nested": {"list": [1, 2.5, None, True], "tuple": (0.1, "a"), "big": 2 ** 62},
            "weights": np.linspace(0, 1, 5, dtype=np.float32), "n": np.int64(-3), "x": np.float32(0.1),
            "flag": False}
    return Scan(intensity=inten, data=data, ranges=ranges, bearings=bearings, poses=poses,
                range_min=0.1, range_max=12.0, beam_pattern="sinc", beamwidth_h=2.9, beamwidth_v=35.1,
                kind="mechanical", sound_speed=1487.3, absorption=0.0217, electronics=elec, meta=meta)


def deep_equal(a, b):
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return type(a) is type(b) and a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(deep_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(deep_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return type(a) is type(b) and a == b


def assert_same_scan(a, b):
    for f in dataclasses.fields(Scan):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y), f.name
        elif f.name == "meta":  # a ScanMeta holding numpy arrays, whose == is elementwise
            assert type(x) is type(y) and deep_equal(x.to_dict(), y.to_dict()), f.name
        else:
            assert x == y and deep_equal(x, y), f.name


@pytest.mark.parametrize("ext", [".exr", ".npz"])
@pytest.mark.parametrize("bit_depth", [8, 4])
def test_round_trip_is_exact(tmp_path, ext, bit_depth):
    scan = make_scan(bit_depth)
    path = tmp_path / f"scan{ext}"
    scan.save(path)
    back = load_scan(path)
    assert_same_scan(scan, back)
    assert back.electronics.noise_floor == -math.inf
    assert back.data.dtype == np.uint8 and back.intensity.dtype == np.float32
    assert sorted(os.listdir(tmp_path)) == [f"scan{ext}"]  # no temporary file left behind


def test_exr_layout_is_documented(tmp_path):
    scan = make_scan()
    path = str(tmp_path / "scan.exr")
    save_scan(scan, path)
    with OpenEXR.File(path, separate_channels=True) as f:  # the binding clears all on exit: copy
        ch = {k: np.array(v.pixels) for k, v in f.channels().items()}
        head = json.loads(f.header()["mitsonar"])
    assert ch["intensity"].dtype == np.float32 and ch["intensity"].shape == (7, 33)
    assert ch["data"].dtype == np.uint32
    assert np.array_equal(ch["data"], scan.data)
    assert head["format"] == "mitsonar-scan" and head["version"] == 1
    assert head["ranges"] == scan.ranges.tolist()


def test_mitsonar_load_scan_and_large_scan(tmp_path, mitsonar_mod):
    scan = make_scan(n_pings=200, n_bins=500)
    for ext in (".exr", ".npz"):
        path = tmp_path / f"big{ext}"
        scan.save(str(path))
        assert_same_scan(scan, mitsonar_mod.load_scan(path))


# ------------------------------------------------------------------------------------------------
# errors

@pytest.fixture
def saved(tmp_path):
    scan = make_scan()
    paths = {}
    for ext in (".exr", ".npz"):
        paths[ext] = str(tmp_path / f"good{ext}")
        save_scan(scan, paths[ext])
    return paths


def _expect_error(path, *words):
    with pytest.raises(ScanFileError) as err:
        load_scan(path)
    msg = str(err.value)
    assert str(path) in msg
    for w in words:
        assert w in msg
    assert "\n" not in msg
    return msg


def test_error_is_a_value_error():
    assert issubclass(ScanFileError, ValueError)


@pytest.mark.parametrize("ext", [".exr", ".npz"])
@pytest.mark.parametrize("fraction", [0.1, 0.5, 0.98])
def test_truncated_file(saved, tmp_path, ext, fraction):
    raw = open(saved[ext], "rb").read()
    bad = tmp_path / f"cut{ext}"
    bad.write_bytes(raw[:max(8, int(len(raw) * fraction))])
    _expect_error(bad)


@pytest.mark.parametrize("ext", [".exr", ".npz"])
def test_random_bytes(tmp_path, ext):
    bad = tmp_path / f"noise{ext}"
    bad.write_bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    _expect_error(bad, "not a")


@pytest.mark.parametrize("ext", [".exr", ".npz"])
def test_flipped_bytes_never_give_a_silent_wrong_scan(saved, tmp_path, ext):
    raw = bytearray(open(saved[ext], "rb").read())
    scan = load_scan(saved[ext])
    rng = np.random.default_rng(1)
    for trial in range(20):
        b = bytearray(raw)
        b[int(rng.integers(8, len(b)))] ^= 1 << int(rng.integers(0, 8))
        path = tmp_path / f"flip{trial}{ext}"
        path.write_bytes(bytes(b))
        try:
            back = load_scan(path)
        except ScanFileError:
            continue
        assert_same_scan(scan, back)  # a flip in padding or an unused field is harmless


def test_foreign_exr(tmp_path):
    path = str(tmp_path / "photo.exr")
    rgb = np.zeros((4, 5, 3), np.float32)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGB": rgb}) as f:
        f.write(path)
    _expect_error(path, "not a mitsonar scan")


def _rewrite_exr(src, dst, header_text=None, drop=None, tamper=None):
    with OpenEXR.File(src, separate_channels=True) as f:
        header = dict(f.header())
        channels = {k: np.array(v.pixels) for k, v in f.channels().items()}
    text = header["mitsonar"] if header_text is None else header_text
    if drop:
        channels.pop(drop)
    if tamper:
        channels[tamper] = channels[tamper].copy()
        channels[tamper][0, 0] += 1
    crc = f"{zlib.crc32(text.encode()):08x}"
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, "mitsonar": text,
                       "mitsonar_crc32": crc}, channels) as f:
        f.write(dst)


def test_missing_channel(saved, tmp_path):
    dst = str(tmp_path / "nodata.exr")
    _rewrite_exr(saved[".exr"], dst, drop="data")
    _expect_error(dst, "channel 'data' is missing")


def test_tampered_pixels_fail_the_checksum(saved, tmp_path):
    dst = str(tmp_path / "tampered.exr")
    _rewrite_exr(saved[".exr"], dst, tamper="intensity")
    _expect_error(dst, "checksum")


def test_bad_header(saved, tmp_path):
    # the whole file, not header_only=True: OpenEXR 3.3.0 (the floor) opens no part with it
    with OpenEXR.File(saved[".exr"]) as f:
        good = json.loads(f.header()["mitsonar"])
    cases = {"json.exr": ("{not json", "not valid JSON"),
             "marker.exr": (json.dumps({**good, "format": "other"}), "not a mitsonar scan"),
             "future.exr": (json.dumps({**good, "version": 99}), "newer mitsonar"),
             "lacks.exr": (json.dumps({k: v for k, v in good.items() if k != "poses"}), "poses"),
             "size.exr": (json.dumps({**good, "n_bins": 3}), "header says")}
    for name, (text, words) in cases.items():
        dst = str(tmp_path / name)
        _rewrite_exr(saved[".exr"], dst, header_text=text)
        _expect_error(dst, words)


def test_header_edited_without_its_checksum(saved, tmp_path):
    with OpenEXR.File(saved[".exr"], separate_channels=True) as f:
        header = dict(f.header())
        channels = {k: np.array(v.pixels) for k, v in f.channels().items()}
    header["mitsonar"] = header["mitsonar"].replace('"sound_speed":1487.3', '"sound_speed":1487.4')
    dst = str(tmp_path / "edited.exr")
    with OpenEXR.File(header, channels) as f:
        f.write(dst)
    _expect_error(dst, "checksum")


def test_foreign_and_pickled_npz(tmp_path):
    foreign = tmp_path / "other.npz"
    np.savez(foreign, a=np.arange(3))
    _expect_error(foreign, "not a mitsonar scan")
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, header=np.array([{"x": 1}], dtype=object), intensity=np.zeros((1, 1)), data=np.zeros((1, 1)),
             ranges=np.zeros(1), bearings=np.zeros(1), poses=np.zeros((1, 4, 4)))
    _expect_error(pickled)


def test_missing_file_and_wrong_extension(tmp_path):
    _expect_error(tmp_path / "absent.exr", "no such file")
    other = tmp_path / "scan.png"
    other.write_bytes(b"\x89PNG....")
    _expect_error(other, "extension")
    with pytest.raises(ScanFileError, match="extension"):
        save_scan(make_scan(), tmp_path / "scan.txt")
    exr_named_npz = tmp_path / "swapped.npz"
    save_scan(make_scan(), tmp_path / "x.exr")
    exr_named_npz.write_bytes((tmp_path / "x.exr").read_bytes())
    _expect_error(exr_named_npz, "not a numpy .npz file")


def test_unstorable_metadata_is_refused_before_writing(tmp_path):
    scan = make_scan()
    scan.meta["when"] = object()
    with pytest.raises(ScanFileError, match=r"meta\['when'\]"):
        save_scan(scan, tmp_path / "scan.exr")
    scan.meta = {1: "x"}
    with pytest.raises(ScanFileError, match="not a string"):
        save_scan(scan, tmp_path / "scan.npz")
    assert os.listdir(tmp_path) == []


def test_saved_files_get_the_usual_permissions(tmp_path):
    import stat

    umask = os.umask(0o022)
    try:
        for name in ("a.exr", "a.npz"):
            save_scan(make_scan(), tmp_path / name)
            assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644
    finally:
        os.umask(umask)


# ------------------------------------------------------------------------------------------------
# field values: checked by Scan, and so by load_scan and save_scan

def _scan_fields(**change):
    scan = make_scan()
    fields = {f.name: getattr(scan, f.name) for f in dataclasses.fields(Scan)}
    return {**fields, **change}


def _with(array, index, value):
    array = np.array(array)
    array[index] = value
    return array


BAD_FIELDS = {  # field: (value, words the message must hold)
    "sound_speed": ("fast", ["'fast' is not a number"]),
    "absorption": (-0.1, ["-0.1 is not allowed", ">= 0 dB/m"]),
    "beamwidth_h": (math.nan, ["nan is not allowed", "(0, 360] deg"]),
    "range_min": (50.0, ["'range_max'", "range_min = 50"]),
    "kind": ("fanbeam", ["'fanbeam' is not allowed", "one of mechanical, multibeam, sidescan"]),
    "beam_pattern": (3, ["not a pattern name"]),
    "bearings": (lambda s: _with(s.bearings, 2, math.nan), ["nan at index 2", "finite values only"]),
    "poses": (lambda s: _with(s.poses, (4, 0, 0), 5.0), ["pose 4 is not allowed", "rigid"]),
    "ranges": (lambda s: _with(s.ranges, 0, 0.05), ["0.05 at index 0", "window [0.1, 12] m"]),
    "intensity": (lambda s: _with(s.intensity, (1, 2), math.nan), ["nan at index (1, 2)", "finite"]),
    "data": (lambda s: _with(s.data.astype(float), 0, 3.5), ["3.5", "integers 0 to 255"]),
}


@pytest.mark.parametrize("name", sorted(BAD_FIELDS))
def test_scan_refuses_a_bad_field(name):
    value, words = BAD_FIELDS[name]
    if callable(value):
        value = value(make_scan())
    with pytest.raises(ValueError) as err:
        Scan(**_scan_fields(**{name: value}))
    msg = str(err.value)
    assert msg.startswith("Scan '") and all(w in msg for w in words), msg


def test_scan_refuses_negative_intensity_and_wrong_shapes():
    scan = make_scan()
    with pytest.raises(ValueError, match=r"Scan 'intensity': -1.0 at index \(0, 0\) is not allowed \(echo energy >= 0\)"):
        Scan(**_scan_fields(intensity=_with(scan.intensity, (0, 0), -1.0)))
    with pytest.raises(ValueError, match=r"Scan 'ranges': shape \(32,\) is not \(n_bins,\) = \(33,\)"):
        Scan(**_scan_fields(ranges=scan.ranges[:-1]))
    with pytest.raises(ValueError, match=r"Scan 'bearings': an array of <U1 is not allowed \(numbers only\)"):
        Scan(**_scan_fields(bearings=["a"] * scan.n_pings))


def test_scans_from_devices_and_float32_poses_are_accepted():
    scan = make_scan()
    # Bytes given as ints, poses rounded to float32 (as a navigation log may hold them).
    back = Scan(**_scan_fields(data=scan.data.astype(np.int64), poses=scan.poses.astype(np.float32),
                               range_min=0, kind="multibeam"))
    assert back.data.dtype == np.uint8 and np.array_equal(back.data, scan.data)


def _forge(src, dst, head_change=None, array_change=None):
    """Rewrite a saved scan with other content but valid checksums, as a foreign writer could."""
    if src.endswith(".exr"):
        with OpenEXR.File(src, separate_channels=True) as f:
            head = json.loads(f.header()["mitsonar"])
            arrays = {k: np.array(v.pixels) for k, v in f.channels().items()}
    else:
        with np.load(src) as z:
            arrays = {k: z[k] for k in z.files if k not in ("header", "header_crc32")}
            head = json.loads(str(z["header"]))
    head.update(head_change or {})
    for name, fn in (array_change or {}).items():
        arrays[name] = fn(arrays[name])
    head["checksums"] = {"intensity": zlib.crc32(arrays["intensity"].astype("<f4").tobytes()),
                         "data": zlib.crc32(arrays["data"].astype(np.uint8).tobytes())}
    text = json.dumps(head)
    if dst.endswith(".exr"):
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, "mitsonar": text,
                           "mitsonar_crc32": f"{zlib.crc32(text.encode()):08x}"}, arrays) as f:
            f.write(dst)
    else:
        np.savez(dst, **arrays, header=np.array(text), header_crc32=np.array(zlib.crc32(text.encode()), np.uint32))


def _scaled_pose(poses):
    poses = np.array(poses)
    poses[3, :3, :3] *= 2.0
    return poses


@pytest.mark.parametrize("ext", [".exr", ".npz"])
def test_file_with_bad_content_names_file_and_field(saved, tmp_path, ext):
    stored = "channel" if ext == ".exr" else "array"
    cases = [({"sound_speed": "fast"}, None, "header 'sound_speed': 'fast' is not a number"),
             ({"kind": "fanbeam"}, None, "header 'kind': 'fanbeam' is not allowed (one of mechanical, multibeam, sidescan, volumetric)"),
             ({"range_min": 50}, None, "header 'range_max': 12.0 is not allowed (a range > range_min = 50 m)"),
             ({"n_bins": -3}, None, "header 'n_bins': -3 is not allowed (a count >= 1)"),
             ({"n_pings": 7.0}, None, "header 'n_pings': 7.0 is not allowed (a count >= 1)"),
             (None, {"intensity": lambda a: _with(a, (0, 5), np.nan)},
              f"{stored} 'intensity': nan at index (0, 5) is not allowed (finite values only)")]
    if ext == ".exr":  # ranges, bearings and poses live in the header
        cases += [({"bearings": [math.nan] + [0.0] * 6}, None, "header 'bearings': nan at index 0"),
                  ({"poses": _scaled_pose(json.loads(json.dumps(load_scan(saved[ext]).poses.tolist()))).tolist()},
                   None, "header 'poses': pose 3 is not allowed (only rigid transforms"),
                  ({"ranges": [["x"]]}, None, "header 'ranges': an array of <U1 is not allowed (numbers only)")]
    else:
        cases += [(None, {"bearings": lambda a: _with(a, 0, np.nan)}, "array 'bearings': nan at index 0"),
                  (None, {"poses": _scaled_pose}, "array 'poses': pose 3 is not allowed (only rigid transforms")]
    for i, (head_change, array_change, words) in enumerate(cases):
        dst = str(tmp_path / f"bad{i}{ext}")
        _forge(saved[ext], dst, head_change, array_change)
        msg = _expect_error(dst, words)
        assert msg == f"{dst}: {words}" or msg.startswith(f"{dst}: {words}"), msg


def test_save_checks_fields_assigned_after_construction(tmp_path):
    scan = make_scan()
    scan.sound_speed = "fast"
    with pytest.raises(ScanFileError, match=r"scan\.exr: not saved: Scan 'sound_speed': 'fast' is not a number"):
        save_scan(scan, tmp_path / "scan.exr")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("ext", [".exr", ".npz"])
def test_directories_are_named_not_temporary_files(tmp_path, ext):
    folder = tmp_path / f"dir{ext}"
    folder.mkdir()
    _expect_error(folder, "is a directory")
    for target, words in ((folder, "is a directory"), (tmp_path / "missing" / f"scan{ext}", "does not exist")):
        with pytest.raises(ScanFileError) as err:
            save_scan(make_scan(), target)
        msg = str(err.value)
        assert msg.startswith(f"{target}: ") and words in msg and ".tmp-" not in msg, msg
    assert sorted(os.listdir(tmp_path)) == [f"dir{ext}"] and os.listdir(folder) == []


def test_exr_opens_in_opencv_as_the_intensity(tmp_path):
    """Every EXR scan also holds a FLOAT 'Y' channel equal to 'intensity': OpenCV's imread (which
    reads only R/G/B/Y channels) returns the intensity bit for bit; our reader ignores 'Y', and
    a file written before it (no 'Y') still loads."""
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless (the test extra) reads EXR")
    if "OpenEXR:                     NO" in cv2.getBuildInformation():
        pytest.skip("this OpenCV build has no OpenEXR codec (opencv-python-headless 5.0 wheels)")
    scan = make_scan()
    path = str(tmp_path / "scan.exr")
    save_scan(scan, path)
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = {k: np.array(v.pixels) for k, v in f.channels().items()}
    assert sorted(ch) == ["Y", "data", "intensity"] and ch["Y"].dtype == np.float32
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
    assert image is not None and image.dtype == np.float32 and image.shape == scan.intensity.shape
    assert np.array_equal(image, scan.intensity)
    assert_same_scan(scan, load_scan(path))
    old = os.path.join(os.path.dirname(__file__), "data", "old_levels_scan.exr")    # written without 'Y'
    assert load_scan(old).n_pings > 0
