"""Loading scenes, and Mitsuba's loading errors as one sentence for the user.

`load_scene` loads a Mitsuba XML scene with the plugins registered; whatever goes wrong comes
back as a `SceneError` naming the file (and, where Mitsuba knows it, the line) and the offending
parameter. A constructor of one of our plugins that refuses a value raises a ValueError, which
Mitsuba wraps into a RuntimeError with the traceback as text; the plugins keep the original
exception (``mitsonar.plugins.take_failure``), so the reason is that exception's own message,
not something recovered from the text. Errors of Mitsuba's own (an XML syntax error, a
property a Mitsuba plugin does not know) are given by Mitsuba's first line.
"""
from __future__ import annotations

import contextlib
import os
import re
import warnings
import xml.etree.ElementTree as ET

from mitsonar._checks import first_line
from mitsonar.sim.variant import ensure_variant


class SceneError(ValueError):
    """A scene file or parameter that cannot be used; the message is one sentence for the user."""


def _location(line: str) -> str:
    """The place in Mitsuba's first line of an error (``Error while loading "x.xml" (at line 5,
    col 3)``), without its source tag (``[xml.cpp:123]``) and what follows the place."""
    line = line.strip()
    if line.startswith("[") and "] " in line:
        line = line.split("] ", 1)[1]
    for cut in (": failed to instantiate", ": Traceback", ": Found "):
        line = line.split(cut)[0]
    return line


def mitsuba_error(exc: BaseException, where: str | None = None) -> str:
    """One line for an exception Mitsuba raised while loading or instantiating plugins.

    The original exception of one of our plugins when it is the one Mitsuba reports (its message
    appears in Mitsuba's text), with Mitsuba's location of it; else Mitsuba's own message on one
    line. ``where`` (a file name) leads unless the message names it already.
    """
    from mitsonar.plugins import take_failure

    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    first = first_line(exc)
    failure = take_failure()
    reason = None if failure is None else first_line(failure, None)
    if reason is not None and reason in str(exc):
        place = _location(first) if "failed to instantiate" in first else ""
        if "dictionary node" in place:   # mi.load_dict: no file to name
            place = ""
        text = f"{place}: {reason}" if place else reason
    else:
        if first.startswith("[") and "] " in first:
            first = first.split("] ", 1)[1]
        text = " ".join([first] + lines[1:3]) if len(lines) > 1 and "Found " in first else first
    if where and where not in text:
        text = f"{where}: {text}"
    return text


def reads_exr(path_or_xml: str, _depth=0) -> bool:
    """Whether a scene (its XML and the XML files it includes) names an OpenEXR file: Mitsuba reads
    those on Dr.Jit's pool, which `single_threaded_build` must not shrink then (the read waits
    for a pool thread that a one-thread pool does not have)."""
    text = str(path_or_xml)
    base = os.getcwd()
    if not text.lstrip().startswith("<"):
        try:
            with open(text, encoding="utf-8", errors="replace") as fh:
                base, text = os.path.dirname(os.path.abspath(text)), fh.read()
        except OSError:
            return False
    if ".exr" in text.lower():
        return True
    if _depth > 8:
        return False
    for name in re.findall(r'(?:filename|value)="([^"]+\.xml)"', text):
        if reads_exr(os.path.join(base, name), _depth + 1):
            return True
    return False


@contextlib.contextmanager
def single_threaded_build(enabled=True):
    """Dr.Jit's pool at one thread while a scene loads (``llvm`` variants): the mesh normals Mitsuba
    computes (atomic adds) and the ray-tracing BVH Embree builds are then the same every time.

    With the whole pool, Embree's parallel build depends on how the threads happen to join, and
    vertex normals summed with float atomics on the order the threads run: another load of the
    same mesh gave other last bits of hit distances and normals (a 8000-triangle terrain loaded 12
    times with 2 threads gave 4 different sets of hits for the same rays, with 16 threads a new
    set nearly every load), so a render depended on the load and not only on its seed, and dataset
    shards on the worker that loaded the scene. Renders use all threads as before; the cost is the
    load's time on one core. A scene that reads an OpenEXR file (`reads_exr`) loads on the whole
    pool, as before."""
    import drjit as dr
    import mitsuba as mi

    threads = dr.thread_count()
    if not enabled or not mi.variant().startswith("llvm") or threads <= 1:
        yield
        return
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(threads)


def check_scene_file(path) -> None:
    """Refuse, in one `SceneError` line, a scene path that is a directory or does not exist."""
    text = os.fspath(path)
    if os.path.isdir(text):
        raise SceneError(f"scene file {text!r} is a directory; expected a scene XML file")
    if not os.path.isfile(text):
        raise SceneError(f"scene file {text!r} does not exist")


def load_scene(path_or_xml: str, **params):
    """Load a Mitsuba XML scene (a file path, or an XML string starting with ``<``).

    ``params`` are substituted for ``$name`` placeholders as in ``mi.load_file``. Registers the
    plugins for the active variant first. Errors come back as a one-line `SceneError` naming the
    file and the offending parameter.
    """
    ensure_variant()
    import mitsuba as mi

    from mitsonar.plugins import take_failure

    text = str(path_or_xml)
    is_xml = text.lstrip().startswith("<")
    if not is_xml:
        check_scene_file(text)
    take_failure()  # forget failures of earlier loads
    try:
        # Serial loading: Mitsuba 3.9's parallel instantiation of Python plugins now and then
        # fails with std::bad_alloc or a garbled string (docs/tutorials/scenes.rst, "From plain Mitsuba").
        load = mi.load_string if is_xml else mi.load_file
        with single_threaded_build(not reads_exr(text)):
            scene = load(text, parallel=False, **params)
    except Exception as exc:  # Mitsuba raises RuntimeError with a traceback inside the message
        raise SceneError(mitsuba_error(exc, "XML string" if is_xml else text)) from None
    if not scene.id():
        # Scans record where they came from; the scene's own id is the one place to keep it.
        scene.set_id("<xml string>" if is_xml else os.path.basename(text))
    return scene


def scene_name(scene) -> str:
    """The scene's id (its file name when `load_scene` loaded it), or ''."""
    return scene.id() or ""


def sonar_of(scene, sensor=0):
    """The sonar sensor ``sensor`` (an index or a sensor) of ``scene``, or a `SceneError` saying
    what the scene has instead; warns when an index picks one of several sonars."""
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.integrators import common
    from mitsonar.plugins.sensors.sonar import SonarSensor

    name = scene_name(scene) or "the scene"
    sonars = [s for s in scene.sensors() if isinstance(s, SonarSensor)]
    if not sonars:
        found = ", ".join(type(s).__name__ for s in scene.sensors()) or "none"
        raise SceneError(f'{name}: needs a <sensor type="sonar"> (sensors found: {found})')
    try:
        chosen = common.resolve_sensor(scene, sensor)
    except ValueError as exc:
        raise SceneError(f"{name}: {exc}") from None
    if isinstance(sensor, int) and len(sonars) > 1:
        warnings.warn(f"{name} has {len(sonars)} sonar sensors; rendering sensor {sensor} "
                      "(choose with render_scan(sensor=...))", stacklevel=3)
    return chosen


def live_scene(path: str, edit=None):
    """The scene of ``path`` with every ``sonar`` sensor reduced to one ping at bearing 0
    (`mitsonar.sim.scene.load_scene` of the edited XML, relative paths resolved from the file's
    folder). ``edit``: a function given the XML's root element to change further before the load
    (`mitsonar.devices.oculus.scenes`)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as e:
        raise SceneError(f"{path}: cannot read the scene XML ({e})") from None
    for sensor in root.iter("sensor"):
        if sensor.get("type") != "sonar" or not _xml_kind(sensor).scanlines:
            continue       # a multibeam keeps its fan: its frames render whole
        for name, tag, value in (("n_pings", "integer", "1"), ("bearing_start", "float", "0")):
            el = next((c for c in sensor if c.get("name") == name), None)
            if el is None:
                el = ET.SubElement(sensor, tag, name=name)
            el.set("value", value)
    if edit is not None:
        edit(root)
    ensure_variant()
    scene_folder(path)
    # optimize=False: shapes keep their ids (no merging of those sharing a BSDF), so that an
    # ``object`` datagram can move one
    scene = load_scene(ET.tostring(root, encoding="unicode"), optimize=False)
    scene.set_id(os.path.basename(path))
    return scene


def scene_folder(path: str) -> None:
    """Put the folder of the scene file ``path`` first on Mitsuba's file resolver (relative paths
    in its XML are found from there)."""
    import mitsuba as mi

    folder = os.path.dirname(os.path.abspath(path))
    resolver = mi.file_resolver() if hasattr(mi, "file_resolver") else mi.Thread.thread().file_resolver()
    if folder not in [str(p) for p in resolver]:
        resolver.prepend(folder)


def _xml_kind(sensor):
    """The `mitsonar.kinds.SonarKind` a ``sonar`` sensor element names (the default kind
    without a ``kind``; an unknown name: the default's, and the scene's load says what is wrong)."""
    import mitsonar.kinds as kinds

    el = next((c for c in sensor if c.get("name") == "kind"), None)
    return kinds.lookup(kinds.DEFAULT if el is None else el.get("value")) or kinds.get(kinds.DEFAULT)


def scene_kinds(path: str) -> list:
    """The `mitsonar.kinds.SonarKind` of each ``sonar`` sensor of the scene file, in order
    (SceneError naming the file if it cannot be read)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as e:
        raise SceneError(f"{path}: cannot read the scene XML ({e})") from None
    return [_xml_kind(s) for s in root.iter("sensor") if s.get("type") == "sonar"]
