"""Light candidates for resampling, with exact pdfs in each emitter kind's own measure (issue 14, item 3).

ReSTIR (Bitterli et al. 2020, Sec. 2-4) resamples light samples ``y`` that are
shared between pixels and frames, so ``y`` must live in a domain that does not
depend on the shading point. We use the disjoint union of

* **area lights** (``area`` emitters on any shape; a mesh is sampled per
  triangle in proportion to area by Mitsuba's ``sample_position``): a point on
  the emitter, **area measure**, pdf ``pmf(k) * ps.pdf`` (1/area for uniform
  area sampling);
* **environment / sunsky** (infinite emitters): a world direction, **solid-angle
  measure** (directions at infinity are the same for every shading point), pdf
  ``pmf(k) * pdf_direction``;
* **delta lights** (point, spot: delta position; directional: delta
  direction): no density, never hit -- a **point mass** of probability
  ``pmf(k)`` on "emitter k".

A sample is stored as ``(k, payload)``: the emitter index and a 3-vector --
the 2D position sample ``u`` (area; re-mapped through ``sample_position`` at
every evaluation, so a *moving* area light is evaluated where it is now), the
direction (environment), nothing (delta). :meth:`EmitterCandidates.evaluate`
returns, at a shading point ``x``, the direction and distance to ``y``, the
"geometry-weighted" radiance ``Lg`` (``Le cos_l / r^2`` for area, ``Le`` for
the environment, ``I / r^2`` or the irradiance for delta lights: the
integrand without the BSDF and the receiver cosine) and the source pdf of
``y`` in its kind's measure. Emitters are selected by ``sampling_weight``
(Mitsuba's rule; our choice: no power-based selection yet).

Fast path for many lights: area emitters on meshes with a uniform radiance
(every built-in light) are sampled and evaluated from one triangle table
(per-emitter triangle choice by area through a global cumulative table, then
a uniform point in the triangle: pdf ``pmf(k) / area_k``, the same density as
Mitsuba's mesh sampling) with gathers instead of virtual calls, whose cost on
the LLVM backend grows with the number of emitters (measured on the 128-light
warehouse: most of the frame). :meth:`EmitterCandidates.refresh` rebuilds the
table when emissive shapes or their radiance are animated.

**Through a light sampler**: ReSTIR DI's light candidates (``restir-pt:lights=NAME``; issue 24 item 3).

:class:`LightCandidates` has the interface of :class:`EmitterCandidates`
(``sample``, ``evaluate``, ``visible``; Bitterli et al. 2020, Alg. 3's source distribution) but draws a
candidate as :class:`~dyngi.lights.nee.LightNEE` draws a NEE sample: with probability ``p_tri`` an
emitter triangle ``k`` chosen by the light sampler at the shading point (pmf ``pmf(k | p, n)``) and a
uniform point on it (area measure: ``pdf = p_tri * pmf / area``), else one of the other emitters through
``EmitterCandidates`` restricted to them (its pdf times ``1 - p_tri``).

Candidate ids: ``k < L`` is triangle light ``k`` (payload: the point's two uniform numbers and, in
``z``, the pmf it was drawn with -- only the initial candidates' source pdf reads it; reuse re-evaluates
the target, never the source pdf); ``k >= L`` is the other emitter ``k - L`` of the restricted table
(payload as ``EmitterCandidates``'). The radiance of a triangle is the emitter table's (exact for
uniform emitters, :mod:`dyngi.lights.emitter_table`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import rays
from ..backend import dr, mi
from ..scene.surface import shading_normal
from .emitter_table import AREA, DELTA_DIRECTION, DELTA_POSITION, ENVIRONMENT, INVALID, emitter_kind
from .nee import LightNEE

@dataclass
class LightEval:
    """A candidate evaluated at a shading point."""

    wi: "mi.Vector3f"     # unit direction shading point -> light
    dist: "mi.Float"      # distance (inf for environment / directional)
    Lg: "mi.Color3f"      # Le * cos_l / r^2 (area), Le (env), I / r^2 or E (delta)
    pdf: "mi.Float"       # source pdf in the kind's measure, selection pmf included
    kind: "mi.UInt32"
    valid: "mi.Bool"
    p_light: "mi.Point3f"  # shadow-ray target (finite kinds)


class EmitterCandidates:
    """Samples and evaluates light candidates ``(k, payload)`` of a Mitsuba scene (see module docstring)."""

    def __init__(self, mi_scene, keep=None):
        """``keep(emitter) -> bool`` (optional): only these emitters are sampled (the others get pmf 0;
        ``count_kept`` of them), as :class:`dyngi.lights.candidates.LightCandidates` needs for the
        emitters that are not triangles of the emitter table."""
        self.mi_scene = mi_scene
        self.emitters = list(mi_scene.emitters())
        self.count = len(self.emitters)
        kept = np.array([keep is None or bool(keep(e)) for e in self.emitters], bool)
        self.count_kept = int(kept.sum())
        if not self.count:
            return
        w = np.array([float(e.sampling_weight()) for e in self.emitters], np.float64)
        if w.sum() <= 0:
            w[:] = 1.0
        if keep is not None and self.count_kept:
            w = np.where(kept, w, 0.0)
            if w.sum() <= 0:
                w = kept.astype(np.float64)
        self.pmf_host = w / w.sum()
        self.kinds_host = np.array([emitter_kind(e) for e in self.emitters], np.uint32)
        self.table = mi.DiscreteDistribution(self.pmf_host.astype(np.float32))
        self.ptrs = mi.EmitterPtr(self.emitters)
        pad = 2 if self.count == 1 else self.count      # width-1 arrays would become literals
        self.pmf = mi.Float(np.resize(self.pmf_host, pad).astype(np.float32))
        self.kinds = mi.UInt32(np.resize(self.kinds_host, pad))
        self.fast_host = np.zeros(self.count, bool)
        self._params = mi.traverse(mi_scene)
        self._fast_keys = []
        for i, e in enumerate(self.emitters):
            sh = e.get_shape() if self.kinds_host[i] == AREA else None
            if sh is None or not sh.is_mesh() or not sh.id():
                continue
            keys = (f"{sh.id()}.vertex_positions", f"{sh.id()}.faces", f"{sh.id()}.emitter.radiance.value")
            if all(k in self._params for k in keys):
                self.fast_host[i] = True
                self._fast_keys.append((i, keys))
        self.fast = mi.Bool(np.resize(self.fast_host, pad))
        self.has = {k: bool(np.any(self.kinds_host == k)) for k in range(4)}
        self.has_fast = bool(self.fast_host.any())
        self.has_slow_area = bool(np.any((self.kinds_host == AREA) & ~self.fast_host))
        if self.has_fast:
            self.refresh()

    def fast_shape_ids(self) -> set:
        """Shape ids whose animation (motion, radiance) needs :meth:`refresh`."""
        return {kp.split(".vertex_positions")[0] for _, (kp, _, _) in self._fast_keys}

    def refresh(self) -> None:
        """Rebuild the triangle table of the fast area emitters from the scene's current parameters."""
        p0, e1, e2, nrm, rad, lo, hi = [], [], [], [], [], [], []
        area_k = np.zeros(max(self.count, 2))
        first_k = np.zeros(max(self.count, 2), np.uint32)
        last_k = np.zeros(max(self.count, 2), np.uint32)
        n_before = 0
        for i, (kp, kf, kr) in self._fast_keys:
            v = np.asarray(self._params[kp], np.float64).reshape(-1, 3)
            f = np.asarray(self._params[kf], np.int64).reshape(-1, 3)
            a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
            cr = np.cross(b - a, c - a)
            ar = 0.5 * np.linalg.norm(cr, axis=1)
            tot = ar.sum()
            area_k[i] = tot
            cum = np.concatenate([[0.0], np.cumsum(ar) / max(tot, 1e-30)])
            cum[-1] = 1.0
            p0.append(a), e1.append(b - a), e2.append(c - a)
            fn = cr / np.maximum(2.0 * ar, 1e-30)[:, None]
            kn = kp.replace(".vertex_positions", ".vertex_normals")
            vn = np.asarray(self._params[kn], np.float64).reshape(-1, 3) if kn in self._params else np.zeros(0)
            if vn.size == v.size:       # emission follows the shading normal (Mitsuba): orient by it
                s_ = np.sign(np.einsum("ij,ij->i", fn, vn[f[:, 0]] + vn[f[:, 1]] + vn[f[:, 2]]))
                fn *= np.where(s_ == 0, 1.0, s_)[:, None]
            nrm.append(fn)
            rad.append(np.repeat(np.asarray(self._params[kr], np.float64).reshape(1, 3), len(f), 0))
            lo.append(i + cum[:-1]), hi.append(i + cum[1:])
            first_k[i], last_k[i] = n_before, n_before + len(f) - 1
            n_before += len(f)
        cat = lambda x: np.concatenate(x)   # noqa: E731
        P0, E1, E2, N, RAD, LO, HI = map(cat, (p0, e1, e2, nrm, rad, lo, hi))
        if len(LO) == 1:      # width-1 arrays would become literals: pad with an unreachable copy
            P0, E1, E2, N, RAD = (np.concatenate([x, x]) for x in (P0, E1, E2, N, RAD))
            LO, HI = np.append(LO, np.inf), np.append(HI, np.inf)
        self.n_tri = len(LO)
        v3 = lambda cls, x: cls(*[mi.Float(x[:, j].astype(np.float32)) for j in range(3)])   # noqa: E731
        self.tri_p0, self.tri_e1, self.tri_e2 = v3(mi.Point3f, P0), v3(mi.Vector3f, E1), v3(mi.Vector3f, E2)
        self.tri_n, self.tri_rad = v3(mi.Vector3f, N), v3(mi.Color3f, RAD)
        self.tri_lo, self.tri_hi = mi.Float(LO.astype(np.float32)), mi.Float(HI.astype(np.float32))
        self.area_k = mi.Float(area_k.astype(np.float32))
        self.first_k, self.last_k = mi.UInt32(first_k), mi.UInt32(last_k)

    # -- sampling ------------------------------------------------------------
    def sample(self, si, u1, u2, active=True):
        """Draw ``(k, payload)`` for shading points ``si`` from the selection pmf and per-emitter sampling."""
        active = mi.Bool(active)
        k = self.table.sample(u1, active)
        payload = mi.Vector3f(u2.x, u2.y, 0.0)
        if self.has[ENVIRONMENT]:
            kind = dr.gather(mi.UInt32, self.kinds, k, active)
            env = active & (kind == ENVIRONMENT)
            em = dr.gather(mi.EmitterPtr, self.ptrs, k, env)
            ds, _ = em.sample_direction(si, u2, env)
            payload[env] = ds.d
        return k, payload

    def _ref(self, p, time):
        it = dr.zeros(mi.SurfaceInteraction3f, dr.width(p))
        it.p = p
        it.time = time
        return it

    def evaluate(self, p, k, payload, time=0.0, active=True) -> LightEval:
        """Evaluate candidates ``(k, payload)`` at points ``p`` (see :class:`LightEval`)."""
        active = mi.Bool(active) & (k < self.count)
        ref = self._ref(p, time)
        kind = dr.gather(mi.UInt32, self.kinds, k, active)
        pmf = dr.gather(mi.Float, self.pmf, k, active)
        em = dr.gather(mi.EmitterPtr, self.ptrs, k, active)
        wi = dr.zeros(mi.Vector3f)
        dist = mi.Float(dr.inf)
        Lg = mi.Color3f(0.0)
        pdf = mi.Float(0.0)
        p_light = mi.Point3f(p)
        # -- fast area lights: triangle table, area measure --
        if self.has_fast:
            fa = active & (kind == AREA) & dr.gather(mi.Bool, self.fast, k, active)
            target_c = mi.Float(k) + dr.minimum(payload.x, 0.99999994)
            t = dr.binary_search(0, self.n_tri - 1,
                                 lambda i: dr.gather(mi.Float, self.tri_hi, i, fa) <= target_c)
            # k + u may round to k + 1 in float32: stay on emitter k's own triangles
            t = dr.clip(t, dr.gather(mi.UInt32, self.first_k, k, fa), dr.gather(mi.UInt32, self.last_k, k, fa))
            t_lo = dr.gather(mi.Float, self.tri_lo, t, fa)
            t_hi = dr.gather(mi.Float, self.tri_hi, t, fa)
            ux = dr.clip((target_c - t_lo) / dr.maximum(t_hi - t_lo, 1e-12), 0.0, 0.99999994)
            b = mi.warp.square_to_uniform_triangle(mi.Point2f(ux, payload.y))
            q = dr.gather(mi.Point3f, self.tri_p0, t, fa) + dr.gather(mi.Vector3f, self.tri_e1, t, fa) * b.x \
                + dr.gather(mi.Vector3f, self.tri_e2, t, fa) * b.y
            nq = dr.gather(mi.Vector3f, self.tri_n, t, fa)
            d = q - p
            r2 = dr.squared_norm(d)
            r = dr.sqrt(r2)
            dn = d / r
            cos_l = -dr.dot(nq, dn)            # one-sided emitter: light leaves along its normal
            Le = dr.select(cos_l > 0.0, dr.gather(mi.Color3f, self.tri_rad, t, fa), 0.0)
            wi[fa] = dn
            dist[fa] = r
            Lg[fa] = Le * dr.maximum(cos_l, 0.0) / r2
            pdf[fa] = pmf / dr.gather(mi.Float, self.area_k, k, fa)
            p_light[fa] = q
        # -- other area lights: point on the emitter (Mitsuba's sample_position), area measure --
        if self.has_slow_area:
            a = active & (kind == AREA)
            if self.has_fast:
                a &= ~dr.gather(mi.Bool, self.fast, k, active)
            ps, _ = em.sample_position(time, mi.Point2f(payload.x, payload.y), a)
            d = ps.p - p
            r2 = dr.squared_norm(d)
            r = dr.sqrt(r2)
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p, ds.n, ds.uv, ds.time = ps.p, ps.n, ps.uv, ps.time
            ds.d = d / r
            ds.dist = r
            ds.pdf = ps.pdf
            ds.delta = mi.Bool(False)
            ds.emitter = em
            cos_l = dr.abs(dr.dot(ds.n, ds.d))
            Le = em.eval_direction(ref, ds, a)
            wi[a] = ds.d
            dist[a] = r
            Lg[a] = Le * cos_l / r2
            pdf[a] = ps.pdf * pmf
            p_light[a] = ps.p
        # -- environment: a direction, solid-angle measure --
        if self.has[ENVIRONMENT]:
            e = active & (kind == ENVIRONMENT)
            ds = dr.zeros(mi.DirectionSample3f)
            ds.d = dr.normalize(payload)
            ds.p = p + ds.d
            ds.dist = mi.Float(dr.inf)
            ds.emitter = em
            it = mi.SurfaceInteraction3f(ref)
            it.wi = -ds.d
            Le = em.eval(it, e)
            wi[e] = ds.d
            Lg[e] = Le
            pdf[e] = em.pdf_direction(ref, ds, e) * pmf
        # -- delta lights: a point mass, deterministic direction --
        if self.has[DELTA_POSITION] or self.has[DELTA_DIRECTION]:
            dl = active & ((kind == DELTA_POSITION) | (kind == DELTA_DIRECTION))
            ds, spec = em.sample_direction(ref, mi.Point2f(0.5, 0.5), dl)
            wi[dl] = ds.d
            dist[dl] = dr.select(kind == DELTA_POSITION, ds.dist, dr.inf)
            Lg[dl] = spec          # pdf 1: spec = I / r^2 (point, spot) or E (directional)
            pdf[dl] = pmf
            p_light[dl] = ds.p
        valid = active & (pdf > 0.0) & dr.all(dr.isfinite(Lg))
        Lg = dr.select(valid, Lg, 0.0)
        return LightEval(wi, dist, mi.Color3f(Lg), dr.select(valid, pdf, 0.0), kind, valid, p_light)

    # -- visibility ----------------------------------------------------------
    def shadow_ray(self, si, ev: LightEval):
        """The shadow ray from ``si`` to the evaluated candidate (to its point, or along its direction)."""
        finite = dr.isfinite(ev.dist)
        r_fin = si.spawn_ray_to(ev.p_light)
        r_inf = si.spawn_ray(ev.wi)
        return dr.select(finite, r_fin, r_inf)

    def visible(self, si, ev: LightEval, active=True, *, stage: str = "shadow"):
        """Lanes whose candidate is unoccluded: one shadow ray each (counted under ``stage``, :mod:`dyngi.rays`)."""
        active = mi.Bool(active) & ev.valid
        ray = self.shadow_ray(si, ev)
        return active & ~rays.occluded(self.mi_scene, ray, active, stage=stage)


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

    def visible(self, si, ev: LightEval, active=True, *, stage: str = "shadow"):
        """Lanes whose candidate is unoccluded: one shadow ray each (counted under ``stage``, :mod:`dyngi.rays`)."""
        active = mi.Bool(active) & ev.valid
        return active & ~rays.occluded(self.mi_scene, self.shadow_ray(si, ev), active, stage=stage)
