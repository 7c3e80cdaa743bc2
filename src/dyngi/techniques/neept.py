"""The VLC paper's evaluation path tracer (technique ``nee-pt``; Dittebrandt et al., Sec. 7).

Each path traces five rays (Sec. 7): the primary ray; at the primary hit NEE (one
shadow ray) and one indirect ray; at the secondary hit NEE and one indirect ray;
at the tertiary hit only emission is collected. As Mitsuba counts vertices this is
``max_depth = 3`` (the emission reached by the second indirect ray is the third
vertex): compare against ``dyngi compare --ref-depth 3``. After the primary hit
every surface is diffuse with the diffuse-lobe albedo of its BSDF
(:func:`dyngi.sampling.diffuse.diffuse_albedo`: a conductor is black, not its
``eval_diffuse_reflectance``) and every emitter triangle a uniform emitter sampled
by plain area sampling (Sec. 7); the primary hit keeps its real BSDF (its
emission is Mitsuba's own). Every NEE sample and every BSDF-sampled emission are
combined by the balance heuristic with the light selector's exact ``pmf``.

The path is the one path walk (:func:`dyngi.transport.path_walk.walk`, unrolled over its three vertices,
no Russian roulette) composed with :class:`NeePTWalk`: its vertex hook (real BSDF or diffuse stand-in,
octree leaves), its light strategy (the NEE and emission estimators above) and its direction strategy. A
path goes on after a sampled direction of zero weight (e.g. a CDQ direction below the surface): the VLC and
the CDQ learn at the vertices it reaches, and each path still traces its five rays (Sec. 7).

Lights
------
A light is an emitter triangle (:mod:`dyngi.lights.emitter_table`). The
``lights`` parameter chooses how NEE selects one, through the one light-sampler interface
(:mod:`dyngi.lights`; any registered sampler, e.g. ``power``):
``uniform`` (pmf 1/L), ``lighttree`` (light BVH, H2), ``sll`` (static light
lists from a conservative PVS, :mod:`dyngi.lights.pvs`, the paper's), ``sll-oracle`` (ray-cast
per-cell visible lists, an oracle baseline, :mod:`dyngi.lights.sll`), ``vlc`` (Visibility Light Cache, :mod:`dyngi.lights.vlc`, default).
Emitters that are not triangles are handled the same way in every variant: delta
lights (point, spot, directional) and analytic area emitters (sphere, disk) by a
second NEE sample through Mitsuba's emitter sampling restricted to them (a sixth
and seventh ray only in scenes that have such emitters), the environment by BSDF
sampling only (the paper's NEE ignores it).

Directions
----------
Through the direction-sampler interface (:mod:`dyngi.directions`).
``directions=bsdf``: the indirect rays sample the (real at the primary hit,
cosine at the secondary) BSDF. ``directions=cdq``: with probability 0.5 from the
CDQ of the octree leaf (:mod:`dyngi.directions.cdq`, issue 18) and 0.5 from the
BSDF, with the mixture pdf (one-sample balance heuristic); NEE/BSDF-emission MIS
uses the mixture pdf for the BSDF side. At a primary hit whose BSDF has a delta
lobe the CDQ is not used (its mixture pdf would be undefined).

Octree (Sec. 6)
---------------
With ``lights=vlc`` or ``directions=cdq`` an :class:`~dyngi.directions.octree.AdaptiveOctree`
over the scene bounds is created; every path vertex (hits 1-3) is placed in it
and it adapts at the end of each frame. Thresholds: the paper's 4096 / 2048 at
1080p scaled by the number of placed vertices per frame (3 per path per spp
here), never below 512 / 256 (issue 17 item 2; ``octree.scaled_thresholds``).
Sampling uses the primary hit's previous-frame position (Sec. 6.3): on animated meshes
(``scene.meta.dynamic_shapes``) :class:`~dyngi.directions.motion.MotionVectors` gives it (the same surface
point one frame earlier), and ``octree.lookup_pair`` finds the sampling leaf (previous position) and the
placing leaf (current position) in one traversal; the VLC and the CDQ sample with the former and record
into the latter. Secondary hits use their current position (our choice: no G-buffer there).

``FrameResult.indirect``: the same paths without the emission seen at the
primary vertex, the emission reached by its indirect ray and its NEE (light that
reflected at least once before the primary vertex, vertices >= 3: the battery's
and the indirect reference's definition), i.e. NEE at the secondary hit plus the
emission at the tertiary hit.

Stats: ``ms`` per stage (``preprocess``: VLC construction + exploration table +
CDQ carry-over; ``trace``: the path-tracing kernel; ``cdq adapt``: CDQ migration;
``adapt``: octree adaptation), ``rays``, the selector's (``selector``) and the
octree's (``octree``) stats, and the CDQ's ``cdq_*`` keys.

CDQ record (directions=cdq): at the primary and the secondary hit, the luminance of
the indirect sample ``f cos L_i / p_mix`` without the camera-path prefix, where
``L_i`` excludes the emission of lights hit by the ray (NEE's job, Sec. 5.1) but
includes the environment and everything reflected at the next vertex.

VLC extensions (ours, off by default; :mod:`dyngi.lights.vlc`): ``record_hits``
(the paper records NEE samples only): an indirect ray that reaches the front of an
emitter triangle is also recorded as a visible sample of that light at its origin
(a free proof of visibility); ``memory`` (1 = the paper): a light stays in its
leaf's cache for that many frames after its last visible sample.
``explore_weights``: the exploration blend (energy, change, camera distance;
default 0.6, 0.2, 0.2, our choice: the paper gives no weights).
``explorer=lighttree`` (ours; default ``global``, the paper's alias table): the VLC explores with the
light tree of ``lights=lighttree`` (exact mixture pmf; warehouse-lights 160x90: MSE 0.00477 -> 0.00174,
:mod:`dyngi.lights.vlc`). ``leaf_samples`` (0 = the scaled paper thresholds): octree split threshold
raised to this many samples per leaf, collapse half of it (an ablation knob; 2048 / 4096 did not lower
the VLC's error on warehouse-lights at 160x90: 0.00462 / 0.00472 vs 0.00477).
The selectors' importance is the diffuse irradiance above the (side-corrected)
shading normal, so behind a rough *transmissive* primary BSDF lights are reached by
exploration / BSDF sampling only (unbiased, noisier; LTC-like glossy importance is
not implemented).
"""
from __future__ import annotations

import numpy as np

from .. import directions as direction_samplers
from .. import lights as light_samplers
from .. import rays as ray_ledger
from ..backend import dr, mi
from ..color import luminance
from ..directions.base import Vertex
from ..directions.mixture import CDQ_FRACTION  # noqa: F401  (re-exported: Sec. 7's "brdf fraction of 50%")
from ..directions.motion import MotionVectors
from ..directions.octree import make_octree, octree_bounds
from ..errors import DyngiError
from ..lights.base import INVALID, EmitterTable, FrameCtx
from ..lights.emitter_sampling import EmitterSubsetSampling
from ..sampling.diffuse import diffuse_albedo
from ..sampling.rng import make_sampler, mix_seed
from ..scene.surface import shading_normal
from ..transport.accumulate import ProgressiveMean
from ..transport.mis import mis_weight
from ..transport.path_walk import walk
from .base import Frame, FrameResult, Param, StageTimer, Technique, register, to_image

MAX_DEPTH = 3
"""Mitsuba's vertex count of nee-pt's paths (emission at the tertiary hit): compare with --ref-depth 3."""


def _balance(a, b):
    """Balance heuristic (Veach 1997, Eq. 9.13) of the one MIS module."""
    return mis_weight(a, b, power=False)


def _weights(text: str) -> tuple:
    """'energy,change,distance' exploration blend weights (Sec. 4.3) -> 3 floats >= 0, not all 0."""
    try:
        w = tuple(float(x) for x in str(text).split(","))
    except ValueError:
        w = ()
    if len(w) != 3 or min(w) < 0 or sum(w) <= 0 or not all(np.isfinite(w)):
        raise DyngiError(f"nee-pt: explore_weights must be three non-negative numbers 'energy,change,distance' "
                         f"(not all 0), got '{text}'")
    return w


def _make_selector(kind: str, tris, mi_scene, bounds, octree, params, dynamic_shapes=()):
    # dynamic_shapes: the SLL's PVS must not count moving occluders (a PVS knows static geometry only)
    opts = dict(octree=octree, dynamic_shapes=list(dynamic_shapes), exploration=params["exploration"],
                capacity=params["capacity"],
                hysteresis=params["hysteresis"], merge_neighbours=params["merge_neighbours"], memory=params["memory"],
                explore_weights=_weights(params["explore_weights"]), explorer=params["explorer"])
    # the one light-sampler interface (dyngi.lights): each sampler takes the options it declares
    accepted = light_samplers.options(kind)
    return light_samplers.make(kind, tris, mi_scene=mi_scene, bounds=bounds,
                               **{k: v for k, v in opts.items() if k in accepted})


def _diffuse_stand_in(si, bsdf, active):
    """(albedo, side-corrected shading normal) of the diffuse stand-in after the primary hit (Sec. 7)."""
    cos_wi = mi.Frame3f.cos_theta(si.wi)
    back_ok = mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide)
    a = diffuse_albedo(bsdf, si, active)
    a = dr.select((cos_wi > 0.0) | back_ok, a, 0.0)
    return a, shading_normal(si)


class NeePTWalk:
    """nee-pt's part of the one path walk (:func:`dyngi.transport.path_walk.walk`, unrolled over the three
    vertices of Sec. 7): its vertex hook, its light strategy (own NEE and emission estimators) and its
    direction strategy, over the technique's selector, emitter table, octree and CDQ. One per frame: it keeps
    each vertex's values (normal, leaves, NEE mask and estimate, sampled direction, environment radiance) for
    the next vertex's MIS weight and for the CDQ record at the end of the walk.

    * vertex 0 (primary hit): its real BSDF; the octree leaf pair of Sec. 6.3 (sampling: the previous
      position's leaf, placing: the current one); vertex 1: the diffuse stand-in, its leaf; vertex 2:
      emission only, placed in the octree.
    * NEE (:meth:`estimate`): one triangle light by the selector (``pmf``), a point on it by area sampling,
      f-gated shadow ray, recorded in the selector's placing leaf; plus one Mitsuba sample of the other
      emitters; both weighted by the balance heuristic against the direction sampler's pdf.
    * emission (:meth:`emitted`): Mitsuba's emitter at vertex 0; after it the table's radiance of a triangle
      hit (or Mitsuba's emitter of another), balance-weighted against the light pdf of the previous vertex's
      NEE (weight 1 where it did none).
    """

    def __init__(self, tech):
        self.t = tech
        self.vx: dict = {}
        self.env: dict = {}

    def begin_walk(self, n: int) -> None:
        """Before the walk (called once as its light and once as its direction strategy): no vertex yet."""
        self.vx, self.env = {}, {}

    def _lk(self, leaf):
        """``leaf=`` keyword for selectors that accept an already looked-up octree leaf (the VLC)."""
        sel = self.t.selector
        return {"leaf": leaf} if (leaf is not None and getattr(sel, "accepts_leaf", False)) else {}

    # -- the vertex hook -------------------------------------------------------------------------
    def vertex(self, c):
        """The walk's vertex hook: the :class:`Vertex` NEE and the direction sampler see at vertex ``c.depth``
        (None at the tertiary hit), its octree placement (class docstring)."""
        t, oc, si, valid = self.t, self.t.octree, c.si, c.active
        if c.depth >= MAX_DEPTH - 1:              # the tertiary hit: emission only
            if oc is not None:
                oc.place(si.p, valid)
            return None
        if c.depth == 0:                          # the primary hit keeps its real BSDF
            n, albedo, bsdf, on = shading_normal(si), None, c.bsdf, valid
        else:                                     # after it: the diffuse stand-in
            albedo, n = _diffuse_stand_in(si, c.bsdf, valid)
            bsdf, on = None, valid & (dr.max(albedo) > 0.0)
        leaf = leaf_s = None
        if oc is not None:
            if c.depth == 0 and t.motion is not None and t.motion.active:   # Sec. 6.3: previous / current
                leaf_s, leaf = oc.lookup_pair(t.motion.previous(si, valid), si.p, valid)
            else:
                leaf = leaf_s = oc.lookup(si.p, valid)
            oc.place_leaf(leaf, valid)
        v = Vertex(si, n, bsdf, albedo, leaf_s, on)
        self.vx[c.depth] = {"v": v, "leaf": leaf, "nee_on": mi.Bool(False), "L_nee": mi.Color3f(0.0)}
        return v

    # -- the light strategy ----------------------------------------------------------------------
    def estimate(self, scene, v, sampler, active, depth, dir_pdf):
        """NEE at a vertex: (radiance estimate without beta, rays traced per lane: the walk counts them,
        ``lanes=True``, :mod:`dyngi.rays`); class docstring."""
        u1, u2, u_o = sampler.next_1d(), sampler.next_2d(), sampler.next_2d()
        active = mi.Bool(active) & v.active
        t = self.t
        tris, sel = t.tris, t.selector
        ctx = mi.BSDFContext()
        L = mi.Color3f(0.0)
        rays = mi.UInt32(0)
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
            vis = ok & ~ray_ledger.occluded(scene, si.spawn_ray_to(pl), ok, stage="trace", lanes=True)
            rays += mi.UInt32(ok)
            Le = tris.gather_radiance(k, vis)
            w = _balance(pdf_l, pdf_b)
            L += dr.select(vis, f * Le * (w / pdf_l), 0.0)
            sel.record(p, n, k, vis, active & (k != INVALID), **self._lk(self.vx[depth]["leaf"]))
        if t.others is not None and t.others.count:
            ds, em_w, traced, n_o = t.others.sample_traced(scene, si, u_o, active, receiver=None, stage="trace",
                                                           lanes=True)
            if real_bsdf is not None:
                f, _ = real_bsdf.eval_pdf(ctx, si, si.to_local(ds.d), traced)
                f = mi.Color3f(f)
            else:
                f = albedo * dr.maximum(dr.dot(n, ds.d), 0.0) * dr.inv_pi
            pdf_b = dir_pdf(ds.d, traced)
            w = dr.select(ds.delta, 1.0, _balance(ds.pdf, pdf_b))
            L += dr.select(traced, f * em_w * w, 0.0)
            rays += n_o
        self.vx[depth].update(nee_on=active, L_nee=L)
        return L, rays

    def emitted(self, scene, si, ray, prev_si, prev_pdf, prev_delta, depth, active):
        """MIS-weighted emission at vertex ``depth`` reached from the previous vertex (class docstring); records
        the environment's part (the CDQ learns it, NEE does not sample it)."""
        if depth == 0:
            return mi.Color3f(si.emitter(scene).eval(si))     # seen directly: Mitsuba's own emitter
        prev = self.vx[depth - 1]
        prev_n, prev_leaf = prev["v"].n, prev["v"].leaf
        prev_delta = mi.Bool(prev_delta) | ~prev["nee_on"]    # no NEE there: the light pdf is 0, weight 1
        t, tris = self.t, self.t.tris
        k = tris.light_id(si, active) if tris.count else mi.UInt32(INVALID)
        is_tri = active & (k != INVALID)
        Le = mi.Color3f(0.0)
        if tris.count:
            nl = dr.gather(mi.Normal3f, tris.normal, k, is_tri)
            cos_l = -dr.dot(nl, ray.d)
            front = is_tri & (cos_l > 0.0)
            area = dr.gather(mi.Float, tris.area, k, front)
            pmf = t.selector.pmf(prev_si.p, prev_n, k, front & ~prev_delta, p_prev=prev_si.p, **self._lk(prev_leaf))
            pdf_l = pmf * dr.square(si.t) / (area * cos_l)
            w = dr.select(prev_delta, 1.0, _balance(prev_pdf, pdf_l))
            Le += dr.select(front, tris.gather_radiance(k, front) * w, 0.0)
            if t._record_hits:   # a BSDF-sampled ray that reached a light's front: a visible light sample
                t.selector.record(prev_si.p, prev_n, k, front, front & ~prev_delta, **self._lk(prev_leaf))
        other = active & ~is_tri
        em = si.emitter(scene, other)
        ds = mi.DirectionSample3f(scene, si, prev_si)
        pdf_o = mi.Float(0.0)
        if t.others is not None and t.others.count:
            pdf_o = t.others.pdf(scene, prev_si, ds, other & ~prev_delta)
        w_o = dr.select(prev_delta, 1.0, _balance(prev_pdf, pdf_o))
        Le_o = dr.select(other, mi.Color3f(em.eval(si, other)) * w_o, 0.0)
        self.env[depth] = dr.select(~si.is_valid(), Le_o, 0.0)
        return Le + Le_o

    # -- the direction strategy ------------------------------------------------------------------
    def sample(self, v, sampler, active):
        """The indirect direction through the direction sampler (:mod:`dyngi.directions`); draws 1D, 1D, 2D."""
        u_sel = sampler.next_1d()
        u1 = sampler.next_1d()
        u2 = sampler.next_2d()
        return self.t.directions.sample(v, u_sel, u1, u2, mi.Bool(active) & v.active)

    def pdf(self, v, wo, active):
        """The direction sampler's density of ``wo`` (the BSDF side of the MIS weights)."""
        return self.t.directions.pdf(v, wo, active)

    def record(self, v, d, L, beta, depth) -> None:
        """Keep vertex ``depth``'s sampled direction for the CDQ record (:meth:`end_walk`)."""
        self.vx[depth]["d"] = d

    def end_walk(self, L) -> None:
        """CDQ record (directions=cdq): at vertices 0 and 1, the luminance of the indirect sample
        ``f cos L_i / p_mix`` without the camera-path prefix, ``L_i`` without the emission of lights (NEE's
        job, Sec. 5.1) but with the environment (module docstring)."""
        cdq = self.t.cdq
        if cdq is None:
            return
        inner = self.env[MAX_DEPTH - 1]      # radiance arriving along vertex d's sample, from the far end back
        recs = []
        for d in range(MAX_DEPTH - 2, -1, -1):
            x = self.vx[d]
            val = x["d"].weight * inner
            recs.append((x["leaf"], x["d"].wo, luminance(val), x["d"].ok))
            if d > 0:
                inner = self.env[d] + x["L_nee"] + val
        for leaf, wo, lum, ok in reversed(recs):
            cdq.record(leaf, wo, lum, ok)


@register
class NeePT(Technique):
    """Five-ray NEE path tracer of the VLC paper (Sec. 7) with pluggable light selection and directions."""

    name = "nee-pt"
    description = ("VLC paper's evaluation path tracer: 5 rays/path, diffuse after the primary hit, "
                   "NEE by lights=uniform|lighttree|sll|sll-oracle|vlc, directions=bsdf|cdq, balance MIS")
    HAS_INDIRECT = True
    REFERENCE_DEPTH = 3   # compare renders its reference at this depth without --ref-depth (Sec. 7's 5-ray path)
    PARAMS = {
        "lights": Param("vlc", "NEE light sampler (dyngi.lights; sll: the paper's PVS lists; sll-oracle: ray-cast "
                        "lists, an oracle baseline)", choices=light_samplers.names()),
        "directions": Param("bsdf", "indirect-ray sampling (dyngi.directions)", choices=direction_samplers.names()),
        "spp": Param(1, "samples per pixel per frame", min=1, max=1 << 12),
        "seed": Param(0, "seed mixed with the frame's seed", min=0),
        "exploration": Param(0.1, "VLC exploration fraction (Sec. 4.3)", min=1e-3, max=1.0),
        "capacity": Param(32, "VLC bucket capacity (Sec. 4.2)", min=1, max=256),
        "hysteresis": Param(0.75, "VLC capacity factor when the bucket count drops (Sec. 4.2)", min=0.05, max=1.0),
        "merge_neighbours": Param(True, "VLC: merge the face neighbours' caches (Sec. 4.1)"),
        "cdq_bits": Param(128, "CDQ bit count (directions=cdq)", choices=(32, 64, 96, 128)),
        "cdq_stability": Param(0.1, "CDQ migration stability factor (Sec. 5.1)", min=1e-3, max=1.0),
        "cdq_fraction": Param(0.5, "probability of drawing an indirect direction from the CDQ in the one-sample "
                              "MIS mixture with the BSDF (directions=cdq; 0.5: the paper's Sec. 7 'brdf fraction of 50%')",
                              min=0.0, max=1.0),
        "cdq_memory": Param(0.0, "CDQ statistics memory per frame (0 = paper: last frame only)", min=0.0, max=0.99),
        "explorer": Param("global", "VLC exploration strategy: the paper's global alias table, or a light tree "
                          "(our extension)", choices=("global", "lighttree")),
        "explore_weights": Param("0.6,0.2,0.2", "VLC exploration blend 'energy,change,camera-distance' (Sec. 4.3; "
                                 "ours: the paper blends the three heuristics with 'configurable weights' and gives "
                                 "none)", ours=True),
        "memory": Param(1, "VLC: frames a visible light stays in its leaf's cache (1: the paper's last frame only)",
                        min=1, max=64),
        "record_hits": Param(False, "VLC: also learn the lights that indirect rays hit (our extension)"),
        "leaf_samples": Param(0, "octree split threshold per leaf (collapse: half); 0 = ours: the paper's 4096 / "
                              "2048 at 1080p (Sec. 7) scaled to the placed vertices per frame and floored at 512 / "
                              "256 (directions.octree.MIN_SPLIT / MIN_COLLAPSE: fewer samples make a meaningless "
                              "VLC); 4096 = the paper's", min=0, max=1 << 20, ours=True, paper=4096),
        "progressive": Param(False, "accumulate over frames while the scene is static"),
    }

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        # nee-pt's depth is fixed (Sec. 7); exposed for the battery's depth-limited furnace value
        self.params["max_depth"] = MAX_DEPTH
        ms = scene.mi_scene
        self.tris = EmitterTable(ms)
        tri_shapes = {sid for sid, _, _ in self.tris.shape_slices()}
        self._lights_move = bool(tri_shapes & set(scene.meta.dynamic_shapes))
        self._tri_emitters = [sh.emitter() for sh in self.tris._shapes]   # kept alive: compared by identity

        def keep(e):   # NEE through Mitsuba for delta lights and non-triangle area emitters; never the environment
            if mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) and not mi.has_flag(
                    e.flags(), mi.EmitterFlags.DeltaDirection):
                return False
            return not any(e is x for x in self._tri_emitters)

        self.others = EmitterSubsetSampling(ms, keep) if any(keep(e) for e in ms.emitters()) else None
        self.bounds = octree_bounds(scene)    # a flat scene's zero extent grown (directions.octree)
        p = self.params
        self.octree = None
        self.cdq = None
        self.motion = None
        self._res = None
        self.selector = None
        _weights(p["explore_weights"])          # bad values fail here, not at the first frame
        if p["directions"] == "cdq":
            try:
                from ..directions.cdq import CDQDirections  # noqa: F401
            except ImportError as e:
                raise DyngiError(f"nee-pt: directions=cdq needs dyngi.directions.cdq ({e}); valid values: bsdf, cdq") \
                    from None
        self.accum = ProgressiveMean()

    # -- per-resolution setup ------------------------------------------------------------------
    def _setup(self, res, spp):
        p = self.params
        need_octree = p["lights"] == "vlc" or p["directions"] == "cdq"
        if need_octree:
            self.octree = make_octree(self.bounds, MAX_DEPTH * res[0] * res[1] * spp, p["leaf_samples"])
            if self.scene.meta.dynamic_shapes:     # motion vectors for Sec. 6.3's previous/current lookup
                self.motion = MotionVectors(self.scene.mi_scene, self.scene.meta.dynamic_shapes)
        if p["directions"] == "cdq":
            from ..directions.cdq import CDQDirections
            self.cdq = CDQDirections(self.octree, bits=p["cdq_bits"], stability=p["cdq_stability"],
                                     memory=p["cdq_memory"])
        opts = {"fraction": float(p["cdq_fraction"])} if p["directions"] == "cdq" else {}
        self.directions = direction_samplers.make(p["directions"], guide=self.cdq, **opts)
        self.selector = _make_selector(p["lights"], self.tris, self.scene.mi_scene, self.bounds, self.octree, p,
                                       self.scene.meta.dynamic_shapes)
        self._record_hits = p["record_hits"] and p["lights"] == "vlc"
        self._res = (tuple(res), spp)

    def _trace(self, frame, spp):
        w, h = frame.res
        n = w * h * spp
        seed = mix_seed(self.params["seed"], frame.seed, 0x4E45)
        sampler = make_sampler(n, seed, frame.index)
        idx = dr.arange(mi.UInt32, n)
        pix = idx // dr.opaque(mi.UInt32, spp) if spp > 1 else idx
        ray = frame.camera.sample_rays(frame.res, pix, sampler.next_2d())
        # -- the one path walk over Sec. 7's three vertices, unrolled (each vertex its own BSDF and records) --
        nw = NeePTWalk(self)
        r = walk(self.scene.mi_scene, sampler, ray, mi.Bool(True), MAX_DEPTH, -1, lights=nw, directions=nw,
                 vertex=nw.vertex, power_heuristic=False, split=True, unroll=True, stop_at_zero=False, lanes=True)
        L = dr.select(dr.isfinite(luminance(r.L)), r.L, 0.0)
        L_ind = dr.select(dr.isfinite(luminance(r.L_ind)), r.L_ind, 0.0)
        pending = list(getattr(self.selector, "pending", lambda: [])())
        # the rays' sum is a kernel of its own, which traces the paths a second time: evaluating the per-lane
        # counts with the image in one kernel made Dr.Jit 1.5's LLVM backend abort ("invalid redefinition of
        # function")
        rays_total = dr.sum(r.n_rays)
        dr.eval(L, L_ind, rays_total, *pending)
        ray_ledger.add("trace", rays_total)     # the walk's rays (lanes=True: counted here, dyngi.rays)
        if spp > 1:
            inv = dr.opaque(mi.Float, 1.0 / spp)
            L = dr.block_reduce(dr.ReduceOp.Add, L, spp) * inv
            L_ind = dr.block_reduce(dr.ReduceOp.Add, L_ind, spp) * inv
        return L, L_ind, rays_total

    def step(self, frame: Frame) -> FrameResult:
        p = self.params
        spp = p["spp"]
        t = StageTimer()
        if self._res != (tuple(frame.res), spp):
            self._setup(frame.res, spp)
        if self._lights_move and frame.index > 0:
            self.tris.refresh(self.scene.mi_scene)
        cam = np.asarray(frame.camera.origin, np.float64)
        ctx = FrameCtx(self.scene.mi_scene, self.tris, frame.index, frame.time, self.octree, self.bounds, cam)
        with t.stage("preprocess"):
            if self.motion is not None:
                self.motion.advance()
            if self.cdq is not None:
                self.cdq.begin_frame(ctx)
            self.selector.begin_frame(ctx)
        with t.stage("trace"):
            L, L_ind, rays = self._trace(frame, spp)
        t.add_rays("trace", rays)
        if self.cdq is not None:
            with t.stage("cdq adapt"):
                self.cdq.end_frame()
        with t.stage("adapt"):
            self.selector.end_frame()
            if self.octree is not None:
                self.octree.adapt()
        self.accum.add(L, L_ind, samples=spp, accumulate=p["progressive"] and frame.static)
        stats = t.as_dict()
        stats["spp"] = spp
        stats["lights"] = self.tris.count
        stats["selector"] = self.selector.stats()
        if self.octree is not None:
            stats["octree"] = self.octree.stats()
        if self.cdq is not None:
            stats.update(self.cdq.stats())
        return FrameResult(image=to_image(self.accum.mean, frame.res),
                           indirect=to_image(self.accum.mean_ind, frame.res),
                           stats=stats)
