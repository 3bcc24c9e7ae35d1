"""mitsonar: physically based underwater imaging-sonar simulation on Mitsuba 3 / Dr.Jit.

``import mitsonar`` only defines names: it imports neither Mitsuba nor Dr.Jit (nor SciPy or
Matplotlib), changes no environment variable and installs no import hook. The Mitsuba variant is
chosen by `set_variant`, or on first use (`load_scene`, `render_scan`, ...: ``MITSONAR_VARIANT``,
else ``llvm_ad_mono``), which also points Dr.Jit at a working libLLVM and registers the plugins
``sonar``, ``acoustic``, ``sonar_tof``, ... for the variant (and again whenever it changes).
"""
from __future__ import annotations

from mitsonar._version import __version__
from mitsonar.geometry.trajectory import Trajectory, TrajectoryError
from mitsonar.jobs.dataset.store import open_dataset
from mitsonar.scan import Scan
from mitsonar.scenes.examples import example_scene, example_scenes
from mitsonar.sim.groundtruth import scene_mesh
from mitsonar.sim.render import render_scan, scan_parameters
from mitsonar.sim.scene import SceneError, load_scene
from mitsonar.sim.survey import render_survey
from mitsonar.sim.variant import VariantError, ensure_variant, set_variant, variant
from mitsonar.sonar_equation import sonar_equation_report
from mitsonar.scan.io import load_scan   # the one way to read a scan file


_LAZY = {"MicronSonar": "devices.micron.driver", "VirtualMicron": "devices.micron.virtual",
         "HeadSettings": "devices.micron.seanet.settings", "StreamParser": "devices.micron.seanet.stream",
         "record": "devices.micron.driver", "replay": "devices.recording",
         "Ping360Sonar": "devices.ping360.driver", "VirtualPing360": "devices.ping360.virtual",
         "Ping360Settings": "devices.ping360.head", "SoundSpeedProfile": "acoustics.profile",
         "render_echoes": "signals.echoes", "Echoes": "signals.echoes"}


def __getattr__(name):
    # Serial devices (pyserial) and the coherent signals (scipy.signal) load on first use.
    if name == "signals":
        import importlib

        return importlib.import_module("mitsonar.signals")
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"mitsonar.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'mitsonar' has no attribute {name!r}")


__all__ = ["Scan", "SceneError", "Trajectory", "TrajectoryError", "VariantError", "example_scene",
           "example_scenes", "load_scan", "load_scene", "open_dataset", "render_scan", "render_survey",
           "scan_parameters", "scene_mesh", "ensure_variant", "set_variant", "sonar_equation_report", "variant", "__version__", "signals", *_LAZY]
