"""``directions=cdq``: the CDQ mixed with the BSDF by one-sample MIS (balance heuristic; Veach 1997,
Sec. 9.2.4): with probability ``fraction`` (0.5, the VLC paper's Sec. 7) from the CDQ, else from the BSDF;
either way the weight is ``f cos / (fraction p_cdq + (1 - fraction) p_bsdf)`` and the pdf the mixture's.
Where the CDQ is not usable (a delta BSDF) the BSDF alone."""
from __future__ import annotations

from ..backend import dr, mi
from ..errors import DyngiError
from .base import DirSample, Vertex, register
from .bsdf import BSDFDirections
from .cdq import CDQComponent

CDQ_FRACTION = 0.5
"""Probability of drawing a direction from the CDQ (Sec. 7: "brdf fraction of 50%")."""


class MixtureDirections:
    """One-sample MIS mixture of a guide component and the BSDF (module docstring)."""

    name = "cdq"

    def __init__(self, guide=None, fraction: float = CDQ_FRACTION):
        if guide is None:
            raise DyngiError("directions=cdq needs a CDQ (dyngi.directions.cdq.CDQDirections over an octree)")
        self.guide = CDQComponent(guide)
        self.base = BSDFDirections()
        self.fraction = fraction

    def pdf(self, v: Vertex, wo, active):
        use = self.guide.usable(v)
        pc = self.guide.pdf(v, wo, active & use)
        pb = self.base.pdf(v, wo, active)
        return dr.select(use, self.fraction * pc + (1.0 - self.fraction) * pb, pb)

    def sample(self, v: Vertex, u_sel, u1, u2, active) -> DirSample:
        """One CDQ walk per lane (Sec. 5.2): a CDQ-drawn direction keeps the pdf and the quadtree node of its
        draw (bottom up), a BSDF-drawn one is located once (top down); the node goes with the sample
        (``DirSample.node``) so that the CDQ's record does not walk again."""
        use = self.guide.usable(v)
        b = self.base.sample(v, u_sel, u1, u2, active)
        take = use & (u_sel < self.fraction)
        wo, pc, node = self.guide.sample_located(v, u2, take, mi.Bool(active) & use, b.wo)
        pb = self.base.pdf(v, wo, active)
        p_mix = dr.select(use, self.fraction * pc + (1.0 - self.fraction) * pb, pb)
        f = self.base.f(v, wo, active & ~b.delta)
        w_mix = dr.select(p_mix > 0.0, f / p_mix, 0.0)
        mixed = use & ~b.delta
        return DirSample(wo, mi.Color3f(dr.select(mixed, w_mix, b.weight)), dr.select(mixed, p_mix, b.pdf),
                         b.delta & ~take, dr.select(take, active & (p_mix > 0.0), b.ok),
                         dr.select(use, node, mi.UInt32(0xFFFFFFFF)))


register("cdq", MixtureDirections, "the CDQ (VLC paper Sec. 5) mixed 50/50 with the BSDF by one-sample MIS")
