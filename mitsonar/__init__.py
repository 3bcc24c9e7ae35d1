"""mitsonar: physically based underwater imaging-sonar simulation on Mitsuba 3 / Dr.Jit.

``import mitsonar`` selects the Mitsuba variant (``llvm_ad_mono`` unless ``MITSONAR_VARIANT``
says otherwise) and registers the plugins ``sonar``, ``acoustic`` and ``sonar_tof`` for it.
"""
from __future__ import annotations

from mitsonar import _aliases

_aliases.install()  # the old flat module paths, for one release

from mitsonar.sim.variant import prepare_llvm_environment  # noqa: E402

prepare_llvm_environment()

from mitsonar._version import __version__  # noqa: E402

from mitsonar.scan import Scan  # noqa: E402
from mitsonar.sim.groundtruth import scene_mesh  # noqa: E402
from mitsonar.sim.render import render_scan, scan_parameters  # noqa: E402
from mitsonar.sim.scene import SceneError, load_scene  # noqa: E402
from mitsonar.sim.survey import render_survey  # noqa: E402
from mitsonar.jobs.dataset.store import open_dataset  # noqa: E402
from mitsonar.scenes.examples import example_scene, example_scenes  # noqa: E402
from mitsonar.sonar_equation import sonar_equation_report  # noqa: E402
from mitsonar.geometry.trajectory import Trajectory, TrajectoryError  # noqa: E402
from mitsonar.sim.variant import VariantError, init_on_import, set_variant, variant  # noqa: E402

init_on_import()


def load_scan(path) -> Scan:
    """Read a scan written by `Scan.save` (``.exr`` or ``.npz``)."""
    return Scan.load(path)


_LAZY = {"MicronSonar": "devices.micron.driver", "VirtualMicron": "devices.micron.virtual",
         "HeadSettings": "devices.micron.seanet.settings", "StreamParser": "devices.micron.seanet.stream",
         "record": "devices.micron.driver", "replay": "devices.recording",
         "Ping360Sonar": "devices.ping360.driver", "VirtualPing360": "devices.ping360.virtual",
         "Ping360Settings": "devices.ping360.head", "SoundSpeedProfile": "acoustics.profile",
         "render_echoes": "signals.echoes", "Echoes": "signals.echoes"}


def __getattr__(name):
    # Serial devices load on first use: pyserial is not needed to render.
    if name == "signals":     # the coherent signals (numpy and scipy.signal) load on first use
        import importlib

        return importlib.import_module("mitsonar.signals")
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"mitsonar.{_LAZY[name]}"), name)
    # ``mitsonar.plots`` and the other modules that moved into packages by role
    module = _aliases.attribute(name)
    if module is not None:
        return module
    raise AttributeError(f"module 'mitsonar' has no attribute {name!r}")


__all__ = ["Scan", "SceneError", "Trajectory", "TrajectoryError", "VariantError", "example_scene",
           "example_scenes", "load_scan", "load_scene", "open_dataset", "render_scan", "render_survey",
           "scan_parameters", "scene_mesh", "set_variant", "sonar_equation_report", "variant", "__version__", "signals", *_LAZY]
