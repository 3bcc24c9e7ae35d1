"""Variant selection, scene loading, `render_scan` and the scene's ground-truth mesh."""
from __future__ import annotations

import os
import re

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


def _first_reason(message: str) -> str:
    """Mitsuba wraps a failing Python constructor's traceback; keep the reason and the place."""
    lines = [ln.strip() for ln in str(message).splitlines() if ln.strip()]
    reason = None
    for ln in reversed(lines):
        m = re.match(r"^(?:\w+\.)*(?:ValueError|BeamPatternError|TypeError|RuntimeError|VariantError)"
                     r":\s*(.*)$", ln)
        if m:
            reason = m.group(1)
            break
    head = lines[0] if lines else str(message)
    head = re.sub(r"^\[[^\]]*\]\s*", "", head)  # drop "[parser.cpp:444]"
    head = head.split(": Traceback")[0]
    if reason:
        prefix = head.split("failed to instantiate")[0].rstrip(": ") if "failed to instantiate" in head else ""
        return f"{prefix}: {reason}" if prefix else reason
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

    try:
        return module("sonar_tof").resolve_sensor(scene, sensor)
    except ValueError as exc:
        raise SceneError(str(exc)) from None


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
    from mitsonar.plugins import module

    sonar = _sonar(scene, sensor)
    if integrator is None:
        integrator = scene.integrator()
        if not hasattr(integrator, "render_histogram"):
            integrator = mi.load_dict({"type": "sonar_tof"})
    elif isinstance(integrator, dict):
        integrator = mi.load_dict(integrator)
    elif isinstance(integrator, str):
        integrator = mi.load_dict({"type": integrator})
    if not hasattr(integrator, "render_histogram"):
        raise SceneError(f"integrator {type(integrator).__name__} is not a sonar integrator (sonar_tof)")
    if pose is not None:
        pose = np.asarray(pose, dtype=np.float64)
    try:
        hist = integrator.render_histogram(scene, sonar, seed=seed, spp=spp, pose=pose, max_depth=max_depth,
                                           progress=progress)
    except ValueError as exc:
        raise SceneError(str(exc)) from None

    from .electronics import Electronics

    settings = dict(sonar.electronics)
    settings.update(electronics or {})
    try:
        model = Electronics.from_dict(settings, source="render_scan electronics" if electronics else "sonar")
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    intensity = hist.astype(np.float32)
    ranges = sonar.bin_centres()
    eseed = seed if electronics_seed is None else electronics_seed
    data = model.apply(intensity, ranges, absorption=sonar.absorption, sound_speed=sonar.sound_speed, seed=eseed)
    from . import __version__

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
    import warnings

    import mitsuba as mi

    try:
        if mi.variant() is None:
            set_variant()
        elif mi.variant() in ("llvm_ad_mono", "cuda_ad_mono"):
            from mitsonar.plugins import register

            register()
    except VariantError as exc:
        warnings.warn(f"mitsonar: {exc}", RuntimeWarning, stacklevel=3)
    mi.detail.add_variant_callback(_on_variant_change)
