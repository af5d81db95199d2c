"""The surface model: Lambertian diffuse plus a GGX microfacet specular lobe.

    f(wi, wo) = albedo / pi + specular * D(h) G(wi, wo) / (4 cos(wi) cos(wo)),
    alpha = (r0 + (1 - r0) roughness)^2

The affine map of roughness in [0, 1] onto [r0, 1] keeps mirror-like settings away from
the 0/0 of D and G without a clamp, so the roughness gradient never vanishes.

``albedo`` (RGB), ``specular`` (grey reflectance) and ``roughness`` come from a
*material field*: any object with ``lookup(si, active) -> (albedo, specular, roughness)``
and ``arrays() -> {name: Dr.Jit array}``, so constants, per-vertex attributes and mesh
colors plug in the same way. The BSDF exposes the field's arrays to ``mi.traverse`` as
``object.bsdf.<name>``: ``mi.render`` differentiates only through traversed parameters,
and assigning through the parameters writes into the field's own arrays."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

MIN_ROUGHNESS = 0.02  # r0: alpha >= 4e-4
MIN_COS = 1e-4


class SurfaceBSDF(mi.BSDF):
    def __init__(self, props: mi.Properties, field=None):
        super().__init__(props)
        self.field = field
        reflection = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        glossy = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        self.m_components = [reflection, glossy]
        self.m_flags = reflection | glossy | mi.BSDFFlags.SpatiallyVarying

    def _params(self, si, active):
        albedo, specular, roughness = self.field.lookup(si, active)
        alpha = dr.square(MIN_ROUGHNESS + (1.0 - MIN_ROUGHNESS) * roughness)
        return albedo, specular, alpha

    @staticmethod
    def _specular_probability(albedo, specular):
        p = specular / (specular + mi.luminance(albedo) + 1e-6)
        return dr.select(p < 0.1, 0.1, dr.select(p > 0.9, 0.9, p))

    def _eval_pdf(self, si, wo, active):
        albedo, specular, alpha = self._params(si, active)
        cos_i, cos_o = mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo)
        active &= (cos_i > MIN_COS) & (cos_o > MIN_COS)
        h = dr.normalize(si.wi + wo)
        distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
        D = distr.eval(h)
        G = distr.G(si.wi, wo, h)
        spec = specular * D * G / (4.0 * cos_i)  # times cos_o / cos_o
        value = albedo * (dr.inv_pi * cos_o) + spec
        p_spec = self._specular_probability(albedo, specular)
        pdf_spec = distr.pdf(si.wi, h) / (4.0 * dr.maximum(dr.dot(wo, h), MIN_COS))
        pdf = (1.0 - p_spec) * mi.warp.square_to_cosine_hemisphere_pdf(wo) + p_spec * pdf_spec
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0), (albedo, specular, alpha, p_spec)

    def eval(self, ctx, si, wo, active=True):
        return self._eval_pdf(si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(si, wo, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        value, pdf, _ = self._eval_pdf(si, wo, active)
        return value, pdf

    def sample(self, ctx, si, sample1, sample2, active=True):
        albedo, specular, alpha = self._params(si, active)
        p_spec = self._specular_probability(albedo, specular)
        choose_spec = sample1 < p_spec
        wo_diffuse = mi.warp.square_to_cosine_hemisphere(sample2)
        distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
        m, _ = distr.sample(si.wi, sample2)
        wo_spec = mi.reflect(si.wi, m)
        wo = dr.select(choose_spec, wo_spec, wo_diffuse)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = wo
        bs.eta = 1.0
        bs.sampled_component = dr.select(choose_spec, mi.UInt32(1), mi.UInt32(0))
        bs.sampled_type = dr.select(choose_spec, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                    mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        value, pdf, _ = self._eval_pdf(si, wo, active & (mi.Frame3f.cos_theta(si.wi) > 0))
        bs.pdf = pdf
        ok = active & (pdf > 0)
        return bs, dr.select(ok, value / dr.maximum(pdf, 1e-12), 0.0)

    def eval_diffuse_reflectance(self, si, active=True):
        return self.field.lookup(si, active)[0]

    def traverse(self, callback):
        for name, value in self.field.arrays().items():
            callback.put(name, value, mi.ParamFlags.Differentiable)

    def to_string(self):
        return "SurfaceBSDF[]"


mi.register_bsdf("sft_surface", lambda props: SurfaceBSDF(props))
