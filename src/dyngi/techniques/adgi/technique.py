"""Adaptive Dynamic GI (Datta et al. 2022) -- Metropolis-guided probe updates (technique ``adgi``).

Estimates DDGI's irradiance/visibility probes, but spends the ray budget where
a guide over probe position x direction says rays matter, sampled by
persistent Metropolis chains (:mod:`dyngi.sampling.metropolis`); each sample
updates the probe texels it lands in with Algorithm 3's moving average
(:mod:`.moving_average`). Primary shading and the frame-0 warm-up are
``ddgi``'s (:mod:`dyngi.techniques.ddgi`), with its ``glossy`` parameter (default off): the primary
vertex adds the Eq. 6 glossy probe lookup of DDGI Resampling (:mod:`dyngi.probes.primary`), which
Fig. 10's glossy floor needs (``dyngi reproduce adgi``).

One frame, in the paper's stages (Table 4; ``stats['ms']`` keys ``P``, ``S``, ``D``):

* **P -- heuristics** (Sec. 4.1-4.4, :mod:`.heuristics`): frusta ``V_in`` /
  ``V_out`` (Fig. 6b); 8 pilot rays per probe of ``V_out`` (AABBCCDD); f_c, f_v,
  f_r, triggers, convolution, f_s, f_d, stored per octant as the 6-10-10 word of
  Sec. 4.3 (:func:`.heuristics.pack_heuristics`; the chains read the quantised
  f_s, f_d). On the first frame of each pair the pilot rays also update the
  caches (Sec. 4.4), as static samples.
* **S -- static chains** (Sec. 4.8): ``static_chains`` chains over continuous
  probe-grid coordinates (a probe owns the unit cell around it) x direction,
  target ``h = exp(min(g / f_s, 1)) f_s`` on probes of ``V_in`` (0 elsewhere),
  ``g`` the luminance of the previous frame's cached irradiance at a coarser
  mip (Sec. 4.8: "from the previous frame and from a higher mip-level"):
  mip ``guide_mip`` = 1 of the 6x6 interior, i.e. 3x3 cells of 2x2 texels per
  probe (the level is ours; :meth:`ADGITechnique.guide_feedback`).
  Samples in entries with ``f_d > 0`` are snapped to the centre of their
  irradiance texel. Each sample costs two rays: along ``w`` (radiance) and
  along ``-w`` (distance, the shadow ray).
* **D -- dynamic chains** (Sec. 4.9): ``dynamic_chains`` chains over 3x3x3 virtual
  proxies with 8 octant directions, target the max of ``f_d`` over the proxy's
  27 probes (alpha = 0), steps 3x (position) / 6x (direction) the static ones.
  Every proxy octant a chain visits this frame (each at most once) traces, for
  each of its probes in ``V_in``, ``dynamic_rays`` = 64 deterministic rays:
  the centres of an 8x8 equal-area stratification of the octant
  (``z = (i + 1/2) / 8``, ``phi = (j + 1/2) / 8 * pi / 2``; ours -- the paper
  sends them through irradiance texel centres, but an octant of our 8x8
  (6x6 interior) map holds only 3-6 texel centres, so 64 rays through them
  would repeat directions), plus the shadow ray along ``-w`` each.
  Dynamic updates use N_max = 10, static ones 63 (Table 3).
* After the updates, probes in ``V_out - V_in`` get their texel counts capped,
  ``N <- min(N, 16)`` (Sec. 4.8).

How a sample becomes a texel update (the paper is silent; ours, :mod:`.radiance`):
the radiance along ``w`` goes into the one *radiance* texel ``w`` falls in
(``radiance_texels`` = 16 per side) with Algorithm 3's batch rule, and every
probe updated in the frame is re-convolved to its 8x8 irradiance texels
(cosine x solid-angle weights over the texels that hold samples). A cosine
splat of each sample over the irradiance texels was tried first and is
biased wherever the guide is 0 over part of a texel's hemisphere (measured
-52% on the Cornell box's front probes). The distance of the ``-w`` ray goes
to the one visibility texel ``-w`` falls in (``bin`` mode, Algorithm 3 on the
volume's distance texels; DDGI's cos^50 kernel is about one 16x16 texel wide).

Budgets (``dyngi compare --budget equal-rays``; ours): after the primary and
pilot rays, half of what remains is reserved for the dynamic stage when it
is on and some octant has f_d > 0 this frame (else the static stage gets it
all: a static scene wastes none of its budget); the static stage runs only
its first ``n`` chains, ``n`` = its share / ((M - K) x (2 + measured NEE
shadow rays per probe ray)); the dynamic stage
traces whole proxy octants in order while the remainder lasts. Rays are
counted exactly (probe rays, their NEE shadow rays, the ``-w`` rays).
Equal time (``Frame.time_budget_ms``): the budget minus the last frame's time
outside S and D, turned into rays of S and D by each stage's measured ms per
ray on its last frame, then shared as above (so the chain counts scale with
the time; the first frame, with nothing measured, runs the defaults); the
spend is recorded (``stats['static_chains_run']``), not guaranteed.

Speed (measured 2026-12-02, 2-core box under load 10-15, so +-50%; /tmp/figs/adgi.md): at the tunnel's
8x6x32 grid and Q-DDGI's ~36k rays a frame, an ``adgi`` frame ran 55-100 ms of which only 17-26 ms is
kernel execution: it launches ~106 JIT kernels (~375 launches with reductions and copies) against
Q-DDGI's ~30 (~133), and syncs with the host for the ragged plans (host sort), the chain/proxy counts and
the radiance convolution (NumPy). That fixed cost, not the rays, makes it slower than ``qddgi`` at small
grids, and it is why an equal-time budget below it cannot be met (the chains shrink to 1 and the frame
overspends; recorded, not hidden). Fused here: the two trigger convolutions (Eqs. 15, 18) share one
launch per axis. At the defaults' ray counts the ratio of probe-sampling times adgi/qddgi fell from 10.7
(1536 probes) to 4.7 (12288) to 2.7 (98304 probes, the largest grid whose set-up + 4 frames ran within a
minute here); the paper's 2.36M-probe grid is out of reach on this CPU.

Probe relocation and classification carry over from ``ddgi`` (the paper is
silent; ours): during the warm-up updates, then every
``reclassify_interval`` = 8 frames on the probes of V_out and the inactive ones, with ``ddgi``'s 32 fixed
classification rays (:meth:`ADGITechnique._states_pass`).

Encoding ``adgi``: Table 3's ``floor(R9)floor(G9)floor(B8)-N`` /
``[R13][G13]-N``, visibility rounded to nearest (:class:`dyngi.probes.encoding.ADGIEncoding`).

Parameters
----------
static_chains : int = 4096        (Sec. 5)
dynamic_chains : int = 1024       (Sec. 5)
iterations : int = 20             M per frame (ours)
burn_in : int = 4                 K per frame (ours): M - K = 16 samples per chain per frame
position_step : float = 0.5       static position step, in probe spacings (ours; "proportional", Sec. 4.8)
direction_step : float = sqrt(pi/256)  static direction step, radians (Sec. 4.8)
camera_threshold : float = 0      k of Eq. 10 (world units); 0 = the probe box diagonal + the camera's
                                  distance to the probe box (ours, :meth:`.heuristics.ADGIHeuristics.k_for`)
theta : float = 16                trigger decay, frames (ours)
n_max_static, n_max_dynamic : int = 63, 10   (Table 3)
outer_count_cap : int = 16        (Sec. 4.8)
encoding : str = 'adgi'           R9G9B8 + 6-bit count / R13G13 + count (Sec. 4.5-4.6, Table 3)
guide_mip : int = 1               mip level of g in the static guide (ours; Sec. 4.8 "a higher mip-level")
reclassify_interval : int = 8     frames between relocation/classification passes after the warm-up (ddgi's)

Bias: the moving average lags dynamic changes (Sec. 3.5); texels no chain
visits keep old values; quantised irradiance storage rounds low.
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...errors import DyngiError
from ...probes import DiffuseHitShader, HysteresisBlend, ProbeStates, RayPlan, ScatterEstimator
from ...probes import UniformSFDirections
from ...probes.accumulator import MeanAccumulator, pull_from
from ...probes.encoding import get_encoding
from ...probes.pipeline import ProbePipeline
from ...probes.trace import HIT_LOOKUPS, ProbeRayResults
from ...probes.volume import upload
from ...sampling.diffuse import diffuse_albedo
from ...sampling.metropolis import ADGI_DIRECTION_STEP, ChainState, MetropolisChains
from ...sampling.octahedral import direction_to_texel_coords, texel_directions
from ..base import Frame, FrameResult, Param, StageTimer, register
from ..ddgi import COMMON_PARAMS, _ProbeTechniqueBase
from .heuristics import (OCTANTS, ADGIHeuristics, frusta, octant_of, octant_signs, pack_heuristics,
                         static_guide, unpack_heuristics)
from .moving_average import N_MAX_DYNAMIC, N_MAX_STATIC, Algorithm3Accumulator
from .radiance import RadianceCache

PROXY = 3                 # 3x3x3 probes per virtual proxy (Sec. 4.9)
DYNAMIC_STRATA = 8        # 8x8 deterministic rays per probe octant


class PilotShader(DiffuseHitShader):
    """:class:`DiffuseHitShader` that also keeps the direct-light part of the radiance (``last_direct``), for
    f_r (Eq. 12); it is evaluated in the same kernel as the radiance (``dr.schedule``)."""

    def shade(self, scene, ray, si, sampler, query, active):
        L, hit, front, shadow = super().shade(scene, ray, si, sampler, None, active)
        self.last_direct = mi.Color3f(L)
        if query is not None:
            albedo = diffuse_albedo(si.bsdf(ray), si, front)
            E = query.irradiance(si.p, si.sh_frame.n, -ray.d, active=front,
                                 sampler=sampler if self.lookup == "stochastic" else None)
            L = L + dr.select(front, albedo * dr.inv_pi * E, 0.0)
        dr.schedule(self.last_direct)
        return L, hit, front, shadow


def sorted_plan(probe, direction, weight, n_probes: int) -> RayPlan:
    """A ragged :class:`RayPlan` from unordered per-sample probe ids: samples grouped by probe with a stable
    host sort (one host copy of the ids; deterministic order). Directions/weights follow the sort."""
    pid = np.asarray(probe, np.uint32)
    order = np.argsort(pid, kind="stable").astype(np.uint32)
    counts = np.bincount(pid, minlength=n_probes)
    ids = np.flatnonzero(counts).astype(np.uint32)
    idx = upload(order, mi.UInt32)
    d = dr.gather(mi.Vector3f, direction, idx)
    w = None if weight is None else dr.gather(mi.Float, weight, idx)
    dr.eval(d, w)
    return RayPlan.ragged(ids, counts[ids], d, weight=w)


def negated(plan: RayPlan) -> RayPlan:
    """The same plan along ``-w`` (the shadow rays of Sec. 4.8)."""
    return RayPlan(plan.probe, -plan.direction, plan.rays_per_probe, None, plan.probe_ids, plan.offsets,
                   plan.slot, plan.weight)


@register
class ADGITechnique(_ProbeTechniqueBase):
    """ADGI (Datta et al. 2022): heuristics + static/dynamic Metropolis chains + Algorithm 3 caches."""

    name = "adgi"
    description = ("ADGI (Datta et al. 2022): probes updated by Metropolis chains guided by camera/visibility/"
                   "change heuristics, count-based moving average, quantised 9-9-8 caches")
    PARAMS = {
        **COMMON_PARAMS,
        "static_chains": Param(4096, "persistent static chains (Sec. 5)", min=1, max=1 << 20),
        "dynamic_chains": Param(1024, "persistent dynamic chains on 3x3x3 proxies (Sec. 5; 0: off)", min=0,
                                max=1 << 20),
        "iterations": Param(20, "Metropolis iterations per chain per frame (M)", min=2, max=256),
        "burn_in": Param(4, "burn-in iterations per frame (K < M); the others each yield a sample", min=0,
                         max=255),
        "position_step": Param(0.5, "static chains' position step, in probe spacings", min=1e-3, max=64.0),
        "direction_step": Param(ADGI_DIRECTION_STEP, "static chains' direction step (radians)", min=1e-3,
                                max=3.0),
        "dynamic_position_scale": Param(3.0, "dynamic/static position step ratio (Sec. 4.9)", min=0.1),
        "dynamic_direction_scale": Param(6.0, "dynamic/static direction step ratio (Sec. 4.9)", min=0.1),
        "dynamic_rays": Param(64, "deterministic rays per probe octant of a sampled proxy (a square)",
                              choices=(16, 64, 256)),
        "camera_threshold": Param(0.0, "k of Eq. 10 in world units (0: the probe box diagonal + the camera's "
                                  "distance to the box)", min=0.0),
        "beta": Param(5.0, "range of the radiance heuristic (Eq. 12)", min=1e-3),
        "mu": Param(2.0, "weight of the radiance change in f_d (Eq. 20)", min=0.0),
        "theta": Param(16.0, "temporal trigger decay in frames (Eq. 14)", min=1.0),
        "n_max_static": Param(N_MAX_STATIC, "N_max of static updates (Table 3)", min=1, max=63),
        "n_max_dynamic": Param(N_MAX_DYNAMIC, "N_max of dynamic updates (Table 3)", min=1, max=63),
        "outer_count_cap": Param(16, "count cap of probes in V_out - V_in (Sec. 4.8)", min=1, max=63),
        "pilot_updates": Param(True, "pilot rays update the caches on alternate frames (Sec. 4.4)"),
        "radiance_texels": Param(16, "radiance texels per side incl. border that samples are binned into "
                                 "(convolved to irradiance each frame)", min=4, max=64),
        "irradiance_texels": Param(8, "irradiance texels per side incl. the 1-texel border", min=4, max=64),
        "distance_texels": Param(16, "distance texels per side incl. the 1-texel border", min=4, max=64),
        "distance_power": Param(50.0, "cosine power of the warm-up's distance blend", min=1.0),
        "encoding": Param("adgi", "texel storage encoding", choices=("fp32", "qddgi", "adgi")),
        "hit_lookup": Param("stochastic", "how probe-ray hits read the previous probes (multi-bounce)",
                            choices=HIT_LOOKUPS),
        "warmup": Param(8, "ddgi-style probe updates on the first frame (no hysteresis)", min=0, max=256),
        "warmup_rays": Param(256, "rays per probe of each warm-up update", min=8, max=1 << 14),
        "relocate": Param(True, "move probes out of geometry (warm-up, then every reclassify_interval frames)"),
        "classify": Param(True, "deactivate probes inside geometry or far from surfaces (as relocate)"),
        "reclassify_interval": Param(8, "frames between ddgi's relocation/classification passes after the "
                                     "warm-up (fixed rays; 0: warm-up only)", min=0),
        "guide_mip": Param(1, "mip level of the irradiance feedback g in the static guide (Sec. 3.2/4.8; "
                           "0: the texel itself)", min=0, max=3),
    }
    BUDGETS = ("equal-rays", "equal-time")

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        p = self.params
        if p["burn_in"] >= p["iterations"]:
            raise DyngiError(f"technique 'adgi': parameter 'burn_in' = {p['burn_in']} must be below "
                             f"'iterations' = {p['iterations']}")
        self._setup_volume(p["irradiance_texels"], p["distance_texels"])
        g = self.grid
        self.counts = tuple(int(c) for c in g.counts)
        self.shader = PilotShader(p["direct"], lookup=p["hit_lookup"])
        self.encoding = get_encoding(p["encoding"])     # Table 3: visibility rounds to nearest
        self.acc_static = Algorithm3Accumulator(p["n_max_static"])
        self.acc_dynamic = Algorithm3Accumulator(p["n_max_dynamic"])
        self._mean = MeanAccumulator()
        self.est_dist = ScatterEstimator(p["distance_power"], "bin")
        self.heur = ADGIHeuristics(g, p["camera_threshold"] or None, p["beta"], p["mu"], p["theta"])
        self.hstate = self.heur.initial_state()
        # -- chains: static over probe cells, dynamic over 3x3x3 proxies (grid units) --
        n = np.asarray(self.counts, np.float64)
        self.proxies = tuple(int(c) for c in np.ceil(n / PROXY).astype(int))
        step = p["position_step"]
        self.static = MetropolisChains(-0.5 * np.ones(3), n - 0.5, step, p["direction_step"], p["burn_in"],
                                       p["iterations"], stream=0xAD61)
        npx = np.asarray(self.proxies, np.float64)
        self.dynamic = MetropolisChains(-0.5 * np.ones(3), npx - 0.5, step * p["dynamic_position_scale"] / PROXY,
                                        min(p["direction_step"] * p["dynamic_direction_scale"], 3.0),
                                        p["burn_in"], p["iterations"], stream=0xAD62)
        self.static_state = self.static.initial_state(p["static_chains"], 0)
        self.dynamic_state = self.dynamic.initial_state(p["dynamic_chains"], 1) if p["dynamic_chains"] else None
        # -- ddgi's warm-up pieces (hysteresis blend, shared SF set, relocation/classification) --
        self.blender = HysteresisBlend(0.0, p["distance_power"], 1.0, 0.25, 1e30, p["encoding"], "auto")
        self.blender.encoding = self.encoding             # the warm-up stores through the same encoding
        # the pipeline: its own update is the warm-up's (ddgi's); the stages P, S, D call its trace and merge
        self.pipeline = ProbePipeline(self.volume, UniformSFDirections(p["warmup_rays"]),
                                      DiffuseHitShader(p["direct"], lookup=p["hit_lookup"]), self.blender,
                                      ProbeStates(p["relocate"], p["classify"]), self.query, reclassify_interval=0)
        self.updater = self.pipeline       # (older name)
        self._warmed = False
        self._shadow_rate = 1.0                # NEE shadow rays per probe ray (measured)
        self._static_rays = None               # this frame's ray allowance of S and D (None: no budget)
        self._dynamic_rays = None
        self._time_avail_ms = None             # equal time: this frame's ms for S + D (None: no time budget)
        self._ms_per_ray = {"S": None, "D": None}   # measured on the last frame that traced in the stage
        self._ms_fixed = 0.0                   # measured: the last frame's time outside S and D
        self._setup_guide_mip(p["guide_mip"])
        self.radiance = RadianceCache(vol_n := self.volume.n_probes, p["radiance_texels"],
                                      self.volume.irradiance_texels)
        self._updated = np.zeros(vol_n, bool)
        self._texel_dirs = mi.Float(texel_directions(self.volume.irradiance_texels)[1:-1, 1:-1]
                                    .reshape(-1).astype(np.float32))
        self._strata = self._octant_strata(int(round(np.sqrt(p["dynamic_rays"]))))

    @staticmethod
    def _octant_strata(k: int):
        """(k*k) directions in the +++ octant: centres of an equal-area k x k stratification."""
        i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        z = (i.ravel() + 0.5) / k
        phi = (j.ravel() + 0.5) / k * np.pi / 2
        r = np.sqrt(1 - z * z)
        d = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1).astype(np.float32)
        return mi.Vector3f(*[upload(d[:, c]) for c in range(3)])

    # -- one frame ------------------------------------------------------------------------------
    def step(self, frame: Frame) -> FrameResult:
        p = self.params
        t = StageTimer()
        if not self._warmed:
            self._warmed = True
            self.pipeline.warm_up(self.scene, p["warmup"], frame.seed, None, t)
            if self.pipeline.last_results is not None:     # the warm-up's last rays seed the radiance texels
                with t.stage("warmup"):
                    self.radiance.merge(self.pipeline.last_results, p["n_max_static"])
        vol = self.volume
        # -- ddgi's relocation/classification after the warm-up (the paper is silent; ours) --
        if self._warmed and frame.index > 0 and p["reclassify_interval"] and \
                frame.index % p["reclassify_interval"] == 0 and (p["relocate"] or p["classify"]):
            _, _, near = frusta(vol, frame.camera, frame.res, self.heur.k_for(frame.camera.origin))
            self._states_pass(frame, t, near | (vol.state.states == 0))
        active = vol.state.states != 0
        fc, v_in, v_out = frusta(vol, frame.camera, frame.res, self.heur.k_for(frame.camera.origin))
        v_in &= active
        v_out &= active
        stats = {}
        # -- P: pilot rays and heuristics (Sec. 4.1-4.4) --
        with t.stage("P"):
            ids = np.flatnonzero(v_out).astype(np.uint32)
            res = None
            if len(ids):
                plan = self.heur.pilot.plan(frame.index, frame.seed, ids)
                # both frames of a pair draw the same NEE samples (sampler seeded by the pair): f_r's time
                # difference then sees scene changes, not NEE noise (ours)
                tt = StageTimer()
                res = self.pipeline.trace(self.scene, plan, frame.seed, frame.index // 2, stream=41, timer=tt,
                                          shader=self.shader)
                lum = mi.luminance(self.shader.last_direct)
                t.add_rays("P", self._count(tt))
                self.hstate = self.heur.update(self.hstate, frame.index, ids, res.distance, lum, fc)
                if p["pilot_updates"] and frame.index % 2 == 0:
                    self._merge(res, None, self.acc_static, p["n_max_static"])
            else:
                self.hstate = self.heur.update(self.hstate, frame.index, ids, mi.Float(), mi.Float(), fc)
            # -- the 6-10-10 heuristics word per octant (Sec. 4.3); the chains read the quantised values --
            vin_dr = upload(v_in.astype(np.float32), mi.Float)
            vin_e = dr.gather(mi.Float, vin_dr, dr.arange(mi.UInt32, vol.n_probes * OCTANTS) // OCTANTS)
            self.lut, self.lut_scale = pack_heuristics(self.hstate.fv, self.hstate.fs, self.hstate.fd(p["mu"]),
                                                       vin_e)
            _, fs_q, fd, _ = unpack_heuristics(self.lut, self.lut_scale)
            self._fs_q = fs_q
            dr.eval(fs_q, fd)
        self._plan_budget(frame, t)
        # -- S: static chains (Sec. 4.8) --
        with t.stage("S"):
            stats["static_samples"] = self._static(frame, vin_dr, fd, t)
        if self._time_avail_ms is not None:      # equal time: D gets what S left
            per = self._ms_per_ray["D"] or self._ms_per_ray["S"]
            self._dynamic_rays = None if per is None else max(self._time_avail_ms - t.ms.get("S", 0.0), 0.0) / per
        # -- D: dynamic chains on proxies (Sec. 4.9) --
        with t.stage("D"):
            stats["dynamic_proxy_octants"] = self._dynamic(frame, vin_dr, fd, t) if self.dynamic_state else 0
            self._cap_outer(v_out & ~v_in, p["outer_count_cap"])
            stats["probes_updated"] = self._convolve_updated()
        img, ind = self._primary(frame, t)
        out = t.as_dict()
        out.update(stats)
        out["v_in"], out["v_out"] = int(v_in.sum()), int(v_out.sum())
        out["static_chains_run"] = self._n_run
        self._measure_time(out)
        return FrameResult(image=img, indirect=ind, stats=out)

    # -- equal-ray and equal-time budgets (ours) ----------------------------------------------------
    def _plan_budget(self, frame: Frame, t: StageTimer) -> None:
        """Share ``frame.ray_budget`` after the primary and pilot rays: the static chains get what the
        dynamic ones do not reserve (half when dynamic chains are on), by running only the first
        ``n`` static chains (``n`` from the rays a sample costs: 2 + the measured NEE shadow rays); the
        dynamic stage then traces proxy octants in order while the remainder lasts.

        ``frame.time_budget_ms`` (equal time): the budget minus the last frame's time outside S and D
        (P, primary, states) is the ms of S + D; it becomes rays through the ms per ray each stage
        measured on its last frame (S: its share; D: what S actually left, after S has run), so the
        chain counts scale with the time budget. Nothing measured yet (the first frame): the defaults."""
        self._static_rays = self._dynamic_rays = self._time_avail_ms = None
        # the dynamic stage is reserved its half only when some entry has f_d > 0 this frame (else it
        # traces nothing and S gets it all); one host read of the f_d scale, only under a budget
        if frame.ray_budget is None and frame.time_budget_ms is None:
            return
        dyn = self.dynamic_state is not None and float(np.asarray(self.lut_scale).ravel()[0]) > 0.0
        share = 0.5 if dyn else 0.0
        if frame.ray_budget is None:
            if frame.time_budget_ms is not None and self._ms_per_ray["S"]:
                self._time_avail_ms = max(float(frame.time_budget_ms) - self._ms_fixed, 0.0)
                self._static_rays = self._time_avail_ms * (1.0 - share) / self._ms_per_ray["S"]
            return
        p = self.params
        spent = sum(v for k, v in t.as_dict()["rays"].items() if k != "warmup")
        primary = frame.res[0] * frame.res[1] * (1 + p["direct_samples"])
        avail = max(float(frame.ray_budget) - spent - primary, 0.0)
        self._static_rays = avail * (1.0 - share)
        self._dynamic_rays = avail      # less what S spends

    def _measure_time(self, stats: dict) -> None:
        """Learn ms per ray of S and D and the ms outside them (for equal-time budgets); not on frames
        with the warm-up (its time is one-off)."""
        ms, rays = stats["ms"], stats["rays"]
        if "warmup" in ms:
            return
        for k in ("S", "D"):
            if rays.get(k):
                self._ms_per_ray[k] = ms[k] / rays[k]
        self._ms_fixed = max(stats["total_ms"] - ms.get("S", 0.0) - ms.get("D", 0.0), 0.0)

    def _states_pass(self, frame: Frame, t: StageTimer, mask: np.ndarray) -> None:
        """``ddgi``'s relocation and classification after the warm-up (issue 12 item 5; the paper is
        silent, ours): every ``reclassify_interval`` frames, the probes of ``V_out`` (those the frame can
        use; ``ddgi`` re-tests the probes it updates) and every inactive probe (``ddgi``'s re-test) are
        re-tested with
        ``ddgi``'s fixed set of classification rays (:class:`~dyngi.probes.update.ProbeUpdater`'s
        ``classify_dirs``, 32 spherical-Fibonacci rays) and :class:`~dyngi.probes.states.ProbeStates`
        moves / (de)activates it as ``ddgi`` does. The rays are counted (stage ``states``) and come out
        of an equal-ray budget before the chains are sized."""
        self.pipeline.classify(self.scene, np.flatnonzero(mask).astype(np.uint32), frame.index, frame.seed, t)

    def _chains_to_run(self) -> int:
        n = self.static_state.n
        if self._static_rays is None:
            return n
        per_chain = self.static.samples_per_chain * (2.0 + self._shadow_rate)
        return int(min(max(self._static_rays // per_chain, 1), n))

    # -- pieces --------------------------------------------------------------------------------
    def _probe_of(self, x, counts):
        """Lattice point (probe or proxy index) nearest to continuous grid coordinates ``x``."""
        nx, ny, nz = counts
        i = dr.clip(mi.Int32(dr.round(x.x)), 0, nx - 1)
        j = dr.clip(mi.Int32(dr.round(x.y)), 0, ny - 1)
        k = dr.clip(mi.Int32(dr.round(x.z)), 0, nz - 1)
        return mi.UInt32(i + nx * (j + ny * k))

    def _texel_of(self, w):
        T = self.volume.irradiance_texels
        c = direction_to_texel_coords(w, T)
        ix = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, T - 3)
        iy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, T - 3)
        return mi.UInt32(iy * (T - 2) + ix), mi.UInt32((iy + 1) * T + ix + 1)

    # -- the guide's feedback at a coarser mip (Sec. 3.2, 4.8) --
    def _setup_guide_mip(self, level: int) -> None:
        """Mip ``level`` of the irradiance maps' interiors: ``(T-2) / 2^level`` texels per side (rounded
        up), each the mean luminance of the ``2^level x 2^level`` interior texels it covers (fewer at an odd
        edge). Our choice: level 1 (3x3 per probe for the 8x8 maps), the first level coarser than the
        texels the samples update; the paper says only "a higher mip-level" (Sec. 4.8)."""
        T = self.volume.irradiance_texels
        n = T - 2
        self._mip_level = int(level)
        self._mip_n = m = -(-n // (1 << self._mip_level))
        iy, ix = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        cell = ((iy >> self._mip_level) * m + (ix >> self._mip_level)).ravel()
        self._mip_cell = upload(cell.astype(np.uint32), mi.UInt32)                  # interior texel -> mip cell
        self._mip_src = upload(((iy + 1) * T + ix + 1).ravel().astype(np.uint32), mi.UInt32)   # -> atlas texel
        self._mip_norm = upload((1.0 / np.bincount(cell, minlength=m * m)).astype(np.float32), mi.Float)

    def guide_feedback(self):
        """Per probe and mip cell (``P * m * m`` Floats): the luminance of the irradiance atlas at mip
        ``guide_mip``, read at the start of the static stage, i.e. the previous frame's convolved
        irradiance (this frame's samples reach the atlas only at the end of the frame). Luminance is our
        scalar of the RGB cache (Rec. 709 weights)."""
        vol = self.volume
        T = vol.irradiance_texels
        n_int = (T - 2) ** 2
        mm = self._mip_n * self._mip_n
        lane = dr.arange(mi.UInt32, vol.n_probes * n_int)
        probe = lane // n_int
        k = lane - probe * n_int
        lum = mi.luminance(dr.gather(mi.Color3f, vol.device.irradiance,
                                     probe * (T * T) + dr.gather(mi.UInt32, self._mip_src, k)))
        cell = dr.gather(mi.UInt32, self._mip_cell, k)
        g = dr.zeros(mi.Float, vol.n_probes * mm)
        dr.scatter_reduce(dr.ReduceOp.Add, g, lum * dr.gather(mi.Float, self._mip_norm, cell), probe * mm + cell)
        dr.eval(g)
        return g

    def _mip_cell_of(self, w):
        """Mip cell (row-major in the ``m x m`` mip) that direction ``w`` falls in."""
        T = self.volume.irradiance_texels
        c = direction_to_texel_coords(w, T)
        ix = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, T - 3)
        iy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, T - 3)
        L = self._mip_level
        return mi.UInt32((iy >> L) * self._mip_n + (ix >> L))

    def _static(self, frame: Frame, vin_dr, fd, t: StageTimer) -> int:
        vol = self.volume
        fs = self._fs_q                      # f_s from the 6-10-10 word (Sec. 4.3)
        g_mip = self.guide_feedback()
        mm = self._mip_n * self._mip_n

        def target(x, w):
            probe = self._probe_of(x, self.counts)
            e = probe * OCTANTS + octant_of(w)
            f = dr.gather(mi.Float, fs, e) * dr.gather(mi.Float, vin_dr, probe)
            g = dr.gather(mi.Float, g_mip, probe * mm + self._mip_cell_of(w))
            return static_guide(f, g)

        n_run = self._n_run = self._chains_to_run()
        st = self.static_state
        if self._static_rays is not None:     # a budget runs the first n_run chains; the others keep their
            # states (this path even when n_run is all of them: one set of kernels whatever the budget)
            # + an opaque 0: Dr.Jit turns a gather of all lanes by a plain arange into the source itself, which
            # would make the n_run == n frames launch other kernels than the others
            lane = dr.arange(mi.UInt32, n_run) + dr.opaque(mi.UInt32, 0)
            sub = ChainState(dr.gather(mi.Vector3f, st.position, lane), dr.gather(mi.Vector3f, st.direction, lane))
            sub, s = self.static.run(sub, target, frame.seed, frame.index)
            pos, dirs = mi.Vector3f(st.position), mi.Vector3f(st.direction)
            dr.scatter(pos, sub.position, lane)
            dr.scatter(dirs, sub.direction, lane)
            dr.eval(pos, dirs)
            self.static_state = ChainState(pos, dirs)
        else:
            self.static_state, s = self.static.run(st, target, frame.seed, frame.index)
        ok = s.value > 0.0
        n = int(dr.count(ok)[0])
        if n == 0:
            return 0
        idx = dr.compress(ok)
        x = dr.gather(mi.Vector3f, s.position, idx)
        w = dr.gather(mi.Vector3f, s.direction, idx)
        h = dr.gather(mi.Float, s.value, idx)
        probe = self._probe_of(x, self.counts)
        # samples in entries with f_d > 0 go through their irradiance texel's centre (Sec. 4.9)
        snap = dr.gather(mi.Float, fd, probe * OCTANTS + octant_of(w)) > 0.0
        ti, _ = self._texel_of(w)
        w = dr.select(snap, dr.gather(mi.Vector3f, self._texel_dirs, ti), w)
        dr.eval(probe, w, h)
        plan = sorted_plan(probe, w, None, vol.n_probes)
        spent = self._trace_and_merge(frame, plan, self.acc_static, self.params["n_max_static"], stream=43)
        t.add_rays("S", spent)
        if self._dynamic_rays is not None:
            self._dynamic_rays = max(self._dynamic_rays - spent, 0.0)
        return n

    def _dynamic(self, frame: Frame, vin_dr, fd, t: StageTimer) -> int:
        vol = self.volume
        nx, ny, nz = self.counts
        px, py, pz = self.proxies
        n_entries = px * py * pz * OCTANTS
        # -- the proxy table: max of f_d over the proxy's 27 probes in V_in, per octant --
        e = dr.arange(mi.UInt32, n_entries)
        q = e // OCTANTS
        o = e - q * OCTANTS
        qi, qj, qk = mi.Int32(q % px), mi.Int32((q // px) % py), mi.Int32(q // (px * py))
        table = dr.zeros(mi.Float, n_entries)
        for di in range(PROXY):
            for dj in range(PROXY):
                for dk in range(PROXY):
                    i, j, k = qi * PROXY + di, qj * PROXY + dj, qk * PROXY + dk
                    inside = (i < nx) & (j < ny) & (k < nz)
                    pr = mi.UInt32(dr.select(inside, i + nx * (j + ny * k), 0))
                    v = dr.gather(mi.Float, fd, pr * OCTANTS + o, inside) * dr.gather(mi.Float, vin_dr, pr, inside)
                    table = dr.maximum(table, v)
        dr.eval(table)

        def target(x, w):
            return dr.gather(mi.Float, table, self._probe_of(x, self.proxies) * OCTANTS + octant_of(w))

        self.dynamic_state, s = self.dynamic.run(self.dynamic_state, target, frame.seed, frame.index)
        # -- each proxy octant a chain visited (with h > 0) traces once --
        mark = dr.zeros(mi.UInt32, n_entries)
        ent = self._probe_of(s.position, self.proxies) * OCTANTS + octant_of(s.direction)
        dr.scatter(mark, mi.UInt32(1), ent, s.value > 0.0)
        dr.eval(mark)
        n_marked = int(dr.count(mark != 0)[0])
        if n_marked == 0:
            return 0
        marked = dr.compress(mark != 0)
        # -- lanes: (marked proxy octant, sub-probe of 27, stratum) --
        R = dr.width(self._strata.x)
        lane = dr.arange(mi.UInt32, n_marked * 27 * R)
        m = lane // (27 * R)
        rest = lane - m * (27 * R)
        sub = rest // R
        r = rest - sub * R
        ent = dr.gather(mi.UInt32, marked, m)
        q = ent // OCTANTS
        oo = ent - q * OCTANTS
        i = mi.Int32(q % px) * PROXY + mi.Int32(sub % PROXY)
        j = mi.Int32((q // px) % py) * PROXY + mi.Int32((sub // PROXY) % PROXY)
        k = mi.Int32(q // (px * py)) * PROXY + mi.Int32(sub // (PROXY * PROXY))
        inside = (i < nx) & (j < ny) & (k < nz)
        probe = mi.UInt32(dr.select(inside, i + nx * (j + ny * k), 0))
        ok = inside & (dr.gather(mi.Float, vin_dr, probe, inside) > 0.0)
        d = dr.gather(mi.Vector3f, self._strata, r) * octant_signs(oo)
        dr.eval(probe, d, ok)
        if self._dynamic_rays is not None:    # budget: whole proxy octants, in order, while rays remain
            # lanes of one proxy octant are contiguous: a block sum, not a scatter into n_marked slots
            # (on LLVM that bakes n_marked into the kernel, a new kernel whenever it changes)
            per = dr.block_reduce(dr.ReduceOp.Add, mi.UInt32(ok), 27 * R)
            cost = np.cumsum(np.asarray(per, np.float64) * (2.0 + self._shadow_rate))
            n_keep = int(np.searchsorted(cost, self._dynamic_rays, side="right"))
            ok &= m < dr.opaque(mi.UInt32, n_keep)
            dr.eval(ok)
        if int(dr.count(ok)[0]) == 0:
            return n_marked
        keep = dr.compress(ok)
        plan = sorted_plan(dr.gather(mi.UInt32, probe, keep), dr.gather(mi.Vector3f, d, keep), None,
                           vol.n_probes)
        t.add_rays("D", self._trace_and_merge(frame, plan, self.acc_dynamic, self.params["n_max_dynamic"],
                                              stream=45))
        return n_marked

    def _trace_and_merge(self, frame: Frame, plan: RayPlan, acc, n_max: int, stream: int) -> int:
        """Trace ``plan`` (radiance along ``w``, distance along ``-w``) and merge; returns the rays cast
        (probe rays, their NEE shadow rays and the ``-w`` rays)."""
        tt = StageTimer()
        res = self.pipeline.trace(self.scene, plan, frame.seed, frame.index, stream=stream, timer=tt,
                                  shader=self.shader)
        back = negated(plan)
        dist = self.pipeline.trace_distances(self.scene, back)
        self._merge(res, ProbeRayResults(res.radiance, dist, back), acc, n_max)
        return self._count(tt) + plan.n_rays

    def _count(self, tt: StageTimer) -> int:
        """Rays a trace cast (from its private timer: its stage times are part of ours); learns the NEE
        shadow rays per probe ray for the equal-ray budget."""
        rays = tt.as_dict()["rays"]
        if rays.get("trace probes"):
            self._shadow_rate = rays.get("shade probes", 0) / rays["trace probes"]
        return int(sum(rays.values()))

    def _merge(self, irr_res, dist_res, acc, n_max: int) -> None:
        """Radiance of ``irr_res`` into the radiance texels (:mod:`.radiance`), distance moments of
        ``dist_res`` (or of ``irr_res`` when None: the pilot rays' own distances) into the visibility texels,
        both with Algorithm 3's batch rule; the probes are convolved to irradiance at the end of the frame."""
        vol = self.volume
        plan = irr_res.plan
        self.radiance.merge(irr_res, n_max)
        est_d = self.est_dist.distance(vol, dist_res if dist_res is not None else irr_res)
        self.pipeline.merge(None, est_d, plan.probe_ids, plan.counts, accumulator=acc, encoding=self.encoding)
        self._updated[plan.probe_ids[plan.counts > 0]] = True

    def _convolve_updated(self) -> int:
        """The per-texel convolution pass (:mod:`.radiance`) for the probes updated this frame."""
        ids = np.flatnonzero(self._updated).astype(np.uint32)
        self._updated[:] = False
        if len(ids):
            est = self.radiance.irradiance_estimate(ids)
            self.pipeline.merge(est, None, ids, accumulator=self._mean, encoding=self.encoding)
        return len(ids)

    def _cap_outer(self, mask: np.ndarray, cap: int) -> None:
        """``N <- min(N, cap)`` for the texels of probes in ``mask`` (V_out - V_in, Sec. 4.8)."""
        if not mask.any():
            return
        self.radiance.cap_counts(mask, cap)
        vol = self.volume
        dev = vol.device
        m = upload(mask.astype(np.uint32), mi.UInt32) != 0
        capd = dr.opaque(mi.UInt32, int(cap))
        for name, T in (("irradiance_count", vol.irradiance_texels), ("distance_count", vol.distance_texels)):
            c = getattr(dev, name)
            k = dr.arange(mi.UInt32, dr.width(c))
            sel = dr.gather(mi.Bool, m, k // (T * T))
            new = dr.select(sel, dr.minimum(c, capd), c)
            dr.eval(new)
            setattr(dev, name, new)
        vol.state.device_is_newer(pull_from(dev))
