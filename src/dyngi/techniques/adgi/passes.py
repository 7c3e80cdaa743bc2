"""ADGI's passes as a multi-pass planner of the probe pipeline (Datta et al. 2022, Secs. 4.1-4.9; a
:class:`~dyngi.probes.protocols.MultiPassPlanner`).

:meth:`ADGIPasses.passes` yields one frame's passes to :meth:`ProbePipeline.update_passes
<dyngi.probes.pipeline.ProbePipeline.update_passes>`, each timed in its stage of Table 4 (``P``, ``S``, ``D``):

* ``'states'`` (every ``reclassify_interval`` frames; ours, ``ddgi``'s): the probes of ``V_out`` and the
  inactive ones re-test their state from ``ddgi``'s fixed classification rays;
* ``'pilot'`` (stage P): 8 pilot rays per probe of ``V_out`` (:class:`.heuristics.PilotRays`; both frames of a
  pair draw the same NEE samples, RNG frame ``index // 2``); from their results the heuristics f_c, f_v,
  f_r, f_s, f_d and the 6-10-10 word per octant (:func:`.heuristics.pack_heuristics`); on the first frame of
  each pair the accumulator merges them too (Sec. 4.4, as static samples);
* ``'static'`` (stage S): the static chains' plan (:class:`.planner.ADGIChainPlanner`), traced along ``w`` and
  ``-w``, merged with N_max static (dynamic for samples of octants with f_d > 0, ``change_cap``);
* ``'dynamic'`` (stage D): the dynamic chains' proxy octants, along ``w`` and ``-w``, N_max dynamic;
* ``'finish'`` (stage D): the accumulator's outer count cap and convolution (:mod:`.accumulate`).

Between the passes: the equal-ray / equal-time budget (:meth:`ADGIPasses._plan_budget`, after P; D gets
what S left), Sec. 4.9's culling (``used``: the probes the last primary pass read), and the rays counted
exactly (probe rays, their NEE shadow rays, the ``-w`` rays). On the device path (``device``) the counts
stay device values until :meth:`ADGIPasses.finish_frame`, after the frame's image. The warm-up's updates
plan ``ddgi``'s shared spherical-Fibonacci set of ``warmup_rays`` (:meth:`ADGIPasses.plan`; 32 by
default, Q-DDGI's warm-up) and are charged to frame 0: an equal-ray budget on frame 0 counts them as spent.
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...probes import UniformSFDirections
from ...probes.arrays import upload
from ...probes.pipeline import ProbePass
from ...probes.trace import ProbeRayResults, trace_probe_distances
from ..base import Frame, StageTimer
from .heuristics import (OCTANTS, ADGIHeuristics, frusta, octant_of, pack_heuristics, unpack_heuristics,
                         view_distances, view_geometry)
from .planner import ADGIChainPlanner

PILOT_STREAM, STATIC_STREAM, DYNAMIC_STREAM = 41, 43, 45     # random streams of the three traces


class ADGIPasses:
    """ADGI's pilot, static and dynamic passes (module docstring).

    ``volume``: the probe volume; ``params``: the technique's; ``shader``: the hit shader of every pass (the
    pilot's direct part for f_r); ``device``: the device path.
    """

    def __init__(self, volume, params: dict, shader, device: bool):
        p = params
        self.params = p
        self.volume = volume
        self.shader = shader
        self.device = bool(device)
        self.heur = ADGIHeuristics(volume.grid, p["camera_threshold"] or None, p["beta"], p["mu"], p["theta"])
        self.hstate = self.heur.initial_state()
        self.cuts = (p["v_in_clip"], p["v_in_fc"], p["v_out_clip"], p["v_out_fc"])     # Fig. 6b (marked)
        # -- the chains: static over probe cells, dynamic over 3x3x3 proxies (grid units) --
        self.chains = ADGIChainPlanner(volume, p)
        self.chains.device = self.device
        self.warmup = UniformSFDirections(p["warmup_rays"])     # ddgi's shared set, for the warm-up's updates
        self.used = dr.full(mi.Float, 1.0, volume.n_probes)    # probes the last primary pass read (all at first)
        self.scene = None           # the scene D's distance rays trace (the technique's, set per frame)
        self._shadow_rate = 1.0                # NEE shadow rays per probe ray (measured)
        self._static_rays = None               # this frame's ray allowance of S and D (None: no budget)
        self._dynamic_rays = None
        self._time_avail_ms = None             # equal time: this frame's ms for S + D (None: no time budget)
        self._ms_per_ray = {"S": None, "D": None}   # measured on the last frame that traced in the stage
        self._ms_fixed = 0.0                   # measured: the last frame's time outside S and D
        self._frame_dev = []        # this frame's device ray counts before the budget: (count, lower, estimate)
        self._rates = []            # (probe rays, NEE shadow rays) of this frame's traces, device values
        self._dyn_prev = False      # the last frame's "some f_d > 0" (device path, read after its image)
        self._static_limit = self._dynamic_limit = None   # device caps of S and D under a ray budget
        self._static_rays_max = self._dynamic_rays_max = None
        self._avail_dev = None

    # -- the warm-up's planner (RayPlanner) ---------------------------------------------------------
    def plan(self, frame: int, seed: int, probe_ids, previous=None, **hints):
        """The warm-up's single-pass updates: ``ddgi``'s rotated spherical-Fibonacci set of ``warmup_rays``."""
        return self.warmup.plan(frame, seed, probe_ids, previous, **hints)

    def k_for(self, frame: Frame, geo=None) -> float:
        """Eq. 10's k on ``frame`` (:meth:`.heuristics.ADGIHeuristics.k_for`: the user's, else from the camera
        distances of the active probes in view); ``geo``: the frame's :func:`.heuristics.view_geometry`."""
        vol = self.volume
        view = None if self.heur.user_k is not None else \
            view_distances(vol, frame.camera, frame.res, vol.state.states != 0, self.cuts[2], geo)
        return self.heur.k_for(frame.camera.origin, view)

    # -- one frame's passes (MultiPassPlanner) --------------------------------------------------------
    def passes(self, frame: Frame, timer: StageTimer):
        """The frame's passes (module docstring); returns the stats of the update (device values on the
        device path: :meth:`finish_frame` reads them)."""
        p = self.params
        t = timer
        vol = self.volume
        # -- ddgi's relocation/classification after the warm-up (the paper is silent; ours) --
        if frame.index > 0 and p["reclassify_interval"] and frame.index % p["reclassify_interval"] == 0 and \
                (p["relocate"] or p["classify"]):
            geo = view_geometry(vol, frame.camera, frame.res)
            _, _, near = frusta(vol, frame.camera, frame.res, self.k_for(frame, geo), self.cuts, geo)
            yield self._states_pass(near | (vol.state.states == 0))
        active = vol.state.states != 0
        geo = view_geometry(vol, frame.camera, frame.res)      # once per frame (the states pass may move probes)
        fc, v_in, v_out = frusta(vol, frame.camera, frame.res, self.k_for(frame, geo), self.cuts, geo)
        v_in &= active
        v_out &= active
        stats = {}
        # -- P: pilot rays and heuristics (Sec. 4.1-4.4), over V_out's bounding box (heuristics.update) --
        box = self.heur.box_of(v_out)
        with t.stage("P"):
            ids = np.flatnonzero(v_out).astype(np.uint32)
            if len(ids):
                plan = self.heur.pilot.plan(frame.index, frame.seed, ids)
                # both frames of a pair draw the same NEE samples (sampler seeded by the pair): f_r's time
                # difference then sees scene changes, not NEE noise (ours)
                got = yield ProbePass("pilot", plan, PILOT_STREAM, frame=frame.index // 2, shader=self.shader,
                                      options={"merge": p["pilot_updates"] and frame.index % 2 == 0})
                res = got.results
                lum = mi.luminance(self.shader.last_direct)
                n_p = self._count(got.timer)
                t.add_rays("P", n_p)
                if self.device and not isinstance(n_p, int):   # the budget's device count (and host bounds)
                    self._frame_dev.append((n_p, 8 * len(ids), 8 * len(ids) * (1.0 + self._shadow_rate)))
                self.hstate = self.heur.update(self.hstate, frame.index, ids, res.distance, lum, fc, box)
            # (no probe in V_out: nothing to update; the triggers decay lazily when probes come back into view)
            # -- the 6-10-10 word per octant (Sec. 4.3) of V_out's box; the chains read the quantised values --
            vin_dr = upload(v_in.astype(np.float32), mi.Float)
            self._pack(box, vin_dr, p["mu"])
        self._plan_budget(frame, t)
        # -- Sec. 4.9's culling: the chains sample only probes of V_in that the last primary pass used --
        samp_dr = vin_dr * self.used if p["cull_unused"] else vin_dr
        # -- S: static chains (Sec. 4.8) --
        with t.stage("S"):
            stats["static_samples"] = yield from self._static(frame, samp_dr, self._fd, t)
        if self._time_avail_ms is not None:      # equal time: D gets what S left
            per = self._ms_per_ray["D"] or self._ms_per_ray["S"]
            self._dynamic_rays = None if per is None else max(self._time_avail_ms - t.ms.get("S", 0.0), 0.0) / per
        # -- D: dynamic chains on proxies (Sec. 4.9), then the outer cap and the convolution --
        with t.stage("D"):
            stats["dynamic_proxy_octants"] = yield from self._dynamic(frame, samp_dr, self._fd, t)
            stats["probes_updated"] = yield ProbePass("finish", options={"outer": v_out & ~v_in})
        stats["v_in"], stats["v_out"] = int(v_in.sum()), int(v_out.sum())
        stats["static_chains_run"] = self.chains.n_run
        return stats

    def _pack(self, box, vin_dr, mu: float) -> None:
        """The 6-10-10 words (Sec. 4.3, :func:`.heuristics.pack_heuristics`) of the entries of ``box`` (V_out's
        bounding box; the scale F the max of f_d there), written into the per-entry tables ``lut``, ``_fs_q``
        and ``_fd`` the chains read (entries outside the box keep older values: only V_in's are read)."""
        vol = self.volume
        P8 = vol.n_probes * OCTANTS
        if getattr(self, "lut", None) is None:
            self.lut = dr.zeros(mi.UInt32, P8)
            self._fs_q = dr.zeros(mi.Float, P8)
            self._fd = dr.zeros(mi.Float, P8)
            dr.make_opaque(self.lut, self._fs_q, self._fd)
        if box is None:
            self.lut_scale = dr.opaque(mi.Float, 0.0)
            return
        nx, ny, _ = (int(c) for c in vol.grid.counts)
        lo, hi = box
        bx, by, bz = (hi[i] - lo[i] for i in range(3))
        lane = dr.arange(mi.UInt32, bx * by * bz * OCTANTS)
        lp = lane // OCTANTS
        o = lane - lp * OCTANTS
        bxo, byo = dr.opaque(mi.UInt32, bx), dr.opaque(mi.UInt32, by)
        gi = lp % bxo + dr.opaque(mi.UInt32, lo[0])
        gj = (lp // bxo) % byo + dr.opaque(mi.UInt32, lo[1])
        gk = lp // (bxo * byo) + dr.opaque(mi.UInt32, lo[2])
        probe = gi + nx * (gj + ny * gk)
        e = probe * OCTANTS + o
        h = self.hstate
        fv = dr.gather(mi.Float, h.fv, e)
        fs = dr.gather(mi.Float, h.fc, probe) * fv
        fd = fs * (dr.gather(mi.Float, h.fdv, e) + dr.opaque(mi.Float, mu) * dr.gather(mi.Float, h.fdr, e))
        word, self.lut_scale = pack_heuristics(fv, fs, fd, dr.gather(mi.Float, vin_dr, probe))
        _, fs_q, fd_q, _ = unpack_heuristics(word, self.lut_scale)
        dr.eval(word, fs_q, fd_q)
        for dst, src in ((self.lut, word), (self._fs_q, fs_q), (self._fd, fd_q)):
            dr.scatter(dst, src, e)
        dr.eval(self.lut, self._fs_q, self._fd)

    def _states_pass(self, mask: np.ndarray) -> ProbePass:
        """``ddgi``'s relocation and classification after the warm-up (issue 12 item 5; the paper is
        silent, ours): every ``reclassify_interval`` frames, the probes of ``V_out`` (those the frame can
        use; ``ddgi`` re-tests the probes it updates) and every inactive probe (``ddgi``'s re-test) are
        re-tested with ``ddgi``'s fixed set of classification rays (:meth:`ProbePipeline.classify
        <dyngi.probes.pipeline.ProbePipeline.classify>`, 32 spherical-Fibonacci rays) and
        :class:`~dyngi.probes.states.ProbeStates` moves / (de)activates it as ``ddgi`` does. The rays are
        counted (stage ``states``) and come out of an equal-ray budget before the chains are sized."""
        return ProbePass("states", classify=np.flatnonzero(mask).astype(np.uint32))

    def _static(self, frame: Frame, vin_dr, fd, t: StageTimer):
        """S: the static plan, traced along ``w`` and ``-w`` and merged with N_max static (Sec. 4.8)."""
        plan = self.chains.plan(frame.index, frame.seed, stage="static", vin=vin_dr, fs=self._fs_q, fd=fd,
                                rays=self._static_rays, shadow_rate=self._shadow_rate,
                                rays_max=self._static_rays_max, limit=self._static_limit)
        if plan is None:
            return 0
        lane_cap = None
        if self.params["change_cap"]:    # samples of entries with f_d > 0 merge with the dynamic N_max (ours)
            changed = dr.gather(mi.Float, fd, plan.probe * OCTANTS + octant_of(plan.direction)) > 0.0
            lane_cap = dr.select(changed, mi.UInt32(self.params["n_max_dynamic"]),
                                 mi.UInt32(self.params["n_max_static"]))
        got = yield ProbePass("static", plan, STATIC_STREAM, shader=self.shader, reverse_distances=True,
                              options={"lane_cap": lane_cap})
        spent = self._count(got.timer) + plan.rays_cast()
        t.add_rays("S", spent)
        if self._avail_dev is not None:       # device path: D's exact cap on the device
            self._dynamic_limit = mi.UInt32(dr.maximum(self._avail_dev - mi.Float(spent), 0.0))   # rays
            dr.make_opaque(self._dynamic_limit)
        elif self._dynamic_rays is not None:
            self._dynamic_rays = max(self._dynamic_rays - spent, 0.0)
        return self.chains.last_samples

    def _dynamic(self, frame: Frame, vin_dr, fd, t: StageTimer):
        """D: the dynamic plan, traced along ``w`` and ``-w`` and merged with N_max dynamic (Sec. 4.9)."""
        plan = self.chains.plan(frame.index, frame.seed, stage="dynamic", vin=vin_dr, fd=fd,
                                rays=self._dynamic_rays, shadow_rate=self._shadow_rate,
                                rays_max=self._dynamic_rays_max, limit=self._dynamic_limit)
        if plan is not None:
            # the paper's texel-centre rays: the distances from their own rays through the distance-texel
            # centres of the opposite octant (traced here, unshaded); the strata: along each ray's -w
            dplan = self.chains.distance_plan
            dist = None
            if dplan is not None:
                dist = ProbeRayResults(None, trace_probe_distances(self.scene, self.volume, dplan), dplan)
            got = yield ProbePass("dynamic", plan, DYNAMIC_STREAM, shader=self.shader,
                                  reverse_distances=dplan is None, options={"distances": dist})
            t.add_rays("D", self._count(got.timer) + (plan if dplan is None else dplan).rays_cast())
        return self.chains.last_samples

    def _count(self, tt: StageTimer):
        """Rays a trace cast (from its private timer: its stage times are part of ours); learns the NEE
        shadow rays per probe ray for the equal-ray budget. Device path: a device count (the lazy counts of
        the trace's timer, not read; the rate is learnt after the frame's image)."""
        if self.device:
            lazy = list(getattr(tt, "_lazy", ()))       # the timer's unread device counts
            total = sum(tt.rays.values())
            if lazy:            # the host part opaque: it changes per frame (a literal would recompile)
                total = dr.opaque(mi.UInt32, total)
                for _, n in lazy:
                    total = n + total
            probe = dict(lazy).get("trace probes", tt.rays.get("trace probes", 0))
            self._rates.append((probe, dict(lazy).get("shade probes", 0)))
            return total
        rays = tt.as_dict()["rays"]
        if rays.get("trace probes"):
            self._shadow_rate = rays.get("shade probes", 0) / rays["trace probes"]
        return int(sum(rays.values()))

    # -- equal-ray and equal-time budgets (ours) ----------------------------------------------------
    def _plan_budget(self, frame: Frame, t: StageTimer) -> None:
        """Share ``frame.ray_budget`` after the primary and pilot rays (and, on frame 0, the warm-up's: charged
        to it): the static chains get what the
        dynamic ones do not reserve (half when dynamic chains are on), by running only the first
        ``n`` static chains (``n`` from the rays a sample costs: 2 + the measured NEE shadow rays); the
        dynamic stage then traces proxy octants in order while the remainder lasts.

        ``frame.time_budget_ms`` (equal time): the budget minus the last frame's time outside S and D
        (P, primary, states) is the ms of S + D; it becomes rays through the ms per ray each stage
        measured on its last frame (S: its share; D: what S actually left, after S has run), so the
        chain counts scale with the time budget. Nothing measured yet (the first frame): the defaults."""
        self._static_rays = self._dynamic_rays = self._time_avail_ms = None
        self._static_limit = self._dynamic_limit = self._avail_dev = None
        self._static_rays_max = self._dynamic_rays_max = None
        # the dynamic stage is reserved its half only when some entry has f_d > 0 this frame (else it
        # traces nothing and S gets it all); one host read of the f_d scale, only under a budget
        if frame.ray_budget is None and frame.time_budget_ms is None:
            return
        if self.device and frame.ray_budget is not None:
            return self._plan_budget_device(frame, t)
        dyn = self._dyn_prev if self.device else \
            self.chains.dynamic_state is not None and float(np.asarray(self.lut_scale).ravel()[0]) > 0.0
        share = float(self.params["dynamic_share"]) if dyn else 0.0
        if frame.ray_budget is None:
            if frame.time_budget_ms is not None and self._ms_per_ray["S"]:
                self._time_avail_ms = max(float(frame.time_budget_ms) - self._ms_fixed, 0.0)
                self._static_rays = self._time_avail_ms * (1.0 - share) / self._ms_per_ray["S"]
            return
        p = self.params
        spent = sum(t.as_dict()["rays"].values())      # the warm-up's rays too: charged to frame 0
        primary = frame.res[0] * frame.res[1] * (1 + p["direct_samples"])
        avail = max(float(frame.ray_budget) - spent - primary, 0.0)
        self._static_rays = avail - self._dynamic_reserve(avail, share)
        self._dynamic_rays = avail      # less what S spends

    def _dynamic_wanted(self) -> float:
        """1.1x the rays D wanted on its last frame (its marked octants' pairs before the budget cut), or
        infinity when it wanted none or is unmeasured (a change may just have begun)."""
        w = self.chains.dynamic_wanted
        return 1.1 * w if w else float("inf")

    def _dynamic_reserve(self, avail: float, share: float) -> float:
        """The rays of ``avail`` that S leaves to D: ``share`` of them (``dynamic_share``; 0 when no f_d > 0),
        at most what D wanted last frame (:meth:`_dynamic_wanted`; ours: D's work is bounded by one proxy
        octant per chain, Sec. 4.9, so a fixed share would leave rays of an equal-ray budget unspent)."""
        return min(avail * share, self._dynamic_wanted())

    def _plan_budget_device(self, frame: Frame, t: StageTimer) -> None:
        """:meth:`_plan_budget` without a host read (device path): the exact caps are device values -- the
        rays spent so far (the pilot's NEE shadow rays are counted on the device) and the dynamic share only
        when some f_d > 0 *this* frame (the 6-10-10 word's scale, on the device) -- while the host sizes the
        chains run and the plans' widths from the last frame's "some f_d > 0" and shadow-ray rate (an
        estimate) and from the fewest rays spent so far (an upper bound of the widths)."""
        p = self.params
        ints = sum(t.rays.values())          # the warm-up's rays too: charged to frame 0
        primary = frame.res[0] * frame.res[1] * (1 + p["direct_samples"])
        fixed = float(frame.ray_budget) - ints - primary
        lower = sum(lo for _, lo, _ in self._frame_dev)
        est = sum(e for _, _, e in self._frame_dev)
        dyn_on = self.chains.dynamic_state is not None
        share = float(p["dynamic_share"]) if dyn_on else 0.0
        avail_est = max(fixed - est, 0.0)
        self._static_rays = avail_est - self._dynamic_reserve(avail_est, share if self._dyn_prev else 0.0)
        self._static_rays_max = self._dynamic_rays_max = max(fixed - lower, 0.0)
        self._dynamic_rays = avail_est
        spent = mi.Float(0.0)
        for c, _, _ in self._frame_dev:
            spent = spent + mi.Float(c)
        avail = dr.maximum(dr.opaque(mi.Float, fixed) - spent, 0.0)
        dyn = (self.lut_scale > 0.0) if dyn_on else mi.Bool(False)
        per = 2.0 + self._shadow_rate
        self._avail_dev = avail
        wanted = self._dynamic_wanted()
        reserve = dr.minimum(avail * dr.opaque(mi.Float, share), dr.opaque(mi.Float, min(wanted, 3.0e38)))
        self._static_limit = mi.UInt32((avail - dr.select(dyn, reserve, 0.0)) / dr.opaque(mi.Float, per))
        dr.make_opaque(self._static_limit)     # evaluated, as the planner's opaque caps: the same kernels

    # -- after the frame's image ----------------------------------------------------------------------
    def finish_frame(self, out: dict) -> None:
        """Device path, after the frame's image: its stats as ints, the NEE shadow rays per probe ray and the
        "some f_d > 0" flag for the next frame's sizes, the chains' counts (:meth:`.planner.ADGIChainPlanner
        .finish_frame`)."""
        for k in ("static_samples", "dynamic_proxy_octants", "probes_updated"):
            if not isinstance(out.get(k, 0), int):
                out[k] = int(np.asarray(out[k]).ravel()[0])
        for probe_rays, shadow in self._rates:
            pr = int(np.asarray(probe_rays).ravel()[0]) if not isinstance(probe_rays, int) else probe_rays
            if pr:
                self._shadow_rate = int(np.asarray(shadow).ravel()[0]) / pr
        self._rates.clear()
        self._frame_dev.clear()
        self._dyn_prev = self.chains.dynamic_state is not None and \
            float(np.asarray(self.lut_scale).ravel()[0]) > 0.0
        self.chains.finish_frame()

    def measure_time(self, stats: dict) -> None:
        """Learn ms per ray of S and D and the ms outside them (for equal-time budgets); not on frames
        with the warm-up (its time is one-off)."""
        ms, rays = stats["ms"], stats["rays"]
        if "warmup" in ms:
            return
        for k in ("S", "D"):
            if rays.get(k):
                self._ms_per_ray[k] = ms[k] / rays[k]
        self._ms_fixed = max(stats["total_ms"] - ms.get("S", 0.0) - ms.get("D", 0.0), 0.0)
