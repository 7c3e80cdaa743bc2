"""Tracing and shading probe rays (replaceable piece #2: what a probe ray returns).

Each probe ray is traced with ``scene.ray_intersect`` in one batch for the
whole volume. At a hit the radiance leaving the surface towards the probe is
estimated as in DDGI (Majercik et al., JCGT 2019, Sec. 3.1):

``L = Le + albedo / pi * (E_direct + E_probes(x, n))``

with ``E_direct`` from next-event estimation (one light sample; its shadow ray is skipped when the
sample lies below the shading normal, where it adds nothing) and
``E_probes`` read from the *previous* frame's probes (multi-bounce through
the cache). Surfaces are treated as diffuse with ``bsdf.eval_diffuse_reflectance``.
Back-face hits return radiance 0 and a negative distance ``-0.2 t`` (the
DDGI/RTXGI convention used for classification and relocation); misses return
distance ``+inf`` (clamped when blending).

Routing of emitters (parameter ``direct``) -- light must enter the cache or
NEE, never both:

* ``'nee'``: every emitter by NEE; the probes store light reflected at least once;
* ``'sky'`` (default): environment emitters (infinite, non-delta) are read by
  probe rays on a miss, all others by NEE (DDGI's sky + analytic lights);
* ``'emissive'``: only delta lights (point, spot, directional) by NEE;
  emissive surfaces and the environment enter through the probes (DDGI's
  original split; the probes then hold the total irradiance, e.g. ``pi L`` in
  a furnace of radiance ``L``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..backend import dr, mi
from ..errors import unknown_choice
from ..sampling.lights import EmitterSubsetSampling, sample_traced
from ..sampling.rng import make_sampler
from ..timing import maybe_stage
from .rays import RayPlan

DIRECT_MODES = ("nee", "sky", "emissive")
BACKFACE_DISTANCE_SCALE = 0.2


def vector_to_numpy(v) -> np.ndarray:
    """(C, n) float32 array from a Dr.Jit 3- or 2-vector, component by component.

    ``np.asarray`` of a nested array runs a Dr.Jit ravel kernel whose width is
    baked in (a recompile whenever the number of traced probes changes); the
    components of an evaluated array convert without any kernel.
    """
    return np.stack([np.asarray(v[i], np.float32) for i in range(len(v))])


def emitter_via_probes(emitter, mode: str, active=True):
    """Mask: is light of ``emitter`` (an EmitterPtr) carried by the probes rather than NEE under ``mode``?"""
    if mode == "nee":
        return mi.Bool(False)
    flags = emitter.flags()
    delta = mi.has_flag(flags, mi.EmitterFlags.DeltaPosition) | mi.has_flag(flags, mi.EmitterFlags.DeltaDirection)
    if mode == "sky":
        return mi.has_flag(flags, mi.EmitterFlags.Infinite) & ~delta & (emitter != None)  # noqa: E711
    return ~delta & (emitter != None)  # noqa: E711


def emitter_via_probes_host(emitter, mode: str) -> bool:
    """Host-side twin of :func:`emitter_via_probes` for one Python emitter object."""
    if mode == "nee":
        return False
    f = emitter.flags()
    delta = mi.has_flag(f, mi.EmitterFlags.DeltaPosition) or mi.has_flag(f, mi.EmitterFlags.DeltaDirection)
    if mode == "sky":
        return bool(mi.has_flag(f, mi.EmitterFlags.Infinite)) and not delta
    return not delta


_NEE_CACHE: dict = {}    # mode -> (mi_scene, sampler), for the most recent scene only


def nee_lights(mi_scene, mode: str) -> EmitterSubsetSampling:
    """NEE over exactly the emitters that the probes do not carry under ``mode`` (cached per scene).

    The cache holds the one scene it serves and checks identity (Mitsuba scenes
    take no weak references). Keyed by ``id`` alone, a freed scene's entry --
    with pointers to its freed emitters -- was handed to a new scene that got
    the same address, and the next kernel crashed. Only the latest scene is
    kept: every live scene's emitters and BSDFs take part in Dr.Jit's virtual
    calls, so keeping old scenes alive made every kernel bigger (the slow test
    suite ran 3x longer with 8 cached scenes).
    """
    if any(scene is not mi_scene for scene, _ in _NEE_CACHE.values()):
        _NEE_CACHE.clear()                      # a new scene: drop the old one
    if mode not in _NEE_CACHE:
        _NEE_CACHE[mode] = (mi_scene, EmitterSubsetSampling(mi_scene, lambda e: not emitter_via_probes_host(e, mode)))
    return _NEE_CACHE[mode][1]


def probes_carry_emitters(mi_scene, mode: str) -> bool:
    """Does any emitter of the scene reach the probes directly (a probe ray that sees it records its
    emission) under ``mode``? When none does, probe-ray shading skips the emitter lookup altogether."""
    return nee_lights(mi_scene, mode).count < len(mi_scene.emitters())


def check_direct_mode(mode: str) -> str:
    if mode not in DIRECT_MODES:
        raise unknown_choice("direct-light mode", mode, DIRECT_MODES)
    return mode


HIT_LOOKUPS = ("stochastic", "filtered")


class DiffuseHitShader:
    """Shades surface points as diffuse: emission + albedo/pi * (NEE + probe irradiance).

    ``shade(scene, ray, si, sampler, query, active) -> (L, hit, front, shadow)``: radiance towards the
    ray's origin, the hit and front-face masks and the lanes that cast an NEE shadow ray (samples below
    the shading normal cast none: their diffuse contribution is 0). ``query`` is a
    :class:`~dyngi.probes.query.ProbeQuery` (or ``None`` for no multi-bounce).
    ``lookup``: how the multi-bounce term reads the probes -- ``'filtered'``
    (default: DDGI's 8 probes x bilinear texels at every hit) or
    ``'stochastic'`` (one texel of one probe with the expectation of the full
    filter, see :mod:`dyngi.probes.query`; the blend averages the extra noise
    away; the ``ddgi`` technique's default).
    """

    def __init__(self, direct: str = "sky", lights=None, lookup: str = "filtered"):
        self.direct = check_direct_mode(direct)
        self.lights = lights   # None: NEE over the emitters the probes do not carry (nee_lights)
        if lookup not in HIT_LOOKUPS:
            raise unknown_choice("probe lookup at hits", lookup, HIT_LOOKUPS)
        self.lookup = lookup

    def shade(self, scene, ray, si, sampler, query, active):
        hit = active & si.is_valid()
        front = hit & (dr.dot(si.n, ray.d) < 0.0)
        # -- emission seen by the ray (hit emitter or environment on a miss), if the probes carry any --
        L = mi.Color3f(0.0)
        if probes_carry_emitters(scene, self.direct):
            em = si.emitter(scene, active)
            Le = em.eval(si, active & (front | ~hit))
            L = mi.Color3f(dr.select(emitter_via_probes(em, self.direct, active), Le, 0.0))
        # -- diffuse albedo --
        bsdf = si.bsdf(ray)
        albedo = bsdf.eval_diffuse_reflectance(si, front)
        # -- direct light by NEE (one light sample; no shadow ray below the shading normal) --
        lights = self.lights if self.lights is not None else nee_lights(scene, self.direct)
        ds, w, shadow = sample_traced(lights, scene, si, sampler.next_2d(), front, receiver=si.sh_frame.n)
        cos = dr.maximum(dr.dot(si.sh_frame.n, ds.d), 0.0)
        if self.lights is not None:   # a general strategy may pick emitters the probes carry
            w = dr.select(emitter_via_probes(ds.emitter, self.direct, front), 0.0, w)
        E = w * cos
        # -- multi-bounce from the previous frame's probes --
        if query is not None:
            E += query.irradiance(si.p, si.sh_frame.n, -ray.d, active=front,
                                  sampler=sampler if self.lookup == "stochastic" else None)
        L += dr.select(front, albedo * dr.inv_pi * E, 0.0)
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
    n = dr.width(plan.direction)
    with maybe_stage(timer, "trace probes"):
        origin = dr.gather(mi.Point3f, volume.device.positions, plan.probe)
        ray = mi.Ray3f(origin, plan.direction)
        pi = mscene.ray_intersect_preliminary(ray, coherent=False)
        # only the hits are stored: the shade kernel recomputes the rays (two gathers) instead of
        # reading back 6 floats per ray
        dr.eval(pi)
        # -- the shade kernel, traced while the intersection kernel runs --
        si = pi.compute_surface_interaction(ray, mi.RayFlags.All)
        sampler = make_sampler(n, seed, frame, stream)
        L, hit, front, shadow = shader.shade(mscene, ray, si, sampler, query, mi.Bool(True))
        dist = dr.select(hit, dr.select(front, si.t, -BACKFACE_DISTANCE_SCALE * si.t), dr.inf)
        L = dr.select(dr.isfinite(L), L, 0.0)   # guard: a NaN/Inf sample must never enter the cache
    if timer is not None:
        timer.add_rays("trace probes", n)
    with maybe_stage(timer, "shade probes"):
        dr.eval(L, dist, shadow)     # the shadow-ray mask too: one kernel whether or not rays are counted
    if timer is not None:
        timer.add_rays("shade probes", dr.count(shadow))     # the NEE shadow rays cast (counted lazily)
    return ProbeRayResults(L, dist, plan)


def trace_probe_distances(scene, volume, plan: RayPlan) -> "mi.Float":
    """Signed hit distances only (classification rays): back faces ``-0.2 t``, misses ``+inf``."""
    mscene = scene.mi_scene if hasattr(scene, "mi_scene") else scene
    origin = dr.gather(mi.Point3f, volume.device.positions, plan.probe)
    ray = mi.Ray3f(origin, plan.direction)
    si = mscene.ray_intersect(ray, ray_flags=mi.RayFlags.Minimal, coherent=False)
    hit = si.is_valid()
    front = dr.dot(si.n, ray.d) < 0.0
    dist = dr.select(hit, dr.select(front, si.t, -BACKFACE_DISTANCE_SCALE * si.t), dr.inf)
    dr.eval(dist)
    return dist
