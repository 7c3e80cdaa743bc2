"""Radiosity of VPLs by a path tracer with next-event estimation, seeded per VPL (Sec. 3.2.3).

``L(y)`` is the outgoing radiance of the diffuse surface at ``y`` *without* its own
emission: ``spp`` paths (16 in the paper) of our path tracer
(:func:`dyngi.transport.path_walk.trace_paths_split`, BSDF sampling + NEE with MIS)
start at ``y`` (a ray just above ``y`` along ``-n`` finds it as the first vertex),
with ``max_depth`` vertices counted from ``y`` (``y`` and the light: 2 = direct
light at ``y``), no Russian roulette; the emission seen at ``y`` itself is
subtracted exactly. The random numbers of sample ``s`` of a VPL come from
``PCG32(initstate=seed, initseq=s)``: the estimate depends only on the VPL's seed
and the scene, so a VPL's radiosity does not flicker while it lives and a static
scene's VPLs are bit-stable across frames.

:func:`stream_seeds` derives further fixed per-VPL seeds from a VPL's seed (our
choice): ``smcir`` selects VPLs on the estimate of stream 0 (the seed itself) and
renders with an estimate of stream 1 (Algorithm 1, line 18), statistically
independent of the one the selection saw, still fixed for the VPL's life.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..rays import intersect
from ..transport.path_walk import trace_paths_split
from .points import aligned, padded, to_point, to_vector

RAY_OFFSET = 1e-4
"""Offset of the radiosity ray's origin above y, relative to 1 + max|y| (our choice)."""


class PCGSampler:
    """A ``next_1d``/``next_2d`` sampler over a per-lane PCG32 (a Dr.Jit struct: loop state)."""

    DRJIT_STRUCT = {"rng": mi.PCG32}

    def __init__(self, rng=None):
        self.rng = rng if rng is not None else mi.PCG32()

    def next_1d(self, active=True):
        return self.rng.next_float32()

    def next_2d(self, active=True):
        return mi.Point2f(self.rng.next_float32(), self.rng.next_float32())


RENDER_STREAM = 1
"""Stream of the rendering estimate (line 18) in :func:`stream_seeds`; stream 0 is the seed itself."""


def stream_seeds(seeds: np.ndarray, stream: int) -> np.ndarray:
    """Per-VPL seeds of random stream ``stream`` (0: ``seeds`` unchanged): a splitmix64 finaliser of
    ``seed + stream * golden``, elementwise on uint64 (deterministic, fixed per VPL; our choice)."""
    s = np.asarray(seeds, np.uint64)
    if int(stream) == 0:
        return s.copy()
    with np.errstate(over="ignore"):
        x = s + np.uint64((int(stream) * 0x9E3779B97F4A7C15) & ((1 << 64) - 1))
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        x = x ^ (x >> np.uint64(31))
    return x >> np.uint64(2)          # 62 bits, as the seeds smcir draws


def per_lane_sampler(seeds: np.ndarray, spp: int) -> PCGSampler:
    """Lane ``i * spp + s``: PCG32 seeded with ``(seeds[i], s)``."""
    seeds = np.asarray(seeds, np.uint64)
    st = aligned(np.repeat(seeds, spp), np.uint64)
    seq = aligned(np.tile(np.arange(spp, dtype=np.uint64), len(seeds)), np.uint64)
    rng = mi.PCG32()       # the sized constructor adds the lane index to initseq: seed explicitly
    rng.seed(mi.UInt64(st), mi.UInt64(seq))
    return PCGSampler(rng)


def estimate_radiosity(mscene, pos: np.ndarray, nrm: np.ndarray, seeds: np.ndarray, spp: int,
                       max_depth: int, lights=None) -> tuple[np.ndarray, int]:
    """Radiosity L(y) (RGB, outgoing radiance without emission) of each point; returns (L[n, 3], rays).

    ``max_depth`` counts path vertices from ``y`` (1: nothing, 2: direct light at ``y``, 4: up to three
    bounces of light reaching ``y``). The host form of
    :func:`estimate_radiosity_device` (the same lanes and samples, averaged there:
    bit-identical to the device estimate of the same seed).
    """
    n = len(pos)
    if n == 0 or max_depth < 2:
        return np.zeros((n, 3), np.float32), 0
    m = max(n, -(-16 // spp))        # at least 16 lanes (a width-1 array would compile its own kernel)
    pos, nrm, seeds = padded(np.asarray(pos, np.float32), m), padded(np.asarray(nrm, np.float32), m), \
        padded(np.asarray(seeds, np.uint64), m)
    L, rays = estimate_radiosity_device(mscene, to_point(pos), to_vector(nrm), mi.UInt64(aligned(seeds, np.uint64)),
                                        spp, max_depth, True, lights)
    dr.eval(L, rays)
    out = np.stack([np.asarray(L[i], np.float32) for i in range(3)], axis=1)[:n]
    return out, int(np.asarray(rays).ravel()[0])


def estimate_radiosity_device(mscene, pos, nrm, seeds, spp: int, max_depth: int, active=True, lights=None):
    """Radiosity L(y) of each point (Color3f, 0 where inactive) and the rays traced (width-1 UInt32).

    The device form of :func:`estimate_radiosity` (which calls it): lane
    ``i * spp + s`` runs PCG32 seeded ``(seeds[i], s)`` from just above y_i along ``-n_i`` through the
    shared path walk (:func:`dyngi.transport.path_walk.trace_paths_split`, NEE + MIS, ``max_depth``
    vertices from y), y's own emission subtracted; each sample clamped to finite, non-negative values
    and the ``spp`` samples averaged by a block sum (deterministic order)."""
    n = dr.width(pos)
    spp = int(spp)
    if max_depth < 2:                  # no vertex beyond y: no light reaches it
        return dr.zeros(mi.Color3f, n), mi.UInt32(0)
    idx = dr.arange(mi.UInt32, n * spp)
    v = idx // spp
    act = dr.gather(mi.Bool, mi.Bool(active) if not isinstance(active, bool) else dr.full(mi.Bool, active, n), v)
    P = dr.gather(mi.Point3f, mi.Point3f(pos), v)
    N = dr.gather(mi.Vector3f, mi.Vector3f(nrm), v)
    eps = dr.opaque(mi.Float, RAY_OFFSET) * (1.0 + dr.max(dr.abs(P)))
    ray = mi.Ray3f(P + N * eps, -N)
    rng = mi.PCG32()       # the sized constructor adds the lane index to initseq: seed explicitly
    rng.seed(dr.gather(mi.UInt64, mi.UInt64(seeds), v), mi.UInt64(idx % spp))
    L, _, n_rays, _ = trace_paths_split(mscene, PCGSampler(rng), ray, act, int(max_depth), int(max_depth) + 1,
                                        lights, True, split=False, stage="radiosity")
    si = intersect(mscene, ray, mi.RayFlags.All, False, act, stage="radiosity")
    L = L - mi.Color3f(si.emitter(mscene).eval(si, act))
    dr.eval(L, n_rays)     # the walk once: each reduction below would otherwise evaluate (re-trace) it anew
    chans = []
    for i in range(3):
        c = dr.select(act & dr.isfinite(L[i]), dr.maximum(L[i], 0.0), 0.0)
        chans.append(dr.block_sum(c, spp) / float(spp))
    rays = dr.sum(dr.select(act, n_rays, 0)) + dr.count(act)
    return mi.Color3f(*chans), mi.UInt32(rays)
