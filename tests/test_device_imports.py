"""Where the serial-device names live after the split, and the old paths that still work."""
from __future__ import annotations

import importlib
import warnings

import pytest

import mitsonar

MOVED = {"RawLogWriter": "mitsonar.devices.rawlog", "read_log": "mitsonar.devices.rawlog", "LOG_MAGIC": "mitsonar.devices.rawlog",
         "LogDamageWarning": "mitsonar.devices.rawlog", "RX": "mitsonar.devices.rawlog", "TX": "mitsonar.devices.rawlog",
         "POSE": "mitsonar.devices.rawlog", "ScanAssembler": "mitsonar.devices.micron.assembler",
         "beam_rotation": "mitsonar.devices.micron.assembler", "replay": "mitsonar.devices.recording"}


@pytest.mark.parametrize("name,home", sorted(MOVED.items()))
def test_old_micron_paths_still_work_and_warn(name, home):
    import mitsonar.devices.micron.driver as micron
    with pytest.warns(DeprecationWarning, match=rf"mitsonar\.devices\.micron\.driver\.{name} moved to {home}"):
        old = getattr(micron, name)
    assert old is getattr(importlib.import_module(home), name)


def test_from_import_of_an_old_path_warns():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        from mitsonar.devices.micron.driver import LOG_MAGIC, replay  # noqa: F401  (map_cli's import line)
    assert [(w.category, str(w.message).split(":")[0]) for w in caught] == [
        (DeprecationWarning, "mitsonar.devices.micron.driver.LOG_MAGIC moved to mitsonar.devices.rawlog"),
        (DeprecationWarning, "mitsonar.devices.micron.driver.replay moved to mitsonar.devices.recording")]


def test_driver_names_and_new_homes_import_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from mitsonar.devices.micron.assembler import ScanAssembler, beam_rotation  # noqa: F401
        from mitsonar.devices.micron.driver import MicronSonar, SonarError, SonarTimeout, record  # noqa: F401
        from mitsonar.devices.rawlog import LOG_MAGIC, LogDamageWarning, RawLogWriter, read_log  # noqa: F401
        from mitsonar.devices.recording import replay  # noqa: F401
        from mitsonar.devices.micron.seanet import HeadData, HeadSettings, StreamParser, decode, encode  # noqa: F401
        from mitsonar.devices.transports import check_port  # noqa: F401
        from mitsonar.devices.micron.virtual import VirtualMicron, check_port as vcheck  # noqa: F401
        for name in ("MicronSonar", "VirtualMicron", "HeadSettings", "StreamParser", "record", "replay"):
            assert getattr(mitsonar, name) is not None
    assert mitsonar.replay is replay and mitsonar.record is record and mitsonar.HeadSettings is HeadSettings


def test_seanet_package_gathers_its_submodules():
    from mitsonar.devices.micron import seanet as sn
    for name in sn.__all__:
        assert getattr(sn, name) is not None
    from mitsonar.devices.micron.seanet import messages, settings, stream
    assert sn.HeadSettings is settings.HeadSettings and sn.StreamParser is stream.StreamParser
    assert sn.HeadData is messages.HeadData
    with pytest.raises(AttributeError, match="mitsonar.devices.micron.driver"):
        sn.SonarError
