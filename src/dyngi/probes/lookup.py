"""The one probe lookup every consumer uses: ``albedo / pi * E`` (diffuse) plus Eq. 6's glossy term.

Diffuse (DDGI, Majercik et al. 2019, Sec. 4): the outgoing radiance of a Lambertian lobe of albedo
``rho`` under the probe irradiance ``E`` is ``rho / pi * E`` (:func:`diffuse_radiance`; texels hold
``E / pi``, :class:`~dyngi.probes.query.ProbeQuery` returns ``E``). Glossy (DDGI Resampling, Majercik
et al. 2022, Sec. 3.4, Eq. 6): one sample of the BSDF's glossy lobes and the probe irradiance read along
it, over pi (:func:`dyngi.probes.glossy.glossy_lookup`; the lobe set is the caller's:
:data:`~dyngi.probes.glossy.GLOSSY_LOBES` at probe-ray hits, the rough ones at the primary vertex,
:mod:`dyngi.probes.primary`). :func:`probe_radiance` is both at a surface point.
"""
from __future__ import annotations

from ..backend import dr, mi
from ..sampling.diffuse import diffuse_albedo
from .glossy import GLOSSY_LOBES, glossy_lookup


def diffuse_radiance(albedo, E, active):
    """``rho / pi * E`` where ``active``, else 0 (Color3f): the diffuse lobe under probe irradiance ``E``."""
    return dr.select(active, albedo * dr.inv_pi * E, 0.0)


def probe_radiance(query, si, bsdf, n, wo, active, sampler=None, glossy: bool = False, u1=None, u2=None,
                   draw=None, lobes=GLOSSY_LOBES, skip_delta: bool = False):
    """Radiance at ``si`` towards ``wo`` (world, towards the viewer) from the probes: the diffuse lobe's
    ``rho / pi * E(x, n)`` (lanes with a diffuse albedo) plus, with ``glossy``, Eq. 6's glossy term from
    ``u1``, ``u2`` over ``lobes``. ``n``: the shading normal on ``wo``'s side; ``sampler``: stochastic
    texel filtering of the lookups (same expectation); ``draw``: the sampler ``u1``, ``u2`` come from when
    not given (drawn after the diffuse lookup). ``si.wi`` must be ``si.to_local(wo)`` for the glossy term."""
    albedo = diffuse_albedo(bsdf, si, active)
    diff = mi.Bool(active) & dr.any(albedo > 0.0)
    L = diffuse_radiance(albedo, query.irradiance(si.p, n, wo, active=diff, sampler=sampler), diff)
    if glossy:
        if u2 is None:
            u1, u2 = draw.next_1d(), draw.next_2d()
        L += glossy_lookup(query, si, n, wo, u1, u2, active, sampler=sampler, lobes=lobes, skip_delta=skip_delta,
                           bsdf=bsdf)
    return L
