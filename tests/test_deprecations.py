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


# The flat module paths of 0.2 (``mitsonar.electronics``, ``mitsonar.seanet``, ...) are gone in
# 0.3 (no import hook answers for them); the four public names are small real modules.
PUBLIC = {"plots": "mitsonar.products.plots", "bathymetry": "mitsonar.products.bathymetry",
          "sidescan": "mitsonar.products.sidescan", "echosounders": "mitsonar.scenes.echosounders"}


@pytest.mark.parametrize("old", ["mitsonar.electronics", "mitsonar.seanet.messages", "mitsonar.frames",
                                 "mitsonar.dataset.cli"])
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
