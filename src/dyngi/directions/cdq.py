"""The CDQ as a direction sampler (the VLC paper's Cumulative Distribution Quantisation, Dittebrandt et
al. Sec. 5; :class:`dyngi.sampling.cdq.CDQDirections` holds the per-leaf distributions). It is a
component of ``directions=cdq`` (:mod:`dyngi.directions.mixture`): alone it would miss the directions it
has not learned, so it is not registered on its own."""
from __future__ import annotations

from ..backend import mi
from .base import Vertex


class CDQComponent:
    """Directions from the CDQ of the vertex's octree leaf; not used where the BSDF has a delta lobe."""

    name = "cdq-component"

    def __init__(self, guide):
        self.guide = guide

    def usable(self, v: Vertex):
        """Lanes where the CDQ takes part: every active lane but those whose real BSDF has a delta lobe
        (the mixture's pdf would be undefined there, nee-pt module docstring)."""
        if v.bsdf is not None:
            return mi.Bool(v.active) & ~mi.has_flag(v.bsdf.flags(), mi.BSDFFlags.Delta)
        return mi.Bool(v.active)

    def sample(self, v: Vertex, u2, active):
        wo, _ = self.guide.sample(v.leaf, u2, active)
        return wo

    def pdf(self, v: Vertex, wo, active):
        return self.guide.pdf(v.leaf, wo, active)
