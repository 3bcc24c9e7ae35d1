"""What the scene converters (`mitsonar.scenes.grid`, `mitsonar.scenes.sdf`) write around their
shapes: a material by name, the sonar (``--sensor``), and the scene file itself with its frame.

Material names (``--material``, a sediment mapping's second column, a model pattern's material):

* an ``acoustic`` BSDF preset (`mitsonar.plugins.bsdfs.materials.PRESETS`: ``seabed_sand``,
  ``seabed_rock``, ``seabed_mud``, ``seabed_clay``, ``seabed_gravel``, ``sand``, ``rock``,
  ``water_calm``, ``concrete_good``, ...), written as ``<bsdf type="acoustic">`` with that preset;
* else a medium of the ``acoustic_material`` BSDF (`mitsonar.acoustics.materials.MATERIALS`:
  ``steel``, ``concrete``, ``gravel``, ``silt``, ``mud``, ``clay``; ``sand`` and ``rock`` are
  the presets above): its reflection from the impedances, with a Lambert backscatter only where
  the medium has a Lambert parameter (``mud``; the others are specular, see
  `mitsonar.acoustics.materials`);
* else an APL-UW TR 9407 sediment (``medium sand``, ``sandy gravel``, ``clay``, ...:
  `mitsonar.acoustics.seabed.SEDIMENTS`) followed by ``@`` and the head's frequency in kHz
  (``medium sand@100``): the ``acoustic_material`` BSDF with ``sediment`` and that ``frequency``
  (the handbook's model holds from 10 to 100 kHz; above it is extrapolated).
"""
from __future__ import annotations

import os
import re
from xml.sax.saxutils import quoteattr

import numpy as np

DEFAULT_SEABED = "seabed_sand"


def material_names():
    from mitsonar.acoustics.materials import MATERIALS
    from mitsonar.plugins.bsdfs.materials import PRESETS

    return sorted(PRESETS), sorted(m for m in MATERIALS if m not in PRESETS)


def material_allowed() -> str:
    presets, media = material_names()
    return (f"an acoustic preset ({', '.join(presets)}), a medium ({', '.join(media)}) or an APL-UW "
            "sediment with the head's frequency in kHz, e.g. 'medium sand@100'")


def check_material(name, where) -> str:
    """``name`` if it is a material `bsdf_xml` writes, else a ValueError of one line naming ``where``."""
    from mitsonar.acoustics.seabed import SEDIMENTS

    presets, media = material_names()
    text = str(name).strip()
    if text in presets or text in media:
        return text
    sediment, at, khz = text.partition("@")
    if sediment.strip() in SEDIMENTS:
        try:
            ok = at and float(khz) > 0
        except ValueError:
            ok = False
        if ok:
            return text
        raise ValueError(f"{where} {text!r}: an APL-UW sediment needs the head's frequency: "
                         f"'{sediment.strip()}@FREQUENCY_KHZ', e.g. '{sediment.strip()}@100'")
    raise ValueError(f"{where} {text!r}: unknown material (allowed: {material_allowed()})")


def bsdf_xml(name, bsdf_id) -> str:
    """The ``<bsdf>`` element of a material name (checked by `check_material` first)."""
    from mitsonar.acoustics.seabed import SEDIMENTS

    presets, media = material_names()
    if name in presets:
        body, bsdf_type = f'<string name="preset" value="{name}"/>', "acoustic"
    elif name in media:
        body, bsdf_type = f'<string name="material" value="{name}"/>', "acoustic_material"
    else:
        sediment, _, khz = name.partition("@")
        assert sediment.strip() in SEDIMENTS, name
        body = (f'<string name="sediment" value="{sediment.strip()}"/>'
                f'<float name="frequency" value="{float(khz) * 1e3:.17g}"/>'
                '<boolean name="extrapolate" value="true"/>')
        bsdf_type = "acoustic_material"
    return f'<bsdf type="{bsdf_type}" id={quoteattr(bsdf_id)}>{body}</bsdf>'


def safe_id(text) -> str:
    """A Mitsuba id from free text: letters, digits and ``_`` (``.`` separates ids from parameter
    names in ``mi.traverse``)."""
    return re.sub(r"[^A-Za-z0-9_]+", "_", str(text)).strip("_") or "x"


def sensor_xml(sensor, pose=None) -> str:
    """The ``<sensor>`` element of ``--sensor``: an echo-sounder preset name
    (`mitsonar.scenes.echosounders.PRESETS`, looking down) or a file holding one ``<sensor>``
    element; ``pose`` (a 4x4 matrix) is applied after the sensor's own ``to_world`` (its mount)."""
    import xml.etree.ElementTree as ET

    from mitsonar.scenes import echosounders

    if sensor in echosounders.PRESETS:
        text = echosounders.sonar_xml(sensor, sensor_id="sonar")
    else:
        if not os.path.isfile(str(sensor)):
            raise ValueError(f"--sensor {sensor}: neither an echo-sounder preset ({', '.join(sorted(echosounders.PRESETS))}) "
                             "nor a file holding a <sensor> element")
        with open(sensor, encoding="utf-8") as f:
            text = f.read()
    try:
        el = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f"--sensor {sensor}: not readable XML ({exc})") from None
    if el.tag != "sensor":
        raise ValueError(f"--sensor {sensor}: holds a <{el.tag}>, not a <sensor> element")
    if pose is not None:
        tr = next((t for t in el.findall("transform") if t.get("name") == "to_world"), None)
        if tr is None:
            tr = ET.SubElement(el, "transform", name="to_world")
        ET.SubElement(tr, "matrix", value=" ".join(f"{v:.17g}" for v in np.asarray(pose, float).ravel()))
    return ET.tostring(el, encoding="unicode")


def scene_text(shapes, bsdfs, frame=None, sensor=None) -> str:
    """A Mitsuba scene: the frame's ``<default>`` parameters (`mitsonar.geometry.geodesy.scene_frame`), the
    ``sonar_tof`` integrator, ``sensor`` (XML text or None), the ``<bsdf>`` elements and the shapes."""
    from mitsonar.geometry.geodesy import frame_defaults

    head = [frame_defaults(frame)] if frame is not None else []
    parts = ['<scene version="3.0.0">', *("    " + h for h in head),
             '    <default name="max_depth" value="2"/>',
             '    <integrator type="sonar_tof"><integer name="max_depth" value="$max_depth"/></integrator>']
    if sensor:
        parts.append("    " + sensor)
    parts += ["    " + b for b in bsdfs] + ["    " + s for s in shapes] + ["</scene>", ""]
    return "\n".join(parts)


def ply_shape(shape_id, filename, bsdf_id, to_world=None, face_normals=True) -> str:
    """A ``<shape type="ply">`` element (``filename`` as written: relative to the scene's folder)."""
    tr = ""
    if to_world is not None:
        tr = ('<transform name="to_world"><matrix value="'
              + " ".join(f"{v:.17g}" for v in np.asarray(to_world, float).ravel()) + '"/></transform>')
    fn = '<boolean name="face_normals" value="true"/>' if face_normals else ""
    return (f'<shape type="ply" id={quoteattr(shape_id)}><string name="filename" value={quoteattr(filename)}/>'
            f'{fn}{tr}<ref id={quoteattr(bsdf_id)}/></shape>')


def write_mesh_ply(path, vertices, faces, comment=None) -> None:
    """``vertices`` (V, 3) and ``faces`` (F, 3) as a binary PLY (float32 x y z,
    `mitsonar.geometry.ply.write_ply`)."""
    from mitsonar.geometry.ply import write_ply

    rows = np.empty(len(vertices), [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    rows["x"], rows["y"], rows["z"] = np.asarray(vertices, np.float64).T
    write_ply(path, rows, np.asarray(faces, np.int64), comment=comment)
