"""Tracing and shading probe rays (replaceable piece #2: what a probe ray returns).

Each probe ray is traced with ``scene.ray_intersect`` in one batch for the
whole volume. At a hit the radiance leaving the surface towards the probe is
estimated as in DDGI (Majercik et al., JCGT 2019, Sec. 3.1):

``L = Le + albedo / pi * (E_direct + E_probes(x, n))``

with ``E_direct`` from next-event estimation (one light sample; its shadow ray is skipped when the
sample lies below the shading normal, where it adds nothing) and
``E_probes`` read from the *previous* frame's probes (multi-bounce through
the cache). ``albedo`` is the albedo the hit reflects as diffuse light, :func:`hit_albedo` under the
volume's **hit-lobe rule** (:attr:`~dyngi.probes.volume.ProbeVolume.hit_lobes`, parameter ``hit_lobes``
of every probe technique):

* ``'layered'`` (default, ours): the diffuse lobe's albedo
  (:func:`dyngi.sampling.diffuse.diffuse_albedo`: 0 for metals and glass) plus, on a BSDF that has a
  diffuse lobe under a rough coating (``plastic``, ``roughplastic``, ``principled``), the directional
  albedo of its rough glossy reflection lobes, one BSDF sample per ray (``f cos / pdf`` of a
  glossy-only sample: unbiased, and nearly constant for the coatings' small roughness). A probe ray
  asks how much light the hit sends back; the coating reflects ~4-10% of it in every direction the
  probes' many rays see, and dropping it lost that share at every bounce of the multi-bounce
  feedback (the wooden staircase's painted walls and wood; docs/probes.md, "The wooden staircase").
  Metals stay 0 (no diffuse lobe: DDGI's diffuse GI);
* ``'diffuse'``: the diffuse lobe only (DDGI, Majercik et al. 2019, Sec. 3.1: the hit is shaded as
  Lambertian with its diffuse albedo).
Back-face hits return a negative distance ``-0.2 t`` (the DDGI/RTXGI
convention used for classification and relocation) and radiance 0. The back of
a two-sided surface is *shaded* like its front (:func:`~dyngi.scene.surface.shading_side`: Mitsuba
does); whether it also counts as a front face for the distance sign is the
**two-sided rule** below. Misses return distance ``+inf`` (clamped when blending).

**The two-sided rule** (one decision for the distance moments, relocation and
classification alike: all three read the one signed distance the tracer
returns; the rule is the probe volume's :attr:`~dyngi.probes.volume.ProbeVolume.two_sided`,
a parameter of every probe technique). A one-sided surface has an inside (its
back), a two-sided one has none by itself: scenes model single walls as
two-sided planes whose normals may point either way (veach-bidir's room is
closed by outward-facing planes), and solids as closed two-sided meshes
(thick slabs). Only the *shape of the enclosure* tells the two apart, so:

* ``'enclosed'`` (default, ours): a ray that hits the back of a two-sided
  surface reports a back face iff the probe is *enclosed* along that line by
  something thinner than a cell: the opposite ray (from the probe, ``-d``)
  hits a two-sided surface (either side) or a one-sided back face, and the two
  hits are nearer together than the chord of one cell along ``d``
  (``min_i spacing_i / |d_i|``). A probe inside a two-sided slab, wall or step
  thinner than a cell is therefore inside geometry -- relocated out of it and,
  where it cannot leave, classified away -- exactly as inside a one-sided
  solid; a probe in a room bounded by two-sided planes (a chord across the
  room, longer than a cell) sees their backs as the front faces they are for
  the light. Costs one short extra ray per two-sided back hit nearer than a
  cell chord (:func:`probe_hit_front`).
* ``'front'``: every two-sided back hit is a front face (commit 7d79077): no
  probe ever finds itself inside a two-sided solid, so probes in thick slabs
  stay active there or are pushed out on the wrong side (the sealed-room leak
  of issue 22);
* ``'back'``: the geometric normal decides (before 7d79077): rooms closed by
  outward-facing two-sided planes classify all their probes away
  (veach-bidir 0.36 of Mitsuba's mean). Probe rays and shadow rays pass
straight through clear surfaces (``dielectric``, ``thindielectric``,
``null``), attenuated by their transmittance, up to
:data:`~dyngi.scene.passthrough.MAX_GLASS_LAYERS` of them: a deliberate
bias, as real-time engines treat glass for GI (:mod:`dyngi.scene.passthrough`).

Routing of emitters (parameter ``direct``; validated by :func:`check_direct_mode`
only) -- every emitter's light enters the image through exactly one of NEE
(at the primary hit and at probe-ray hits) or the probes, never both:

* ``'sun'`` (default): NEE samples every area, point, spot and directional
  emitter and the *sun* of a ``sunsky`` emitter (its ``sky_scale = 0`` part,
  :mod:`dyngi.scene.sunsky`); the *sky* of a ``sunsky`` (its ``sun_scale = 0``
  part) and plain ``envmap``/``constant`` emitters reach the image only through
  the probes' miss rays, which evaluate exactly that sky part;
* ``'sky'``: the whole environment (infinite, non-delta emitters, a
  ``sunsky``'s sun included) through the probes' miss rays, all others by NEE
  (the split before issue 11; a sun in a ``sunsky`` is then carried only by
  the probes, which blur it);
* ``'nee'``: every emitter by NEE; the probes store light reflected at least once;
* ``'emissive'``: only delta lights (point, spot, directional) by NEE;
  emissive surfaces and the environment enter through the probes (DDGI's
  original split; the probes then hold the total irradiance, e.g. ``pi L`` in
  a furnace of radiance ``L``).

In every mode the camera seeing an emitter or the environment directly
evaluates the full emitter (the primary hit's ``Le``), since neither NEE nor
the probes carry light the camera sees without a bounce.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError, unknown_choice
from ..lights.nee import TracedNEE
from ..rays import intersect, intersect_preliminary
from ..sampling.diffuse import diffuse_albedo, front_wi, has_diffuse_lobe
from ..scene.surface import shading_side
from ..lights.emitter_sampling import EmitterSubsetSampling, sample_traced
from ..scene.passthrough import intersect_through_glass, scene_has_glass
from ..sampling.rng import make_sampler
from ..scene.sunsky import is_sunsky, split_sunsky
from ..timing import maybe_stage
from .glossy import sample_glossy
from .lookup import diffuse_radiance
from .rays import RayPlan

DIRECT_MODES = ("sun", "sky", "nee", "emissive")
DEFAULT_DIRECT = "sun"
BACKFACE_DISTANCE_SCALE = 0.2
HIT_LOBES = ("layered", "diffuse")
"""Which lobes a probe-ray hit reflects as diffuse light (module docstring, the hit-lobe rule)."""
DEFAULT_HIT_LOBES = "layered"
TWO_SIDED_RULES = ("enclosed", "front", "back")
"""How the back of a two-sided surface signs a probe ray's distance (module docstring, "The two-sided rule")."""
DEFAULT_TWO_SIDED = "enclosed"


def check_two_sided(rule: str) -> str:
    """The one validation of the two-sided rule: returns it, or raises a DyngiError listing the choices."""
    if rule not in TWO_SIDED_RULES:
        raise unknown_choice("two-sided rule", rule, TWO_SIDED_RULES)
    return rule


def check_hit_lobes(rule: str) -> str:
    if rule not in HIT_LOBES:
        raise unknown_choice("probe-hit lobe rule", rule, HIT_LOBES)
    return rule


def coating_albedo(bsdf, si, active, u1, u2):
    """The rough glossy reflection lobes' directional albedo towards ``si.wi`` on lanes whose BSDF also has a
    diffuse lobe (a coating: ``plastic``, ``roughplastic``, ``principled``), else 0: one BSDF sample from
    ``(u1, u2)`` with ``type_mask = GlossyReflection``, its ``f cos / pdf`` (unbiased)."""
    coated = mi.Bool(active) & has_diffuse_lobe(bsdf)
    _, w, _ = sample_glossy(bsdf, front_wi(si), u1, u2, coated, lobes=mi.BSDFFlags.GlossyReflection)
    return w


def hit_albedo(bsdf, si, active, u1, u2, rule: str = DEFAULT_HIT_LOBES):
    """Albedo a probe-ray hit reflects as diffuse light (module docstring, the hit-lobe rule): the diffuse
    lobe's (:func:`~dyngi.sampling.diffuse.diffuse_albedo`) plus, under ``'layered'`` (ours),
    :func:`coating_albedo` from ``(u1, u2)``. Clamped to [0, 1]."""
    albedo = diffuse_albedo(bsdf, si, active)
    if check_hit_lobes(rule) == "diffuse":
        return albedo
    return dr.clip(albedo + coating_albedo(bsdf, si, active, u1, u2), 0.0, 1.0)


def check_direct_mode(mode: str) -> str:
    """The one validation of the ``direct`` routing parameter: returns it, or raises a DyngiError."""
    if mode not in DIRECT_MODES:
        raise unknown_choice("direct-light mode", mode, DIRECT_MODES)
    return mode


def vector_to_numpy(v) -> np.ndarray:
    """(C, n) float32 array from a Dr.Jit 3- or 2-vector, component by component.

    ``np.asarray`` of a nested array runs a Dr.Jit ravel kernel whose width is
    baked in (a recompile whenever the number of traced probes changes); the
    components of an evaluated array convert without any kernel.
    """
    return np.stack([np.asarray(v[i], np.float32) for i in range(len(v))])


def _is_delta(f) -> bool:
    return bool(mi.has_flag(f, mi.EmitterFlags.DeltaPosition) or mi.has_flag(f, mi.EmitterFlags.DeltaDirection))


def _is_environment(emitter) -> bool:
    f = emitter.flags()
    return bool(mi.has_flag(f, mi.EmitterFlags.Infinite)) and not _is_delta(f)


def emitter_split_host(emitter, mode: str) -> bool:
    """Is ``emitter`` shared between NEE (its sun) and the probes (its sky) under ``mode``?"""
    return mode == "sun" and is_sunsky(emitter)


def emitter_via_probes_host(emitter, mode: str) -> bool:
    """Is *all* the light of ``emitter`` (one Python emitter object) carried by the probes under ``mode``?"""
    check_direct_mode(mode)
    if mode == "nee":
        return False
    if mode == "emissive":
        return not _is_delta(emitter.flags())
    return _is_environment(emitter) and not emitter_split_host(emitter, mode)


def emitter_via_probes(emitter, mode: str, active=True, split_ids=()):
    """Per lane: is *all* the light of ``emitter`` (an EmitterPtr) carried by the probes under ``mode``?
    ``split_ids``: registry ids of the ``sunsky`` emitters that are split under ``'sun'`` (not wholly the
    probes'; :attr:`LightRouting.split_ids`, see :meth:`LightRouting.nee_weight`)."""
    check_direct_mode(mode)
    if mode == "nee":
        return mi.Bool(False)
    flags = emitter.flags()
    delta = mi.has_flag(flags, mi.EmitterFlags.DeltaPosition) | mi.has_flag(flags, mi.EmitterFlags.DeltaDirection)
    valid = emitter != None  # noqa: E711
    if mode == "emissive":
        return ~delta & valid
    env = mi.has_flag(flags, mi.EmitterFlags.Infinite) & ~delta & valid
    if mode == "sun":
        for sid in split_ids:
            env &= dr.reinterpret_array(mi.UInt32, emitter) != sid
    return env


class LightRouting:
    """Which light NEE samples and which the probes carry, for one scene and one ``direct`` mode.

    * ``nee``: an :class:`~dyngi.lights.emitter_sampling.EmitterSubsetSampling` over the
      emitters NEE owns (plus the standalone sun part of a ``sunsky`` under ``'sun'``);
    * ``probe_env``: the emitter a probe ray's miss evaluates (the scene's
      environment, its sky part, or ``None``);
    * ``probe_hits``: do probe rays that hit an emitting surface record its emission (``'emissive'``)?
    """

    def __init__(self, mi_scene, mode: str):
        self.mode = check_direct_mode(mode)
        emitters = list(mi_scene.emitters())
        self.splits = []          # (sunsky emitter, its registry id, sun part, sky part)
        if mode == "sun":
            for e in emitters:
                if is_sunsky(e):
                    sun, sky = split_sunsky(e, mi_scene)
                    rid = int(np.asarray(dr.reinterpret_array(mi.UInt32, mi.EmitterPtr([e])))[0])
                    self.splits.append((e, rid, sun, sky))
        self.split_ids = tuple(s[1] for s in self.splits)
        suns = [s[2] for s in self.splits]
        self.nee = EmitterSubsetSampling(mi_scene, lambda e: not emitter_via_probes_host(e, mode)
                                         and not emitter_split_host(e, mode), extra=suns)
        env = mi_scene.environment()
        self.probe_env = None
        if env is not None and mode != "nee" and _is_environment(env):
            self.probe_env = env
            for e, _, _, sky in self.splits:
                if e is env:
                    self.probe_env = sky       # None when the sky scale is 0
        self.probe_hits = mode == "emissive" and any(not _is_delta(e.flags()) and not _is_environment(e)
                                                     for e in emitters)

    @property
    def probes_carry_emitters(self) -> bool:
        return self.probe_env is not None or self.probe_hits

    def probe_emission(self, scene, si, hit, front, active):
        """Emission a probe ray records: the environment part the probes carry on a miss, and (only
        under ``'emissive'``) the emission of a front-facing emitter it hits."""
        L = mi.Color3f(0.0)
        if self.probe_env is not None:
            miss = active & ~hit
            L += dr.select(miss, mi.Color3f(self.probe_env.eval(si, miss)), 0.0)
        if self.probe_hits:
            em = si.emitter(scene, active & front)
            on = active & front & emitter_via_probes(em, self.mode, active & front, self.split_ids)
            L += dr.select(on, mi.Color3f(em.eval(si, on)), 0.0)
        return L

    def nee_weight(self, ds, w, active):
        """The share of a light sample ``(ds, w)`` drawn by a *general* strategy (one that may pick any
        emitter) that NEE owns: 0 for emitters the probes carry, and for a split ``sunsky`` its sun's
        part ``w * L_sun(d) / L(d)``; unchanged otherwise."""
        w = dr.select(emitter_via_probes(ds.emitter, self.mode, active, self.split_ids), 0.0, mi.Color3f(w))
        for e, rid, sun, _ in self.splits:
            mine = active & (dr.reinterpret_array(mi.UInt32, ds.emitter) == rid)
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = -ds.d
            full = mi.Color3f(e.eval(si, mine))
            part = mi.Color3f(sun.eval(si, mine)) if sun is not None else mi.Color3f(0.0)
            w = dr.select(mine, w * dr.select(full > 0.0, part / full, 0.0), w)
        return w


_ROUTING_CACHE: dict = {}    # mode -> (mi_scene, LightRouting), for the most recent scene only


def light_routing(mi_scene, mode: str) -> LightRouting:
    """The :class:`LightRouting` of ``mi_scene`` under ``mode`` (cached per scene).

    The cache holds the one scene it serves and checks identity (Mitsuba scenes
    take no weak references). Keyed by ``id`` alone, a freed scene's entry --
    with pointers to its freed emitters -- was handed to a new scene that got
    the same address, and the next kernel crashed. Only the latest scene is
    kept: every live scene's emitters and BSDFs take part in Dr.Jit's virtual
    calls, so keeping old scenes alive made every kernel bigger (the slow test
    suite ran 3x longer with 8 cached scenes).
    """
    if any(scene is not mi_scene for scene, _ in _ROUTING_CACHE.values()):
        _ROUTING_CACHE.clear()                  # a new scene: drop the old one
    if mode not in _ROUTING_CACHE:
        _ROUTING_CACHE[mode] = (mi_scene, LightRouting(mi_scene, mode))
    return _ROUTING_CACHE[mode][1]


def nee_lights(mi_scene, mode: str) -> EmitterSubsetSampling:
    """NEE over exactly the light that the probes do not carry under ``mode`` (cached per scene)."""
    return light_routing(mi_scene, mode).nee


def probes_carry_emitters(mi_scene, mode: str) -> bool:
    """Does any emitter of the scene reach the probes directly (a probe ray that sees it records its
    emission) under ``mode``? When none does, probe-ray shading skips the emitter lookup altogether."""
    return light_routing(mi_scene, mode).probes_carry_emitters


HIT_LOOKUPS = ("stochastic", "filtered")


class DiffuseHitShader:
    """Shades surface points as diffuse: emission + albedo/pi * (NEE + probe irradiance).

    ``shade(scene, ray, si, sampler, query, active) -> (L, hit, front, shadow)``: radiance towards the
    ray's origin, the hit and front-face masks and the lanes that cast an NEE shadow ray (samples below
    the shading normal cast none: their diffuse contribution is 0). ``query`` is a
    :class:`~dyngi.probes.query.ProbeQuery` (or ``None`` for no multi-bounce).
    ``lights``: ``None`` (NEE over the light the probes do not carry, :func:`nee_lights`), a light-sampling
    strategy with ``sample_traced`` over any emitters, or a :class:`~dyngi.lights.nee.LightNEE` (a
    ``dyngi.lights`` sampler, ``lights=`` of the probe techniques; used through
    :class:`~dyngi.lights.nee.TracedNEE` with this shader's sampler, its samples recorded for a learning
    sampler). A general strategy's samples are weighted by :meth:`LightRouting.nee_weight` (our choice: the
    routing stays the ``direct`` mode's whatever the sampler, so a sampler changes the noise, not the mean).
    ``lookup``: how the multi-bounce term reads the probes -- ``'filtered'``
    (default: DDGI's 8 probes x bilinear texels at every hit) or
    ``'stochastic'`` (one texel of one probe with the expectation of the full
    filter, see :mod:`dyngi.probes.query`; the blend averages the extra noise
    away; the ``ddgi`` technique's default).
    """

    hit_lobes = DEFAULT_HIT_LOBES
    """The hit-lobe rule (module docstring); :func:`trace_probe_rays` sets the traced volume's."""

    def __init__(self, direct: str = DEFAULT_DIRECT, lights=None, lookup: str = "filtered"):
        self.direct = check_direct_mode(direct)
        self.lights = lights   # None: NEE over the light the probes do not carry (nee_lights)
        if lookup not in HIT_LOOKUPS:
            raise unknown_choice("probe lookup at hits", lookup, HIT_LOOKUPS)
        self.lookup = lookup

    def shade(self, scene, ray, si, sampler, query, active):
        hit = active & si.is_valid()
        bsdf = si.bsdf(ray)
        front, n = shading_side(si, ray, bsdf, hit)       # two-sided surfaces face the ray from both sides
        routing = light_routing(scene, self.direct)
        # -- emission the probes carry (the sky part on a miss; emitting surfaces under 'emissive') --
        L = mi.Color3f(0.0)
        if routing.probes_carry_emitters:
            L = routing.probe_emission(scene, si, hit, front, active)
        # -- diffuse albedo (the diffuse lobe only: 0 for metals and glass; the coating's below) --
        albedo = diffuse_albedo(bsdf, si, front)
        # -- direct light by NEE (one light sample; no shadow ray below the shading normal) --
        lights = self.lights if self.lights is not None else routing.nee
        if getattr(lights, "walk_aware", False):     # a dyngi.lights sampler: its selection number from `sampler`
            lights = TracedNEE(lights, sampler, record=True)
        ds, w, shadow = sample_traced(lights, scene, si, sampler.next_2d(), front, receiver=n, stage="shade probes")
        cos = dr.maximum(dr.dot(n, ds.d), 0.0)
        if self.lights is not None:   # a general strategy may pick light the probes carry
            w = routing.nee_weight(ds, w, front)
        E = w * cos
        # -- multi-bounce from the previous frame's probes --
        if query is not None:
            E += query.irradiance(si.p, n, -ray.d, active=front,
                                  sampler=sampler if self.lookup == "stochastic" else None)
        # -- the hit-lobe rule: a coating's glossy albedo reflected as diffuse light too (ours). Its numbers
        # are drawn last, so that the draws above (NEE, the stochastic lookup) are those of 'diffuse' --
        if check_hit_lobes(self.hit_lobes) == "layered":
            albedo = dr.minimum(albedo + coating_albedo(bsdf, si, front, sampler.next_1d(), sampler.next_2d()),
                                1.0)
        L += diffuse_radiance(albedo, E, front)
        return L, hit, front, shadow


@dataclass
class ProbeRayResults:
    radiance: "mi.Color3f"      # per ray
    distance: "mi.Float"        # per ray: hit distance, negative (-0.2 t) for back faces, +inf on a miss
    plan: RayPlan
    _host: tuple | None = field(default=None, init=False, repr=False)

    def host(self) -> tuple:
        """(radiance (3, n) channel-planar, distance (n,)) float32 host copies, pulled once and kept.

        Pulling waits for the Dr.Jit work queued so far; the probe update pulls
        right after tracing, so that kernels it launches later (the state
        summaries) can run beside the host's blend products.
        """
        if self._host is None:
            self._host = (vector_to_numpy(self.radiance), np.asarray(self.distance, np.float32))
        return self._host

    def to_numpy(self):
        """(radiance (P, N, 3) float32, distance (P, N) float32) for plans with a constant count per probe."""
        n = self.plan.rays_per_probe
        if not n:
            raise DyngiError("ProbeRayResults.to_numpy needs a constant ray count per probe; for a ragged "
                             "plan use host() with plan.offsets")
        P = len(self.plan.probe_ids)
        rad, dist = self.host()
        return rad.reshape(3, P, n).transpose(1, 2, 0), dist.reshape(P, n)


def trace_probe_rays(scene, volume, plan: RayPlan, shader: DiffuseHitShader, query, seed: int, frame: int,
                     stream: int = 11, timer=None) -> ProbeRayResults:
    """Trace all rays of ``plan`` from the probes of ``volume`` (one batch) and shade their hits.

    Two kernels: the preliminary intersection (stage ``trace probes`` of ``timer``)
    and surface interaction + shading (stage ``shade probes``). The shade kernel
    is traced (built in Python) while the intersection kernel runs, so that
    Python time hides behind it; it counts towards ``trace probes``.
    """
    mscene = scene.mi_scene if hasattr(scene, "mi_scene") else scene
    volume.geometry = mscene      # relocation checks its moves against the geometry the rays saw
    n = dr.width(plan.direction)
    masked = plan.valid is not None      # a masked plan: only its valid lanes trace (no host read)
    active = plan.valid if masked else mi.Bool(True)
    with maybe_stage(timer, "trace probes"):
        origin = dr.gather(mi.Point3f, volume.device.positions, plan.probe)
        ray = mi.Ray3f(origin, plan.direction)
        glass = scene_has_glass(mscene)
        if glass:   # clear surfaces pass the ray (attenuated); one kernel with the shading
            si, throughput, t_hit, _ = intersect_through_glass(mscene, ray, active, stage="trace probes")
        elif masked:
            pi = intersect_preliminary(mscene, ray, False, active, stage="trace probes")
            dr.eval(pi)
            si = pi.compute_surface_interaction(ray, mi.RayFlags.All, active)
            t_hit = si.t
        else:
            pi = intersect_preliminary(mscene, ray, False, stage="trace probes")
            # only the hits are stored: the shade kernel recomputes the rays (two gathers) instead of
            # reading back 6 floats per ray
            dr.eval(pi)
            # -- the shade kernel, traced while the intersection kernel runs --
            si = pi.compute_surface_interaction(ray, mi.RayFlags.All)
            t_hit = si.t
        sampler = make_sampler(n, seed, frame, stream)
        if isinstance(shader, DiffuseHitShader):      # the volume's hit-lobe rule (module docstring)
            shader.hit_lobes = getattr(volume, "hit_lobes", DEFAULT_HIT_LOBES)
        L, hit, front, shadow = shader.shade(mscene, ray, si, sampler, query, active)
        if glass:
            L = L * throughput
        signed_front = probe_hit_front(mscene, volume, ray, si, t_hit, hit, glass)
        dist = dr.select(hit, dr.select(signed_front, t_hit, -BACKFACE_DISTANCE_SCALE * t_hit), dr.inf)
        L = dr.select(dr.isfinite(L), L, 0.0)   # guard: a NaN/Inf sample must never enter the cache
    if timer is not None:
        timer.add_rays("trace probes", plan.rays_cast() if masked else n)
    with maybe_stage(timer, "shade probes"):
        dr.eval(L, dist, shadow)     # the shadow-ray mask too: one kernel whether or not rays are counted
    if timer is not None:
        timer.add_rays("shade probes", dr.count(shadow))     # the NEE shadow rays cast (counted lazily)
    return ProbeRayResults(L, dist, plan)


def trace_probe_distances(scene, volume, plan: RayPlan, stage: str = "distances") -> "mi.Float":
    """Signed hit distances only (classification rays): back faces ``-0.2 t``, misses ``+inf``. ``stage``:
    the name its rays are counted under (:mod:`dyngi.rays`)."""
    mscene = scene.mi_scene if hasattr(scene, "mi_scene") else scene
    volume.geometry = mscene
    origin = dr.gather(mi.Point3f, volume.device.positions, plan.probe)
    ray = mi.Ray3f(origin, plan.direction)
    glass = scene_has_glass(mscene)
    masked = plan.valid is not None
    if glass:     # clear surfaces are no geometry for classification either
        si, _, t_hit, _ = intersect_through_glass(mscene, ray, plan.valid if masked else mi.Bool(True), stage=stage)
    elif masked:  # a masked plan: only its valid lanes trace
        si = intersect(mscene, ray, mi.RayFlags.Minimal, False, plan.valid, stage=stage)
        t_hit = si.t
    else:
        si = intersect(mscene, ray, mi.RayFlags.Minimal, False, stage=stage)
        t_hit = si.t
    hit = si.is_valid()
    front = probe_hit_front(mscene, volume, ray, si, t_hit, hit, glass)
    dist = dr.select(hit, dr.select(front, t_hit, -BACKFACE_DISTANCE_SCALE * t_hit), dr.inf)
    dr.eval(dist)
    return dist


def _two_sided_hit(si, ray, hit):
    """(geometric front, two-sided) masks of the hits ``si`` of ``ray``."""
    geo_front = hit & (dr.dot(si.n, ray.d) < 0.0)
    bsdf = si.bsdf(ray)
    two = hit & mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide) & (bsdf != None)   # noqa: E711
    return geo_front, two


def probe_hit_front(mscene, volume, ray, si, t_hit, hit, glass: bool = False):
    """Per probe ray: does its hit count as a *front* face for the distance sign (hence for the distance
    moments, relocation and classification)? The two-sided rule of ``volume`` (module docstring).

    One-sided surfaces: the geometric normal decides. Two-sided ones hit from behind, under
    ``'enclosed'``: a back face iff the opposite ray from the probe meets a two-sided surface or a
    one-sided back face within the chord of one cell along the ray's line (``min_i s_i / |d_i|``) minus
    the hit distance -- the probe sits inside something thinner than a cell. Only the lanes with such
    a near two-sided back hit trace the opposite ray (masked; bounded by ``maxt``)."""
    rule = check_two_sided(getattr(volume, "two_sided", DEFAULT_TWO_SIDED))
    geo_front, two = _two_sided_hit(si, ray, hit)
    if rule == "back":
        return geo_front
    if rule == "front":
        return geo_front | two
    back2 = two & ~geo_front
    _, spacing, _ = volume.grid.opaque_params()
    ad = dr.abs(ray.d)
    big = 3.0e38
    chord = dr.minimum(dr.minimum(dr.select(ad.x > 0.0, spacing.x / ad.x, big),
                                  dr.select(ad.y > 0.0, spacing.y / ad.y, big)),
                       dr.select(ad.z > 0.0, spacing.z / ad.z, big))
    near = back2 & (t_hit < chord)
    opp = mi.Ray3f(ray.o, -ray.d)
    if glass:    # clear surfaces are no enclosure either
        si2, _, t2, _ = intersect_through_glass(mscene, opp, near, stage="two-sided")
    else:
        opp.maxt = dr.select(near, chord - t_hit, 0.0)
        si2 = intersect(mscene, opp, mi.RayFlags.Minimal, False, near, stage="two-sided")
        t2 = si2.t
    hit2 = near & si2.is_valid() & (t2 <= chord - t_hit)
    front2, two2 = _two_sided_hit(si2, opp, hit2)
    enclosed = hit2 & (two2 | ~front2)
    return geo_front | (back2 & ~enclosed)
