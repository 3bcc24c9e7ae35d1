"""Survey scenes with options: a flat specular sea surface at z = 0, and the sonar swapped.

    from mitsonar.scenes.sea_surface import load_survey_scene
    scene = load_survey_scene("scenes_xml/wreck.xml", surface=True)          # + the sea surface
    scene = load_survey_scene("scenes_xml/rocky_slope.xml", sonar=xml)      # another head

``surface`` (off by default) adds a calm sea surface: a horizontal rectangle at ``z = 0`` (world
frame, z up), ``SURFACE_HALF_SIZE`` m from the origin each way, facing down into the water (the
``acoustic`` BSDF is one-sided: its front is the water side), with the ``water_calm`` preset
(``specular`` 0.99, ``shininess`` 2000: a mirror within about 2 deg, see
``mitsonar.plugins.bsdfs.materials``). Paths that reach it reflect as off a mirror, so every kind of head
sees shallow-water multipath where the image-source method puts it: a target at ``t`` seen from
a head at ``h`` answers at the direct range ``|t - h|``, via the surface once at
``(|t - h| + |t' - h|) / 2`` and via the surface both ways at the image-source range ``|t' - h|``,
``t' = (t_x, t_y, -t_z)`` the target's mirror image in the surface (needs ``max_depth`` >= 3).

The scene file is read as XML, edited and loaded from text: relative file names in it
(``filename``, ``beam_table``) are made absolute against the file's folder first, so the edited
scene finds its meshes wherever it is loaded from. The ground truth of a scene with the surface
(`mitsonar.scene_mesh`) includes the surface's rectangle.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET

from mitsonar.sim.scene import SceneError, load_scene

SURFACE_ID = "sea_surface"
SURFACE_PRESET = "water_calm"
SURFACE_HALF_SIZE = 1000.0
#: String properties that name files, made absolute when a scene file is edited.
FILE_PROPERTIES = ("filename", "beam_table")


def surface_xml(half_size=SURFACE_HALF_SIZE, preset=SURFACE_PRESET) -> str:
    """The sea surface as a Mitsuba ``<shape>``: a rectangle at z = 0 whose normal points down
    (``rotate x 180`` turns the rectangle's +z normal to -z)."""
    return (f'<shape type="rectangle" id="{SURFACE_ID}"><transform name="to_world">'
            f'<scale x="{half_size:.17g}" y="{half_size:.17g}"/><rotate x="1" angle="180"/></transform>'
            f'<bsdf type="acoustic"><string name="preset" value="{preset}"/></bsdf></shape>')


def edit_scene(path_or_xml, *, surface=False, sonar=None) -> str:
    """The XML text of a scene (a file or an XML string) with the options applied.

    ``surface``: add the sea surface (`surface_xml`). ``sonar``: a ``<sensor>`` element (text)
    replacing every sensor of the scene. Refused with one line: a missing file, text that is not
    XML, a ``surface`` that is not True/False, a scene that already has a shape ``sea_surface``.
    """
    if not isinstance(surface, bool):
        raise SceneError(f"scene option 'surface': {surface!r} is not allowed (True or False)")
    text = str(path_or_xml)
    is_xml = text.lstrip().startswith("<")
    if is_xml:
        where, folder = "XML string", os.getcwd()
    else:
        if not os.path.isfile(text):
            raise SceneError(f"scene file {text!r} does not exist")
        where, folder = text, os.path.dirname(os.path.abspath(text))
        with open(text, encoding="utf-8") as f:
            text = f.read()
    try:
        root = ET.fromstring(text.encode("utf-8") if text.lstrip().startswith("<?xml") else text)
    except ET.ParseError as exc:
        raise SceneError(f"{where}: not a readable XML scene ({exc})") from None
    for el in root.iter("string"):
        value = el.get("value", "")
        if el.get("name") in FILE_PROPERTIES and value and not value.startswith("$") and not os.path.isabs(value):
            el.set("value", os.path.join(folder, value))
    if sonar is not None:
        for el in list(root.findall("sensor")):
            root.remove(el)
        try:
            new = ET.fromstring(sonar)
        except ET.ParseError as exc:
            raise SceneError(f"scene option 'sonar': not a readable <sensor> element ({exc})") from None
        # after the integrator, like the scenes write it (order does not matter to Mitsuba)
        root.insert(len([e for e in root if e.tag in ("default", "integrator")]), new)
    if surface:
        if any(el.get("id") == SURFACE_ID for el in root.iter("shape")):
            raise SceneError(f"{where}: already has a shape '{SURFACE_ID}'; the 'surface' option would add a second")
        root.append(ET.fromstring(surface_xml()))
    return ET.tostring(root, encoding="unicode")


def load_survey_scene(path_or_xml, *, surface=False, sonar=None, **params):
    """Load a scene with the options of `edit_scene` (``params``: the XML's ``$name`` defaults,
    as in `load_scene`). The scene keeps its file's name as its id."""
    text = str(path_or_xml)
    try:
        scene = load_scene(edit_scene(path_or_xml, surface=surface, sonar=sonar), **params)
    except SceneError as exc:
        if text.lstrip().startswith("<"):
            raise
        # The edited scene is loaded from a string: Mitsuba's place in it ("At string (line 9, col 6)")
        # is no line of the file. The file as written names its own line when the fault is its own;
        # else the fault is in what the options added.
        load_scene(text, **params)
        import re

        reason = re.sub(r"^(XML string: )?(At|Error while loading) string \(line \d+, col \d+\): ", "", str(exc))
        added = " and ".join(x for x in ("the sea surface" if surface else "",
                                         "the replacement sensor" if sonar is not None else "") if x)
        raise SceneError(f"{text} with {added}: {reason}") from None
    if not text.lstrip().startswith("<"):
        scene.set_id(os.path.basename(text) + (" +surface" if surface else ""))
    return scene
