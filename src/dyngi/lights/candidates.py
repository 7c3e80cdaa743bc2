"""ReSTIR DI's light candidates through a light sampler (``restir-pt:lights=NAME``; issue 24 item 3).

:class:`LightCandidates` has the interface of :class:`~dyngi.sampling.candidates.EmitterCandidates`
(``sample``, ``evaluate``, ``visible``; Bitterli et al. 2020, Alg. 3's source distribution) but draws a
candidate as :class:`~dyngi.lights.nee.LightNEE` draws a NEE sample: with probability ``p_tri`` an
emitter triangle ``k`` chosen by the light sampler at the shading point (pmf ``pmf(k | p, n)``) and a
uniform point on it (area measure: ``pdf = p_tri * pmf / area``), else one of the other emitters through
``EmitterCandidates`` restricted to them (its pdf times ``1 - p_tri``).

Candidate ids: ``k < L`` is triangle light ``k`` (payload: the point's two uniform numbers and, in
``z``, the pmf it was drawn with -- only the initial candidates' source pdf reads it; reuse re-evaluates
the target, never the source pdf); ``k >= L`` is the other emitter ``k - L`` of the restricted table
(payload as ``EmitterCandidates``'). The radiance of a triangle is the emitter table's (exact for
uniform emitters, :mod:`dyngi.sampling.emitter_triangles`).
"""
from __future__ import annotations

from ..backend import dr, mi
from ..sampling.candidates import EmitterCandidates, LightEval
from .base import INVALID
from ..scene.surface import shading_normal
from .nee import LightNEE


class LightCandidates:
    """ReSTIR DI candidates from a :class:`LightNEE`'s light sampler (module docstring)."""

    def __init__(self, nee: LightNEE, mi_scene):
        self.nee = nee
        self.mi_scene = mi_scene
        self.tris = nee.tris
        self.L = int(self.tris.count)
        tri_em = nee._tri_emitters
        self.inner = EmitterCandidates(mi_scene, keep=lambda e: not any(e is x for x in tri_em))
        n_other = self.inner.count_kept if self.inner.count else 0
        self.p_tri = 1.0 if n_other == 0 else (0.0 if self.L == 0 else nee.p_tri)
        self.count = self.L + n_other
        self.has_fast = True       # refresh() follows moving emitter meshes (the tables are the lights' own)

    def fast_shape_ids(self) -> set:
        ids = {sid for sid, _, _ in self.tris.shape_slices()}
        return ids | (self.inner.fast_shape_ids() if self.inner.count else set())

    def refresh(self) -> None:
        """The other emitters' triangle table; the emitter table is refreshed by ``LightNEE.begin_frame``."""
        if self.inner.count and self.inner.has_fast:
            self.inner.refresh()

    def sample(self, si, u1, u2, active=True):
        active = mi.Bool(active)
        p_tri = self.p_tri
        k = dr.full(mi.UInt32, INVALID, dr.width(active))
        payload = mi.Vector3f(u2.x, u2.y, 0.0)
        pick = active & (u1 < p_tri) if 0.0 < p_tri < 1.0 else active & (p_tri > 0.0)
        if self.L and p_tri > 0.0:
            u_s = dr.minimum(u1 / p_tri, 0.99999994) if p_tri < 1.0 else u1
            nee = self.nee
            leaf = nee._leaf(si.p, pick)
            k_t, pmf = nee.sampler.sample(si.p, shading_normal(si), u_s, pick, **nee._lk(leaf))
            k = dr.select(pick, k_t, k)
            payload.z = dr.select(pick, pmf, 0.0)
        if p_tri < 1.0:
            other = active & ~pick
            u_o = dr.minimum((u1 - p_tri) / (1.0 - p_tri), 0.99999994) if p_tri > 0.0 else u1
            k_o, pl_o = self.inner.sample(si, u_o, u2, other)
            k = dr.select(other, k_o + self.L, k)
            payload = dr.select(other, pl_o, payload)
        return k, payload

    def evaluate(self, p, k, payload, time=0.0, active=True) -> LightEval:
        active = mi.Bool(active) & (k != INVALID)
        p = mi.Point3f(p)
        tri = active & (k < self.L)
        wi, dist, Lg = dr.zeros(mi.Vector3f, dr.width(active)), mi.Float(dr.inf), mi.Color3f(0.0)
        pdf, kind, p_light = mi.Float(0.0), mi.UInt32(0), mi.Point3f(p)
        if self.L:
            kt = dr.select(tri, k, 0)
            q, nq, pdf_a = self.tris.sample_point(kt, mi.Point2f(payload.x, payload.y), tri)
            d = q - p
            r2 = dr.squared_norm(d)
            r = dr.sqrt(r2)
            dn = d / r
            cos_l = -dr.dot(nq, dn)
            Le = dr.select(cos_l > 0.0, self.tris.gather_radiance(kt, tri), 0.0)
            wi = dr.select(tri, dn, wi)
            dist = dr.select(tri, r, dist)
            Lg = dr.select(tri, Le * dr.maximum(cos_l, 0.0) / r2, Lg)
            pdf = dr.select(tri, self.p_tri * payload.z * pdf_a, pdf)
            p_light = dr.select(tri, q, p_light)
        if self.p_tri < 1.0:
            other = active & ~tri
            ev = self.inner.evaluate(p, dr.select(other, k - self.L, 0), payload, time, other)
            wi = dr.select(other, ev.wi, wi)
            dist = dr.select(other, ev.dist, dist)
            Lg = dr.select(other, ev.Lg, Lg)
            pdf = dr.select(other, ev.pdf * (1.0 - self.p_tri), pdf)
            kind = dr.select(other, ev.kind, kind)
            p_light = dr.select(other, ev.p_light, p_light)
        valid = active & (pdf > 0.0) & dr.all(dr.isfinite(Lg))
        return LightEval(wi, dist, mi.Color3f(dr.select(valid, Lg, 0.0)), dr.select(valid, pdf, 0.0), kind, valid,
                         p_light)

    def shadow_ray(self, si, ev: LightEval):
        finite = dr.isfinite(ev.dist)
        return dr.select(finite, si.spawn_ray_to(ev.p_light), si.spawn_ray(ev.wi))

    def visible(self, si, ev: LightEval, active=True):
        active = mi.Bool(active) & ev.valid
        return active & ~self.mi_scene.ray_test(self.shadow_ray(si, ev), active)
