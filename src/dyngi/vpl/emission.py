"""Photon emission through a light sampler: where the photons of ``ir`` and ``tcas`` leave the lights.

Keller's instant radiosity (1997) and TCAS (Barák et al. 2013) start their VPLs from photons leaving the
lights; the papers do not say how a light is chosen. By default (``lights=None``) Mitsuba chooses, as
before: :func:`sample_photon_ray` is then ``scene.sample_emitter_ray`` (an emitter by its sampling
weight, a point, a direction; weight = power / pdf). With a
:class:`~dyngi.lights.nee.LightNEE` (``lights=uniform`` or ``power``) the one light-sampler interface
chooses instead, over the one emitter table, as the NEE of :class:`~dyngi.lights.nee.LightNEE` does:

1. with probability ``p_tri`` an emitter triangle ``k`` with the sampler's ``pmf(k)``, a point ``y`` on
   it by area sampling (pdf ``1/area``) and a cosine-distributed direction about its emitting normal
   (pdf ``cos / pi``), so the photon's weight is ``Le(k) * pi * area / (p_tri * pmf(k))`` (the triangle's
   constant radiance of the table: the same known bias for textured emitters as the NEE);
2. else one of the other emitters (delta lights, analytic shapes, the environment) by its sampling
   weight through Mitsuba's ``Emitter.sample_ray``, weight divided by ``(1 - p_tri) * pmf``.

The mean weight is the scene's emitted power for every sampler whose pmf is positive on every light,
so the VPLs' flux is unbiased whatever the choice (``tests/techniques/test_vpl_lights.py``). A photon
has no receiving point, so only samplers whose pmf does not depend on one apply
(:data:`EMISSION_SAMPLERS`: pbrt-v4 emits light-tracing and SPPM photons through such a sampler, its
``PowerLightSampler``; our choice to reject the others, whose pmf at an arbitrary point may be 0 for a
light that matters elsewhere). The random numbers keep Mitsuba's layout (one number for the light, two
for the point, two for the direction), so TCAS's chains move in the same primary sample space.
"""
from __future__ import annotations

from ..backend import dr, mi
from ..lights.base import INVALID

EMISSION_SAMPLERS = ("uniform", "power")
"""Light samplers whose pmf does not depend on a shading point: the ones photon emission can use."""


def _spawn(p, n, d):
    """A ray from ``p`` along ``d`` offset off the surface of normal ``n`` (Mitsuba's ``spawn_ray``)."""
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(p))
    si.p, si.n = mi.Point3f(p), mi.Normal3f(n)
    return si.spawn_ray(mi.Vector3f(d))


def sample_photon_ray(mscene, lights, u_sel, u_pos, u_dir, active=True):
    """One photon per lane: (ray leaving a light, weight = emitted power / pdf as a ``Color3f``).

    ``lights``: None (Mitsuba's ``sample_emitter_ray``) or a :class:`~dyngi.lights.nee.LightNEE` whose
    sampler is one of :data:`EMISSION_SAMPLERS` (module docstring). ``u_sel`` a Float, ``u_pos`` and
    ``u_dir`` Point2f, all uniform in [0, 1)."""
    active = mi.Bool(active)
    if lights is None:
        ray, w, _ = mscene.sample_emitter_ray(0.0, u_sel, u_pos, u_dir, active)
        return ray, mi.Color3f(w)
    u_sel = mi.Float(u_sel)
    p_tri = lights.p_tri
    pick = active & (u_sel < p_tri) if 0.0 < p_tri < 1.0 else active & (p_tri > 0.0)
    ray = dr.zeros(mi.Ray3f, dr.width(active))
    weight = mi.Color3f(0.0)
    tris = lights.tris
    # -- an emitter triangle by the light sampler (pmf independent of any shading point) --
    if tris.count and p_tri > 0.0:
        u_s = dr.minimum(u_sel / p_tri, 0.99999994) if p_tri < 1.0 else u_sel
        zero = mi.Point3f(0.0)
        k, pmf = lights.sampler.sample(zero, mi.Vector3f(0.0, 0.0, 1.0), u_s, pick)
        ok = pick & (k != INVALID) & (pmf > 0.0)
        pl, nl, pdf_a = tris.sample_point(k, u_pos, ok)
        ok &= pdf_a > 0.0
        d = mi.Frame3f(mi.Vector3f(nl)).to_world(mi.warp.square_to_cosine_hemisphere(u_dir))
        Le = tris.gather_radiance(k, ok)
        w_tri = Le * (dr.pi / (p_tri * pmf * pdf_a))
        r_tri = _spawn(pl, nl, d)
        ray = dr.select(ok, r_tri, ray)
        weight = dr.select(ok, w_tri, weight)
    # -- one of the other emitters by its sampling weight, through Mitsuba --
    others = lights.others
    if others is not None and p_tri < 1.0:
        q = 1.0 - p_tri
        other = active & ~pick
        u_o = dr.minimum((u_sel - p_tri) / q, 0.99999994) if p_tri > 0.0 else u_sel
        if others.single is not None:
            r_o, w_o = others.single.sample_ray(0.0, u_o, u_pos, u_dir, other)
            pmf_o = mi.Float(1.0)
        else:
            i, u_re, pmf_o = others.table.sample_reuse_pmf(u_o, other)
            em = dr.gather(mi.EmitterPtr, others.ptrs, i, other)
            r_o, w_o = em.sample_ray(0.0, u_re, u_pos, u_dir, other)
        ok_o = other & (pmf_o > 0.0)
        ray = dr.select(ok_o, r_o, ray)
        weight = dr.select(ok_o, mi.Color3f(w_o) / (q * pmf_o), weight)
    return ray, weight
