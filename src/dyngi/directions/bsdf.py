"""``directions=bsdf``: the vertex's BSDF (Mitsuba's ``bsdf.sample`` / ``pdf``, pbrt-v4 Sec. 9.1.2), or the
cosine-weighted hemisphere of a diffuse stand-in (``Vertex.bsdf is None``: ``albedo``, Malley's method)."""
from __future__ import annotations

from ..backend import dr, mi
from .base import DirSample, Vertex, register


class BSDFDirections:
    """Direction from the BSDF (or the diffuse stand-in's cosine lobe); ``u_sel`` is not used."""

    name = "bsdf"

    def __init__(self, guide=None):
        pass

    def pdf(self, v: Vertex, wo, active):
        if v.bsdf is not None:
            return v.bsdf.pdf(mi.BSDFContext(), v.si, v.si.to_local(wo), active)
        return dr.select(active, dr.maximum(dr.dot(v.n, wo), 0.0) * dr.inv_pi, 0.0)

    def sample(self, v: Vertex, u_sel, u1, u2, active) -> DirSample:
        if v.bsdf is not None:
            bs, bw = v.bsdf.sample(mi.BSDFContext(), v.si, u1, u2, active)
            return DirSample(v.si.to_world(bs.wo), mi.Color3f(bw), bs.pdf,
                             mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta), active & (bs.pdf > 0.0))
        lw = mi.warp.square_to_cosine_hemisphere(u2)
        pdf = mi.warp.square_to_cosine_hemisphere_pdf(lw)
        return DirSample(mi.Frame3f(v.n).to_world(lw), mi.Color3f(v.albedo), pdf, mi.Bool(False), active & (pdf > 0.0))

    def f(self, v: Vertex, wo, active):
        """BSDF value times cosine for direction ``wo`` (the mixture's numerator)."""
        if v.bsdf is not None:
            return mi.Color3f(v.bsdf.eval(mi.BSDFContext(), v.si, v.si.to_local(wo), active))
        return v.albedo * dr.maximum(dr.dot(v.n, wo), 0.0) * dr.inv_pi


register("bsdf", BSDFDirections, "the vertex's BSDF (cosine lobe for a diffuse stand-in)")
