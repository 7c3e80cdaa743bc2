"""One unidirectional path walk: BSDF sampling + next-event estimation with MIS + Russian roulette.

Estimator (Veach 1997, Ch. 9; pbrt-v4's ``PathIntegrator::Li``): at each vertex the emission reached
by the BSDF-sampled ray, weighted by MIS against light sampling (power or balance heuristic,
:mod:`dyngi.transport.mis`), plus one light sample (NEE, :func:`dyngi.lights.emitter_sampling.sample_traced`)
weighted by MIS against BSDF sampling; Russian roulette from ``rr_depth`` on with survival probability
``min(max(beta) * eta^2, 0.95)`` (Mitsuba's ``path``). ``max_depth`` counts path vertices as in
Mitsuba (1: emitters seen directly, 2: direct illumination; -1 unbounded). The whole path is one
symbolic ``@dr.syntax`` loop: one kernel, and a steady frame compiles nothing new.

A walk starts from **camera rays** (:func:`walk` without ``si``: the first intersection is its vertex
0) or from **given surface interactions** (``si`` and the ray that reached them: a G-buffer's primary
vertex, a VPL's point); both consume the sampler identically, so the same sampler gives the same path
(``tests/transport/test_path_walk.py``). Vertex ``depth`` 0 is the first one; its emission is what the
ray sees directly.

Per-vertex choices (Python callables evaluated inside the loop, on Dr.Jit masks):

* ``emission(depth, prev_delta) -> Bool``: which vertices' emission counts (``prev_delta``: the vertex
  was reached through a delta lobe, which light sampling cannot produce). Default: all.
* ``nee(depth) -> Bool``: where NEE happens. Default: every vertex with a smooth lobe.
* ``terminate(si, ray, depth, active) -> (stop, radiance)``: where ``stop``, the path ends at this
  vertex (after its emission) and ``beta * radiance`` replaces the rest of it (a probe lookup, a
  footprint test); no NEE and no further bounce there. Default: none.
* ``shade(v: VertexCtx) -> (radiance, stop, state)``: radiance this vertex adds besides its emission and
  NEE (``beta * radiance``; e.g. a probe's diffuse term), where ``stop`` no bounce follows (NEE at the
  vertex still happens; e.g. DDGI Resampling's footprint termination, Eq. 8), and the hook's per-lane
  ``state`` (a Dr.Jit PyTree given as ``state=``, carried through the loop; e.g. Eq. 7's running
  footprint sum). Default: none.
* ``vertex(v: VertexCtx) -> Vertex``: the vertex (:class:`dyngi.directions.base.Vertex`) that NEE and the
  direction strategy see, called at every vertex with ``v.active`` its valid lanes: its BSDF, or a diffuse
  stand-in (``bsdf=None`` with an ``albedo``: nee-pt after the primary hit), its side-corrected shading
  normal, its octree leaf; the hook may also record the vertex (octree placement). Default: the direction
  strategy's ``vertex`` (or none).

A light strategy may supply its own estimators (optional methods, used where present):
``emitted(scene, si, ray, prev_si, prev_pdf, prev_delta, depth, active)``: the MIS-weighted emission at the
vertex (instead of Mitsuba's emitter times the walk's MIS weight), and ``estimate(scene, vtx, sampler,
active, depth, dir_pdf) -> (radiance, rays)``: the NEE estimate at the vertex without ``beta`` (instead of one
light sample; ``dir_pdf(wo, active)``: the BSDF side's density, the direction strategy's where there is
one), e.g. nee-pt's one triangle sample by its light selector plus one Mitsuba sample of the other emitters
(the VLC paper, Sec. 7: :class:`dyngi.lights.nee.LightNEE` with ``estimator="separate"``). A strategy with
an ``own_estimators`` attribute says by it whether both are used (a :class:`~dyngi.lights.nee.LightNEE` has
them, for its separate estimator only).

``unroll=True`` traces the loop in Python: exactly ``max_depth`` vertices, each hook gets its vertex index as
a Python ``int`` (so it may specialise per vertex, and keep per-vertex values between its calls, e.g. per-frame
record lists of a learning sampler), and the last vertex draws no NEE or bounce sample. The estimate is the
symbolic loop's, bit for bit (same random numbers in the same order, ``tests/transport/test_path_walk.py``);
for short fixed-depth walks (nee-pt's three vertices).

Other choices: ``stop_at_zero=False``: a path whose throughput became 0 goes on (its vertices add
nothing, but the hooks and a learning sampler see them; nee-pt's VLC and CDQ learn at the vertices that
zero-weight samples reach, e.g. a CDQ direction below the surface); ``mis=False`` weighs NEE and emission
1 (no MIS; for an estimator whose emission hook leaves out what NEE covers); ``rr_depth < 0``: no Russian
roulette (and no random number drawn for it); ``nee=False``: no NEE at all (no light sample drawn);
``directions``: a direction strategy instead of the BSDF's own sampling
(:class:`dyngi.directions.walk.WalkDirections`; a restricted one such as
:class:`dyngi.directions.glossy.GlossyLobes`).

A path that can no longer contribute (its next vertex counts no emission and is the last) stops early.

Rays (issue 40): every ray of the walk (the camera ray or none, each bounce, each NEE shadow ray, the
continuations of a shadow ray through glass) is traced through :mod:`dyngi.rays` with ``lanes=True``
and counted per lane in ``n_rays`` (a light strategy's ``sample_walk`` / ``sample_traced`` with
``lanes=True`` and ``estimate`` return their rays per lane); after the loop the walk adds ``n_rays`` to the
open ray ledgers under its ``stage`` (lazily: the per-lane counter, read when the ledger's total is asked
for), unless the caller passes ``lanes=True`` and counts them itself (a walk inside a symbolic loop or a
frozen function).

Outputs, from the same terms: ``L`` (everything counted), ``L_ind`` (the *indirect* part: emission at
vertices >= 2, NEE at vertices >= 1, terminate radiance at vertices >= 1, i.e. light that reflected at
least once before vertex 0 -- the papers' "indirect", as the indirect reference), ``L_near`` (the
counted rest: emission at vertices 0 and 1, NEE and terminate radiance at vertex 0). Each is a
separate running sum, so ``L`` is not ``L_near + L_ind`` to the last bit; ask only for what is used.
"""
from __future__ import annotations

from dataclasses import dataclass

from .. import rays
from ..backend import dr, mi
from ..errors import DyngiError
from ..lights.emitter_sampling import EmitterSampling, sample_traced
from ..sampling.rng import make_sampler
from ..scene.passthrough import count_lanes
from .mis import mis_weight


@dataclass
class PathResult:
    """What :func:`walk` returns: the sums asked for (else None), rays traced per lane, and whether
    vertex 0 is a surface (for camera rays: the first hit)."""

    L: object
    L_ind: object
    L_near: object
    n_rays: object
    first_valid: object
    bounces: object = None
    state: object = None


@dataclass
class VertexCtx:
    """What a ``shade`` hook sees at a vertex: the surface interaction, the ray that reached it, its BSDF,
    the vertex index ``depth``, the active lanes (valid hits), the pdf and delta flag of the direction that
    led here (at vertex 0 of a walk from surfaces: 1 and True), the walk's sampler and the hook's state."""

    si: object
    ray: object
    bsdf: object
    depth: object
    active: object
    prev_pdf: object
    prev_delta: object
    sampler: object
    state: object


def _mask(hook, base, *args):
    """``base`` restricted by a per-vertex hook (``None``: not restricted)."""
    return base if hook is None else base & mi.Bool(hook(*args))


def _terminate(hook, si, ray, depth, active, active_next, beta, L, L_ind, L_near, total, split, near):
    """Apply the terminate hook at this vertex: add ``beta * radiance`` where it stops the path."""
    stop, L_t = hook(si, ray, depth, active & si.is_valid())
    stop = active & si.is_valid() & mi.Bool(stop)
    if total:
        L = dr.select(stop, dr.fma(beta, L_t, L), L)
    if split:
        L_ind = dr.select(stop & (depth >= 1), dr.fma(beta, L_t, L_ind), L_ind)
    if near:
        L_near = dr.select(stop & (depth == 0), dr.fma(beta, L_t, L_near), L_near)
    return L, L_ind, L_near, active_next & ~stop


def _light_pdf(lights, scene, prev_si, si, ds, active):
    """Solid-angle pdf of light sampling for the emission hit at ``si`` from ``prev_si``: a light sampler
    (:class:`dyngi.lights.nee.LightNEE`) reads the light's id from the hit, a strategy only ``ds``."""
    if getattr(lights, "walk_aware", False):
        return lights.pdf_hit(scene, prev_si, si, ds, active)
    return lights.pdf(scene, prev_si, ds, active)


def _light_sample(lights, scene, si, sampler, active, depth, stage):
    """One NEE sample: (ds, weight, lanes whose sample counts, shadow rays traced per lane). A light sampler
    draws its own numbers (a 2D point and a 1D light choice); a strategy one 2D number (the default's
    stream is unchanged). The rays are the walk's to count (``lanes=True``)."""
    if getattr(lights, "walk_aware", False):
        return lights.sample_walk(scene, si, sampler, active, depth, stage=stage, lanes=True)
    return sample_traced(lights, scene, si, sampler.next_2d(), active, stage=stage, lanes=True)


def _dir_vertex(directions, si, bsdf, active):
    """The vertex a direction strategy sees (None for the BSDF's own sampling)."""
    return None if directions is None else directions.vertex(si, bsdf, active)


def _dir_pdf(directions, vtx, wo, active, bsdf_pdf):
    """BSDF-side pdf of the NEE sample's MIS weight: the BSDF's, or the direction strategy's."""
    return bsdf_pdf if directions is None else directions.pdf(vtx, wo, active)


def _f_pdf(vtx, bsdf, ctx, si, wo, active):
    """NEE's BSDF side at the vertex: (f cos, pdf) of its BSDF, or of a ``vertex`` hook's diffuse stand-in
    (``albedo / pi`` times the cosine to the hook's normal; cosine-hemisphere pdf)."""
    if vtx is None or vtx.bsdf is not None:
        return bsdf.eval_pdf(ctx, si, si.to_local(wo), active)
    cos = dr.maximum(dr.dot(vtx.n, wo), 0.0)
    return dr.select(active, vtx.albedo * cos * dr.inv_pi, 0.0), dr.select(active, cos * dr.inv_pi, 0.0)


def _pdf_fn(directions, vtx, bsdf, ctx, si):
    """``dir_pdf(wo, active)`` for a light strategy's own NEE estimator: the density with which the walk's
    bounce produces ``wo`` (the direction strategy's, else the BSDF's or the vertex hook's stand-in's)."""
    def dir_pdf(wo, active):
        if directions is not None:
            return directions.pdf(vtx, wo, active)
        return _f_pdf(vtx, bsdf, ctx, si, wo, active)[1]
    return dir_pdf


def _more(active, depth, n_unroll):
    """The loop condition: the active lanes (symbolic loop), or ``depth < n_unroll`` (a Python loop)."""
    return active if n_unroll is None else depth < n_unroll


def _bounce(directions, vtx, bsdf, ctx, si, sampler, active, L, beta, depth):
    """Next direction: (world direction, weight f cos / pdf, pdf, delta lobe, eta), by the BSDF or by a
    direction strategy (which records its sample for learning)."""
    if directions is None:
        bs, bsdf_weight = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), active)
        return si.to_world(bs.wo), bsdf_weight, bs.pdf, mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta), bs.eta
    d = directions.sample(vtx, sampler, active)
    directions.record(vtx, d, L, beta, depth)
    ok = mi.Bool(d.ok)
    return d.wo, dr.select(ok, d.weight, 0.0), dr.select(ok, d.pdf, 0.0), mi.Bool(d.delta), mi.Float(1.0)


def _shade(hook, si, ray, bsdf, depth, active, prev_pdf, prev_delta, sampler, state, beta, L, L_ind, L_near,
           total, split, near):
    """Apply the shade hook at this vertex: add ``beta * radiance``; return the sums, the lanes that stop
    after this vertex, and the hook's new state."""
    on = active & si.is_valid()
    L_s, stop, state = hook(VertexCtx(si, ray, bsdf, depth, on, prev_pdf, prev_delta, sampler, state))
    L_s = dr.select(on, L_s, 0.0)
    if total:
        L = dr.fma(beta, L_s, L)
    if split:
        L_ind = dr.select(depth >= 1, dr.fma(beta, L_s, L_ind), L_ind)
    if near:
        L_near = dr.select(depth == 0, dr.fma(beta, L_s, L_near), L_near)
    return L, L_ind, L_near, on & mi.Bool(stop), state


@dr.syntax
def walk(scene, sampler, ray, active, max_depth: int, rr_depth: int, lights=None, power_heuristic: bool = True,
         si=None, emission=None, nee=None, terminate=None, total: bool = True, split: bool = False,
         near: bool = False, directions=None, shade=None, state=None, mis: bool = True, vertex=None,
         unroll: bool = False, stop_at_zero: bool = True, stage: str = "trace", lanes: bool = False) -> PathResult:
    """Trace one path per lane (module docstring); ``si``: start at these surface interactions
    (``ray``: the rays that reached them), else intersect ``ray`` first. ``total``/``split``/``near``:
    which of ``L``/``L_ind``/``L_near`` to sum. ``directions``: a direction strategy
    (:class:`dyngi.directions.walk.WalkDirections`) instead of the BSDF's own sampling. ``shade`` and
    ``state``: the per-vertex shade hook and its initial state; ``mis``: MIS between NEE and emission;
    ``vertex``: the vertex hook; ``unroll``: trace the loop in Python (``max_depth`` >= 1 vertices);
    ``stop_at_zero``: a path whose throughput is 0 ends. ``stage``: the name its rays are counted under
    (:mod:`dyngi.rays`); ``lanes``: the caller counts ``n_rays`` itself (module docstring)."""
    lights = lights if lights is not None else EmitterSampling()
    do_nee = nee is not False
    if unroll and max_depth < 1:
        raise DyngiError(f"path walk: unroll needs a bounded max_depth >= 1, got {max_depth}")
    n_unroll = max_depth if unroll else None
    own = getattr(lights, "own_estimators", None)    # a strategy may say whether its estimators replace the walk's
    own_emission = hasattr(lights, "emitted") if own is None else bool(own)
    own_estimate = hasattr(lights, "estimate") if own is None else bool(own)
    if state is None:
        state = mi.Float(0.0)
    max_depth = mi.UInt32(0xFFFFFFFF) if max_depth < 0 else mi.UInt32(max_depth)
    rr_depth_u = mi.UInt32(max(rr_depth, 0))
    ctx = mi.BSDFContext()
    active = mi.Bool(active)
    ray = mi.Ray3f(ray)
    # -- vertex 0: the camera ray's first hit, or the given surface --
    if si is None:
        si = rays.intersect(scene, ray, mi.RayFlags.All, True, active, stage=stage, lanes=True)
        n_rays = mi.UInt32(active)
    else:
        si = mi.SurfaceInteraction3f(si)
        n_rays = dr.zeros(mi.UInt32, dr.width(active))
    first_valid = active & si.is_valid()
    # the record buffers hold one slot per lane of ``active``: a caller passes a mask as wide as its paths
    # (``render_paths_split`` once passed a scalar ``True``: every lane wrote the same two slots and path's VLC / CDQ
    # learnt from almost nothing)
    if hasattr(lights, "begin_walk"):     # a learning light sampler's record buffers (dyngi.lights.nee)
        lights.begin_walk(dr.width(active))
    if directions is not None:            # a learning direction sampler's record buffers
        directions.begin_walk(dr.width(active))
    L = mi.Spectrum(0.0)
    L_ind = mi.Spectrum(0.0)
    L_near = mi.Spectrum(0.0)
    beta = mi.Spectrum(1.0)
    depth = 0 if unroll else mi.UInt32(0)
    prev_si = dr.zeros(mi.SurfaceInteraction3f)
    prev_pdf = mi.Float(1.0)
    prev_delta = mi.Bool(True)
    bounces = mi.UInt32(0)

    while dr.hint(_more(active, depth, n_unroll), label="dyngi_path_walk"):
        # -- emission hit by the BSDF-sampled ray, MIS against NEE --
        em_on = _mask(emission, active, depth, prev_delta)
        if dr.hint(own_emission, mode="scalar"):      # the light strategy's own emission estimator
            Le_w = lights.emitted(scene, si, ray, prev_si, prev_pdf, prev_delta, depth, em_on)
        else:
            ds = mi.DirectionSample3f(scene, si, prev_si)
            w_bsdf = mi.Float(1.0)
            if mis and do_nee:
                em_pdf = mi.Float(0.0)
                if ~prev_delta:
                    em_pdf = _light_pdf(lights, scene, prev_si, si, ds, active & ~prev_delta)
                w_bsdf = mis_weight(prev_pdf, em_pdf, power_heuristic)
            Le_w = ds.emitter.eval(si, em_on & (prev_pdf > 0)) * w_bsdf
        if total:
            L[em_on] = dr.fma(beta, Le_w, L)
        if split:    # not the emission of vertex 0 nor of vertex 1 (direct light)
            L_ind[em_on & (depth >= 2)] = dr.fma(beta, Le_w, L_ind)
        if near:
            L_near[em_on & (depth < 2)] = dr.fma(beta, Le_w, L_near)

        last = n_unroll is not None and depth + 1 >= n_unroll    # an unrolled walk's last vertex: nothing follows
        active_next = active & si.is_valid() & (depth + 1 < max_depth)
        bsdf = si.bsdf(ray)

        # -- terminate hook: radiance replaces the rest of the path --
        if terminate is not None:
            L, L_ind, L_near, active_next = _terminate(terminate, si, ray, depth, active, active_next, beta,
                                                       L, L_ind, L_near, total, split, near)

        # -- shade hook: radiance of this vertex besides emission and NEE; where it stops, no bounce --
        active_bounce = mi.Bool(active_next)
        if shade is not None:
            L, L_ind, L_near, stop_s, state = _shade(shade, si, ray, bsdf, depth, active, prev_pdf, prev_delta,
                                                     sampler, state, beta, L, L_ind, L_near, total, split, near)
            active_bounce = active_next & ~stop_s

        if dr.hint(vertex is None, mode="scalar"):
            vtx = _dir_vertex(directions, si, bsdf, active_next)
        else:   # the vertex hook sees every valid vertex (also the last: e.g. its octree placement)
            vtx = vertex(VertexCtx(si, ray, bsdf, depth, active & si.is_valid(), prev_pdf, prev_delta, sampler,
                                   state))
        # -- next-event estimation --
        if dr.hint(do_nee and not last, mode="scalar"):
            active_em = _mask(nee, active_next, depth) & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            if dr.hint(own_estimate, mode="scalar"):   # the light strategy's own NEE estimator
                L_em, r_em = lights.estimate(scene, vtx, sampler, active_em, depth,
                                             _pdf_fn(directions, vtx, bsdf, ctx, si))
                n_rays += r_em
            else:
                ds_em, em_weight, active_em, r_em = _light_sample(lights, scene, si, sampler, active_em, depth,
                                                                  stage)
                n_rays += r_em
                bsdf_val, bsdf_pdf = _f_pdf(vtx, bsdf, ctx, si, ds_em.d, active_em)
                w_em = mi.Float(1.0)
                if mis:
                    bsdf_pdf = _dir_pdf(directions, vtx, ds_em.d, active_em, bsdf_pdf)
                    w_em = dr.select(ds_em.delta, 1.0, mis_weight(ds_em.pdf, bsdf_pdf, power_heuristic))
                L_em = bsdf_val * em_weight * w_em
            if total:
                L[active_em] = dr.fma(beta, L_em, L)
            if split:    # not NEE at vertex 0 (direct light)
                L_ind[active_em & (depth >= 1)] = dr.fma(beta, L_em, L_ind)
            if near:
                L_near[active_em & (depth == 0)] = dr.fma(beta, L_em, L_near)

        if dr.hint(last, mode="scalar"):
            depth += 1
        else:
            # -- BSDF sampling --
            active_next = active_bounce
            wo_w, bsdf_weight, s_pdf, delta_lobe, s_eta = _bounce(directions, vtx, bsdf, ctx, si, sampler,
                                                                   active_next, L, beta, depth)
            ray = si.spawn_ray(wo_w)
            beta *= bsdf_weight
            prev_si = dr.detach(si, True)
            prev_pdf = s_pdf
            prev_delta = delta_lobe
            depth += 1
            # the next vertex contributes if it counts emission or is not the last one
            useful = _mask(emission, mi.Bool(True), depth, delta_lobe) | (depth + 1 < max_depth)

            # -- Russian roulette --
            beta_max = dr.max(beta)
            survive = mi.Bool(True)
            if rr_depth >= 0:
                rr_active = depth >= rr_depth_u
                rr_prob = dr.minimum(beta_max * dr.square(s_eta), 0.95)
                rr_continue = sampler.next_1d() < rr_prob
                beta[rr_active] *= dr.rcp(rr_prob)
                survive = ~rr_active | rr_continue
            alive = (beta_max != 0.0) if stop_at_zero else mi.Bool(True)
            active = active_next & useful & survive & alive & (s_pdf > 0.0)

            si = rays.intersect(scene, ray, mi.RayFlags.All, False, active, stage=stage, lanes=True)
            n_rays += mi.UInt32(active)
            bounces += mi.UInt32(active)

    if directions is not None:
        directions.end_walk(L)
    count_lanes(stage, n_rays, lanes, schedule=False)     # the callers evaluate n_rays with L (their self-report)
    return PathResult(L if total else None, L_ind if split else None, L_near if near else None, n_rays,
                      first_valid, bounces, state)


def trace_paths_split(scene, sampler, ray, active, max_depth: int, rr_depth: int, lights=None,
                      power_heuristic: bool = True, split: bool = True, directions=None, *, stage: str = "trace",
                      lanes: bool = False):
    """Camera-ray paths; return (radiance, indirect radiance, rays per lane, first-hit validity).

    The indirect part (with ``split``; else it is 0) sums the same terms as the full radiance except
    the emission seen at the first vertex, the emission reached by its BSDF-sampled ray and its NEE
    sample: light that reflected at least once before the first vertex (vertices >= 3). Both come from
    the same paths, so ``full - indirect`` is each sample's emission + direct light, and
    ``indirect <= full`` per sample. ``stage``/``lanes``: as :func:`walk`'s (its rays, counted)."""
    r = walk(scene, sampler, ray, active, max_depth, rr_depth, lights, power_heuristic, split=split,
             directions=directions, stage=stage, lanes=lanes)
    L_ind = r.L_ind if split else mi.Spectrum(0.0)
    return r.L, L_ind, r.n_rays, r.first_valid


def trace_paths(scene, sampler, ray, active, max_depth: int, rr_depth: int, lights=None,
                power_heuristic: bool = True, indirect_only: bool = False, directions=None, *, stage: str = "trace",
                lanes: bool = False):
    """Camera-ray paths; return (radiance, rays traced per lane, first-hit validity).

    ``indirect_only`` keeps only the indirect part (:func:`trace_paths_split`): the "indirect" image
    the papers compare (same definition as the indirect reference: depth-D minus depth-2). Nothing is
    clamped: every term dropped is a non-negative sample contribution. ``stage``/``lanes``: as :func:`walk`'s."""
    L, L_ind, n_rays, first_valid = trace_paths_split(scene, sampler, ray, active, max_depth, rr_depth, lights,
                                                      power_heuristic, split=indirect_only, directions=directions,
                                                      stage=stage, lanes=lanes)
    return (L_ind if indirect_only else L), n_rays, first_valid


def render_paths(scene, camera, res, spp: int, seed: int, frame_index: int, max_depth: int,
                 rr_depth: int, lights=None, power_heuristic=True, indirect_only=False, directions=None, *,
                 stage: str = "trace", lanes: bool = False):
    """Render ``spp`` paths per pixel; return (mean colour per pixel, total rays as a Dr.Jit UInt32 sum).

    ``indirect_only``: the indirect part only (see :func:`trace_paths`). ``stage``/``lanes``: as
    :func:`render_paths_split`'s."""
    L, L_ind, n = render_paths_split(scene, camera, res, spp, seed, frame_index, max_depth, rr_depth, lights,
                                     power_heuristic, split=indirect_only, directions=directions, stage=stage,
                                     lanes=lanes)
    return (L_ind if indirect_only else L), n


def render_paths_split(scene, camera, res, spp: int, seed: int, frame_index: int, max_depth: int,
                       rr_depth: int, lights=None, power_heuristic=True, split: bool = True, directions=None, *,
                       stage: str = "trace", lanes: bool = False):
    """Render ``spp`` paths per pixel; return (mean colour, mean indirect colour, total rays as a UInt32 sum).

    ``seed``: a Python int mixed with ``frame_index`` (:func:`~dyngi.sampling.rng.make_sampler`), or a
    ``mi.UInt32`` seed already mixed (then ``frame_index`` is not read). The indirect image comes from the
    same paths (:func:`trace_paths_split`); without ``split`` it is 0 and costs nothing. ``scene``: a dyngi Scene or a Mitsuba scene.
    The rays are added to the open ray ledgers under ``stage`` (:mod:`dyngi.rays`) as the returned sum,
    unless ``lanes`` (a frozen function's body: its caller adds the returned sum)."""
    w, h = res
    n = w * h * spp
    if isinstance(seed, mi.UInt32):     # an already mixed Dr.Jit seed (a frozen frame's input)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, n)
    else:
        sampler = make_sampler(n, seed, frame_index)
    idx = dr.arange(mi.UInt32, n)
    pix = idx // dr.opaque(mi.UInt32, spp) if spp > 1 else idx
    ray = camera.sample_rays(res, pix, sampler.next_2d())
    L, L_ind, n_rays, _ = trace_paths_split(scene.mi_scene if hasattr(scene, "mi_scene") else scene, sampler,
                                            ray, dr.full(mi.Bool, True, n), max_depth, rr_depth, lights,
                                            power_heuristic, split,
                                            directions, stage=stage, lanes=True)
    if split:
        dr.eval(L, L_ind, n_rays)  # one kernel for the whole path loop; outputs evaluated together
    else:
        dr.eval(L, n_rays)
    if spp > 1:
        inv = dr.opaque(mi.Float, 1.0 / spp)
        L = dr.block_reduce(dr.ReduceOp.Add, L, spp) * inv
        if split:
            L_ind = dr.block_reduce(dr.ReduceOp.Add, L_ind, spp) * inv
    total = dr.sum(n_rays)
    if not lanes:
        rays.add(stage, total)
    return L, L_ind, total
