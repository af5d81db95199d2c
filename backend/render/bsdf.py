"""The surface model: Lambertian diffuse plus a GGX microfacet specular lobe.

    f(wi, wo) = albedo / pi + specular * D(h) G(wi, wo) / (4 cos(wi) cos(wo)),  alpha = roughness^2

``albedo`` (RGB), ``specular`` (grey reflectance) and ``roughness`` come from a
*material field*: any object with ``lookup(si, active) -> (albedo, specular, roughness)``,
so constants, per-vertex attributes and mesh colors plug in the same way. The field's
Dr.Jit arrays are read while the render is traced, so gradients reach them directly."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

MIN_ROUGHNESS = 0.02  # alpha = 4e-4: sharp highlights without 0/0 in D and G
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
        alpha = dr.square(dr.maximum(roughness, MIN_ROUGHNESS))
        return albedo, specular, alpha

    @staticmethod
    def _specular_probability(albedo, specular):
        lum = mi.luminance(albedo)
        return dr.clip(specular / dr.maximum(specular + lum, 1e-6), 0.1, 0.9)

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
        pass

    def to_string(self):
        return "SurfaceBSDF[]"


mi.register_bsdf("sft_surface", lambda props: SurfaceBSDF(props))
