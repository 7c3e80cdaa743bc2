"""The diffuse part of a BSDF, as diffuse GI (irradiance probes) consumes it.

DDGI shades a surface point with ``albedo / pi * E`` (Majercik et al. 2019,
Sec. 4): ``albedo`` must be the reflectance of the BSDF's *diffuse lobe*
only. Mitsuba's ``bsdf.eval_diffuse_reflectance`` is not that for every
plugin: ``roughconductor`` returns ``pi * f(wi, n)`` (its lobe evaluated at
the normal: 23 at alpha 0.1 seen head-on), so a metal read through it acts as
a bright diffuse reflector (the speckles and the flicker of issue 11).

:func:`diffuse_albedo` returns, per lane: 0 for a BSDF without a diffuse lobe
(``conductor``, ``roughconductor``, ``dielectric``, ``thindielectric``,
``null``: checked with ``bsdf.flags()`` on the BSDFPtr against
``BSDFFlags.DiffuseReflection``), else the diffuse lobe's directional albedo
towards ``si.wi``, clamped to [0, 1]:

* a BSDF whose only lobe is diffuse (``diffuse``; ``twosided``/``mask`` around
  it): Mitsuba's ``eval_diffuse_reflectance``, its reflectance, exactly;
* a BSDF with a diffuse lobe *and* other lobes (``plastic``,
  ``roughplastic``, ``principled``, a ``blendbsdf`` of a diffuse and a
  conductor): ``rho_d(wi) = 2 pi int_0^1 f_d(wi, mu) mu dmu``, the diffuse
  lobe alone (``BSDFContext.type_mask = DiffuseReflection``) evaluated by
  Mitsuba at :data:`ALBEDO_NODES` Gauss-Legendre cosines (azimuth 0: the
  layered diffuse lobes depend on the outgoing cosine only). ``eval_diffuse_reflectance``
  is *not* that for these plugins: it returns the layer's texture, while the
  lobe Mitsuba renders is that texture under the coating,
  ``R (1 - F_i)(1 - F_o) / (eta^2 (1 - R F_dr))`` -- 0.578 read as 0.578 is
  0.34 rendered by ``roughplastic`` (``intIOR`` 1.5, alpha 0.1, nonlinear) (the wooden
  staircase's painted walls and wood: every probe technique's multi-bounce
  light came out far over Mitsuba's; docs/probes.md, "The wooden
  staircase"). The quadrature is ours
  (:data:`ALBEDO_NODES` virtual calls per lane, exact for a lobe that is a
  polynomial of degree < 8 in the cosine).

``twosided`` surfaces seen from behind are evaluated from their front (Mitsuba
shades them so). Wrappers forward as Mitsuba forwards them: ``twosided`` and
``mask`` report their nested BSDF's flags, ``blendbsdf`` the union of its two
BSDFs' flags (a conductor's share of a blend has no diffuse lobe and adds
nothing). Glossy lobes are not part of diffuse GI (the DDGI Resampling
technique adds them; probe-ray hits count a layered BSDF's rough glossy lobes
as diffuse, :func:`dyngi.probes.trace.hit_albedo`).
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi

ALBEDO_NODES = 4
"""Gauss-Legendre nodes over the outgoing cosine for a layered BSDF's diffuse-lobe albedo (ours)."""
_MU, _W = np.polynomial.legendre.leggauss(ALBEDO_NODES)
_MU, _W = (_MU + 1.0) / 2.0, _W / 2.0          # nodes and weights on [0, 1]
_NON_DIFFUSE = int(mi.BSDFFlags.Glossy | mi.BSDFFlags.Delta | mi.BSDFFlags.Transmission
                | mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.Null)


def has_diffuse_lobe(bsdf):
    """Per lane: does ``bsdf`` (a BSDFPtr) have a diffuse reflection lobe?"""
    return (bsdf != None) & mi.has_flag(bsdf.flags(), mi.BSDFFlags.DiffuseReflection)   # noqa: E711


def front_wi(si):
    """A copy of ``si`` whose ``wi`` is mirrored to the front side (``wi.z >= 0``): a ``twosided`` BSDF seen
    from behind is evaluated as Mitsuba shades it, from its front."""
    si2 = mi.SurfaceInteraction3f(si)
    si2.wi = mi.Vector3f(si.wi.x, si.wi.y, dr.abs(si.wi.z))
    return si2


def lobe_albedo(bsdf, si, active, type_mask) -> "mi.Color3f":
    """Directional albedo towards ``si.wi`` of the lobes of ``bsdf`` in ``type_mask`` whose value depends on
    the outgoing cosine only: ``2 pi int_0^1 f(wi, mu) mu dmu`` by :data:`ALBEDO_NODES` Gauss-Legendre
    nodes at azimuth 0 (``bsdf.eval`` includes the cosine). Not clamped."""
    ctx = mi.BSDFContext()
    ctx.type_mask = int(type_mask)
    si2 = front_wi(si)
    a = mi.Color3f(0.0)
    for mu, w in zip(_MU, _W):
        wo = mi.Vector3f(float(np.sqrt(1.0 - mu * mu)), 0.0, float(mu))
        a += mi.Color3f(bsdf.eval(ctx, si2, wo, active)) * float(2.0 * np.pi * w)
    return a


def diffuse_albedo(bsdf, si, active):
    """Diffuse-lobe albedo in [0, 1] of ``bsdf`` at ``si`` towards ``si.wi``; 0 without a diffuse lobe
    (module docstring: the reflectance of a purely diffuse BSDF, the quadrature for layered ones)."""
    active = mi.Bool(active) & has_diffuse_lobe(bsdf)
    layered = active & ((bsdf.flags() & mi.UInt32(_NON_DIFFUSE)) != 0)
    plain = active & ~layered
    a = mi.Color3f(bsdf.eval_diffuse_reflectance(si, plain))
    a = dr.select(layered, lobe_albedo(bsdf, si, layered, mi.BSDFFlags.DiffuseReflection), a)
    return dr.select(active, dr.clip(a, 0.0, 1.0), 0.0)
