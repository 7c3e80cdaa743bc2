"""Primary-vertex shading with a probe volume (the DDGI consumer, Majercik et al. 2019, Sec. 4).

``L = T * (Le + sum_NEE f * Le_light / pdf + albedo / pi * E_probes(x, n))`` at
the first opaque surface the camera ray meets: emission seen directly (the full
emitter, environment included, in every ``direct`` mode), direct light by NEE
over the light the probes do not carry (:mod:`dyngi.probes.trace`, routing),
and the probes' irradiance times the diffuse lobe's albedo
(:func:`dyngi.sampling.diffuse.diffuse_albedo`; glossy indirect light is not
part of DDGI). NEE evaluates the full BSDF (``bsdf.eval``): direct light on a
metal is its true glossy reflection.

Glossy indirect light (``glossy=True``; the probe techniques' ``glossy`` parameter, default off):
the primary vertex adds DDGI Resampling's Eq. 6 glossy term (Majercik et al. 2022, Sec. 3.4;
:mod:`dyngi.probes.glossy`) to the indirect part, one sample of the BSDF's glossy lobes and the
probe irradiance read along the sampled direction, over pi (the normalisation settled by
``tests/probes/test_ddgi_plus.py::test_glossy_furnace_pi_normalisation``):

``L += T * E(x, wi) / pi * f_g(wo, wi) cos(n, wi) / p(wi)``.

Only the *rough* lobes are sampled (:data:`PRIMARY_GLOSSY_LOBES`: glossy reflection and
transmission), not the delta ones (our choice, unlike :data:`dyngi.probes.glossy.GLOSSY_LOBES`): a
mirror or a smooth dielectric keeps today's handling (a mirror's indirect light is black, clear glass
is passed through), since an 8x8 cosine-prefiltered texel read along a mirror direction is a blur, not
a reflection; and a BSDF with a delta and a rough lobe (a coated conductor) does not lose the rough
lobe's share to the delta one. The sample's numbers come from the primary sampler after the NEE
draws (one 1D + one 2D draw per pixel), so ``glossy=False`` draws nothing more and its image is
bit-identical to the diffuse-only shading. ``volume_query.irradiance`` must accept ``direction=``
(:class:`~dyngi.probes.query.ProbeQuery` does).

Surfaces face the camera by :func:`~dyngi.scene.surface.shading_side` (the back of a
``twosided`` surface is shaded like its front, as Mitsuba shades it).

Camera rays pass straight through clear surfaces (``dielectric``,
``thindielectric``, ``null``) with their transmittance ``T``, as real-time
engines draw glass (a transparent pass without refraction;
:mod:`dyngi.scene.passthrough`): a deliberate bias -- the glass's own
reflection (~4-8%) is dropped and a solid glass object is not refracted (a
flat pane does not shift the image, a glass ball would).
"""
from __future__ import annotations

from ..backend import dr, mi
from ..rays import intersect
from ..lights.nee import PRIMARY_NEE_STREAM, TracedNEE
from ..sampling.diffuse import diffuse_albedo
from ..lights.emitter_sampling import sample_traced
from ..scene.passthrough import intersect_through_glass, scene_has_glass
from ..sampling.rng import make_sampler
from .glossy import glossy_lookup
from .lookup import diffuse_radiance
from ..scene.surface import shading_side
from .trace import light_routing

PRIMARY_GLOSSY_LOBES = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.GlossyTransmission
"""The lobes the primary vertex's glossy term samples: the rough ones, not delta (module docstring)."""


def shade_primary(scene, camera, res, volume_query, seed: int, frame: int, direct: str, jitter: bool,
                  lights=None, direct_samples: int = 1, glossy: bool = False):
    """Primary-vertex shading (the consumer): emission + NEE direct + albedo/pi * probe irradiance.

    ``glossy``: also Eq. 6's glossy probe lookup at the primary vertex (module docstring), added to the
    indirect part; False (default) is the diffuse-only shading, bit for bit.

    Direct light: ``direct_samples`` NEE samples per pixel over the light the
    probes do not carry (:func:`dyngi.probes.trace.nee_lights`), unless a
    ``lights`` strategy is given (its samples are then weighted by
    :meth:`~dyngi.probes.trace.LightRouting.nee_weight`). A :class:`~dyngi.lights.nee.LightNEE`
    (``lights=`` of the probe techniques) is used through :class:`~dyngi.lights.nee.TracedNEE`, its
    light-selection numbers from stream :data:`~dyngi.lights.nee.PRIMARY_NEE_STREAM` of ``(seed, frame)``
    (opaque), its samples recorded for a learning sampler. DDGI itself shades
    direct light with shadow maps (noise-free); here it is Monte Carlo, so a
    many-light scene needs more samples (or a better light sampler) to look clean.

    Returns (image Color3f, indirect Color3f, rays cast: the camera rays (with their pass-through
    continuations) plus the shadow rays actually traced, as a lazily read Dr.Jit count for
    :meth:`~dyngi.timing.StageTimer.add_rays`).
    """
    mscene = scene.mi_scene if hasattr(scene, "mi_scene") else scene
    routing = light_routing(mscene, direct)
    custom = lights is not None
    lights = lights if custom else routing.nee
    w, h = res
    n = w * h
    if getattr(lights, "walk_aware", False):     # a dyngi.lights sampler (LightNEE): as a sample_traced strategy
        lights = TracedNEE.stream(lights, n, seed, frame, PRIMARY_NEE_STREAM, record=True)
    sampler = make_sampler(n, seed, frame, 101)
    idx = dr.arange(mi.UInt32, n)
    u = sampler.next_2d() if jitter else mi.Point2f(0.5, 0.5)
    ray = camera.sample_rays(res, idx, u)
    glass = scene_has_glass(mscene)
    passes = mi.UInt32(0)
    if glass:
        si, throughput, _, passes = intersect_through_glass(mscene, ray, mi.Bool(True), stage="primary")
    else:
        si = intersect(mscene, ray, mi.RayFlags.All, True, stage="primary")
    hit = si.is_valid()
    bsdf = si.bsdf(ray)
    front, n_side = shading_side(si, ray, bsdf, hit)    # two-sided surfaces face the camera from both sides
    # -- emission seen directly (always: the camera sees every emitter in full). The emitter decides which
    # side emits (Mitsuba: the shading normal's side); the geometric ``front`` disagrees with it on shapes
    # with a mirroring to_world, and used as the mask it blacked out such lights (the staircase2 doorway) --
    em = si.emitter(mscene)
    L = mi.Color3f(em.eval(si))
    # -- direct light by NEE for the light NEE owns --
    ctx = mi.BSDFContext()
    k = max(int(direct_samples), 1)
    shadow_rays = mi.UInt32(0)
    for _ in range(k):
        ds, wl, traced = sample_traced(lights, mscene, si, sampler.next_2d(), front, stage="primary")
        shadow_rays += mi.UInt32(traced)
        if custom:
            wl = routing.nee_weight(ds, wl, front)
        f = bsdf.eval(ctx, si, si.to_local(ds.d), front)
        L += dr.select(front, f * wl * (1.0 / k), 0.0)
    # -- indirect light from the probes (diffuse lobe only) --
    albedo = diffuse_albedo(bsdf, si, front)
    ind = diffuse_radiance(albedo, volume_query.irradiance(si.p, n_side, -ray.d, active=front), front)
    if glossy:
        ind += glossy_term(volume_query, si, bsdf, n_side, -ray.d, sampler, front)
    L += ind
    if glass:
        L *= throughput
        ind *= throughput
    L = dr.select(dr.isfinite(L), L, 0.0)
    dr.eval(L, ind, shadow_rays)
    return L, ind, dr.sum(shadow_rays) + n + dr.sum(passes)


def glossy_term(volume_query, si, bsdf, n, wo, sampler, active):
    """Eq. 6's glossy term at the primary vertex ``si`` towards ``wo`` (world, towards the camera): Color3f.

    One sample of the rough glossy lobes (:data:`PRIMARY_GLOSSY_LOBES`; ``si.wi`` is the camera
    direction in the local frame, as ``ray_intersect`` leaves it), weight ``f cos / pdf``, times the
    probe irradiance along the sampled direction over :data:`~dyngi.probes.glossy.GLOSSY_NORMALISATION`.
    Lanes without such a lobe, or whose sample fails or comes from a delta lobe, give 0. Draws one
    1D and one 2D number from ``sampler`` (for every lane: the draws do not depend on the surface).
    """
    u1 = sampler.next_1d()
    u2 = sampler.next_2d()
    return glossy_lookup(volume_query, si, n, wo, u1, u2, active, lobes=PRIMARY_GLOSSY_LOBES, skip_delta=True,
                         bsdf=bsdf)
