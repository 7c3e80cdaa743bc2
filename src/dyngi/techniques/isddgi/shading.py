"""Probe-ray shading with per-ray keyed random numbers for IS-DDGI's paired visits (ours; issue 13 item 4).

IS-DDGI's change measure compares a set's hit sample with the one of its previous visit. With the
probe core's shading (:class:`~dyngi.probes.trace.DiffuseHitShader`: one NEE light sample per hit and a
stochastic multi-bounce lookup, both from a per-frame sampler) two visits of an unchanged set differ by
their shading noise: in ``corridor-rooms`` one NEE sample over 14 lights makes a single ray's luminance
0 or ~14x its mean, which hides a light switch (few importance rays reached the switched room;
docs/techniques/isddgi.md). Here every ray's NEE sample and hit lookup draw from hashes of the
ray's own key (:attr:`ISDDGIPlanInfo.ray_key <dyngi.techniques.isddgi.planner.ISDDGIPlanInfo>`): the planner
gives the two uniform rays of a *pattern* (two successive visits of a set) the same key and the same
jitter, so in a static scene they hit the same point, pick the same light point and read the same probe
texel, and their luminance differs only by the drift of the probes they read. All other rays (and the
next pattern) get keys from (frame, seed): the estimate stays an average over independent samples, except
that each uniform sample enters twice (the price of the clean change signal).
"""
from __future__ import annotations

from ...backend import dr, mi
from ...probes.trace import DiffuseHitShader
from .sets import _hash_u32_dr

DIM_STREAM = 0x68E31DA4                    # mixes the dimension index into the key


class KeyedSampler:
    """``next_1d`` / ``next_2d`` (the part of ``mi.Sampler`` the probe shading uses) as stateless hashes of
    (the lane's key, the dimension): dimension ``k`` of a lane is ``lowbias32(lowbias32(key ^ c_k) + k)``'s top
    24 bits over 2^24. Our choice over a PCG32 stream seeded by the key (``PCG32.seed(key, const)``): that
    gave far heavier-tailed NEE samples in the ellipsoid furnace (per-ray radiance up to 50x the median
    vs ~8x with Mitsuba's independent sampler; the battery's furnace failed), this matches the independent
    sampler there. The dimension counter is a Python int, the same every frame: no recompiles."""

    def __init__(self, keys: "mi.UInt32"):
        self.keys = keys
        self.dim = 0

    def _next(self):
        self.dim += 1
        h = _hash_u32_dr(self.keys ^ ((self.dim * DIM_STREAM) & 0xFFFFFFFF))
        h = _hash_u32_dr(h + self.dim)
        return mi.Float(h >> 8) * (1.0 / 16777216.0)

    def next_1d(self, active=True):
        return self._next()

    def next_2d(self, active=True):
        u = self._next()
        return mi.Point2f(u, self._next())


class KeyedHitShader(DiffuseHitShader):
    """:class:`DiffuseHitShader` whose random numbers come from ``keys`` (one UInt32 per ray of the plan
    being traced; set by :meth:`prepare`, which the probe pipeline calls around each trace). Without keys
    of the batch's width it uses the given sampler."""

    keys = None

    def prepare(self, plan) -> None:
        """The keys of ``plan``'s rays (IS-DDGI's paired visits: ``plan.shade_key``); None clears them."""
        self.keys = None if plan is None else getattr(plan, "shade_key", None)

    def shade(self, scene, ray, si, sampler, query, active):
        if self.keys is not None and dr.width(self.keys) == dr.width(ray.d):
            sampler = KeyedSampler(self.keys)
        return super().shade(scene, ray, si, sampler, query, active)
