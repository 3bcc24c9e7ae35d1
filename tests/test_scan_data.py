"""A `Scan` is data (issue 57 item 3): fields, checks, files and the migrations of old files, with
typed settings (`ElectronicsSettings`) and metadata (`ScanMeta`); its levels are functions of it in
`mitsonar.sonar_equation`, and `mitsonar.load_scan` is the one way to read a file."""
import ast
import json
import os
import warnings

import numpy as np
import pytest

import mitsonar
from mitsonar.receiver.electronics import Electronics
from mitsonar.scan import ElectronicsSettings, Scan, ScanFieldError, ScanMeta

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: What the Scan's folder must not import, even inside a function.
NOT_FROM_SCAN = ("mitsonar.sonar_equation", "mitsonar.plugins", "mitsonar.sim", "mitsonar.receiver",
                 "mitsuba", "drjit", "plugins")


def small_scan(**kw) -> Scan:
    n, m = 3, 4
    fields = dict(intensity=np.ones((n, m), np.float32), data=np.zeros((n, m), np.uint8),
                  ranges=np.arange(m) + 0.5, bearings=np.zeros(n), poses=np.tile(np.eye(4), (n, 1, 1)),
                  range_min=0.0, range_max=float(m))
    fields.update(kw)
    return Scan(**fields)


def test_the_scan_folder_imports_no_renderer_plugin_or_sonar_equation():
    bad = []
    folder = os.path.join(ROOT, "mitsonar", "scan")
    for name in sorted(os.listdir(folder)):
        if not name.endswith(".py"):
            continue
        tree = ast.parse(open(os.path.join(folder, name), encoding="utf-8").read())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module]
            else:
                continue
            bad += [(name, n) for n in names if any(n == p or n.startswith(p + ".") for p in NOT_FROM_SCAN)]
    assert bad == []


def test_the_old_level_properties_are_functions_of_the_scan():
    for name in ("echo_level", "directivity_index", "noise_band_level", "snr"):
        assert not hasattr(Scan, name)
    from mitsonar import sonar_equation

    scan = small_scan(meta={"directivity_index": 20.0}, electronics={"noise_level": 50.0, "pulse_length": 0.0,
                                                                     "receiver_bandwidth": 1e4})
    levels = sonar_equation.scan_levels(scan)
    assert sonar_equation.directivity_index(scan) == levels.directivity_index == 20.0
    assert levels.noise_band_level == pytest.approx(50.0 + 40.0 - 20.0)
    np.testing.assert_array_equal(sonar_equation.scan_echo_level(scan), levels.echo_level)
    np.testing.assert_allclose(levels.echo_level, 200.0, atol=1e-4)   # intensity 1 in a bin, SL 200 dB
    np.testing.assert_array_equal(sonar_equation.snr(scan), levels.snr)
    np.testing.assert_allclose(levels.snr, 200.0 - 70.0, atol=1e-4)


def test_electronics_are_typed_settings():
    scan = small_scan(electronics={"gain": 30.0, "bit_depth": 8, "seed": 7, "note": "mine"})
    e = scan.electronics
    assert isinstance(e, ElectronicsSettings)
    assert (e.gain, e.bit_depth, e.seed, e.ad_low, e.extra) == (30.0, 8, 7, None, {"note": "mine"})
    assert e.to_dict() == {"gain": 30.0, "bit_depth": 8, "seed": 7, "note": "mine"}
    # the receiver's fields, in its order (a new receiver setting is recorded under its own name)
    assert [f for f in ElectronicsSettings.__dataclass_fields__ if f not in ("seed", "extra")] == \
        list(Electronics.__dataclass_fields__)
    with pytest.raises(ScanFieldError, match=r"^Scan 'electronics': 'gain': 'high' is not allowed \(a number"):
        small_scan(electronics={"gain": "high"})
    with pytest.raises(ScanFieldError, match="'bit_depth': 8.5 is not allowed"):
        e.bit_depth = 8.5
    assert ElectronicsSettings.from_dict({"bandwidth": 1e4}).receiver_bandwidth == 1e4   # the old name


@pytest.mark.parametrize("ext", [".npz", ".exr"])
@pytest.mark.parametrize("settings", [{**Electronics().to_dict(), "seed": 3},          # render_scan's
                                      {"bit_depth": 4, "gain": 20.0, "ad_low": 10.0, "ad_span": 30.0},  # a Micron's
                                      {}])
def test_files_hold_the_settings_as_the_dict_era_wrote_them(tmp_path, ext, settings):
    """The header's electronics JSON is the dict's own, key for key and in order: the bytes of a
    file do not change with the typed settings, and a file read and written again is the same."""
    scan = small_scan(electronics=settings)
    path = tmp_path / f"s{ext}"
    scan.save(path)
    from mitsonar.scan import fileformat

    head = fileformat._header(scan, with_arrays=False, path=str(path))
    assert json.dumps(head["electronics"]) == json.dumps(settings)
    back = mitsonar.load_scan(path)
    assert list(back.electronics.to_dict().items()) == list(settings.items())
    again = tmp_path / f"again{ext}"
    back.save(again)
    assert again.read_bytes() == path.read_bytes()


def test_load_scan_is_the_one_way_and_scan_load_warns(tmp_path):
    from mitsonar.scan.io import load_scan

    assert mitsonar.load_scan is load_scan
    scan = small_scan(meta={"seed": 2})
    scan.save(tmp_path / "s.npz")
    with pytest.warns(DeprecationWarning, match=r"mitsonar\.load_scan"):
        old = Scan.load(tmp_path / "s.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = mitsonar.load_scan(tmp_path / "s.npz")
    assert old.meta == new.meta and isinstance(new.meta, ScanMeta) and new.meta.seed == 2


def test_records_replace_without_sharing_extra():
    meta = ScanMeta.from_dict({"seed": 1, "note": [1]})
    other = meta.replace(side="port", seed=None)
    assert other.to_dict() == {"side": "port", "note": [1]} and meta.to_dict() == {"seed": 1, "note": [1]}
    other.extra["more"] = 1
    assert "more" not in meta.extra
