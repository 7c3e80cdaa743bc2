"""IS-DDGI -- importance-based ray allocation per probe direction set (Liu, Huang, Rocha, Malmros, Zhang,
"Importance-Based Ray Strategies for Dynamic Diffuse Global Illumination", I3D 2023; supplement).

DDGI's probe volume with 256 direction sets per probe (a 16x16 octahedral tile, the unit of ray allocation;
irradiance and visibility stored at ``ddgi``'s 8x8 and 16x16 squares incl. border, see :mod:`.estimator`)
and, per frame, ``x_i`` uniform rays per probe
(rotating cells, random per-probe shift, adaptive ``x_i``) plus importance rays allocated to the
(probe, set) pairs whose hits changed (balance-heuristic mixture, Secs. 4.3-4.4). Planner, change
measure (paired visits) and adaptive rule: :mod:`.planner`; integration (Algorithm 3)
and probe states (Algorithm 2): :mod:`.estimator`; hit shading is ``ddgi``'s with
per-ray keyed random numbers (:mod:`.shading`: a check visit repeats its reference's
NEE sample and hit lookup, so a static set's difference is ~0). Tracing, merging, the hysteresis blend
(0.97; its running mean linear, see "Static-scene penalty" below), the frame-0 warm-up and relocation are the probe pipeline's (:mod:`dyngi.probes.pipeline`); the
query and primary shading are ``ddgi``'s (:mod:`dyngi.techniques.probe_base`).

Parameters (besides ``ddgi``'s common ones: probe_counts, biases, direct, jitter, ...)
----------
x_init, x_min, x_max : int = 32, 8, 32     uniform rays per probe (powers of two <= 256; supplement's example 32)
irradiance_texels : int = 8     irradiance square per probe incl. border: 8 (``ddgi``'s; ours) or 18 (per set)
distance_texels : int = 16      distance square per probe incl. border: 16 (``ddgi``'s; ours) or 18 (per set)
hold_frames : int = 16          frames a probe keeps its uniform count (ours)
importance_rays : float = 16    importance rays per frame, per active probe (ours)
variant : str = 'multi-rays'    'multi-rays' (<= 4 rays per set) | 'one-ray' (Table 1)
eps : float = 0.1               defensive uniform share of the per-probe allocation pdf (ours)
dynamic_threshold : float = 0.8 change above which a ray is dynamic (ours)
decay : float = 0.9             per-frame decay of the smoothed change (ours)
hysteresis : float = 0.97, warmup : int = 8, irradiance_gamma, change_threshold, distance_power: as ``ddgi``
relocate, classify : bool       relocation (Majercik et al. 2021, as ``ddgi``, but only every
                                ``reclassify_interval`` frames: ours, its per-count grouping is costly on
                                thousands of probes), classification by Algorithm 2 (every frame)
near_surface : bool = True      Algorithm 2 combined with DDGI's near-surface test (issue 26; ours): a probe
                                whose rays found no front face inside its cell neighbourhood during the last
                                ``256 / x_i`` of its traced frames (one rotation of its uniform pattern) is
                                OFF, so isddgi does not update probes ``ddgi`` would not
                                (:func:`~.estimator.near_surface_hits`); False: Algorithm 2 alone
reclassify_interval : int = 8   inactive probes trace their uniform rays every this many frames (ours)
impl : str = 'device'           'device' (Dr.Jit planner and states, :mod:`.device_planner`) | 'host' (NumPy)

Warm-up (ours, as ``ddgi``'s): ``warmup`` updates on frame 0 with one ray in every set (256 per probe)
and no hysteresis; afterwards the change measure forgets their samples (the probes they read changed).

Stages: ``ddgi``'s (the probe pipeline's), so that a stage table compares like with like: ``trace probes``,
``shade probes``, ``blend``, ``states``. ``states`` holds relocation, Algorithm 2 with the near-surface test, the change measure *and
the allocation* (ours: the plan turns the per-probe allocation state -- Table 1's per-probe bytes -- into
this frame's rays; ``ddgi``'s rotation of its direction set costs nothing comparable, so there is no
``plan`` stage that ``ddgi`` would lack); the stat ``plan_ms`` gives the allocation alone. ``impl='device'``
(default): the allocation (uniform cells, importance draws by prefix sum + binary search, per-set caps by
atomic counters, the ray layout), the change measure, Algorithm 2 and the near-surface test run as Dr.Jit
kernels over device state (:mod:`.device_planner`); a frame reads back two small buffers (the plan's ray
count per probe, which the pipeline's CSR plan holds on the host, and the new ON flags; nothing per ray or
per set), and a steady frame compiles no kernel. ``impl='host'``: the former path (NumPy allocation and
change measure, every ray's radiance and distance read back; :mod:`.planner`), kept for comparison -- it is
not faster on the CPU (docs/techniques/isddgi.md). Comparison budgets plan on the host in either. Stats per frame:
``plan_ms``, ``uniform_rays``, ``importance_rays`` (kept after the per-set limit),
``importance_dropped``, ``probe_trace_ms`` (the ``trace probes`` stage), ``dynamic_rays``,
``changed_probes``, ``check_rays`` (paired visits that measured change), ``mean_uniform_per_probe``.

Bias: as ``ddgi`` (hysteresis lag, spatial/angular blur, leaks); in addition a set that no ray visited for
``256 / x_i`` frames lags a change that the change measure did not see (a change the uniform rays miss is
found only when the rotation reaches it), and the per-frame estimate is a ratio (self-normalised).
Static-scene penalty (removed; ours): DDGI's perceptual (gamma 5) blend averages ``E^(1/5)`` and so biases
noisy per-frame estimates low (Jensen), by more the fewer rays; isddgi's static probes drop to
``x_min = 8`` uniform rays, and its converged irradiance was ~9% below ``ddgi``'s (256 rays) -- as low as
``ddgi`` at 8 rays per probe, while at gamma 1 the two agreed (the sampling is unbiased). The blend
therefore keeps a *linear* running mean and uses the perceptual space only for the change threshold
(:class:`~.estimator.LinearMeanHysteresis`): on a static scene with no change detected the uniform rays
converge to ``ddgi``'s answer at the same gamma and hysteresis (within 3%; the residual ~2% is the
spread between ``ddgi`` and ``probes-reference`` themselves). Figures: docs/techniques/isddgi.md.
Texel counts (``irradiance_count``) count frames that gave a texel weight, not rays.

Budgets (``dyngi compare --budget equal-rays|equal-time``; ours): the frame's probe-ray target (equal rays:
the budget minus the primary rays, over 1 + the measured NEE shadow rays per probe ray; equal time: the
budget minus the last frame's non-update time, over its update ms per probe ray) scales uniform and
importance rays together (:meth:`ISDDGIPlanner.plan`, ``n_rays``): probe rays exact (the last few
uniformly drawn where no probe saw change). Stats ``budget_probe_rays`` and ``time_budget_ms``.
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...color import luminance
from ...probes import ProbeStates
from ...probes.grid import PROBE_ACTIVE, PROBE_INACTIVE
from ...probes.params import DDGI_SPECS
from ...probes.pipeline import ProbePipeline
from ...probes.trace import HIT_LOOKUPS, vector_to_numpy
from ..base import Frame, FrameResult, Param, StageTimer, register
from ..probe_base import COMMON_PARAMS, _ProbeTechniqueBase, params_from
from .device_planner import IMPLS, DeviceISDDGIPlanner, DevicePlanInfo
from .estimator import BACKFACE_THRESHOLD, SetBlend, near_surface_hits, near_window, probe_states_alg2
from .planner import SETS_PER_SIDE, VARIANTS, ISDDGIPlanner
from .shading import KeyedHitShader

UPDATE_STAGES = ("trace probes", "shade probes", "blend", "states")     # ddgi's (the pipeline's) stages


def _pow2(name, default, doc):
    return Param(default, doc, choices=tuple(1 << k for k in range(9)))


@register
class ISDDGITechnique(_ProbeTechniqueBase):
    """IS-DDGI (Liu et al. 2023): uniform + importance rays per direction set; see the module docstring."""

    name = "isddgi"
    BUDGETS = ("equal-rays", "equal-time")
    description = ("IS-DDGI (Liu et al. 2023): DDGI with 256 direction sets per probe, few rotating uniform rays "
                   "and importance rays where the probes' hits changed")
    PARAMS = {
        **COMMON_PARAMS,
        "x_init": _pow2("x_init", 32, "initial uniform rays per probe (power of two <= 256)"),
        "x_min": Param(32, "fewest uniform rays per probe, i.e. a static probe's (the adaptive rule halves x_i "
                       "down to it). 32 = x_init: a static probe keeps the supplement's 32 uniform rays (Fig. 1's "
                       "example; the supplement gives no floor). Ours: 8, the former default (static probes at 8 "
                       "rays, half of them paired-visit repeats)", choices=tuple(1 << k for k in range(9)),
                       ours=True, paper=32),
        "x_max": _pow2("x_max", 32, "most uniform rays per probe"),
        "hold_frames": Param(16, "frames a probe keeps its uniform ray count (ours: the supplement keeps such a "
                             "counter, gives no value)", min=1, max=255, ours=True),
        "importance_rays": Param(16.0, "importance rays per frame per active probe (ours: the supplement gives no "
                                 "count)", min=0.0, max=1024.0, ours=True),
        "paired_repeats": Param(True, "a check visit of the change measure repeats its reference ray exactly "
                                "(same jitter, NEE sample and hit lookup: a clean change signal, but every uniform "
                                "sample then enters the estimate twice). Ours (default: the change measure needs it; "
                                "with fresh samples NEE noise over many lights reads as change, measured: on "
                                "corridor-rooms after its light switch 9 % of the importance rays in the switched "
                                "room against > 70 %); false: every ray an independent sample, as the supplement "
                                "integrates all of a frame's rays (its change measure is the main paper's, not "
                                "available)", ours=True, paper=False),
        "linear_mean": Param(True, "the hysteresis blend keeps a linear running mean (the perceptual gamma space "
                             "only for the change threshold: no low bias from few rays per texel). Ours; false: "
                             "DDGI's gamma-space blend, the supplement's (it says nothing else)", ours=True,
                             paper=False),
        "variant": Param("multi-rays", "Table 1: 'multi-rays' (<= 4 rays per set) or 'one-ray'", choices=VARIANTS),
        "eps": Param(0.1, "defensive uniform share of the allocation pdf (ours: no value in the supplement)",
                     min=0.0, max=1.0, ours=True),
        "dynamic_threshold": Param(0.8, "change above which a ray counts as dynamic (ours: the change measure is "
                                   "ours)", min=0.0, max=0.99, ours=True),
        "decay": Param(0.9, "per-frame decay of the smoothed change (ours)", min=0.0, max=1.0, ours=True),
        "warmup": Param(8, "extra updates on frame 0 (one ray per set, no hysteresis; ours, as ddgi's: the "
                        "supplement describes none; charged to frame 0)", min=0, max=256, ours=True),
        **params_from({k: DDGI_SPECS[k] for k in ("hysteresis", "distance_power", "irradiance_gamma",
                                                  "change_threshold")}),     # as ddgi's
        "hit_lookup": Param("stochastic", "how probe-ray hits read the previous probes", choices=HIT_LOOKUPS),
        "relocate": Param(True, "move probes out of geometry (Majercik et al. 2021; ours: the supplement has "
                          "Algorithm 2's states only, relocation is ddgi's, every reclassify_interval frames)",
                          ours=True),
        "classify": Param(True, "probe states by Algorithm 2"),
        "irradiance_texels": Param(8, "irradiance texels per side incl. the border: 8 as ddgi (default; ours, see "
                                   "the estimator), 18 one per direction set (Algorithm 3's irradiance_tex read "
                                   "literally)", choices=(8, 18), ours=True, paper=18),
        "distance_texels": Param(16, "distance texels per side incl. the border: 16 as ddgi (default; ours, see "
                                 "the estimator), 18 one per direction set (Algorithm 3's visibility_tex read "
                                 "literally)", choices=(16, 18), ours=True, paper=18),
        "near_surface": Param(True, "Algorithm 2 and DDGI's near-surface test: a probe with no front-face hit in "
                              "its cell neighbourhood for a rotation of its uniform rays is OFF (ours; false: "
                              "Algorithm 2 alone, the supplement's)", ours=True, paper=False),
        "backface_threshold": Param(BACKFACE_THRESHOLD, "back-face ratio at or above which a probe is OFF (ours: "
                                    "Algorithm 2's BACKFACE_THRESHOLD has no value in the supplement)",
                                    min=0.0, max=1.0, ours=True),
        "reclassify_interval": Param(8, "frames between updates of inactive probes (ours: the supplement does not "
                                     "say when an OFF probe traces again)", min=1, ours=True),
        "impl": Param("device", "where the allocation, change measure and probe states run: 'device' (Dr.Jit "
                      "kernels, the default) or 'host' (NumPy, the former CPU path)", choices=IMPLS),
    }

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        p = self.params
        self._setup_volume(p["irradiance_texels"], p["distance_texels"])
        cls = DeviceISDDGIPlanner if p["impl"] == "device" else ISDDGIPlanner
        self.planner = cls(self.volume.n_probes, p["x_init"], p["x_min"], p["x_max"], p["hold_frames"],
                           p["importance_rays"], p["variant"], p["eps"], p["dynamic_threshold"],
                           p["decay"], self.volume.max_distance)
        self._mean_x = float(p["x_init"])
        self.shader = KeyedHitShader(p["direct"], lights=self.light_nee, lookup=p["hit_lookup"])
        (self.planner.host if p["impl"] == "device" else self.planner).repeat_checks = bool(p["paired_repeats"])
        self.blender = SetBlend(p["hysteresis"], p["distance_power"], p["irradiance_gamma"],
                                p["change_threshold"], float("inf"), "fp32", "scatter",
                                linear_mean=p["linear_mean"])
        self.relocator = ProbeStates(relocate=True, classify=False) if p["relocate"] else None
        # plan, trace and merge through the pipeline; integration (Algorithm 3) and states (Algorithm 2)
        # are this technique's update step
        self.pipeline = ProbePipeline(self.volume, self.planner, self.shader, self.blender, None, self.query,
                                      plan_stage="states", warmup=p["warmup"])
        self._near_age = np.full(self.volume.n_probes, 255, np.uint8)   # traced frames since a near hit
        self.last_plan = None
        self._shadow_per_probe_ray = 1.0      # NEE shadow rays per probe ray (measured), for equal-ray budgets
        self._ms_per_probe_ray = None         # update ms per probe ray on the last frame, for equal-time budgets
        self._ms_fixed = 0.0

    # -- one probe update -------------------------------------------------------------
    def update(self, frame_index: int, seed: int, t: StageTimer, warm: bool = False,
               frame: Frame | None = None) -> dict:
        """One probe update (the pipeline's update step, :meth:`ProbePipeline.step
        <dyngi.probes.pipeline.ProbePipeline.step>`): the pipeline plans, traces and merges; then relocation on
        re-test frames, Algorithm 2's probe states and the change measure. ``warm``: an update of the warm-up
        (one ray per set; the change measure does not adapt)."""
        p = self.params
        adapt = not warm
        vol = self.volume
        st = vol.state
        live = st.states != 0
        wake = warm or frame_index % p["reclassify_interval"] == 0
        ids = np.flatnonzero(live | wake).astype(np.uint32)
        info = {"uniform_rays": 0, "importance_rays": 0, "importance_dropped": 0, "dynamic_rays": 0,
                "changed_probes": 0, "probes_traced": int(len(ids))}
        if not len(ids):
            return info
        n_rays = None if frame is None else self._budget_probe_rays(frame, len(ids))
        if n_rays is not None:
            info["budget_probe_rays"] = n_rays
        device = isinstance(self.planner, DeviceISDDGIPlanner)
        host_pl = self.planner.host if device else self.planner
        pulled = device and n_rays is not None and self.planner.force_uniform is None
        if pulled:          # a budget plans on the host: its state follows (ours; see device_planner)
            self._near_age = self.planner.pull()
        # plan (importance hints), trace with keyed shading, per-set estimate + hysteresis merge: the pipeline
        self.pipeline.update(self.scene, frame_index, seed, timer=t, probe_ids=ids, importance=live[ids],
                             n_rays=n_rays)
        plan = self.last_plan = self.pipeline.last_plan
        info.update(plan.info.stats)
        if not plan.n_rays:
            return info
        res = self.pipeline.last_results
        # -- states: relocation on re-test frames, Algorithm 2, the change measure (ours: this step's) --
        with t.stage("states"):
            on_device = isinstance(plan.info, DevicePlanInfo)
            if self.relocator is not None and wake:      # relocation on re-test frames only (ours: cost)
                before = st.offsets.copy()
                fin = self.pipeline.begin_states(plan, res, self.relocator)
                if fin is not None:
                    fin()
                # a moved probe's stored samples are no reference for its next rays (ours)
                moved = np.flatnonzero(np.any(st.offsets != before, axis=1))
                (self.planner if on_device else host_pl).forget(moved)
            if on_device:
                info.update(self._states_device(plan, res, warm, adapt))
                return info
            L, d = res.host()
            if p["classify"]:
                on = probe_states_alg2(plan.info, d, p["backface_threshold"])
                pid = plan.probe_ids.astype(np.int64)
                if p["near_surface"]:       # DDGI's near-surface test over a rotation window (estimator)
                    near = near_surface_hits(vol, pid, plan.info.ray_slot, vector_to_numpy(plan.direction).T, d)
                    age = np.where(near, 0, np.minimum(self._near_age[pid].astype(np.int64) + 1, 255))
                    self._near_age[pid] = age.astype(np.uint8)
                    x = plan.info.total if warm else host_pl.state.x[pid]
                    on &= age < near_window(x)
                old = st.states[pid].copy()
                new = np.where(on, PROBE_ACTIVE, PROBE_INACTIVE).astype(np.uint8)
                st.states[pid] = new
                st.updates[pid[(old == PROBE_INACTIVE) & (new == PROBE_ACTIVE)]] = 0
                if np.any(old != new):
                    vol.sync(("positions", "states"))
            lum = luminance(L.T)                         # L: (3, n) channel-planar
            info.update(host_pl.observe(plan, lum, d, adapt=adapt))
            self._mean_x = float(np.mean(host_pl.state.x))
            if pulled:
                self.planner.push(self._near_age)
        return info

    def _states_device(self, plan, res, warm: bool, adapt: bool) -> dict:
        """The ``states`` step on the device (:class:`~.device_planner.DeviceISDDGIPlanner`): Algorithm 2 with the
        near-surface test, then the change measure and the allocation state; one read of the new ON flags and
        the statistics (``S + 5`` integers; the last, the probes with change, lets the next plan skip its
        importance draws when there is none)."""
        p, vol = self.params, self.volume
        st = vol.state
        S = plan.info.S
        pl = self.planner
        buf = dr.zeros(mi.UInt32, S + 5)                  # ON flags, then observe's five statistics
        on = None
        if p["classify"]:
            on = pl.probe_states(vol, plan, res.distance, warm, p["backface_threshold"], p["near_surface"], out=buf)
        pl.observe(plan, mi.luminance(res.radiance), res.distance, adapt=adapt, out=buf)
        host = np.asarray(buf).astype(np.int64)          # the states step's one read
        pl.n_changed = int(host[S + 4])                  # bounds the next plan's draw candidates
        pl.any_change = pl.n_changed > 0                 # the next plan skips its draws without change
        self._mean_x = float(host[S + 3]) / max(vol.n_probes, 1)
        if on is not None:
            pid = plan.probe_ids.astype(np.int64)
            old = st.states[pid].copy()
            new = np.where(host[:S] != 0, PROBE_ACTIVE, PROBE_INACTIVE).astype(np.uint8)
            st.states[pid] = new
            st.updates[pid[(old == PROBE_INACTIVE) & (new == PROBE_ACTIVE)]] = 0
            if np.any(old != new):
                vol.sync(("positions", "states"))
        return {"dynamic_rays": int(host[S]), "check_rays": int(host[S + 1]), "changed_probes": int(host[S + 2])}

    # -- comparison budgets (ours) -------------------------------------------------------
    def _budget_probe_rays(self, frame: Frame, n_probes: int) -> int | None:
        """Probe rays this frame may trace under ``frame.ray_budget`` / ``time_budget_ms``; None: no budget.

        Equal rays: the budget minus the primary rays (camera + ``direct_samples`` NEE rays per pixel, an upper
        bound) and, on frame 0, the warm-up's rays (charged to it), over 1 + the NEE shadow rays per probe ray measured on the last frame (the warm-up's before
        the first). Equal time: the budget minus the last frame's time outside the probe update, over the
        last frame's update ms per probe ray (a linear model; the first frame runs the defaults). At least
        one ray per traced probe."""
        p = self.params
        if frame.ray_budget is not None:
            other = frame.res[0] * frame.res[1] * (1 + p["direct_samples"])
            other += sum(self.pipeline.last_warmup_rays.values())     # the warm-up is charged to frame 0
            n = (frame.ray_budget - other) / (1.0 + self._shadow_per_probe_ray)
        elif frame.time_budget_ms is not None and self._ms_per_probe_ray:
            n = (frame.time_budget_ms - self._ms_fixed) / self._ms_per_probe_ray
        else:
            return None
        return int(max(n, n_probes))

    def _measure(self, stats: dict) -> None:
        rays, ms = stats["rays"], stats["ms"]
        if rays.get("trace probes"):
            self._shadow_per_probe_ray = rays.get("shade probes", 0) / rays["trace probes"]
            if "warmup" not in ms:
                update = sum(ms.get(k, 0.0) for k in UPDATE_STAGES)
                self._ms_per_probe_ray = update / rays["trace probes"]
                self._ms_fixed = max(stats["total_ms"] - update, 0.0)

    def _learn_warmup_rate(self, mask=None) -> None:
        """The NEE shadow rays per probe ray of the warm-up (if one ran this frame), before the frame's budget."""
        wr = self.pipeline.last_warmup_rays
        if wr.get("trace probes"):
            self._shadow_per_probe_ray = wr.get("shade probes", 0) / wr["trace probes"]

    def step(self, frame: Frame) -> FrameResult:
        t = StageTimer()
        self._lights_begin(frame, t)        # lights=: the sampler's per-frame hook before the first probe ray
        # the warm-up (one ray per set: the planner's warm-up hooks) and the frame's update, both this update step
        info = self.pipeline.step(self.scene, frame, t, update=self.update, before_update=self._learn_warmup_rate)
        img, ind = self._primary(frame, t)
        stats = t.as_dict()
        stats.update(info)
        self._measure(stats)
        if frame.time_budget_ms is not None:
            stats["time_budget_ms"] = float(frame.time_budget_ms)
        stats["probe_trace_ms"] = stats["ms"].get("trace probes", 0.0)
        stats["active_probes"] = int(np.count_nonzero(self.volume.state.states))
        stats["mean_uniform_per_probe"] = self._mean_x
        return FrameResult(image=img, indirect=ind, stats=stats)
