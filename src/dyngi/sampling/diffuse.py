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
``BSDFFlags.DiffuseReflection``), else Mitsuba's diffuse reflectance
(``diffuse``: its reflectance; ``plastic``/``roughplastic``/``principled``:
the diffuse layer's), clamped to [0, 1]. Wrappers forward as Mitsuba
forwards them: ``twosided`` and ``mask`` report their nested BSDF's flags and
reflectance, ``blendbsdf`` the union of its two BSDFs' flags and the blend of
their reflectances (a conductor's share of a blend is still read through
``eval_diffuse_reflectance``, but weighted by the blend; our choice, one
virtual call per lane). Glossy lobes are not part of diffuse GI (the DDGI
Resampling technique adds them).
"""
from __future__ import annotations

from ..backend import dr, mi


def has_diffuse_lobe(bsdf):
    """Per lane: does ``bsdf`` (a BSDFPtr) have a diffuse reflection lobe?"""
    return (bsdf != None) & mi.has_flag(bsdf.flags(), mi.BSDFFlags.DiffuseReflection)   # noqa: E711


def diffuse_albedo(bsdf, si, active):
    """Diffuse reflectance in [0, 1] of ``bsdf`` at ``si``; 0 without a diffuse lobe (module docstring)."""
    active = mi.Bool(active) & has_diffuse_lobe(bsdf)
    a = mi.Color3f(bsdf.eval_diffuse_reflectance(si, active))
    return dr.select(active, dr.clip(a, 0.0, 1.0), 0.0)
