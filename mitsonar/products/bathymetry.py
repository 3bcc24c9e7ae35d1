"""Bathymetry from a downward echo sounder: bottom detection per beam, soundings in the world frame,
and their errors against the scene's true seabed.

    import mitsonar
    from mitsonar.products import bathymetry
    from mitsonar.scenes import echosounders
    from mitsonar.scenes import sea_surface
    scene = sea_surface.load_survey_scene("scenes_xml/rocky_slope.xml",
                                          sonar=echosounders.sonar_xml("r2sonic_2024", range_max=30))
    track = mitsonar.Trajectory.from_tum("scenes_xml/rocky_slope_survey.tum")
    run = bathymetry.survey(scene, track, spp=256, max_scans=20)
    run.soundings     # structured array, one row per detected beam (SOUNDING_DTYPE)
    run.errors        # depth error statistics per beam angle (see `error_table`)

Bottom detection (`detect`): in each row (receive beam) of a scan's intensity, the strongest bin
is found; the echo is the run of bins around it whose intensity is within ``threshold_db`` of that
peak; its range is the intensity-weighted (energy-weighted) mean range of that run (``centroid``,
the "weighted mean time" / centre-of-gravity detection of MBES, here weighted by the echo's power,
not its amplitude), or (``leading_edge``, for the altimeter) the range where the intensity first
rises through the threshold, interpolated linearly between bins. The sounding is
``transducer + range * boresight`` of the row's beam frame (straight rays in a constant sound
speed), so every sounding is in the world frame. With a sound-speed profile (`soundings`'s
``sound_speed_profile``, a `mitsonar.acoustics.SoundSpeedProfile`) the sounding is placed as
hydrographic processing does (`refracted`): the range is turned back into the one-way travel time
``range / c`` (``c`` the scan's nominal sound speed: what the head used), and the beam is
ray-traced through the profile from the head's depth (``-z`` of the transducer) at its launch
angle for that time (`mitsonar.acoustics.SoundSpeedProfile.locate`).

Speckle (`speckled`): the rendered intensity is an expectation (noise-free but for Monte Carlo
noise); real echoes fluctuate. Detection with speckle runs on ``intensity * |g|^2``, ``g`` the
scene's own complex speckle of the scan (`mitsonar.receiver.speckle`, through
`mitsonar.receiver.electronics.Electronics.scene_speckle` with the scan's recorded electronics, its
``speckle_seed`` and geometry: what `mitsonar.sim.render.render_scan` multiplied into the device
bytes). So a still head sees the same speckle, and the same soundings, ping after ping; a moving
or turning head sees it change at the physical rate; another ``speckle_seed`` (another set of
scatterers) gives another pattern. The speckle's grains are one range resolution
``L = max(c pulse_length / 2, bin)`` long (the bathymetric presets' pulse gives ``L`` = 1.25 cm,
`mitsonar.scenes.echosounders`). Detection does not use the device bytes: their TVG, noise floor and
8-bit A/D window clip a strong bottom echo's peak to 255 and flatten the centroid's weights; a
bathymetric head detects on its beamformed power before any display scaling.

Known bias and error of the centroid, and why errors grow at the outer beams: a beam of across-track
width ``w`` at angle ``theta`` from the vertical, at altitude ``H``, lights the seabed over beam
angles ``theta + phi``; its echo spreads over ranges ``r(phi) = H / cos(theta + phi)``, a spread of
about ``sigma_r = r tan(theta) sigma_phi`` with ``sigma_phi = w / sqrt(8 ln 2)`` (the receive
beam's gaussian, two-way across track: the transmit fan is wide there), plus the bin's own
``b / sqrt(12)``. At nadir the echo is one or two bins long; at 60 deg and 10 m altitude, with
w = 0.5 deg, it is 0.13 m rms, ten bins of 1.25 cm. (1) Bias: the centroid of ``r(phi)`` is
``r (1/2 (1 + 2 tan^2 theta) - 3 tan^2 theta) sigma_phi^2`` away from ``r(0)`` (convexity of
``1 / cos`` against the Lambertian ``cos^3`` weight leaning to nadir), under 1e-4 r for beams
under 1 deg: negligible against (2) the random error. Linearised, the centroid's error is
``sum (r_i - c) I_i (s_i - 1) / sum I_i`` (``s_i = |g_i|^2``, unit-mean exponential, with intensity
correlation ``exp(-8 ln2 (dr / L)^2)`` between bins ``dr`` apart). For a gaussian echo of rms
length ``sigma_r`` and a gaussian speckle correlation of rms length ``l``, its variance is
``sigma_r^4 / (l^2 (1 + 2 sigma_r^2 / l^2)^(3/2))``; ``l = b_c / sqrt(2 pi)`` with
``b_c = b sum_j exp(-8 ln2 (j b / L)^2)`` the correlation length the bins see (``b_c = 1.008 b``
for ``L = b``: independent bins; ``b_c = 0.75 L`` for ``L >> b``). A long echo
(``sigma_r >> l``) thus has ``sqrt(sigma_r b_c / (4 sqrt(pi)))``; a short one (``sigma_r << l``:
the whole echo under one speckle grain, which scales it without moving it) ``sigma_r^2 / l``. (3)
Quantisation: an echo much shorter than a bin (``p = r tan(theta) sigma_phi << b``: nadir) lies in
one bin whatever the speckle and is found at that bin's centre, an error uniform over the bin
(rms ``b / sqrt(12)``); it fades as the echo spreads over bins, stated here as
``q^2 = b^2 / 12 exp(-4 pi^2 p^2 / b^2)`` (the square of the first Fourier coefficient of a
gaussian sampled every ``b``; an interpolation between the two limits, not an exact law). The
depth error is ``cos(theta)`` times the range error: at nadir with ``L = b`` about ``0.31 b``
(speckle ``0.12 b``, quantisation ``0.29 b``), growing to about
``cos(theta) sqrt(r tan(theta) sigma_phi b / 7.1)`` at the outer beams (`predicted_rms`) — real
MBES see the same growth and switch to phase (split-aperture) detection at the outer beams, which
this module does not model. Threshold truncation makes the measured error somewhat smaller than
the formula and speckle fades that cut a long echo's window (beyond about 50 deg for 1 deg beams)
much larger; finite ``spp`` adds Monte Carlo noise.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar._checks import is_number, not_allowed

WHERE = "bathymetry"
METHODS = ("centroid", "leading_edge")
#: dB below the peak: the window of the echo. Under 1 dB an echo is its peak bin; beyond 60 dB
#: float32 intensities and Monte Carlo noise make the window meaningless.
THRESHOLD_RANGE = (1.0, 60.0)
#: Bins of the running mean on which the echo's window is found (`detect`).
SMOOTH_BINS = 5

SOUNDING_DTYPE = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("intensity", "<f4"), ("beam", "<u2"),
                           ("angle", "<f4"), ("ping", "<u4"), ("time", "<f8"), ("range", "<f8"),
                           ("head_z", "<f8")])


class NoBottomError(ValueError):
    """No beam of any ping found the bottom inside the range window."""


def check_options(threshold_db=10.0, method="centroid"):
    """The detector's options, each refused with one line naming it and the allowed values."""
    lo, hi = THRESHOLD_RANGE
    if not (is_number(threshold_db) and lo <= threshold_db <= hi):
        raise not_allowed(WHERE, "threshold_db", threshold_db, f"dB below the echo's peak, {lo:g} to {hi:g}")
    if method not in METHODS:
        raise not_allowed(WHERE, "method", method, "one of " + ", ".join(METHODS))
    return float(threshold_db), method


def speckle_power(scan) -> np.ndarray:
    """The scene's speckle power ``|g|^2`` (mean 1) of every bin of ``scan`` (n_rows x n_bins):
    the field `mitsonar.sim.render.render_scan` multiplied into the scan's bytes, from the scan's
    recorded electronics (``speckle``, ``speckle_seed``, ``pulse_length``, ``speckle_shape``),
    poses, ranges, beam width and ``meta`` (``frequency``, ``aperture_h``). Ones for ``speckle``
    ``off``; ``weibull`` reshapes the power as the electronics do. A scan that does not say
    where its echoes come from (``meta['speckle'] != 'scene'``: a real head's) is refused."""
    from mitsonar.receiver.electronics import Electronics, has_scene_speckle

    e = Electronics.from_dict(scan.electronics, source=f"{WHERE} scan.electronics")
    if e.speckle == "off":
        return np.ones(np.shape(scan.intensity))
    if not has_scene_speckle(scan):
        raise not_allowed(WHERE, "scan", f"speckle {scan.meta.speckle!r}",
                          "a rendered scan (meta['speckle'] == 'scene'), or speckle=False")
    g = e.scene_speckle(scan.poses, scan.ranges, sound_speed=scan.sound_speed, beamwidth_h=scan.beamwidth_h,
                        aperture_h=float(scan.meta.aperture_h))
    power = g.real ** 2 + g.imag ** 2
    if e.speckle == "weibull":
        k = e.speckle_shape
        return power ** (1.0 / k) / math.gamma(1.0 + 1.0 / k)
    return power


def speckle_resolution(scan) -> float:
    """The range length ``L`` (m) of the scan's speckle grains: ``max(c pulse_length / 2, bin)``."""
    from mitsonar.receiver.electronics import Electronics

    e = Electronics.from_dict(scan.electronics, source=f"{WHERE} scan.electronics")
    b = float(scan.ranges[1] - scan.ranges[0]) if len(scan.ranges) > 1 else 0.0
    return max(scan.sound_speed * e.pulse_length / 2.0, b)


def speckled(scan) -> np.ndarray:
    """``scan.intensity * |g|^2``: the echo power with the scene's own speckle (`speckle_power`)."""
    return np.asarray(scan.intensity, dtype=np.float64) * speckle_power(scan)


def smoothed(intensity, width=SMOOTH_BINS):
    """Running mean of each row over ``width`` bins (odd; zeros beyond the ends)."""
    I = np.asarray(intensity, dtype=np.float64)
    if width <= 1:
        return I
    h = width // 2
    c = np.cumsum(np.pad(I, ((0, 0), (h + 1, h))), axis=1)
    return (c[:, width:] - c[:, :-width]) / width


def detect(intensity, ranges, threshold_db=10.0, method="centroid"):
    """Bottom detection per row: ``(range (n_rows,), energy (n_rows,))``, NaN range (and 0 energy)
    for rows with no echo. The echo's window is found on the intensity smoothed over
    `SMOOTH_BINS` bins (a speckle fade must not cut an echo in two), its range from the intensity
    itself. An echo whose window reaches either end of the range window (cut off: its centroid
    would be biased) is no detection. See the module docstring for the estimators."""
    threshold_db, method = check_options(threshold_db, method)
    I = np.asarray(intensity, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)
    n_rows, n_bins = I.shape
    j = np.arange(n_bins)[None, :]
    S = smoothed(I)
    peak = S.argmax(1)
    top = S[np.arange(n_rows), peak]
    level = top * 10.0 ** (-threshold_db / 10.0)
    below = S < level[:, None]
    left = np.where(below & (j < peak[:, None]), j, -1).max(1) + 1
    right = np.where(below & (j > peak[:, None]), j, n_bins).min(1) - 1
    inside = (j >= left[:, None]) & (j <= right[:, None])
    w = np.where(inside, I, 0.0)
    energy = w.sum(1)
    # An echo cut by either end of the range window has no trustworthy range: no detection.
    found = (top > 0) & (left > 0) & (right < n_bins - 1)
    if method == "centroid":
        out = (w * r[None, :]).sum(1) / np.where(found, energy, 1.0)
    else:
        # the first bin of the window whose own intensity reaches the threshold below the window's
        # own peak, interpolated linearly from the bin before it (bin centres)
        bin_w = r[1] - r[0] if n_bins > 1 else 1.0
        rows = np.arange(n_rows)
        raw_level = w.max(1) * 10.0 ** (-threshold_db / 10.0)
        first = np.argmax((w >= raw_level[:, None]) & inside & (w > 0), axis=1)
        prev = np.maximum(first - 1, 0)
        i0, i1 = I[rows, prev], I[rows, first]
        frac = np.clip((raw_level - i0) / np.where(i1 > i0, i1 - i0, 1.0), 0.0, 1.0)
        out = np.where(first > 0, r[prev] + frac * bin_w, r[first] - 0.5 * bin_w)
    return np.where(found, out, np.nan), np.where(found, energy, 0.0)


def check_profile(sound_speed_profile):
    """``sound_speed_profile``: None or a `mitsonar.acoustics.SoundSpeedProfile`, else one line."""
    from mitsonar.acoustics.profile import SoundSpeedProfile

    if sound_speed_profile is not None and not isinstance(sound_speed_profile, SoundSpeedProfile):
        raise not_allowed(WHERE, "sound_speed_profile", sound_speed_profile,
                          "a mitsonar.acoustics.SoundSpeedProfile, or None for straight rays")
    return sound_speed_profile


def refracted(positions, boresights, ranges, sound_speed, sound_speed_profile):
    """World positions (n, 3) of echoes at ``ranges`` (m) along beams launched from ``positions``
    (n, 3; world, z up, the sea surface at z = 0) towards ``boresights`` (n, 3, unit), placed by
    ray tracing through ``sound_speed_profile`` for the one-way time ``range / sound_speed``
    (``sound_speed`` the head's nominal speed, m/s, which turned the two-way time into a range):
    the launch grazing angle is ``atan2(-b_z, |b_xy|)``, the ray stays in the vertical plane of
    the boresight, and its depth is ``-z``. A head above the sea surface (z > 0) is refused."""
    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    bore = np.asarray(boresights, np.float64).reshape(-1, 3)
    above = pos[:, 2] > 0
    if above.any():
        raise ValueError(f"{WHERE}: the head is {pos[above, 2][0]:g} m above the sea surface (z = 0): a "
                         "sound-speed profile's rays start in the water (a transducer at z <= 0)")
    horizontal = np.hypot(bore[:, 0], bore[:, 1])
    grazing = np.arctan2(-bore[:, 2], horizontal)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(horizontal[:, None] > 0, bore[:, :2] / horizontal[:, None], 0.0)
    t = np.asarray(ranges, np.float64).reshape(-1) / float(sound_speed)
    x, depth = sound_speed_profile.locate(-pos[:, 2], grazing, t)
    return np.column_stack([pos[:, 0] + x * u[:, 0], pos[:, 1] + x * u[:, 1], -depth])


def soundings(scan, threshold_db=10.0, method="centroid", speckle=False, ping=0, start_time=None,
              sound_speed_profile=None):
    """One sounding per beam of ``scan`` that found the bottom: a `SOUNDING_DTYPE` array.

    ``x, y, z`` world position (m), ``intensity`` the echo's energy in dB (10 log10 of the window's
    sum, the scan's intensity units), ``beam`` the row, ``angle`` its bearing (deg; for a downward
    multibeam the across-track beam angle, positive to port), ``ping`` (``ping``, e.g. the scan's
    index in a survey), ``time`` the row's ping time (``start_time`` + the scan's row time; the
    scan's ``meta.start_time`` by default: 0 when it has none), ``range`` the detected range, ``head_z`` the
    transducer's height. ``speckle``: False detects on the noise-free intensity, True on
    `speckled` (the scene's speckle of the scan; pick another pattern with `render_scan`'s
    ``speckle_seed``). ``sound_speed_profile``: None places each sounding on the straight beam
    (``transducer + range * boresight``); a `mitsonar.acoustics.SoundSpeedProfile` ray-traces it
    through that water (`refracted`, from the one-way time ``range / scan.sound_speed``).
    """
    threshold_db, method = check_options(threshold_db, method)
    check_profile(sound_speed_profile)
    if not isinstance(speckle, bool):
        raise not_allowed(WHERE, "speckle", speckle, "True (the scan's scene speckle) or False")
    spread = float(np.degrees(np.ptp(scan.bearings))) if scan.n_pings > 1 else 0.0
    top = scan.sonar_kind.max_sounding_fan
    if top is not None and spread > top + 1e-9:
        raise not_allowed(WHERE, "scan", f"a fan of {spread:g} deg", f"a bathymetric fan of at most {top:g} deg")
    I = speckled(scan) if speckle else scan.intensity
    rng, energy = detect(I, scan.ranges, threshold_db, method)
    ok = np.isfinite(rng)
    k = np.flatnonzero(ok)
    pos, bore = scan.poses[k, :3, 3], scan.poses[k, :3, 2]
    if sound_speed_profile is None:
        p = pos + rng[k, None] * bore
    else:
        p = refracted(pos, bore, rng[k], scan.sound_speed, sound_speed_profile)
    if start_time is None:
        start_time = scan.meta.start_time if scan.meta.start_time is not None else 0.0
    t0 = float(start_time)
    out = np.zeros(len(k), SOUNDING_DTYPE)
    out["x"], out["y"], out["z"] = p[:, 0], p[:, 1], p[:, 2]
    with np.errstate(divide="ignore"):
        out["intensity"] = 10.0 * np.log10(energy[k])
    out["beam"], out["angle"], out["ping"] = k, np.degrees(scan.bearings[k]), ping
    out["time"], out["range"], out["head_z"] = t0 + scan.times[k], rng[k], pos[:, 2]
    return out


def no_bottom(n_pings, range_min, range_max) -> NoBottomError:
    return NoBottomError(f"{WHERE}: no bottom in range: no beam of the {n_pings} ping(s) found an echo in "
                         f"[{range_min:g}, {range_max:g}) m (is the seabed beyond range_max, or the head "
                         "not looking at it?)")


def true_height(scene, x, y, z_from):
    """Height of the first surface straight below ``(x, y, z_from)`` in ``scene`` (the ground
    truth: the scene's own geometry), NaN where a vertical ray meets nothing. Starts 1 mm below
    ``z_from`` (a sea surface at the head's own height is not the seabed)."""
    import drjit as dr
    import mitsuba as mi

    x_in = x
    x, y, z = (np.ascontiguousarray(np.broadcast_to(np.asarray(v, np.float64), np.shape(x))).ravel()
               for v in (x, y, z_from))
    out = np.full(x.size, np.nan)
    # A ray through a mesh's edge or vertex may slip between its triangles (float32): misses are
    # cast again 0.1 mm aside, twice, before they count as no seabed.
    for dx, dy in ((0.0, 0.0), (1e-4, 0.7e-4), (-0.7e-4, 1e-4)):
        todo = np.flatnonzero(np.isnan(out))
        if todo.size == 0:
            break
        n = todo.size
        o = mi.Point3f(mi.Float(x[todo] + dx), mi.Float(y[todo] + dy), mi.Float(z[todo] - 1e-3))
        ray = mi.Ray3f(o, mi.Vector3f(mi.Float(np.zeros(n)), mi.Float(np.zeros(n)), mi.Float(-np.ones(n))))
        si = scene.ray_intersect(ray)
        t = np.array(dr.select(si.is_valid(), si.t, dr.nan), dtype=np.float64)
        out[todo] = z[todo] - 1e-3 - t
    return out.reshape(np.shape(x_in))


def predicted_rms(range_m, angle_deg, beam_width_deg, bin_width, incidence_deg=None, resolution=None):
    """The centroid's rms depth error under the scene's speckle at beam angle ``angle_deg`` (module
    docstring): the range error ``sqrt(sigma_r^4 / (l^2 (1 + 2 sigma_r^2 / l^2)^(3/2)) + q^2)``
    times ``cos(i) / cos(theta - i)``, ``q^2 = b^2 / 12 exp(-4 pi^2 p^2 / b^2)`` the bins'
    quantisation (``p = r tan(i) sigma_phi``: see the module docstring).

    ``sigma_r = sqrt((r tan(i) sigma_phi)^2 + b^2 / 12)`` is the echo's rms range spread,
    ``sigma_phi = w / sqrt(8 ln 2)``, ``i`` the incidence on the seabed (default the beam angle:
    a flat seabed; on a seabed tilted by ``beta = theta - i`` in the beam's plane the vertical
    error is ``cos(i) / cos(beta)`` times the range error, ``cos(theta)`` when flat);
    ``l = b_c / sqrt(2 pi)``, ``b_c = b sum_j exp(-8 ln2 (j b / L)^2)`` the speckle's correlation
    length over bins ``b`` for grains ``L = resolution`` long (default one bin: `speckle_resolution`
    gives a scan's). For ``L = b`` and long echoes this is ``sqrt(sigma_r b / (4 sqrt(pi)))``."""
    th = np.radians(np.asarray(angle_deg, np.float64))
    inc = th if incidence_deg is None else np.radians(np.asarray(incidence_deg, np.float64))
    b = float(bin_width)
    L = b if resolution is None else max(float(resolution), b)
    j = np.arange(-int(math.ceil(4 * L / b)) - 1, int(math.ceil(4 * L / b)) + 2)
    b_c = b * float(np.sum(np.exp(-8.0 * math.log(2.0) * (j * b / L) ** 2)))
    ell2 = b_c ** 2 / (2.0 * math.pi)
    sigma_phi = math.radians(beam_width_deg) / math.sqrt(8.0 * math.log(2.0))
    p2 = (np.asarray(range_m) * np.tan(np.abs(inc)) * sigma_phi) ** 2     # the echo's own spread
    s2 = p2 + b ** 2 / 12.0
    var = s2 ** 2 / (ell2 * (1.0 + 2.0 * s2 / ell2) ** 1.5)
    quantisation = b ** 2 / 12.0 * np.exp(-4.0 * math.pi ** 2 * p2 / b ** 2)
    return np.cos(inc) / np.cos(th - inc) * np.sqrt(var + quantisation)


def error_table(angle, error, depth, angle_step=5.0):
    """Depth error statistics per beam angle: a list of dicts, one per ``angle_step``-wide bin of
    beam angle (deg, edges at whole multiples of the step) holding soundings: ``angle`` (bin
    centre), ``n``, ``mean``, ``std``, ``rms``, ``p95`` (95th percentile of |error|) in metres,
    and ``rms_percent`` (rms over the mean depth, %). ``error`` is measured minus true depth
    (positive: too deep); NaN errors (no truth) are left out."""
    if not (is_number(angle_step) and 0 < angle_step <= 180):
        raise not_allowed(WHERE, "angle_step", angle_step, "a bin width in (0, 180] deg")
    a, e, d = (np.asarray(v, np.float64) for v in (angle, error, depth))
    keep = np.isfinite(e)
    a, e, d = a[keep], e[keep], d[keep]
    idx = np.floor(a / angle_step + 0.5).astype(int)
    rows = []
    for i in np.unique(idx):
        m = idx == i
        ei = e[m]
        rms = float(np.sqrt(np.mean(ei ** 2)))
        rows.append(dict(angle=float(i * angle_step), n=int(m.sum()), mean=float(ei.mean()), std=float(ei.std()),
                         rms=rms, p95=float(np.percentile(np.abs(ei), 95)),
                         rms_percent=float(100.0 * rms / np.mean(d[m]))))
    return rows


class SurveyResult:
    """What `survey` returns: ``soundings`` (`SOUNDING_DTYPE`), ``true_z`` (the seabed's height
    under each sounding), ``error`` (measured minus true depth, m; depth = -z), ``errors``
    (`error_table`), ``n_pings``, ``sonar`` (the sensor's settings: kind, beam widths, bins)."""

    def __init__(self, soundings, true_z, n_pings, sonar, angle_step=5.0):
        self.soundings, self.true_z, self.n_pings, self.sonar = soundings, true_z, n_pings, sonar
        self.error = true_z - soundings["z"]   # measured depth (-z) minus true depth (-true_z)
        self.errors = error_table(soundings["angle"], self.error, -true_z, angle_step)

    def grid(self, cell=0.5, bounds=None):
        """The soundings' depth map (`mitsonar.products.soundings.grid_depths`)."""
        from mitsonar.products.soundings import grid_depths

        return grid_depths(self.soundings, cell, bounds)

    def summary(self) -> dict:
        """A JSON-ready summary: counts, overall error, and the table per beam angle."""
        e = self.error[np.isfinite(self.error)]
        return dict(n_pings=int(self.n_pings), n_soundings=int(len(self.soundings)),
                    mean_error=float(e.mean()) if e.size else None,
                    rms_error=float(np.sqrt(np.mean(e ** 2))) if e.size else None,
                    sonar=self.sonar, per_angle=self.errors)


def survey(scene, trajectory, *, spp=256, seed=0, threshold_db=10.0, method=None, speckle=True, max_scans=None,
           start_time=None, end_time=None, max_depth=None, sensor=0, angle_step=5.0, progress=None,
           sound_speed_profile=None, water_profile=None):
    """Render a survey of ``scene``'s echo sounder along ``trajectory`` and detect the bottom in
    every ping: a `SurveyResult`. ``method`` defaults to ``centroid`` for a multibeam and
    ``leading_edge`` for a single beam; ``speckle``: detect on each scan's scene speckle (True:
    `speckled`, the sensor's ``speckle_seed``, changing along the track as the head moves) or on
    the noise-free intensity (False); ``sound_speed_profile``: the water the soundings are
    processed with (`soundings`; None: straight rays at the head's nominal speed);
    ``water_profile``: the water the survey is rendered in (refracted paths, `render_scan`'s
    ``sound_speed_profile``; None: uniform at the head's nominal speed).
    Every option is checked before the first render; a survey in which no beam finds the bottom
    is refused with one line (`NoBottomError`)."""
    from mitsonar.sim.scene import sonar_of
    from mitsonar.sim.survey import render_survey

    sonar = sonar_of(scene, sensor)
    method = method or sonar.sonar_kind.bathymetry_method
    threshold_db, method = check_options(threshold_db, method)
    if not isinstance(speckle, bool):
        raise not_allowed(WHERE, "speckle", speckle, "True or False")
    error_table([], [], [], angle_step)     # the step, checked before any render
    check_profile(sound_speed_profile)
    check_profile(water_profile)
    scans = render_survey(scene, trajectory, None, spp=spp, seed=seed, max_scans=max_scans, start_time=start_time,
                          end_time=end_time, sensor=sensor, max_depth=max_depth, progress=progress or False,
                          sound_speed_profile=water_profile)
    parts, n, resolution, scans_speed = [], 0, float(sonar.bin_width), float("nan")
    for i, scan in enumerate(scans):
        parts.append(soundings(scan, threshold_db, method, speckle, ping=i, sound_speed_profile=sound_speed_profile))
        resolution = speckle_resolution(scan)
        scans_speed = scan.sound_speed
        n += 1
    s = np.concatenate(parts) if parts else np.zeros(0, SOUNDING_DTYPE)
    if len(s) == 0:
        raise no_bottom(n, sonar.range_min, sonar.range_max)
    true_z = true_height(scene, s["x"], s["y"], s["head_z"])
    info = dict(kind=sonar.kind, beams=int(sonar.n_pings), beamwidth_h=float(sonar.beam.beamwidth_h),
                beamwidth_v=float(sonar.beam.beamwidth_v), bin_width=float(sonar.bin_width),
                range_min=float(sonar.range_min), range_max=float(sonar.range_max), method=method,
                threshold_db=threshold_db, speckle=speckle, speckle_resolution=resolution, spp=int(spp),
                seed=int(seed), sound_speed=float(scans_speed),
                processing_svp=None if sound_speed_profile is None else
                dict(depth=sound_speed_profile.depths.tolist(), sound_speed=sound_speed_profile.speeds.tolist()))
    return SurveyResult(s, true_z, n, info, angle_step)
