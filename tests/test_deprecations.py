"""Old import paths of the renderer keep working for one release, with a DeprecationWarning that
names the new home (issue "Architecture"); the devices' are in test_device_imports.py."""
import warnings

import pytest


@pytest.mark.parametrize("module, name, home", [
    ("mitsonar.sim.render", "load_scene", "mitsonar.sim.scene"),
    ("mitsonar.sim.render", "set_variant", "mitsonar.sim.variant"),
    ("mitsonar.sim.render", "scene_mesh", "mitsonar.sim.groundtruth"),
])
def test_old_paths_warn_and_give_the_same_object(mitsonar_mod, module, name, home):
    import importlib

    with pytest.warns(DeprecationWarning, match=home.replace(".", r"\.")):
        old = getattr(importlib.import_module(module), name)
    assert old is getattr(importlib.import_module(home), name)


# The flat module paths of 0.2 (``mitsonar.electronics``, ``mitsonar.seanet``, ...) are gone in
# 0.3 (no import hook answers for them); the four public names are small real modules.
PUBLIC = {"plots": "mitsonar.products.plots", "bathymetry": "mitsonar.products.bathymetry",
          "sidescan": "mitsonar.products.sidescan", "echosounders": "mitsonar.scenes.echosounders"}


@pytest.mark.parametrize("old", ["mitsonar.electronics", "mitsonar.seanet.messages", "mitsonar.frames",
                                 "mitsonar.dataset.cli",
                                 # the flat plugin modules (internal) are gone since the plugins
                                 # live by family (sensors/, bsdfs/, integrators/)
                                 "mitsonar.plugins.sonar_tof", "mitsonar.plugins.sonar_sensor",
                                 "mitsonar.plugins.acoustic_bsdf", "mitsonar.plugins.common",
                                 "mitsonar.plugins.echo_path", "mitsonar.plugins.exact_sum"])
def test_the_old_flat_module_paths_are_gone(old):
    import importlib

    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_public_modules_import_under_their_names_without_a_warning(name):
    import importlib

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        module = importlib.import_module(f"mitsonar.{name}")
        exec(f"from mitsonar import {name} as again", {})
    room = importlib.import_module(PUBLIC[name])
    assert module.__doc__ == room.__doc__ and module.__all__
    for n in module.__all__:
        assert getattr(module, n) is getattr(room, n), n


def test_the_public_names_need_no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from mitsonar import (Scan, Trajectory, load_scan, load_scene, open_dataset, render_scan,  # noqa: F401
                              render_survey, scene_mesh)
        from mitsonar.cli import main  # noqa: F401  (the console script)


def test_an_unknown_attribute_is_still_an_error():
    import mitsonar

    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        mitsonar.nothing_here


# ---- renamed names (issue 57 item 4: ``kind`` is the sonar kind only) ---------------------------
# Each row of mitsonar._moved.RENAMED keeps working under its old name, warning with the new one.

def test_every_renamed_name_is_tested_here():
    from mitsonar._moved import RENAMED

    assert set(RENAMED) == set(RENAMED_TESTS)


def _pulse_kind():
    from mitsonar.signals import cw

    with pytest.warns(DeprecationWarning, match=r"Pulse\.kind is now Pulse\.waveform; .* 0\.4\.0"):
        assert cw(1e5, 1e-4).kind == "cw"


def _pulse_kind_keyword():
    from mitsonar.signals import Pulse, lfm

    with pytest.warns(DeprecationWarning, match=r"Pulse\(kind=\.\.\.\) is now Pulse\(waveform=\.\.\.\)"):
        old = Pulse(kind="lfm", f_start=1e5, f_stop=1.2e5, duration=1e-3)
    assert old == lfm(1e5, 1.2e5, 1e-3) and old.waveform == "lfm"
    with pytest.raises(TypeError, match="both 'waveform' and its old name 'kind'"):
        Pulse(kind="cw", waveform="cw", f_start=1e5, f_stop=1e5, duration=1e-3)


def _plot_kinds():
    import mitsonar.kinds as kinds

    with pytest.warns(DeprecationWarning, match=r"SonarKind\.plot_kinds is now SonarKind\.pictures"):
        assert kinds.SIDESCAN.plot_kinds == ("waterfall", "ascan")
    with pytest.warns(DeprecationWarning, match=r"SonarKind\.plot_kinds is now SonarKind\.pictures"):
        class Old(kinds.Mechanical):      # a kind written with the old name
            name = "old_toy"
            plot_kinds = ("ascan",)
    assert Old().pictures == ("ascan",) and "plot_kinds" not in Old.__dict__


def _register_plugin_kind():
    import inspect

    from mitsonar.plugins.registry import register_plugin

    target = inspect.unwrap(register_plugin)
    assert list(inspect.signature(target).parameters)[0] == "family"
    with pytest.warns(DeprecationWarning, match=r"register_plugin\(kind=\.\.\.\) is now register_plugin\(family=\.\.\.\)"):
        with pytest.raises(ValueError, match="register_plugin 'family': 'nothing' is not allowed"):
            register_plugin(kind="nothing", name="toy", cls=object)   # reached the body as the family


def _rawlog_write_kind():
    import tempfile

    from mitsonar.devices.rawlog import RX, RawLogWriter, read_log

    with tempfile.TemporaryDirectory() as d:
        path = f"{d}/x.log"
        with RawLogWriter(path) as w:
            with pytest.warns(DeprecationWarning, match=r"RawLogWriter\.write\(kind=\.\.\.\) is now "
                                                        r"RawLogWriter\.write\(record_type=\.\.\.\)"):
                w.write(kind=RX, data=b"\x40abc")
            w.write(record_type=RX, data=b"\x40def")
        assert [(k, d) for _, k, d in read_log(path)[1]] == [(RX, b"\x40abc"), (RX, b"\x40def")]


def _cli_kind_flag():
    import contextlib
    import io

    from mitsonar.cli.main import build_parser, old_picture_flag

    args = build_parser().parse_args(["plot", "x.npz", "-o", "x.png", "--kind", "ascan"])
    err = io.StringIO()
    with pytest.warns(DeprecationWarning, match=r"--kind is now --picture; the old name is removed in mitsonar 0\.4\.0"):
        with contextlib.redirect_stderr(err):
            old_picture_flag(args)
    assert args.picture == "ascan"
    args = build_parser().parse_args(["plot", "x.npz", "-o", "x.png", "--kind", "ascan", "--picture", "polar"])
    with pytest.warns(DeprecationWarning), pytest.raises(Exception, match="--kind ascan: the old name of --picture"):
        old_picture_flag(args)


RENAMED_TESTS = {
    "Pulse.kind": _pulse_kind,
    "Pulse(kind=...)": _pulse_kind_keyword,
    "SonarKind.plot_kinds": _plot_kinds,
    "register_plugin(kind=...)": _register_plugin_kind,
    "RawLogWriter.write(kind=...)": _rawlog_write_kind,
    "mitsonar render/plot --kind": _cli_kind_flag,
}


@pytest.mark.parametrize("old", sorted(RENAMED_TESTS))
def test_an_old_name_still_works_with_a_warning_naming_the_new_one(old):
    RENAMED_TESTS[old]()
