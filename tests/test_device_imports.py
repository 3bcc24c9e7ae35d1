"""Where the serial-device names live after the split, and the old paths that still work."""
from __future__ import annotations

import importlib
import warnings

import pytest

import mitsonar

MOVED = {"RawLogWriter": "mitsonar.rawlog", "read_log": "mitsonar.rawlog", "LOG_MAGIC": "mitsonar.rawlog",
         "LogDamageWarning": "mitsonar.rawlog", "RX": "mitsonar.rawlog", "TX": "mitsonar.rawlog",
         "POSE": "mitsonar.rawlog", "ScanAssembler": "mitsonar.assembler",
         "beam_rotation": "mitsonar.assembler", "replay": "mitsonar.recording"}


@pytest.mark.parametrize("name,home", sorted(MOVED.items()))
def test_old_micron_paths_still_work_and_warn(name, home):
    import mitsonar.micron as micron
    with pytest.warns(DeprecationWarning, match=rf"mitsonar\.micron\.{name} moved to {home}"):
        old = getattr(micron, name)
    assert old is getattr(importlib.import_module(home), name)


def test_from_import_of_an_old_path_warns():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        from mitsonar.micron import LOG_MAGIC, replay  # noqa: F401  (map_cli's import line)
    assert [(w.category, str(w.message).split(":")[0]) for w in caught] == [
        (DeprecationWarning, "mitsonar.micron.LOG_MAGIC moved to mitsonar.rawlog"),
        (DeprecationWarning, "mitsonar.micron.replay moved to mitsonar.recording")]


def test_driver_names_and_new_homes_import_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from mitsonar.assembler import ScanAssembler, beam_rotation  # noqa: F401
        from mitsonar.micron import MicronSonar, SonarError, SonarTimeout, record  # noqa: F401
        from mitsonar.rawlog import LOG_MAGIC, LogDamageWarning, RawLogWriter, read_log  # noqa: F401
        from mitsonar.recording import replay  # noqa: F401
        from mitsonar.seanet import HeadData, HeadSettings, StreamParser, decode, encode  # noqa: F401
        from mitsonar.transports import check_port  # noqa: F401
        from mitsonar.virtual_sonar import VirtualMicron, check_port as vcheck  # noqa: F401
        for name in ("MicronSonar", "VirtualMicron", "HeadSettings", "StreamParser", "record", "replay"):
            assert getattr(mitsonar, name) is not None
    assert mitsonar.replay is replay and mitsonar.record is record and mitsonar.HeadSettings is HeadSettings


def test_seanet_package_gathers_its_submodules():
    from mitsonar import seanet as sn
    for name in sn.__all__:
        assert getattr(sn, name) is not None
    from mitsonar.seanet import messages, settings, stream
    assert sn.HeadSettings is settings.HeadSettings and sn.StreamParser is stream.StreamParser
    assert sn.HeadData is messages.HeadData
    with pytest.raises(AttributeError, match="mitsonar.micron"):
        sn.SonarError
