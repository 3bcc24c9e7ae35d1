"""Scan files: exact round trips through .exr and .npz, and clear errors for bad files."""
import dataclasses
import json
import math
import os
import zlib

import numpy as np
import OpenEXR
import pytest

from mitsonar.electronics import Electronics
from mitsonar.io import ScanFileError, load_scan, save_scan
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
        elif f.name == "meta":  # holds numpy arrays, whose == is elementwise
            assert deep_equal(x, y), f.name
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
    assert back.electronics["noise_floor"] == -math.inf
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
    with OpenEXR.File(saved[".exr"], header_only=True) as f:
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
