"""Sound speed and absorption of sea water.

* :func:`sound_speed`: Mackenzie (1981), the nine-term equation.
* :func:`absorption`: Francois and Garrison (1982), boric acid + magnesium sulphate + pure water.

Both are NumPy-vectorised (inputs broadcast against each other) and refuse, before any work, an
input outside the range the equation was fitted over, with one line naming the field and the range.

References
----------
K. V. Mackenzie, "Nine-term equation for sound speed in the oceans", J. Acoust. Soc. Am. 70(3),
807-812 (1981).
R. E. Francois and G. R. Garrison, "Sound absorption based on ocean measurements. Part I: Pure
water and magnesium sulfate contributions", J. Acoust. Soc. Am. 72(3), 896-907 (1982);
"Part II: Boric acid contribution and equation for total absorption", J. Acoust. Soc. Am. 72(6),
1879-1890 (1982).
"""
from __future__ import annotations

import numpy as np

from mitsonar.acoustics._checks import in_range

__all__ = ["sound_speed", "absorption", "MACKENZIE_RANGE", "FRANCOIS_GARRISON_RANGE"]

#: Mackenzie (1981)'s stated validity: temperature (deg C), salinity (ppt), depth (m).
MACKENZIE_RANGE = {"temperature": (-2.0, 30.0), "salinity": (25.0, 40.0), "depth": (0.0, 8000.0)}

#: The range this package accepts for Francois and Garrison (1982): temperature (deg C), salinity
#: (ppt), depth (m), frequency (Hz), pH. Temperature, salinity and depth are the domain of the
#: magnesium-sulphate fit (Part I, the 5 % accuracy domain: -2 to 22 deg C, 30 to 35 ppt, 0 to
#: 3.5 km); frequency is Part II's: the total equation "may not hold below 200 Hz" and is
#: tabulated up to 1 MHz (Part II, Table IV). pH 7.7 to 8.3 is the range of open-ocean water
#: the boric-acid term was fitted to.
FRANCOIS_GARRISON_RANGE = {"temperature": (-2.0, 22.0), "salinity": (30.0, 35.0), "depth": (0.0, 3500.0),
                           "frequency": (200.0, 1.0e6), "ph": (7.7, 8.3)}

_MACKENZIE = "Mackenzie (1981)"
_FG = "Francois and Garrison (1982)"


def sound_speed(temperature, salinity, depth):
    """Speed of sound in sea water, m/s: Mackenzie's nine-term equation.

    .. math::

        c = 1448.96 + 4.591 T - 5.304\\times10^{-2} T^2 + 2.374\\times10^{-4} T^3
            + 1.340 (S - 35) + 1.630\\times10^{-2} D + 1.675\\times10^{-7} D^2
            - 1.025\\times10^{-2} T (S - 35) - 7.139\\times10^{-13} T D^3

    (Mackenzie 1981, J. Acoust. Soc. Am. 70, 807: the nine-term equation stated in the paper's
    abstract; standard error 0.070 m/s.)

    Parameters
    ----------
    temperature : float or array_like
        Temperature, deg C, -2 to 30.
    salinity : float or array_like
        Salinity, parts per thousand, 25 to 40.
    depth : float or array_like
        Depth, metres, 0 to 8000.

    Returns
    -------
    float or ndarray
        Sound speed in m/s, broadcast over the inputs (a float for scalar inputs).

    Raises
    ------
    ValueError
        An input outside Mackenzie's range, or not a finite number, e.g.
        ``sound_speed: temperature 35 deg C is outside Mackenzie (1981)'s -2 to 30 deg C``.

    Examples
    --------
    Mackenzie's own check value: ``sound_speed(25, 35, 1000)`` is 1550.744 m/s.
    """
    r = MACKENZIE_RANGE
    t = in_range("sound_speed", "temperature", temperature, *r["temperature"], "deg C", _MACKENZIE)
    s = in_range("sound_speed", "salinity", salinity, *r["salinity"], "ppt", _MACKENZIE)
    d = in_range("sound_speed", "depth", depth, *r["depth"], "m", _MACKENZIE)
    ds = s - 35.0
    c = (1448.96 + 4.591 * t - 5.304e-2 * t ** 2 + 2.374e-4 * t ** 3 + 1.340 * ds + 1.630e-2 * d
         + 1.675e-7 * d ** 2 - 1.025e-2 * t * ds - 7.139e-13 * t * d ** 3)
    return c[()] if isinstance(c, np.ndarray) else c


def absorption(frequency, temperature, salinity, depth, ph=8.0):
    """Absorption of sound in sea water, dB/m: Francois and Garrison (1982).

    The total absorption is the sum of two relaxations and a viscous term (Part II, the equation
    for total absorption):

    .. math::

        \\alpha = \\frac{A_1 P_1 f_1 f^2}{f_1^2 + f^2} + \\frac{A_2 P_2 f_2 f^2}{f_2^2 + f^2}
                  + A_3 P_3 f^2 \\quad \\text{(dB/km, f in kHz)}

    * boric acid (Part II): :math:`c = 1412 + 3.21 T + 1.19 S + 0.0167 D`,
      :math:`A_1 = (8.86 / c)\\, 10^{0.78\\,pH - 5}`, :math:`P_1 = 1`,
      :math:`f_1 = 2.8 \\sqrt{S/35}\\, 10^{4 - 1245/(273 + T)}`;
    * magnesium sulphate (Part I): :math:`A_2 = 21.44 (S/c)(1 + 0.025 T)`,
      :math:`P_2 = 1 - 1.37\\times10^{-4} D + 6.2\\times10^{-9} D^2`,
      :math:`f_2 = 8.17\\times10^{8 - 1990/(273 + T)} / (1 + 0.0018 (S - 35))`;
    * pure water (Part I): :math:`P_3 = 1 - 3.83\\times10^{-5} D + 4.9\\times10^{-10} D^2`,
      and two temperature branches:
      :math:`A_3 = 4.937\\times10^{-4} - 2.59\\times10^{-5} T + 9.11\\times10^{-7} T^2 - 1.50\\times10^{-8} T^3`
      for :math:`T \\le 20` deg C,
      :math:`A_3 = 3.964\\times10^{-4} - 1.146\\times10^{-5} T + 1.45\\times10^{-7} T^2 - 6.5\\times10^{-10} T^3`
      above.

    F&G's formula gives dB/km with f in kHz; this function takes Hz and returns dB/m.

    Parameters
    ----------
    frequency : float or array_like
        Frequency, Hz, 200 Hz to 1 MHz (Part II: the equation "may not hold below 200 Hz"; its
        Table IV stops at 1 MHz).
    temperature : float or array_like
        Temperature, deg C, -2 to 22.
    salinity : float or array_like
        Salinity, ppt, 30 to 35.
    depth : float or array_like
        Depth, metres, 0 to 3500.
    ph : float or array_like
        pH (NBS scale), 7.7 to 8.3; default 8.

    The temperature, salinity and depth ranges are the domain over which F&G state their
    magnesium-sulphate term (which dominates from 10 to 500 kHz) is accurate to 5 %.

    Returns
    -------
    float or ndarray
        Absorption coefficient in dB/m, broadcast over the inputs.

    Raises
    ------
    ValueError
        An input outside the ranges above, naming the field and the range.

    Examples
    --------
    At 10 deg C, 35 ppt, pH 8, the surface: 0.060 dB/km at 1 kHz, 0.963 dB/km at 10 kHz and
    33.6 dB/km at 100 kHz (values tabulated for F&G's equation), so
    ``absorption(100e3, 10, 35, 0)`` is about 0.0336 dB/m.
    """
    r = FRANCOIS_GARRISON_RANGE
    f = in_range("absorption", "frequency", frequency, *r["frequency"], "Hz", _FG) / 1000.0  # kHz
    t = in_range("absorption", "temperature", temperature, *r["temperature"], "deg C", _FG)
    s = in_range("absorption", "salinity", salinity, *r["salinity"], "ppt", _FG)
    d = in_range("absorption", "depth", depth, *r["depth"], "m", _FG)
    p = in_range("absorption", "ph", ph, *r["ph"], "", _FG)
    theta = 273.0 + t                                          # F&G write 273 + T (kelvin, rounded)
    c = 1412.0 + 3.21 * t + 1.19 * s + 0.0167 * d              # F&G's own sound speed
    f2_ = f * f
    # boric acid
    a1 = 8.86 / c * 10.0 ** (0.78 * p - 5.0)
    f1 = 2.8 * np.sqrt(s / 35.0) * 10.0 ** (4.0 - 1245.0 / theta)
    boric = a1 * f1 * f2_ / (f1 * f1 + f2_)
    # magnesium sulphate
    a2 = 21.44 * s / c * (1.0 + 0.025 * t)
    p2 = 1.0 - 1.37e-4 * d + 6.2e-9 * d * d
    fm = 8.17 * 10.0 ** (8.0 - 1990.0 / theta) / (1.0 + 0.0018 * (s - 35.0))
    mgso4 = a2 * p2 * fm * f2_ / (fm * fm + f2_)
    # pure water: two temperature branches
    p3 = 1.0 - 3.83e-5 * d + 4.9e-10 * d * d
    a3 = np.where(t <= 20.0,
                  4.937e-4 - 2.59e-5 * t + 9.11e-7 * t ** 2 - 1.50e-8 * t ** 3,
                  3.964e-4 - 1.146e-5 * t + 1.45e-7 * t ** 2 - 6.5e-10 * t ** 3)
    water = a3 * p3 * f2_
    alpha = (boric + mgso4 + water) / 1000.0                   # dB/km -> dB/m
    return alpha[()] if isinstance(alpha, np.ndarray) else alpha
