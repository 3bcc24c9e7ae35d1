"""The example scenes shipped with mitsonar, found from any working directory.

They live in ``scenes_xml/`` of the source tree and install as the data package
``mitsonar.scenes_xml`` (pyproject's package-dir and package-data), every file of the folder
together: a scene that names a mesh by a relative path (``rocky_slope.ply``) finds it next to
itself, since Mitsuba resolves a scene's relative paths from the scene file's folder.

>>> scene = mitsonar.load_scene(mitsonar.example_scene("box"))
"""
from __future__ import annotations

import os
from importlib import resources

#: The package holding the example scenes.
PACKAGE = "mitsonar.scenes_xml"


def _folder():
    return resources.files(PACKAGE)


def example_scenes() -> list[str]:
    """The names of the example scenes (``box``, ``harbour``, ...), sorted."""
    return sorted(p.name[:-4] for p in _folder().iterdir() if p.name.endswith(".xml"))


def example_files() -> list[str]:
    """Every data file shipped with the scenes (``box.xml``, ``wreck_survey.tum``, meshes), sorted."""
    return sorted(p.name for p in _folder().iterdir()
                  if p.is_file() and not p.name.startswith(("_", ".")) and not p.name.endswith((".py", ".pyc")))


def example_scene(name: str) -> str:
    """The path of the example scene ``name`` (``"box"`` for ``box.xml``), from any working directory.

    A name with a suffix names any file shipped with the scenes, e.g. ``"wreck_sidescan_survey.tum"``
    (a trajectory) or ``"box.xml"``. An unknown name raises ValueError (one line, listing the
    scenes). The path is a file on disk (pip installs unpacked), next to the files it uses.
    """
    if not isinstance(name, str) or not name or os.sep in name or "/" in name:
        raise ValueError(f"example_scene: {name!r} is not a scene name; available: {', '.join(example_scenes())}")
    files = example_files()
    file = name if name in files else f"{name}.xml"
    if file not in files:
        raise ValueError(f"example_scene: no example scene {name!r}; available: {', '.join(example_scenes())} "
                         "(other shipped files by name and suffix: mitsonar.scenes.examples.example_files())")
    return os.fspath(_folder() / file)


__all__ = ["PACKAGE", "example_files", "example_scene", "example_scenes"]
