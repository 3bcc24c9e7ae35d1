"""Where a scene keeps its place on the Earth: two Mitsuba ``<default>`` parameters.

A scene written by ``mitsonar scene from-grid`` or ``from-sdf`` (`mitsonar.scenes.grid`,
`mitsonar.scenes.sdf`) carries the origin and CRS of its world frame (the
`mitsonar.geometry.geodesy.GeoFrame` that ``--origin``/``--crs`` give the survey and export
commands) as two parameter defaults at the top of its XML::

    <default name="mitsonar_origin" value="52.0000000001 4.49999999 0"/>   <!-- lat lon height -->
    <default name="mitsonar_crs" value="EPSG:32631"/>

Mitsuba's parser takes a ``<default>`` of any name and uses it only where the scene says
``$mitsonar_origin`` (nowhere), so the file stays a plain Mitsuba scene (an attribute on
``<scene>`` would be refused: "unexpected attribute"). `scene_frame` reads them back;
`mitsonar.geometry.geodesy.frame_from_args` falls back on it when a command that takes a scene
(``survey``, ``bathymetry``) gets no ``--origin``, so the products come out in the scene's CRS.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET

ORIGIN_PARAM = "mitsonar_origin"
CRS_PARAM = "mitsonar_crs"


def frame_defaults(frame) -> str:
    """The two ``<default>`` elements that record ``frame`` (a `GeoFrame`) in a scene."""
    lat, lon, h = (repr(float(v)) for v in (frame.lat, frame.lon, frame.height))
    return (f'<default name="{ORIGIN_PARAM}" value="{lat} {lon} {h}"/>\n'
            f'    <default name="{CRS_PARAM}" value="{frame.crs}"/>')


def scene_frame(path_or_xml):
    """The `GeoFrame` a scene file (or XML text) records (`frame_defaults`), or None when it
    records none (or is not readable XML: loading it says why). A recorded origin or CRS that is
    not allowed is refused in one line naming the file and the parameter."""
    from mitsonar.geometry.geodesy import GeoFrame

    text = str(path_or_xml)
    where = "XML string"
    if not text.lstrip().startswith("<"):
        if not os.path.isfile(text):
            return None
        where = text
        with open(text, "rb") as f:
            text = f.read()
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return None
    values = {el.get("name"): el.get("value", "") for el in root.findall("default")}
    if ORIGIN_PARAM not in values:
        return None
    origin = values[ORIGIN_PARAM].split()
    return GeoFrame.make(origin, values.get(CRS_PARAM),
                         (f"{where}: <default name=\"{ORIGIN_PARAM}\">", f"{where}: <default name=\"{CRS_PARAM}\">"))
