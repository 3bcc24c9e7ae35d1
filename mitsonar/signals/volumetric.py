"""3D imaging sonar: a 2D receive array beamformed in azimuth and elevation into a volume.

A `Volumetric` head (a Coda Octopus Echoscope-like sonar) transmits one wide fan and receives on a
planar array of ``rows x columns`` elements at ``pitch`` in its beam frame's x (azimuth, across
the columns) and y (elevation, across the rows), facing +z. One transmission gives a volume of
range x azimuth x elevation, not a fan image that collapses elevation:

* `render_echoes` renders the element data: the head is a ``volumetric`` sensor (its rows the
  beam grid, `mitsonar.kinds.Volumetric`) whose transmit fan covers the field of view
  (`Volumetric.sensor_xml`) and whose elements are the planar array (`Volumetric.elements`); one
  row, the frame's transmission; `mitsonar.render_scan` of that sensor renders each beam's echo
  energy straight from its receive beam (`mitsonar.scan.Scan.volume` gives the volume);
* `beamform_3d` focuses it: for every voxel ``q = r u(az, el)`` (``u = (cos el sin az, sin el,
  cos el cos az)``, the beam frame's azimuth ``atan2(x, z)`` and elevation ``asin(y)``) the exact
  two-way delay of every element (`mitsonar.signals.focusing`: focused near-field delay-and-sum,
  not only far-field steering, so a target inside the array's Fraunhofer distance ``2 L^2 /
  lambda`` is imaged sharp at its own range). The volume is (n_elevation, n_azimuth, n_bins);
* `point_cloud` keeps the strongest (or the first) return per beam above a threshold: x, y, z
  (world), intensity (float32), the beam's elevation and azimuth indices and its range; written
  as PLY (`write_point_cloud_ply`); the formats' room writes it as LAS
  (`mitsonar.export.las.write_point_cloud_las`) and as a ROS 2 sensor_msgs/PointCloud2 message
  (`mitsonar.export.ros.messages.point_cloud_message`);
* `render_volume` is the incoherent fast path: the echo paths scored into every beam by the
  array's pattern, the speckle-averaged mean of the focused beams without element data.

Beam widths (Van Trees, *Optimum Array Processing*, 2002, ch. 2-4, the uniform line and planar
arrays): a uniform aperture of ``N`` elements at pitch ``d`` has the -3 dB width
``0.886 lambda / (N d)`` rad at broadside, widening as ``1 / cos(steer)`` off it (the projected
aperture shrinks): `Volumetric.beamwidths`. The pitch defaults to half a wavelength (no grating
lobe anywhere).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mitsonar.acoustics.water import SOUND_SPEED
import mitsonar.presets.volumetric as volumetric_presets

#: Voxels of one kernel launch: bounds the memory whatever the volume.
CHUNK = 1 << 18


@dataclass(frozen=True)
class Volumetric:
    """A 3D imaging sonar (module docstring): ``rows`` x ``columns`` receive elements at ``pitch`` m
    (default half a wavelength), ``frequency`` (carrier) and ``bandwidth`` Hz, a regular grid of
    ``n_azimuth`` x ``n_elevation`` beams over ``fov_azimuth`` x ``fov_elevation`` deg (full
    angles), ``range_max`` m in ``n_bins`` bins, ``sound_speed`` m/s."""

    rows: int
    columns: int
    frequency: float
    bandwidth: float
    n_azimuth: int
    n_elevation: int
    fov_azimuth: float
    fov_elevation: float
    range_max: float
    n_bins: int = 200
    pitch: float | None = None
    sound_speed: float = SOUND_SPEED
    range_min: float = 0.0

    def __post_init__(self):
        for name in ("rows", "columns", "n_azimuth", "n_elevation", "n_bins"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 100000:
                raise ValueError(f"Volumetric '{name}': {v!r} is not allowed (a whole number 1 to 100000)")
        for name, hi in (("frequency", None), ("bandwidth", None), ("range_max", None), ("sound_speed", None),
                         ("fov_azimuth", 180.0), ("fov_elevation", 180.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(v) or v <= 0 or (hi is not None and v >= hi):
                extra = f" and < {hi:g}" if hi is not None else ""
                raise ValueError(f"Volumetric '{name}': {v!r} is not allowed (a finite value > 0{extra})")
        if self.pitch is not None and (not math.isfinite(self.pitch) or self.pitch <= 0):
            raise ValueError(f"Volumetric 'pitch': {self.pitch!r} is not allowed (None for half a wavelength, or > 0 m)")
        if not 0 <= self.range_min < self.range_max:
            raise ValueError(f"Volumetric 'range_min': {self.range_min!r} is not allowed (0 <= range_min < range_max)")

    @property
    def wavelength(self) -> float:
        return self.sound_speed / self.frequency

    @property
    def spacing(self) -> float:
        """m: the element pitch (half a wavelength unless given)."""
        return 0.5 * self.wavelength if self.pitch is None else float(self.pitch)

    def elements(self) -> np.ndarray:
        """(rows * columns, 3) m in the beam frame: x across the columns, y across the rows, z = 0,
        centred on the transmitter; row-major (row r, column c at index r columns + c)."""
        d = self.spacing
        x = (np.arange(self.columns) - 0.5 * (self.columns - 1)) * d
        y = (np.arange(self.rows) - 0.5 * (self.rows - 1)) * d
        X, Y = np.meshgrid(x, y)
        return np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)

    def azimuths(self) -> np.ndarray:
        """rad: the beams' azimuths, a regular grid over the field of view (its centres)."""
        return _centres(self.fov_azimuth, self.n_azimuth)

    def elevations(self) -> np.ndarray:
        return _centres(self.fov_elevation, self.n_elevation)

    def ranges(self) -> np.ndarray:
        """m: bin centres."""
        w = (self.range_max - self.range_min) / self.n_bins
        return self.range_min + (np.arange(self.n_bins) + 0.5) * w

    def beamwidths(self, azimuth=0.0, elevation=0.0, window_factor=0.886) -> tuple[float, float]:
        """rad: (azimuth, elevation) -3 dB widths of a beam steered to (azimuth, elevation):
        ``0.886 lambda / (N d cos steer)`` for the columns and the rows (module docstring): the
        columns' phase follows ``cos el sin az``, whose derivative in azimuth is ``cos el cos az``;
        the rows' follows ``sin el``."""
        lam, d = self.wavelength, self.spacing
        return (window_factor * lam / (self.columns * d * math.cos(elevation) * math.cos(azimuth)),
                window_factor * lam / (self.rows * d * math.cos(elevation)))

    @property
    def fraunhofer(self) -> float:
        """m: ``2 L^2 / lambda`` of the larger aperture, where the far field begins."""
        L = max(self.rows, self.columns) * self.spacing
        return 2.0 * L * L / self.wavelength

    def pulse(self, duration=None):
        """An LFM over the band (default 20 / bandwidth s long, at most a tenth of the two-way window)."""
        from mitsonar.signals.pulses import lfm

        T = min(20.0 / self.bandwidth, 0.2 * self.range_max / self.sound_speed) if duration is None else duration
        return lfm(self.frequency - 0.5 * self.bandwidth, self.frequency + 0.5 * self.bandwidth, T)

    def sensor_xml(self, to_world=None, source_level=210.0) -> str:
        """A ``<sensor type="sonar">`` of kind ``volumetric`` (`mitsonar.kinds.Volumetric`)
        for `mitsonar.render_echoes`, `render_volume` and `mitsonar.render_scan`: its rows the
        ``n_elevation x n_azimuth`` beams at `elevations` x `azimuths`, each a gaussian receive beam
        of the array's broadside widths (`beamwidths`), a uniform transmit fan over the field of
        view (plus a tenth), the band, the range; ``to_world`` a 4x4 beam frame (default identity)."""
        from mitsonar.kinds import VOLUMETRIC

        az, el = np.degrees(self.azimuths()), np.degrees(self.elevations())
        w_az, w_el = (min(179.0, math.degrees(w)) for w in self.beamwidths())
        items = {"kind": VOLUMETRIC.name, "range_min": float(self.range_min), "range_max": float(self.range_max),
                 "n_bins": int(self.n_bins), "n_azimuth": int(self.n_azimuth), "n_elevation": int(self.n_elevation),
                 "bearing_start": float(az[0]), "bearing_step": float(self.fov_azimuth / self.n_azimuth),
                 "elevation_start": float(el[0]), "elevation_step": float(self.fov_elevation / self.n_elevation),
                 "beam_pattern": "gaussian", "beamwidth_h": float(w_az), "beamwidth_v": float(w_el),
                 "tx_pattern": "uniform", "tx_beamwidth_h": min(179.0, 1.1 * self.fov_azimuth),
                 "tx_beamwidth_v": min(179.0, 1.1 * self.fov_elevation),
                 "frequency": float(self.frequency), "bandwidth": float(self.bandwidth),
                 "sound_speed": float(self.sound_speed), "absorption": 0.0, "source_level": float(source_level)}
        from mitsonar.sim.sensor_xml import sensor_xml

        return sensor_xml(items, None if to_world is None else np.asarray(to_world, dtype=np.float64).ravel())


def _centres(fov_deg, n):
    w = math.radians(fov_deg) / n
    return (np.arange(n) - 0.5 * (n - 1)) * w


#: 3D sonars by name: their published figures (`mitsonar.presets.volumetric`, with the sources).
PRESETS = {name: Volumetric(**figures) for name, figures in volumetric_presets.FIGURES.items()}


@dataclass
class Volume:
    """A beamformed volume: ``intensity`` float32 (n_elevation, n_azimuth, n_bins), the focused
    beam's power ``|b|^2 / pressure_scale^2`` at each voxel (range at the bin centre; a lone echo
    of energy E peaks at E over the pulse's equivalent duration times the sample rate, as
    `mitsonar.signals.beamform`'s per-sample power); ``azimuths``, ``elevations`` rad; ``ranges``
    m (bin centres); ``pose`` (4, 4) the beam frame in the world; ``meta``."""

    intensity: np.ndarray
    azimuths: np.ndarray
    elevations: np.ndarray
    ranges: np.ndarray
    pose: np.ndarray
    sound_speed: float
    meta: dict[str, Any] = field(default_factory=dict)

    def directions(self) -> np.ndarray:
        """(n_elevation, n_azimuth, 3) unit look directions in the beam frame."""
        return directions(self.azimuths, self.elevations)


def directions(azimuths, elevations) -> np.ndarray:
    """(n_elevation, n_azimuth, 3): ``(cos el sin az, sin el, cos el cos az)``."""
    A, E = np.meshgrid(np.asarray(azimuths, np.float64), np.asarray(elevations, np.float64))
    return np.stack([np.cos(E) * np.sin(A), np.sin(E), np.cos(E) * np.cos(A)], axis=-1)


def beamform_3d(echoes, azimuths, elevations, ranges, *, row=0, upsample=8, chunk=CHUNK) -> Volume:
    """Focused near-field delay-and-sum of one row of `Echoes` from a planar array (module
    docstring): a `Volume` over ``azimuths`` x ``elevations`` (rad, 1-D each) x ``ranges`` (m, 1-D:
    the voxels' ranges, e.g. `Volumetric.ranges`). Uniform weights (``1 / n_elements``: a unit
    plane wave from the look direction gives a unit beam); ``upsample`` the interpolation factor of
    the compressed data; ``chunk`` voxels per kernel launch."""
    from mitsonar.signals.focusing import FocusKernel, compressed

    az = np.atleast_1d(np.asarray(azimuths, dtype=np.float64))
    el = np.atleast_1d(np.asarray(elevations, dtype=np.float64))
    rg = np.atleast_1d(np.asarray(ranges, dtype=np.float64))
    for name, v in (("azimuths", az), ("elevations", el), ("ranges", rg)):
        if v.ndim != 1 or not len(v) or not np.isfinite(v).all():
            raise ValueError(f"beamform_3d '{name}': not allowed (a 1-D array of finite values)")
    if (np.abs(az) >= math.pi / 2).any() or (np.abs(el) >= math.pi / 2).any() or (rg <= 0).any():
        raise ValueError("beamform_3d: azimuths and elevations must lie inside (-90, 90) deg and ranges be > 0 m")
    if isinstance(row, bool) or not isinstance(row, (int, np.integer)) or not 0 <= row < echoes.signal.shape[0]:
        raise ValueError(f"beamform_3d 'row': {row!r} is not allowed (0 to {echoes.signal.shape[0] - 1})")
    data = compressed(_one_row(echoes, row), upsample)
    n_el = data.shape[1]
    fs_up = echoes.sample_rate * (data.shape[-1] / echoes.n_samples)
    pose = np.asarray(echoes.poses[row], dtype=np.float64)
    e = np.asarray(echoes.elements, dtype=np.float64)
    tx = pose[:3, 3]
    rx = e @ pose[:3, :3].T + tx
    v = echoes.meta.get("velocities")
    vel = np.zeros(3) if v is None else np.asarray(v)[row]
    u = directions(az, el)                                                # (n_el_beams, n_az, 3) beam frame
    local = u[:, :, None, :] * rg[None, None, :, None]                    # (E, A, B, 3)
    pts = (local.reshape(-1, 3) @ pose[:3, :3].T) + tx
    kernel = FocusKernel(data, fs_up, echoes.carrier, echoes.sound_speed, 1.0, "uniform")
    out = np.empty(len(pts), np.complex64)
    pairs = np.arange(n_el)
    ones = np.ones((n_el, 1))
    for a in range(0, len(pts), int(chunk)):
        p = pts[a:a + int(chunk)]
        centre = 0.5 * (p.min(axis=0) + p.max(axis=0))
        out[a:a + len(p)] = kernel(p - centre, ones * (tx - centre), rx - centre, ones * vel,
                                   ones * pose[:3, 0], pairs)
    scale = float(echoes.meta.get("pressure_scale", 1.0))
    power = (np.abs(out.astype(np.complex128)) / n_el / scale) ** 2
    return Volume(power.reshape(len(el), len(az), len(rg)).astype(np.float32), az, el, rg, pose,
                  float(echoes.sound_speed), {"source": "beamform_3d", "n_elements": n_el, "row": int(row)})


def _one_row(echoes, row):
    import dataclasses

    return dataclasses.replace(echoes, signal=echoes.signal[row:row + 1])


def scan_volume(scan) -> Volume:
    """The `Volume` of a frame of a ``volumetric`` `mitsonar.scan.Scan` (`mitsonar.render_scan` of
    a `Volumetric.sensor_xml` head, a live frame): ``intensity`` its rows' echo energy per bin
    (``Scan.volume``), the grid's azimuths (``Scan.bearings``) and elevations (``meta``), ``pose``
    the head frame in the world (row 0's pose turned back by its own rotation)."""
    intensity = scan.volume()
    n_el, n_az = intensity.shape[:2]
    az = np.asarray(scan.bearings[:n_az], dtype=np.float64)
    el = np.radians(scan.meta.elevation_start + np.arange(n_el) * scan.meta.elevation_step)
    turn = scan.sonar_kind.rotations(np.degrees(az[:1]), None, None, np.degrees(el[:1]))[0]
    pose = np.asarray(scan.poses[0], dtype=np.float64) @ turn.T     # a pure rotation: its inverse
    return Volume(intensity, az, el, np.asarray(scan.ranges, np.float64), pose, float(scan.sound_speed),
                  {"source": "scan", "kind": scan.kind})


#: Fields of a point of `point_cloud` (PLY vertex properties, in this order).
POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                        ("elevation_index", "<i4"), ("azimuth_index", "<i4"), ("range", "<f4")])


def point_cloud(volume, threshold_db=-20.0, mode="strongest", absolute=None) -> np.ndarray:
    """A `POINT_DTYPE` array: per beam (elevation x azimuth) of ``volume`` its strongest return
    (``mode='strongest'``) or its first (``'first'``: the nearest bin above the threshold), kept
    when its intensity is above ``absolute`` (linear, the volume's units) or, by default,
    ``threshold_db`` dB re the volume's peak; x, y, z in the world (the voxel's centre)."""
    if mode not in ("strongest", "first"):
        raise ValueError(f"point_cloud 'mode': {mode!r} is not allowed (strongest or first)")
    I = np.asarray(volume.intensity, dtype=np.float64)
    top = float(I.max()) if I.size else 0.0
    level = float(absolute) if absolute is not None else top * 10.0 ** (float(threshold_db) / 10.0)
    above = I > level
    hit = above.any(axis=2)
    k = np.argmax(I, axis=2) if mode == "strongest" else np.argmax(above, axis=2)
    ie, ia = np.nonzero(hit)
    kk = k[ie, ia]
    u = volume.directions()[ie, ia]
    r = volume.ranges[kk]
    world = (u * r[:, None]) @ volume.pose[:3, :3].T + volume.pose[:3, 3]
    out = np.empty(len(ie), POINT_DTYPE)
    out["x"], out["y"], out["z"] = world[:, 0], world[:, 1], world[:, 2]
    out["intensity"] = I[ie, ia, kk]
    out["elevation_index"], out["azimuth_index"], out["range"] = ie, ia, r
    return out


def write_point_cloud_ply(path, points, comment="mitsonar 3D sonar point cloud") -> int:
    """Write a `point_cloud` as binary PLY (`mitsonar.geometry.ply.write_ply`); returns the count."""
    from mitsonar.geometry.ply import write_ply

    pts = np.asarray(points)
    if pts.dtype != POINT_DTYPE:
        raise ValueError(f"write_point_cloud_ply 'points': dtype {pts.dtype} is not allowed (point_cloud's POINT_DTYPE)")
    write_ply(path, pts, comment=comment)
    return len(pts)


def array_factor(head, directions, look) -> np.ndarray:
    """``|AF|^2`` (n, m): the narrowband receive pattern at the carrier of the head's uniform planar
    array steered to ``look`` (m, 3) beam-frame unit vectors, at ``directions`` (n, 3):
    ``D_C(k d (u_x - u0_x))^2 D_R(k d (u_y - u0_y))^2`` with the Dirichlet kernel
    ``D_N(psi) = sin(N psi / 2) / (N sin(psi / 2))`` (Van Trees 2002, ch. 4, the uniform
    rectangular array: separable in the direction cosines), 1 in the look direction."""
    k = 2.0 * math.pi / head.wavelength * head.spacing
    u = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    u0 = np.asarray(look, dtype=np.float64).reshape(-1, 3)

    def dirichlet(n, psi):
        half = 0.5 * psi
        s = np.sin(half)
        small = np.abs(s) < 1e-9
        return np.where(small, np.cos(n * half) / np.where(small, np.cos(half), 1.0),
                        np.sin(n * half) / (n * np.where(small, 1.0, s)))

    dx = dirichlet(head.columns, k * (u[:, None, 0] - u0[None, :, 0]))
    dy = dirichlet(head.rows, k * (u[:, None, 1] - u0[None, :, 1]))
    return (dx * dy) ** 2


def render_volume(scene, head, *, spp=4096, seed=0, pose=None, sensor=0, max_depth=None, chunk=4096) -> Volume:
    """The incoherent fast path: the mean volume of ``head`` (a `Volumetric`) over ``scene``, its
    ``intensity`` the echo energy per bin and beam (the units of `mitsonar.render_scan`), without
    element data.

    The echo paths are `mitsonar.render_echoes`'s (``sonar_tof`` from the scene's sensor, a
    ``volumetric`` head whose transmit fan is the head's, `Volumetric.sensor_xml`), merged into
    scatterers of energy ``E`` at ``x``; each scores ``E |AF_b(u)|^2`` into the bin of its range in
    every beam ``b`` (`array_factor` of its direction ``u`` from the array), so the volume is the
    expectation over speckle of the focused beams' energy (`beamform_3d`): each beam's energy
    summed over range agrees with the coherent path's speckle-averaged one, which spreads it over
    the bins by the pulse's autocorrelation. Cost: scatterers x beams (numpy, ``chunk`` scatterers
    at a time); no pulse, no elements."""
    import mitsonar.kinds as kinds
    from mitsonar.signals.echoes import _trace
    from mitsonar.sim.render import SEED_ALLOWED, SEED_MAX, SPP_ALLOWED, SPP_MAX, _check_pose, _whole
    from mitsonar.sim.scene import SceneError, sonar_of
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    where = "render_volume"
    if not isinstance(head, Volumetric):
        raise SceneError(f"{where} 'head': {type(head).__name__} is not allowed (a Volumetric)")
    spp = _whole("spp", spp, 1, SPP_MAX, SPP_ALLOWED, where)
    seed = _whole("seed", seed, 0, SEED_MAX, SEED_ALLOWED, where)
    if pose is not None:
        pose = _check_pose(pose)
    sonar = sonar_of(scene, sensor)
    if not sonar.sonar_kind.grid:
        raise SceneError(f"{where} 'scene': its sensor of kind {sonar.kind!r} is not allowed (kind "
                         f"{kinds.which('grid')}: Volumetric.sensor_xml)")
    if (sonar.n_elevation, sonar.n_azimuth) != (head.n_elevation, head.n_azimuth):
        raise SceneError(f"{where} 'head': its {head.n_elevation} x {head.n_azimuth} beams are not allowed (the "
                         f"scene's sensor's grid, n_elevation x n_azimuth = {sonar.n_elevation} x {sonar.n_azimuth})")
    heads = sonar.head_pose(pose)
    row_poses = (heads[:1] if heads.ndim == 3 else heads[None]).copy()
    ranges = head.ranges()
    width = (head.range_max - head.range_min) / head.n_bins
    amp, pos, out, _ = _trace(scene, sonar, row_poses, spp, seed, max_depth, 0.5 * width, width, 0, omni=True)[0]
    o = row_poses[0, :3, 3]
    d = pos - o
    dist = np.linalg.norm(d, axis=1)
    local = (d / np.maximum(dist, 1e-12)[:, None]) @ row_poses[0, :3, :3]
    r = 0.5 * (out + dist)
    j = np.floor((r - head.range_min) / width).astype(np.int64)
    ok = (j >= 0) & (j < head.n_bins)
    energy = np.abs(amp[ok]) ** 2
    local, j = local[ok], j[ok]
    look = directions(head.azimuths(), head.elevations()).reshape(-1, 3)
    n_beams = len(look)
    acc = np.zeros(n_beams * head.n_bins)
    for a in range(0, len(j), int(chunk)):
        w = energy[a:a + chunk, None] * array_factor(head, local[a:a + chunk], look)        # (m, beams)
        idx = np.arange(n_beams)[None, :] * head.n_bins + j[a:a + chunk, None]
        acc += np.bincount(idx.ravel(), weights=w.ravel(), minlength=len(acc))
    intensity = acc.reshape(head.n_elevation, head.n_azimuth, head.n_bins).astype(np.float32)
    return Volume(intensity, head.azimuths(), head.elevations(), ranges, row_poses[0], float(sonar.sound_speed),
                  {"source": "render_volume", "spp": spp, "seed": seed, "n_scatterers": int(ok.sum())})
