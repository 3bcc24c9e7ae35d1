"""A wider A/D (electronics ``bit_depth`` 16 and 32): the same levels as the 8-bit chain on a wider
code range (the byte is the 16-bit code / 257 up to rounding), a Scan keeping uint16 and uint32
data through NPZ and EXR, and the virtual Oculus sending 16- and 32-bit images from that chain."""
import numpy as np
import pytest

from mitsonar.receiver.electronics import Electronics
from mitsonar.scan import Scan

RANGES = (np.arange(300) + 0.5) * 0.02


def echoes():
    return np.random.default_rng(0).exponential(1e-9, (20, 300))


@pytest.mark.parametrize("bits, dtype, per_byte", [(16, np.uint16, 257), (32, np.uint32, 16843009)])
def test_a_wider_ad_gives_the_same_levels_on_more_codes(bits, dtype, per_byte):
    d8 = Electronics().apply(echoes(), RANGES, seed=3)
    wide = Electronics(bit_depth=bits).apply(echoes(), RANGES, seed=3)
    assert d8.dtype == np.uint8 and wide.dtype == dtype
    # the same dB-to-code mapping on 2^bits - 1: the byte is the code / per_byte up to rounding
    back = np.round(wide / float(per_byte))
    assert np.abs(back - d8).max() <= 1 and np.mean(back == d8) > 0.99
    assert np.abs((wide >> (bits - 8)).astype(np.int64) - d8).max() <= 1        # the top byte
    # and finer: codes between the bytes' levels (not a byte times per_byte)
    assert np.any(wide % per_byte != 0)
    assert wide.max() == np.iinfo(dtype).max                                   # full scale reached
    assert np.array_equal(Electronics(bit_depth=bits).quantise([0.0, 12.5, 36.5, 80.0]),
                          np.array([0, 0, np.iinfo(dtype).max, np.iinfo(dtype).max], dtype))


def test_a_bad_bit_depth_is_refused_naming_the_widths():
    with pytest.raises(ValueError, match="bit_depth.*one of 8, 4, 16, 32"):
        Electronics(bit_depth=12)


def scan_of(data):
    n, m = data.shape
    return Scan(intensity=np.zeros((n, m), np.float32), data=data, ranges=(np.arange(m) + 0.5) * 0.1,
                bearings=np.zeros(n), poses=np.broadcast_to(np.eye(4), (n, 4, 4)).copy(), range_min=0.0,
                range_max=m * 0.1, kind="multibeam", sound_speed=1500.0,
                electronics={**Electronics(bit_depth=8 * data.itemsize).to_dict()})


@pytest.mark.parametrize("dtype", [np.uint16, np.uint32])
@pytest.mark.parametrize("ext", ["npz", "exr"])
def test_wide_data_round_trips_through_the_scan_files(tmp_path, dtype, ext):
    import mitsonar
    top = np.iinfo(dtype).max
    data = np.random.default_rng(1).integers(0, top, (4, 7), dtype=dtype, endpoint=True)
    data[0, 0] = top
    scan = scan_of(data)
    assert scan.data.dtype == dtype
    path = tmp_path / f"wide.{ext}"
    scan.save(str(path))
    back = mitsonar.load_scan(str(path))
    assert back.data.dtype == dtype
    np.testing.assert_array_equal(back.data, data)


def test_the_virtual_oculus_sends_wide_samples_from_the_receiver_chain(tmp_path):
    import mitsonar
    from mitsonar.devices.oculus.protocol import FireMessage
    from mitsonar.devices.oculus.virtual import VirtualOculus
    from test_oculus import WALL
    path = tmp_path / "wall.xml"
    path.write_text(WALL)
    scan = mitsonar.render_scan(mitsonar.load_scene(str(path)), spp=16, seed=0)
    head = VirtualOculus(scan, tcp_port=0, udp_port=None)
    img8 = head.ping(FireMessage(flags=0x0D, range=10.0)).image
    img16 = head.ping(FireMessage(flags=0x0F, range=10.0)).image
    img32 = head.ping(FireMessage(flags=0x0D, range=10.0, ext_flags=0x200)).image
    assert (img8.dtype, img16.dtype, img32.dtype) == (np.uint8, np.uint16, np.uint32)
    assert img8.any()
    for img, per_byte in ((img16, 257), (img32, 16843009)):
        back = np.round(img / float(per_byte))
        assert np.abs(back - img8).max() <= 1 and np.mean(back == img8) > 0.99
        assert np.any(img % per_byte != 0)          # finer levels than the byte's, not byte x per_byte
