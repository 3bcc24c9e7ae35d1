"""`render_scan`: one scan of a scene through the sonar integrators and the head's electronics."""
from __future__ import annotations

import contextlib

import math
import warnings

import numpy as np

from mitsonar._checks import is_whole
from mitsonar._limits import LIMITS
from mitsonar.geometry.frames import check_rigid
from mitsonar.scan import ElectronicsSettings, Scan, ScanMeta
from mitsonar.sim.scene import SceneError, mitsuba_error, scene_name, sonar_of
from mitsonar.geometry.trajectory import Trajectory
from mitsonar.sim.variant import ensure_variant

DEFAULT_SPP = 4096

# Names that lived here before the scene, variant and ground-truth modules; importable from here
# for one release, with a DeprecationWarning.
_MOVED = {"load_scene": "sim.scene", "set_variant": "sim.variant", "variant": "sim.variant",
          "init_on_import": "sim.variant", "VariantError": "sim.variant", "scene_mesh": "sim.groundtruth"}


def __getattr__(name):
    if name in _MOVED:
        import importlib

        warnings.warn(f"mitsonar.sim.render.{name} is deprecated: import it from mitsonar.{_MOVED[name]} "
                      f"(or from mitsonar)", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(f"mitsonar.{_MOVED[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _whole(name, value, lo, hi, what, where="render_scan"):
    """A count or seed argument: a whole number in [lo, hi] (4096.0 counts; 1.5, True, "8" do not)."""
    if not (is_whole(value) and lo <= value <= hi):
        raise SceneError(f"{where} '{name}': {value!r} is not allowed ({what})")
    return int(value)


def _check_pose(pose):
    """A render's pose in one sentence: array-like, 4x4, finite, rigid."""
    try:
        m = np.asarray(pose, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"render_scan 'pose': expected a 4x4 rigid transform (array-like), got "
                         f"{type(pose).__name__} {pose!r:.40}") from None
    try:
        return check_rigid(m, "render_scan 'pose'")
    except ValueError as exc:
        raise SceneError(str(exc)) from None


def _check_start_time(trajectory, start_time):
    """A render's trajectory and start time in one sentence each (the span is checked later, with
    the sensor's ping schedule)."""
    if not isinstance(trajectory, Trajectory):
        raise SceneError(f"render_scan 'trajectory': expected a mitsonar.Trajectory, got {type(trajectory).__name__}")
    if start_time is None:
        return float(trajectory.times[0])
    if (isinstance(start_time, bool) or not isinstance(start_time, (int, float, np.integer, np.floating))
            or not math.isfinite(start_time)):
        raise SceneError(f"render_scan 'start_time': {start_time!r} is not allowed (a finite time in seconds, "
                         "on the trajectory's clock)")
    return float(start_time)


class Frame:
    """What `render_frame` returns: ``intensity`` (``mi.Float32``, the noise-free echo energy per
    bin) and ``data`` (``mi.UInt8``, the device's bytes; ``mi.UInt32`` codes of a 16- or 32-bit
    A/D), Dr.Jit arrays of ``shape = (n_rows,
    n_bins)`` values in row-major order; ``numpy()`` gives both as NumPy arrays of that shape."""

    __slots__ = ("intensity", "data", "shape", "_scan")

    def __init__(self, intensity, data, shape):
        self.intensity, self.data, self.shape, self._scan = intensity, data, tuple(shape), None

    def numpy(self):
        """(intensity float32, data uint8), each ``shape``."""
        return self.intensity.numpy().reshape(self.shape), self.data.numpy().reshape(self.shape)


def moving_head_poses(sonar, trajectory, start_time, mount=None):
    """(n_pings, 4, 4) head pose of each row, ``trajectory.at(start_time + times[k]) @ mount``
    (``mount``: the sensor's ``to_world`` unless given), refused with one sentence naming the
    scan's ping times and the trajectory's span when the pings do not fit in it."""
    t = start_time + sonar.ping_times()
    if not trajectory.covers(t[0], t[-1]):
        lo, hi = trajectory.span
        raise SceneError(f"render_scan 'start_time': the scan's pings at {t[0]:.9g} .. {t[-1]:.9g} s "
                         f"({sonar.n_pings} pings, ping_period {sonar.ping_period:.6g} s) do not fit in the "
                         f"trajectory's span [{lo:.9g}, {hi:.9g}] s")
    return trajectory.at(t) @ (sonar.to_world_np if mount is None else mount)


def sonar_integrators() -> tuple:
    """The XML names of mitsonar's integrators (``sonar_bdpt``, ...), as registered for the variant, sorted."""
    ensure_variant()
    from mitsonar.plugins import registered

    return tuple(sorted(name for name, (family, _) in registered().items() if family == "integrator"))


SEED_MAX = 2 ** 32 - 1   # the path seed is a 32-bit integer: larger seeds would repeat smaller ones
SPP_MAX = int(LIMITS["spp"].hi)    # paths per ping: a signed 32-bit count (`mitsonar._limits`)
SPP_ALLOWED = LIMITS["spp"].allowed()
SEED_ALLOWED = f"a whole number from 0 to {SEED_MAX}"


def sensor_list(scene) -> str:
    """The scene's sensors for a message: ``0 'sonar' (mechanical), 1 'cam' (PerspectiveCamera)``
    (index, XML id, sonar kind or the sensor's class)."""
    items = []
    for i, s in enumerate(scene.sensors()):
        kind = getattr(s, "kind", None) if hasattr(s, "ping_times") else None
        items.append(f"{i} {s.id()!r} ({kind or type(s).__name__})")
    return ", ".join(items) or "none"


def pick_sensor(scene, sensor=None, option="--sensor"):
    """The sonar sensor a command line names: ``sensor`` is its XML id or its index in the scene's
    sensors (a string of digits counts as an index); None: the first sonar sensor, with one
    warning naming it when the scene has several. Refused with one `SceneError` naming the
    scene, ``option`` and its sensors (index, id, kind). Returns the sensor object, which
    `render_scan` and `render_survey` take without warning again."""
    ensure_variant()
    from mitsonar.plugins.sensors.sonar import SonarSensor

    name = scene_name(scene) or "the scene"
    sensors = list(scene.sensors())
    sonars = [s for s in sensors if isinstance(s, SonarSensor)]
    listing = sensor_list(scene)
    if sensor is None:
        if not sonars:
            raise SceneError(f'{name}: needs a <sensor type="sonar"> (sensors found: {listing})')
        chosen = sonars[0]
        if len(sonars) > 1:
            warnings.warn(f"{name} has {len(sonars)} sonar sensors ({listing}); rendering "
                          f"{sensors.index(chosen)} {chosen.id()!r} (choose with {option} ID|INDEX)", stacklevel=2)
        return chosen
    text = str(sensor).strip()
    if text.isdigit():
        index = int(text)
        if index >= len(sensors):
            raise SceneError(f"{name}: {option} {text}: no sensor of that index; its sensors: {listing}")
        chosen = sensors[index]
    else:
        found = [s for s in sensors if s.id() == text]
        if not found:
            raise SceneError(f"{name}: {option} {text!r}: no sensor of that id; its sensors: {listing}")
        chosen = found[0]
    if not isinstance(chosen, SonarSensor):
        raise SceneError(f"{name}: {option} {text}: not a sonar sensor; its sensors: {listing}")
    return chosen


def _integrator(scene, integrator):
    import mitsuba as mi

    ensure_variant()
    from mitsonar.plugins.integrators.common import SonarIntegrator as base

    if integrator is None:
        integrator = scene.integrator()
        if not isinstance(integrator, base):
            if integrator is not None:  # None: the XML names no integrator, sonar_tof is the default
                name = integrator.class_name() if hasattr(integrator, "class_name") else type(integrator).__name__
                warnings.warn(f"{scene_name(scene) or 'the scene'}: its integrator {name} is not a sonar "
                              "integrator; rendering with sonar_tof", stacklevel=3)
            return mi.load_dict({"type": "sonar_tof"})
        return integrator
    if isinstance(integrator, str):
        integrator = {"type": integrator}
    if isinstance(integrator, dict):
        integrator_type = integrator.get("type")
        if integrator_type not in sonar_integrators():
            raise SceneError(f"render_scan 'integrator': {integrator_type!r} is not a sonar integrator "
                             f"(one of {', '.join(sonar_integrators())})")
        try:
            return mi.load_dict(integrator)
        except Exception as exc:
            raise SceneError(f"render_scan 'integrator': {mitsuba_error(exc)}") from None
    if not isinstance(integrator, base):
        raise SceneError(f"render_scan 'integrator': {type(integrator).__name__} is not a sonar integrator "
                         f"(one of {', '.join(sonar_integrators())})")
    return integrator


def render_frame(scene, spp: int = DEFAULT_SPP, seed: int = 0, pose=None, integrator=None, sensor=0,
                 max_depth=None, electronics=None, electronics_seed=None, progress=None, trajectory=None,
                 start_time=None, speckle_seed=None, sound_speed_profile=None) -> "Frame":
    """Render one frame of ``scene`` and pass it through the head's electronics, keeping the
    result on the device: a `Frame` whose ``intensity`` (``mi.Float32``) and ``data``
    (``mi.UInt8``) are Dr.Jit arrays of the active variant (on the GPU for ``cuda``), row-major
    ``shape = (n_rows, n_bins)``. `render_scan` is this frame brought to the host as a `Scan`;
    a caller that feeds the frame to more Dr.Jit work (a learning pipeline, a display) skips
    that transfer. From the render's exact sums to the bytes the frame stays on the device:
    ``sonar_tof`` sums and averages its passes there (`render_histogram_device`), and the receiver
    chain runs as Dr.Jit kernels (`mitsonar.receiver.devicechain`); no NumPy array on the way
    (integrators that sum on the host, ``sonar_bdpt`` and ``sonar_mlt``, upload their histogram
    once).

    Parameters
    ----------
    scene : mitsuba.Scene
        A scene from `load_scene` (or ``mi.load_*``) with a ``sonar`` sensor.
    spp : int
        Paths per ping (default 4096).
    seed : int
        Seed of the paths (and of the receiver's noise unless ``electronics_seed``).
    pose : array_like, optional
        4x4 world transform of the beam frame at bearing 0, replacing ``to_world``
        (with a ``trajectory``: the mount on the vehicle, in the vehicle frame).
    integrator : mitsuba.Integrator or dict, optional
        An integrator object or XML dict; default: the scene's if it is a sonar
        integrator, else ``sonar_tof``.
    sensor : int, str or mitsuba.Sensor
        Sensor index, XML id (a string) or object.
    max_depth : int, optional
        Override of the integrator's surface bounces.
    electronics : dict, optional
        Electronics fields overriding the sensor's (the gain and the A/D window
        within the head's 0..80 dB: `mitsonar.receiver.electronics.HEAD_LIMITS`); its
        ``speckle_seed`` picks the scene's speckle (`mitsonar.receiver.speckle`).
    electronics_seed : int, optional
        Seed of the receiver's noise only (default ``seed``): never the speckle,
        which follows the scene, the ``speckle_seed`` and the head's pose.
    progress : callable, optional
        ``progress(done_spp, spp)``, called after each render pass.
    trajectory : Trajectory, optional
        The vehicle carrying the head; ``to_world`` (or ``pose``) is
        then the mount in the vehicle frame (x forward, y port, z up).
    start_time : float, optional
        Seconds on the trajectory's clock of the scan's first ping (default: the
        trajectory's first time).
    speckle_seed : int, optional
        The scene's speckle (which scatterers its surfaces hold, `mitsonar.receiver.speckle`);
        default the sensor's ``speckle_seed`` (XML), 0 unless given.
    sound_speed_profile : mitsonar.acoustics.SoundSpeedProfile, optional
        The water the paths refract through (``sonar_tof`` only; replaces the integrator's XML
        ``sound_speed_profile`` for this render). The sensor's ``sound_speed`` stays the head's
        nominal speed: range = sound_speed x two-way travel time / 2.

    Returns
    -------
    Frame
        ``intensity`` and ``data`` as Dr.Jit arrays, and ``shape``; the same arguments give the
        same arrays, bit for bit (``intensity`` is `render_scan`'s, ``data`` its bytes).
    """
    ensure_variant()

    # Every argument is checked before the render: a mistake costs a sentence, not a render.
    spp = _whole("spp", spp, 1, SPP_MAX, SPP_ALLOWED)
    seed = _whole("seed", seed, 0, SEED_MAX, SEED_ALLOWED)
    if electronics_seed is not None:
        electronics_seed = _whole("electronics_seed", electronics_seed, 0, SEED_MAX,
                                  f"a whole number from 0 to {SEED_MAX}, or None for seed")
    if max_depth is not None:
        ensure_variant()
        from mitsonar.plugins.integrators.common import MAX_DEPTH as top
        max_depth = _whole("max_depth", max_depth, 1, top, f"a whole number of surface bounces from 1 to {top}")
    if pose is not None:
        pose = _check_pose(pose)
    if trajectory is not None:
        start_time = _check_start_time(trajectory, start_time)
    elif start_time is not None:
        raise SceneError("render_scan 'start_time': only used with a 'trajectory'")
    if electronics is not None and not isinstance(electronics, dict):
        raise SceneError(f"render_scan 'electronics': expected a dict of electronics fields, got "
                         f"{type(electronics).__name__}")
    if speckle_seed is not None:
        speckle_seed = _whole("speckle_seed", speckle_seed, 0, SEED_MAX, f"a whole number from 0 to {SEED_MAX}")
        electronics = {**(electronics or {}), "speckle_seed": speckle_seed}
    if isinstance(sensor, str):
        sensor = pick_sensor(scene, sensor, "render_scan 'sensor':")
    sonar = sonar_of(scene, sensor)
    if trajectory is not None:
        pose = moving_head_poses(sonar, trajectory, start_time, pose)
    integrator = _integrator(scene, integrator)
    if sound_speed_profile is not None:
        from mitsonar.acoustics.profile import SoundSpeedProfile

        if not isinstance(sound_speed_profile, SoundSpeedProfile):
            raise SceneError(f"render_scan 'sound_speed_profile': expected a mitsonar.acoustics.SoundSpeedProfile, "
                             f"got {type(sound_speed_profile).__name__}")
        if not getattr(integrator, "REFRACTS", False):
            raise SceneError(f"render_scan 'sound_speed_profile': refracted paths are traced by the sonar_tof "
                             f"integrator only, not {type(integrator).__name__}")

    from mitsonar.receiver.electronics import Electronics, check_head_settings

    settings = dict(sonar.electronics)
    settings.update(electronics or {})
    try:
        check_head_settings(electronics or {}, "render_scan electronics")
        model = Electronics.from_dict(settings, source="render_scan electronics" if electronics else "sonar")
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    eseed = seed if electronics_seed is None else electronics_seed
    ranges = sonar.bin_centres()
    try:
        sonar.head_pose(pose)
        with _profile_of(integrator, sound_speed_profile):
            # the mean and its float32 (as NumPy rounds it, subnormals kept), on the device
            _, intensity = integrator.render_histogram_device(scene, sonar, seed=seed, spp=spp, pose=pose,
                                                              max_depth=max_depth, progress=progress)
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    poses = sonar.ping_poses(pose)
    speckle = None if model.speckle == "off" else model.scene_speckle_field(poses, ranges, **speckle_geometry(sonar))
    shape = (int(sonar.n_pings), int(sonar.n_bins))
    data = model.device_bytes(intensity, shape, ranges, absorption=sonar.absorption, sound_speed=sonar.sound_speed,
                              seed=eseed, speckle=speckle)
    frame = Frame(intensity=intensity, data=data, shape=shape)
    frame._scan = (scene, sonar, integrator, model, ranges, poses, seed, spp, max_depth, eseed,
                   trajectory, start_time)
    return frame


def render_scan(scene, spp: int = DEFAULT_SPP, seed: int = 0, pose=None, integrator=None, sensor=0,
                max_depth=None, electronics=None, electronics_seed=None, progress=None, trajectory=None,
                start_time=None, speckle_seed=None, sound_speed_profile=None) -> Scan:
    """Render one scan of ``scene`` and pass it through the head's electronics.

    Parameters
    ----------
    scene, spp, seed, pose, integrator, sensor, max_depth, electronics, electronics_seed, progress,
    trajectory, start_time, speckle_seed, sound_speed_profile
        As `render_frame`'s (below).

    Returns
    -------
    Scan
        The noise-free ``intensity`` and the device's ``data``, with the ranges, bearings,
        poses and times of every row: `render_frame`'s arrays brought to the host (one transfer).

    Notes
    -----
    With a trajectory, row k is pinged at ``start_time + scan.times[k]`` (the sensor's
    ``ping_period`` schedule) from ``scan.poses[k] = trajectory.at(start_time + times[k]) @ mount
    @ bearing_rotation(bearings[k])``, all rows in one wavefront as for a static head. The head
    is taken as still during one ping's flight ``T = 2 range_max / sound_speed``: moving at ``v``,
    an echo's range differs from the range measured at the ping's pose by at most ``v T / 2``
    (1.6 cm at 2 m/s and 12 m, under one 2.4 cm bin of the default 500 bins).
    The same arguments give the same scan, bit for bit.
    """
    import mitsuba as mi

    frame = render_frame(scene, spp=spp, seed=seed, pose=pose, integrator=integrator, sensor=sensor,
                         max_depth=max_depth, electronics=electronics, electronics_seed=electronics_seed,
                         progress=progress, trajectory=trajectory, start_time=start_time,
                         speckle_seed=speckle_seed, sound_speed_profile=sound_speed_profile)
    (scene, sonar, integrator, model, ranges, poses, seed, spp, max_depth, eseed, trajectory,
     start_time) = frame._scan
    from mitsonar.receiver import devicechain

    # the frame's one transfer to the host: its intensity and bytes
    intensity = frame.intensity.numpy().reshape(frame.shape)
    data = devicechain.host_codes(frame.data, frame.shape, model.bit_depth)
    from mitsonar._version import __version__

    transmit = getattr(sonar, "transmit", None)   # multibeam: the transmit fan beside the receive beams
    # the fields of every scan, then what the kind records beyond them (a side-scan's channels and
    # their tilt, a volumetric grid): one record, built once
    meta = ScanMeta.from_dict(dict(
        scene=scene_name(scene), seed=int(seed), spp=int(spp), integrator=type(integrator).__name__,
        max_depth=int(max_depth if max_depth is not None else getattr(integrator, "max_depth", 0)),
        mitsonar_version=__version__, variant=mi.variant(),
        bearing_start=sonar.bearing_start, bearing_step=sonar.bearing_step, electronics_seed=int(eseed),
        ping_period=float(sonar.ping_period), frequency=float(sonar.beam.frequency), speckle="scene",
        aperture_h=float(sonar.beam.across_aperture()),
        directivity_index=float(sonar.beam.directivity_index()),   # the receive beam's, for the SNR
        start_time=start_time if trajectory is not None else None,
        tx_pattern=None if transmit is None else transmit.pattern,
        tx_beamwidth_h=None if transmit is None else transmit.beamwidth_h,
        tx_beamwidth_v=None if transmit is None else transmit.beamwidth_v,
        **sonar.sonar_kind.render_meta(sonar)))
    return Scan(intensity=intensity, data=data, ranges=ranges,
                bearings=np.radians(sonar.bearings_deg()), poses=poses, times=sonar.ping_times(),
                range_min=sonar.range_min, range_max=sonar.range_max,
                beam_pattern=sonar.beam.pattern, beamwidth_h=sonar.beam.beamwidth_h,
                beamwidth_v=sonar.beam.beamwidth_v, kind=sonar.kind, sound_speed=sonar.sound_speed,
                absorption=sonar.absorption,
                electronics=ElectronicsSettings.from_dict({**model.to_dict(), "seed": int(eseed)}), meta=meta)


@contextlib.contextmanager
def _profile_of(integrator, profile):
    """``integrator`` rendering through ``profile`` for the block (None: its own, unchanged)."""
    if profile is None:
        yield
        return
    before = integrator.sound_speed_profile
    integrator.sound_speed_profile = profile
    try:
        yield
    finally:
        integrator.sound_speed_profile = before


def speckle_geometry(sonar) -> dict:
    """The head's numbers that shape its scene speckle (`Electronics.scene_speckle`'s keywords)."""
    return {"sound_speed": sonar.sound_speed, "beamwidth_h": sonar.beam.beamwidth_h,
            "aperture_h": sonar.beam.across_aperture()}


def scan_parameters(scene, keys=None):
    """The scene's differentiable scan parameters, for ``mi.render(scene, params, ...)``.

    ``keys``: a name or a list of names (None: all of them) among the parameters mitsonar's
    plugins differentiate: the sonar sensor's ``<id>.to_world``, ``<id>.absorption``,
    ``<id>.beamwidth_h``/``_v`` (gaussian beam) and the acoustic BSDF's ``<id>.diffuse``,
    ``.specular``, ``.shininess`` (a textured diffuse: its texture's ``<id>.diffuse.data``), and a
    mesh's ``<id>.vertex_positions`` (single-bounce echoes, silhouettes ignored; see
    docs/tutorials/gradients.rst; a scene asked for vertex positions is rendered without frozen
    passes from then on: a replay would cast rays at the geometry it recorded). Returns ``mi.traverse(scene)`` kept to those keys. Refused in one line: a variant without
    automatic differentiation, or a key that is not one of these (the message lists them).
    """
    import re

    import drjit as dr
    import mitsuba as mi

    ensure_variant()
    if not dr.is_diff_v(mi.Float):
        raise SceneError(f"scan_parameters: gradients need a Mitsuba variant with automatic differentiation "
                         f"(llvm_ad_mono, cuda_ad_mono); the active variant is {mi.variant()}")
    params = mi.traverse(scene)
    from mitsonar.plugins.integrators.paths import frozen_pass, path_replay

    allowed = path_replay.differentiable_keys(params)
    wanted = allowed if keys is None else [keys] if isinstance(keys, str) else list(keys)
    for k in wanted:
        if k not in allowed:
            raise SceneError(f"scan_parameters: {k!r} is not a differentiable parameter of this scene; "
                             f"allowed: {', '.join(allowed) or 'none'}")
    params.keep([re.escape(k) + "$" for k in wanted])
    if any(k.endswith(".vertex_positions") for k in wanted):
        # a frozen pass replays the ray casts of the geometry it recorded: a scene whose meshes
        # move is traced every pass (plugins/integrators/paths/frozen_pass.py, `trace_every_pass`)
        frozen_pass.trace_every_pass(scene)
    return params
