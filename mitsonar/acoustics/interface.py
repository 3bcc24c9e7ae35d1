"""Plane-wave reflection at a flat fluid-fluid interface (water over a fluid seabed).

References
----------
F. B. Jensen, W. A. Kuperman, M. B. Porter and H. Schmidt, *Computational Ocean Acoustics*,
2nd ed., Springer (2011), chapter 1, "Reflection and transmission" (the Rayleigh reflection
coefficient of a fluid-fluid interface, total reflection and the critical angle).
APL-UW, *High-Frequency Ocean Environmental Acoustic Models Handbook*, Technical Report
APL-UW TR 9407 (1994), sec. IV.B (bottom reflection loss: the same coefficient written with the
complex wavenumber ratio ``kappa = (1 + i delta) / nu``).
"""
from __future__ import annotations

import numpy as np

from mitsonar.acoustics._checks import as_array, at_least, grazing_angle

__all__ = ["reflection_coefficient", "critical_angle", "loss_parameter"]

#: ``40 pi log10(e)``: attenuation in dB per wavelength per unit loss parameter delta
#: (``alpha_lambda = 40 pi log10(e) delta``, APL-UW TR 9407 sec. IV.A).
DB_PER_WAVELENGTH_PER_DELTA = 40.0 * np.pi * np.log10(np.e)


def loss_parameter(attenuation):
    """The loss parameter ``delta = Im k / Re k`` of a medium whose attenuation is ``attenuation``
    dB per wavelength: ``delta = attenuation / (40 pi log10 e)`` (APL-UW TR 9407 sec. IV.A).

    An amplitude ``exp(-Im(k) x)`` loses ``20 log10(e) Im(k) lambda = 40 pi log10(e) delta`` dB over
    one wavelength ``lambda = 2 pi / Re(k)``.
    """
    return as_array("loss_parameter", "attenuation", attenuation) / DB_PER_WAVELENGTH_PER_DELTA


def _vertical_wavenumber_ratio(kappa, cos_grazing):
    """``P = sqrt(kappa^2 - cos^2 theta)`` on the branch ``Im P >= 0`` (the transmitted wave decays
    away from the interface, or, lossless below the critical angle, is evanescent)."""
    p = np.sqrt(kappa * kappa - cos_grazing * cos_grazing + 0j)
    return np.where(p.imag < 0.0, -p, p)


def reflection_coefficient(grazing, density_ratio, sound_speed_ratio, attenuation=0.0):
    """Complex plane-wave (Rayleigh) reflection coefficient of a fluid-fluid interface.

    .. math::

        R(\\theta) = \\frac{m \\sin\\theta - P(\\theta)}{m \\sin\\theta + P(\\theta)},\\qquad
        P(\\theta) = \\sqrt{\\kappa^2 - \\cos^2\\theta},\\qquad
        \\kappa = \\frac{k_2}{k_1} = \\frac{1 + i\\delta}{\\nu}

    with :math:`m = \\rho_2/\\rho_1`, :math:`\\nu = c_2/c_1` and the lower medium's wavenumber made
    complex by its attenuation, :math:`k_2 = (\\omega/c_2)(1 + i\\delta)`,
    :math:`\\delta = \\alpha_\\lambda / (40\\pi\\log_{10} e)` (:func:`loss_parameter`). This is the Rayleigh
    coefficient of Jensen et al., *Computational Ocean Acoustics* (2011), ch. 1, written in grazing angle
    (:math:`R = (Z_2 - Z_1)/(Z_2 + Z_1)`, :math:`Z_i = \\rho_i c_i / \\sin\\theta_i`), and APL-UW TR 9407
    sec. IV.B (``R = (y - 1)/(y + 1)``, ``y = m sin(theta) / P``). The square root takes the branch
    ``Im P >= 0``: with time dependence ``exp(-i omega t)`` the transmitted wave decays into the
    seabed, and without loss below the critical angle it is evanescent, so ``|R| = 1`` there.

    Parameters
    ----------
    grazing : float or array_like
        Grazing angle in the water, radians, 0 (along the interface) to pi/2 (normal incidence).
    density_ratio : float or array_like
        Lower medium density over water density, ``>= 0`` (0: a pressure-release boundary, R = -1).
    sound_speed_ratio : float or array_like
        Lower medium compressional sound speed over water sound speed, ``> 0``.
    attenuation : float or array_like
        Lower medium attenuation, dB per wavelength, ``>= 0`` (default 0: lossless).

    Returns
    -------
    complex or ndarray of complex
        :math:`R`, broadcast over the inputs (shaped like ``grazing`` for scalar parameters).
        At ``grazing = 0`` it is -1, except on a lossless interface with equal sound speeds
        (``nu = 1``, ``delta = 0``: numerator and denominator both vanish), where the limit
        ``(m - 1)/(m + 1)`` is returned.

    Raises
    ------
    ValueError
        A grazing angle outside 0 to pi/2, a negative density ratio, a sound speed ratio <= 0 or a
        negative attenuation.
    """
    theta = grazing_angle("reflection_coefficient", grazing)
    m = at_least("reflection_coefficient", "density_ratio", density_ratio, 0.0, "")
    nu = at_least("reflection_coefficient", "sound_speed_ratio", sound_speed_ratio, 0.0, "", strict=True)
    att = at_least("reflection_coefficient", "attenuation", attenuation, 0.0, "dB/wavelength")
    kappa = (1.0 + 1j * (att / DB_PER_WAVELENGTH_PER_DELTA)) / nu
    p = _vertical_wavenumber_ratio(kappa, np.cos(theta))
    y = m * np.sin(theta)
    num, den = y - p, y + p
    degenerate = den == 0                                     # only theta = 0, nu = 1, delta = 0
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(degenerate, (m - 1.0) / (m + 1.0) + 0j, num / np.where(degenerate, 1.0, den))
    return r[()] if isinstance(r, np.ndarray) else r


def critical_angle(sound_speed_ratio):
    """Critical grazing angle of a fluid seabed, radians: :math:`\\theta_c = \\arccos(1/\\nu)`.

    Below :math:`\\theta_c` a lossless fast seabed (:math:`\\nu = c_2/c_1 > 1`) reflects totally
    (Snell's law, Jensen et al. 2011, ch. 1, :math:`\\cos\\theta_2 = \\nu\\cos\\theta_1`).

    Parameters
    ----------
    sound_speed_ratio : float or array_like
        Seabed sound speed over water sound speed, ``> 0``.

    Returns
    -------
    float or ndarray
        :math:`\\theta_c` in radians where ``sound_speed_ratio > 1``; **NaN** where
        ``sound_speed_ratio <= 1``: a slow (or matched) seabed has no critical angle, every grazing
        angle transmits. NaN rather than an error, so that an array of seabeds can be evaluated at
        once; test with ``numpy.isnan``.

    Raises
    ------
    ValueError
        A ratio that is not a finite number > 0.
    """
    nu = at_least("critical_angle", "sound_speed_ratio", sound_speed_ratio, 0.0, "", strict=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(nu > 1.0, np.arccos(np.minimum(1.0, 1.0 / nu)), np.nan)
    return out[()] if isinstance(out, np.ndarray) else out
