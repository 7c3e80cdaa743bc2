"""Adaptive Dynamic GI (Datta et al. 2022) -- Metropolis-guided probe updates (technique ``adgi``).

Estimates DDGI's irradiance/visibility probes, but spends the ray budget where
a guide over probe position x direction says rays matter, sampled by
persistent Metropolis chains (:mod:`dyngi.sampling.metropolis`); each sample
updates the probe texels it lands in with Algorithm 3's moving average
(:mod:`.moving_average`). The probe pipeline (:mod:`dyngi.probes.pipeline`) does the tracing,
merging, relocation/classification and the frame-0 warm-up; the chains are its planner
(:class:`.planner.ADGIChainPlanner`). Primary shading is ``ddgi``'s
(:mod:`dyngi.techniques.probe_base`), with its ``glossy`` parameter (default off): the primary
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
  probe (the level is ours; :meth:`.planner.ADGIChainPlanner.guide_feedback`).
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
  Dynamic updates use N_max = 10, static ones 63 (Table 3); a static sample in an octant with
  ``f_d > 0`` also merges into its radiance texel with N_max = 10 (``change_cap``; ours: the paper
  snaps such samples to texel centres "to avoid injecting sampling noise" but does not say which
  N_max they use; with 63, a texel visited every other frame at an equal-ray budget keeps ~100
  frames of samples from before a change, and the tunnel's interior lagged Q-DDGI's, measured in
  docs/techniques/adgi.md).
* Culling (Sec. 4.9, ``cull_unused``): the primary pass marks on the device the 8 cage probes of every
  pixel's probe lookup (:class:`CageMarkingQuery`); the next frame's S and D sample only probes of
  ``V_in`` so marked (the paper culls "probes that are not used in deferred shading" in D; ours in S too,
  the issue's reading; the mask is one frame old since our primary pass shades in the same pass).
* After the updates, probes in ``V_out - V_in`` get their texel counts capped,
  ``N <- min(N, 16)`` (Sec. 4.8).

How a sample becomes a texel update (Algorithm 2 updates "the closest entry"; how a radiance sample
becomes irradiance the paper does not say; ours, :mod:`.radiance`): the radiance along ``w`` goes into
the one *radiance* texel ``w`` falls in (``radiance_texels`` = 8 per side: the irradiance map's own
8x8 octahedral layout, so a sample updates the entry Algorithm 2 would) with Algorithm 3's batch rule,
and every probe updated in the frame is re-convolved to its 8x8 irradiance texels (cosine x solid-angle
weights over the texels that hold samples), which removes the closest-entry update's bias (a radiance
mean is not an irradiance). A finer radiance layer (16 per side, the earlier default) spreads a probe's
samples over 196 texels instead of 36: at an equal-ray budget each texel is then visited about 5x less
often, and Algorithm 3's count-based memory of up to 63 samples spans 5x more frames -- it slowed ADGI's
recovery on the opening tunnel (docs/techniques/adgi.md). A cosine
splat of each sample over the irradiance texels was tried first and is
biased wherever the guide is 0 over part of a texel's hemisphere (measured
-52% on the Cornell box's front probes). The distance of the ``-w`` ray goes
to the one visibility texel ``-w`` falls in (``bin`` mode, Algorithm 3 on the
volume's distance texels; DDGI's cos^50 kernel is about one 16x16 texel wide).

Budgets (``dyngi compare --budget equal-rays``; ours): after the primary and
pilot rays, half of what remains is reserved for the dynamic stage when it
is on and some octant has f_d > 0 this frame (else the static stage gets it
all: a static scene wastes none of its budget); the static stage runs only
``n`` chains, ``n`` = its share / ((M - K) x the last frame's share of unique samples x (2 + measured
NEE shadow rays per probe ray)) + 15%, starting where the last frame's stopped (the chains rotate), and
a device prefix sum caps the traced samples at the share; a state repeated by rejected moves is traced
once with its multiplicity (the plan's weight: the radiance and distance texels count it ``m`` times);
the dynamic stage traces whole proxy octants, the highest guide value first (a device counting sort
by f_d's 10-bit level, :func:`.planner.budget_keep`), while the remainder lasts. Rays are
counted exactly (probe rays, their NEE shadow rays, the ``-w`` rays).
Equal time (``Frame.time_budget_ms``): the budget minus the last frame's time
outside S and D, turned into rays of S and D by each stage's measured ms per
ray on its last frame, then shared as above (so the chain counts scale with
the time; the first frame, with nothing measured, runs the defaults); the
spend is recorded (``stats['static_chains_run']``), not guaranteed.

Two implementations of one sampling (``impl``; ours): the **host** path sizes ragged plans on the host
(the sample counts from ``dr.compress``, a host sort of the traced probe ids: one read per stage and plan;
under a budget the f_d scale), counts probe updates on the host, and convolves the radiance layer with
NumPy/BLAS (the CPU fast path). The **device** path never waits for the host in a steady probe update
(:meth:`ADGITechnique.update_probes`; tests/techniques/adgi/test_device_path.py): masked fixed-width plans
(:meth:`RayPlan.masked <dyngi.probes.rays.RayPlan.masked>`; widths set on the host from the chains, the
budget or, without one, 1.25x the last frame's lanes, :mod:`.planner`), the exact budget caps as
device values (the rays spent so far and "some f_d > 0" this frame, on the device; the chain count from
the last frame's measurements), update counts on the device (:meth:`ProbePipeline.merge_slots
<dyngi.probes.pipeline.ProbePipeline.merge_slots>`) and the device convolution; its counts (stats, the
NEE shadow-ray rate, the unique share) are read after the frame's image. A frame with the warm-up or a
relocation/classification pass (every ``reclassify_interval`` frames; ``ddgi``'s host states) still
reads back. ``impl='auto'``: the device path on a GPU; on the LLVM backend the host path, measured faster
there (masked lanes still cost CPU time, the device convolution is a symbolic loop; docs/techniques/adgi.md,
issue 25). Either path samples the same chains with the same caps: the images agree statistically (the
NEE streams follow the ray order).

Speed: an ``adgi`` frame launches several times the kernels of a ``qddgi`` frame; that fixed cost, not the
rays, makes it slower than ``qddgi`` at small grids, and it is why an equal-time budget below it cannot
be met (the chains shrink to 1 and the frame overspends; recorded, not hidden). The two trigger
convolutions (Eqs. 15, 18) share one launch per axis. Figures: docs/techniques/adgi.md, "Kernel launches and
probe-sampling time against grid size".

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
camera_threshold : float = 0      k of Eq. 10 (world units); 0 = the 0.9 quantile of the camera distances
                                  of the probes in view (ours, :meth:`.heuristics.ADGIHeuristics.k_for`)
theta : float = 16                trigger decay, frames (ours)
cull_unused : bool = True         S and D skip probes no pixel's cage used (Sec. 4.9)
change_cap : bool = True          static samples of octants with f_d > 0 merge with N_max dynamic (ours)
dynamic_share : float = 0.5       share of a budget reserved for D when some f_d > 0 (ours)
n_max_static, n_max_dynamic : int = 63, 10   (Table 3)
outer_count_cap : int = 16        (Sec. 4.8)
encoding : str = 'adgi'           R9G9B8 + 6-bit count / R13G13 + count (Sec. 4.5-4.6, Table 3)
guide_mip : int = 1               mip level of g in the static guide (ours; Sec. 4.8 "a higher mip-level")
reclassify_interval : int = 8     frames between relocation/classification passes after the warm-up (ddgi's)
impl : str = 'auto'               'device' (no host read in a steady update) | 'host' | 'auto' (device on a
                                  GPU, host on the CPU: measured faster there)

Bias: the moving average lags dynamic changes (Sec. 3.5); texels no chain
visits keep old values; quantised irradiance storage rounds low.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ...backend import dr, mi
from ...errors import DyngiError
from ...probes import DiffuseHitShader, HysteresisBlend, ProbeStates, RayPlan, ScatterEstimator, UniformSFDirections
from ...probes.arrays import upload
from ...probes.accumulator import MeanAccumulator, pull_from
from ...probes.estimator import is_cpu_backend
from ...probes.rays import compact
from ...probes.encoding import get_encoding
from ...probes.lookup import diffuse_radiance
from ...probes.pipeline import ProbePipeline
from ...probes.trace import HIT_LOOKUPS, ProbeRayResults
from ...sampling.diffuse import diffuse_albedo
from ...sampling.metropolis import ADGI_DIRECTION_STEP
from ..base import Frame, FrameResult, Param, StageTimer, register
from ..probe_base import COMMON_PARAMS, _ProbeTechniqueBase
from .heuristics import (OCTANTS, ADGIHeuristics, frusta, octant_of, pack_heuristics, unpack_heuristics,
                         view_distances)
from .moving_average import N_MAX_DYNAMIC, N_MAX_STATIC, Algorithm3Accumulator
from .planner import ADGIChainPlanner, negated
from .radiance import RadianceCache

IMPLS = ("auto", "device", "host")


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
            L = L + diffuse_radiance(albedo, E, front)
        dr.schedule(self.last_direct)
        return L, hit, front, shadow


class CageMarkingQuery:
    """A :class:`~dyngi.probes.query.ProbeQuery` that also scatters 1 into ``used[probe]`` for the 8 probes of
    the cage each irradiance lookup reads (the same biased position and base cell as the query), so the
    primary pass records on the device which probes the image uses (Sec. 4.9's culling). Everything else is
    the wrapped query's."""

    def __init__(self, query, used):
        self._q = query
        self.used = used

    def __getattr__(self, name):
        return getattr(self._q, name)

    def irradiance(self, pos, normal, wo, direction=None, active=True, sampler=None):
        self.mark(pos, normal, wo, active)
        return self._q.irradiance(pos, normal, wo, direction=direction, active=active, sampler=sampler)

    def mark(self, pos, normal, wo, active=True) -> None:
        q = self._q
        g = q.volume.grid
        nx, ny, nz = (int(c) for c in g.counts)
        origin, _, inv_spacing = g.opaque_params()
        scale = g.min_spacing
        ok = mi.Bool(active) & dr.all(dr.isfinite(pos)) & dr.all(dr.isfinite(normal)) & dr.all(dr.isfinite(wo))
        bpos = pos + normal * (q.normal_bias * scale) + wo * (q.view_bias * scale)
        rel = dr.select(ok, (bpos - origin) * inv_spacing, mi.Vector3f(0.0))
        base = mi.Vector3u(dr.clip(dr.floor(rel), 0.0, mi.Vector3f(nx - 2, ny - 2, nz - 2)))
        for c in range(8):
            i = base.x + (c & 1)
            j = base.y + ((c >> 1) & 1)
            k = base.z + ((c >> 2) & 1)
            dr.scatter(self.used, mi.Float(1.0), i + nx * (j + ny * k), ok)


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
        "camera_threshold": Param(0.0, "k of Eq. 10 in world units (0: the 0.9 quantile of the camera "
                                  "distances of the probes in view)", min=0.0),
        "beta": Param(5.0, "range of the radiance heuristic (Eq. 12)", min=1e-3),
        "mu": Param(2.0, "weight of the radiance change in f_d (Eq. 20)", min=0.0),
        "theta": Param(16.0, "temporal trigger decay in frames (Eq. 14)", min=1.0),
        "n_max_static": Param(N_MAX_STATIC, "N_max of static updates (Table 3)", min=1, max=63),
        "n_max_dynamic": Param(N_MAX_DYNAMIC, "N_max of dynamic updates (Table 3)", min=1, max=63),
        "outer_count_cap": Param(16, "count cap of probes in V_out - V_in (Sec. 4.8)", min=1, max=63),
        "pilot_updates": Param(True, "pilot rays update the caches on alternate frames (Sec. 4.4)"),
        "radiance_texels": Param(8, "radiance texels per side incl. border that samples are binned into "
                                 "(convolved to irradiance each frame; 8: the irradiance map's, Algorithm 2's "
                                 "closest entry)", min=4, max=64),
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
        "cull_unused": Param(True, "Sec. 4.9: the static and dynamic stages skip probes that no pixel's probe "
                             "cage used on the previous frame's primary pass"),
        "cache_update": Param("convolve", "how a radiance sample updates the irradiance texels: 'convolve' (the "
                              "radiance layer, convolved each frame) or 'closest-entry' (Algorithm 2 literally: the "
                              "irradiance texel the sample falls in, Algorithm 3 in the encoded word; biased)",
                              choices=("convolve", "closest-entry")),
        "change_cap": Param(True, "static samples in octants with f_d > 0 merge into the radiance texels with "
                            "the dynamic N_max (ours)"),
        "dynamic_share": Param(0.5, "share of an equal-ray/equal-time budget (after primary and pilot rays) "
                               "reserved for the dynamic stage when some octant has f_d > 0 (ours)", min=0.0,
                               max=1.0),
        "reclassify_interval": Param(8, "frames between ddgi's relocation/classification passes after the "
                                     "warm-up (fixed rays; 0: warm-up only)", min=0),
        "guide_mip": Param(1, "mip level of the irradiance feedback g in the static guide (Sec. 3.2/4.8; "
                           "0: the texel itself)", min=0, max=3),
        "impl": Param("auto", "'device': masked fixed-width plans, no host read in the probe update; 'host': "
                      "ragged plans sized on the host (reads back); 'auto': device on a GPU, host on the CPU",
                      choices=IMPLS),
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
        self.shader = PilotShader(p["direct"], lights=self.light_nee, lookup=p["hit_lookup"])
        self.encoding = get_encoding(p["encoding"])     # Table 3: visibility rounds to nearest
        self.acc_static = Algorithm3Accumulator(p["n_max_static"])
        self.acc_dynamic = Algorithm3Accumulator(p["n_max_dynamic"])
        self._mean = MeanAccumulator()
        self.est_dist = ScatterEstimator(p["distance_power"], "bin")
        self.est_irr = ScatterEstimator(p["distance_power"], "bin")     # closest-entry: one texel per sample
        self.heur = ADGIHeuristics(g, p["camera_threshold"] or None, p["beta"], p["mu"], p["theta"])
        self.hstate = self.heur.initial_state()
        # -- the planner: static chains over probe cells, dynamic ones over 3x3x3 proxies (grid units) --
        self.planner = ADGIChainPlanner(self.volume, p)
        # -- ddgi's warm-up pieces (hysteresis blend, shared SF set, relocation/classification) --
        self.blender = HysteresisBlend(0.0, p["distance_power"], 1.0, 0.25, 1e30, p["encoding"], "auto")
        self.blender.encoding = self.encoding             # the warm-up stores through the same encoding
        # the pipeline: its own update is the warm-up's (ddgi's); the stages P, S, D call its trace and merge
        self.pipeline = ProbePipeline(self.volume, UniformSFDirections(p["warmup_rays"]),
                                      DiffuseHitShader(p["direct"], lights=self.light_nee,
                                                       lookup=p["hit_lookup"]), self.blender,
                                      ProbeStates(p["relocate"], p["classify"]), self.query, reclassify_interval=0)
        self.updater = self.pipeline       # (older name)
        self._warmed = False
        self._shadow_rate = 1.0                # NEE shadow rays per probe ray (measured)
        self._static_rays = None               # this frame's ray allowance of S and D (None: no budget)
        self._dynamic_rays = None
        self._time_avail_ms = None             # equal time: this frame's ms for S + D (None: no time budget)
        self._ms_per_ray = {"S": None, "D": None}   # measured on the last frame that traced in the stage
        self._ms_fixed = 0.0                   # measured: the last frame's time outside S and D
        self.radiance = RadianceCache(vol_n := self.volume.n_probes, p["radiance_texels"],
                                      self.volume.irradiance_texels)
        self._updated = np.zeros(vol_n, bool)
        self._used = dr.full(mi.Float, 1.0, vol_n)     # probes the last primary pass read (all, before one ran)
        # -- the device path (impl): masked plans, counts on the device, read after the frame's image --
        self.device = p["impl"] == "device" or (p["impl"] == "auto" and not is_cpu_backend())
        self.planner.device = self.device
        self._updated_dev = dr.zeros(mi.UInt32, vol_n)   # probes merged this frame (device path)
        self._slots_merged = 0                            # slots merged this frame (host: the convolve width)
        self._frame_dev = []        # this frame's device ray counts before the budget: (count, lower, estimate)
        self._rates = []            # (probe rays, NEE shadow rays) of this frame's traces, device values
        self._dyn_prev = False      # the last frame's "some f_d > 0" (device path, read after its image)
        self._static_limit = self._dynamic_limit = None   # device caps of S and D under a ray budget
        self._static_rays_max = self._dynamic_rays_max = None
        self._avail_dev = None

    def memory_per_probe(self) -> dict:
        """Bytes per probe by part: the irradiance and visibility texels as their encoded words (Table 3:
        ``adgi``'s ``R9G9B8-N`` and ``R13G13-N`` are 32 bits each, so 8x8 + 16x16 words = 1280 B), the
        6-10-10 heuristics word per octant (Sec. 4.3, 32 B), and ours: the radiance layer as held (fp32 RGB +
        a UInt32 count per interior texel, 16 B each; Table 3 has none) and the fp32 moments' working copy
        is not counted (the encoded word is what is stored). Bits per word from the encoding."""
        enc = self.encoding
        irr_bits = sum(getattr(enc, "IRR_BITS", (32, 32, 32, 32)))
        vis_bits = sum(getattr(enc, "VIS_BITS", (32, 32, 32)))
        Ti, Td = self.volume.irradiance_texels, self.volume.distance_texels
        return {"irradiance": Ti * Ti * irr_bits // 8, "visibility": Td * Td * vis_bits // 8,
                "heuristics": OCTANTS * 4, "radiance_layer": self.radiance.n_tex * 16}

    # the planner's chains and guide, readable here (the viewer draws the static chains)
    @property
    def static_state(self):
        return self.planner.static_state

    def guide_feedback(self):
        """The static guide's irradiance feedback (:meth:`.planner.ADGIChainPlanner.guide_feedback`)."""
        return self.planner.guide_feedback()

    def k_for(self, frame: Frame) -> float:
        """Eq. 10's k on ``frame`` (:meth:`.heuristics.ADGIHeuristics.k_for`: the user's, else from the camera
        distances of the active probes in view)."""
        vol = self.volume
        view = None if self.heur.user_k is not None else \
            view_distances(vol, frame.camera, frame.res, vol.state.states != 0)
        return self.heur.k_for(frame.camera.origin, view)

    # -- one frame ------------------------------------------------------------------------------
    def step(self, frame: Frame) -> FrameResult:
        t = StageTimer()
        stats = self.update_probes(frame, t)
        img, ind = self._primary(frame, t)
        return self.finish_frame(t, stats, img, ind)

    def update_probes(self, frame: Frame, t: StageTimer) -> dict:
        """One frame's probe update, stages P, S, D (and the warm-up / relocation passes when due); returns
        its stats (device values on the device path). On the device path (``impl``) a frame without the
        warm-up or a relocation/classification pass reads nothing back to the host here (tests/techniques/
        adgi/test_device_path.py); the counts are read by :meth:`finish_frame`, after the image."""
        p = self.params
        self._lights_begin(frame, t)        # lights=: the sampler's per-frame hook before the first probe ray
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
            _, _, near = frusta(vol, frame.camera, frame.res, self.k_for(frame))
            self._states_pass(frame, t, near | (vol.state.states == 0))
        active = vol.state.states != 0
        fc, v_in, v_out = frusta(vol, frame.camera, frame.res, self.k_for(frame))
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
                n_p = self._count(tt)
                t.add_rays("P", n_p)
                if self.device and not isinstance(n_p, int):   # the budget's device count (and host bounds)
                    self._frame_dev.append((n_p, 8 * len(ids), 8 * len(ids) * (1.0 + self._shadow_rate)))
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
        # -- Sec. 4.9's culling: the chains sample only probes of V_in that the last primary pass used --
        samp_dr = vin_dr * self._used if p["cull_unused"] else vin_dr
        # -- S: static chains (Sec. 4.8) --
        with t.stage("S"):
            stats["static_samples"] = self._static(frame, samp_dr, fd, t)
        if self._time_avail_ms is not None:      # equal time: D gets what S left
            per = self._ms_per_ray["D"] or self._ms_per_ray["S"]
            self._dynamic_rays = None if per is None else max(self._time_avail_ms - t.ms.get("S", 0.0), 0.0) / per
        # -- D: dynamic chains on proxies (Sec. 4.9) --
        with t.stage("D"):
            stats["dynamic_proxy_octants"] = self._dynamic(frame, samp_dr, fd, t)
            self._cap_outer(v_out & ~v_in, p["outer_count_cap"])
            stats["probes_updated"] = self._convolve_updated()
        stats["v_in"], stats["v_out"] = int(v_in.sum()), int(v_out.sum())
        stats["static_chains_run"] = self.planner.n_run
        return stats

    def finish_frame(self, t: StageTimer, stats: dict, img, ind) -> FrameResult:
        """The frame's result after :meth:`update_probes` and the primary pass: the timer's stats with the
        update's (device counts read here, after the image: no extra wait), the equal-time measurements."""
        out = t.as_dict()
        out.update(stats)
        if self.device:
            self._finish_device_frame(out)
        self._measure_time(out)
        return FrameResult(image=img, indirect=ind, stats=out)

    def _primary(self, frame: Frame, t: StageTimer):
        """The primary pass (``ddgi``'s), which also marks, on the device, the 8 cage probes of every pixel's
        probe lookup (:class:`CageMarkingQuery`): the next frame's stages S and D skip the others (Sec. 4.9,
        "culling probes that are not used in deferred shading"; the paper renders its G-buffer before the
        probe update, ours shades in the same pass, so the mask is one frame old; our choice). Probe-ray hits
        (multi-bounce) do not mark."""
        if not self.params["cull_unused"]:
            return super()._primary(frame, t)
        used = dr.zeros(mi.Float, self.volume.n_probes)
        inner = self.query
        self.query = CageMarkingQuery(inner, used)
        try:
            out = super()._primary(frame, t)
        finally:
            self.query = inner
        dr.eval(used)
        self._used = used
        return out

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
        self._static_limit = self._dynamic_limit = self._avail_dev = None
        self._static_rays_max = self._dynamic_rays_max = None
        # the dynamic stage is reserved its half only when some entry has f_d > 0 this frame (else it
        # traces nothing and S gets it all); one host read of the f_d scale, only under a budget
        if frame.ray_budget is None and frame.time_budget_ms is None:
            return
        if self.device and frame.ray_budget is not None:
            return self._plan_budget_device(frame, t)
        dyn = self._dyn_prev if self.device else \
            self.planner.dynamic_state is not None and float(np.asarray(self.lut_scale).ravel()[0]) > 0.0
        share = float(self.params["dynamic_share"]) if dyn else 0.0
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

    def _plan_budget_device(self, frame: Frame, t: StageTimer) -> None:
        """:meth:`_plan_budget` without a host read (device path): the exact caps are device values -- the
        rays spent so far (the pilot's NEE shadow rays are counted on the device) and the dynamic share only
        when some f_d > 0 *this* frame (the 6-10-10 word's scale, on the device) -- while the host sizes the
        chains run and the plans' widths from the last frame's "some f_d > 0" and shadow-ray rate (an
        estimate) and from the fewest rays spent so far (an upper bound of the widths)."""
        p = self.params
        ints = sum(v for k, v in t.rays.items() if k != "warmup")
        primary = frame.res[0] * frame.res[1] * (1 + p["direct_samples"])
        fixed = float(frame.ray_budget) - ints - primary
        lower = sum(lo for _, lo, _ in self._frame_dev)
        est = sum(e for _, _, e in self._frame_dev)
        dyn_on = self.planner.dynamic_state is not None
        share = float(p["dynamic_share"]) if dyn_on else 0.0
        avail_est = max(fixed - est, 0.0)
        self._static_rays = avail_est * (1.0 - (share if self._dyn_prev else 0.0))
        self._static_rays_max = self._dynamic_rays_max = max(fixed - lower, 0.0)
        self._dynamic_rays = avail_est
        spent = mi.Float(0.0)
        for c, _, _ in self._frame_dev:
            spent = spent + mi.Float(c)
        avail = dr.maximum(dr.opaque(mi.Float, fixed) - spent, 0.0)
        dyn = (self.lut_scale > 0.0) if dyn_on else mi.Bool(False)
        per = 2.0 + self._shadow_rate
        self._avail_dev = avail
        self._static_limit = mi.UInt32(avail * (1.0 - dr.select(dyn, dr.opaque(mi.Float, share), 0.0))
                                       / dr.opaque(mi.Float, per))
        dr.make_opaque(self._static_limit)     # evaluated, as the planner's opaque caps: the same kernels

    def _finish_device_frame(self, out: dict) -> None:
        """Device path, after the frame's image: its stats as ints, the NEE shadow rays per probe ray and the
        "some f_d > 0" flag for the next frame's sizes, the planner's counts (:meth:`.planner.ADGIChainPlanner
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
        self._dyn_prev = self.planner.dynamic_state is not None and \
            float(np.asarray(self.lut_scale).ravel()[0]) > 0.0
        self.planner.finish_frame()

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
        re-tested with ``ddgi``'s fixed set of classification rays (:meth:`ProbePipeline.classify
        <dyngi.probes.pipeline.ProbePipeline.classify>`, 32 spherical-Fibonacci rays) and
        :class:`~dyngi.probes.states.ProbeStates` moves / (de)activates it as ``ddgi`` does. The rays are
        counted (stage ``states``) and come out of an equal-ray budget before the chains are sized."""
        if self.device:     # the host pass resets the counts of woken probes: the device counts go through it
            self.pipeline.history_to_host()
        self.pipeline.classify(self.scene, np.flatnonzero(mask).astype(np.uint32), frame.index, frame.seed, t)
        if self.device:
            self.pipeline.history_from_host()

    # -- the stages' traces and merges ----------------------------------------------------------------
    def _static(self, frame: Frame, vin_dr, fd, t: StageTimer) -> int:
        """S: the planner's static plan, traced and merged with N_max static (Sec. 4.8)."""
        plan = self.planner.plan(frame.index, frame.seed, stage="static", vin=vin_dr, fs=self._fs_q, fd=fd,
                                 rays=self._static_rays, shadow_rate=self._shadow_rate,
                                 rays_max=self._static_rays_max, limit=self._static_limit)
        if plan is None:
            return 0
        lane_cap = None
        if self.params["change_cap"]:    # samples of entries with f_d > 0 merge with the dynamic N_max (ours)
            changed = dr.gather(mi.Float, fd, plan.probe * OCTANTS + octant_of(plan.direction)) > 0.0
            lane_cap = dr.select(changed, mi.UInt32(self.params["n_max_dynamic"]),
                                 mi.UInt32(self.params["n_max_static"]))
        spent = self._trace_and_merge(frame, plan, self.acc_static, self.params["n_max_static"], stream=43,
                                      lane_cap=lane_cap)
        t.add_rays("S", spent)
        if self._avail_dev is not None:       # device path: D's exact cap on the device
            self._dynamic_limit = mi.UInt32(dr.maximum(self._avail_dev - mi.Float(spent), 0.0)
                                            / dr.opaque(mi.Float, 2.0 + self._shadow_rate))
            dr.make_opaque(self._dynamic_limit)
        elif self._dynamic_rays is not None:
            self._dynamic_rays = max(self._dynamic_rays - spent, 0.0)
        return self.planner.last_samples

    def _dynamic(self, frame: Frame, vin_dr, fd, t: StageTimer) -> int:
        """D: the planner's dynamic plan, traced and merged with N_max dynamic (Sec. 4.9)."""
        plan = self.planner.plan(frame.index, frame.seed, stage="dynamic", vin=vin_dr, fd=fd,
                                 rays=self._dynamic_rays, shadow_rate=self._shadow_rate,
                                 rays_max=self._dynamic_rays_max, limit=self._dynamic_limit)
        if plan is not None:
            t.add_rays("D", self._trace_and_merge(frame, plan, self.acc_dynamic, self.params["n_max_dynamic"],
                                                  stream=45))
        return self.planner.last_samples

    def _trace_and_merge(self, frame: Frame, plan: RayPlan, acc, n_max: int, stream: int, lane_cap=None) -> int:
        """Trace ``plan`` (radiance along ``w``, distance along ``-w``) and merge; returns the rays cast
        (probe rays, their NEE shadow rays and the ``-w`` rays)."""
        tt = StageTimer()
        res = self.pipeline.trace(self.scene, plan, frame.seed, frame.index, stream=stream, timer=tt,
                                  shader=self.shader)
        back = negated(plan)
        dist = self.pipeline.trace_distances(self.scene, back)
        self._merge(res, ProbeRayResults(res.radiance, dist, back), acc, n_max, lane_cap)
        return self._count(tt) + plan.rays_cast()

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

    def _merge(self, irr_res, dist_res, acc, n_max: int, lane_cap=None) -> None:
        """Radiance of ``irr_res`` into the radiance texels (:mod:`.radiance`), distance moments of
        ``dist_res`` (or of ``irr_res`` when None: the pilot rays' own distances) into the visibility texels,
        both with Algorithm 3's batch rule; the probes are convolved to irradiance at the end of the frame."""
        vol = self.volume
        plan = irr_res.plan
        if self.params["cache_update"] == "closest-entry":
            self._merge_closest(irr_res, acc, lane_cap)
        else:
            self.radiance.merge(irr_res, n_max, lane_cap)
        est_d = self.est_dist.distance(vol, dist_res if dist_res is not None else irr_res)
        if plan.weight is not None:      # the static plan's weight is a multiplicity: m samples of one ray
            est_d = dataclasses.replace(est_d, count=mi.UInt32(dr.round(est_d.weight)))
        if self.device:
            slot_probe, slot_valid = self._slots(plan)
            self.pipeline.merge_slots(None, est_d, slot_probe, slot_valid, accumulator=acc, encoding=self.encoding)
            dr.scatter(self._updated_dev, mi.UInt32(1), slot_probe, slot_valid)
            self._slots_merged += dr.width(slot_probe)
            return
        self.pipeline.merge(None, est_d, plan.probe_ids, plan.counts, accumulator=acc, encoding=self.encoding)
        self._updated[plan.probe_ids[plan.counts > 0]] = True

    @staticmethod
    def _slots(plan: RayPlan):
        """(probe per slot, slot used) on the device: a masked plan's own, a host plan's uploaded."""
        if plan.is_masked:
            return plan.probe_ids, plan.slot_valid
        return (upload(np.asarray(plan.probe_ids, np.uint32), mi.UInt32),
                upload((plan.counts > 0).astype(np.uint32), mi.UInt32) != 0)

    def _merge_closest(self, res, acc, lane_cap=None) -> None:
        """``cache_update='closest-entry'``: each sample's radiance updates the irradiance texel its direction
        falls in (Algorithm 2's closest entry) with Algorithm 3's batch form through the encoding (the word
        stores the texel's mean radiance, not a cosine integral: biased where radiance varies over the
        hemisphere); with ``lane_cap`` the samples of changed octants merge with the dynamic N_max."""
        plan = res.plan
        w = mi.Float(1.0) + dr.zeros(mi.Float, plan.n_rays) if plan.weight is None else plan.weight
        parts = [(w, acc)]
        if lane_cap is not None:
            changed = lane_cap < int(self.params["n_max_static"])
            parts = [(dr.select(changed, 0.0, w), acc), (dr.select(changed, w, 0.0), self.acc_dynamic)]
        for wp, a in parts:
            sub = ProbeRayResults(res.radiance, res.distance, dataclasses.replace(plan, weight=wp))
            est = self.est_irr.irradiance(self.volume, sub)
            est = dataclasses.replace(est, count=mi.UInt32(dr.round(est.weight)))
            if self.device:
                self.pipeline.merge_slots(est, None, *self._slots(plan), accumulator=a, encoding=self.encoding)
            else:
                self.pipeline.merge(est, None, plan.probe_ids, plan.counts, accumulator=a, encoding=self.encoding)

    def _convolve_updated(self):
        """The per-texel convolution pass (:mod:`.radiance`) for the probes updated this frame. Device path:
        those probes packed on the device (at most the slots merged this frame), the device convolution, a
        slot merge; returns a device count."""
        if self.device:
            S = max(min(self.volume.n_probes, self._slots_merged), 1)
            self._slots_merged = 0
            ids, ok = compact(self._updated_dev != 0, S)
            n = dr.count(ok)
            if self.params["cache_update"] == "convolve":
                est = self.radiance.irradiance_estimate_device(ids)
                self.pipeline.merge_slots(est, None, ids, ok, accumulator=self._mean, encoding=self.encoding)
            self._updated_dev = dr.zeros(mi.UInt32, self.volume.n_probes)
            return n
        ids = np.flatnonzero(self._updated).astype(np.uint32)
        self._updated[:] = False
        if len(ids) and self.params["cache_update"] == "convolve":
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
