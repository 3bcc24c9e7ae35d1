"""Seabed backscattering strength: Lambert's law and the APL-UW high-frequency model.

The APL-UW model is the bottom model of the *APL-UW High-Frequency Ocean Environmental Acoustic
Models Handbook* (Technical Report APL-UW TR 9407, 1994), section IV (after Jackson, Winebrenner
and Ishimaru 1986, J. Acoust. Soc. Am. 79, 1410, and Mourad and Jackson 1989): interface roughness
scattering (the Kirchhoff approximation near normal incidence, the composite-roughness
approximation with shadowing and slope averaging elsewhere, an empirical large-roughness form for
rock and gravel) plus sediment volume scattering, from six sediment parameters (handbook Table 1):
density ratio, sound speed ratio, loss parameter delta, volume parameter sigma2, spectral strength
w2 and spectral exponent gamma. Sediment classes by mean grain size ``Mz`` (phi units) come from
the handbook's grain-size relations (sec. IV.A.4, Eqs. 2-10), which reproduce its Table 2.

Equation numbers below are those of TR 9407 section IV as quoted by an independent implementation
(uacpy, ``uacpy/sonar/bottom_scattering.py``); the handbook's scan itself was not available here
to check them against. The relief spectrum is ``W(K) = w2 / (h0 K)^gamma`` (Eq. 7) with
``h0 = 1 cm`` and ``w2`` in cm^4, so every wavenumber in the roughness terms is in cm^-1.

All angles are grazing angles in radians (0 along the seabed, pi/2 straight down).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mitsonar.acoustics._checks import as_array, at_least, grazing_angle, in_range
from mitsonar.acoustics.interface import DB_PER_WAVELENGTH_PER_DELTA
from mitsonar.acoustics.water import SOUND_SPEED

__all__ = ["lambert", "bistatic_mean_grazing", "Sediment", "SEDIMENTS", "sediment", "apl_uw_backscatter",
           "APL_UW_FREQUENCY_RANGE"]

#: The handbook's frequency band for the bottom model (TR 9407 sec. IV.A.8), Hz.
APL_UW_FREQUENCY_RANGE = (10.0e3, 100.0e3)
#: Water sound speed the handbook used to form delta from Hamilton's attenuation (Eq. 4), m/s.
HANDBOOK_WATER_SOUND_SPEED = 1528.0
_TR = "APL-UW TR 9407"
_H0 = 1.0                          # cm, reference length of the relief spectrum (Eq. 7)
_GAMMA = 3.25                      # spectral exponent when none is measured (Eq. 8)
_MIN_GRAZING = math.radians(0.001)  # below this the handbook uses the value at it (sec. IV.C.4)
# Three-point Gauss-Hermite rule for the slope average (Eqs. 46-48): int exp(-x^2) g(x) dx.
_GH_NODES = (-1.224745, 0.0, 1.224745)
_GH_WEIGHTS = (0.295410, 1.181636, 0.295410)


def lambert(grazing, mu):
    """Lambert's-law backscattering strength, dB: :math:`S_b = \\mu + 10\\log_{10}\\sin^2\\theta`.

    The monostatic case of :math:`S = \\mu + 10\\log_{10}(\\sin\\theta_i \\sin\\theta_s)` (Lambert's
    law for a diffusely scattering surface; e.g. Mackenzie 1961, J. Acoust. Soc. Am. 33, 1498,
    who found :math:`\\mu = -27` dB for the deep-ocean floor).

    Parameters
    ----------
    grazing : float or array_like
        Grazing angle, radians, 0 to pi/2.
    mu : float or array_like
        Lambert parameter, dB (the strength at normal incidence).

    Returns
    -------
    float or ndarray
        Backscattering strength in dB (``-inf`` at zero grazing).
    """
    theta = grazing_angle("lambert", grazing)
    m = as_array("lambert", "mu", mu)
    if not np.isfinite(m).all():
        raise ValueError(f"lambert: mu {m[~np.isfinite(m)].flat[0]} is not a finite number of dB")
    with np.errstate(divide="ignore"):
        out = m + 10.0 * np.log10(np.sin(theta) ** 2)
    return out[()] if isinstance(out, np.ndarray) else out


def bistatic_mean_grazing(incident, scattered):
    """The grazing angle at which to evaluate a monostatic model for a bistatic geometry.

    ``(incident + scattered) / 2``. This is an approximation, not the handbook's: the APL-UW
    bottom model above is monostatic (backscatter). For a bistatic pair near the backscatter
    direction, evaluate it at the mean of the incident and scattered grazing angles; Lambert's law
    needs no such help (``mu + 10 log10(sin(incident) sin(scattered))``). Far from backscatter
    (forward scatter, the specular direction) use a bistatic model instead, e.g. Williams and
    Jackson (1998), J. Acoust. Soc. Am. 103, 169.

    Parameters
    ----------
    incident, scattered : float or array_like
        Grazing angles, radians, 0 to pi/2.
    """
    a = grazing_angle("bistatic_mean_grazing", incident)
    b = grazing_angle("bistatic_mean_grazing", scattered)
    out = 0.5 * (a + b)
    return out[()] if isinstance(out, np.ndarray) else out


# --------------------------------------------------------------------------- sediment parameters

def _density_ratio(mz: float) -> float:
    """TR 9407 Eq. 2: density ratio from mean grain size (phi)."""
    if mz < 1.0:
        return 0.007797 * mz ** 2 - 0.17057 * mz + 2.3139
    if mz < 5.3:
        return -0.0165406 * mz ** 3 + 0.2290201 * mz ** 2 - 1.1069031 * mz + 3.0455
    return -0.0012973 * mz + 1.1565


def _sound_speed_ratio(mz: float) -> float:
    """TR 9407 Eq. 3: sound speed ratio from mean grain size (phi)."""
    if mz < 1.0:
        return 0.002709 * mz ** 2 - 0.056452 * mz + 1.2778
    if mz < 5.3:
        return -0.0014881 * mz ** 3 + 0.0213937 * mz ** 2 - 0.1382798 * mz + 1.3425
    return -0.0024324 * mz + 1.0019


def _attenuation_per_khz(mz: float) -> float:
    """TR 9407 Eq. 5, Hamilton's (1972) sediment attenuation over frequency, dB m^-1 kHz^-1."""
    if mz < 0.0:
        return 0.4556
    if mz < 2.6:
        return 0.4556 + 0.0245 * mz
    if mz < 4.5:
        return 0.1978 + 0.1245 * mz
    if mz < 6.0:
        return 8.0399 - 2.5228 * mz + 0.20098 * mz ** 2
    if mz < 9.5:
        return 0.9431 - 0.2041 * mz + 0.0117 * mz ** 2
    return 0.0601


@dataclass(frozen=True)
class Sediment:
    """One seabed, the six inputs of APL-UW TR 9407 Table 1.

    Attributes
    ----------
    name : str
        Sediment name (TR 9407 Table 2 names for the presets in :data:`SEDIMENTS`).
    density_ratio : float
        Sediment over water mass density (recommended 1 to 3, sec. IV.A.8).
    sound_speed_ratio : float
        Sediment over water sound speed, ``nu`` (0.8 to 3).
    loss : float
        Loss parameter ``delta``, imaginary over real sediment wavenumber (> 0, up to 0.1).
    volume : float
        Volume parameter ``sigma2``: sediment volume scattering coefficient over sediment
        attenuation coefficient (0 to 1, though 0.001 to 0.002 are the handbook's values).
    spectral_strength : float
        ``w2``, cm^4: the relief spectrum ``W(K) = w2 / (h0 K)^gamma`` at ``K = 1 cm^-1`` (> 0, up to 1).
    spectral_exponent : float
        ``gamma``, the relief spectrum's power-law exponent (2.4 to 3.9; 3.25 by default, Eq. 8).
    grain_size : float or None
        Mean grain size ``Mz`` in phi where the row comes from the grain-size relations.

    Values outside the handbook's recommended limits (sec. IV.A.8) are refused.
    """
    name: str
    density_ratio: float
    sound_speed_ratio: float
    loss: float
    volume: float
    spectral_strength: float
    spectral_exponent: float = _GAMMA
    grain_size: float | None = None

    def __post_init__(self):
        where = f"Sediment {self.name!r}"
        limits = {"density_ratio": (1.0, 3.0), "sound_speed_ratio": (0.8, 3.0), "loss": (0.0, 0.1),
                  "volume": (0.0, 1.0), "spectral_strength": (0.0, 1.0), "spectral_exponent": (2.4, 3.9)}
        for field, (lo, hi) in limits.items():
            in_range(where, field, getattr(self, field), lo, hi, "", f"{_TR} sec. IV.A.8")
        for field in ("loss", "spectral_strength"):     # the model divides by both
            at_least(where, field, getattr(self, field), 0.0, "", strict=True)

    @property
    def attenuation(self) -> float:
        """Sediment attenuation, dB per wavelength: ``40 pi log10(e) delta`` (TR 9407 sec. IV.A)."""
        return DB_PER_WAVELENGTH_PER_DELTA * self.loss

    @classmethod
    def from_grain_size(cls, grain_size: float, name: str | None = None) -> "Sediment":
        """The handbook's sediment for mean grain size ``grain_size`` (phi, -1 to 9): TR 9407
        sec. IV.A.4, Eqs. 2-10 (density and sound speed ratios, Eqs. 2-3; delta from Hamilton's
        attenuation with ``c1 = 1528 m/s``, Eqs. 4-5; ``sigma2`` 0.002 below 5.5 phi and 0.001
        above, Eq. 6; ``gamma = 3.25``, Eq. 8; ``w2 = 0.00207 h^2`` cm^4 from the rms relief ``h``
        of a 1 m track, Eqs. 9-10)."""
        mz = float(in_range("Sediment.from_grain_size", "grain_size", grain_size, -1.0, 9.0, "phi",
                            f"{_TR} Eqs. 2-10"))
        nu = _sound_speed_ratio(mz)
        delta = (_attenuation_per_khz(mz) * nu * (HANDBOOK_WATER_SOUND_SPEED / 1000.0)
                 * math.log(10.0) / (40.0 * math.pi))                        # Eq. 4
        h = (2.03846 - 0.26923 * mz) / (1.0 + 0.076923 * mz) if mz < 5.0 else 0.5   # Eqs. 9-10, cm
        return cls(name=name or f"Mz {mz:g} phi", density_ratio=_density_ratio(mz), sound_speed_ratio=nu,
                   loss=delta, volume=0.002 if mz < 5.5 else 0.001,
                   spectral_strength=0.00207 * h * h * _H0 ** 2, spectral_exponent=_GAMMA, grain_size=mz)


def _rock(name: str, sound_speed_ratio: float, w2: float) -> Sediment:
    # TR 9407 Table 2: the rock, cobble and gravel rows are constants, not grain-size relations.
    return Sediment(name, density_ratio=2.5, sound_speed_ratio=sound_speed_ratio, loss=0.01374, volume=0.002,
                    spectral_strength=w2, spectral_exponent=_GAMMA)


# TR 9407 Table 2 ("model inputs in terms of sediment name"): name -> mean grain size (phi), every
# row but the rocks from the grain-size relations (which reproduce the table's printed digits).
_TABLE2_GRAIN_SIZE = {
    "sandy gravel": -1.0, "very coarse sand": -0.5, "muddy sandy gravel": 0.0, "coarse sand": 0.5,
    "gravelly muddy sand": 1.0, "medium sand": 1.5, "muddy gravel": 2.0, "fine sand": 2.5,
    "muddy sand": 3.0, "very fine sand": 3.5, "clayey sand": 4.0, "coarse silt": 4.5, "sandy silt": 5.0,
    "medium silt": 5.5, "sandy mud": 6.0, "fine silt": 6.5, "clayey silt": 6.5, "sandy clay": 7.0,
    "very fine silt": 7.5, "silty clay": 8.0, "clay": 9.0,
}

#: Seabeds by TR 9407 Table 2 name. ``rough rock``, ``rock`` and ``cobble`` are the table's
#: constants (density ratio 2.5, delta 0.01374, sigma2 0.002; nu 2.5, 2.5, 1.8; w2 0.20693,
#: 0.01862, 0.016 cm^4); every other row is :meth:`Sediment.from_grain_size` at the table's Mz.
SEDIMENTS: dict[str, Sediment] = {
    "rough rock": _rock("rough rock", 2.5, 0.20693),
    "rock": _rock("rock", 2.5, 0.01862),
    "cobble": _rock("cobble", 1.8, 0.016),
    **{name: Sediment.from_grain_size(mz, name) for name, mz in _TABLE2_GRAIN_SIZE.items()},
}


def sediment(name: str) -> Sediment:
    """The :data:`SEDIMENTS` entry called ``name`` (case and spacing insensitive)."""
    key = " ".join(str(name).lower().replace("_", " ").replace("-", " ").split())
    if key not in SEDIMENTS:
        raise ValueError(f"sediment: unknown name {name!r} (known: {', '.join(SEDIMENTS)})")
    return SEDIMENTS[key]


_sediment_by_name = sediment   # apl_uw_backscatter's parameter is called ``sediment``


# --------------------------------------------------------------------------- the APL-UW model

def _shadowing(theta, s):
    """Eqs. 43-45: Wagner's shadowing for rms slope ``s``; 1 where ``tan(theta)/s > 2``."""
    from scipy.special import erfc  # here: scipy.special is a quarter second of every CLI start

    t = np.tan(theta) / s
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        q = (np.exp(-t * t) / np.sqrt(np.pi) - t * erfc(t)) / (4.0 * t)
        out = (1.0 - np.exp(-2.0 * q)) / (2.0 * q)
    return np.where(t > 2.0, 1.0, np.where(np.isfinite(out), out, 0.0))


def _slope_average(theta, s, cross_section):
    """Eqs. 46-49: ``(1/sqrt(pi)) sum_i w_i sigma(theta - x_i s)``, the cross section averaged over
    Gaussian large-scale slopes of rms ``s`` (three-point Gauss-Hermite); arguments clipped to
    0..pi/2."""
    total = 0.0
    for x, w in zip(_GH_NODES, _GH_WEIGHTS):
        total = total + w * cross_section(np.clip(theta - x * s, 0.0, np.pi / 2))
    return total / np.sqrt(np.pi)


def _interp(x):
    """Eq. 57: the logistic weight ``1 / (1 + exp(x))``, clamped beyond |x| = 40 (sec. IV.C.4)."""
    return 1.0 / (1.0 + np.exp(np.clip(x, -40.0, 40.0)))


def apl_uw_backscatter(grazing, frequency, sediment, sound_speed=SOUND_SPEED, extrapolate=False):
    """Seabed backscattering strength, dB: the APL-UW high-frequency bottom model (TR 9407 sec. IV.C).

    :math:`S_b = 10\\log_{10}(\\sigma_r + \\sigma_v)` (sec. IV.C, Eqs. 34-66), with

    * :math:`\\sigma_r = f_y \\sigma_m + (1 - f_y)\\sigma_{lr}` and
      :math:`\\sigma_m = f_x \\sigma_{kr} + (1 - f_x)\\sigma_{cr}` (Eqs. 57-64: logistic weights
      :math:`f_x` on :math:`\\cos\\theta` about the angle where the Kirchhoff term has fallen 30 dB,
      :math:`f_y` on the rms slope angle about 7 deg);
    * the Kirchhoff term (Eqs. 35-40), the closed-form approximation of
      :math:`\\frac{|R(\\pi/2)|^2}{8\\pi\\sin^2\\theta\\cos^2\\theta}\\int_0^\\infty e^{-q u^{2\\alpha}} J_0(u)\\,u\\,du`,
      :math:`q = q_c \\sin^2\\theta / \\cos^{2\\alpha}\\theta`:
      :math:`\\sigma_{kr} = b\\,q_c|R(\\pi/2)|^2 / (8\\pi[\\cos^{4\\alpha}\\theta + a q_c^2\\sin^4\\theta]^{(1+\\alpha)/2\\alpha})`,
      :math:`\\alpha = \\gamma/2 - 1`,
      :math:`q_c = C_h^2 2^{1-2\\alpha} k^{2(1-\\alpha)}`,
      :math:`C_h^2 = 2\\pi w_2 \\Gamma(2-\\alpha) 2^{-2\\alpha} / (h_0^\\gamma \\alpha(1-\\alpha)\\Gamma(1+\\alpha))`,
      :math:`a = [8\\alpha^2\\Gamma(\\tfrac{1}{2\\alpha}+\\tfrac12) / (\\Gamma(\\tfrac12)\\Gamma(\\tfrac1\\alpha)\\Gamma(\\tfrac{1}{2\\alpha}))]^{2\\alpha}`
      and :math:`b = a^{(1+\\alpha)/2\\alpha}\\Gamma(1/\\alpha)/(2\\alpha)`, the constant that makes it
      the integral's exact limit at normal incidence, :math:`|R|^2\\Gamma(1/\\alpha) q_c^{-1/\\alpha}/(16\\pi\\alpha)`
      (as in Williams and Jackson's bistatic form of the same term, J. Acoust. Soc. Am. 103, 169, 1998);
    * the composite-roughness term (Eqs. 41-52): the perturbation cross section
      :math:`\\sigma_{pr} = 4k^4\\sin^4\\theta\\,|Y|^2 W(2k\\cos\\theta)`,
      :math:`Y = ((m-1)^2\\cos^2\\theta + m^2 - \\kappa^2)/(m\\sin\\theta + P)^2`, averaged over the
      large-scale slopes (rms :math:`s`, Gauss-Hermite) and shadowed;
    * the large-roughness term for rock and gravel (Eqs. 53-56);
    * sediment volume scattering (Eqs. 65-66):
      :math:`\\sigma_{pv} = 5\\delta\\sigma_2|1 - R^2|^2\\sin^2\\theta / (\\nu\\ln 10\\,|P|^2\\,\\mathrm{Im}\\,P)`,
      slope averaged and shadowed like :math:`\\sigma_{pr}`.

    :math:`R`, :math:`P` and :math:`\\kappa` are those of
    :func:`~mitsonar.acoustics.interface.reflection_coefficient`; :math:`k = 2\\pi f / c` in cm^-1.

    Parameters
    ----------
    grazing : float or array_like
        Grazing angle, radians, 0 to pi/2 (below 0.001 deg the value at 0.001 deg, sec. IV.C.4).
    frequency : float or array_like
        Frequency, Hz, 10 to 100 kHz (the handbook's band, sec. IV.A.8); broadcast with ``grazing``.
    sediment : Sediment or str
        The seabed, or a :data:`SEDIMENTS` name such as ``"medium sand"``.
    sound_speed : float
        Water sound speed just above the seabed, m/s (sets ``k``). The handbook's Table 3 used 1528.
    extrapolate : bool
        Accept frequencies outside 10-100 kHz (the model has no stated accuracy there).

    Returns
    -------
    float or ndarray
        Backscattering strength, dB re 1 m^2 per m^2, shaped like ``grazing`` broadcast with
        ``frequency``.

    Notes
    -----
    The handbook quotes about 3 dB uncertainty for well-characterised sand and silt above 5 deg
    grazing and about 10 dB for rock and gravel (sec. IV.C.3).
    """
    sed = _sediment_by_name(sediment) if isinstance(sediment, str) else sediment
    if not isinstance(sed, Sediment):
        raise ValueError(f"apl_uw_backscatter: sediment {sediment!r} is not a Sediment or a SEDIMENTS name")
    theta = grazing_angle("apl_uw_backscatter", grazing)
    lo, hi = APL_UW_FREQUENCY_RANGE
    if extrapolate:
        f = as_array("apl_uw_backscatter", "frequency", frequency)
        if not (np.isfinite(f).all() and (f > 0).all()):
            raise ValueError(f"apl_uw_backscatter: frequency {frequency!r} is not a frequency > 0 Hz")
    else:
        f = in_range("apl_uw_backscatter", "frequency", frequency, lo, hi, "Hz", f"{_TR} (pass extrapolate=True)")
    c1 = float(in_range("apl_uw_backscatter", "sound_speed", sound_speed, 1400.0, 1600.0, "m/s",
                        f"{_TR} sec. IV.A.8"))
    theta, f = np.broadcast_arrays(np.maximum(theta, _MIN_GRAZING), f)
    rho, nu, delta = sed.density_ratio, sed.sound_speed_ratio, sed.loss
    w2, gamma = sed.spectral_strength, sed.spectral_exponent
    k = 2.0 * np.pi * f / (100.0 * c1)                            # cm^-1
    kappa = (1.0 + 1j * delta) / nu

    def rayleigh(th):
        p = np.sqrt(kappa * kappa - np.cos(th) ** 2 + 0j)         # Im P >= 0 since Im kappa^2 > 0
        y = rho * np.sin(th)
        return (y - p) / (y + p), p

    r90 = abs((rho - kappa) / (rho + kappa)) ** 2                  # |R(pi/2)|^2
    # Kirchhoff approximation, Eqs. 35-40
    alpha = gamma / 2.0 - 1.0
    g = math.gamma
    ch2 = 2.0 * np.pi * w2 * g(2.0 - alpha) * 2.0 ** (-2.0 * alpha) / (_H0 ** gamma * alpha * (1.0 - alpha)
                                                                       * g(1.0 + alpha))
    qc = ch2 * 2.0 ** (1.0 - 2.0 * alpha) * k ** (2.0 * (1.0 - alpha))
    a = (8.0 * alpha ** 2 * g(0.5 / alpha + 0.5) / (g(0.5) * g(1.0 / alpha) * g(0.5 / alpha))) ** (2.0 * alpha)
    b = a ** ((1.0 + alpha) / (2.0 * alpha)) * g(1.0 / alpha) / (2.0 * alpha)
    sigma_kr = b * qc * r90 / (8.0 * np.pi * (np.cos(theta) ** (4.0 * alpha) + a * qc ** 2 * np.sin(theta) ** 4)
                               ** ((1.0 + alpha) / (2.0 * alpha)))
    # composite roughness, Eqs. 41-52: rms slope of the relief larger than the small-roughness cutoff
    s = np.sqrt((2.0 * np.pi * w2 * _H0 ** (-gamma)) ** (1.0 / alpha) / (2.0 * (1.0 - alpha))
                * (k ** 2 / alpha) ** ((1.0 - alpha) / alpha))

    def sigma_pr(th):                                             # Eqs. 50-52
        _, p = rayleigh(th)
        y = ((rho - 1.0) ** 2 * np.cos(th) ** 2 + rho ** 2 - kappa ** 2) / (rho * np.sin(th) + p) ** 2
        bragg = np.sqrt(4.0 * k ** 2 * np.cos(th) ** 2 + (k / 10.0) ** 2)   # floored at normal incidence
        return 4.0 * k ** 4 * np.sin(th) ** 4 * np.abs(y) ** 2 * w2 / (_H0 * bragg) ** gamma

    shadow = _shadowing(theta, s)
    sigma_cr = shadow * _slope_average(theta, s, sigma_pr)
    # large roughness (rock, gravel), Eqs. 53-56; angles in degrees as the handbook writes them
    theta_deg, theta_s_deg = np.degrees(theta), np.degrees(s)
    theta_c = math.degrees(math.acos(1.0 / nu)) if nu >= 1.001 else 2.5613
    crit = 1.0 + 0.81 * theta_c ** 2 / theta_deg ** 2
    sigma_1 = (0.04682 * s ** 1.25 * nu ** 3.25 * ((1.0 - 2.0 / rho) / nu ** 2 + 1.0) ** 2
               / (1.0 + 3.54 * theta_s_deg / theta_c))
    sigma_lr = (sigma_1 * np.sin(np.radians(180.0 / crit)) ** (0.7263 * s ** (-1.0 / 3.0))
                + 0.0260 * r90 / (s ** 2 * (1.0 + (theta_deg - 90.0) ** 2 / (2.6 * theta_s_deg ** 2)) ** 1.9 * crit))
    # interpolations, Eqs. 57-64
    c4 = 1000.0 ** (1.0 / (1.0 + alpha)) * (a * qc ** 2) ** (1.0 / alpha)
    cos_kdb = (1.0 / c4 + 4.0) ** -0.25
    fx = _interp((np.cos(theta) - cos_kdb) / 0.0125)
    fy = _interp((np.degrees(np.arctan(s)) - 7.0) / 0.5)
    sigma_r = fy * (fx * sigma_kr + (1.0 - fx) * sigma_cr) + (1.0 - fy) * sigma_lr

    # sediment volume scattering, Eqs. 65-66
    def sigma_pv(th):
        r, p = rayleigh(th)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = (5.0 * delta * sed.volume * np.abs(1.0 - r * r) ** 2 * np.sin(th) ** 2
                   / (nu * math.log(10.0) * np.abs(p) ** 2 * p.imag))
        return np.where(np.isfinite(out), out, 0.0)

    sigma_v = shadow * _slope_average(theta, s, sigma_pv)
    out = 10.0 * np.log10(sigma_r + sigma_v)
    return out[()] if out.ndim == 0 else out
