"""Glossy probe lookup (DDGI Resampling, Majercik et al. 2022, Sec. 3.4, Eq. 6; after MMSM21).

The glossy term of ``L_DDGI+`` (Eq. 6) is estimated with **one** sample of the
BSDF's glossy lobes (every non-diffuse lobe: glossy and delta reflection, and
-- our choice, so that glass is not black -- glossy and delta transmission, whose
lookup reads the probes along the refracted direction):

``L_g(x -> wo) ~= E(x, wi) / pi * f_g(wo, wi) cos(n, wi) / p(wi) = E(x, wi) / pi * weight``

with ``wi`` drawn by ``bsdf.sample`` restricted to those lobes, ``weight``
Mitsuba's ``f cos / pdf`` and ``E(x, wi)`` the probe irradiance read along the
sampled direction (the irradiance field around ``wi``, re-interpreted as
cosine-prefiltered incident radiance, MMSM21).

**Normalisation: ``/ pi``, not the paper's ``/ 2 pi``** (settled by a test).
The paper divides by ``2 pi``, "the mass of the cosine under the integration
measure"; but ``int_H cos dw = pi``, and a probe texel of a furnace of
constant radiance ``L`` holds ``E = pi L`` (our texels store ``E / pi = L``,
:mod:`dyngi.probes.volume`; :class:`~dyngi.probes.query.ProbeQuery` returns
``E``). Prefiltered radiance is therefore ``E / pi``, and the glossy lookup in a
furnace returns ``albedo_g x L`` with ``/ pi`` and half of it with ``/ 2 pi``:
``tests/probes/test_ddgi_plus.py::test_glossy_furnace_pi_normalisation`` checks the
first and that the second fails. :data:`GLOSSY_NORMALISATION` is the divisor.
"""
from __future__ import annotations

from ..backend import dr, mi

GLOSSY_NORMALISATION = dr.pi
"""Divisor turning a probe irradiance into prefiltered radiance (pi: the cosine's mass; module docstring)."""

GLOSSY_LOBES = (mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.GlossyTransmission
                | mi.BSDFFlags.DeltaTransmission)
"""The lobes Eq. 6's glossy term (and ``ddgi-primary``'s recursion) samples: every non-diffuse lobe."""


def glossy_context(lobes=GLOSSY_LOBES) -> "mi.BSDFContext":
    """A BSDF context that enables only ``lobes`` (default the glossy and delta ones, :data:`GLOSSY_LOBES`)."""
    ctx = mi.BSDFContext()
    ctx.type_mask = int(lobes)
    return ctx


def has_glossy_lobe(bsdf, lobes=GLOSSY_LOBES):
    """Per lane: does ``bsdf`` (a BSDFPtr) have one of ``lobes`` (default: a glossy or delta lobe)?"""
    flags = bsdf.flags()
    return (bsdf != None) & ((flags & mi.UInt32(int(lobes))) != 0)   # noqa: E711


def sample_glossy(bsdf, si, u1, u2, active, with_delta: bool = False, lobes=GLOSSY_LOBES):
    """One sample of the glossy lobes (``lobes``) of ``bsdf`` at ``si`` (``si.wi`` set, local frame).

    Returns (world direction, weight = f_g cos / pdf as Color3f, valid mask[, delta mask where
    ``with_delta``: the sample came from a delta lobe]). Lanes without such a lobe, or whose sample
    fails, are invalid (weight 0).
    """
    active = mi.Bool(active) & has_glossy_lobe(bsdf, lobes)
    bs, w = bsdf.sample(glossy_context(lobes), si, u1, u2, active)
    w = mi.Color3f(w)
    ok = active & (bs.pdf > 0.0) & dr.all(dr.isfinite(w)) & dr.any(w > 0.0)
    out = (si.to_world(bs.wo), dr.select(ok, w, 0.0), ok)
    if with_delta:
        return out + (ok & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta),)
    return out


def glossy_lookup(query, si, n, wo, u1, u2, active, sampler=None, normalisation: float = GLOSSY_NORMALISATION,
                  lobes=GLOSSY_LOBES, skip_delta: bool = False, bsdf=None):
    """Eq. 6's glossy term at ``si`` towards ``wo`` (world, towards the viewer): Color3f radiance.

    ``n``: the shading normal on ``wo``'s side (for the query's normal bias and wrap weight);
    ``query``: a :class:`~dyngi.probes.query.ProbeQuery`; ``sampler`` (optional): stochastic texel
    filtering of the lookup (same expectation). ``si.wi`` must be ``si.to_local(wo)``. ``lobes``: the
    lobes sampled (the primary vertex samples the rough ones only, :mod:`dyngi.probes.primary`);
    ``skip_delta``: a sample from a delta lobe gives 0. ``bsdf``: ``si.bsdf()`` unless given.
    ``normalisation`` exists for the furnace test only (``2 pi`` is the paper's, wrong, divisor).
    """
    if skip_delta:
        d, w, ok, delta = sample_glossy(si.bsdf() if bsdf is None else bsdf, si, u1, u2, active, True, lobes)
        ok &= ~delta
    else:
        d, w, ok = sample_glossy(si.bsdf() if bsdf is None else bsdf, si, u1, u2, active, lobes=lobes)
    E = query.irradiance(si.p, n, wo, direction=d, active=ok, sampler=sampler)
    return dr.select(ok, w * E * (1.0 / normalisation), 0.0)
