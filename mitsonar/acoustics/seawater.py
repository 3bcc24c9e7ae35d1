"""Sound speed and absorption of sea water (and fresh water), each from a published equation chosen by name.

* :func:`sound_speed` ``model=``: ``"mackenzie"`` (Mackenzie 1981, the nine-term equation, the
  default), ``"unesco"`` (Chen and Millero 1977 as UNESCO 1983, in Wong and Zhu's 1995 ITS-90
  coefficients; depth to pressure by Leroy and Parthiot 1998 at a ``latitude``) and
  ``"del_grosso"`` (Del Grosso 1974, Wong and Zhu's ITS-90 form).
* :func:`absorption` ``model=``: ``"francois_garrison"`` (Francois and Garrison 1982, the default),
  ``"ainslie_mccolm"`` (Ainslie and McColm 1998, the wide-range simplified formula),
  ``"fresh_water"`` (Francois and Garrison's pure-water term alone) and ``"auto"``
  (Francois-Garrison inside its range, Ainslie-McColm outside it).

All are NumPy-vectorised (inputs broadcast against each other). An input outside the range an
equation was published for warns once per equation and field (`OutOfRangeWarning`) and is
computed anyway, or is refused with one line naming the field and the range when ``strict=True``;
an input no equation can take (not a finite number, a negative depth, salinity or frequency) is
always refused.

References
----------
K. V. Mackenzie, "Nine-term equation for sound speed in the oceans", J. Acoust. Soc. Am. 70(3),
807-812 (1981).
R. E. Francois and G. R. Garrison, "Sound absorption based on ocean measurements. Part I: Pure
water and magnesium sulfate contributions", J. Acoust. Soc. Am. 72(3), 896-907 (1982);
"Part II: Boric acid contribution and equation for total absorption", J. Acoust. Soc. Am. 72(6),
1879-1890 (1982).
M. A. Ainslie and J. G. McColm, "A simplified formula for viscous and chemical absorption in sea
water", J. Acoust. Soc. Am. 103(3), 1671-1672 (1998).
C.-T. Chen and F. J. Millero, "Speed of sound in seawater at high pressures", J. Acoust. Soc. Am.
62(5), 1129-1135 (1977); N. P. Fofonoff and R. C. Millard, "Algorithms for computation of
fundamental properties of seawater", UNESCO Tech. Pap. Mar. Sci. 44 (1983).
V. A. Del Grosso, "New equation for the speed of sound in natural waters (with comparisons to
other equations)", J. Acoust. Soc. Am. 56(4), 1084-1091 (1974).
G. S. K. Wong and S. Zhu, "Speed of sound in seawater as a function of salinity, temperature, and
pressure", J. Acoust. Soc. Am. 97(3), 1732-1736 (1995).
C. C. Leroy and F. Parthiot, "Depth-pressure relationships in the oceans and seas", J. Acoust.
Soc. Am. 103(3), 1346-1352 (1998).
"""
from __future__ import annotations

import warnings

import numpy as np

from mitsonar.acoustics._checks import as_array, in_range

__all__ = ["sound_speed", "absorption", "depth_to_pressure", "OutOfRangeWarning", "MACKENZIE_RANGE",
           "FRANCOIS_GARRISON_RANGE", "UNESCO_RANGE", "DEL_GROSSO_RANGE", "AINSLIE_MCCOLM_RANGE", "FRESH_WATER_RANGE",
           "SOUND_SPEED_MODELS", "ABSORPTION_MODELS", "ainslie_mccolm", "in_francois_garrison_range"]

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

#: Chen and Millero (1977) / UNESCO (1983) in Wong and Zhu (1995)'s ITS-90 form: temperature (deg C),
#: salinity (ppt), pressure (bar).
UNESCO_RANGE = {"temperature": (0.0, 40.0), "salinity": (0.0, 40.0), "pressure": (0.0, 1000.0)}
#: Del Grosso (1974) as Wong and Zhu (1995) state it: temperature (deg C), salinity (ppt),
#: pressure (kg/cm^2).
DEL_GROSSO_RANGE = {"temperature": (0.0, 30.0), "salinity": (30.0, 40.0), "pressure": (0.0, 1000.0)}
#: Ainslie and McColm (1998): the ranges over which they compared their formula with Francois and
#: Garrison's (-6 to 35 deg C, 5 to 50 ppt, 0 to 7 km, pH 7.7 to 8.3) and the frequencies of the
#: latter's total equation.
AINSLIE_MCCOLM_RANGE = {"temperature": (-6.0, 35.0), "salinity": (5.0, 50.0), "depth": (0.0, 7000.0),
                        "frequency": (100.0, 1.0e6), "ph": (7.7, 8.3)}
#: Fresh water: Francois and Garrison (1982, Part I)'s pure-water term, fitted to measurements of
#: distilled water from 0 to 30 deg C (the two temperature branches).
FRESH_WATER_RANGE = {"temperature": (0.0, 30.0), "depth": (0.0, 3500.0), "frequency": (200.0, 1.0e6)}

_MACKENZIE = "Mackenzie (1981)"
_FG = "Francois and Garrison (1982)"
_AM = "Ainslie and McColm (1998)"
_UNESCO = "Chen and Millero (1977, UNESCO 1983)"
_DG = "Del Grosso (1974)"
_FRESH = "Francois and Garrison (1982)'s pure-water term"

#: The names `sound_speed` and `absorption` take for ``model``.
SOUND_SPEED_MODELS = ("mackenzie", "unesco", "del_grosso")
ABSORPTION_MODELS = ("francois_garrison", "ainslie_mccolm", "fresh_water", "auto")


class OutOfRangeWarning(UserWarning):
    """An input outside the range an equation was published for (computed anyway)."""


_WARNED: set = set()


def _field(func, field, value, lo, hi, unit, source, strict, physical=None):
    """``value`` as a float array. Refused if not finite or outside ``physical`` (always), or
    outside ``[lo, hi]`` when ``strict``; else a value outside ``[lo, hi]`` warns once per
    ``(func, source, field)``."""
    if strict:
        return in_range(func, field, value, lo, hi, unit, source)
    arr = as_array(func, field, value)
    u = f" {unit}" if unit else ""
    if not np.isfinite(arr).all():
        raise ValueError(f"{func}: {field} {arr[~np.isfinite(arr)].flat[0]} is not a finite number "
                         f"({source}'s {lo:g} to {hi:g}{u})")
    if physical is not None:
        plo, phi = physical
        bad = (arr < plo) | (arr > phi)
        if bad.any():
            raise ValueError(f"{func}: {field} {arr[bad].flat[0]:g}{u} is not allowed (no water has it: "
                             f"{plo:g} to {phi:g}{u})")
    outside = (arr < lo) | (arr > hi)
    if outside.any() and (func, source, field) not in _WARNED:
        _WARNED.add((func, source, field))
        warnings.warn(f"{func}: {field} {arr[outside].flat[0]:g}{u} is outside {source}'s {lo:g} to {hi:g}{u}; "
                      f"computed anyway (strict=True refuses it; warned once)", OutOfRangeWarning, stacklevel=3)
    return arr


def _model(func, model, names):
    if model not in names:
        raise ValueError(f"{func}: model {model!r} is not one of {', '.join(names)}")
    return model


def depth_to_pressure(depth, latitude=45.0):
    """Gauge pressure (dbar) at ``depth`` (m) and ``latitude`` (deg): Leroy and Parthiot (1998)'s
    depth-pressure relationship for the standard ocean, ``p = h45(z) k(z, phi)`` with
    ``h45 = 1.00818e-2 z + 2.465e-8 z^2 - 1.25e-13 z^3 + 2.8e-19 z^4`` (MPa) and
    ``k = (g(phi) - 2e-5 z) / (9.80612 - 2e-5 z)``, ``g(phi) = 9.7803 (1 + 5.3e-3 sin^2 phi)``."""
    z = as_array("depth_to_pressure", "depth", depth)
    lat = as_array("depth_to_pressure", "latitude", latitude)
    if not (np.isfinite(z).all() and (z >= 0).all()):
        raise ValueError("depth_to_pressure: depth must be finite numbers >= 0 m")
    if not (np.isfinite(lat).all() and (np.abs(lat) <= 90).all()):
        raise ValueError("depth_to_pressure: latitude must be -90 to 90 deg")
    g = 9.7803 * (1.0 + 5.3e-3 * np.sin(np.radians(lat)) ** 2)
    h45 = 1.00818e-2 * z + 2.465e-8 * z ** 2 - 1.25e-13 * z ** 3 + 2.8e-19 * z ** 4
    k = (g - 2e-5 * z) / (9.80612 - 2e-5 * z)
    p = 100.0 * h45 * k                                   # MPa -> dbar
    return p[()] if isinstance(p, np.ndarray) else p


def _chen_millero(t, s, p):
    """Chen and Millero (1977) / UNESCO (1983) sound speed, m/s, in Wong and Zhu (1995)'s ITS-90
    coefficients (their Table I): t deg C (ITS-90), s ppt, p bar."""
    cw = ((1402.388 + t * (5.03830 + t * (-5.81090e-2 + t * (3.3432e-4 + t * (-1.47797e-6 + t * 3.1419e-9)))))
          + (0.153563 + t * (6.8999e-4 + t * (-8.1829e-6 + t * (1.3632e-7 + t * -6.1260e-10)))) * p
          + (3.1260e-5 + t * (-1.7111e-6 + t * (2.5986e-8 + t * (-2.5353e-10 + t * 1.0415e-12)))) * p ** 2
          + (-9.7729e-9 + t * (3.8513e-10 + t * -2.3654e-12)) * p ** 3)
    a = ((1.389 + t * (-1.262e-2 + t * (7.166e-5 + t * (2.008e-6 + t * -3.21e-8))))
         + (9.4742e-5 + t * (-1.2583e-5 + t * (-6.4928e-8 + t * (1.0515e-8 + t * -2.0142e-10)))) * p
         + (-3.9064e-7 + t * (9.1061e-9 + t * (-1.6009e-10 + t * 7.994e-12))) * p ** 2
         + (1.100e-10 + t * (6.651e-12 + t * -3.391e-13)) * p ** 3)
    b = -1.922e-2 - 4.42e-5 * t + (7.3637e-5 + 1.7950e-7 * t) * p
    d = 1.727e-3 - 7.9836e-6 * p
    return cw + a * s + b * s ** 1.5 + d * s * s


def _del_grosso(t, s, p):
    """Del Grosso (1974) sound speed, m/s, in Wong and Zhu (1995)'s ITS-90 coefficients: t deg C,
    s ppt, p kg/cm^2 (gauge)."""
    return (1402.392 + 0.5012285e1 * t - 0.551184e-1 * t ** 2 + 0.221649e-3 * t ** 3
            + 0.1329530e1 * s + 0.1288598e-3 * s ** 2
            + 0.1560592 * p + 0.2449993e-4 * p ** 2 - 0.8833959e-8 * p ** 3
            - 0.1275936e-1 * s * t + 0.6353509e-2 * t * p + 0.2656174e-7 * t ** 2 * p ** 2
            - 0.1593895e-5 * t * p ** 2 + 0.5222483e-9 * t * p ** 3 - 0.4383615e-6 * t ** 3 * p
            - 0.1616745e-8 * s ** 2 * p ** 2 + 0.9688441e-4 * s * t ** 2 + 0.4857614e-5 * s ** 2 * t * p
            - 0.3406824e-3 * s * t * p)


def sound_speed(temperature, salinity, depth, *, model="mackenzie", latitude=45.0, strict=False):
    """Speed of sound in sea water, m/s: Mackenzie's nine-term equation (the default), or
    ``model="unesco"`` (Chen and Millero 1977 / UNESCO 1983, Wong and Zhu 1995's ITS-90
    coefficients; 0 to 40 deg C, 0 to 40 ppt, 0 to 1000 bar; the depth converted to pressure by
    `depth_to_pressure` at ``latitude``) or ``model="del_grosso"`` (Del Grosso 1974, Wong and Zhu's
    ITS-90 form; 0 to 30 deg C, 30 to 40 ppt, 0 to 1000 kg/cm^2). UNESCO's check value is
    ``c(S=40, T=40 deg C, P=1000 bar) = 1731.995 m/s`` (Fofonoff and Millard 1983, on IPTS-68).

    Mackenzie:

    .. math::

        c = 1448.96 + 4.591 T - 5.304\\times10^{-2} T^2 + 2.374\\times10^{-4} T^3
            + 1.340 (S - 35) + 1.630\\times10^{-2} D + 1.675\\times10^{-7} D^2
            - 1.025\\times10^{-2} T (S - 35) - 7.139\\times10^{-13} T D^3

    (Mackenzie 1981, J. Acoust. Soc. Am. 70, 807: the nine-term equation stated in the paper's
    abstract; standard error 0.070 m/s.)

    Parameters
    ----------
    temperature : float or array_like
        Temperature, deg C (Mackenzie: -2 to 30).
    salinity : float or array_like
        Salinity, parts per thousand (Mackenzie: 25 to 40).
    depth : float or array_like
        Depth, metres (Mackenzie: 0 to 8000).
    model : str
        ``"mackenzie"``, ``"unesco"`` or ``"del_grosso"``.
    latitude : float
        Degrees, for the depth-to-pressure conversion of ``unesco`` and ``del_grosso``.
    strict : bool
        Refuse an input outside the model's range instead of warning once (`OutOfRangeWarning`).

    Returns
    -------
    float or ndarray
        Sound speed in m/s, broadcast over the inputs (a float for scalar inputs).

    Raises
    ------
    ValueError
        An input that is not a finite number, a negative depth or salinity, or (``strict``) one
        outside the model's range, e.g.
        ``sound_speed: temperature 35 deg C is outside Mackenzie (1981)'s -2 to 30 deg C``.

    Examples
    --------
    Mackenzie's own check value: ``sound_speed(25, 35, 1000)`` is 1550.744 m/s.
    """
    f = "sound_speed"
    _model(f, model, SOUND_SPEED_MODELS)
    if model != "mackenzie":
        src, r = (_UNESCO, UNESCO_RANGE) if model == "unesco" else (_DG, DEL_GROSSO_RANGE)
        t = _field(f, "temperature", temperature, *r["temperature"], "deg C", src, strict, (-5.0, 100.0))
        s = _field(f, "salinity", salinity, *r["salinity"], "ppt", src, strict, (0.0, 300.0))
        d = _field(f, "depth", depth, 0.0, 12000.0, "m", src, True)
        p_dbar = np.asarray(depth_to_pressure(d, latitude))
        if model == "unesco":
            p = _field(f, "pressure", p_dbar / 10.0, *r["pressure"], "bar", src, strict)
            c = _chen_millero(t, s, p)
        else:
            p = _field(f, "pressure", p_dbar * 1.019716e-1, *r["pressure"], "kg/cm^2", src, strict)
            c = _del_grosso(t, s, p)
        return c[()] if isinstance(c, np.ndarray) else c
    r = MACKENZIE_RANGE
    t = _field(f, "temperature", temperature, *r["temperature"], "deg C", _MACKENZIE, strict, (-5.0, 100.0))
    s = _field(f, "salinity", salinity, *r["salinity"], "ppt", _MACKENZIE, strict, (0.0, 300.0))
    d = _field(f, "depth", depth, *r["depth"], "m", _MACKENZIE, strict, (0.0, 12000.0))
    ds = s - 35.0
    c = (1448.96 + 4.591 * t - 5.304e-2 * t ** 2 + 2.374e-4 * t ** 3 + 1.340 * ds + 1.630e-2 * d
         + 1.675e-7 * d ** 2 - 1.025e-2 * t * ds - 7.139e-13 * t * d ** 3)
    return c[()] if isinstance(c, np.ndarray) else c


def absorption(frequency, temperature, salinity, depth, ph=8.0, *, model="francois_garrison", strict=False):
    """Absorption of sound in sea water, dB/m: Francois and Garrison (1982) (the default), or
    ``model="ainslie_mccolm"`` (`ainslie_mccolm`'s simplified formula, valid from -6 to 35 deg C
    and 5 to 50 ppt), ``"fresh_water"`` (F&G's pure-water term alone: no salts) or ``"auto"``
    (Francois-Garrison where every input lies in its range, Ainslie-McColm elsewhere, element by
    element). ``strict=True`` refuses an input outside the model's range instead of warning once.

    Francois and Garrison:

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
    fn = "absorption"
    _model(fn, model, ABSORPTION_MODELS)
    if model == "auto":
        return _absorption_auto(frequency, temperature, salinity, depth, ph, strict)
    if model == "ainslie_mccolm":
        return ainslie_mccolm(frequency, temperature, salinity, depth, ph, strict=strict)
    if model == "fresh_water":
        r = FRESH_WATER_RANGE
        f = _field(fn, "frequency", frequency, *r["frequency"], "Hz", _FRESH, strict, (0.0, np.inf)) / 1000.0
        t = _field(fn, "temperature", temperature, *r["temperature"], "deg C", _FRESH, strict, (-5.0, 100.0))
        d = _field(fn, "depth", depth, *r["depth"], "m", _FRESH, strict, (0.0, 12000.0))
        alpha = _pure_water(f, t, d) / 1000.0
        return alpha[()] if isinstance(alpha, np.ndarray) else alpha
    r = FRANCOIS_GARRISON_RANGE
    f = _field(fn, "frequency", frequency, *r["frequency"], "Hz", _FG, strict, (0.0, np.inf)) / 1000.0  # kHz
    t = _field(fn, "temperature", temperature, *r["temperature"], "deg C", _FG, strict, (-5.0, 100.0))
    s = _field(fn, "salinity", salinity, *r["salinity"], "ppt", _FG, strict, (0.0, 300.0))
    d = _field(fn, "depth", depth, *r["depth"], "m", _FG, strict, (0.0, 12000.0))
    p = _field(fn, "ph", ph, *r["ph"], "", _FG, strict, (0.0, 14.0))
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
    alpha = (boric + mgso4 + _pure_water(f, t, d)) / 1000.0     # dB/km -> dB/m
    return alpha[()] if isinstance(alpha, np.ndarray) else alpha


def _pure_water(f, t, d):
    """F&G (1982, Part I)'s pure-water (viscous) absorption, dB/km, f in kHz: two temperature branches."""
    p3 = 1.0 - 3.83e-5 * d + 4.9e-10 * d * d
    a3 = np.where(t <= 20.0,
                  4.937e-4 - 2.59e-5 * t + 9.11e-7 * t ** 2 - 1.50e-8 * t ** 3,
                  3.964e-4 - 1.146e-5 * t + 1.45e-7 * t ** 2 - 6.5e-10 * t ** 3)
    return a3 * p3 * f * f


def ainslie_mccolm(frequency, temperature, salinity, depth, ph=8.0, *, strict=False):
    """Absorption of sound in sea water, dB/m: Ainslie and McColm (1998)'s simplified formula
    (the total-absorption formula of their letter, with its two relaxation frequencies), f in kHz
    and z in km, dB/km:

    .. math::

        \\alpha = 0.106 \\frac{f_1 f^2}{f_1^2 + f^2} e^{(pH - 8)/0.56}
                 + 0.52 \\left(1 + \\frac{T}{43}\\right) \\frac{S}{35} \\frac{f_2 f^2}{f_2^2 + f^2} e^{-z/6}
                 + 0.00049 f^2 e^{-(T/27 + z/17)},

    :math:`f_1 = 0.78 \\sqrt{S/35}\\, e^{T/26}`, :math:`f_2 = 42 e^{T/17}` (kHz). Boric acid,
    magnesium sulphate and pure water, as Francois and Garrison's, in a form that stays sensible
    from -6 to 35 deg C, 5 to 50 ppt, 0 to 7 km and pH 7.7 to 8.3 (their comparison with F&G).
    Arguments as `absorption` (frequency in Hz, depth in m)."""
    fn = "absorption"
    r = AINSLIE_MCCOLM_RANGE
    f = _field(fn, "frequency", frequency, *r["frequency"], "Hz", _AM, strict, (0.0, np.inf)) / 1000.0
    t = _field(fn, "temperature", temperature, *r["temperature"], "deg C", _AM, strict, (-5.0, 100.0))
    s = _field(fn, "salinity", salinity, *r["salinity"], "ppt", _AM, strict, (0.0, 300.0))
    z = _field(fn, "depth", depth, *r["depth"], "m", _AM, strict, (0.0, 12000.0)) / 1000.0
    p = _field(fn, "ph", ph, *r["ph"], "", _AM, strict, (0.0, 14.0))
    f1 = 0.78 * np.sqrt(s / 35.0) * np.exp(t / 26.0)
    f2 = 42.0 * np.exp(t / 17.0)
    ff = f * f
    boric = 0.106 * f1 * ff / (f1 * f1 + ff) * np.exp((p - 8.0) / 0.56)
    mgso4 = 0.52 * (1.0 + t / 43.0) * (s / 35.0) * f2 * ff / (f2 * f2 + ff) * np.exp(-z / 6.0)
    water = 0.00049 * ff * np.exp(-(t / 27.0 + z / 17.0))
    alpha = (boric + mgso4 + water) / 1000.0
    return alpha[()] if isinstance(alpha, np.ndarray) else alpha


def in_francois_garrison_range(frequency, temperature, salinity, depth, ph=8.0):
    """Boolean (broadcast): every input inside `FRANCOIS_GARRISON_RANGE`."""
    r = FRANCOIS_GARRISON_RANGE
    ok = True
    for name, v in (("frequency", frequency), ("temperature", temperature), ("salinity", salinity),
                    ("depth", depth), ("ph", ph)):
        lo, hi = r[name]
        v = np.asarray(v, dtype=float)
        ok = ok & (v >= lo) & (v <= hi)
    return ok


def _absorption_auto(frequency, temperature, salinity, depth, ph, strict):
    """Francois-Garrison where every input is in its range, Ainslie-McColm elsewhere (element by
    element; the other model's range then applies)."""
    args = np.broadcast_arrays(*(as_array("absorption", n, v) for n, v in
                                 (("frequency", frequency), ("temperature", temperature), ("salinity", salinity),
                                  ("depth", depth), ("ph", ph))))
    inside = np.asarray(in_francois_garrison_range(*args))
    out = np.zeros(np.shape(args[0]))
    if inside.any():
        out[inside] = absorption(*(a[inside] for a in args), strict=strict)
    if (~inside).any():
        out[~inside] = ainslie_mccolm(*(a[~inside] for a in args), strict=strict)
    return out[()] if out.ndim == 0 else out
