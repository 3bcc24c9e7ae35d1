"""The ``acoustic`` BSDF: Lambertian scatter plus a normalised Phong specular lobe (thesis 2.3.2)."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from mitsonar._checks import not_allowed
from mitsonar.plugins.props import number, text
from mitsonar.plugins.registry import register_plugin

from .materials import PRESETS

# What each parameter takes, for the message on a wrong XML type (an <rgb>, a <texture>).
_EXPECTED = {"diffuse": "a <float> in [0, 1]", "specular": "a <float> in [0, 1]", "shininess": "a <float> >= 0"}



def lobe_direction(si, pick_spec, shininess, sample2):
    """An outgoing direction of a Phong-plus-Lambert BSDF (local frame): the Phong lobe about the
    mirror direction (``cos(alpha) = u^(1/(n+1))``) where ``pick_spec``, else cosine-weighted."""
    mirror = mi.Vector3f(-si.wi.x, -si.wi.y, si.wi.z)
    cos_a = dr.power(sample2.x, 1.0 / (shininess + 1))
    sin_a = dr.safe_sqrt(1 - cos_a * cos_a)
    s, c = dr.sincos(2 * dr.pi * sample2.y)
    wo_spec = mi.Frame3f(mirror).to_world(mi.Vector3f(sin_a * c, sin_a * s, cos_a))
    wo_diff = mi.warp.square_to_cosine_hemisphere(sample2)
    return dr.select(pick_spec, wo_spec, wo_diff)


def lobe_sample(wo, value, pdf, valid, pick_spec, active):
    """``(BSDFSample3f, weight)`` of a direction drawn by `lobe_direction`: ``value`` is ``f cos``
    there, ``pdf`` the mixture's density; the lobe picked is the sample's type and component."""
    bs = mi.BSDFSample3f()
    bs.wo = wo
    bs.pdf = pdf
    bs.eta = 1.0
    bs.sampled_type = mi.UInt32(dr.select(pick_spec, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                          mi.UInt32(+mi.BSDFFlags.DiffuseReflection)))
    bs.sampled_component = dr.select(pick_spec, mi.UInt32(1), mi.UInt32(0))
    ok = active & valid & (pdf > 0)
    weight = dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)
    return bs, mi.Spectrum(weight)

class AcousticBSDF(mi.BSDF):
    r"""Acoustic reflection of a surface: diffuse scatter plus a Phong lobe about the mirror direction.

    .. math:: f = \frac{d}{\pi} + s \frac{n + 2}{2 \pi} \cos^n \alpha

    with ``alpha`` the angle between the outgoing and the mirror direction. As in Mitsuba, ``eval``
    returns ``f cos(theta_o)``. One-sided: wrap it in ``twosided`` for thin sheets.

    ============ ========= ==========================================================
    Parameter    Default   Meaning
    ============ ========= ==========================================================
    preset       (none)    a material name from ``mitsonar.plugins.bsdfs.materials.PRESETS``
                           (concrete qualities of thesis Table 2.2, ``water_calm``,
                           ``sand``, ``rock``, Lambert seabeds ``seabed_sand``, ``_mud``,
                           ``_gravel``, ``_rock``, ``_clay``); explicit values override it
    diffuse      0.1       fraction of incident energy scattered diffusely (>= 0); a
                           ``<float>`` or a ``<texture>`` (e.g. a ``bitmap`` of
                           reflectance over a seabed, by the shape's uv)
    specular     0.6       fraction of incident energy in the Phong lobe (>= 0);
                           ``diffuse + specular <= 1`` (energy conservation)
    shininess    30        Phong exponent n (>= 0); large is mirror-like
    ============ ========= ==========================================================

    ``diffuse``, ``specular`` and ``shininess`` are exposed through ``mi.traverse`` and stay opaque,
    so changing them does not recompile the render kernels; all three are differentiable. A
    textured ``diffuse`` is exposed as Mitsuba exposes textured parameters, by the texture's own
    parameters (``<bsdf id>.diffuse.data`` for a ``bitmap``). ``diffuse + specular <= 1`` is checked
    with the texture's maximum.
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        preset = text(props, "preset", "", "acoustic")
        if preset:
            if preset not in PRESETS:
                raise ValueError(f"acoustic 'preset': {preset!r} is not one of {', '.join(sorted(PRESETS))}")
            base = PRESETS[preset]
        else:
            base = {"diffuse": 0.1, "specular": 0.6, "shininess": 30.0}
        self.preset = preset
        self.diffuse_texture = None
        if "diffuse" in props and isinstance(props.get("diffuse"), mi.Texture):
            self.diffuse_texture = props.get("diffuse")
        values = {k: number(props, k, base[k], "acoustic", _EXPECTED[k]) for k in ("diffuse", "specular", "shininess")
                  if not (k == "diffuse" and self.diffuse_texture is not None)}
        if self.diffuse_texture is not None:
            values["diffuse"] = texture_max(self.diffuse_texture)
        check_parameters(**values)
        self.diffuse = dr.opaque(mi.Float, values["diffuse"])
        self.specular = dr.opaque(mi.Float, values["specular"])
        self.shininess = dr.opaque(mi.Float, values["shininess"])
        self.m_components = [mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide,
                             mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide]
        self.m_flags = self.m_components[0] | self.m_components[1]

    # ------------------------------------------------------------------ helpers
    def _lobe_terms(self, si, wo):
        cos_i = mi.Frame3f.cos_theta(si.wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        mirror = mi.Vector3f(-si.wi.x, -si.wi.y, si.wi.z)
        cos_a = dr.maximum(dr.dot(wo, mirror), 0.0)
        phong = dr.select(cos_a > 0, dr.power(cos_a, self.shininess), 0.0)
        valid = (cos_i > 0) & (cos_o > 0)
        return cos_o, phong, valid

    def _diffuse(self, si, active=True):
        """The diffuse coefficient at ``si``: the float, or the texture's value there."""
        if self.diffuse_texture is None:
            return self.diffuse
        return self.diffuse_texture.eval_1(si, active)

    def _spec_prob(self, si):
        total = self._diffuse(si) + self.specular
        return dr.select(total > 0, self.specular / total, 0.0)

    def _eval(self, si, wo):
        cos_o, phong, valid = self._lobe_terms(si, wo)
        f = self._diffuse(si) * dr.inv_pi + self.specular * (self.shininess + 2) * (0.5 * dr.inv_pi) * phong
        return dr.select(valid, f * cos_o, 0.0), cos_o, phong, valid

    def _pdf(self, si, cos_o, phong, valid):
        return dr.select(valid, lobe_pdf(self._spec_prob(si), self.shininess, cos_o, phong), 0.0)

    # ------------------------------------------------------------------ BSDF interface
    def sample(self, ctx, si, sample1, sample2, active=True):
        pick_spec = sample1 < self._spec_prob(si)
        wo = lobe_direction(si, pick_spec, self.shininess, sample2)
        value, cos_o, phong, valid = self._eval(si, wo)
        pdf = self._pdf(si, cos_o, phong, valid)
        return lobe_sample(wo, value, pdf, valid, pick_spec, active)

    def eval(self, ctx, si, wo, active=True):
        value, _, _, _ = self._eval(si, wo)
        return mi.Spectrum(dr.select(active, value, 0.0))

    def pdf(self, ctx, si, wo, active=True):
        _, cos_o, phong, valid = self._eval(si, wo)
        return dr.select(active, self._pdf(si, cos_o, phong, valid), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        value, cos_o, phong, valid = self._eval(si, wo)
        return (mi.Spectrum(dr.select(active, value, 0.0)),
                dr.select(active, self._pdf(si, cos_o, phong, valid), 0.0))

    def traverse(self, callback):
        if self.diffuse_texture is None:
            callback.put("diffuse", self.diffuse, mi.ParamFlags.Differentiable)
        else:
            callback.put("diffuse", self.diffuse_texture, mi.ParamFlags.Differentiable)
        callback.put("specular", self.specular, mi.ParamFlags.Differentiable)
        callback.put("shininess", self.shininess, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        vals = {k: float(getattr(self, k)[0]) for k in ("diffuse", "specular", "shininess")}
        if self.diffuse_texture is not None:
            vals["diffuse"] = texture_max(self.diffuse_texture)
        check_parameters(**vals)
        dr.make_opaque(self.diffuse, self.specular, self.shininess)

    def to_string(self):
        return (f"AcousticBSDF[preset={self.preset!r}, diffuse={self.diffuse[0]:g}, "
                f"specular={self.specular[0]:g}, shininess={self.shininess[0]:g}]")


def lobe_pdf(p_spec, shininess, cos_o, phong):
    """The sampling density (solid angle) of the acoustic BSDF: the cosine lobe with probability
    ``1 - p_spec``, the normalised Phong lobe ``(n + 1) / (2 pi) cos^n alpha`` (``phong`` =
    ``cos^n alpha``) with ``p_spec``. Dr.Jit arrays or Python floats."""
    return (1 - p_spec) * cos_o * dr.inv_pi + p_spec * (shininess + 1) * (0.5 * dr.inv_pi) * phong


def texture_max(texture) -> float:
    """The largest value of a texture: ``Texture.max()``, or (a ``bitmap`` has none) the largest of
    its traversed ``data``/``value`` arrays."""
    try:
        return float(texture.max())
    except RuntimeError:
        params = mi.traverse(texture)
        arrays = [params[k] for k in params.keys() if k.split(".")[-1] in ("data", "value")]
        values = [float(dr.max(dr.detach(a.array if isinstance(a, mi.TensorXf) else a), axis=None)[0]) for a in arrays]
        return max(values) if values else 0.0


def check_parameters(diffuse, specular, shininess):
    """Reject values that are negative, non-finite or not energy conserving."""
    for name, v in (("diffuse", diffuse), ("specular", specular), ("shininess", shininess)):
        if not (v == v and abs(v) != float("inf")) or v < 0:
            raise not_allowed("acoustic", name, v, "must be a finite number >= 0")
    if diffuse + specular > 1.0 + 1e-6:
        raise ValueError(f"acoustic 'diffuse' + 'specular' = {diffuse + specular:g} > 1: "
                         "a surface cannot reflect more energy than it receives")


register_plugin("BSDF", "acoustic", AcousticBSDF)
