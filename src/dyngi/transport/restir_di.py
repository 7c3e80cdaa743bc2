"""ReSTIR DI as a component (Bitterli et al. 2020, "Spatiotemporal reservoir resampling"): the stages
every technique that resamples direct light at the primary vertex holds (``restir-pt``, the DDGI
Resampling family; issue 24). The target is a parameter of each reuse stage.

1. **G-buffer** (:mod:`dyngi.transport.gbuffer`): one jittered primary ray per pixel, reprojection by
   each shape's own rigid motion, disocclusion mask (:meth:`ReSTIRDI.gbuffer`).
2. **Initial candidates** (Bitterli Alg. 3, :func:`initial_candidates`): M light samples per pixel from
   :class:`~dyngi.lights.candidates.EmitterCandidates` (area lights in area measure, environment in
   solid angle, delta lights as point masses) streamed through a reservoir with the default target
   ``p_hat(y) = lum(Lg(y)) * cos+(n, wi)`` (:func:`target`; ``|cos|`` on transmissive surfaces): the
   unshadowed contribution without the BSDF, so any neighbour's or the previous frame's target is
   exact and needs only a G-buffer's position and normal. **Visibility** (``visibility_reuse``; the
   component's default ``'none'``, ``restir-pt``'s and ``ddgi-resampling``'s ``'unbiased'``;
   measured: docs/techniques/restir-pt.md, docs/techniques/ddgi-resampling.md):

   * ``'unbiased'`` (**unbiased**; Bitterli et al.'s unbiased variant, a generalized-RIS partition of unity
     over the true supports): the candidate's shadow ray of ``'candidate'``, and in every reuse stage the
     MIS / 1/Z weights over ``p_hat_j(y) V_j(y)`` of the final sample at each domain (this pixel, each
     accepted neighbour, the previous pixel): one shadow ray per domain other than the one ``y`` came from
     (visible there: every stored reservoir holds a sample visible from its own pixel, or ``W = 0``). The
     final shading then needs no ray. Rays per pixel: 1 candidate + 1 temporal + ``spatial`` (stages
     ``candidates``, ``temporal``, ``spatial``), instead of the 1 shading ray of ``'none'``;
   * ``'candidate'`` (Bitterli Alg. 5; **biased**): one shadow ray to the chosen candidate before any reuse,
     ``W = 0`` (and no weight in merges) if occluded, weights over the unshadowed targets;
   * ``'final'`` (**biased**): the final shadow ray's visibility written into the stored reservoir (no extra
     ray), weights over the unshadowed targets;
   * ``'none'`` (**unbiased**): no visibility in the reservoirs (a sample occluded at its pixel stays and is
     reused: unbiased, but in a room lit through a window most samples are occluded and the few visible
     ones persist for tens of frames, so an accumulated image converges slowly).
3. **Temporal reuse** (Alg. 4/5, :meth:`ReSTIRDI.temporal_reuse`): the reprojected previous pixel's
   reservoir, M capped at ``m_cap`` x M (Bitterli Sec. 6: 20); skipped where the disocclusion mask
   rejects the previous pixel.
4. **Spatial reuse** (Alg. 4/5, unbiased Alg. 6, :func:`spatial_reuse`): ``spatial`` neighbours
   uniformly in a disk of ``radius`` pixels *at 1920-pixel width* (Bitterli's 30 px at 1080p), scaled
   with the image width (:func:`radius_px`, at least 2 px), accepted by the depth (10 %) / normal
   (25 deg) test.
5. **Shading** (:meth:`ReSTIRDI.shade`): one shadow ray for the final sample; BSDF x Lg x W.

:func:`continue_paths` is the path walk after ReSTIR DI's primary vertex (vertex 0): it counts what
ReSTIR's light samples cannot (emission behind a delta lobe of vertex 0) and everything from vertex 2
on (the indirect part).

Bias: none with ``combine='mis'`` or ``'1/z'`` and ``visibility_reuse='unbiased'`` or ``'none'`` on static
frames (``tests/techniques/test_restir.py``: per region on ``living-room-sky``, per pixel on the Cornell box).
``'candidate'`` and ``'final'`` are biased but consistent, as in Bitterli et al.'s Alg. 5: a sample's
visibility at its own pixel decides its reuse while the MIS weights count every domain with a positive
unshadowed target, a darkening wherever a neighbour or the previous pixel cannot see the light (20-64 % per
image block in a room lit through a window, docs/techniques/restir-pt.md). On dynamic frames the previous
pixel's target is evaluated with today's lights and a reused ``W`` may belong to a light that moved (both
documented in :mod:`dyngi.techniques.restir`).
"""
from __future__ import annotations

from dataclasses import dataclass

from .. import lights as light_samplers
from ..backend import dr, mi
from ..errors import DyngiError, unknown_choice
from ..lights.candidates import EmitterCandidates, LightCandidates
from ..lights.emitter_sampling import EmitterSampling
from ..lights.nee import LightNEE
from ..sampling.reservoir import COMBINE_MODES, Reservoir, finalize, finalize_single, merge
from ..sampling.rng import make_sampler
from .gbuffer import GBufferHistory, render_gbuffer, similar
from .path_walk import walk

PATH_STREAM = 0x7E57
"""RNG stream of the path after the primary vertex (:meth:`ReSTIRDI.path_after`; the ReSTIR stages use
stream 0)."""

VISIBILITY_REUSE = ("unbiased", "candidate", "final", "none")
"""Where a shadow ray's visibility enters the reservoirs (:class:`ReSTIRDI`, ``visibility_reuse``)."""
REFERENCE_WIDTH = 1920
"""``radius`` is given in pixels of an image this wide (Bitterli et al. Sec. 6: 30 px at 1920x1080)."""
MIN_RADIUS_PX = 2.0
"""Smallest spatial radius in pixels after the width scaling (our choice: below ~1.5 px most neighbours
round to the pixel itself, which spatial reuse skips). The default of the ``min_radius_px`` option of
:class:`ReSTIRDI` and of restir-pt's parameter (:data:`MIN_RADIUS_PARAM`)."""
MIN_RADIUS_PARAM = dict(default=MIN_RADIUS_PX, doc="smallest spatial reuse radius in pixels after the width "
                        "scaling (ours: at our resolutions Bitterli's 30 px at 1920 px shrinks below ~1.5 px, where "
                        "most neighbours round to the pixel itself, which spatial reuse skips; Bitterli et al. "
                        "give no floor)", min=0.0, max=1e4, ours=True)
"""restir-pt's ``min_radius_px`` parameter (``Param`` keyword arguments; issue 40: a choice of ours, no paper
value)."""


def radius_px(radius: float, width: int, min_px: float = MIN_RADIUS_PX) -> float:
    """The spatial radius in pixels at image ``width``: ``radius`` x ``width / 1920``, at least ``min_px``
    (:data:`MIN_RADIUS_PX`; our choice of scaling: the same fraction of the image at every resolution)."""
    return max(float(radius) * width / REFERENCE_WIDTH, float(min_px))


PARAM_SPECS = {
    "candidates": dict(default=32, doc="initial light candidates per pixel (M)", min=1, max=1024),
    "temporal": dict(default=True, doc="temporal reuse (motion-vector reprojection)"),
    "m_cap": dict(default=20.0, doc="temporal M cap in multiples of 'candidates'", min=0.0, max=1e4),
    "spatial": dict(default=3, doc="spatial neighbours per pixel (Bitterli et al.: 5)", min=0, max=16),
    "radius": dict(default=30.0, doc="spatial reuse radius in pixels of a 1920-pixel-wide image (Bitterli "
                   "et al.: 30 px at 1080p), scaled with the image width (at least MIN_RADIUS_PX)",
                   min=1.0, max=1e5),
    "visibility_reuse": dict(default="none", doc="visibility in the reservoirs: 'unbiased' (unbiased: the reuse's "
                             "MIS weights over p_hat_j V_j of the final sample, one shadow ray per other domain), "
                             "'candidate' (biased, Bitterli Alg. 5: a shadow ray to the initial candidate before "
                             "reuse, W = 0 if occluded), 'final' (biased: the final shadow ray's visibility written "
                             "back into the stored reservoir), 'none' (unbiased, no visibility: the component's "
                             "default, bit-identical for its users; restir-pt's is 'unbiased', "
                             "docs/techniques/restir-pt.md)",
                             choices=VISIBILITY_REUSE),
    "combine": dict(default="mis", doc="reservoir combination: unbiased 'mis' or '1/z', or 'biased'",
                    choices=COMBINE_MODES),
    "lights": dict(default="scene", doc="light sampler of the candidates and the path's NEE: 'scene' (Mitsuba's "
                   "emitter sampling) or a dyngi.lights sampler over the emitter triangles",
                   choices=("scene",) + light_samplers.names()),
}
"""The component's settings, as keyword arguments of a technique's parameter declaration (``Param``):
a technique that holds a :class:`ReSTIRDI` exposes these under these names."""


def target(n, two_sided, ev):
    """ReSTIR target ``lum(Lg) cos+`` (``|cos|`` where ``two_sided``) of evaluated candidates ``ev``."""
    c = dr.dot(n, ev.wi)
    c = dr.select(two_sided, dr.abs(c), dr.maximum(c, 0.0))
    return dr.select(ev.valid, mi.luminance(ev.Lg) * c, 0.0)


@dr.syntax
def initial_candidates(cand, si, n, two_sided, active, sampler, m: int, time, target_fn=target):
    """Stream ``m`` light candidates per lane (Bitterli Alg. 3); returns (k, payload, w_sum, p_hat).
    ``target_fn(n, two_sided, ev)``: the target of evaluated candidates (default :func:`target`)."""
    k_sel = dr.zeros(mi.UInt32, dr.width(active))
    pl_sel = dr.zeros(mi.Vector3f, dr.width(active))
    w_sum = dr.zeros(mi.Float, dr.width(active))
    ph_sel = dr.zeros(mi.Float, dr.width(active))
    i = mi.UInt32(0)
    m_u = mi.UInt32(m)
    while dr.hint(i < m_u, label="dyngi_restir_candidates"):
        k, pl = cand.sample(si, sampler.next_1d(), sampler.next_2d(), active)
        ev = cand.evaluate(si.p, k, pl, time, active)
        ph = target_fn(n, two_sided, ev)
        w = dr.select(active & (ev.pdf > 0.0), ph / ev.pdf, 0.0)
        w_sum += w
        take = (w > 0.0) & (sampler.next_1d() * w_sum < w)
        k_sel = dr.select(take, k, k_sel)
        pl_sel = dr.select(take, pl, pl_sel)
        ph_sel = dr.select(take, ph, ph_sel)
        i += 1
    return k_sel, pl_sel, w_sum, ph_sel


def spatial_reuse(gb, r_t, active, sampler, radius, count: int, combine: str, eval_here, gather_domain,
                  eval_there, vis_here=None, vis_there=None):
    """Spatial reuse of ``r_t`` over ``count`` neighbours in a disk of ``radius`` pixels (Bitterli et al.
    Alg. 4/5, the unbiased combination of Alg. 6), for any target function.

    ``eval_here(sample, ok)``: the target of a neighbour's sample at this pixel; ``gather_domain(nid, npos,
    nn, ntwo, ok)``: what the target needs of neighbour ``nid`` (a tuple); ``eval_there(domain, sample,
    ok)``: the target of this pixel's chosen sample at that neighbour (for the MIS / 1/Z weights).

    ``vis_here(sample, ok)`` and ``vis_there(nid, sample, ok)`` (both or neither; ``visibility_reuse=
    'unbiased'``): one shadow ray each, the final sample's visibility at this pixel and at neighbour ``nid``.
    Every reservoir then holds a sample visible from its own pixel or ``W = 0`` (the invariant that
    :meth:`ReSTIRDI.candidates` starts), so a domain's support is ``p_hat_j V_j > 0`` and the MIS / 1/Z
    weights are taken over ``p_hat_j(y) V_j(y)`` (generalized RIS: a partition of unity over the true
    supports). The domain the sample came from needs no ray (visible there by the invariant); the output's
    ``W`` is 0 where the sample is occluded at this pixel (which keeps the invariant, and lets the shading
    skip its shadow ray)."""
    w, h = gb.res
    npix = w * h
    idx = dr.arange(mi.UInt32, npix)
    x = mi.Int32(idx % w)
    y = mi.Int32(idx // w)
    out = Reservoir.empty(r_t.sample, npix)
    merge(out, r_t, r_t.p_hat, sampler.next_1d(), active, src=0)
    counts, domains, masks, nids = [r_t.M], [], [active], []
    radius = dr.opaque(mi.Float, radius)
    for j in range(count):
        off = mi.warp.square_to_uniform_disk_concentric(sampler.next_2d()) * radius
        nx = dr.clip(x + mi.Int32(dr.round(off.x)), 0, w - 1)
        ny = dr.clip(y + mi.Int32(dr.round(off.y)), 0, h - 1)
        nid = mi.UInt32(ny * w + nx)
        nvalid = dr.gather(mi.Bool, gb.valid, nid, active)
        npos = dr.gather(mi.Point3f, gb.pos, nid, active)
        nn = dr.gather(mi.Vector3f, gb.n_sh, nid, active)
        ntwo = dr.gather(mi.Bool, gb.transmissive, nid, active)
        ndepth = dr.gather(mi.Float, gb.depth, nid, active)
        dom = gather_domain(nid, npos, nn, ntwo, active)
        ok = active & (nid != idx) & similar(gb.depth, gb.n_sh, ndepth, nn, nvalid)
        rn = r_t.gather(nid, ok)
        ok &= rn.M > 0.0
        merge(out, rn, eval_here(rn.sample, ok), sampler.next_1d(), ok, src=j + 1)
        counts.append(rn.M)
        domains.append(dom)
        masks.append(ok)
        nids.append(nid)
    p_hats = [out.p_hat]
    for dom, ok in zip(domains, masks[1:]):
        p_hats.append(eval_there(dom, out.sample, ok))
    vis0 = None
    if vis_here is not None:    # -- 'unbiased': V_j(y) of the final sample at every other domain --
        have = out.p_hat > 0.0
        vis0 = (out.src == 0) | vis_here(out.sample, active & have & (out.src != 0))
        p_hats[0] = dr.select(vis0, p_hats[0], 0.0)
        for j, (nid, ok) in enumerate(zip(nids, masks[1:])):
            need = ok & have & (p_hats[j + 1] > 0.0) & (out.src != j + 1)
            vj = (out.src == j + 1) | vis_there(nid, out.sample, need)
            p_hats[j + 1] = dr.select(vj, p_hats[j + 1], 0.0)
    finalize(out, combine, counts, p_hats, masks)
    if vis0 is not None:
        out.W = dr.select(vis0, out.W, 0.0)
    dr.eval(*out.arrays())
    return out


def _after_restir_emission(depth, prev_delta):
    """Emission the continuation counts: from vertex 2 on (vertex 1's through a smooth lobe is ReSTIR's
    direct light), and at vertex 1 behind a delta lobe, which ReSTIR's light samples cannot reach."""
    return (depth >= 2) | ((depth == 1) & prev_delta)


def _after_restir_nee(depth):
    """NEE from vertex 1 on: the primary vertex's direct light is ReSTIR's."""
    return depth >= 1


def continue_paths(scene, sampler, ray, si, active, max_depth: int, rr_depth: int, lights, directions=None, *,
                   stage: str = "path"):
    """Path tracing from the primary vertex ``si`` on (BSDF + NEE with power-heuristic MIS, RR): the
    path walk (:func:`dyngi.transport.path_walk.walk`) from a given surface, with ReSTIR DI's share left
    out. Returns (light through a delta lobe of the primary vertex straight from an emitter [vertex 2],
    light from vertices >= 3 [the indirect part], rays traced per lane). The primary vertex's own
    emission and its direct light through smooth lobes are ReSTIR's (not counted here). ``directions``: a
    direction strategy of the walk (:class:`dyngi.directions.walk.WalkDirections`), else the BSDF's. Its rays
    are counted under ``stage`` (:mod:`dyngi.rays`)."""
    r = walk(scene, sampler, ray, active, max_depth, rr_depth, lights, True, si=si,
             emission=_after_restir_emission, nee=_after_restir_nee, total=directions is not None, split=True,
             near=True, directions=directions, stage=stage)      # a learning strategy reads the total (its record)
    return r.L_near, r.L_ind, r.n_rays


@dataclass
class PrimaryVertex:
    """A frame's primary vertices (:meth:`ReSTIRDI.begin`): the ReSTIR stages' sampler (stream 0), the
    frame time (opaque), G-buffer, reprojection (None without temporal reuse), BSDF, smooth-lobe mask."""

    sampler: object
    time: object
    gb: object
    reproj: object
    bsdf: object
    smooth: object


class ReSTIRDI:
    """ReSTIR DI at the primary vertex (module docstring): owns the G-buffer history, the light
    candidates' table and last frame's reservoirs; a technique holds one and calls its stages.

    ``target_fn(n, two_sided, ev)``: the target of the emitter-sample stages (:meth:`direct`), from a
    shading normal and evaluated candidates (default :func:`target`); any target that is positive
    wherever the integrand is keeps the estimate unbiased. The reuse stages also take the target as
    callables, so a technique whose reservoirs hold other samples (DDGI Resampling's emitter + BSDF-hit
    reservoir) uses the same temporal and spatial reuse."""

    def __init__(self, scene, candidates: int = 32, temporal: bool = True, m_cap: float = 20.0, spatial: int = 3,
                 radius: float = 30.0, combine: str = "mis", target_fn=target, cand=None, lights: str = "scene",
                 visibility_reuse: str = "none", min_radius_px: float = MIN_RADIUS_PX, leaf_samples: int = 0):
        if visibility_reuse not in VISIBILITY_REUSE:
            raise unknown_choice("visibility_reuse", visibility_reuse, VISIBILITY_REUSE)
        self.visibility_reuse = visibility_reuse
        self.scene = scene
        # -- the light choice (``lights``): one strategy for the candidates and the NEE of the path after --
        if lights == "scene":
            self.lights = EmitterSampling()
        else:    # a light sampler (a learning one sees the candidates' and the path's samples)
            self.lights = LightNEE(scene, lights, leaf_samples=leaf_samples)
            if cand is None:
                cand = LightCandidates(self.lights, scene.mi_scene)
        self.target_fn = target_fn
        self.m = int(candidates)
        self.temporal = bool(temporal)
        self.m_cap = float(m_cap)
        self.spatial = int(spatial)
        self.radius = float(radius)
        self.min_radius_px = float(min_radius_px)
        self.combine = combine
        # the candidates' source: Mitsuba's emitters (default) or a light sampler's (dyngi.lights.candidates)
        self.cand = cand if cand is not None else EmitterCandidates(scene.mi_scene)
        ids = self.cand.fast_shape_ids() if self.cand.count else set()
        # animators that move an emissive mesh or change its radiance: the triangle table follows them
        self.light_anim = any((getattr(a, "shape", None) in ids)
                              or str(getattr(a, "key", "")).split(".")[0] in ids for a in scene.animators)
        self.hist = GBufferHistory(scene)
        self.prev_res: Reservoir | None = None
        self.candidate_rays = 0     # shadow rays of the last candidates() ('candidate' visibility reuse)
        # whether any surface has a delta lobe (mirror, glass): only then does direct light need a path
        self.has_delta = any(sh.bsdf() is not None and mi.has_flag(sh.bsdf().flags(), mi.BSDFFlags.Delta)
                             for sh in scene.mi_scene.shapes())

    @classmethod
    def from_params(cls, scene, params: dict, **kw) -> "ReSTIRDI":
        """The component with a technique's settings (the keys of :data:`PARAM_SPECS`)."""
        return cls(scene, **{k: params[k] for k in PARAM_SPECS}, **kw)

    # -- per frame ------------------------------------------------------------------------------
    def lights_begin(self, frame, timer) -> None:
        """A light sampler's per-frame hook (rebuild, cache construction; stage ``lights``)."""
        if isinstance(self.lights, LightNEE):
            with timer.stage("lights"):
                self.lights.begin_frame(self.scene, frame, 2 * frame.res[0] * frame.res[1])

    def lights_end(self, timer) -> None:
        """A learning light sampler's update from the frame's samples (stage ``lights adapt``)."""
        if isinstance(self.lights, LightNEE):
            with timer.stage("lights adapt"):
                self.lights.end_frame()

    def begin_frame(self, frame) -> None:
        """Follow moving or changing emissive meshes (the candidates' triangle table)."""
        if self.light_anim and not frame.static and self.cand.has_fast:
            self.cand.refresh()

    def gbuffer(self, frame, sampler, timer):
        """Stage ``gbuffer``: primary rays (one ``next_2d`` of ``sampler``), history, reprojection;
        returns (G-buffer, reprojection or None without temporal reuse)."""
        with timer.stage("gbuffer"):
            gb = render_gbuffer(self.scene, frame.camera, frame.res, sampler.next_2d(), frame.time,
                                material=False)
            self.hist.push(gb)
            reproj = self.hist.reproject() if self.temporal else None
        timer.add_rays("gbuffer", frame.res[0] * frame.res[1])
        return gb, reproj

    def begin(self, frame, timer) -> PrimaryVertex:
        """The frame's set-up: sampler, opaque time, moving lights, stage ``gbuffer``."""
        npix = frame.res[0] * frame.res[1]
        sampler = make_sampler(npix, frame.seed, frame.index)
        time = dr.opaque(mi.Float, float(frame.time))
        self.begin_frame(frame)
        gb, reproj = self.gbuffer(frame, sampler, timer)
        bsdf = gb.si.bsdf(gb.ray)
        smooth = gb.valid & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        return PrimaryVertex(sampler, time, gb, reproj, bsdf, smooth)

    def path_after(self, pv: PrimaryVertex, frame, lights, max_depth: int, rr_depth: int, timer, directions=None):
        """What ReSTIR DI does not deliver at the primary vertex (stage ``path``): returns (its emission,
        the light behind its delta lobes straight from an emitter, light from vertices >= 3), the path
        walk's :func:`continue_paths` on stream :data:`PATH_STREAM`. ``max_depth`` as Mitsuba's (2: direct
        light only, so only the delta lobes need a path, and only where the scene has one)."""
        npix = frame.res[0] * frame.res[1]
        si, valid = pv.gb.si, pv.gb.valid
        Le0 = si.emitter(self.scene.mi_scene).eval(si, mi.Bool(True))
        L_d = dr.zeros(mi.Color3f, npix)
        L_ind = dr.zeros(mi.Color3f, npix)
        if max_depth < 0 or max_depth > 2 or (max_depth == 2 and self.has_delta):
            with timer.stage("path"):
                ps = make_sampler(npix, frame.seed, frame.index, PATH_STREAM)
                cont = valid
                if max_depth == 2:    # direct light only: just the primary vertex's delta lobes
                    cont = valid & mi.has_flag(pv.bsdf.flags(), mi.BSDFFlags.Delta)
                L_d, L_ind, rays = continue_paths(self.scene.mi_scene, ps, pv.gb.ray, si, cont, max_depth, rr_depth,
                                                  lights, directions)
                dr.eval(L_d, L_ind, rays)
            timer.add_rays("path", dr.sum(rays))
        return Le0, L_d, L_ind

    # -- the default target ---------------------------------------------------------------------
    def eval_at(self, pos, n, two_sided, sample, time, active):
        """The default target of ``sample`` = (k, payload) at a shading domain (position, normal, two-sided)."""
        ev = self.cand.evaluate(pos, sample[0], sample[1], time, active)
        return self.target_fn(n, two_sided, ev)

    # -- stages -----------------------------------------------------------------------------------
    def candidates(self, gb, active, sampler, time) -> Reservoir:
        """Initial candidates (Bitterli Alg. 3) with the default target: a one-sample reservoir per lane."""
        npix = dr.width(gb.valid)
        k, pl, w_sum, ph = initial_candidates(self.cand, gb.si, gb.n_sh, gb.transmissive, active, sampler, self.m,
                                              time, self.target_fn)
        r = Reservoir((k, pl), w_sum, dr.select(active, float(self.m), 0.0), ph, mi.Float(0.0),
                      dr.zeros(mi.UInt32, npix))
        finalize_single(r)
        self.candidate_rays = 0
        if self.visibility_reuse in ("candidate", "unbiased"):   # Alg. 5: W = 0 (no weight in merges) if occluded
            vis, traced = self.candidate_visibility(gb, (k, pl), active & (r.W > 0.0), time)
            r.W = dr.select(vis, r.W, 0.0)
            r.w_sum = dr.select(vis, r.w_sum, 0.0)
            self.candidate_rays = dr.count(traced)
        dr.eval(*r.arrays())
        return r

    def temporal_reuse(self, r, gb, reproj, active, sampler, m: float, eval_here, eval_prev, vis_here=None,
                       vis_prev=None) -> None:
        """Merge the reprojected previous pixel's reservoir into ``r`` (Alg. 4/5; in place), M capped at
        ``m_cap * m`` (``m``: the candidates a fresh reservoir holds). ``eval_here(sample, ok)``: the
        target at this pixel; ``eval_prev(prev_gbuffer, prev_pixel, sample, ok)``: at the previous pixel
        (for the MIS / 1/Z weights). Does nothing without temporal reuse or a previous frame.

        ``vis_here(sample, ok)``, ``vis_prev(prev_gbuffer, prev_pixel, sample, ok)`` (``visibility_reuse=
        'unbiased'``): the final sample's visibility at this pixel and at the previous pixel, one shadow ray
        where the sample came from the other domain (visible at its own by the invariant of
        :func:`spatial_reuse`); the weights over ``p_hat V`` and ``W = 0`` where occluded here."""
        npix = dr.width(gb.valid)
        prev = self.hist.prev
        if not (self.temporal and self.prev_res is not None and prev is not None
                and dr.width(self.prev_res.W) == npix):
            return
        ok = active & reproj.valid
        rp = self.prev_res.gather(reproj.prev_pixel, ok)
        cap = dr.opaque(mi.Float, self.m_cap * m)
        m_prev = dr.minimum(rp.M, cap)
        ph_here = eval_here(rp.sample, ok)
        merge(r, rp, ph_here, sampler.next_1d(), ok, src=1, m_cap=cap)
        # the final sample's target at the previous pixel (its G-buffer, today's lights)
        ph_prev = eval_prev(prev, reproj.prev_pixel, r.sample, ok)
        ph_here = r.p_hat
        vis0 = None
        if self.visibility_reuse == "unbiased":
            self._need_vis(vis_here, vis_prev)
            have = r.p_hat > 0.0
            vis0 = (r.src == 0) | vis_here(r.sample, active & have & (r.src != 0))
            visp = (r.src == 1) | vis_prev(prev, reproj.prev_pixel, r.sample, ok & have & (ph_prev > 0.0)
                                           & (r.src != 1))
            ph_here = dr.select(vis0, ph_here, 0.0)
            ph_prev = dr.select(visp, ph_prev, 0.0)
        finalize(r, self.combine, [mi.Float(m), m_prev], [ph_here, ph_prev], [True, ok])
        if vis0 is not None:
            r.W = dr.select(vis0, r.W, 0.0)
        dr.eval(*r.arrays())

    def spatial_reuse(self, gb, r, active, sampler, eval_here, gather_domain, eval_there, vis_here=None,
                      vis_there=None) -> Reservoir:
        """Spatial reuse (:func:`spatial_reuse`) with this component's count, radius (scaled with the image
        width, :func:`radius_px`) and combination; ``vis_here`` / ``vis_there`` are used (and required) with
        ``visibility_reuse='unbiased'`` only."""
        unbiased = self.visibility_reuse == "unbiased"
        if unbiased:
            self._need_vis(vis_here, vis_there)
        return spatial_reuse(gb, r, active, sampler, radius_px(self.radius, gb.res[0], self.min_radius_px),
                             self.spatial, self.combine,
                             eval_here, gather_domain, eval_there, vis_here if unbiased else None,
                             vis_there if unbiased else None)

    @staticmethod
    def _need_vis(*fns) -> None:
        if any(f is None for f in fns):
            raise DyngiError("visibility_reuse='unbiased' needs the reuse stage's visibility callables "
                             "(vis_here, vis_prev / vis_there); this caller passes none")

    @staticmethod
    def ray_origin(g, idx, active, time):
        """What a shadow ray from G-buffer ``g``'s pixels ``idx`` needs of their surface (position, geometric
        normal for the origin's offset, time): a surface interaction with only those set (cheaper to gather
        than the full one)."""
        it = dr.zeros(mi.SurfaceInteraction3f, dr.width(idx))
        it.p = dr.gather(mi.Point3f, g.pos, idx, active)
        it.n = dr.gather(mi.Vector3f, g.n_geo, idx, active)
        it.time = time
        return it

    def visible_at(self, si, sample, time, active, stage: str):
        """Visibility of emitter samples ``sample`` = (k, payload) from surface interactions ``si`` (one shadow
        ray per ``active`` lane with a valid sample, counted under ``stage``); returns (visible, lanes that
        traced a ray)."""
        ev = self.cand.evaluate(si.p, sample[0], sample[1], time, active)
        traced = mi.Bool(active) & ev.valid
        return self.cand.visible(si, ev, traced, stage=stage), traced

    def shade(self, gb, bsdf, sample, W, active, time, known_visible: bool = False):
        """One shadow ray to the emitter sample ``sample`` = (k, payload) per ``active`` lane; returns
        (BSDF x Lg x W where visible, lanes that traced a shadow ray, lanes that found it occluded).
        ``known_visible``: the reservoirs hold only samples visible from their pixel (``W > 0``;
        ``visibility_reuse='unbiased'``), so no ray is traced (none is counted)."""
        si = gb.si
        ev = self.cand.evaluate(gb.pos, sample[0], sample[1], time, active)
        if known_visible:
            vis = ev.valid
            f = bsdf.eval(mi.BSDFContext(), si, si.to_local(ev.wi), vis)
            none = dr.zeros(mi.Bool, dr.width(vis))
            return dr.select(vis, f * ev.Lg * W, 0.0), none, none
        vis = self.cand.visible(si, ev, ev.valid, stage="shadow")
        f = bsdf.eval(mi.BSDFContext(), si, si.to_local(ev.wi), vis)
        return dr.select(vis, f * ev.Lg * W, 0.0), ev.valid, ev.valid & ~vis

    def candidate_visibility(self, gb, sample, active, time):
        """Bitterli Alg. 5's visibility reuse: one shadow ray from the primary vertex to each ``active``
        lane's emitter sample ``sample`` = (k, payload); returns (visible, lanes that traced a ray)."""
        ev = self.cand.evaluate(gb.pos, sample[0], sample[1], time, active)
        return self.cand.visible(gb.si, ev, ev.valid, stage="candidates"), ev.valid

    @staticmethod
    def store_visibility(r: Reservoir, occluded) -> None:
        """``visibility_reuse='final'``: the final shadow ray's result written back into the reservoir that
        is kept for the next frame (``W = 0`` where it found the sample occluded; Bitterli Alg. 5 applies
        the same rule to the initial candidate), so an occluded sample is not reused."""
        r.W = dr.select(occluded, 0.0, r.W)

    # -- all stages with the default target -------------------------------------------------------
    def direct(self, pv: PrimaryVertex, timer):
        """Direct light at the primary vertex by ReSTIR DI with the default target: stages
        ``candidates``, ``temporal``, ``spatial``, ``shadow`` (timed on ``timer``). Keeps the final
        reservoirs as next frame's temporal input."""
        gb, reproj, bsdf, smooth, sampler, time = pv.gb, pv.reproj, pv.bsdf, pv.smooth, pv.sampler, pv.time
        with timer.stage("candidates"):
            r = self.candidates(gb, smooth, sampler, time)
        if self.visibility_reuse in ("candidate", "unbiased"):
            timer.add_rays("candidates", self.candidate_rays)
        unbiased = self.visibility_reuse == "unbiased"
        vis_rays = []

        def vis_here(sample, ok, stage):
            v, traced = self.visible_at(gb.si, sample, time, ok, stage)
            vis_rays.append((stage, traced))
            return v
        with timer.stage("temporal"):
            def here(sample, ok):
                return self.eval_at(gb.pos, gb.n_sh, gb.transmissive, sample, time, ok)

            def there_prev(prev, pix, sample, ok):
                ppos = dr.gather(mi.Point3f, prev.pos, pix, ok)
                pn = dr.gather(mi.Vector3f, prev.n_sh, pix, ok)
                ptwo = dr.gather(mi.Bool, prev.transmissive, pix, ok)
                return self.eval_at(ppos, pn, ptwo, sample, time, ok)

            def vis_prev(prev, pix, sample, ok):
                v, traced = self.visible_at(self.ray_origin(prev, pix, ok, time), sample, time, ok, "temporal")
                vis_rays.append(("temporal", traced))
                return v

            self.temporal_reuse(r, gb, reproj, smooth, sampler, self.m, here, there_prev,
                                lambda s, ok: vis_here(s, ok, "temporal"), vis_prev)
        with timer.stage("spatial"):
            if self.spatial > 0:
                def vis_there(nid, sample, ok):
                    v, traced = self.visible_at(self.ray_origin(gb, nid, ok, time), sample, time, ok, "spatial")
                    vis_rays.append(("spatial", traced))
                    return v

                r = self.spatial_reuse(gb, r, smooth, sampler, here,
                                       lambda nid, npos, nn, ntwo, act: (npos, nn, ntwo),
                                       lambda dom, sample, ok: self.eval_at(*dom, sample, time, ok),
                                       lambda s, ok: vis_here(s, ok, "spatial"), vis_there)
        for stage, ok in vis_rays:
            timer.add_rays(stage, dr.count(ok))
        with timer.stage("shadow"):
            direct, shadow, occluded = self.shade(gb, bsdf, r.sample, r.W, smooth & (r.W > 0.0), time,
                                                  known_visible=unbiased)
            if self.visibility_reuse == "final":
                self.store_visibility(r, occluded)
            dr.eval(direct, r.W)
        timer.add_rays("shadow", dr.count(smooth & shadow))
        self.prev_res = r
        return direct
