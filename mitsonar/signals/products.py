"""Products of element data: a multibeam `Scan` by beamforming, side-scan bathymetry by interferometry."""
from __future__ import annotations

import math

import numpy as np

import mitsonar.kinds as kinds

from mitsonar.signals.processing import (arrival_angle, delay_and_sum, equivalent_duration, look_directions,
                                         matched_filter)


def beamform(echoes, bearings=None, *, row=0, n_bins=None, weights=None):
    """A multibeam `mitsonar.Scan` from one row of `Echoes`: pulse compression (`matched_filter`), then
    wideband delay-and-sum (`delay_and_sum`) towards each bearing.

    Same conventions as a rendered multibeam scan: row k is the receive beam at ``bearings[k]``
    (rad; default the head's ``bearing_start + k bearing_step``), its pose the head's @
    ``bearing_rotation(bearings[k])``, times zeros; bin j covers ranges
    ``range_min + [j, j + 1) (range_max - range_min) / n_bins`` (default the head's bins), range
    ``c t / 2``. ``intensity`` is energy per bin in the renderer's units: the beam's power
    ``|b|^2 / pressure_scale^2`` summed over the bin's samples over ``sample_rate * int |R|^2``
    (a lone echo of energy E adds up to E); ``data`` the bytes of the head's electronics
    (`mitsonar.receiver.electronics.Electronics.apply`, noise seeded by the render's ``seed``) without
    their statistical speckle: the beams already hold the physical one."""
    from mitsonar.geometry.frames import bearing_rotation
    from mitsonar.scan import ElectronicsSettings, Scan, ScanMeta

    b = np.asarray(echoes.bearings if bearings is None else bearings, dtype=np.float64).reshape(-1)
    n_bins = int(echoes.n_bins if n_bins is None else n_bins)
    fs, c = echoes.sample_rate, echoes.sound_speed
    y = matched_filter(echoes.signal[row], echoes.pulse, fs)
    beams = delay_and_sum(y, echoes.elements, look_directions(b), fs, echoes.carrier, c, weights)
    scale = float(echoes.meta.get("pressure_scale", 1.0))
    power = np.abs(beams) ** 2 / (scale * scale * fs * equivalent_duration(echoes.pulse, fs))
    r = c * echoes.sample_times / 2.0
    width = (echoes.range_max - echoes.range_min) / n_bins
    j = np.floor((r - echoes.range_min) / width).astype(np.int64)
    ok = (j >= 0) & (j < n_bins)
    intensity = np.stack([np.bincount(j[ok], weights=p[ok], minlength=n_bins) for p in power])
    ranges = echoes.range_min + (np.arange(n_bins) + 0.5) * width
    poses = echoes.poses[row] @ bearing_rotation(b)
    intensity = intensity.astype(np.float32)
    data = np.zeros(intensity.shape, np.uint8)
    settings = echoes.meta.get("electronics")
    if settings is not None:
        from mitsonar.receiver.electronics import Electronics

        model = Electronics.from_dict(settings)
        data = model.apply(intensity, ranges, absorption=echoes.meta.get("absorption", 0.0), sound_speed=c,
                           seed=int(echoes.meta.get("seed", 0)), speckle=np.ones(intensity.shape, np.complex128))
    return Scan(intensity=intensity, data=data, ranges=ranges,
                bearings=b, poses=poses, range_min=echoes.range_min, range_max=echoes.range_max,
                beam_pattern="delay_and_sum", beamwidth_h=_beamwidth_deg(echoes), beamwidth_v=180.0,
                kind=kinds.MULTIBEAM.name, sound_speed=c, absorption=float(echoes.meta.get("absorption", 0.0)),
                electronics=ElectronicsSettings.from_dict(settings), meta=ScanMeta.from_dict({"source": "beamformed echoes", **{
                    k: v for k, v in echoes.meta.items() if k in ("spp", "seed", "speckle_seed")}}))


def _beamwidth_deg(echoes) -> float:
    """deg: the array's broadside -3 dB width ``0.886 lambda / L`` (L the aperture across +x; 180 if none)."""
    x = echoes.elements[:, 0]
    n = len(x)
    aperture = (x.max() - x.min()) * n / max(n - 1, 1)
    if aperture <= 0:
        return 180.0
    return float(min(180.0, math.degrees(0.886 * echoes.wavelength / aperture)))


def sidescan_bathymetry(echoes, pair=(0, 1), average=5, threshold=0.05):
    """Interferometric side-scan bathymetry: per row and sample, the world point the echo came from.

    The elements ``pair`` (their baseline across the fan, at most half a wavelength for unambiguous
    angles) give after pulse compression the angle of arrival ``psi`` off the baseline's normal in the
    plane of the boresight and the baseline (`arrival_angle`, phases averaged over ``average``
    samples); the echo at range ``r = c t / 2`` comes from ``origin + r (cos psi z + sin psi b)`` (``z``
    the boresight, ``b`` the baseline's unit vector, in the world by the row's pose). Returns a dict:
    ``points`` (n_rows, n_samples, 3) world (NaN where the compressed amplitude is under
    ``threshold`` of the row's peak, or the phase is ambiguous), ``angle`` (rad), ``range`` (m)."""
    i, j = pair
    e = echoes.elements
    base = e[j] - e[i]
    b_len = float(np.linalg.norm(base))
    b_hat = base / b_len
    fs, c = echoes.sample_rate, echoes.sound_speed
    y = matched_filter(echoes.signal[:, [i, j]], echoes.pulse, fs)
    psi = arrival_angle(y[:, 0], y[:, 1], b_len, echoes.wavelength, average)
    amp = np.abs(y).mean(axis=1)
    weak = amp < threshold * amp.max(axis=1, keepdims=True)
    psi = np.where(weak, np.nan, psi)
    r = c * echoes.sample_times / 2.0
    z = np.array([0.0, 0.0, 1.0])
    local = (np.cos(psi)[..., None] * z + np.sin(psi)[..., None] * b_hat) * r[None, :, None]
    origin = e[i] + 0.5 * base
    local = local + origin
    R, o = echoes.poses[:, :3, :3], echoes.poses[:, :3, 3]
    points = np.einsum("rij,rkj->rki", R, local) + o[:, None, :]
    return {"points": points, "angle": psi, "range": r}
