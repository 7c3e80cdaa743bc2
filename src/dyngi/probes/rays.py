"""Ray planners for probe updates (replaceable piece #1) and the ray plan they return.

A planner decides, per frame, which rays each probe traces. Interface
(:class:`~dyngi.probes.protocols.RayPlanner`):

``plan(frame, seed, probe_ids, previous=None, **hints) -> RayPlan``. ``previous`` is
the :class:`~dyngi.probes.trace.ProbeRayResults` of the previous update (its
per-ray radiance, distance and plan), or ``None`` on the first update; the
:class:`~dyngi.probes.pipeline.ProbePipeline` passes it. ADGI's Metropolis
chains (Datta et al. 2022, Algorithm 1-3) and IS-DDGI's allocation (its
supplement: ray counts per probe and per direction set from the previous
frame's change measure) consume it; the planners below ignore it.

A :class:`RayPlan` is a **per-probe ragged list** in CSR form: the rays of
traced probe ``i`` (``probe_ids[i]``) are ``offsets[i] .. offsets[i+1]``, each
with its probe index, slot ``i``, world direction and weight (``1 / pdf``
up to a constant; ``None`` = 1). The shared spherical-Fibonacci set of DDGI
is its fast path: ``shared_directions`` set and a constant ``rays_per_probe``,
which lets the estimator be one dense matrix product on the CPU (see
:mod:`dyngi.probes.estimator`).

A **masked** plan (:meth:`RayPlan.masked`; ours, for a frame that never reads back to the host) has a
fixed width set on the host (e.g. the ray budget) and a per-ray ``valid`` mask instead of a compacted
ragged list: its ``probe_ids`` is then a Dr.Jit ``UInt32`` of *slots* (``slot_valid`` says which are
used: each probe with a valid ray owns one slot, numbered by a device prefix sum over the probes), the
invalid rays have weight 0 (no estimator counts them) and the tracer masks them out; the rays cast are
``dr.count(valid)``, a device value. :func:`compact` packs the chosen lanes of a wider array into such a
fixed width on the device (``dr.compress`` without its host read).

* :class:`UniformSFDirections` -- DDGI (Majercik et al., JCGT 2019, Sec. 3.1):
  ``n`` spherical-Fibonacci directions under one fresh uniformly random
  rotation per frame, shared by every probe.
* :class:`FixedSFDirections` -- the same set without rotation (classification
  rays, Majercik et al. 2021 Sec. 5).
* :class:`LobeDirections` -- per-texel lobes for the reference volume: ``k``
  rays per texel drawn from a cosine-power lobe around the texel direction;
  its plan names the texel of every ray (``texel``), which the estimator bins by.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError
from ..sampling.fibonacci import coherent_order, rotation_for_frame, spherical_fibonacci_np
from ..sampling.octahedral import texel_directions
from ..sampling.rng import make_sampler
from .arrays import upload as _upload


@dataclass
class RayPlan:
    """One frame's probe rays as a per-probe ragged list (CSR). Dr.Jit arrays are per ray.

    probe : UInt32              probe index per ray
    direction : Vector3f        world direction per ray
    rays_per_probe : int | None constant count per probe, or ``None`` (ragged)
    shared_directions : (N, 3) ndarray | None   the one set every probe traces (fast path)
    probe_ids : (P_traced,) ndarray   traced probes, in ray order
    offsets : (P_traced + 1,) int64 ndarray   CSR: rays of slot ``i`` are ``offsets[i]:offsets[i+1]``
    slot : UInt32               index into ``probe_ids`` per ray
    weight : Float | None       per-ray sample weight (``1 / pdf``, any constant factor); ``None`` = 1
    texel : UInt32 | None       interior texel (row-major in the ``(T-2)^2`` interior) each ray belongs
                                to, for plans that sample per texel (``texel_res`` = that ``T``)
    valid : Bool | None         a masked plan (:meth:`masked`): the rays traced; ``probe_ids`` is then a
                                Dr.Jit UInt32 per slot and ``slot_valid`` the slots in use (no host copy)
    """

    probe: "mi.UInt32"
    direction: "mi.Vector3f"
    rays_per_probe: int | None
    shared_directions: np.ndarray | None
    probe_ids: np.ndarray
    offsets: np.ndarray | None = None
    slot: "mi.UInt32" = None
    weight: "mi.Float" = None
    texel: "mi.UInt32" = None
    texel_res: int | None = None
    valid: "mi.Bool" = None
    slot_valid: "mi.Bool" = None

    def __post_init__(self):
        if self.valid is not None:      # a masked plan: everything stays on the device
            if self.slot is None or self.slot_valid is None:
                raise DyngiError("a masked RayPlan needs its slots (use RayPlan.masked)")
            return
        self.probe_ids = np.asarray(self.probe_ids)
        P = len(self.probe_ids)
        if self.offsets is None:
            if self.rays_per_probe is None:
                raise DyngiError("a ragged RayPlan needs its per-probe offsets (use RayPlan.ragged)")
            self.offsets = np.arange(P + 1, dtype=np.int64) * int(self.rays_per_probe)
        self.offsets = np.asarray(self.offsets, np.int64)
        if self.slot is None:
            if self.rays_per_probe:
                n = dr.opaque(mi.UInt32, self.rays_per_probe)    # not a literal: budgets change it per frame
                self.slot = dr.arange(mi.UInt32, P * self.rays_per_probe) // n
            else:
                self.slot = upload(np.repeat(np.arange(P, dtype=np.uint32), self.counts), mi.UInt32)

    @property
    def is_masked(self) -> bool:
        return self.valid is not None

    @property
    def counts(self) -> np.ndarray:
        """(P_traced,) rays per traced probe (host plans only)."""
        if self.valid is not None:
            raise DyngiError("a masked RayPlan has no host counts (its slots are on the device)")
        return np.diff(self.offsets)

    @property
    def n_rays(self) -> int:
        """Rays of a host plan; lanes (an upper bound of the rays) of a masked one."""
        return dr.width(self.direction) if self.valid is not None else int(self.offsets[-1])

    def rays_cast(self):
        """Rays traced: an int for a host plan, a device ``dr.count(valid)`` (UInt32, width 1) for a masked one."""
        return dr.count(self.valid) if self.valid is not None else self.n_rays

    def reversed(self) -> "RayPlan":
        """The same plan along ``-w`` (same probes, slots, weights and lanes; no shared direction set, no
        texels): ADGI's shadow rays, whose distances go to the visibility texels (Sec. 4.8)."""
        return RayPlan(self.probe, -self.direction, self.rays_per_probe, None, self.probe_ids, self.offsets,
                       self.slot, self.weight, valid=self.valid, slot_valid=self.slot_valid)

    @staticmethod
    def masked(probe, direction, valid, n_probes: int, weight=None) -> "RayPlan":
        """A masked plan (module docstring) of ``dr.width(direction)`` lanes: lane ``i`` traces from probe
        ``probe[i]`` along ``direction[i]`` where ``valid[i]``. Slots: each probe with a valid lane gets the
        rank ``r`` of its id among those probes (a device prefix sum over the ``n_probes`` probes, so slots
        follow probe order as a host plan's would); there are ``min(n_probes, lanes)`` slots, ``probe_ids[r]``
        the probe of slot ``r`` and ``slot_valid[r]`` whether it is used. ``weight`` (a multiplicity or
        ``1 / pdf``; None = 1) is 0 on invalid lanes. No host read."""
        W = dr.width(direction)
        P = int(n_probes)
        S = max(min(P, W), 1)
        valid = mi.Bool(valid)
        has = dr.zeros(mi.UInt32, P)
        dr.scatter(has, mi.UInt32(1), probe, valid)
        rank = dr.prefix_sum(has)                           # exclusive: the slot of each probe that has rays
        slot = dr.select(valid, dr.gather(mi.UInt32, rank, probe, valid), 0)
        slot_probe = dr.zeros(mi.UInt32, S)
        dr.scatter(slot_probe, dr.arange(mi.UInt32, P), rank, has != 0)
        used = dr.sum(has)                                   # width 1, on the device
        slot_valid = dr.arange(mi.UInt32, S) < dr.gather(mi.UInt32, used, dr.zeros(mi.UInt32, S))
        w = mi.Float(1.0) if weight is None else mi.Float(weight)
        w = dr.select(valid, w, 0.0)
        dr.eval(slot, slot_probe, slot_valid, w)
        return RayPlan(mi.UInt32(probe), direction, None, None, slot_probe, None, slot, w, valid=valid,
                       slot_valid=slot_valid)

    @staticmethod
    def ragged(probe_ids, counts, direction, weight=None, pdf=None, texel=None, texel_res=None) -> "RayPlan":
        """A plan with ``counts[i]`` rays (possibly 0) for probe ``probe_ids[i]``, directions in slot order.

        ``pdf`` (per solid angle) gives ``weight = 1 / pdf``; give at most one of the two.
        """
        if weight is not None and pdf is not None:
            raise DyngiError("RayPlan.ragged: give either 'weight' or 'pdf', not both")
        pids = np.asarray(probe_ids, np.uint32)
        counts = np.asarray(counts, np.int64)
        if counts.shape != pids.shape or np.any(counts < 0):
            raise DyngiError(f"RayPlan.ragged: 'counts' must be {len(pids)} non-negative integers")
        offsets = np.concatenate([[0], np.cumsum(counts)])
        # uploaded copies: an aliased NumPy buffer's alignment decides the gather kernel (see arrays.upload)
        slot = upload(np.repeat(np.arange(len(pids), dtype=np.uint32), counts), mi.UInt32)
        probe = dr.gather(mi.UInt32, upload(pids, mi.UInt32), slot) if len(pids) else mi.UInt32()
        if pdf is not None:
            weight = dr.rcp(mi.Float(pdf))
        constant = int(counts[0]) if len(counts) and np.all(counts == counts[0]) and counts[0] > 0 else None
        return RayPlan(probe, direction, constant, None, pids, offsets, slot, weight, texel, texel_res)


def compact(active, capacity: int):
    """``dr.compress`` into a fixed ``capacity`` without a host read: ``(index UInt32, ok Bool)`` of width
    ``capacity``; the first ``min(dr.count(active), capacity)`` entries are the indices of the active lanes
    in increasing order (``ok`` True), the others 0 (``ok`` False). Lanes past the capacity are dropped."""
    C = max(int(capacity), 1)
    a = mi.Bool(active)
    pos = dr.prefix_sum(mi.UInt32(a))                     # exclusive: the output position of each lane
    idx = dr.zeros(mi.UInt32, C)
    fits = a & (pos < dr.opaque(mi.UInt32, C))     # opaque: the capacity may change per frame
    dr.scatter(idx, dr.arange(mi.UInt32, dr.width(a)), pos, fits)
    n = dr.count(a)
    ok = dr.arange(mi.UInt32, C) < dr.gather(mi.UInt32, mi.UInt32(n), dr.zeros(mi.UInt32, C))
    dr.eval(idx, ok)
    return idx, ok


def upload(array: np.ndarray, cls):
    return _upload(array, cls) if np.size(array) else cls()


def _shared_plan(probe_ids: np.ndarray, dirs: np.ndarray) -> RayPlan:
    n = len(dirs)
    pids = mi.UInt32(np.asarray(probe_ids, np.uint32))
    m = len(probe_ids) * n
    idx = dr.arange(mi.UInt32, m)
    nn = dr.opaque(mi.UInt32, n)     # a budget changes n per frame: not a literal in the kernels
    slot = idx // nn
    local = idx - slot * nn
    probe = dr.gather(mi.UInt32, pids, slot)
    dset = mi.Float(np.asarray(dirs, np.float32).ravel())
    d = dr.gather(mi.Vector3f, dset, local)
    return RayPlan(probe, d, n, np.asarray(dirs, np.float64), np.asarray(probe_ids), slot=slot)


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

    def plan(self, frame: int, seed: int, probe_ids, previous=None, **hints) -> RayPlan:
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

    def plan(self, frame: int, seed: int, probe_ids, previous=None, **hints) -> RayPlan:
        n = self.n_texels * self.k
        pids = mi.UInt32(np.asarray(probe_ids, np.uint32))
        m = len(probe_ids) * n
        idx = dr.arange(mi.UInt32, m)
        slot = idx // n
        probe = dr.gather(mi.UInt32, pids, slot)
        texel = (idx - slot * n) // self.k
        axis = dr.gather(mi.Vector3f, self.texel_dirs, texel)
        sampler = make_sampler(m, seed, frame, self.stream)
        u = sampler.next_2d()
        # cos^power lobe: cos(theta) = u^(1/(power+1))
        cos_t = dr.power(u.x, 1.0 / (self.power + 1.0))
        sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
        sp, cp = dr.sincos(2.0 * dr.pi * u.y)
        local = mi.Vector3f(cp * sin_t, sp * sin_t, cos_t)
        d = mi.Frame3f(axis).to_world(local)
        return RayPlan(probe, d, n, None, np.asarray(probe_ids), slot=slot, texel=texel, texel_res=self.texels)
