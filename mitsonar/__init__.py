"""mitsonar: physically based underwater imaging-sonar simulation on Mitsuba 3 / Dr.Jit.

``import mitsonar`` selects the Mitsuba variant (``llvm_ad_mono`` unless ``MITSONAR_VARIANT``
says otherwise) and registers the plugins ``sonar``, ``acoustic`` and ``sonar_tof`` for it.
"""
from __future__ import annotations

from mitsonar.sim.variant import prepare_llvm_environment

prepare_llvm_environment()

from mitsonar._version import __version__  # noqa: E402

from mitsonar.scan import Scan  # noqa: E402
from mitsonar.sim.groundtruth import scene_mesh  # noqa: E402
from mitsonar.sim.render import render_scan, scan_parameters  # noqa: E402
from mitsonar.sim.scene import SceneError, load_scene  # noqa: E402
from mitsonar.sim.survey import render_survey  # noqa: E402
from mitsonar.jobs.dataset.store import open_dataset  # noqa: E402
from mitsonar.geometry.trajectory import Trajectory, TrajectoryError  # noqa: E402
from mitsonar.sim.variant import VariantError, init_on_import, set_variant, variant  # noqa: E402

init_on_import()


def load_scan(path) -> Scan:
    """Read a scan written by `Scan.save` (``.exr`` or ``.npz``)."""
    return Scan.load(path)


_LAZY = {"MicronSonar": "micron", "VirtualMicron": "virtual_sonar", "HeadSettings": "seanet.settings",
         "StreamParser": "seanet.stream", "record": "micron", "replay": "recording",
         "Ping360Sonar": "ping360", "VirtualPing360": "virtual_ping360", "Ping360Settings": "ping360_head",
         "SoundSpeedProfile": "acoustics.profile"}


def __getattr__(name):
    # Serial devices load on first use: pyserial is not needed to render.
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'mitsonar' has no attribute {name!r}")


__all__ = ["Scan", "SceneError", "Trajectory", "TrajectoryError", "VariantError", "load_scan", "load_scene",
           "open_dataset", "render_scan", "render_survey", "scan_parameters", "scene_mesh",
           "set_variant", "variant", "__version__", *_LAZY]
