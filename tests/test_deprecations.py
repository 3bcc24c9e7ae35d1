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
