"""Ray-direction strategies for probe updates (replaceable piece #1).

A strategy decides, per frame, which rays each probe traces. Interface:

``plan(frame, seed, probe_ids) -> RayPlan`` where :class:`RayPlan` holds the
probe index and world direction of every ray as Dr.Jit arrays, and -- when all
probes share one direction set -- that set as an (N, 3) NumPy array, which lets
the blend be a dense matrix product (see :mod:`dyngi.probes.blend`).

* :class:`UniformSFDirections` -- DDGI (Majercik et al., JCGT 2019, Sec. 3.1):
  ``n`` spherical-Fibonacci directions under one fresh uniformly random
  rotation per frame, shared by every probe.
* :class:`FixedSFDirections` -- the same set without rotation (classification
  rays, Majercik et al. 2021 Sec. 5).
* :class:`LobeDirections` -- per-texel lobes for the reference volume: ``k``
  rays per texel drawn from a cosine-power lobe around the texel direction.

Metropolis chains (ADGI) and importance allocation (IS-DDGI) implement the
same ``plan`` interface with ``shared_directions = None``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backend import dr, mi
from ..sampling.fibonacci import coherent_order, rotation_for_frame, spherical_fibonacci_np
from ..sampling.octahedral import texel_directions
from ..sampling.rng import make_sampler


@dataclass
class RayPlan:
    probe: "mi.UInt32"               # probe index per ray
    direction: "mi.Vector3f"         # world direction per ray
    rays_per_probe: int | None       # constant count per probe (rays of one probe are contiguous)
    shared_directions: np.ndarray | None   # (N, 3) when every probe uses the same set
    probe_ids: np.ndarray            # (P_traced,) probe indices, in ray order

    @property
    def n_rays(self) -> int:
        return int(len(self.probe_ids) * self.rays_per_probe) if self.rays_per_probe else dr.width(self.probe)


def _shared_plan(probe_ids: np.ndarray, dirs: np.ndarray) -> RayPlan:
    n = len(dirs)
    pids = mi.UInt32(np.asarray(probe_ids, np.uint32))
    m = len(probe_ids) * n
    idx = dr.arange(mi.UInt32, m)
    local = idx % n
    probe = dr.gather(mi.UInt32, pids, idx // n)
    dset = mi.Float(np.asarray(dirs, np.float32).ravel())
    d = dr.gather(mi.Vector3f, dset, local)
    return RayPlan(probe, d, n, np.asarray(dirs, np.float64), np.asarray(probe_ids))


class UniformSFDirections:
    """``n`` spherical-Fibonacci directions, one random rotation per frame shared by all probes.

    The set is stored in :func:`~dyngi.sampling.fibonacci.coherent_order`
    (rays of one SIMD packet leave a probe in nearby directions); the order
    changes nothing in what is estimated.
    """

    name = "uniform-sf"

    def __init__(self, n: int, stream: int = 0):
        self.n = int(n)
        base = spherical_fibonacci_np(self.n)
        self.base = base[coherent_order(base)]
        self.stream = stream

    def directions(self, frame: int, seed: int) -> np.ndarray:
        R = rotation_for_frame(seed, frame, self.stream)
        return self.base @ R.T

    def plan(self, frame: int, seed: int, probe_ids) -> RayPlan:
        return _shared_plan(probe_ids, self.directions(frame, seed))


class FixedSFDirections(UniformSFDirections):
    """The unrotated spherical-Fibonacci set (stable rays for probe classification)."""

    name = "fixed-sf"

    def directions(self, frame: int, seed: int) -> np.ndarray:
        return self.base


class LobeDirections:
    """``k`` rays per texel of a bordered ``T x T`` probe square, drawn from ``cos^power`` lobes.

    Interior texels only, in row-major order; ``power = 1`` gives the cosine
    lobe whose plain sample mean estimates ``E / pi`` around the texel direction.
    Ray ``r`` of probe ``p``: texel ``(r // k)``, sample ``r % k``.
    """

    name = "lobe"

    def __init__(self, texels: int, k: int, power: float, stream: int = 7):
        self.texels = int(texels)
        self.k = int(k)
        self.power = float(power)
        self.stream = stream
        inner = texel_directions(self.texels)[1:-1, 1:-1].reshape(-1, 3)
        self.texel_dirs = mi.Float(inner.astype(np.float32).ravel())
        self.n_texels = len(inner)

    def plan(self, frame: int, seed: int, probe_ids) -> RayPlan:
        n = self.n_texels * self.k
        pids = mi.UInt32(np.asarray(probe_ids, np.uint32))
        m = len(probe_ids) * n
        idx = dr.arange(mi.UInt32, m)
        probe = dr.gather(mi.UInt32, pids, idx // n)
        texel = (idx % n) // self.k
        axis = dr.gather(mi.Vector3f, self.texel_dirs, texel)
        sampler = make_sampler(m, seed, frame, self.stream)
        u = sampler.next_2d()
        # cos^power lobe: cos(theta) = u^(1/(power+1))
        cos_t = dr.power(u.x, 1.0 / (self.power + 1.0))
        sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
        sp, cp = dr.sincos(2.0 * dr.pi * u.y)
        local = mi.Vector3f(cp * sin_t, sp * sin_t, cos_t)
        d = mi.Frame3f(axis).to_world(local)
        return RayPlan(probe, d, n, None, np.asarray(probe_ids))
