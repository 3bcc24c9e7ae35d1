"""Variant selection, scene loading, `render_scan` and the scene's ground-truth mesh."""
from __future__ import annotations

import difflib
import math
import os
import re
import warnings

import numpy as np

from .scan import Scan
from .variant import VariantError, check_backend, requested_variant

DEFAULT_SPP = 4096


class SceneError(ValueError):
    """A scene file or parameter that cannot be used; the message is one sentence for the user."""


def _on_variant_change(old, new):
    if new in ("llvm_ad_mono", "cuda_ad_mono"):
        from mitsonar.plugins import register

        register()


def set_variant(name=None) -> str:
    """Activate a Mitsuba variant (default ``llvm_ad_mono`` or ``$MITSONAR_VARIANT``) and register
    the plugins for it. Returns the variant's name."""
    import mitsuba as mi

    name = requested_variant(name)
    check_backend(name)
    if mi.variant() != name:
        mi.set_variant(name)
    from mitsonar.plugins import register

    register()
    return name


def variant():
    import mitsuba as mi

    return mi.variant()


def _ensure_variant():
    import mitsuba as mi

    if mi.variant() not in ("llvm_ad_mono", "cuda_ad_mono") or os.environ.get("MITSONAR_VARIANT"):
        if mi.variant() != requested_variant():
            set_variant()
    from mitsonar.plugins import register

    register()


_PLUGIN_CLASSES = {"sonar": ("sonar_sensor", "SonarSensor"), "acoustic": ("acoustic_bsdf", "AcousticBSDF"),
                   "sonar_tof": ("sonar_tof", "SonarTOFIntegrator"), "sonar_mlt": ("sonar_mlt", "SonarMLTIntegrator")}


def plugin_parameters(plugin_type: str) -> list:
    """The XML parameter names of one of our plugins, read from its docstring's parameter table
    (the table is the documentation, so the two cannot disagree)."""
    if plugin_type not in _PLUGIN_CLASSES:
        return []
    from mitsonar.plugins import module

    mod, cls = _PLUGIN_CLASSES[plugin_type]
    doc = getattr(module(mod), cls).__doc__ or ""
    names, rules = [], 0
    for line in doc.splitlines():
        text = line.strip()
        if text.startswith("===="):
            rules += 1
            continue
        if rules == 2 and text and not line.startswith(" " * 12):  # body rows, not continuation lines
            first = text.split()[0]
            stem, _, alt = first.partition("/")
            names.append(stem)
            if alt.startswith("_"):  # "aperture_h/_v"
                names.append(stem.rsplit("_", 1)[0] + alt)
    if plugin_type == "sonar":
        import dataclasses

        from .electronics import Electronics

        names = [n for n in names if n != "electronics"] + [f.name for f in dataclasses.fields(Electronics)]
    return names


def _unreferenced(head: str, lines: list) -> str | None:
    """Mitsuba's 'Found N unreferenced property in <kind> plugin of type "t": - float "x": 5' as a
    sentence that names the parameter and the nearest known one."""
    m = re.search(r'unreferenced propert(?:y|ies) in (\w+) plugin of type "([^"]+)"', head)
    if not m:
        return None
    where = head.split(": Found")[0]
    if "dictionary node" in where:  # mi.load_dict: no file to name
        where = ""
    kind = {"sonar": "sensor", "acoustic": "BSDF", "sonar_tof": "integrator",
            "sonar_mlt": "integrator"}.get(m.group(2), m.group(1))
    known = plugin_parameters(m.group(2))
    parts = []
    for ln in lines[1:]:
        p = re.match(r'^-\s*(\w+)\s+"([^"]+)"(?::\s*(.*))?$', ln)
        if not p:
            continue
        name = p.group(2)
        hint = difflib.get_close_matches(name, known, n=1)
        parts.append(f'"{name}"' + (f' (did you mean "{hint[0]}"?)' if hint else ""))
    allowed = f"; its parameters: {', '.join(known)}" if known else ""
    text = f'the {kind} "{m.group(2)}" has no parameter {", ".join(parts)}{allowed}'
    return f"{where}: {text}" if where else text


def _first_reason(message: str) -> str:
    """Mitsuba wraps a failing Python constructor's traceback; keep the reason and the place."""
    lines = [re.sub(r"^\[[\w.]+:\d+\]\s*", "", ln.strip()) for ln in str(message).splitlines() if ln.strip()]
    reason = None
    for ln in reversed(lines):
        m = re.match(r"^(?:\w+\.)*(?:ValueError|BeamPatternError|TypeError|RuntimeError|VariantError)"
                     r":\s*(.*)$", ln)
        if m:
            reason = m.group(1)
            break
    head = lines[0] if lines else str(message)
    head = head.split(": Traceback")[0]
    if reason:
        prefix = head.split("failed to instantiate")[0].rstrip(": ") if "failed to instantiate" in head else ""
        return f"{prefix}: {reason}" if prefix else reason
    unref = _unreferenced(head, lines)
    if unref:
        return unref
    return " ".join(lines[:3]) if len(lines) > 1 else head


def load_scene(path_or_xml: str, **params):
    """Load a Mitsuba XML scene (a file path, or an XML string starting with ``<``).

    ``params`` are substituted for ``$name`` placeholders as in ``mi.load_file``. Registers the
    plugins for the active variant first. Errors come back as one-line `SceneError`s naming the
    file and the offending parameter.
    """
    _ensure_variant()
    import mitsuba as mi

    text = str(path_or_xml)
    is_xml = text.lstrip().startswith("<")
    if not is_xml and not os.path.isfile(text):
        raise SceneError(f"scene file {text!r} does not exist")
    try:
        # Serial loading: Mitsuba 3.9's parallel instantiation of Python plugins now and then
        # fails with std::bad_alloc or a garbled string (about 1 in 150 first loads here).
        load = mi.load_string if is_xml else mi.load_file
        scene = load(text, parallel=False, **params)
    except Exception as exc:  # Mitsuba raises RuntimeError with a traceback inside the message
        where = "XML string" if is_xml else text
        reason = _first_reason(str(exc))
        if where not in reason:
            reason = f"{where}: {reason}"
        raise SceneError(reason) from None
    if not scene.id():
        # Scans record where they came from; the scene's own id is the one place to keep it.
        scene.set_id("<xml string>" if is_xml else os.path.basename(text))
    return scene


def _sonar(scene, sensor):
    from mitsonar.plugins import module

    common = module("common")
    name = _scene_name(scene) or "the scene"
    sonars = [s for s in scene.sensors() if isinstance(s, common.SonarSensor)]
    if not sonars:
        kinds = ", ".join(type(s).__name__ for s in scene.sensors()) or "none"
        raise SceneError(f'{name}: needs a <sensor type="sonar"> (sensors found: {kinds})')
    try:
        chosen = common.resolve_sensor(scene, sensor)
    except ValueError as exc:
        raise SceneError(f"{name}: {exc}") from None
    if isinstance(sensor, int) and len(sonars) > 1:
        warnings.warn(f"{name} has {len(sonars)} sonar sensors; rendering sensor {sensor} "
                      "(choose with render_scan(sensor=...))", stacklevel=3)
    return chosen


def _whole(name, value, lo, hi, what):
    """A count or seed argument: a whole number in [lo, hi] (4096.0 counts; 1.5, True, "8" do not)."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    if (not ok and isinstance(value, (float, np.floating)) and math.isfinite(value)
            and float(value).is_integer()):
        ok = True
    if not ok or not lo <= value <= hi:
        raise SceneError(f"render_scan '{name}': {value!r} is not allowed ({what})")
    return int(value)


def _check_pose(pose):
    """A render's pose in one sentence: array-like, 4x4, finite, rigid."""
    from .scan import check_rigid

    try:
        m = np.asarray(pose, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"render_scan 'pose': expected a 4x4 rigid transform (array-like), got "
                         f"{type(pose).__name__} {pose!r:.40}") from None
    try:
        return check_rigid(m, "render_scan 'pose'")
    except ValueError as exc:
        raise SceneError(str(exc)) from None


SONAR_INTEGRATORS = ("sonar_tof", "sonar_mlt")
SEED_MAX = 2 ** 32 - 1   # the path seed is a 32-bit integer: larger seeds would repeat smaller ones


def _integrator(scene, integrator):
    import mitsuba as mi

    from mitsonar.plugins import module

    base = module("common").SonarIntegrator
    if integrator is None:
        integrator = scene.integrator()
        if not isinstance(integrator, base):
            if integrator is not None:  # None: the XML names no integrator, sonar_tof is the default
                name = integrator.class_name() if hasattr(integrator, "class_name") else type(integrator).__name__
                warnings.warn(f"{_scene_name(scene) or 'the scene'}: its integrator {name} is not a sonar "
                              "integrator; rendering with sonar_tof", stacklevel=3)
            return mi.load_dict({"type": "sonar_tof"})
        return integrator
    if isinstance(integrator, str):
        integrator = {"type": integrator}
    if isinstance(integrator, dict):
        kind = integrator.get("type")
        if kind not in SONAR_INTEGRATORS:
            raise SceneError(f"render_scan 'integrator': {kind!r} is not a sonar integrator "
                             f"(one of {', '.join(SONAR_INTEGRATORS)})")
        try:
            return mi.load_dict(integrator)
        except Exception as exc:
            raise SceneError(f"render_scan 'integrator': {_first_reason(str(exc))}") from None
    if not isinstance(integrator, base):
        raise SceneError(f"render_scan 'integrator': {type(integrator).__name__} is not a sonar integrator "
                         f"(one of {', '.join(SONAR_INTEGRATORS)})")
    return integrator


def render_scan(scene, spp: int = DEFAULT_SPP, seed: int = 0, pose=None, integrator=None, sensor=0,
                max_depth=None, electronics=None, electronics_seed=None, progress=None) -> Scan:
    """Render one scan of ``scene`` and pass it through the head's electronics.

    ============== ==============================================================================
    scene          a scene from `load_scene` (or ``mi.load_*``) with a ``sonar`` sensor
    spp            paths per ping (default 4096)
    seed           seed of the paths (and of the electronics noise unless ``electronics_seed``)
    pose           4x4 world transform of the beam frame at bearing 0, replacing ``to_world``
    integrator     an integrator object or XML dict; default: the scene's if it is a sonar
                   integrator, else ``sonar_tof``
    sensor         sensor index or object
    max_depth      override of the integrator's surface bounces
    electronics    dict of electronics fields overriding the sensor's
    progress       optional callable ``progress(done_spp, spp)`` called after each render pass
    ============== ==============================================================================

    The same arguments give the same scan, bit for bit.
    """
    _ensure_variant()
    import mitsuba as mi

    # Every argument is checked before the render: a mistake costs a sentence, not a render.
    spp = _whole("spp", spp, 1, 2 ** 31 - 1, "a whole number of paths per ping, 1 or more")
    seed = _whole("seed", seed, 0, SEED_MAX, f"a whole number from 0 to {SEED_MAX}")
    if electronics_seed is not None:
        electronics_seed = _whole("electronics_seed", electronics_seed, 0, SEED_MAX,
                                  f"a whole number from 0 to {SEED_MAX}, or None for seed")
    if max_depth is not None:
        max_depth = _whole("max_depth", max_depth, 1, 64, "a whole number of surface bounces from 1 to 64")
    if pose is not None:
        pose = _check_pose(pose)
    if electronics is not None and not isinstance(electronics, dict):
        raise SceneError(f"render_scan 'electronics': expected a dict of electronics fields, got "
                         f"{type(electronics).__name__}")
    sonar = _sonar(scene, sensor)
    integrator = _integrator(scene, integrator)

    from .electronics import Electronics

    settings = dict(sonar.electronics)
    settings.update(electronics or {})
    try:
        model = Electronics.from_dict(settings, source="render_scan electronics" if electronics else "sonar")
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    try:
        sonar.head_pose(pose)
        hist = integrator.render_histogram(scene, sonar, seed=seed, spp=spp, pose=pose, max_depth=max_depth,
                                           progress=progress)
    except ValueError as exc:
        raise SceneError(str(exc)) from None

    intensity = hist.astype(np.float32)
    ranges = sonar.bin_centres()
    eseed = seed if electronics_seed is None else electronics_seed
    data = model.apply(intensity, ranges, absorption=sonar.absorption, sound_speed=sonar.sound_speed, seed=eseed)
    from ._version import __version__

    poses = sonar.ping_poses(pose)
    meta = {
        "scene": _scene_name(scene),
        "seed": int(seed),
        "spp": int(spp),
        "integrator": type(integrator).__name__,
        "max_depth": int(max_depth if max_depth is not None else getattr(integrator, "max_depth", 0)),
        "mitsonar_version": __version__,
        "variant": mi.variant(),
        "bearing_start": sonar.bearing_start,
        "bearing_step": sonar.bearing_step,
        "electronics_seed": int(eseed),
    }
    if getattr(sonar, "transmit", None) is not None:  # multibeam: the transmit fan beside the receive beams
        meta.update(tx_pattern=sonar.transmit.kind, tx_beamwidth_h=sonar.transmit.beamwidth_h,
                    tx_beamwidth_v=sonar.transmit.beamwidth_v)
    return Scan(intensity=intensity, data=data, ranges=ranges,
                bearings=np.radians(sonar.bearings_deg()), poses=poses,
                range_min=sonar.range_min, range_max=sonar.range_max,
                beam_pattern=sonar.beam.kind, beamwidth_h=sonar.beam.beamwidth_h,
                beamwidth_v=sonar.beam.beamwidth_v, kind=sonar.kind, sound_speed=sonar.sound_speed,
                absorption=sonar.absorption, electronics={**model.to_dict(), "seed": int(eseed)},
                meta=meta)


def _scene_name(scene) -> str:
    return scene.id() or ""


# ---------------------------------------------------------------------------- ground truth
def _sphere_mesh(n_lat=24, n_lon=48):
    lat = np.linspace(0, np.pi, n_lat + 1)
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    verts = [[0, 0, 1]]
    for t in lat[1:-1]:
        for p in lon:
            verts.append([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
    verts.append([0, 0, -1])
    faces = []
    for j in range(n_lon):
        faces.append([0, 1 + j, 1 + (j + 1) % n_lon])
    for i in range(n_lat - 2):
        a, b = 1 + i * n_lon, 1 + (i + 1) * n_lon
        for j in range(n_lon):
            j2 = (j + 1) % n_lon
            faces += [[a + j, b + j, b + j2], [a + j, b + j2, a + j2]]
    last = len(verts) - 1
    base = 1 + (n_lat - 2) * n_lon
    for j in range(n_lon):
        faces.append([base + j, last, base + (j + 1) % n_lon])
    return np.array(verts, float), np.array(faces, np.int64)


def _disk_mesh(n=64):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = np.concatenate([[[0, 0, 0]], np.stack([np.cos(t), np.sin(t), np.zeros(n)], 1)])
    f = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    return v, f


def scene_mesh(scene):
    """The scene's surfaces as one triangle mesh ``(vertices (V, 3) float64, faces (F, 3) int64)``.

    Meshes are taken as they are; rectangles, disks and spheres are triangulated (spheres with
    ~2300 triangles). This is the ground truth maps are scored against.
    """
    import mitsuba as mi

    verts, faces, offset = [], [], 0
    for shape in scene.shapes():
        name = shape.class_name() if hasattr(shape, "class_name") else type(shape).__name__
        if isinstance(shape, mi.Mesh):
            v = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
            f = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        else:
            params = mi.traverse(shape)
            key = next((k for k in params.keys() if k.endswith("to_world")), None)
            if key is None:
                raise SceneError(f"scene_mesh: cannot triangulate shape {shape.id()!r} ({name})")
            m = np.array(params[key].matrix, dtype=np.float64).reshape(4, 4)
            if name == "Rectangle":
                local = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
                lf = np.array([[0, 1, 2], [0, 2, 3]])
            elif name == "Sphere":
                local, lf = _sphere_mesh()
            elif name == "Disk":
                local, lf = _disk_mesh()
            else:
                raise SceneError(f"scene_mesh: cannot triangulate shape {shape.id()!r} of type {name}; "
                                 "use rectangle, disk, sphere or a mesh")
            v = local @ m[:3, :3].T + m[:3, 3]
            f = lf
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(verts), np.concatenate(faces)


__all__ = ["SceneError", "VariantError", "load_scene", "render_scan", "scene_mesh", "set_variant", "variant"]


def init_on_import() -> None:
    """Activate the default variant if none is set, register the plugins, follow variant changes.

    A missing or too old libLLVM does not make ``import mitsonar`` fail (the command line must
    still start and explain); it is reported as a `VariantError` by the first `load_scene` or
    `render_scan`, and as a warning here.
    """
    import mitsuba as mi

    try:
        if mi.variant() is None:
            set_variant()
        elif mi.variant() in ("llvm_ad_mono", "cuda_ad_mono"):
            from mitsonar.plugins import register

            register()
    except VariantError as exc:
        # The command line reports the same error as its one line; a warning would repeat it.
        import sys

        # (The console script's argv[0] is "mitsonar"; under `python -m mitsonar.cli` it is
        # still "-m" while the package imports.)
        if os.path.basename(sys.argv[0] if sys.argv else "") not in ("mitsonar", "-m"):
            warnings.warn(f"mitsonar: {exc}", RuntimeWarning, stacklevel=3)
    mi.detail.add_variant_callback(_on_variant_change)
