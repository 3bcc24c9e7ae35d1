"""Old import paths of the renderer keep working for one release, with a DeprecationWarning that
names the new home (issue "Architecture"); the devices' are in test_device_imports.py."""
import warnings

import pytest


@pytest.mark.parametrize("module, name, home", [
    ("mitsonar.sim.render", "load_scene", "mitsonar.sim.scene"),
    ("mitsonar.sim.render", "set_variant", "mitsonar.sim.variant"),
    ("mitsonar.sim.render", "scene_mesh", "mitsonar.sim.groundtruth"),
    ("mitsonar.plugins.sonar_tof", "resolve_sensor", "mitsonar.plugins.common"),
    ("mitsonar.plugins.sonar_tof", "check_max_depth", "mitsonar.plugins.common"),
    ("mitsonar.plugins.echo_path", "HashSamples", "mitsonar.plugins.samples"),
    ("mitsonar.plugins.echo_path", "n_dims", "mitsonar.plugins.samples"),
])
def test_old_paths_warn_and_give_the_same_object(mitsonar_mod, module, name, home):
    import importlib

    with pytest.warns(DeprecationWarning, match=home.replace(".", r"\.")):
        old = getattr(importlib.import_module(module), name)
    assert old is getattr(importlib.import_module(home), name)


def test_trace_echoes_still_traces_the_same_paths(mitsonar_mod):
    """echo_path.trace_echoes, deprecated, runs the one path function with the same result."""
    import os

    import drjit as dr
    import mitsuba as mi
    import numpy as np

    from conftest import SCENES
    from mitsonar.plugins import module

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "box.xml"))
    integrator = mi.load_dict({"type": "sonar_tof", "max_depth": 2})
    setup = integrator.setup(scene, 0)
    n = 4096
    lane = dr.arange(mi.UInt32, n)
    ping = lane % 200
    samples = module("samples").HashSamples(mi.UInt32(3), ping, lane // 200)
    totals = []
    for call in ("new", "old"):
        energy = dr.zeros(mi.Float, n)

        def record(k, rng, e, valid, hit=None):
            dr.scatter_add(energy, e, lane, valid)

        if call == "new":
            integrator.sample(setup, ping, samples, record)
        else:
            ep = importlib_module("mitsonar.plugins.echo_path")
            with pytest.warns(DeprecationWarning):
                ep.trace_echoes(scene, setup.frames, setup.sensor.beam, ping, samples, setup.depth_o,
                                setup.absorption, record, connect=setup.connect)
        totals.append(np.asarray(energy))
    np.testing.assert_array_equal(totals[0], totals[1])
    assert totals[0].sum() > 0


def importlib_module(name):
    import importlib

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return importlib.import_module(name)


# The flat modules of mitsonar moved into packages by role: every old path imports, for one
# release, the same module object with a warning naming its new home; the public names stay
# without a warning.
from mitsonar._aliases import MOVED, PUBLIC  # noqa: E402


def _fresh(old):
    """Forget an old path's alias so that importing it runs the finder again."""
    import sys

    sys.modules.pop(old, None)
    parent, _, child = old.rpartition(".")
    if parent in sys.modules and child in vars(sys.modules[parent]):
        delattr(sys.modules[parent], child)  # an import set it on the package


@pytest.mark.parametrize("old", sorted(set(MOVED) - PUBLIC))
def test_old_module_paths_warn_and_give_the_same_module(old):
    import importlib

    new = f"mitsonar.{MOVED[old]}"
    _fresh(f"mitsonar.{old}")
    with pytest.warns(DeprecationWarning, match=rf"mitsonar\.{old} moved to {new}"):
        module = importlib.import_module(f"mitsonar.{old}")
    assert module is importlib.import_module(new)
    # the module keeps its own name and spec (pickling, reload and autodoc read them)
    assert module.__name__ == new and module.__spec__.name == new


def test_submodules_of_a_moved_package_follow_it():
    import importlib

    _fresh("mitsonar.seanet.messages")
    with pytest.warns(DeprecationWarning, match="mitsonar.devices.micron.seanet"):
        old = importlib.import_module("mitsonar.seanet.messages")
    assert old is importlib.import_module("mitsonar.devices.micron.seanet.messages")


def test_an_old_module_as_an_attribute_warns():
    import sys

    import mitsonar

    _fresh("mitsonar.trajectory")
    with pytest.warns(DeprecationWarning, match="mitsonar.geometry.trajectory"):
        module = mitsonar.trajectory
    assert module is sys.modules["mitsonar.geometry.trajectory"]


@pytest.mark.parametrize("old", sorted(PUBLIC))
def test_public_modules_import_under_their_names_without_a_warning(old):
    import importlib

    _fresh(f"mitsonar.{old}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        module = importlib.import_module(f"mitsonar.{old}")
        exec(f"from mitsonar import {old} as again", {})
    assert module is importlib.import_module(f"mitsonar.{MOVED[old]}")


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
