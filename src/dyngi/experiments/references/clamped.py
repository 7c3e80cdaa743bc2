"""Clamped path tracing (Hedman et al. 2017, Sec. 5.4): the indirect image that infinitely many VPLs give.

"We clamp the geometry term of all light transport path segments that originate
from the primary hits, except for those that directly connect to a light source.
This effectively corresponds to using an infinite number of VPLs, and the result
approximates the maximal quality obtainable with our chosen level of clamping."

Per sample: the camera ray (pixel area jittered) finds the primary hit x (front
face, diffuse albedo a_x: the VPL techniques shade the diffuse lobe only); a
cosine-sampled ray finds y; our path tracer
(:func:`dyngi.transport.path_walk.trace_paths_split`, BSDF + NEE with MIS) estimates
the radiance L leaving y towards x with ``max_depth - 1`` vertices from y, minus
y's own emission (that segment is direct light, which the indirect image leaves
out). The sample is ``a_x * min(1, G_max / G(x, y)) * L`` with
``G = cos_x cos_y / |x - y|^2``: cosine sampling makes ``f G / p = a_x``, and the
clamp scales it as the VPL shading's ``min(G, G_max)`` does. With ``G_max = inf`` it
is an unclamped indirect-only estimator (tested against the indirect reference).
``G_max`` comes from :func:`dyngi.vpl.shading.clamp_value` (``clamp_distance``).

As a comparison reference (``dyngi compare --indirect --reference clamped``,
``dyngi reproduce smcir --reference clamped``): :func:`dyngi.experiments.evaluate.collect_clamped_references`
renders each frame as two independent halves (their difference estimates the
reference's noise, as the path-traced references do), cached on disk
(``$DYNGI_CACHE/clamped/``), and the 8 tracked pixels' per-pixel references with
the same clamped estimator (:func:`clamped_indirect` with ``pixels``). The clamp is
the compared VPL techniques' ``clamp_distance`` (:func:`reference_clamp_distance`:
they must agree).
"""
from __future__ import annotations

import math

import numpy as np

from ...backend import dr, mi
from ...errors import DyngiError
from ...rays import intersect
from ...sampling.rng import make_sampler, mix_seed
from ...techniques.vpl_base import COMMON_PARAMS, VPLTechnique
from ...transport.path_walk import trace_paths_split
from ...scene.surface import diffuse_surface
from ...vpl.points import aligned
from .cache import cached_npy, default_cache_dir, reference_key
from .path import combine_halves, half_spp

REFERENCES = ("path", "clamped")
"""Comparison references: the path-traced one (the default) or clamped path tracing (Sec. 5.4)."""
CLAMPED_FORMAT = 1


def clamped_indirect(scene, t: float, res, spp: int, max_depth: int = 5, gmax: float = math.inf,
                     seed: int = 0, chunk: int = 1 << 20, pixels=None) -> np.ndarray:
    """H x W x 3 clamped indirect image (module docstring) at time ``t``, ``spp`` samples per pixel;
    with ``pixels`` ((n, 2) rows, columns) only those pixels: (n, 3)."""
    scene.at(t)
    mscene = scene.mi_scene

    w, h = res
    flat = None if pixels is None else (np.asarray(pixels, np.int64)[:, 0] * w +
                                        np.asarray(pixels, np.int64)[:, 1]).astype(np.uint32)
    npix = w * h if flat is None else len(flat)
    acc = np.zeros((npix, 3), np.float64)
    per = max(1, min(int(spp), chunk // npix))
    done, it = 0, 0
    g = dr.opaque(mi.Float, min(float(gmax), 3.0e38))
    while done < spp:
        k = min(per, int(spp) - done)
        n = npix * k
        sampler = make_sampler(n, mix_seed(seed, int(round(t * 1e6)), 0xC1A), it)
        if flat is None:
            pix = dr.arange(mi.UInt32, n) // dr.opaque(mi.UInt32, k)
        else:
            pix = mi.UInt32(aligned(np.repeat(flat, k), np.uint32))
        ray = scene.camera(t).sample_rays(res, pix, sampler.next_2d())
        si, okx, nx, alb = diffuse_surface(mscene, ray, mi.Bool(True), stage="reference")
        d = mi.Frame3f(nx).to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
        ray2 = si.spawn_ray(d)
        si2 = intersect(mscene, ray2, mi.RayFlags.All, False, okx, stage="reference")
        hit = okx & si2.is_valid()
        d2 = dr.squared_norm(si2.p - si.p)
        G = dr.dot(nx, d) * dr.abs(dr.dot(si2.n, d)) / dr.maximum(d2, 1e-20)
        scale = dr.select(G > g, g / dr.maximum(G, 1e-30), 1.0)
        L, _, _, _ = trace_paths_split(mscene, sampler, ray2, hit, int(max_depth) - 1, int(max_depth) + 1,
                                       None, True, split=False, stage="reference")
        Le = mi.Color3f(si2.emitter(mscene).eval(si2, hit))
        v = dr.select(hit, alb * scale * (L - Le), 0.0)
        dr.eval(v)
        arr = np.stack([np.asarray(v[i], np.float64) for i in range(3)], axis=1)
        arr = np.where(np.isfinite(arr), arr, 0.0)
        acc += arr.reshape(npix, k, 3).sum(axis=1)
        done += k
        it += 1
    out = (acc / max(int(spp), 1)).astype(np.float32)
    return out if flat is not None else out.reshape(h, w, 3)


def check_reference(kind: str, indirect: bool) -> None:
    """A DyngiError unless ``kind`` is one of :data:`REFERENCES` (``clamped`` needs ``indirect``)."""
    if kind not in REFERENCES:
        raise DyngiError(f"unknown reference '{kind}'; valid references: {', '.join(REFERENCES)}")
    if kind == "clamped" and not indirect:
        raise DyngiError("--reference clamped is an indirect-only reference (clamped path tracing, SMC-IR "
                         "Sec. 5.4): add --indirect")


def reference_clamp_distance(techs) -> float:
    """The ``clamp_distance`` of the compared VPL techniques (``techs``: label -> technique); they must
    agree; with none, the VPL techniques' default."""
    vals = {lb: float(t.params["clamp_distance"]) for lb, t in techs.items() if isinstance(t, VPLTechnique)}
    if len(set(vals.values())) > 1:
        raise DyngiError("--reference clamped needs one clamp_distance for every VPL technique; got "
                         + ", ".join(f"{lb}: {v:g}" for lb, v in vals.items()))
    return next(iter(vals.values())) if vals else float(COMMON_PARAMS["clamp_distance"].default)


def cached_clamped(kind: str, key: dict, compute, shape):
    """``compute()``, cached as ``$DYNGI_CACHE/clamped/<hash>.npy`` (a sibling of ``reference/``)."""
    key = dict(key, kind=kind, format=CLAMPED_FORMAT, mitsuba=mi.__version__, variant=mi.variant())
    h = reference_key(key)
    return cached_npy(default_cache_dir().parent / "clamped" / f"{kind}-{h}.npy", shape, compute)


def clamped_reference_halves(scene, t: float, res, spp: int, max_depth: int, gmax: float):
    """(image, noise): the clamped reference of ``spp`` samples as two independent cached halves."""
    n1, n2 = half_spp(spp)
    w, h = res
    base = {"state": scene.state_hash(float(t)), "res": [int(w), int(h)], "max_depth": int(max_depth),
            "gmax": float(min(gmax, 3.0e38))}
    a, b = (cached_clamped("image", dict(base, spp=n, seed=sd),
                    lambda n=n, sd=sd: clamped_indirect(scene, t, res, n, max_depth, gmax, seed=sd), (h, w, 3))
            for n, sd in ((n1, 0), (n2, 1)))
    img, noise = combine_halves(a, b, n1, n2)
    noise.update(spp=int(spp), halves=[n1, n2], clamped=True)
    return img.astype(np.float32), noise
