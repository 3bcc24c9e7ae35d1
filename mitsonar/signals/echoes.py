"""`render_echoes`: the complex baseband pressure at each receive element of a sonar head.

Estimator. The echo paths are the incoherent renderer's (`plugins/integrators/common.py`,
``SonarIntegrator.sample``, consumed through its ``record`` callback): each path reports, per bounce,
its echo energy, range and surface point. The received field is a sum over *scatterers* frozen to
the scene, each with amplitude ``sqrt(sigma dA)`` (the square root of its echo energy), a phase of
its own and per element the delay of its path (`synthesis`):

* **rough (diffuse) surfaces**: the surface is cut by a cubic lattice of spacing ``h``
  (``scatterer_spacing``; default a quarter of the pulse's range resolution ``c / (2 B)``, so a
  resolution cell holds many scatterers); the cell holds one scatterer at the cell centre projected
  on the surface, of energy the Monte-Carlo estimate of the energy its paths return
  (``sigma dA``: the render's energy in that cell) and of phase a hash of the cell and the
  ``speckle_seed`` (uniform in [0, 2 pi): fully developed speckle emerges from their interference,
  Jackson and Richardson, *High-Frequency Seafloor Acoustics*, 2007, on seafloor speckle statistics;
  Goodman 1976). A still head sees the same scatterers at any path seed: only their energies carry
  Monte-Carlo noise, which falls with ``spp``; a moving head sees their delays change, hence the
  physical decorrelation;
* **mirror-like surfaces** (BSDF with a specular part larger than the diffuse one and a lobe
  exponent of at least 100, `plugins.integrators.paths.image_guide.MIN_EXPONENT`) are **coherent**: physical optics in
  its stationary-phase limit (the Kirchhoff approximation; Jackson and Richardson
  2007): the echoes of one shape, bounce order and range-resolution cell merge into one glint at
  their energy centroid, of amplitude ``sqrt(sum E)`` and deterministic phase ``-2 pi f_c tau`` from
  its travel time to each element. Glints closer than a resolution cell merge (their mutual
  interference is lost).

The echo energy is the incoherent renderer's with the receive pattern divided out: an element is
omnidirectional (aperture 1 m^2 in every direction) unless ``element_pattern='beam'``, and the
transmit directivity is the head's beam (mechanical, side-scan) or its transmit fan (multibeam).
With ``element_pattern='beam'`` (one element, the transducer) the mean over speckle seeds of the
matched-filtered power is therefore the incoherent `render_scan` intensity convolved with the
pulse's autocorrelation (`mitsonar.signals.processing.expected_power`). Amplitudes are in uPa:
``10^(source_level / 20) sqrt(E)`` (``source_level`` of the head's electronics, dB re 1 uPa at 1 m).

Moving objects (``velocities``: a shape's world velocity by its XML id): each scatterer on a moving
shape carries its shape's velocity into the delays (`synthesis`: the head's velocity relative to the
scatterer), so its echo has the Doppler shift of the closing speed; a moving shape's scatterers are
kept apart from other shapes' in a shared lattice cell.

Approximations, stated: a multi-bounce echo's Doppler uses its last leg's direction for both legs
and the velocity of the last shape it met; a moving object's geometry is the scene's at every
ping (its velocity moves the echoes' delays during a ping, not the shape between pings); elements
are omnidirectional.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import mitsonar.kinds as kinds

from mitsonar.signals.arrays import check_elements, interferometer, line_array
from mitsonar.signals.pulses import Pulse
from mitsonar.signals.synthesis import synthesize
from mitsonar.signals.targets import check_targets, target_scatterers

DEFAULT_SPP = 1024
#: ``elements`` by name, built at the pulse's carrier and the head's sound speed (`mitsonar.signals.arrays`):
#: a 64-element forward-looking line array at half a wavelength, a two-row interferometric side-scan.
PRESETS = {"line_array": lambda **k: line_array(64, **k), "interferometer": lambda **k: interferometer(2, **k)}
#: Lanes (paths x bounces slots) of one tracing pass: bounds the memory whatever the spp.
PASS_SLOTS = 1 << 21


@dataclass
class Echoes:
    """Element data of one render (`render_echoes`).

    ``signal`` complex64 (n_rows, n_elements, n_samples): complex baseband pressure (uPa), passband
    ``Re{ s(t) exp(i 2 pi carrier t) }``, sample k at ``k / sample_rate`` s after that row's pulse
    started; ``elements`` (n_elements, 3) m in the beam frame; ``sample_rate`` Hz; ``carrier`` Hz;
    ``pulse``; ``times`` (n_rows,) s of each row's ping; ``poses`` (n_rows, 4, 4) each row's beam
    frame (a multibeam head's: its frame at bearing 0); ``sound_speed`` m/s; ``kind``; the head's
    ``range_min``/``range_max`` and, for beamforming, ``bearings`` (rad) and ``n_bins`` of its
    receive beams; ``meta`` provenance (``pressure_scale``: uPa per sqrt of energy).
    """

    signal: np.ndarray
    elements: np.ndarray
    sample_rate: float
    carrier: float
    pulse: Pulse
    times: np.ndarray
    poses: np.ndarray
    sound_speed: float
    kind: str = kinds.DEFAULT
    range_min: float = 0.0
    range_max: float = 12.0
    bearings: np.ndarray | None = None
    n_bins: int = 500
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return int(self.signal.shape[-1])

    @property
    def sample_times(self) -> np.ndarray:
        """s: the time of each sample from the row's pulse start."""
        return np.arange(self.n_samples) / self.sample_rate

    @property
    def wavelength(self) -> float:
        return self.sound_speed / self.carrier


def _elements(elements, where):
    """The ``elements`` argument as positions: None (one element at the origin), an (n, 3) array, or the
    path of a CSV of x,y,z rows (`mitsonar.signals.arrays.read_elements`)."""
    import os

    if elements is None:
        return np.zeros((1, 3))
    if isinstance(elements, (str, os.PathLike)):
        if not os.path.isfile(elements):
            raise ValueError(f"{where} 'elements': {str(elements)!r} is not allowed (an (n, 3) array, the path of "
                             f"a CSV of x,y,z rows in m, or a preset: {', '.join(PRESETS)})")
        from mitsonar.signals.arrays import read_elements

        return read_elements(elements, f"{where} (elements file {os.fspath(elements)})")
    return check_elements(elements, where)


def _check_pulse(pulse):
    if not isinstance(pulse, Pulse):
        raise ValueError(f"render_echoes 'pulse': {type(pulse).__name__} is not allowed (a Pulse from "
                         "mitsonar.signals.cw or mitsonar.signals.lfm)")


def head_band(sonar) -> tuple[float, float]:
    """(low, high) Hz: the head's band, the sensor's ``frequency`` +- half its ``bandwidth`` (the
    XML's, else a preset's published band, else ``frequency / 2``: `plugins.sensors.sonar.DEFAULT_Q`)."""
    f = float(sonar.beam.frequency)
    bw = float(sonar.bandwidth)
    return f - 0.5 * bw, f + 0.5 * bw


def _velocities(trajectory, t, mount_times_shape):
    """(n, 3) m/s of the platform at times ``t`` (central differences on the trajectory)."""
    if trajectory is None:
        return np.zeros(mount_times_shape + (3,))
    lo, hi = trajectory.span
    h = 1e-3
    a = np.clip(t - h, lo, hi)
    b = np.clip(t + h, lo, hi)
    pa, pb = trajectory.at(a)[..., :3, 3], trajectory.at(b)[..., :3, 3]
    return (pb - pa) / np.maximum(b - a, 1e-12)[..., None]


def _phase(cells, seed):
    """Uniform phases in [0, 2 pi) of lattice cells (int64 (n, 3)) for a speckle seed (splitmix64)."""
    with np.errstate(over="ignore"):
        z = (cells[:, 0].astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
             ^ cells[:, 1].astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
             ^ cells[:, 2].astype(np.uint64) * np.uint64(0x165667B19E3779F9)
             ^ np.uint64(seed) * np.uint64(0x27D4EB2F165667C5))
        for shift, mul in ((30, 0xBF58476D1CE4E5B9), (27, 0x94D049BB133111EB)):
            z = (z ^ (z >> np.uint64(shift))) * np.uint64(mul)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * (2.0 * np.pi / 2.0 ** 53)


def render_echoes(scene, pulse, *, elements=None, sample_rate=None, spp=DEFAULT_SPP, seed=0, speckle_seed=None,
                  pose=None, trajectory=None, start_time=None, sensor=0, max_depth=None,
                  scatterer_spacing=None, element_pattern=None, velocities=None, targets=None) -> Echoes:
    """Render the element data of one scan of ``scene`` for a transmitted ``pulse`` (module docstring).

    A row is one transmission: one per ping for a mechanical or side-scan head, one per frame for a
    multibeam head (its receive beams come from `mitsonar.signals.beamform`). ``elements`` (n, 3) m in
    the beam frame (default the sensor's XML ``elements``, else one element at the transmitter, the
    origin), the path of a CSV of x,y,z rows, or a preset name (`PRESETS`: ``line_array``, ``interferometer``); ``sample_rate`` Hz (default
    twice the pulse's bandwidth, ``4 / duration`` for a CW); ``spp`` paths per row; ``seed`` the
    paths'; ``speckle_seed`` the scene's scatterers (default the sensor's, 0); ``pose``,
    ``trajectory``, ``start_time``, ``sensor``, ``max_depth`` as `mitsonar.render_scan`;
    ``scatterer_spacing`` m, the lattice of rough-surface scatterers (default ``c / (8 B)``);
    ``element_pattern`` the elements' own directivity: None omnidirectional, ``beam`` the head's beam
    (a mechanical or side-scan head's transducer used as its own receiver: its echoes then carry the
    two-way pattern of `mitsonar.render_scan`, the setting in which the two agree on average);
    ``velocities`` {shape id: (vx, vy, vz)} m/s in the world, the shapes that move (their echoes'
    Doppler shift; module docstring), each finite and slower than a tenth of the sound speed;
    ``targets`` a `mitsonar.signals.PointTarget` or a list of them: isotropic, deterministic point
    scatterers of a given target strength summed coherently with the scene's echoes
    (`mitsonar.signals.targets`). With a ``trajectory``, ``meta`` holds ``start_time`` and
    ``mounts`` (n_rows, 4, 4), each row's beam frame in the vehicle frame, and ``velocities``
    (n_rows, 3) m/s, the platform's, so a processor can place the rows along another trajectory (`mitsonar.sas.form_image`'s ``navigation``).
    Refused in one line before any rendering: non-finite or overlapping elements, a sample rate
    below the pulse's bandwidth, a pulse longer than the two-way window ``2 range_max / c``, a
    carrier outside the head's band (`head_band`).
    """
    from mitsonar.sim.render import (SEED_ALLOWED, SEED_MAX, SPP_ALLOWED, SPP_MAX, _check_pose,
                                     _check_start_time, _whole, moving_head_poses, pick_sensor)
    from mitsonar.sim.scene import SceneError, sonar_of
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    where = "render_echoes"
    try:
        _check_pulse(pulse)
        target_pos, target_ts = check_targets(targets, where)
        e = None if isinstance(elements, str) and elements in PRESETS else _elements(elements, where)
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    spp = _whole("spp", spp, 1, SPP_MAX, SPP_ALLOWED, where)
    seed = _whole("seed", seed, 0, SEED_MAX, SEED_ALLOWED, where)
    if pose is not None:
        pose = _check_pose(pose)
    if trajectory is not None:
        start_time = _check_start_time(trajectory, start_time)
    elif start_time is not None:
        raise SceneError(f"{where} 'start_time': only used with a 'trajectory'")
    if isinstance(sensor, str):
        sensor = pick_sensor(scene, sensor, f"{where} 'sensor':")
    sonar = sonar_of(scene, sensor)
    c = float(sonar.sound_speed)
    if elements is None and getattr(sonar, "elements", None) is not None:
        e = np.array(sonar.elements, dtype=np.float64)     # the sensor's XML elements (checked on load)
    elif e is None:   # a preset at the pulse's carrier
        e = PRESETS[elements](frequency=pulse.carrier, sound_speed=c)
    if speckle_seed is None:
        speckle_seed = int(sonar.electronics.get("speckle_seed", 0))
    speckle_seed = _whole("speckle_seed", speckle_seed, 0, SEED_MAX, SEED_ALLOWED, where)
    fs = pulse.default_sample_rate() if sample_rate is None else sample_rate
    if isinstance(fs, bool) or not isinstance(fs, (int, float, np.integer, np.floating)) or not math.isfinite(fs) \
            or fs < pulse.bandwidth:
        raise SceneError(f"{where} 'sample_rate': {fs!r} is not allowed (a rate >= the pulse's bandwidth, "
                         f"{pulse.bandwidth:g} Hz)")
    fs = float(fs)
    flight = 2.0 * sonar.range_max / c
    if pulse.duration > flight:
        raise SceneError(f"{where} 'pulse': its duration {pulse.duration:g} s is not allowed (at most the two-way "
                         f"window 2 range_max / sound_speed = {flight:.6g} s)")
    lo, hi = head_band(sonar)
    if not lo <= pulse.carrier <= hi:
        raise SceneError(f"{where} 'pulse': its carrier {pulse.carrier:g} Hz is not allowed (inside the head's band "
                         f"{lo:g} to {hi:g} Hz: frequency +- bandwidth / 2)")
    if element_pattern not in (None, "beam") or (element_pattern == "beam" and sonar.sonar_kind.transmit_fan):
        raise SceneError(f"{where} 'element_pattern': {element_pattern!r} is not allowed (None for omnidirectional "
                         "elements, or 'beam' for the transducer's own beam on a mechanical or side-scan head)")
    moving = _velocity_table(scene, velocities, c, where)
    h = pulse.range_resolution(c) / 4.0 if scatterer_spacing is None else scatterer_spacing
    if isinstance(h, bool) or not isinstance(h, (int, float, np.integer, np.floating)) or not (math.isfinite(h) and h > 0):
        raise SceneError(f"{where} 'scatterer_spacing': {h!r} is not allowed (a spacing > 0 m)")

    # Rows: one per ping (mechanical, side-scan), one per frame (multibeam: its frame at bearing 0).
    times = sonar.ping_times()
    if trajectory is not None:
        pose = moving_head_poses(sonar, trajectory, start_time, pose)
    try:
        if sonar.sonar_kind.transmit_fan:
            heads = sonar.head_pose(pose)
            row_poses = (heads[:1] if heads.ndim == 3 else heads[None]).copy()
            times = times[:1]
        else:
            row_poses = sonar.ping_poses(pose)
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    n_rows = len(row_poses)
    velocity = _velocities(trajectory, (start_time or 0.0) + times, times.shape)
    n_samples = int(math.ceil((flight + pulse.duration) * fs))

    scatterers = _trace(scene, sonar, row_poses, spp, seed, max_depth, h, pulse.range_resolution(c), speckle_seed,
                        omni=element_pattern is None, moving=None if moving is None else moving.any(axis=1))
    scale = 10.0 ** (float(sonar.electronics_model.source_level) / 20.0)
    signal = np.zeros((n_rows, len(e), n_samples), dtype=np.complex64)
    gain = _beam_gain(sonar.transmit if sonar.sonar_kind.transmit_fan else sonar.beam)
    for r in range(n_rows):
        amp, pos, out, shape = scatterers[r]
        R, o = row_poses[r, :3, :3], row_poses[r, :3, 3]
        w = None if moving is None else moving[shape]
        if len(target_pos):
            ta, tp, to = target_scatterers(target_pos, target_ts, row_poses[r], gain, float(sonar.absorption),
                                           two_way=element_pattern == "beam")
            amp, pos, out = np.concatenate([amp, ta]), np.concatenate([pos, tp]), np.concatenate([out, to])
            if w is not None:
                w = np.concatenate([w, np.zeros((len(ta), 3))])
        signal[r] = synthesize(amp * scale, pos, out, e @ R.T + o, o, pulse, fs, n_samples, c,
                               velocity=velocity[r], scatterer_velocity=w).astype(np.complex64)
    meta = {"spp": spp, "seed": seed, "speckle_seed": speckle_seed, "scatterer_spacing": float(h),
            "pressure_scale": scale, "n_scatterers": int(sum(len(s[0]) for s in scatterers)),
            "band": (lo, hi), "electronics": sonar.electronics_model.to_dict(), "absorption": float(sonar.absorption),
            "bearing_start": float(sonar.bearing_start), "bearing_step": float(sonar.bearing_step)}
    if sonar.sonar_kind.sided:
        meta.update(side=sonar.side, depression=float(sonar.depression))
    if len(target_pos):
        meta["n_targets"] = len(target_pos)
    if trajectory is not None:
        vehicle = trajectory.at(start_time + times)
        meta.update(start_time=float(start_time), mounts=np.linalg.inv(vehicle) @ row_poses, velocities=velocity)
    return Echoes(signal=signal, elements=e, sample_rate=fs, carrier=pulse.carrier, pulse=pulse, times=times,
                  poses=row_poses, sound_speed=c, kind=sonar.kind, range_min=float(sonar.range_min),
                  range_max=float(sonar.range_max), bearings=np.radians(sonar.bearings_deg()),
                  n_bins=int(sonar.n_bins), meta=meta)


def _beam_gain(beam):
    """numpy (n, 3) beam-frame unit directions -> (n,) one-way gain of ``beam`` (a plugin beam)."""
    def gain(d):
        import mitsuba as mi

        d = np.asarray(d, dtype=np.float64)
        return np.asarray(beam.eval_dir(mi.Vector3f(d[:, 0], d[:, 1], d[:, 2])).numpy(), dtype=np.float64)

    return gain


def _shape_tables(scene):
    """(pointer -> shape index table, per-shape coherent flags) of the scene's shapes."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.bsdfs.acoustic import AcousticBSDF as acoustic
    from mitsonar.plugins.integrators.paths import image_guide as guide

    shapes = scene.shapes()
    registry = dr.reinterpret_array(mi.UInt32, scene.shapes_dr()).numpy() if shapes else np.zeros(1, np.uint32)
    table = np.zeros(int(registry.max()) + 1, np.uint32)
    table[registry] = np.arange(len(registry), dtype=np.uint32)
    coherent = []
    for s in shapes:
        b = s.bsdf()
        mirror = guide.lobe_exponent(b) >= guide.MIN_EXPONENT
        if isinstance(b, acoustic):
            d, sp = (float(dr.detach(getattr(b, k))[0]) for k in ("diffuse", "specular"))
            mirror = mirror and sp > d
        coherent.append(mirror)
    return mi.UInt32(table), np.array(coherent + [False], dtype=bool)


def _velocity_table(scene, velocities, c, where):
    """(n_shapes + 1, 3) m/s of each shape (the last row: no shape), None when nothing moves; or a
    SceneError naming ``velocities`` in one line."""
    from mitsonar.sim.scene import SceneError

    if velocities is None or (isinstance(velocities, dict) and not velocities):
        return None
    ids = [s.id() for s in scene.shapes()]
    if not isinstance(velocities, dict):
        raise SceneError(f"{where} 'velocities': {type(velocities).__name__} is not allowed (a dict of shape id: "
                         "(vx, vy, vz) m/s)")
    table = np.zeros((len(ids) + 1, 3))
    for name, value in velocities.items():
        if not name or name not in ids:
            named = ", ".join(repr(i) for i in ids if i) or "none has an id"
            raise SceneError(f"{where} 'velocities': {name!r} is not allowed (a shape id of the scene: {named})")
        try:
            v = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            v = np.full(1, np.nan)
        if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) >= 0.1 * c:
            raise SceneError(f"{where} 'velocities': {name!r}: {value!r} is not allowed (a finite (vx, vy, vz) in "
                             f"m/s, slower than a tenth of the sound speed, {0.1 * c:g} m/s)")
        table[ids.index(name)] = v
    return table


def _trace(scene, sonar, row_poses, spp, seed, max_depth, spacing, resolution, speckle_seed, omni=True, moving=None):
    """Per row, the scatterers (complex amplitude sqrt(E) e^{i phi}, position (n, 3), outbound length
    (n,), shape index (n,): the last index for a still shape's rough scatterers) from ``spp`` paths per row, streamed in passes of at most `PASS_SLOTS` echo slots."""
    import types

    import drjit as dr
    import mitsuba as mi

    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.integrators.paths.samples import HashSamples, row_lanes
    from mitsonar.plugins.sensors.sonar import PingFrames

    integ = scene.integrator()
    depth = int(max_depth) if max_depth is not None else int(getattr(integ, "max_depth", 5) or 5)
    integrator = mi.load_dict({"type": "sonar_tof", "max_depth": depth, "guide": "none"})
    setup = integrator.setup(scene, sonar)
    beam = sonar.transmit if sonar.sonar_kind.transmit_fan else sonar.beam
    setup.frames = PingFrames(row_poses)
    setup.connect = None
    setup.sensor = types.SimpleNamespace(beam=beam)
    setup.guide = False
    table, coherent = _shape_tables(scene)
    moving = np.zeros(len(coherent), bool) if moving is None else moving
    n_rows = len(row_poses)
    count_max = max(1, PASS_SLOTS // (n_rows * depth))
    acc = _Accumulator(n_rows)
    start = 0
    with dr.suspend_grad():
        while start < spp:
            count = min(count_max, spp - start)
            n = n_rows * count * depth
            ping, samples = row_lanes(HashSamples, n_rows, seed, start, count)
            lane = dr.arange(mi.UInt32, n_rows * count)
            store = [dr.zeros(mi.Float, n) for _ in range(8)]
            shape_of = dr.zeros(mi.UInt32, n)
            depth_o = dr.opaque(mi.UInt32, depth)

            def record(k, rng, energy, valid, hit):
                x_ax, y_ax, z_ax, origin = setup.frames.gather(ping)
                d = hit.p - origin
                dist = dr.norm(d)
                d = d / dist
                gain = beam.eval_dir(mi.Vector3f(dr.dot(d, x_ax), dr.dot(d, y_ax), dr.dot(d, z_ax)))
                e_tx = dr.select(gain > 0, energy / gain, 0.0) if omni else energy
                ok = valid & (e_tx > 0)
                slot = lane * depth_o + k
                n_ = hit.n
                for arr, val in zip(store, (hit.p.x, hit.p.y, hit.p.z, n_.x, n_.y, n_.z, 2.0 * rng - dist, e_tx)):
                    dr.scatter(arr, val, slot, ok)
                dr.scatter(shape_of, dr.gather(mi.UInt32, table, dr.reinterpret_array(mi.UInt32, hit.shape), ok),
                           slot, ok)

            integrator.sample(setup, ping, samples, record)
            dr.eval(store, shape_of)
            vals = np.stack([a.numpy() for a in store], axis=1).astype(np.float64)
            shp = shape_of.numpy().astype(np.int64)
            rows = np.repeat(ping.numpy().astype(np.int64), depth)
            ks = np.tile(np.arange(depth), n_rows * count)
            energy = vals[:, 7]
            energy[np.abs(energy) < np.finfo(np.float32).tiny] = 0.0
            keep = energy > 0
            acc.add(rows[keep], ks[keep], shp[keep], vals[keep], coherent[shp[keep]], row_poses, spacing, resolution,
                    moving[shp[keep]])
            start += count
    return acc.scatterers(spp, row_poses, speckle_seed)


class _Accumulator:
    """Energy and energy-weighted positions per scatterer key, summed over passes (module docstring)."""

    def __init__(self, n_rows):
        self.keys = np.zeros((0, 7), np.int64)    # row, k, coherent, shape/-1, ix, iy, iz
        self.sums = np.zeros((0, 5))              # E, E x, E y, E z, E excess
        self.spacing = None

    def add(self, rows, ks, shapes, vals, coh, row_poses, spacing, resolution, moving=None):
        self.spacing = spacing
        p, nrm, out, E = vals[:, 0:3], vals[:, 3:6], vals[:, 6], vals[:, 7]
        o = row_poses[rows, :3, 3]
        dist = np.linalg.norm(p - o, axis=1)
        excess = out - dist
        cell = np.floor(p / spacing).astype(np.int64)
        # a glint's key: its range-resolution cell (range = half the total path length)
        cell[coh] = 0
        cell[coh, 0] = np.floor(0.5 * (out[coh] + dist[coh]) / resolution).astype(np.int64)
        centre = (cell + 0.5) * spacing
        n_len = np.maximum(np.linalg.norm(nrm, axis=1), 1e-12)
        nrm = nrm / n_len[:, None]
        proj = centre + (np.sum((p - centre) * nrm, axis=1))[:, None] * nrm
        pos = np.where(coh[:, None], p, proj)
        apart = coh if moving is None else coh | moving      # scatterers that keep their shape
        keys = np.column_stack([rows, ks, coh.astype(np.int64), np.where(apart, shapes, -1), cell])
        sums = np.column_stack([E, E[:, None] * pos, E * excess])
        allk = np.concatenate([self.keys, keys])
        alls = np.concatenate([self.sums, sums])
        uniq, inv = np.unique(allk, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        self.keys = uniq
        self.sums = np.stack([np.bincount(inv, weights=alls[:, j], minlength=len(uniq)) for j in range(5)], axis=1)

    def scatterers(self, spp, row_poses, speckle_seed):
        out = []
        for r in range(len(row_poses)):
            m = self.keys[:, 0] == r
            k, s = self.keys[m], self.sums[m]
            E = s[:, 0]
            pos = s[:, 1:4] / E[:, None]
            outbound = np.linalg.norm(pos - row_poses[r, :3, 3], axis=1) + s[:, 4] / E
            phase = np.where(k[:, 2] == 1, 0.0, _phase(k[:, 4:7], speckle_seed))
            out.append((np.sqrt(E / spp) * np.exp(1j * phase), pos, outbound, k[:, 3]))
        return out
