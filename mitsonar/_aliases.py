"""The old flat module paths of mitsonar, kept importable for one release after the move into
packages by role: ``import mitsonar.electronics`` gives `mitsonar.receiver.electronics` (the same
module object) with a `DeprecationWarning` naming the new home.

The aliases are lazy: a finder on ``sys.meta_path`` answers only for the old names, imports the
new module when an old name is first imported, and enters it in ``sys.modules`` under the old name;
``mitsonar.<old>`` as an attribute goes through the package's ``__getattr__`` (`attribute`).
The public modules of `PUBLIC` (``mitsonar.plots``, ``mitsonar.bathymetry``,
``mitsonar.echosounders``, ``mitsonar.sidescan``) are names users keep: they alias without a
warning.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: old path under ``mitsonar.`` -> new path under ``mitsonar.`` (subpackages move with their
#: submodules: ``mitsonar.seanet.messages`` -> ``mitsonar.devices.micron.seanet.messages``)
MOVED = {
    "variant": "sim.variant", "scene": "sim.scene", "render": "sim.render", "survey": "sim.survey",
    "groundtruth": "sim.groundtruth", "sensor_xml": "sim.sensor_xml",
    "scanfile": "scan.fileformat", "io": "scan.io",
    "electronics": "receiver.electronics", "speckle": "receiver.speckle", "realism": "receiver.realism",
    "frames": "geometry.frames", "trajectory": "geometry.trajectory", "northup": "geometry.northup",
    "ply": "geometry.ply",
    "terrain": "scenes.terrain", "sea_surface": "scenes.sea_surface", "sidescan_demo": "scenes.sidescan_demo",
    "echosounders": "scenes.echosounders",
    "sidescan": "products.sidescan", "mosaic": "products.mosaic", "bathymetry": "products.bathymetry",
    "soundings": "products.soundings", "plots": "products.plots", "sidescan_plots": "products.sidescan_plots",
    "ros": "export.ros",
    "transports": "devices.transports", "rawlog": "devices.rawlog", "recording": "devices.recording",
    "micron": "devices.micron.driver", "virtual_sonar": "devices.micron.virtual",
    "assembler": "devices.micron.assembler", "seanet": "devices.micron.seanet",
    "ping360": "devices.ping360.driver", "virtual_ping360": "devices.ping360.virtual",
    "ping360_head": "devices.ping360.head", "ping_protocol": "devices.ping360.protocol",
    "compare": "jobs.compare", "dataset": "jobs.dataset", "dataset.cli": "cli.dataset",
    "bathy_cli": "cli.bathymetry", "compare_cli": "cli.compare", "export_cli": "cli.export",
    "map_cli": "cli.map", "serial_cli": "cli.serial", "survey_cli": "cli.survey",
}

#: Old names that stay public (documented for users): aliased without a warning.
PUBLIC = {"plots", "bathymetry", "echosounders", "sidescan"}

_OLDEST_FIRST = sorted(MOVED, key=len, reverse=True)  # "dataset.cli" before "dataset"


def new_name(fullname: str) -> str | None:
    """The new module path of an old one (``mitsonar.frames`` -> ``mitsonar.geometry.frames``),
    or None when ``fullname`` is not an old path."""
    if not fullname.startswith("mitsonar."):
        return None
    rest = fullname[len("mitsonar."):]
    for old in _OLDEST_FIRST:
        if rest == old or rest.startswith(old + "."):
            return "mitsonar." + MOVED[old] + rest[len(old):]
    return None


def _warn(old: str, new: str, stacklevel: int) -> None:
    if old[len("mitsonar."):] not in PUBLIC:
        warnings.warn(f"{old} moved to {new}; the old path goes in the next release",
                      DeprecationWarning, stacklevel=stacklevel)


class _Alias(importlib.abc.Loader):
    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec):
        module = importlib.import_module(self.new)
        self.spec = module.__spec__
        return module

    def exec_module(self, module):
        # The new module ran when it was imported; importlib set its __spec__ to the alias's:
        # give it back its own (reload, pickling and introspection read it).
        module.__spec__ = self.spec


class _OldPaths(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        new = new_name(fullname)
        if new is None or fullname == new:
            return None
        _warn(fullname, new, stacklevel=4)
        return importlib.util.spec_from_loader(fullname, _Alias(new))


def install() -> None:
    """Put the finder of old paths at the head of ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _OldPaths) for f in sys.meta_path):
        # first: under an old package path (mitsonar.seanet.messages) the path finder would load
        # the new file again as a second module
        sys.meta_path.insert(0, _OldPaths())


def attribute(name: str):
    """``mitsonar.<name>`` for an old module name (the package's ``__getattr__``), or None."""
    if name not in MOVED or "." in name:
        return None
    old = f"mitsonar.{name}"
    if old in sys.modules:
        return sys.modules[old]
    new = new_name(old)
    _warn(old, new, stacklevel=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # warned once, just above
        return importlib.import_module(old)
