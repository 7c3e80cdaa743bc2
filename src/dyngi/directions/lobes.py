"""Directions from a subset of the BSDF's lobes, as a strategy of the path walk (issue 24, item 1).

The DDGI Resampling family's glossy recursions (Majercik et al. 2022, Sec. 3.1 ``T_fg L`` and Sec. 3.4
``S(x_n)``) continue a path only through the glossy (and delta) lobes; the diffuse part is read from the
probes instead. :class:`LobeDirections` gives :func:`dyngi.transport.path_walk.walk` that choice: one
sample of ``bsdf.sample`` with a context whose ``type_mask`` enables only ``lobes`` (Mitsuba samples the
enabled lobes in proportion to their own weights; ``weight`` is ``f_lobes cos / pdf``). A lane whose BSDF
has none of those lobes, whose sample fails (pdf 0, a non-finite or zero weight) or, with
``reflection_only``, leaves through the other side of the surface, does not continue.

Not a registered direction sampler (``directions=``): on its own it leaves out the other lobes, which
only an estimator that adds them otherwise (the probes) may do.
"""
from __future__ import annotations

from ..backend import dr, mi
from .base import DirSample, Vertex


class LobeDirections:
    """The walk's direction strategy restricted to the BSDF lobes ``lobes`` (a ``mi.BSDFFlags`` mask)."""

    def __init__(self, lobes, reflection_only: bool = False):
        self.lobes = int(lobes)
        self.reflection_only = reflection_only

    def _ctx(self):
        ctx = mi.BSDFContext()
        ctx.type_mask = self.lobes
        return ctx

    def _has_lobes(self, bsdf):
        return (bsdf != None) & ((bsdf.flags() & mi.UInt32(self.lobes)) != 0)   # noqa: E711

    def begin_walk(self, n: int) -> None:
        pass

    def end_walk(self, L) -> None:
        pass

    def record(self, v, d, L, beta, depth) -> None:
        pass

    def vertex(self, si, bsdf, active) -> Vertex:
        return Vertex(si, si.sh_frame.n, bsdf, None, None, mi.Bool(active))

    def pdf(self, v: Vertex, wo, active):
        """Density of :meth:`sample` for world direction ``wo`` (solid angle)."""
        return v.bsdf.pdf(self._ctx(), v.si, v.si.to_local(wo), active & self._has_lobes(v.bsdf))

    def sample(self, v: Vertex, sampler, active) -> DirSample:
        """One sample of the enabled lobes (module docstring)."""
        on = mi.Bool(active) & self._has_lobes(v.bsdf)
        bs, w = v.bsdf.sample(self._ctx(), v.si, sampler.next_1d(), sampler.next_2d(), on)
        w = mi.Color3f(w)
        ok = on & (bs.pdf > 0.0) & dr.all(dr.isfinite(w)) & dr.any(w > 0.0)
        if self.reflection_only:
            ok &= mi.Frame3f.cos_theta(bs.wo) * mi.Frame3f.cos_theta(v.si.wi) > 0.0
        return DirSample(v.si.to_world(bs.wo), dr.select(ok, w, 0.0), dr.select(ok, bs.pdf, 0.0),
                         ok & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta), ok)
