"""Strip-map SAS image formation in the wavenumber domain (omega-k, range migration), numpy FFTs.

The processor of Hayes and Gough ("Synthetic aperture sonar: a review of current status", IEEE J.
Oceanic Eng. 34(3), 2009, the wavenumber algorithm; Cafforio, Prati and Rocca, "SAR data focusing
using seismic migration techniques", IEEE Trans. Aerosp. Electron. Syst. 27(2), 1991, for radar),
for a straight, level track along world x (the navigation's; refused otherwise):

1. each receiver of each ping becomes a monostatic element at its phase centre ``u`` (the
   transmitter-receiver midpoint), the phase-centre approximation's error ``d^2 / (4 R)``
   (``d`` the pair's baseline, grown by the receiver's motion ``v t`` during the flight) removed
   sample by sample; the phase centres, ``D / 2`` apart when the platform advances a whole number
   of half receivers per ping (the DPCA condition, `mitsonar.sas.StripMap`), fill a uniform
   along-track grid (a centre that pings share is taken once);
2. the compressed data in a range window around the image, 2-D Fourier transformed to ``(k_u,
   omega)``; the receivers' motion during the flight (each sample's phase centre is ``v t / 2``
   further on) is a linear phase in ``k_u`` per sample;
3. the reference function ``exp(i sqrt(4 k^2 - k_u^2) rho_0)`` (``rho_0`` the window's centre, the
   slant range from the track line) focuses the reference range exactly, and the Stolt mapping
   ``k_rho = sqrt(4 k^2 - k_u^2)`` (linear interpolation on the oversampled spectrum) every other;
   the processed beam is the window over ``s = k_u / (2 k)`` (uniform or Hann over ``|s| <
   sin(theta_p / 2)``), the same as `mitsonar.sas.form_image`'s, so the two give the same
   resolutions;
4. the inverse transform gives the image over along-track x and slant range rho, interpolated
   (bilinearly, at baseband) onto the ground-range `Grid` at its height.

Its cost is a few FFTs of the data instead of pixels x pairs; it assumes what backprojection does
not: a straight track (navigation errors cannot be focused, only committed), constant speed and
sound speed, a flat image plane.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.sas.backprojection import Grid, SASImage, row_geometry
from mitsonar.sas.config import WINDOW_FACTORS


def _fail(name, value, allowed):
    raise ValueError(f"omega_k '{name}': {value!r} is not allowed ({allowed})")


def omega_k(echoes, grid, *, navigation=None, beamwidth=None, window="uniform", oversample=4) -> SASImage:
    """Focus strip-map `Echoes` onto ``grid`` with the wavenumber algorithm (module docstring).
    ``navigation``, ``beamwidth``, ``window`` as `mitsonar.sas.form_image`; ``oversample`` the
    zero-padding of both transforms (the image's sampling). Returns a `SASImage`."""
    import time

    from scipy import fft as sfft

    from mitsonar.signals.processing import matched_filter

    if not isinstance(grid, Grid):
        _fail("grid", type(grid).__name__, "a mitsonar.sas.Grid")
    if window not in WINDOW_FACTORS:
        _fail("window", window, " or ".join(WINDOW_FACTORS))
    if not (isinstance(oversample, (int, np.integer)) and 1 <= oversample <= 16):
        _fail("oversample", oversample, "a whole number 1 to 16")
    t_start = time.perf_counter()
    e = np.asarray(echoes.elements, dtype=np.float64)
    c, fc, fs = echoes.sound_speed, echoes.carrier, echoes.sample_rate
    poses, vel = row_geometry(echoes, navigation)
    tx = poses[:, :3, 3]
    if np.ptp(tx[:, 1]) > 1e-6 or np.ptp(tx[:, 2]) > 1e-6 or np.any(np.abs(vel[:, 1:]) > 1e-6) \
            or np.ptp(vel[:, 0]) > 1e-6 * max(1.0, abs(vel[0, 0])):
        _fail("navigation", "the track", "a straight, level track along world x at constant speed: use form_image")
    rx = np.einsum("rij,ej->rei", poses[:, :3, :3], e) + tx[:, None, :]
    if np.ptp(rx[..., 1]) > 1e-6 or np.ptp(rx[..., 2]) > 1e-6:
        _fail("echoes", "the elements", "receivers along the track, at the transmitter's height and offset")
    if beamwidth is None:
        d = np.diff(np.sort(e[:, 0]))
        beamwidth = echoes.wavelength / float(np.median(d[d > 0]))
    if not (isinstance(beamwidth, (int, float, np.floating)) and 0 < beamwidth <= math.pi):
        _fail("beamwidth", beamwidth, "a full angle in rad, > 0 and <= pi")
    smax = math.sin(0.5 * beamwidth)
    v = float(vel[0, 0])
    h = float(tx[0, 2] - grid.z)
    y0 = float(tx[0, 1])

    # 1. phase centres on a uniform grid
    centre = 0.5 * (tx[:, None, 0] + rx[..., 0])                      # (rows, el)
    base = rx[..., 0] - tx[:, None, 0]                                # baseline at the ping's start
    spacing = float(np.median(np.diff(np.unique(np.round(centre.ravel(), 9)))))
    u0 = float(centre.min())
    slot = (centre - u0) / spacing
    if np.max(np.abs(slot - np.round(slot))) > 0.05:
        _fail("echoes", "their phase centres", "a uniform along-track grid: advance a whole number of half "
              "receivers per ping (the DPCA condition)")
    slot = np.round(slot).astype(np.int64)
    M = int(slot.max()) + 1
    pick = np.full(M, -1, np.int64)
    flat = slot.ravel()
    order = np.argsort(flat, kind="stable")
    first = np.unique(flat[order], return_index=True)
    pick[first[0]] = order[first[1]]
    if (pick < 0).any():
        _fail("echoes", "their phase centres", "no gaps along track (the DPCA condition)")
    # the slant-range window around the grid
    rho = np.sqrt((grid.y - y0) ** 2 + h * h)
    rho_lo, rho_hi = float(rho.min()), float(rho.max())
    pad = 0.5 * np.max(np.abs(base)) + 8 * c / (2 * echoes.pulse.bandwidth)
    t_lo = 2 * max(rho_lo - pad, 0.0) / c
    tan_p = min(smax, 0.99) / math.sqrt(1.0 - min(smax, 0.99) ** 2)        # the migration at the beam's edge
    t_hi = 2 * (math.hypot(rho_hi, tan_p * rho_hi + 0.5 * np.ptp(grid.x)) + pad) / c
    k_lo, k_hi = int(math.floor(t_lo * fs)), min(echoes.n_samples, int(math.ceil(t_hi * fs)) + 1)
    t = np.arange(k_lo, k_hi) / fs
    rows, els = np.divmod(pick, len(e))
    y = np.empty((M, len(t)), np.complex128)
    for r in np.unique(rows):
        m = rows == r
        y[m] = matched_filter(echoes.signal[r, els[m]], echoes.pulse, fs)[:, k_lo:k_hi]
    # PCA: the pair's extra path d^2 / (4 R), d the baseline grown by the receiver's motion v t
    d_eff = base.ravel()[pick][:, None] + v * t[None, :]
    R = np.maximum(0.5 * c * t, 1e-6)[None, :]
    y *= np.exp(2j * np.pi * fc / c * d_eff ** 2 / (4.0 * R))
    # 2. along-track transform (zero-padded), the in-flight shift v t / 2, range transform
    nu = sfft.next_fast_len(int(oversample) * (M + int(math.ceil(np.ptp(grid.x) / spacing)) + 8))
    Y = sfft.fft(y, nu, axis=0)
    ku = 2 * np.pi * sfft.fftfreq(nu, spacing)
    Y *= np.exp(-1j * ku[:, None] * (0.5 * v * t[None, :]))
    nt = sfft.next_fast_len(int(oversample) * len(t))
    S = sfft.fft(Y, nt, axis=1) * np.exp(-2j * np.pi * sfft.fftfreq(nt, 1 / fs)[None, :] * t[0])
    fb = sfft.fftfreq(nt, 1 / fs)
    k = 2 * np.pi * (fc + fb) / c                                        # (nt,)
    inband = np.abs(fb) <= 0.5 * echoes.pulse.bandwidth
    # 3. processed beam, reference function, Stolt mapping
    s = ku[:, None] / (2 * k[None, :])
    u = np.abs(s) / smax
    w = (u < 1.0) & inband[None, :]
    if window == "hann":
        w = w * (0.5 + 0.5 * np.cos(np.pi * np.minimum(u, 1.0)))
    rho0 = 0.5 * (rho_lo + rho_hi)
    kr = np.sqrt(np.maximum(4 * k[None, :] ** 2 - ku[:, None] ** 2, 0.0))
    F = S * w * np.exp(1j * kr * rho0)
    kc = 2 * 2 * np.pi * fc / c
    dk = 4 * np.pi * (fs / nt) / c
    K = kc + (np.arange(nt) - nt // 2) * dk                              # uniform k_rho grid
    srt = np.argsort(fb)
    G = np.zeros((nu, nt), np.complex128)
    for i in range(nu):
        src = kr[i, srt]
        G[i] = np.interp(K, src, F[i, srt].real, left=0.0, right=0.0) \
            + 1j * np.interp(K, src, F[i, srt].imag, left=0.0, right=0.0)
    # 4. back to (x, rho): x = u0 + j spacing, rho = rho0 + delta; each target's focused lobe has a
    # constant phase exp(-i kc Delta), no carrier across rho: interpolated as it is
    # the image sampled oversample times finer than the data: both spectra zero-padded (in fft order)
    G = sfft.ifftshift(G, axes=1)                                        # column 0: K = kc
    nx, nr = nu * int(oversample), nt * int(oversample)
    H = np.zeros((nx, nr), np.complex128)
    hu, hr = (nu + 1) // 2, (nt + 1) // 2
    for rows_src, rows_dst in ((slice(0, hu), slice(0, hu)), (slice(hu, nu), slice(nx - (nu - hu), nx))):
        H[rows_dst, :hr] = G[rows_src, :hr]
        H[rows_dst, nr - (nt - hr):] = G[rows_src, hr:]
    img = sfft.ifft2(H)
    dx = 2 * np.pi / (nx * (ku[1] - ku[0]))
    x_axis = u0 + np.arange(nx) * dx
    drho = 2 * np.pi / (nr * dk)
    delta = np.where(np.arange(nr) < nr // 2, np.arange(nr), np.arange(nr) - nr) * drho
    ordr = np.argsort(delta)
    delta, img = delta[ordr], img[:, ordr]
    # onto the ground grid
    gx = (grid.x - u0) / dx
    gr = (rho - rho0 - delta[0]) / drho
    ix, ir = np.floor(gx).astype(np.int64), np.floor(gr).astype(np.int64)
    fx, fr = gx - ix, gr - ir
    ok_x = (ix >= 0) & (ix + 1 < nx)
    ok_r = (ir >= 0) & (ir + 1 < nr)
    ix, ir = np.clip(ix, 0, nx - 2), np.clip(ir, 0, nr - 2)
    a = img[np.ix_(ix, ir)] * (1 - fx)[:, None] + img[np.ix_(ix + 1, ir)] * fx[:, None]
    b = img[np.ix_(ix, ir + 1)] * (1 - fx)[:, None] + img[np.ix_(ix + 1, ir + 1)] * fx[:, None]
    out = (a * (1 - fr)[None, :] + b * fr[None, :]) * (ok_x[:, None] & ok_r[None, :])
    # the carrier phase of the slant range, as backprojection's pixels carry it
    out = out * np.exp(1j * kc * (rho - rho0))[None, :]
    meta = {"processor": "omega_k", "beamwidth": float(beamwidth), "window": window, "sound_speed": float(c),
            "navigation": "given" if navigation is not None else "rendered poses", "phase_centres": M,
            "seconds": time.perf_counter() - t_start}
    return SASImage(out.astype(np.complex64), grid, meta)
