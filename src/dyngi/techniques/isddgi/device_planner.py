"""IS-DDGI's planner on the device (issue 26): the allocation, importance draws, per-set caps, the ray
layout and the change measure as Dr.Jit kernels over device state (Liu et al., I3D 2023, supplement
Secs. 2.1 and 4.2-4.4; Table 1's Multi-Rays / One-Ray limits).

:class:`DeviceISDDGIPlanner` is the device twin of :class:`~.planner.ISDDGIPlanner` (whose docstring
describes every choice; the formulas are the same): its per-probe and per-set state (Table 1's
allocation bytes, the smoothed change ``f_ij`` / ``F_i``, the stored hit samples and reference keys, the
adaptive ``x_i`` and the near-surface age) are Dr.Jit arrays, and one frame runs

1. **uniform rays** (Fig. 1's cells and rotation): one lane per (traced probe, cell) up to the largest
   uniform count, masked where ``c >= x_i`` -- the same integer hashes as the host's :func:`~.sets.uniform_keys`
   (32-bit wrap-around; ``K = 256 / x_i`` divides 2^32, so the rotation's ``mod K`` agrees);
2. **importance draws** (Secs. 4.3-4.4): the allocation pdf over the (probe, set) pairs of the candidates
   (traced probes with ``F_i > 0``; the pdf is 0 elsewhere), compacted on the device into a capacity that the
   last states read bounds (ours: the probes with change then; ``F`` changes only in :meth:`observe`)
   (:func:`~.device.allocation_pdf_dr`), its prefix sum and one binary search per draw
   (:func:`~.device.sample_pairs_dr`), ``importance_rays x`` (candidates) draws, the count computed on the
   device (the draw kernel runs at the capacity ``importance_rays x S``, masked); a frame after one without
   change skips steps 2-3 (:meth:`_uniform_plan`);
3. **per-set cap** with atomic counters (``dr.scatter_inc``): uniform rays first (slot 0 of their set),
   then each draw takes the next slot and is dropped at the limit. Draws of one set are
   indistinguishable (same pair, same frame key), so which ones the atomics keep does not change the
   rays: the plan is deterministic;
4. **layout**: the capped per-set counts' exclusive prefix sum gives each ray its place (rays grouped by
   probe, sets in order, the uniform ray first: the host plan's order), and one kernel computes the
   ray hash (a check visit repeats its set's reference key), Algorithm 1's jittered direction, the weight
   ``Omega_j / n_ij`` and the shading key -- bit-identical to the host planner's rays for the same
   uniform plan (tested).

**Host reads.** The probe pipeline's :class:`~dyngi.probes.rays.RayPlan` holds its CSR offsets on the host
and the volume its probe states, so a frame reads back two small buffers: after step 3 the per-probe ray
counts and three plan statistics (``S + 3`` integers), and after the states step the new ON/OFF flags
and five statistics (``S + 5``; one of them, the number of probes with ``F_i > 0``, lets the next frame
skip the draw kernels when no probe saw change); no per-ray or per-set array comes back. Relocation frames (every
``reclassify_interval``) read the rays' distances as ``ddgi``'s relocation does.

The change measure and the state update after the trace (:meth:`observe`; the paired visits, peak hold,
neighbour share, ``F_i`` and the adaptive rule of :meth:`~.planner.ISDDGIPlanner.observe`) and Algorithm 2
with the near-surface test (:meth:`probe_states`) run as kernels over the rays and the traced probes.

Budgets (``n_rays``; comparison budgets, ours) use the host planner on a host copy of the state
(:meth:`pull` / :meth:`push`: the budget's exact counts and redraws are host code). Float32 sums
throughout (ours; the host twin uses float64 for ``F_i``).
"""
from __future__ import annotations

import time

import numpy as np

from ...backend import dr, mi
from ...probes.arrays import upload
from ...probes.rays import RayPlan, compact
from ...probes.states import cell_extents
from ...sampling.rng import mix_seed
from .device import _LOCAL, allocation_pdf_dr, sample_pairs_dr
from .planner import ISDDGIPlanner, ISDDGIState
from .sets import (CELL_STREAM, CHANGE_EPS, LUMINANCE_FLOOR, N_SETS, NEIGHBOUR_SHARE, PROBE_MEAN_SHARE, RAYS_LIMIT,
                   SETS_PER_SIDE, SHIFT_STREAM, _NB, _hash_u32_dr, rays_from_hash)

IMPLS = ("device", "host")


def _op(cls, v):
    return dr.opaque(cls, v)


class DevicePlanInfo:
    """Device bookkeeping of one plan (per ray, Dr.Jit; per traced probe slot, ``total`` on the host).

    S : int; total : (S,) int64 (host; read back once); total_dr : (S,) UInt32
    slot, set, pair (``probe * 256 + set``, the volume's probe index), k (index inside its set) : UInt32
    paired : Bool (the set's uniform ray), check : Bool (a paired ray repeating its set's reference),
    rkey : UInt32 (the ray's random key); stats : dict of host ints."""

    def __init__(self, S, total, total_dr, pid_dr, slot, dset, pair, k, paired, check, rkey):
        self.S = int(S)
        self.total, self.total_dr, self.pid_dr = total, total_dr, pid_dr
        self.slot, self.set, self.pair, self.k = slot, dset, pair, k
        self.paired, self.check, self.rkey = paired, check, rkey
        self.dropped = 0
        self.stats: dict = {}

    def _table(self, mask=None):
        key = np.asarray(self.slot, np.int64) * N_SETS + np.asarray(self.set, np.int64)
        if mask is not None:
            key = key[np.asarray(mask, bool)]
        return np.bincount(key, minlength=self.S * N_SETS).reshape(self.S, N_SETS)

    # host tables for tests and diagnostics (they read back; the frame itself never builds them)
    @property
    def counts(self) -> np.ndarray:
        """(S, 256) rays per set (rayHitInfo ``num_ij``)."""
        return self._table()

    @property
    def uniform(self) -> np.ndarray:
        return self._table(self.paired) > 0

    @property
    def importance(self) -> np.ndarray:
        return self._table(~np.asarray(self.paired, bool))


class DeviceISDDGIPlanner:
    """The device planner (module docstring); the parameters are :class:`~.planner.ISDDGIPlanner`'s, whose
    host instance :attr:`host` serves budgets and holds the constants."""

    name = "isddgi"

    def __init__(self, n_probes: int, *args, **kwargs):
        self.host = ISDDGIPlanner(n_probes, *args, **kwargs)
        self.P = int(n_probes)
        self.force_uniform: int | None = None
        self.any_change = True      # some probe had F_i > 0 at the last states read (False: no draws to make)
        self.n_changed = int(n_probes)  # how many (bounds this frame's candidates of the draws)
        self._omega = upload(self.host.omega.astype(np.float32), mi.Float)
        self._nb = upload(((_NB[:, 1] + 1) * 3 + (_NB[:, 0] + 1)).astype(np.uint32), mi.UInt32)
        self._reset()

    # -- state -------------------------------------------------------------------------------
    def _reset(self) -> None:
        h, P = self.host, self.P
        PS = P * N_SETS
        self.log2x = dr.full(mi.UInt32, int(np.log2(h.x_init)), P)
        self.hold = dr.full(mi.UInt32, h.hold_frames, P)
        self.f = dr.zeros(mi.Float, PS)
        self.F = dr.zeros(mi.Float, P)
        self.sample_lum = dr.zeros(mi.Float, PS)
        self.sample_dist = dr.zeros(mi.Float, PS)
        self.has_sample = dr.full(mi.Bool, False, PS)
        self.open_ref = dr.full(mi.Bool, False, PS)
        self.ref_key = dr.zeros(mi.UInt32, PS)
        self.near_age = dr.full(mi.UInt32, 255, P)
        # memory, not literals: a literal zero array would be folded into the first frames' kernels, which
        # would then differ from the steady ones (a recompile the first time a change is measured)
        dr.make_opaque(self.log2x, self.hold, self.f, self.F, self.sample_lum, self.sample_dist, self.has_sample,
                       self.open_ref, self.ref_key, self.near_age)

    def pull(self) -> np.ndarray:
        """Copy the device state into :attr:`host`'s (host reads; budgets); returns the near-surface ages."""
        st, P = self.host.state, self.P
        st.log2_x[:] = np.asarray(self.log2x).astype(np.uint8)
        st.hold[:] = np.asarray(self.hold).astype(np.uint8)
        st.f[:] = np.asarray(self.f).reshape(P, N_SETS)
        st.F[:] = np.asarray(self.F)
        st.sample_lum[:] = np.asarray(self.sample_lum).reshape(P, N_SETS)
        st.sample_dist[:] = np.asarray(self.sample_dist).reshape(P, N_SETS)
        st.has_sample[:] = np.asarray(self.has_sample).reshape(P, N_SETS)
        st.open_ref[:] = np.asarray(self.open_ref).reshape(P, N_SETS)
        st.ref_key[:] = np.asarray(self.ref_key).reshape(P, N_SETS)
        return np.minimum(np.asarray(self.near_age), 255).astype(np.uint8)

    def push(self, near_age: np.ndarray) -> None:
        """Upload :attr:`host`'s state (after a budget frame) and the near-surface ages."""
        st = self.host.state
        self.log2x = upload(st.log2_x.astype(np.uint32), mi.UInt32)
        self.hold = upload(st.hold.astype(np.uint32), mi.UInt32)
        self.f = upload(st.f.ravel(), mi.Float)
        self.F = upload(st.F.astype(np.float32), mi.Float)
        self.sample_lum = upload(st.sample_lum.ravel(), mi.Float)
        self.sample_dist = upload(st.sample_dist.ravel(), mi.Float)
        self.has_sample = upload(st.has_sample.ravel().astype(np.uint32), mi.UInt32) != 0
        self.open_ref = upload(st.open_ref.ravel().astype(np.uint32), mi.UInt32) != 0
        self.ref_key = upload(st.ref_key.ravel(), mi.UInt32)
        self.near_age = upload(np.asarray(near_age, np.uint32), mi.UInt32)
        dr.eval(self.has_sample, self.open_ref)
        self.n_changed = int(np.count_nonzero(st.F > 0.0))
        self.any_change = self.n_changed > 0

    # -- the pipeline's warm-up hooks ---------------------------------------------------------
    def begin_warmup(self) -> None:
        self.force_uniform = N_SETS
        self.host.force_uniform = N_SETS

    def end_warmup(self) -> None:
        """As the host's: the change measure forgets the warm-up (its bounces are no scene change)."""
        self.force_uniform = None
        self.host.force_uniform = None
        PS = self.P * N_SETS
        self.f = dr.zeros(mi.Float, PS)
        self.F = dr.zeros(mi.Float, self.P)
        self.has_sample = dr.full(mi.Bool, False, PS)
        self.open_ref = dr.full(mi.Bool, False, PS)
        dr.make_opaque(self.f, self.F, self.has_sample, self.open_ref)

    def forget(self, probes) -> None:
        """Drop the stored samples (references) of ``probes`` (host ids; relocated probes)."""
        probes = np.asarray(probes, np.uint32)
        if not len(probes):
            return
        k = dr.arange(mi.UInt32, len(probes) * N_SETS)
        idx = dr.gather(mi.UInt32, upload(probes, mi.UInt32), k >> 8) * N_SETS + (k & 255)
        dr.scatter(self.has_sample, mi.Bool(False), idx)
        dr.scatter(self.open_ref, mi.Bool(False), idx)
        dr.eval(self.has_sample, self.open_ref)

    # -- planning ------------------------------------------------------------------------------
    def plan(self, frame: int, seed: int, probe_ids, previous=None, importance: np.ndarray | None = None,
             n_rays: int | None = None) -> RayPlan:
        """This frame's rays for ``probe_ids`` (see :meth:`ISDDGIPlanner.plan`); a budget (``n_rays``) plans
        on the host (:meth:`pull`; the caller pushes after its observe)."""
        if n_rays is not None and self.force_uniform is None:
            return self.host.plan(frame, seed, probe_ids, previous, importance, n_rays)
        t0 = time.perf_counter()
        h = self.host
        pid = np.asarray(probe_ids, np.uint32)
        S = len(pid)
        pid_dr = upload(pid, mi.UInt32)
        # no probe with change at the last states read: the draws would all be empty (skip their kernels)
        NI = int(np.ceil(h.importance_rays * S)) if self.force_uniform is None and self.any_change else 0
        if NI == 0:
            return self._uniform_plan(frame, seed, pid, pid_dr, t0)
        # -- 1. uniform rays: one lane per (slot, cell) up to the capacity, masked where c >= x_i --
        XC = self.force_uniform or h.x_max
        k = dr.arange(mi.UInt32, S * XC)
        xc = _op(mi.UInt32, XC)
        slot = k // xc
        c = k - slot * xc
        probe = dr.gather(mi.UInt32, pid_dr, slot)
        if self.force_uniform is None:
            lx = dr.gather(mi.UInt32, self.log2x, probe)
        else:
            lx = _op(mi.UInt32, int(np.log2(self.force_uniform)))
        valid_u = c < (mi.UInt32(1) << lx)
        K = mi.UInt32(N_SETS) >> lx
        sh = _hash_u32_dr(probe + SHIFT_STREAM)
        perm = _hash_u32_dr(sh * 0x9E3779B1 + c + CELL_STREAM)
        off = (_op(mi.UInt32, int(frame) & 0xFFFFFFFF) + sh + perm) & (K - 1)
        pair_u = slot * N_SETS + K * c + off
        buf = dr.zeros(mi.UInt32, S + 3)                    # the plan's read: counts per probe, statistics
        So = _op(mi.UInt32, S)                              # opaque: the traced-probe count varies per frame
        one = mi.UInt32(1)
        counts = dr.zeros(mi.UInt32, S * N_SETS)
        dr.scatter_inc(counts, pair_u, valid_u)
        dr.scatter_reduce(dr.ReduceOp.Add, buf, one, So, valid_u, mode=_LOCAL)          # uniform rays
        dr.eval(counts)
        # -- 2. importance draws over the allocation pdf of the traced probes --
        imp = (dr.full(mi.Bool, True, S) if importance is None
               else upload(np.asarray(importance, np.uint32), mi.UInt32) != 0)
        Fs = dr.select(imp, dr.gather(mi.Float, self.F, pid_dr), 0.0)
        n_cand = dr.sum(mi.UInt32(Fs > 0.0))
        n_imp = mi.UInt32(dr.round(mi.Float(n_cand) * _op(mi.Float, h.importance_rays)))
        # the candidates (F_i > 0; the pdf is 0 elsewhere), compacted on the device into a capacity known on the
        # host: the probes with change at the last states read, which bounds them (F changes only in observe)
        C = max(1, min(S, self.n_changed))
        cand, cok = compact(Fs > 0.0, C)
        Fc = dr.select(cok, dr.gather(mi.Float, Fs, cand), 0.0)
        kk = dr.arange(mi.UInt32, C * N_SETS)
        cs = dr.gather(mi.UInt32, cand, kk >> 8)
        fv = dr.gather(mi.Float, self.f, dr.gather(mi.UInt32, pid_dr, cs) * N_SETS + (kk & 255))
        pdf = allocation_pdf_dr(Fc, fv, h.eps)
        pc = sample_pairs_dr(pdf, NI, mix_seed(seed, frame, 0x15DD62), self.P * N_SETS)   # prefix sum + search
        pair_i = dr.gather(mi.UInt32, cand, pc >> 8) * N_SETS + (pc & 255)
        valid_i = (dr.arange(mi.UInt32, NI) < n_imp) & (dr.gather(mi.Float, pdf, pc) > 0.0)
        # -- 3. per-set cap: atomic counters, the uniform ray first --
        si = dr.scatter_inc(counts, pair_i, valid_i)
        keep_i = valid_i & (si < _op(mi.UInt32, h.limit))
        dr.scatter_reduce(dr.ReduceOp.Add, buf, one, So + 1, keep_i, mode=_LOCAL)       # importance rays kept
        dr.scatter_reduce(dr.ReduceOp.Add, buf, one, So + 2, valid_i, mode=_LOCAL)      # drawn
        dr.eval(si, keep_i, counts)
        capped = dr.minimum(counts, _op(mi.UInt32, h.limit))
        totals = dr.block_sum(capped, N_SETS)
        start = dr.prefix_sum(capped)                       # exclusive
        dr.scatter(buf, totals, dr.arange(mi.UInt32, S))
        host = np.asarray(buf).astype(np.int64)            # the plan's one read
        tot = host[:S]
        R = int(tot.sum())
        # -- 4. layout: each ray's place from the prefix sum (a set's uniform ray first) --
        ray_pair = dr.zeros(mi.UInt32, R)
        ray_k = dr.zeros(mi.UInt32, R)
        paired = dr.full(mi.Bool, False, R)                 # the set's uniform ray (a draw may be ray 0 of its set)
        pos_u = dr.gather(mi.UInt32, start, pair_u, valid_u)
        dr.scatter(ray_pair, pair_u, pos_u, valid_u)
        dr.scatter(paired, mi.Bool(True), pos_u, valid_u)
        pos_i = dr.gather(mi.UInt32, start, pair_i, keep_i) + si
        dr.scatter(ray_pair, pair_i, pos_i, keep_i)
        dr.scatter(ray_k, si, pos_i, keep_i)
        dr.eval(ray_pair, ray_k, paired)
        rslot = ray_pair >> 8
        dset = ray_pair & 255
        rprobe = dr.gather(mi.UInt32, pid_dr, rslot)
        gp = rprobe * N_SETS + dset
        check = paired & dr.gather(mi.Bool, self.open_ref, gp)
        fkey = _op(mi.UInt32, mix_seed(seed, frame, 0x1DD61))
        rep = check if self.host.repeat_checks else dr.full(mi.Bool, False, R)   # paired-visit repeats (ours)
        key = dr.select(rep, dr.gather(mi.UInt32, self.ref_key, gp), fkey)
        hsh = _hash_u32_dr(rprobe * (N_SETS * RAYS_LIMIT) + dset * RAYS_LIMIT + ray_k + key)
        hsh = _hash_u32_dr(hsh ^ key)
        npair = dr.gather(mi.UInt32, capped, ray_pair)
        dr.schedule(rslot, dset, gp, check, key)          # evaluated with the rays' kernel below
        direction, weight, shade_key = rays_from_hash(hsh, dset, npair, self._omega)
        offsets = np.concatenate([[0], np.cumsum(tot)])
        plan = RayPlan(rprobe, direction, None, None, pid, offsets, rslot, weight)   # ragged always (no literal)
        info = DevicePlanInfo(S, tot, totals, pid_dr, rslot, dset, gp, ray_k, paired, check, key)
        info.dropped = int(host[S + 2] - host[S + 1])
        info.stats = {"uniform_rays": int(host[S]), "importance_rays": int(host[S + 1]),
                      "importance_dropped": info.dropped}
        plan.info = info
        plan.shade_key = shade_key
        info.stats["plan_ms"] = (time.perf_counter() - t0) * 1e3
        return plan

    def _uniform_plan(self, frame: int, seed: int, pid: np.ndarray, pid_dr, t0: float) -> RayPlan:
        """A plan without importance rays (the warm-up, frames after one without change): ``x_i`` uniform
        rays per probe, already in set order (cell ``c``'s set ``K c + off`` grows with ``c``), so a ray's place
        is its probe's offset plus its cell -- no per-set count tables or prefix sums over ``S x 256`` (ours;
        the same rays as the general path). One read: the ``S`` uniform counts."""
        S = len(pid)
        if self.force_uniform is None:
            lxs = dr.gather(mi.UInt32, self.log2x, pid_dr)
        else:
            lxs = dr.full(mi.UInt32, int(np.log2(self.force_uniform)), S)
        xs = mi.UInt32(1) << lxs
        dr.eval(xs)
        tot = np.asarray(xs).astype(np.int64)              # the plan's one read: rays per probe
        R = int(tot.sum())
        offsets = np.concatenate([[0], np.cumsum(tot)])
        rslot = upload(np.repeat(np.arange(S, dtype=np.uint32), tot), mi.UInt32)
        start = upload(offsets[:-1].astype(np.uint32), mi.UInt32)
        c = dr.arange(mi.UInt32, R) - dr.gather(mi.UInt32, start, rslot)
        rprobe = dr.gather(mi.UInt32, pid_dr, rslot)
        lx = dr.gather(mi.UInt32, lxs, rslot)
        K = mi.UInt32(N_SETS) >> lx
        sh = _hash_u32_dr(rprobe + SHIFT_STREAM)
        perm = _hash_u32_dr(sh * 0x9E3779B1 + c + CELL_STREAM)
        dset = K * c + ((_op(mi.UInt32, int(frame) & 0xFFFFFFFF) + sh + perm) & (K - 1))
        gp = rprobe * N_SETS + dset
        check = dr.gather(mi.Bool, self.open_ref, gp)
        rep = check if self.host.repeat_checks else dr.full(mi.Bool, False, R)   # paired-visit repeats (ours)
        key = dr.select(rep, dr.gather(mi.UInt32, self.ref_key, gp), _op(mi.UInt32, mix_seed(seed, frame, 0x1DD61)))
        hsh = _hash_u32_dr(_hash_u32_dr(rprobe * (N_SETS * RAYS_LIMIT) + dset * RAYS_LIMIT + key) ^ key)
        dr.eval(dset, gp, check, key, hsh)
        direction, weight, shade_key = rays_from_hash(hsh, dset, mi.UInt32(1), self._omega)
        plan = RayPlan(rprobe, direction, None, None, pid, offsets, rslot, weight)
        info = DevicePlanInfo(S, tot, xs, pid_dr, rslot, dset, gp, dr.zeros(mi.UInt32, R), dr.full(mi.Bool, True, R),
                              check, key)
        info.stats = {"uniform_rays": R, "importance_rays": 0, "importance_dropped": 0}
        plan.info = info
        plan.shade_key = shade_key
        info.stats["plan_ms"] = (time.perf_counter() - t0) * 1e3
        return plan

    # -- feedback --------------------------------------------------------------------------------
    def observe(self, plan: RayPlan, lum, dist, adapt: bool = True, out=None):
        """The host :meth:`~.planner.ISDDGIPlanner.observe` on the device: ``lum``, ``dist`` (R,) Float in
        ray order (the paired-visit change measure of :meth:`~.planner.ISDDGIPlanner.ray_change`, its sums
        sharing kernels with the state updates: a handful of launches per frame). Statistics are added into ``out``
        (UInt32, ``S + 5``; allocated if None, and returned): ``S`` dynamic rays, ``S + 1`` check rays,
        ``S + 2`` probes that saw change, ``S + 3`` the sum of ``x_i`` over all probes, ``S + 4`` the probes
        with ``F_i > 0``."""
        h, info = self.host, plan.info
        S = info.S
        pid_dr, slot, gp, dset = info.pid_dr, info.slot, info.pair, info.set
        paired, check = info.paired, info.check
        if out is None:
            out = dr.zeros(mi.UInt32, S + 5)
        So = _op(mi.UInt32, S)
        dmax, tau, decay = _op(mi.Float, h.max_distance), _op(mi.Float, h.tau), _op(mi.Float, h.decay)
        one = mi.UInt32(1)
        # -- the probe's mean hit luminance (the change measure's floor) --
        lum_sum, cnt = dr.zeros(mi.Float, S), dr.zeros(mi.Float, S)
        dr.scatter_reduce(dr.ReduceOp.Add, lum_sum, lum, slot, mode=_LOCAL)
        dr.scatter_reduce(dr.ReduceOp.Add, cnt, mi.Float(1.0), slot, mode=_LOCAL)
        dr.eval(lum_sum, cnt)
        # -- change g of the check visits against the stored samples; per-probe sums; statistics --
        ybar = dr.gather(mi.Float, lum_sum, slot) / dr.maximum(dr.gather(mi.Float, cnt, slot), 1.0)
        y_old = dr.gather(mi.Float, self.sample_lum, gp, paired)
        d_old = dr.gather(mi.Float, self.sample_dist, gp, paired)
        hs_old = dr.gather(mi.Bool, self.has_sample, gp, paired)
        measured = paired & check & hs_old
        dcl = dr.minimum(dr.abs(dist), dmax)
        c_l = dr.abs(lum - y_old) / (lum + y_old + PROBE_MEAN_SHARE * ybar + LUMINANCE_FLOOR)
        c_d = dr.abs(dcl - d_old) / dmax
        g = dr.select(measured, dr.maximum(dr.maximum(c_l, c_d) - tau, 0.0) / dr.maximum(1.0 - tau, 1e-6), 0.0)
        g_sum, n_meas, dyn = dr.zeros(mi.Float, S), dr.zeros(mi.Float, S), dr.zeros(mi.UInt32, S)
        dr.scatter_reduce(dr.ReduceOp.Add, g_sum, g, slot, mode=_LOCAL)
        dr.scatter_reduce(dr.ReduceOp.Add, n_meas, mi.Float(1.0), slot, measured, mode=_LOCAL)
        dr.scatter_reduce(dr.ReduceOp.Add, dyn, one, slot, g > 0.0, mode=_LOCAL)
        dr.scatter_reduce(dr.ReduceOp.Add, out, one, So, g > 0.0, mode=_LOCAL)          # dynamic rays
        dr.scatter_reduce(dr.ReduceOp.Add, out, one, So + 1, measured, mode=_LOCAL)     # check rays
        # a reference visit opens a reference (a first visit only on the even checkerboard squares)
        openv = ~check & (hs_old | ((((dset & 15) + (dset >> 4)) & 1) == 0))
        dr.eval(g, openv, dcl)
        dr.scatter(self.open_ref, openv, gp, paired)
        dr.scatter(self.sample_lum, lum, gp, paired)
        dr.scatter(self.sample_dist, dcl, gp, paired)
        dr.scatter(self.ref_key, info.rkey, gp, paired)
        dr.scatter(self.has_sample, mi.Bool(True), gp, paired)
        # -- smoothed change per set: one lane per traced (probe, set): decay, then at the sets with a paired
        #    ray the peak hold and its threshold (the host's order; g reaches its set through a scratch array) --
        g_pair = dr.full(mi.Float, -1.0, S * N_SETS)          # -1: no paired ray in the set this frame
        dr.scatter(g_pair, g, (slot << 8) + dset, paired)
        kk = dr.arange(mi.UInt32, S * N_SETS)
        q = dr.gather(mi.UInt32, pid_dr, kk >> 8) * N_SETS + (kk & 255)
        fd = dr.gather(mi.Float, self.f, q) * decay
        gk = dr.gather(mi.Float, g_pair, kk)
        fv = dr.maximum(gk, fd)
        fd = dr.select(gk >= 0.0, dr.select(fv < CHANGE_EPS * 0.1, 0.0, fv), fd)
        dr.eval(fd)
        dr.scatter(self.f, fd, q)
        # -- F_i (Sec. 4.3: 256 x the check visits' mean g) and the adaptive uniform count (one lane per probe) --
        F_est = dr.select(n_meas > 0.0, N_SETS * g_sum / dr.maximum(n_meas, 1.0), 0.0)
        Fn = dr.maximum(F_est, decay * dr.gather(mi.Float, self.F, pid_dr))
        dr.scatter(self.F, dr.select(Fn < CHANGE_EPS, 0.0, Fn), pid_dr)
        changed = dyn > 0
        dr.scatter_reduce(dr.ReduceOp.Add, out, one, So + 2, changed, mode=_LOCAL)      # probes that saw change
        if adapt:
            lo, hi = int(np.log2(h.x_min)), int(np.log2(h.x_max))
            lx = dr.gather(mi.UInt32, self.log2x, pid_dr)
            hold = dr.gather(mi.UInt32, self.hold, pid_dr)
            expire = ~changed & (hold <= 1)
            lx = dr.select(changed, dr.minimum(lx + 1, _op(mi.UInt32, hi)),
                           dr.select(expire & (lx > _op(mi.UInt32, lo)), lx - 1, lx))
            hold = dr.select(changed | expire, _op(mi.UInt32, h.hold_frames), hold - 1)
            dr.scatter(self.log2x, lx, pid_dr)
            dr.scatter(self.hold, hold, pid_dr)
        dr.eval()                  # f, F, x: before the neighbours' share and the statistics read them
        # -- the 8 neighbouring sets get NEIGHBOUR_SHARE of a measured change --
        R = dr.width(g)
        if R:
            kn = dr.arange(mi.UInt32, R * len(_NB))
            r = kn // len(_NB)
            nb = dr.gather(mi.UInt32, self._nb, kn - r * len(_NB))       # (dy + 1) * 3 + dx + 1
            gr = dr.gather(mi.Float, g, r)
            jr = dr.gather(mi.UInt32, dset, r)
            nx = dr.clip(mi.Int32(jr & 15) + mi.Int32(nb % 3) - 1, 0, SETS_PER_SIDE - 1)
            ny = dr.clip(mi.Int32(jr >> 4) + mi.Int32(nb // 3) - 1, 0, SETS_PER_SIDE - 1)
            idx = (dr.gather(mi.UInt32, gp, r) & ~mi.UInt32(255)) + mi.UInt32(ny * SETS_PER_SIDE + nx)
            # Direct: Auto picked "expand" here (a per-thread copy of the P x 256 target, cleared and reduced every
            # frame: ~4 of observe's ~7 ms on tunnel-gate) although few lanes are active
            dr.scatter_reduce(dr.ReduceOp.Max, self.f, gr * NEIGHBOUR_SHARE, idx, gr > 0.0, mode=dr.ReduceMode.Direct)
        # -- over all probes: the sum of x_i and the probes with change --
        dr.scatter_reduce(dr.ReduceOp.Add, out, one << self.log2x, So + 3, mode=_LOCAL)
        dr.scatter_reduce(dr.ReduceOp.Add, out, one, So + 4, self.F > 0.0, mode=_LOCAL)
        dr.eval(out, self.f)
        return out

    def probe_states(self, volume, plan: RayPlan, dist, warm: bool, backface_threshold: float,
                     near_surface: bool, out=None):
        """Algorithm 2 (front-face minimum over front faces, :func:`~.estimator.probe_states_alg2`) and, with
        ``near_surface``, DDGI's near-surface test over the rotation window (:func:`~.estimator.near_surface_hits`,
        :func:`~.estimator.near_window`) on the device: (S,) Bool ON per traced slot, also written (as 0/1)
        into ``out[:S]`` if given. Runs before :meth:`observe` (the window uses this frame's ``x_i``)."""
        info = plan.info
        S, slot = info.S, info.slot
        one = mi.UInt32(1)
        back, front, ns = dr.zeros(mi.UInt32, S), dr.zeros(mi.UInt32, S), dr.zeros(mi.UInt32, S)
        fin = dr.isfinite(dist)
        dr.scatter_reduce(dr.ReduceOp.Add, back, one, slot, dist < 0.0, mode=_LOCAL)
        dr.scatter_reduce(dr.ReduceOp.Add, front, one, slot, (dist >= 0.0) & fin, mode=_LOCAL)
        if near_surface:
            lo, hi = cell_extents(volume, np.asarray(plan.probe_ids, np.int64))
            ext = upload(np.concatenate([lo, hi], 1).astype(np.float32).ravel(), mi.Float)     # (S, 6)
            w = plan.direction
            t_exit = mi.Float(np.inf)
            for a in range(3):
                e = dr.gather(mi.Float, ext, slot * 6 + dr.select(w[a] > 0.0, a + 3, a))
                aw = dr.abs(w[a])
                t_exit = dr.minimum(t_exit, dr.select(aw > 0.0, e / aw, np.inf))
            near = (dist > 0.0) & fin & (dist <= t_exit)
            dr.scatter_reduce(dr.ReduceOp.Add, ns, one, slot, near, mode=_LOCAL)
        dr.eval(back, front, ns)
        tot = info.total_dr
        on = (front > 0) & (mi.Float(back) < _op(mi.Float, backface_threshold) * mi.Float(tot)) & (tot > 0)
        if near_surface:
            pid_dr = info.pid_dr
            age = dr.gather(mi.UInt32, self.near_age, pid_dr)
            age = dr.select(ns > 0, 0, dr.minimum(age + 1, 255))
            x = tot if warm else (one << dr.gather(mi.UInt32, self.log2x, pid_dr))
            on &= age < dr.maximum(mi.UInt32(N_SETS) // dr.maximum(x, 1), 1)
            dr.eval(age, on)
            dr.scatter(self.near_age, age, pid_dr)
        if out is not None:
            dr.scatter(out, mi.UInt32(on), dr.arange(mi.UInt32, S))
        dr.eval(on, self.near_age)
        return on


__all__ = ["DeviceISDDGIPlanner", "DevicePlanInfo", "IMPLS", "ISDDGIState"]
