"""Clamped path tracing (Hedman et al. 2017, Sec. 5.4): the indirect image that infinitely many VPLs give.

"We clamp the geometry term of all light transport path segments that originate
from the primary hits, except for those that directly connect to a light source.
This effectively corresponds to using an infinite number of VPLs, and the result
approximates the maximal quality obtainable with our chosen level of clamping."

Per sample: the camera ray (pixel area jittered) finds the primary hit x (front
face, diffuse albedo a_x: the VPL techniques shade the diffuse lobe only); a
cosine-sampled ray finds y; our path tracer
(:func:`dyngi.techniques.path.trace_paths_split`, BSDF + NEE with MIS) estimates
the radiance L leaving y towards x with ``max_depth - 1`` vertices from y, minus
y's own emission (that segment is direct light, which the indirect image leaves
out). The sample is ``a_x * min(1, G_max / G(x, y)) * L`` with
``G = cos_x cos_y / |x - y|^2``: cosine sampling makes ``f G / p = a_x``, and the
clamp scales it as the VPL shading's ``min(G, G_max)`` does. With ``G_max = inf`` it
is an unclamped indirect-only estimator (tested against the indirect reference).
``G_max`` comes from :func:`dyngi.vpl.shading.clamp_value` (``clamp_distance``).
"""
from __future__ import annotations

import math

import numpy as np

from ..backend import dr, mi


def clamped_indirect(scene, t: float, res, spp: int, max_depth: int = 5, gmax: float = math.inf,
                     seed: int = 0, chunk: int = 1 << 20) -> np.ndarray:
    """H x W x 3 clamped indirect image (module docstring) at time ``t``, ``spp`` samples per pixel."""
    from ..sampling.rng import make_sampler, mix_seed
    from ..techniques.path import trace_paths_split
    from ..vpl.points import _surface

    scene.at(t)
    mscene = scene.mi_scene
    w, h = res
    npix = w * h
    acc = np.zeros((npix, 3), np.float64)
    per = max(1, min(int(spp), chunk // npix))
    done, it = 0, 0
    g = dr.opaque(mi.Float, min(float(gmax), 3.0e38))
    while done < spp:
        k = min(per, int(spp) - done)
        n = npix * k
        sampler = make_sampler(n, mix_seed(seed, int(round(t * 1e6)), 0xC1A), it)
        pix = dr.arange(mi.UInt32, n) // dr.opaque(mi.UInt32, k)
        ray = scene.camera(t).sample_rays(res, pix, sampler.next_2d())
        si, okx, nx, alb = _surface(mscene, ray, mi.Bool(True))
        d = mi.Frame3f(nx).to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
        ray2 = si.spawn_ray(d)
        si2 = mscene.ray_intersect(ray2, ray_flags=mi.RayFlags.All, coherent=False, active=okx)
        hit = okx & si2.is_valid()
        d2 = dr.squared_norm(si2.p - si.p)
        G = dr.dot(nx, d) * dr.abs(dr.dot(si2.n, d)) / dr.maximum(d2, 1e-20)
        scale = dr.select(G > g, g / dr.maximum(G, 1e-30), 1.0)
        L, _, _, _ = trace_paths_split(mscene, sampler, ray2, hit, int(max_depth) - 1, int(max_depth) + 1,
                                       None, True, split=False)
        Le = mi.Color3f(si2.emitter(mscene).eval(si2, hit))
        v = dr.select(hit, alb * scale * (L - Le), 0.0)
        dr.eval(v)
        arr = np.stack([np.asarray(v[i], np.float64) for i in range(3)], axis=1)
        arr = np.where(np.isfinite(arr), arr, 0.0)
        acc += arr.reshape(npix, k, 3).sum(axis=1)
        done += k
        it += 1
    return (acc / max(int(spp), 1)).reshape(h, w, 3).astype(np.float32)
