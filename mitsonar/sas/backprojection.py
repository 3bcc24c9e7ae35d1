"""Strip-map SAS image formation by time-domain backprojection, as Dr.Jit kernels.

Each ping ``r`` and receiver ``j`` of `Echoes` rendered along a trajectory is pulse-compressed
(`mitsonar.signals.matched_filter`), upsampled by ``upsample`` (zero-padded spectrum) and summed
into every pixel ``p`` of a ground-range grid with the delay of its own bistatic path:

    I(p) = sum_{r, j} w(s_rj(p)) y_rj(tau_rj(p)) exp(i 2 pi f_c tau_rj(p)),
    tau_rj(p) = (|p - t_r| + |p - e_rj(tau)|) / c,   e_rj(tau) = e_rj + v_r tau

(Hayes and Gough, "Synthetic aperture sonar: a review of current status", IEEE J. Oceanic Eng.
34(3), 2009, the time-domain (backprojection) image reconstruction: the exact delay of every
transmitter-receiver pair, hence no far-field, stop-and-hop or range-migration approximation;
the receiver's motion during the two-way flight is the first-order one of the renderer,
`mitsonar.signals.synthesis`). ``t_r`` is the transmitter at ping ``r``, ``e_rj`` the receiver,
``v_r`` the platform's velocity, all from the *navigation*: by default the poses the echoes were
rendered at, or the ``navigation`` trajectory (each row's mount from ``Echoes.meta['mounts']``),
so a navigation that differs from the true track (sway, yaw, a wrong ``sound_speed``) defocuses
the image as it does at sea. ``y_rj(tau)`` is linearly interpolated between the upsampled
samples and its baseband phase restored by ``exp(i 2 pi f_c tau)``.

The processed beam: ``s_rj(p)``, the sine of the squint, the mean of the along-track components
(beam frame +x) of the unit vectors from ``t_r`` and ``e_rj`` to ``p``; the pair contributes when
``|s| < sin(theta_p / 2)`` with the weight ``w`` of the ``window`` over ``s / sin(theta_p / 2)``
(uniform, or Hann). Uniform in ``s`` is uniform in the along-track wavenumber ``2 k s``, so a point
target's along-track -3 dB width is ``k_w lambda / (4 sin(theta_p / 2))``
(`mitsonar.sas.StripMap.along_track_resolution`).

Memory: the pixels are processed in square tiles of at most ``chunk`` lanes; per tile only the
pairs whose processed beam can reach it are looped over (a conservative test on the chunk's corners), in
one symbolic loop (`mitsonar.signals.focusing.FocusKernel`, shared with the 3D imaging sonar's
focused beamformer), every value that changes between tiles opaque, so one kernel serves every
tile and call. The same code runs on the CUDA variants (a GPU).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mitsonar.sas.config import WINDOW_FACTORS
from mitsonar.signals.focusing import FocusKernel, compressed

#: Pixels of one kernel launch: bounds the memory (a few dozen bytes per pixel) whatever the grid.
CHUNK = 1 << 18
WINDOWS = tuple(WINDOW_FACTORS)


@dataclass
class Grid:
    """A horizontal ground-range grid: pixel centres ``x`` (n_x,) along track and ``y`` (n_y,)
    across it, world m, at height ``z``. `image` arrays are (n_x, n_y)."""

    x: np.ndarray
    y: np.ndarray
    z: float = 0.0

    @classmethod
    def around(cls, centre, half_along, half_across, pixel):
        """A grid of ``pixel`` m spacing over ``centre`` +- (half_along, half_across) m at its z."""
        if not (isinstance(pixel, (int, float, np.integer, np.floating)) and math.isfinite(pixel) and pixel > 0):
            raise ValueError(f"Grid.around 'pixel': {pixel!r} is not allowed (a spacing > 0 m)")
        cx, cy, cz = (float(v) for v in centre)
        na, nc = int(round(2 * half_along / pixel)) + 1, int(round(2 * half_across / pixel)) + 1
        return cls(cx + (np.arange(na) - (na - 1) / 2) * pixel, cy + (np.arange(nc) - (nc - 1) / 2) * pixel, cz)

    @property
    def shape(self):
        return (len(self.x), len(self.y))

    def points(self) -> np.ndarray:
        """(n_x * n_y, 3) world pixel centres, x-major."""
        X, Y = np.meshgrid(self.x, self.y, indexing="ij")
        return np.stack([X.ravel(), Y.ravel(), np.full(X.size, float(self.z))], axis=1)


@dataclass
class SASImage:
    """A backprojected image: ``image`` complex64 (n_x, n_y) on ``grid``; ``meta`` the processing
    (beamwidth, window, sound speed, pairs summed, rate)."""

    image: np.ndarray
    grid: Grid
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def power_db(self) -> np.ndarray:
        """dB of ``|image|^2`` re its peak."""
        p = np.abs(self.image.astype(np.complex128)) ** 2
        return 10.0 * np.log10(np.maximum(p / max(p.max(), 1e-300), 1e-30))


def _check(name, value, ok, allowed):
    if not ok:
        raise ValueError(f"form_image '{name}': {value!r} is not allowed ({allowed})")


def row_geometry(echoes, navigation=None):
    """(poses (n_rows, 4, 4), velocities (n_rows, 3)) of each row as the processor believes them:
    the rendered ones, or ``navigation``'s at the rows' times (module docstring)."""
    meta = echoes.meta
    if navigation is None:
        v = meta.get("velocities")
        return echoes.poses, np.zeros((len(echoes.poses), 3)) if v is None else np.asarray(v)
    from mitsonar.signals.echoes import _velocities

    if "mounts" not in meta:
        raise ValueError("form_image 'navigation': not allowed for echoes rendered without a trajectory "
                         "(their rows have no mount to place along another track)")
    t = meta["start_time"] + echoes.times
    lo, hi = navigation.span
    if t.min() < lo - 1e-9 or t.max() > hi + 1e-9:
        raise ValueError(f"form_image 'navigation': its span {lo:g} to {hi:g} s is not allowed (it must cover "
                         f"the pings, {t.min():g} to {t.max():g} s)")
    return navigation.at(t) @ meta["mounts"], _velocities(navigation, t, t.shape)


def form_image(echoes, grid, *, navigation=None, sound_speed=None, beamwidth=None, window="uniform",
               upsample=8, chunk=CHUNK, data=None) -> SASImage:
    """Backproject strip-map `Echoes` (rendered along a trajectory) onto ``grid`` (module docstring).

    ``navigation`` a `mitsonar.Trajectory` used for focusing (default the rendered poses);
    ``sound_speed`` m/s assumed (default the echoes'); ``beamwidth`` the processed beamwidth
    ``theta_p`` in rad (full angle, default ``lambda / D`` with ``D`` the receivers' spacing, the
    classical full-beam case; at most pi); ``window`` ``uniform`` or ``hann``; ``upsample`` the
    interpolation factor; ``chunk`` pixels per kernel launch; ``data`` pre-compressed element data
    (`compressed`) to reuse between calls. Returns a `SASImage`."""
    import time

    _check("grid", type(grid).__name__, isinstance(grid, Grid), "a mitsonar.sas.Grid")
    _check("window", window, window in WINDOWS, " or ".join(WINDOWS))
    c = echoes.sound_speed if sound_speed is None else sound_speed
    _check("sound_speed", sound_speed, isinstance(c, (int, float, np.integer, np.floating)) and not isinstance(c, bool)
           and math.isfinite(c) and c > 0, "a speed > 0 m/s")
    c = float(c)
    e = np.asarray(echoes.elements, dtype=np.float64)
    if beamwidth is None:
        d = np.diff(np.sort(e[:, 0]))
        d = d[d > 0]
        _check("beamwidth", beamwidth, len(d) > 0, "a processed beamwidth in rad; the default needs two or more "
               "receivers along the beam frame's x")
        beamwidth = echoes.wavelength / float(np.median(d))
    _check("beamwidth", beamwidth, isinstance(beamwidth, (int, float, np.floating)) and 0 < beamwidth <= math.pi,
           "a full angle in rad, > 0 and <= pi")
    _check("upsample", upsample, isinstance(upsample, (int, np.integer)) and 1 <= upsample <= 64, "a whole number 1 to 64")
    _check("chunk", chunk, isinstance(chunk, (int, np.integer)) and chunk >= 1, "a whole number >= 1")
    poses, vel = row_geometry(echoes, navigation)

    if data is None:
        data = compressed(echoes, upsample)
    n_rows, n_el, n_up = data.shape
    fs_up = echoes.sample_rate * (n_up / echoes.n_samples)
    tx = poses[:, :3, 3]                                                  # (rows, 3)
    rx = np.einsum("rij,ej->rei", poses[:, :3, :3], e) + tx[:, None, :]   # (rows, el, 3)
    axis = poses[:, :3, 0]
    smax = math.sin(0.5 * float(beamwidth))

    out = np.zeros(grid.shape, np.complex64)
    t0 = time.perf_counter()
    kernel = FocusKernel(data, fs_up, echoes.carrier, c, smax, window)
    pairs_done = 0
    tau_max = n_up / fs_up
    n_x, n_y = grid.shape
    side = max(1, int(math.isqrt(int(chunk))))             # square tiles: the tightest pair selection
    t_y = min(n_y, side)
    t_x = max(1, int(chunk) // t_y)
    for i0 in range(0, n_x, t_x):
        for j0 in range(0, n_y, t_y):
            X, Y = np.meshgrid(grid.x[i0:i0 + t_x], grid.y[j0:j0 + t_y], indexing="ij")
            p = np.stack([X.ravel(), Y.ravel(), np.full(X.size, float(grid.z))], axis=1)
            centre = 0.5 * (p.min(axis=0) + p.max(axis=0))
            rows, els = _pairs(p, tx, rx, axis, vel, smax, tau_max)
            if not len(rows):
                continue
            val = kernel(p - centre, tx[rows] - centre, rx[rows, els] - centre, vel[rows], axis[rows],
                         rows * n_el + els)
            out[i0:i0 + t_x, j0:j0 + t_y] = val.reshape(X.shape)
            pairs_done += len(p) * len(rows)
    seconds = time.perf_counter() - t0
    meta = {"beamwidth": float(beamwidth), "window": window, "sound_speed": c, "upsample": int(n_up // echoes.n_samples),
            "navigation": "given" if navigation is not None else "rendered poses",
            "pixel_pairs": int(pairs_done), "seconds": seconds,
            "pixel_pairs_per_second": pairs_done / seconds if seconds > 0 else float("nan")}
    return SASImage(out, grid, meta)


def _pairs(p, tx, rx, axis, vel, smax, tau_max):
    """(rows, elements) of the pairs whose processed beam may reach any of the points ``p``: a
    conservative test on the bounding box's corners (module docstring)."""
    n_rows, n_el = rx.shape[:2]
    if smax >= 1.0 - 1e-12:
        r, j = np.meshgrid(np.arange(n_rows), np.arange(n_el), indexing="ij")
        return r.ravel(), j.ravel()
    lo, hi = p.min(axis=0), p.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    m = 0.5 * (tx[:, None, :] + rx)                                           # (rows, el, 3) phase centres
    d = corners[None, None, :, :] - m[:, :, None, :]                          # (rows, el, 8, 3)
    dx = np.einsum("rekc,rc->rek", d, axis)
    rho = np.linalg.norm(d - dx[..., None] * axis[:, None, None, :], axis=-1).max(axis=-1)
    same = (np.all(dx > 0, axis=-1) | np.all(dx < 0, axis=-1))
    near = np.where(same, np.abs(dx).min(axis=-1), 0.0)
    slack = 0.5 * np.linalg.norm(rx - tx[:, None, :], axis=-1) + np.linalg.norm(vel, axis=-1)[:, None] * tau_max + 0.01
    keep = near <= smax / math.sqrt(1.0 - smax * smax) * rho + slack
    r, j = np.nonzero(keep)
    return r, j
