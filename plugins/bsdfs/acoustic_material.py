"""The ``acoustic_material`` BSDF: a reflector in physical units.

Two lobes, both functions of grazing angles (0 along the surface, pi/2 along its normal):

**Specular reflection from impedance.** The medium below (``density``, ``sound_speed``,
``attenuation``, or a ``material`` preset) and the water above give the plane-wave reflection
coefficient ``R(theta)`` of a fluid-fluid interface (`mitsonar.acoustics.interface`, Jensen et al.,
*Computational Ocean Acoustics* 2011, ch. 1). The specular lobe returns ``|R|^2`` of the incident
energy about the mirror direction, in a narrow normalised Phong lobe::

    f_s(wi, wo) = w(g) (n + 1) / (2 pi) cos^n(alpha) / sqrt(cos theta_i cos theta_o)

with ``alpha`` the angle between ``wo`` and the mirror of ``wi``, ``g`` the mean grazing angle of
``wi`` and ``wo`` and ``w(g) = min(|R(g)|^2, 1 - a(g))`` (``a`` the scattered fraction below, so
that what the rough interface scatters is taken from the coherent reflection when the two would
exceed the incident energy; with no backscatter ``w = |R|^2``). Integrated over the hemisphere,
``f_s cos theta_o`` gives ``w(g_i)`` up to the part of the lobe (width ~ ``sqrt(2/n)`` rad) clipped
by the horizon, and never more (the geometric mean of the cosines makes the lobe's integral fall
short at second order). So a fast sediment reflects totally below its critical angle
``arccos(c_water / c)`` (lossless) and falls to the Rayleigh value at normal incidence; the sea
surface (``material`` ``sea_surface``, a pressure-release boundary, density 0) has ``R = -1`` at
every angle; steel (``nu = 3.86``, a fluid without shear here) reflects totally below 75 deg and
87 % at normal incidence.

**Seabed backscatter.** The backscattering strength ``S_b(g)`` (dB re 1 m^2 per m^2 per sr) is the
cross section per unit area and solid angle ``sigma = 10^(S_b/10)`` (APL-UW TR 9407 sec. IV.C;
Jackson and Richardson, *High-Frequency Seafloor Acoustics*, 2007, ch. 2: scattered intensity at
range ``r`` from area ``A`` is ``I_i sigma A / r^2``). A BSDF ``f`` returns from area ``A`` lit by
irradiance ``I_i cos theta_i`` the radiance ``f I_i cos theta_i``, i.e. intensity
``f I_i cos theta_i cos theta_o A / r^2`` (projected area ``A cos theta_o``), so::

    sigma(wi, wo) = f(wi, wo) cos theta_i cos theta_o,   f = sigma / (sin g_i sin g_o)

(cosines from the normal are sines of the grazing angles). A monostatic model gives
``f_mono(g) = sigma(g) / sin^2 g`` in the backscatter direction; for any other pair the model is
evaluated at the mean grazing angle (`mitsonar.acoustics.seabed.bistatic_mean_grazing`)::

    f_d(wi, wo) = k f_mono((g_i + g_o) / 2)

symmetric in ``wi`` and ``wo`` (reciprocal), exact at backscatter, and for Lambert's law
(``S_b = mu + 10 log10 sin^2 g``, ``f_mono = 10^(mu/10)``) it is Lambert's bistatic law
``mu + 10 log10(sin g_i sin g_o)`` itself, whose albedo is ``pi 10^(mu/10)``: ``mu`` above
``10 log10(1/pi) = -4.97 dB`` is refused. ``backscatter`` ``apl_uw`` tabulates
`mitsonar.acoustics.seabed.apl_uw_backscatter` (NumPy) over 1025 grazing angles at ``frequency``
when the BSDF is made, and renders interpolate ``ln f_mono`` linearly (below the first positive
grazing angle, 0.088 deg, the value there). The scattered fraction ``a(g_i) = 2 pi int f_d
sin g_o cos g_o dg_o`` is integrated at construction; where the mean-grazing extension of a
monostatic strength would scatter more than it receives (the handbook's rough rock and rock, whose
large-roughness strengths are strongly retro-reflective: max ``a`` 8.77 and 1.67 at 100 kHz,
at grazing incidence),
``k = 1 / max a`` scales the scattered lobe down (``backscatter_scale``, in ``to_string``: -9.4
and -2.2 dB for those; their specular lobe is then 0 where ``a`` reaches 1); otherwise ``k = 1``.

Sampling picks the specular lobe with probability ``w / (w + a)`` at the incident angle (Phong
sampling about the mirror direction), else a cosine-weighted direction.

================== ============ ==============================================================
Parameter          Default      Meaning
================== ============ ==============================================================
material           (none)       preset of the medium below: ``steel``, ``concrete``, ``rock``,
                                ``gravel``, ``sand``, ``silt``, ``mud``, ``clay``
                                (`mitsonar.acoustics.materials.MATERIALS`, with their sources)
                                or ``sea_surface`` (pressure release, R = -1)
density            preset       kg/m^3 of the medium below, >= 0 (0: pressure release)
sound_speed        preset       m/s, compressional speed of the medium below, > 0
attenuation        preset       dB per wavelength in the medium below, >= 0 (0 without preset)
water_density      1027         kg/m^3 of the water above
water_sound_speed  1528         m/s of the water above (the handbook's reference water)
backscatter        see Meaning  ``none``, ``lambert`` or ``apl_uw``; default ``lambert`` with
                                ``mu``, ``apl_uw`` with ``sediment``, else ``none``
mu                 preset       dB, Lambert parameter, <= -4.97 (``mud``: -27, Mackenzie 1961)
sediment           material's   APL-UW TR 9407 Table 2 name (``medium sand``, ``clay``, ...);
                                without ``material`` it also sets the medium below
frequency          (none)       Hz, the head's frequency (``apl_uw``: 10 to 100 kHz)
extrapolate        false        ``<boolean>``: ``apl_uw`` outside 10 to 100 kHz
shininess          1000         Phong exponent n of the specular lobe (>= 1)
================== ============ ==============================================================

The sediment presets take the APL-UW row named in their source (``gravel``: ``sandy gravel``,
``sand``: ``medium sand``, ``silt``: ``medium silt``, ``mud``: ``clayey silt``, ``clay`` and
``rock`` themselves) for ``apl_uw`` without a ``sediment``.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsonar._checks import not_allowed
from mitsonar._compat import trapezoid
from mitsonar.acoustics.interface import reflection_coefficient
from mitsonar.acoustics.materials import MATERIALS, WATER_DENSITY, WATER_SOUND_SPEED
from mitsonar.acoustics.seabed import APL_UW_FREQUENCY_RANGE, SEDIMENTS, apl_uw_backscatter
from mitsonar.acoustics.seabed import sediment as find_sediment
from mitsonar.plugins.props import number, text
from mitsonar.plugins.registry import register_plugin

from .acoustic import lobe_direction, lobe_sample

NAME = "acoustic_material"
BACKSCATTER = ("none", "lambert", "apl_uw")
#: Intervals of the grazing-angle tables over 0 to pi/2.
N_TABLE = 1024
#: Largest Lambert parameter: the albedo pi 10^(mu/10) is at most 1.
MAX_MU = 10.0 * math.log10(1.0 / math.pi)
SEA_SURFACE = "sea_surface"
#: The APL-UW row of each sediment preset (the row its density and sound speed come from).
PRESET_SEDIMENT = {"rock": "rock", "gravel": "sandy gravel", "sand": "medium sand", "silt": "medium silt",
                   "mud": "clayey silt", "clay": "clay"}
_GRID = np.linspace(0.0, 0.5 * np.pi, N_TABLE + 1)


def lerp_table(table: np.ndarray, g) -> np.ndarray:
    """Linear interpolation of a table over `_GRID` at grazing angles ``g`` (NumPy, as the
    renders do it in Dr.Jit)."""
    x = np.clip(np.asarray(g, float) / (0.5 * np.pi) * N_TABLE, 0.0, N_TABLE)
    i = np.minimum(np.floor(x).astype(int), N_TABLE - 1)
    t = x - i
    return table[i] * (1 - t) + table[i + 1] * t


def _boolean(props, name: str, default: bool) -> bool:
    if name not in props:
        return default
    prop_type = props.type(name).name
    if prop_type != "Bool":
        raise ValueError(f"{NAME} '{name}': expected <boolean>, got <{prop_type.lower()}> {props.get(name)!r}")
    return bool(props.get(name))


def _finite(name: str, value, lo: float, allowed: str, strict: bool = False):
    if value is None:
        return None
    if not (math.isfinite(value) and (value > lo if strict else value >= lo)):
        raise not_allowed(NAME, name, value, allowed)
    return value


class Medium:
    """What the BSDF reads from its properties, checked, in NumPy: the reflection and the tables."""

    def __init__(self, props):
        num = lambda name, default=None: number(props, name, default, NAME)  # noqa: E731
        self.material = text(props, "material", None, NAME)
        self.sediment = text(props, "sediment", None, NAME)
        self.water_density = _finite("water_density", num("water_density", WATER_DENSITY), 0.0,
                                     "a density > 0 kg/m^3", strict=True)
        self.water_sound_speed = _finite("water_sound_speed", num("water_sound_speed", WATER_SOUND_SPEED), 0.0,
                                         "a sound speed > 0 m/s", strict=True)
        density, speed, att, mu = None, None, 0.0, None
        preset = None
        if self.material is not None:
            key = self.material.strip().lower()
            if key == SEA_SURFACE:
                density, speed = 0.0, self.water_sound_speed
            elif key in MATERIALS:
                preset = MATERIALS[key]
                density, speed, att, mu = preset.density, preset.sound_speed, preset.attenuation, preset.lambert_mu
            else:
                raise not_allowed(NAME, "material", self.material, "one of " + ", ".join([*MATERIALS, SEA_SURFACE]))
            self.material = key
        sed = None
        if self.sediment is not None:
            try:
                sed = find_sediment(self.sediment)
            except ValueError:
                raise not_allowed(NAME, "sediment", self.sediment, "one of " + ", ".join(SEDIMENTS)) from None
            if self.material is None:
                density = sed.density_ratio * self.water_density
                speed = sed.sound_speed_ratio * self.water_sound_speed
                att = sed.attenuation
        elif self.material in PRESET_SEDIMENT:
            sed = SEDIMENTS[PRESET_SEDIMENT[self.material]]
        self.density = _finite("density", num("density", density), 0.0, "a density >= 0 kg/m^3 (0: pressure release)")
        self.sound_speed = _finite("sound_speed", num("sound_speed", speed), 0.0, "a sound speed > 0 m/s",
                                   strict=True)
        self.attenuation = _finite("attenuation", num("attenuation", att), 0.0, "an attenuation >= 0 dB/wavelength")
        if self.density is None or self.sound_speed is None:
            missing = "density" if self.density is None else "sound_speed"
            raise ValueError(f"{NAME} '{missing}': missing: give 'material' (one of "
                             f"{', '.join([*MATERIALS, SEA_SURFACE])}), 'sediment', or 'density' and 'sound_speed'")
        self.shininess = _finite("shininess", num("shininess", 1000.0), 1.0, "a Phong exponent >= 1")

        # --- the scattered lobe
        given_mu = num("mu")
        default = "lambert" if given_mu is not None else ("apl_uw" if self.sediment is not None else "none")
        self.backscatter = text(props, "backscatter", default, NAME)
        if self.backscatter not in BACKSCATTER:
            raise not_allowed(NAME, "backscatter", self.backscatter, "one of " + ", ".join(BACKSCATTER))
        frequency = num("frequency")
        extrapolate = _boolean(props, "extrapolate", False)
        if given_mu is not None and self.backscatter != "lambert":
            raise ValueError(f"{NAME} 'mu': only used with backscatter 'lambert' (backscatter is {self.backscatter!r})")
        if self.sediment is not None and self.backscatter == "lambert":
            raise ValueError(f"{NAME} 'sediment': give 'mu' (backscatter 'lambert') or 'sediment' "
                             "(backscatter 'apl_uw'), not both")
        if self.backscatter != "apl_uw":
            for name in ("frequency", "extrapolate"):
                if name in props:
                    raise ValueError(f"{NAME} '{name}': only used with backscatter 'apl_uw' "
                                     f"(backscatter is {self.backscatter!r})")
        self.mu = self.frequency = self.sediment_row = None
        grid = _GRID
        if self.backscatter == "lambert":
            self.mu = given_mu if given_mu is not None else mu
            if self.mu is None:
                raise ValueError(f"{NAME} 'mu': missing: backscatter 'lambert' needs a Lambert parameter in dB "
                                 f"(<= {MAX_MU:.2f}); only the 'mud' preset has one")
            _finite("mu", self.mu, -math.inf, "")
            if not self.mu <= MAX_MU:
                raise not_allowed(NAME, "mu", self.mu, f"a Lambert parameter <= {MAX_MU:.2f} dB: the albedo "
                                  "pi 10^(mu/10) is at most 1")
            f_mono = np.full_like(grid, 10.0 ** (self.mu / 10.0))
        elif self.backscatter == "apl_uw":
            if sed is None:
                raise ValueError(f"{NAME} 'sediment': missing: backscatter 'apl_uw' needs an APL-UW sediment "
                                 f"(one of {', '.join(SEDIMENTS)})")
            if frequency is None:
                raise ValueError(f"{NAME} 'frequency': missing: backscatter 'apl_uw' needs the head's frequency "
                                 f"(Hz, {APL_UW_FREQUENCY_RANGE[0]:g} to {APL_UW_FREQUENCY_RANGE[1]:g})")
            lo, hi = APL_UW_FREQUENCY_RANGE
            if not (math.isfinite(frequency) and frequency > 0 and (extrapolate or lo <= frequency <= hi)):
                raise not_allowed(NAME, "frequency", frequency, f"{lo:g} to {hi:g} Hz, APL-UW TR 9407's band, "
                                  "or any frequency > 0 with <boolean name=\"extrapolate\" value=\"true\"/>")
            if not 1400.0 <= self.water_sound_speed <= 1600.0:
                raise not_allowed(NAME, "water_sound_speed", self.water_sound_speed,
                                  "1400 to 1600 m/s with backscatter 'apl_uw' (APL-UW TR 9407 sec. IV.A.8)")
            self.frequency, self.sediment_row = frequency, sed.name
            s_b = apl_uw_backscatter(grid, frequency, sed, self.water_sound_speed, extrapolate=extrapolate)
            with np.errstate(divide="ignore"):
                f_mono = 10.0 ** (s_b / 10.0) / np.sin(grid) ** 2
            f_mono[0] = f_mono[1]
        else:
            f_mono = np.zeros_like(grid)
        self.diffuse_on = self.backscatter != "none"
        self.log_f = np.log(np.where(f_mono > 0, f_mono, 1.0))
        albedo = self.scattered_fraction(grid, scale=1.0)
        self.backscatter_scale = float(min(1.0, 1.0 / albedo.max())) if self.diffuse_on else 1.0
        self.scattered = albedo * self.backscatter_scale
        self.r2 = self.reflectance(grid)
        self.w = np.maximum(np.minimum(self.r2, 1.0 - self.scattered), 0.0)

    def reflectance(self, grazing):
        """``|R(grazing)|^2`` of the water over the medium below."""
        r = reflection_coefficient(grazing, self.density / self.water_density,
                                   self.sound_speed / self.water_sound_speed, self.attenuation)
        return np.abs(r) ** 2

    def f_diffuse(self, g_i, g_o, scale=None):
        """The scattered lobe's BSDF value (NumPy): ``k f_mono((g_i + g_o) / 2)``."""
        if not self.diffuse_on:
            return np.zeros(np.broadcast(g_i, g_o).shape)
        k = self.backscatter_scale if scale is None else scale
        return k * np.exp(lerp_table(self.log_f, 0.5 * (np.asarray(g_i) + np.asarray(g_o))))

    def scattered_fraction(self, g_i, scale=None, n=4097):
        """``a(g_i) = 2 pi int_0^{pi/2} f_d(g_i, g_o) sin g_o cos g_o dg_o`` (trapezoid rule)."""
        g_o = np.linspace(0.0, 0.5 * np.pi, n)
        vals = self.f_diffuse(np.asarray(g_i, float)[..., None], g_o, scale) * np.sin(g_o) * np.cos(g_o)
        return 2.0 * np.pi * trapezoid(vals, g_o, axis=-1)


class AcousticMaterialBSDF(mi.BSDF):
    __doc__ = __doc__

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.medium = m = Medium(props)
        self.log_f = mi.Float(m.log_f.astype(np.float32))
        self.w_table = mi.Float(m.w.astype(np.float32))
        self.a_table = mi.Float(m.scattered.astype(np.float32))
        self.diffuse_on = m.diffuse_on
        self.shininess = dr.opaque(mi.Float, m.shininess)
        self.m_components = [mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide,
                             mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide]
        self.m_flags = self.m_components[0] | self.m_components[1]

    # ------------------------------------------------------------------ tables
    @staticmethod
    def _lookup(table, g):
        x = dr.clip(g * (2.0 / dr.pi) * N_TABLE, 0.0, N_TABLE)
        i = mi.UInt32(dr.minimum(dr.floor(x), N_TABLE - 1))
        t = x - mi.Float(i)
        return dr.lerp(dr.gather(mi.Float, table, i), dr.gather(mi.Float, table, i + 1), t)

    @staticmethod
    def _grazing(cos_theta):
        return dr.safe_asin(dr.clip(cos_theta, 0.0, 1.0))

    def _terms(self, si, wo):
        """(f cos theta_o, pdf, valid) for the pair ``si.wi``, ``wo``."""
        cos_i = mi.Frame3f.cos_theta(si.wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        valid = (cos_i > 0) & (cos_o > 0)
        g_i, g_o = self._grazing(cos_i), self._grazing(cos_o)
        g_mean = 0.5 * (g_i + g_o)
        mirror = mi.Vector3f(-si.wi.x, -si.wi.y, si.wi.z)
        cos_a = dr.maximum(dr.dot(wo, mirror), 0.0)
        phong = dr.select(cos_a > 0, dr.power(cos_a, self.shininess), 0.0)
        lobe = (self.shininess + 1) * (0.5 * dr.inv_pi) * phong
        w = self._lookup(self.w_table, g_mean)
        f_spec = w * lobe * dr.rsqrt(dr.maximum(cos_i * cos_o, 1e-12))
        f = f_spec
        if self.diffuse_on:
            f = f + dr.exp(self._lookup(self.log_f, g_mean)) * self.medium.backscatter_scale
        p_s = self._spec_prob(g_i)
        pdf = (1 - p_s) * cos_o * dr.inv_pi + p_s * lobe
        return dr.select(valid, f * cos_o, 0.0), dr.select(valid, pdf, 0.0), valid

    def _spec_prob(self, g_i):
        w = self._lookup(self.w_table, g_i)
        a = self._lookup(self.a_table, g_i)
        return dr.select(w + a > 0, w / (w + a), 1.0)

    # ------------------------------------------------------------------ BSDF interface
    def sample(self, ctx, si, sample1, sample2, active=True):
        pick_spec = sample1 < self._spec_prob(self._grazing(mi.Frame3f.cos_theta(si.wi)))
        wo = lobe_direction(si, pick_spec, self.shininess, sample2)
        value, pdf, valid = self._terms(si, wo)
        return lobe_sample(wo, value, pdf, valid, pick_spec, active)

    def eval(self, ctx, si, wo, active=True):
        value, _, _ = self._terms(si, wo)
        return mi.Spectrum(dr.select(active, value, 0.0))

    def pdf(self, ctx, si, wo, active=True):
        _, pdf, _ = self._terms(si, wo)
        return dr.select(active, pdf, 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        value, pdf, _ = self._terms(si, wo)
        return mi.Spectrum(dr.select(active, value, 0.0)), dr.select(active, pdf, 0.0)

    def traverse(self, callback):
        """``shininess`` (the specular lobe's exponent; any n >= 1 keeps the energy argument). The
        tables are made from the XML's physical parameters and are not exposed."""
        callback.put("shininess", self.shininess, mi.ParamFlags.NonDifferentiable)

    def parameters_changed(self, keys):
        n = float(self.shininess[0])
        _finite("shininess", n, 1.0, "a Phong exponent >= 1")
        dr.make_opaque(self.shininess)

    def to_string(self):
        m = self.medium
        what = "none"
        if m.backscatter == "lambert":
            what = f"lambert mu={m.mu:g} dB"
        elif m.backscatter == "apl_uw":
            what = f"apl_uw {m.sediment_row!r} at {m.frequency:g} Hz"
        scale = f", backscatter_scale={10 * math.log10(m.backscatter_scale):.2f} dB" if m.backscatter_scale < 1 else ""
        return (f"AcousticMaterialBSDF[material={m.material!r}, density={m.density:g} kg/m^3, "
                f"sound_speed={m.sound_speed:g} m/s, attenuation={m.attenuation:g} dB/wavelength, "
                f"backscatter={what}{scale}, shininess={float(self.shininess[0]):g}]")


register_plugin("BSDF", "acoustic_material", AcousticMaterialBSDF)
