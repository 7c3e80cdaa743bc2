"""Next-event estimation through a light sampler: the path walk's light strategy for ``lights=NAME``.

:class:`LightNEE` holds the one emitter table (:class:`~dyngi.lights.base.EmitterTable`), one light
sampler over it (:func:`dyngi.lights.make`) and, for the emitters that are not triangles (delta lights,
analytic area shapes, the environment; :func:`~dyngi.lights.base.emitter_kind`), Mitsuba's emitter
sampling restricted to them. One NEE sample (pbrt-v4's ``PathIntegrator::SampleLd``, Sec. 13.3.3):

1. with probability ``p_tri`` (1 without other emitters, 0 without triangles, else 0.5: our choice) a
   triangle: the sampler picks light ``k`` with ``pmf(k | p, n)``, a point ``y`` on it is drawn by area
   sampling, so the solid-angle pdf is ``p_tri * pmf * |y - p|^2 / (area * cos_l)``;
2. else one of the other emitters through Mitsuba (its pdf times ``1 - p_tri``).

:meth:`LightNEE.pdf_hit` is the same density for emission reached by BSDF sampling (the light's id from
the hit), so the walk's MIS weights are exact and the estimator is unbiased for every sampler whose
``pmf`` is that of its ``sample`` (``tests/lights/``). ``n`` is the shading normal turned to the side
of ``wi`` (the importance of the light tree, SLL and VLC is the diffuse irradiance above it).

Known bias: the triangles' radiance is the table's (the emitter at each triangle's centroid), exact for
uniform emitters, an approximation for textured ones (:mod:`dyngi.lights.emitter_table`).

:class:`TracedNEE` adapts a :class:`LightNEE` to the light-sampling strategies' ``sample_traced`` interface
(:func:`dyngi.lights.emitter_sampling.sample_traced`) for shading that is not a path walk: the primary-vertex NEE of
the probe and VPL techniques (:func:`dyngi.probes.primary.shade_primary`) and the NEE at probe-ray hits
(:class:`dyngi.probes.trace.DiffuseHitShader`).

Learning samplers (the VLC): every NEE sample's light, visibility and octree leaf is scattered into
per-lane buffers inside the walk's loop (the first ``RECORD_VERTICES`` vertices of each path) and
handed to ``record`` in :meth:`end_frame`; path vertices are placed in the octree (VLC Sec. 6), which
adapts at the end of the frame.

``estimator="separate"`` (the VLC paper's evaluation path tracer, Sec. 7; ``nee-pt``): the walk's own
estimators (:meth:`LightNEE.estimate`, :meth:`LightNEE.emitted`) for an unrolled walk whose vertex hook
and per-vertex records are a :class:`~dyngi.directions.walk.WalkDirections` with ``record="vertex"``
(``vertices=``). At each vertex two NEE samples instead of one choice between them: one triangle light by
the sampler (its ``pmf``, a point by area sampling), the shadow ray traced only where the BSDF value (or
the diffuse stand-in's) is positive, recorded into the sampler inside the kernel at the vertex's placing
leaf; plus one Mitsuba sample of the other emitters excluding the environment (which only BSDF sampling
reaches); each weighted by the MIS function ``mis`` (the walk's balance heuristic) against the direction
strategy's pdf; random numbers in the order 1D (light), 2D (point), 2D (other emitters). The emission
reached by a bounce is weighted against the previous vertex's NEE (weight 1 where it did none); with
``record_hits`` a bounce that reaches a light's front is recorded as a visible sample of that light.
The octree is shared (:meth:`LightNEE.share_octree`): its owner places the vertices and adapts it.
"""
from __future__ import annotations

import numpy as np

from .. import rays
from ..backend import dr, mi
from ..directions.octree import make_octree, octree_bounds, octree_rule
from ..errors import DyngiError
from ..registry import Param
from ..sampling.rng import make_sampler
from ..scene.surface import shading_normal
from .base import INVALID, EmitterTable, FrameCtx, entry, make
from ..scene.passthrough import count_lanes
from .emitter_sampling import EmitterSubsetSampling

RECORD_VERTICES = 3
"""Path vertices per lane whose NEE samples a learning sampler records (the VLC paper's path has 2)."""
P_TRI = 0.5
"""Probability of sampling the triangle lights when the scene also has other emitters (our choice)."""
PRIMARY_NEE_STREAM = 0x7B1
"""Random stream of the light-selection numbers of the primary-vertex NEE through a light sampler
(:meth:`TracedNEE.stream`)."""


def _pad_single_entries(obj) -> None:
    """Replace each size-1 Dr.Jit array attribute of ``obj`` (read by gathers only) by its entry twice.

    A kernel reads a size-1 input as a scalar, and the scalar's load is emitted with the alignment of its
    allocation, which varies from upload to upload: with a hierarchy rebuilt every frame a light moves
    (``lights=lighttree`` on two emitter triangles: one node, one leaf), the path walk's kernel was
    compiled anew every frame (~1.5 s; ``tests/lights/``). A size-2 array is an indexed input, whose code
    does not depend on its address."""
    for k, v in list(vars(obj).items()):
        if dr.is_array_v(v) and not dr.is_tensor_v(v) and dr.width(v) == 1:
            c = dr.gather(type(v), v, dr.zeros(mi.UInt32, 2))
            dr.eval(c)
            setattr(obj, k, c)


class LightNEE:
    """The walk's light strategy for light sampler ``kind`` (module docstring)."""

    walk_aware = True     # the walk calls sample_walk / pdf_hit / begin_walk

    def __init__(self, scene, kind: str, leaf_samples: int = 0, *, estimator: str = "choice", vertices=None,
                 mis=None, record_hits: bool = False, **opts):
        """``leaf_samples``: the octree's split threshold per leaf of an octree-based sampler (collapse: half;
        0: the paper's scaled and floored, :func:`~dyngi.directions.octree.make_octree`); ``estimator``:
        ``"choice"`` (one NEE sample, the walk's estimators) or ``"separate"`` (the VLC paper's Sec. 7, module
        docstring; ``vertices``: the per-vertex records, ``mis(pdf_a, pdf_b)``: the MIS weight,
        ``record_hits``: also learn the lights that bounces hit); ``opts``: the light sampler's options."""
        if estimator not in ("choice", "separate"):
            raise DyngiError(f"LightNEE: estimator must be 'choice' or 'separate', got '{estimator}'")
        if estimator == "separate" and mis is None:
            raise DyngiError("LightNEE: estimator='separate' needs mis= (and vertices=, the walk's per-vertex records, "
                             "before the first walk)")
        self.estimator = estimator
        self.own_estimators = estimator == "separate"    # the walk calls estimate / emitted
        self.vertices = vertices
        self._mis = mis
        self.record_hits = bool(record_hits)
        self._owns_octree = True
        ms = scene.mi_scene if hasattr(scene, "mi_scene") else scene
        self.leaf_samples = int(leaf_samples)
        self.kind = kind
        self.entry = entry(kind)
        self.name = f"lights={kind}"
        self.tris = EmitterTable(ms)
        self._tri_emitters = [sh.emitter() for sh in self.tris._shapes]   # compared by identity
        meta = getattr(scene, "meta", None)
        self.dynamic = tuple(getattr(meta, "dynamic_shapes", ()) or ())
        tri_shapes = {sid for sid, _, _ in self.tris.shape_slices()}
        self._lights_move = bool(tri_shapes & set(self.dynamic))

        separate = self.own_estimators

        def keep(e):
            if separate and mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) and not mi.has_flag(
                    e.flags(), mi.EmitterFlags.DeltaDirection):
                return False     # the separate estimator's NEE ignores the environment (BSDF sampling only)
            return not any(e is x for x in self._tri_emitters)

        self.others = EmitterSubsetSampling(ms, keep) if any(keep(e) for e in ms.emitters()) else None
        if self.others is not None and not separate:
            self.others.glass = False      # shadow rays stop at glass, as Mitsuba's path (the reference)
        n_other = self.others.count if self.others is not None else 0
        self.p_tri = 1.0 if n_other == 0 else (0.0 if self.tris.count == 0 else P_TRI)
        self.bounds = octree_bounds(scene)
        if "dynamic_shapes" in self.entry.options and "dynamic_shapes" not in opts:
            opts["dynamic_shapes"] = list(self.dynamic)
        if "rebuild" in self.entry.options and "rebuild" not in opts:
            opts["rebuild"] = "change"   # our choice: rebuild a hierarchy only when a light moved (not per frame)
        self.octree = None
        self._opts = opts
        self.sampler = None
        if not self.entry.needs_octree:
            self.sampler = make(kind, self.tris, mi_scene=ms, bounds=self.bounds, **opts)
        else:   # an octree-based sampler is built in begin_frame, once the vertex count is known
            bad = sorted(set(opts) - set(self.entry.options) - {"octree"})
            if bad:
                raise DyngiError(f"light sampler '{kind}': unknown option(s) {', '.join(bad)}; valid: "
                                 f"{', '.join(self.entry.options)}")
        self._ms = ms
        self._walks: list = []
        self._verts = None
        self._light_emitters = None     # per light: its emitter (built on the first sample_walk(emitters=True))

    def light_emitters(self):
        """Per light of the table: its Mitsuba emitter (an ``EmitterPtr`` array padded to >= 2 entries)."""
        if self._light_emitters is None:
            shape_of = np.repeat(np.arange(len(self._tri_emitters), dtype=np.uint32),
                                 np.asarray(self.tris._counts, np.int64))
            if shape_of.size < 2:
                shape_of = np.concatenate([shape_of, np.zeros(2 - shape_of.size, np.uint32)])
            if self._tri_emitters:
                self._light_emitters = dr.gather(mi.EmitterPtr, mi.EmitterPtr(self._tri_emitters), mi.UInt32(shape_of))
            else:
                self._light_emitters = dr.zeros(mi.EmitterPtr, 2)
            dr.eval(self._light_emitters)
        return self._light_emitters

    def share_octree(self, octree) -> None:
        """Use ``octree`` (owned by the caller, who places the path vertices and adapts it; None: none) from
        the next frame on; an octree-based sampler is built anew over it in :meth:`begin_frame`."""
        self.octree = octree
        self._owns_octree = False
        if self.entry.needs_octree:
            self.sampler = None

    # -- per-frame hooks ---------------------------------------------------------------------------
    def begin_frame(self, scene, frame, vertices_per_frame: int = 0) -> None:
        """Refresh the table of moving lights, build the octree (first frame), call the sampler's hook."""
        if self.entry.needs_octree and self.sampler is None:
            if self._owns_octree:
                self.octree = make_octree(self.bounds, vertices_per_frame, self.leaf_samples)
            self.sampler = make(self.kind, self.tris, mi_scene=self._ms, bounds=self.bounds, octree=self.octree,
                                **{k: v for k, v in self._opts.items() if k != "octree"})
        if self._lights_move and frame.index > 0:
            self.tris.refresh(self._ms)
        cam = np.asarray(frame.camera.origin, np.float64) if getattr(frame, "camera", None) is not None else None
        self.sampler.begin_frame(FrameCtx(self._ms, self.tris, frame.index, frame.time, self.octree, self.bounds,
                                          cam))
        if "rebuild" in self.entry.options:     # a hierarchy rebuilt on the host (the light tree)
            _pad_single_entries(self.sampler)

    def end_frame(self) -> None:
        """Hand the recorded NEE samples to a learning sampler; adapt the octree."""
        if self.entry.learns:
            for leaf, light, vis in self._walks:
                kw = {"leaf": leaf} if getattr(self.sampler, "accepts_leaf", False) else {}
                self.sampler.record(None, None, light, vis != 0, light != INVALID, **kw)
        self._walks = []
        self.sampler.end_frame()
        if self.octree is not None and self._owns_octree:
            self.octree.adapt()

    def stats(self) -> dict:
        return self.sampler.stats() if self.sampler is not None else {}

    def begin_walk(self, n: int) -> None:
        """Before a walk of ``n`` lanes: the record buffers of a learning sampler (the separate estimator
        records at each vertex: none)."""
        if not self.entry.learns or self.own_estimators:
            return
        size = n * RECORD_VERTICES
        bufs = (dr.full(mi.UInt32, INVALID, size), dr.full(mi.UInt32, INVALID, size), dr.zeros(mi.UInt32, size))
        dr.make_opaque(*bufs)
        self._lane = dr.arange(mi.UInt32, n)
        self._walks.append(bufs)

    # -- the walk's strategy -----------------------------------------------------------------------
    def _leaf(self, p, active):
        return self.octree.lookup(p, active) if self.octree is not None else None

    def _lk(self, leaf):
        return {"leaf": leaf} if (leaf is not None and getattr(self.sampler, "accepts_leaf", False)) else {}

    def sample_walk(self, scene, si, sampler, active, depth=None, emitters: bool = False, *, stage: str = "shadow",
                    lanes: bool = False):
        """One NEE sample at ``si``: (ds, weight = Le * visibility / pdf, lanes that cast a shadow ray).

        ``emitters``: also set ``ds.emitter`` (the sampled light's emitter), which a caller that routes light
        by emitter needs (:class:`TracedNEE`); the path walk does not read it. The shadow ray is counted
        under ``stage`` (:mod:`dyngi.rays`); with ``lanes`` (the path walk's symbolic loop) it is not, and a
        fourth value gives the rays traced per lane."""
        u2 = sampler.next_2d()
        u_sel = sampler.next_1d()
        active = mi.Bool(active)
        p_tri = self.p_tri
        pick = active & (u_sel < p_tri) if 0.0 < p_tri < 1.0 else active & (p_tri > 0.0)
        ds = dr.zeros(mi.DirectionSample3f, dr.width(active))
        weight = mi.Color3f(0.0)
        traced = mi.Bool(False)
        n_rays = mi.UInt32(0)
        if self.tris.count and p_tri > 0.0:
            n = shading_normal(si)
            u_s = dr.minimum(u_sel / p_tri, 0.99999994) if p_tri < 1.0 else u_sel
            leaf = self._leaf(si.p, pick)
            if self.octree is not None:
                self.octree.place_leaf(leaf, pick)
            k, pmf = self.sampler.sample(si.p, n, u_s, pick, **self._lk(leaf))
            ok = pick & (k != INVALID) & (pmf > 0.0)
            pl, nl, pdf_a = self.tris.sample_point(k, u2, ok)
            d = pl - si.p
            dist2 = dr.squared_norm(d)
            wi = d * dr.rsqrt(dist2)
            cos_l = -dr.dot(nl, wi)
            ok &= (cos_l > 0.0) & (dist2 > 0.0) & (pdf_a > 0.0)
            pdf = p_tri * pmf * pdf_a * dist2 / cos_l
            vis = ok & ~rays.occluded(scene, si.spawn_ray_to(pl), ok, stage=stage, lanes=lanes)
            Le = self.tris.gather_radiance(k, vis)
            weight = dr.select(vis, Le / pdf, 0.0)
            traced = ok
            n_rays = mi.UInt32(ok)
            ds.p, ds.n, ds.d, ds.dist = mi.Point3f(pl), mi.Normal3f(nl), wi, dr.sqrt(dist2)
            ds.pdf = dr.select(ok, pdf, 0.0)
            if emitters:
                ds.emitter = dr.gather(mi.EmitterPtr, self.light_emitters(), k, ok)
            if self.entry.learns and depth is not None:
                rec = ok & (mi.UInt32(depth) < RECORD_VERTICES)
                slot = self._lane * RECORD_VERTICES + mi.UInt32(depth)
                leaf_b, light_b, vis_b = self._walks[-1]
                dr.scatter(leaf_b, leaf if leaf is not None else mi.UInt32(0), slot, rec)
                dr.scatter(light_b, k, slot, rec)
                dr.scatter(vis_b, dr.select(vis, mi.UInt32(1), mi.UInt32(0)), slot, rec)
        if self.others is not None and p_tri < 1.0:
            other = active & ~pick
            ds_o, w_o, tr_o, n_o = self.others.sample_traced(scene, si, u2, other, stage=stage, lanes=True)
            n_rays = n_rays + n_o
            count_lanes(stage, n_o, lanes)
            q = 1.0 - p_tri
            ds.p = dr.select(other, ds_o.p, ds.p)
            ds.n = dr.select(other, ds_o.n, ds.n)
            ds.d = dr.select(other, ds_o.d, ds.d)
            ds.dist = dr.select(other, ds_o.dist, ds.dist)
            ds.delta = dr.select(other, ds_o.delta, ds.delta)
            ds.pdf = dr.select(other, ds_o.pdf * q, ds.pdf)
            if emitters:
                ds.emitter = dr.select(other, ds_o.emitter, ds.emitter)
            weight = dr.select(other, w_o / q, weight)
            traced = dr.select(other, tr_o, traced)
        if lanes:
            return ds, mi.Color3f(weight), traced, n_rays
        return ds, mi.Color3f(weight), traced

    def pdf_hit(self, scene, prev_si, si, ds, active):
        """Solid-angle pdf with which :meth:`sample_walk` at ``prev_si`` produces the emission hit at ``si``."""
        active = mi.Bool(active)
        pdf = mi.Float(0.0)
        is_tri = mi.Bool(False)
        if self.tris.count and self.p_tri > 0.0:
            k = self.tris.light_id(si, active)
            is_tri = active & (k != INVALID)
            nl = dr.gather(mi.Normal3f, self.tris.normal, k, is_tri)
            cos_l = -dr.dot(nl, ds.d)
            front = is_tri & (cos_l > 0.0)
            area = dr.gather(mi.Float, self.tris.area, k, front)
            leaf = self._leaf(prev_si.p, front)
            pmf = self.sampler.pmf(prev_si.p, shading_normal(prev_si), k, front, **self._lk(leaf))
            pdf = dr.select(front, self.p_tri * pmf * dr.square(ds.dist) / (area * cos_l), 0.0)
        if self.others is not None and self.p_tri < 1.0:
            pdf += dr.select(active & ~is_tri,
                             (1.0 - self.p_tri) * self.others.pdf(scene, prev_si, ds, active & ~is_tri), 0.0)
        return pdf

    def pdf(self, scene, ref_si, ds, active):
        """Solid-angle pdf with which :meth:`sample_walk` at ``ref_si`` produces the emitter point that a ray
        from ``ref_si`` along ``ds.d`` reaches first (the density MIS against BSDF sampling needs; the
        light-sampling strategies' interface, which gives the direction and not the hit): traces that ray,
        then :meth:`pdf_hit`. 0 where the ray reaches no emitter."""
        active = mi.Bool(active)
        ref_si = mi.SurfaceInteraction3f(ref_si)
        si = rays.intersect(scene, ref_si.spawn_ray(ds.d), mi.RayFlags.All, False, active, stage="mis")
        ds_hit = mi.DirectionSample3f(scene, si, ref_si)
        hit = active & (si.emitter(scene, active) != None)   # noqa: E711
        return dr.select(hit, self.pdf_hit(scene, ref_si, si, ds_hit, hit), 0.0)

    # -- the separate estimator (estimator="separate": the walk's own NEE and emission estimators) -------
    def estimate(self, scene, v, sampler, active, depth, dir_pdf):
        """NEE at vertex ``v`` of an unrolled walk (module docstring): (radiance estimate without beta, rays
        traced per lane: the walk counts them, ``lanes=True``, :mod:`dyngi.rays`). Keeps the vertex's NEE mask
        and estimate in the per-vertex records (the next vertex's MIS weight, the CDQ's record)."""
        u1, u2, u_o = sampler.next_1d(), sampler.next_2d(), sampler.next_2d()
        active = mi.Bool(active) & v.active
        tris, sel, balance = self.tris, self.sampler, self._mis
        ctx = mi.BSDFContext()
        L = mi.Color3f(0.0)
        n_rays = mi.UInt32(0)
        si, n, real_bsdf, albedo, p = v.si, v.n, v.bsdf, v.albedo, v.si.p
        if tris.count:
            k, pmf = sel.sample(p, n, u1, active, p_prev=p, **self._lk(v.leaf))
            ok = active & (k != INVALID) & (pmf > 0.0)
            pl, nl, pdf_a = tris.sample_point(k, u2, ok)
            d = pl - p
            dist2 = dr.squared_norm(d)
            wi = d * dr.rsqrt(dist2)
            cos_l = -dr.dot(nl, wi)
            cos_r = dr.dot(n, wi)
            ok &= (cos_l > 0.0) & (dist2 > 0.0) & (pdf_a > 0.0)
            pdf_l = pmf * pdf_a * dist2 / cos_l
            if real_bsdf is not None:
                f, _ = real_bsdf.eval_pdf(ctx, si, si.to_local(wi), ok)
                f = mi.Color3f(f)
            else:
                f = albedo * dr.maximum(cos_r, 0.0) * dr.inv_pi
                ok &= cos_r > 0.0
            ok &= dr.max(f) > 0.0
            pdf_b = dir_pdf(wi, ok)
            vis = ok & ~rays.occluded(scene, si.spawn_ray_to(pl), ok, stage="trace", lanes=True)
            n_rays += mi.UInt32(ok)
            Le = tris.gather_radiance(k, vis)
            w = balance(pdf_l, pdf_b)
            L += dr.select(vis, f * Le * (w / pdf_l), 0.0)
            sel.record(p, n, k, vis, active & (k != INVALID), **self._lk(self.vertices.vx[depth]["leaf"]))
        if self.others is not None and self.others.count:
            ds, em_w, traced, n_o = self.others.sample_traced(scene, si, u_o, active, receiver=None, stage="trace",
                                                              lanes=True)
            if real_bsdf is not None:
                f, _ = real_bsdf.eval_pdf(ctx, si, si.to_local(ds.d), traced)
                f = mi.Color3f(f)
            else:
                f = albedo * dr.maximum(dr.dot(n, ds.d), 0.0) * dr.inv_pi
            pdf_b = dir_pdf(ds.d, traced)
            w = dr.select(ds.delta, 1.0, balance(ds.pdf, pdf_b))
            L += dr.select(traced, f * em_w * w, 0.0)
            n_rays += n_o
        self.vertices.vx[depth].update(nee_on=active, L_nee=L)
        return L, n_rays

    def emitted(self, scene, si, ray, prev_si, prev_pdf, prev_delta, depth, active):
        """MIS-weighted emission at vertex ``depth`` of an unrolled walk reached from the previous vertex
        (module docstring): Mitsuba's emitter at vertex 0; after it the table's radiance of a triangle hit (or
        Mitsuba's emitter of another), weighted against the previous vertex's NEE. Keeps the environment's
        part in the per-vertex records (the CDQ learns it, NEE does not sample it)."""
        if depth == 0:
            return mi.Color3f(si.emitter(scene).eval(si))     # seen directly: Mitsuba's own emitter
        rec = self.vertices
        prev = rec.vx[depth - 1]
        prev_n, prev_leaf = prev["v"].n, prev["v"].leaf
        prev_delta = mi.Bool(prev_delta) | ~prev["nee_on"]    # no NEE there: the light pdf is 0, weight 1
        tris, balance = self.tris, self._mis
        k = tris.light_id(si, active) if tris.count else mi.UInt32(INVALID)
        is_tri = active & (k != INVALID)
        Le = mi.Color3f(0.0)
        if tris.count:
            nl = dr.gather(mi.Normal3f, tris.normal, k, is_tri)
            cos_l = -dr.dot(nl, ray.d)
            front = is_tri & (cos_l > 0.0)
            area = dr.gather(mi.Float, tris.area, k, front)
            pmf = self.sampler.pmf(prev_si.p, prev_n, k, front & ~prev_delta, p_prev=prev_si.p, **self._lk(prev_leaf))
            pdf_l = pmf * dr.square(si.t) / (area * cos_l)
            w = dr.select(prev_delta, 1.0, balance(prev_pdf, pdf_l))
            Le += dr.select(front, tris.gather_radiance(k, front) * w, 0.0)
            if self.record_hits:   # a BSDF-sampled ray that reached a light's front: a visible light sample
                self.sampler.record(prev_si.p, prev_n, k, front, front & ~prev_delta, **self._lk(prev_leaf))
        other = active & ~is_tri
        em = si.emitter(scene, other)
        ds = mi.DirectionSample3f(scene, si, prev_si)
        pdf_o = mi.Float(0.0)
        if self.others is not None and self.others.count:
            pdf_o = self.others.pdf(scene, prev_si, ds, other & ~prev_delta)
        w_o = dr.select(prev_delta, 1.0, balance(prev_pdf, pdf_o))
        Le_o = dr.select(other, mi.Color3f(em.eval(si, other)) * w_o, 0.0)
        rec.env[depth] = dr.select(~si.is_valid(), Le_o, 0.0)
        return Le + Le_o


class _Numbers:
    """The two draws of :meth:`LightNEE.sample_walk`: the shading's 2D number, then a 1D one from ``stream``
    (the strategies' interface hands over one 2D number per sample)."""

    def __init__(self, u2, stream):
        self.u2, self.stream = u2, stream

    def next_2d(self):
        return self.u2

    def next_1d(self):
        return self.stream.next_1d()


class TracedNEE:
    """A :class:`LightNEE` as a light-sampling strategy with ``sample_traced`` (the interface of
    :func:`dyngi.lights.emitter_sampling.sample_traced`): one NEE sample of the light sampler per call, its point
    from the caller's 2D number and its light-selection number from ``numbers.next_1d()`` (a per-lane
    sampler: the caller's own, or a stream of its own, :meth:`stream`). The same estimator as the path
    walk's NEE (``path:lights=...``, pbrt-v4's ``SampleLd``): unbiased for every sampler whose pmf is that of
    its ``sample``. ``ds.emitter`` is set, so that a caller can route the sample by emitter (the probe
    techniques' :meth:`~dyngi.probes.trace.LightRouting.nee_weight`).

    ``record``: a learning sampler records each call's samples as path vertex 0 of a walk of its own
    (:meth:`LightNEE.begin_walk`; handed over in :meth:`LightNEE.end_frame`); False: nothing is recorded.
    With a ``receiver`` normal, samples below it get weight 0 (their shadow ray is still traced: the
    direction is known only after the sample).
    """

    def __init__(self, nee: LightNEE, numbers, record: bool = False):
        self.nee = nee
        self.numbers = numbers
        self.record = record

    @classmethod
    def stream(cls, nee: LightNEE, n: int, seed: int, frame: int, stream: int = PRIMARY_NEE_STREAM,
               record: bool = False) -> "TracedNEE":
        """The adapter with light-selection numbers from stream ``stream`` of ``(seed, frame)`` for ``n``
        lanes (:func:`~dyngi.sampling.rng.make_sampler`: the per-frame seed is opaque, a new frame compiles
        nothing)."""
        return cls(nee, make_sampler(n, seed, frame, stream), record)

    def sample_traced(self, scene, si, u2, active, receiver=None, *, stage: str = "shadow", lanes: bool = False):
        depth = None
        if self.record and self.nee.entry.learns:
            self.nee.begin_walk(dr.width(u2))
            depth = 0
        out = self.nee.sample_walk(scene, si, _Numbers(u2, self.numbers), active, depth, emitters=True, stage=stage,
                                   lanes=lanes)
        ds, w = out[0], out[1]
        if receiver is not None:
            w = dr.select(dr.dot(receiver, ds.d) > 0.0, w, 0.0)
        return (ds, w) + tuple(out[2:])


def share_octrees(lights, directions, records: int, leaf_samples: int, leaf_scaling: bool) -> tuple:
    """Build the octree of each octree-based strategy of a path (a learning light sampler, :class:`LightNEE`
    whose entry needs one; a CDQ direction sampler) with ``nee-pt``'s threshold rule for ``records`` placed
    vertices per frame (:func:`~dyngi.directions.octree.octree_rule`: the paper's 4096 / 2048 from 8 x 4096
    records, scaled below unless ``leaf_scaling`` is false) and hand it over; returns (light strategy's or None,
    direction strategy's or None). ``path`` and ``restir-pt`` call it at their first frame."""
    rule = octree_rule(leaf_scaling)
    built = []
    for s, uses in ((lights, isinstance(lights, LightNEE) and lights.entry.needs_octree),
                    (directions, directions is not None and directions.kind == "cdq")):
        oc = make_octree(s.bounds, records, leaf_samples, rule=rule) if uses else None
        if oc is not None:
            s.share_octree(oc)
        built.append(oc)
    return tuple(built)


def octree_params(placed: str) -> dict:
    """The ``leaf_samples`` and ``leaf_scaling`` parameters of a path technique whose ``lights=vlc`` and
    ``directions=cdq`` share nee-pt's octree rule (:func:`share_octrees`); ``placed`` says how many vertices a
    frame places (e.g. "2 per path per spp")."""
    return {
        "leaf_samples": Param(0, "octree split threshold per leaf of lights=vlc and directions=cdq raised to this "
                              "(collapse: half); 0 = the thresholds of leaf_scaling", min=0, max=1 << 20),
        "leaf_scaling": Param(True, "octree thresholds of lights=vlc and directions=cdq (nee-pt's rule): the VLC "
                              "paper's 4096 / 2048 records per leaf (Sec. 7) wherever the frame places >= 8 x 4096 "
                              f"vertices ({placed}); below that (ours) scaled down to records/8 / records/16 so "
                              "that the tree still adapts (directions.octree.paper_thresholds); false = the "
                              "paper's at every resolution", ours=True, paper=False),
    }
