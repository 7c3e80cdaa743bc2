"""Adaptive Dynamic GI (Datta et al. 2022) -- Metropolis-guided probe updates (technique ``adgi``).

Estimates DDGI's irradiance/visibility probes, but spends the ray budget where
a guide over probe position x direction says rays matter, sampled by
persistent Metropolis chains (:mod:`dyngi.sampling.metropolis`); each sample
updates the probe texels it lands in with Algorithm 3's moving average
(:mod:`.moving_average`). The probe pipeline (:mod:`dyngi.probes.pipeline`) runs the frame: the
frame-0 warm-up (``ddgi``'s single-pass updates; Q-DDGI's by default -- ``warmup`` = 8 updates x ``warmup_rays`` =
32 rays on the probes ``qddgi`` warms -- its rays counted in frame 0's stats (``rays['warmup']``) and charged to
frame 0's budget; ``warmup_rays=256`` is the former ADGI warm-up, ours), then ADGI's passes -- its multi-pass planner
(:class:`.passes.ADGIPasses`: relocation when due, the pilot rays and heuristics, the static and dynamic
chains of :class:`.planner.ADGIChainPlanner`, the budget between them) and its accumulator
(:class:`.accumulate.ADGIAccumulator`: Algorithm 3 into the radiance layer and the visibility texels, the
outer count cap, the convolution to irradiance); the pipeline traces every pass. Primary shading is ``ddgi``'s
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
  Each chain marks at most one proxy octant per frame, its last sample's (Sec. 4.9: "the first invocation
  to update the octant marks it"; the stage's fixed bound, ``dynamic_chains`` octants); every marked octant
  traces, for each of its probes in ``V_in``, one ray through each irradiance-texel centre of the octant
  (``dynamic_rays`` = 0, the paper's "passing through the center of a texel"; an octant of the 8x8 map
  holds 3-6 of the 36 centres, :func:`.planner.octant_texel_centres`) and one unshaded distance ray through
  each distance-texel centre of the opposite octant (21-28 of the 196 at 16x16: the texels the ``-w`` rays
  of the octant reach). A centre ray's radiance is one sample of its radiance texel's mean (the midpoint
  rule; tests/techniques/adgi/test_dynamic_rays.py checks it against a stratified estimate of the texels),
  and the convolution weights that texel by its solid angle x cosine, as every radiance texel; a distance
  ray is one sample of its visibility texel. ``dynamic_rays`` = 16 / 64 / 256: the former rule (ours), that
  many centres of an equal-area stratification of the octant, each with its ``-w`` ray.
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
  ``N <- min(N, 16)`` (Sec. 4.8), applied lazily by the next merge of each texel
  (:class:`.sparse.LazyCountCap`). Merges are sparse (:mod:`.sparse`): a pass's (probe, texel) keys
  compacted and reduced, Algorithm 3 only on the texels that received samples. The static guide's mip and
  the dynamic proxy table are read per chain sample (:meth:`.planner.ADGIChainPlanner.guide_at`,
  :meth:`~.planner.ADGIChainPlanner.proxy_value`): a frame's work follows the chains and the view
  (tests/techniques/adgi/test_view_work.py); the heuristics' tables (P x 8) still span the grid.

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
classification rays (:meth:`.passes.ADGIPasses._states_pass`).

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
warmup, warmup_rays : int = 8, 32 Q-DDGI's warm-up (ours: the paper describes none), charged to frame 0
cache_update : str = 'convolve'   ours; the paper's Algorithm 2 is 'closest-entry' (marked, paper value)
v_in_clip, v_in_fc, v_out_clip, v_out_fc = 1.2, 0.75, 1.4, 0.5   Fig. 6b's labels (the pairing ours; marked)

Marked settings (``Param(ours=True)``, issue 40; :mod:`dyngi.experiments.claims` builds the paper-literal and
ablation rows from them): with a paper value ``change_cap`` (paper: false), ``cache_update`` (paper:
'closest-entry') and the four Fig. 6b cuts (paper: their defaults); without one ``iterations``, ``burn_in``,
``position_step``, ``camera_threshold``, ``theta``, ``radiance_texels``, ``warmup``,
``warmup_rays``, ``relocate``, ``classify``, ``cull_unused``, ``dynamic_share``, ``reclassify_interval``,
``guide_mip``.
impl : str = 'auto'               'device' (no host read in a steady update) | 'host' | 'auto' (device on a
                                  GPU, host on the CPU: measured faster there)

Bias: the moving average lags dynamic changes (Sec. 3.5); texels no chain
visits keep old values; quantised irradiance storage rounds low.
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...errors import DyngiError
from ...probes import DiffuseHitShader, HysteresisBlend, ProbeStates
from ...probes.estimator import is_cpu_backend
from ...probes.encoding import get_encoding
from ...probes.lookup import diffuse_radiance
from ...probes.pipeline import ProbePipeline
from ...probes.trace import HIT_LOOKUPS
from ...sampling.diffuse import diffuse_albedo
from ...sampling.metropolis import ADGI_DIRECTION_STEP
from ..base import Frame, FrameResult, Param, StageTimer, register
from ..probe_base import COMMON_PARAMS, _ProbeTechniqueBase
from .accumulate import ADGIAccumulator
from .heuristics import OCTANTS, V_IN_CLIP, V_IN_FC, V_OUT_CLIP, V_OUT_FC
from .moving_average import N_MAX_DYNAMIC, N_MAX_STATIC
from .passes import ADGIPasses

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


def allocated_bytes(objs) -> int:
    """Bytes allocated by ``objs``: NumPy arrays (``nbytes``), Dr.Jit arrays (the ``nbytes`` of their
    evaluated contents, every component of a vector) and the array fields of a dataclass or plain object
    (one level); ``None`` counts 0 and each array once."""
    seen: set = set()

    def one(x) -> int:
        if x is None or id(x) in seen:
            return 0
        seen.add(id(x))
        if isinstance(x, np.ndarray):
            return int(x.nbytes)
        if dr.is_array_v(x):
            return int(np.asarray(x).nbytes)
        if hasattr(x, "__dict__"):
            return sum(one(v) for v in vars(x).values() if isinstance(v, np.ndarray) or dr.is_array_v(v))
        return 0
    return sum(one(x) for x in objs)


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
        "iterations": Param(20, "Metropolis iterations per chain per frame (M; ours: Algorithm 1 takes M as an "
                            "input, the paper gives no value)", min=2, max=256, ours=True),
        "burn_in": Param(4, "burn-in iterations per frame (K < M); the others each yield a sample (ours: the paper "
                         "rejects 'a few' initial samples, no value)", min=0, max=255, ours=True),
        "position_step": Param(0.5, "static chains' position step, in probe spacings (ours: Sec. 4.8 says "
                               "'proportional to the size of a voxel', no factor)", min=1e-3, max=64.0, ours=True),
        "direction_step": Param(ADGI_DIRECTION_STEP, "static chains' direction step (radians)", min=1e-3,
                                max=3.0),
        "dynamic_position_scale": Param(3.0, "dynamic/static position step ratio (Sec. 4.9)", min=0.1),
        "dynamic_direction_scale": Param(6.0, "dynamic/static direction step ratio (Sec. 4.9)", min=0.1),
        "dynamic_rays": Param(0, "rays per probe octant of a sampled proxy: 0, the paper's (Sec. 4.9), one ray "
                              "per irradiance-texel centre of the octant (3-6 at 8x8) and one distance ray per "
                              "distance-texel centre of the opposite octant (21-28 at 16x16); 16, 64, 256: that "
                              "many equal-area strata with their -w rays (ours, the former default 64)",
                              choices=(0, 16, 64, 256)),
        "camera_threshold": Param(0.0, "k of Eq. 10 in world units (0: the 0.9 quantile of the camera "
                                  "distances of the probes in view; ours: the paper leaves k to the user, no "
                                  "value)", min=0.0, ours=True),
        "beta": Param(5.0, "range of the radiance heuristic (Eq. 12)", min=1e-3),
        "mu": Param(2.0, "weight of the radiance change in f_d (Eq. 20)", min=0.0),
        "theta": Param(16.0, "temporal trigger decay in frames (Eq. 14; ours: the paper names theta, gives no "
                       "value)", min=1.0, ours=True),
        "n_max_static": Param(N_MAX_STATIC, "N_max of static updates (Table 3)", min=1, max=63),
        "n_max_dynamic": Param(N_MAX_DYNAMIC, "N_max of dynamic updates (Table 3)", min=1, max=63),
        "outer_count_cap": Param(16, "count cap of probes in V_out - V_in (Sec. 4.8)", min=1, max=63),
        "pilot_updates": Param(True, "pilot rays update the caches on alternate frames (Sec. 4.4)"),
        "radiance_texels": Param(8, "radiance texels per side incl. border that samples are binned into "
                                 "(convolved to irradiance each frame; 8: the irradiance map's, Algorithm 2's "
                                 "closest entry; ours: the radiance layer is ours, see cache_update; no paper "
                                 "value)", min=4, max=64, ours=True),
        "irradiance_texels": Param(8, "irradiance texels per side incl. the 1-texel border", min=4, max=64),
        "distance_texels": Param(16, "distance texels per side incl. the 1-texel border", min=4, max=64),
        "distance_power": Param(50.0, "cosine power of the warm-up's distance blend", min=1.0),
        "encoding": Param("adgi", "texel storage encoding", choices=("fp32", "qddgi", "adgi")),
        "hit_lookup": Param("stochastic", "how probe-ray hits read the previous probes (multi-bounce)",
                            choices=HIT_LOOKUPS),
        "warmup": Param(8, "ddgi-style probe updates on the first frame (no hysteresis), Q-DDGI's warm-up (ours: "
                        "the paper describes no warm-up; charged to frame 0's rays and budget)", min=0, max=256,
                        ours=True),
        "warmup_rays": Param(32, "rays per probe of each warm-up update: 32, Q-DDGI's (qddgi's warm-up: 8 updates "
                             "x 32 rays on the same probes, charged to frame 0); 256 the former ADGI warm-up "
                             "(ours: the paper describes no warm-up)", min=8, max=1 << 14, ours=True),
        "relocate": Param(True, "move probes out of geometry (warm-up, then every reclassify_interval frames; "
                          "ours, ddgi's: the paper is silent)", ours=True),
        "classify": Param(True, "deactivate probes inside geometry or far from surfaces (as relocate; ours, "
                          "ddgi's: the paper is silent)", ours=True),
        "cull_unused": Param(True, "Sec. 4.9: the static and dynamic stages skip probes that no pixel's probe "
                             "cage used on the previous frame's primary pass (the paper culls in D; in S too is "
                             "ours, no paper setting for it)", ours=True),
        "cache_update": Param("convolve", "how a radiance sample updates the irradiance texels: 'convolve' (the "
                              "radiance layer, convolved each frame) or 'closest-entry' (Algorithm 2 literally: the "
                              "irradiance texel the sample falls in, Algorithm 3 in the encoded word; biased). "
                              "Ours: 'convolve'; the paper's: 'closest-entry'",
                              choices=("convolve", "closest-entry"), ours=True, paper="closest-entry"),
        "change_cap": Param(True, "static samples in octants with f_d > 0 merge into the radiance texels with "
                            "the dynamic N_max (ours: the paper snaps such samples to texel centres but has no cap "
                            "on their count; its value: false, no cap)", ours=True, paper=False),
        "dynamic_share": Param(0.5, "share of an equal-ray/equal-time budget (after primary and pilot rays) "
                               "reserved for the dynamic stage when some octant has f_d > 0 (ours: the paper runs "
                               "fixed chain counts, no budget)", min=0.0, max=1.0, ours=True),
        "reclassify_interval": Param(8, "frames between ddgi's relocation/classification passes after the "
                                     "warm-up (fixed rays; 0: warm-up only; ours, ddgi's: the paper is silent)",
                                     min=0, ours=True),
        "guide_mip": Param(1, "mip level of the irradiance feedback g in the static guide (Sec. 3.2/4.8; "
                           "0: the texel itself; ours: the paper says 'a higher mip-level', not which)",
                           min=0, max=3, ours=True),
        "v_in_clip": Param(V_IN_CLIP, "V_in's clip-space bound |clip xy| (Fig. 6b's label 1.2; ours: the pairing "
                           "of Fig. 6b's labels with the two volumes is our reading of the figure)", min=0.0,
                           ours=True, paper=V_IN_CLIP),
        "v_in_fc": Param(V_IN_FC, "V_in's camera falloff cut f_c >= (Fig. 6b's label 0.75; ours: the pairing is "
                         "our reading of the figure)", min=0.0, max=1.0, ours=True, paper=V_IN_FC),
        "v_out_clip": Param(V_OUT_CLIP, "V_out's clip-space bound |clip xy| (Fig. 6b's label 1.4; ours: the "
                            "pairing is our reading of the figure)", min=0.0, ours=True, paper=V_OUT_CLIP),
        "v_out_fc": Param(V_OUT_FC, "V_out's camera falloff cut f_c >= (Fig. 6b's label 0.5; ours: the pairing is "
                          "our reading of the figure)", min=0.0, max=1.0, ours=True, paper=V_OUT_FC),
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
        self.volume.add_radiance_layer(p["radiance_texels"])     # the radiance layer: the volume's third atlas
        self.counts = tuple(int(c) for c in self.grid.counts)
        self.shader = PilotShader(p["direct"], lights=self.light_nee, lookup=p["hit_lookup"])
        self.encoding = get_encoding(p["encoding"])     # Table 3: visibility rounds to nearest
        # -- the device path (impl): masked plans, counts on the device, read after the frame's image --
        self.device = p["impl"] == "device" or (p["impl"] == "auto" and not is_cpu_backend())
        # -- the pipeline's multi-pass planner (P, S, D) and accumulator (Algorithm 3, the radiance layer) --
        self.passes = ADGIPasses(self.volume, p, self.shader, self.device)
        self.accumulator = ADGIAccumulator(self.volume, p, self.encoding, self.device)
        # -- ddgi's warm-up pieces (hysteresis blend, shared SF set, relocation/classification): the pipeline's
        # single-pass updates before the first frame, through the same encoding --
        self.blender = HysteresisBlend(0.0, p["distance_power"], 1.0, 0.25, 1e30, p["encoding"], "auto")
        self.blender.encoding = self.encoding
        self.pipeline = ProbePipeline(self.volume, self.passes,
                                      DiffuseHitShader(p["direct"], lights=self.light_nee, lookup=p["hit_lookup"]),
                                      self.blender, ProbeStates(p["relocate"], p["classify"]), self.query,
                                      reclassify_interval=0, warmup=p["warmup"], accumulator=self.accumulator)

    def memory_per_probe(self) -> dict:
        """Bytes per probe by part, *measured*: the sum of the ``nbytes`` of the per-probe arrays the technique
        holds (host NumPy and device Dr.Jit alike; the device mirrors of the host atlases count apart) over the
        probe count (:func:`allocated_bytes`). Parts: the volume's (:meth:`ProbeVolume.memory_parts
        <dyngi.probes.volume.ProbeVolume.memory_parts>`) -- ``irradiance`` / ``visibility`` (the atlases and
        texel counts, host and device), ``probe_state`` (offsets, states, update counts, positions; with the
        pipeline's update history), ``radiance_layer`` (ours: the volume's radiance atlas and counts, device
        only, :mod:`.radiance`) -- and ``heuristics`` (the per-octant tables of
        :class:`.heuristics.HeuristicState`, the 6-10-10 word, the culling mask), ``merge_tables`` (the sparse
        merges' key owners and the lazy count cap's stamps, :mod:`.sparse`), ``total``. Beside them,
        not measured: ``table3`` -- what the paper's Table 3 words would take (8x8 + 16x16 32-bit words and
        the 6-10-10 word per octant, 1312 B): our texels are fp32 values quantised through the encoding, not
        packed words, so the measured figure is larger (docs/techniques/adgi.md)."""
        vol = self.volume
        P = vol.n_probes
        parts = vol.memory_parts()
        parts["probe_state"].append(self.pipeline._history)
        parts["heuristics"] = [self.passes.hstate, getattr(self.passes, "lut", None), self.passes.used]
        acc = self.accumulator
        # the sparse merges' per-key tables (.sparse): owners of the (probe, texel) keys, the lazy cap's stamps
        parts["merge_tables"] = [acc.radiance.keys.owner, acc.dist_keys.owner, acc.cap_rad, acc.cap_dist,
                                 self.passes.chains._entry_keys.owner]
        parts["radiance_layer"] = parts.pop("radiance_layer")          # the report's order: the layer last
        out = {k: allocated_bytes(v) / P for k, v in parts.items()}
        out["total"] = sum(out.values())
        Ti, Td = vol.irradiance_texels, vol.distance_texels
        out["table3"] = (Ti * Ti + Td * Td) * 4 + OCTANTS * 4
        return out

    # the passes' chains and heuristics, readable here (the viewer draws the static chains; tests read the
    # heuristics); the radiance layer is the volume's (``volume.device.radiance_count``, ``volume.radiance_host()``)
    @property
    def static_state(self):
        return self.passes.chains.static_state

    @property
    def hstate(self):
        return self.passes.hstate

    def guide_feedback(self):
        """The static guide's irradiance feedback (:meth:`.planner.ADGIChainPlanner.guide_feedback`)."""
        return self.passes.chains.guide_feedback()

    def k_for(self, frame: Frame) -> float:
        """Eq. 10's k on ``frame`` (:meth:`.passes.ADGIPasses.k_for`)."""
        return self.passes.k_for(frame)

    # -- one frame ------------------------------------------------------------------------------
    def step(self, frame: Frame) -> FrameResult:
        t = StageTimer()
        stats = self.update_probes(frame, t)
        img, ind = self._primary(frame, t)
        return self.finish_frame(t, stats, img, ind)

    def update_probes(self, frame: Frame, t: StageTimer) -> dict:
        """One frame's probe update: the pipeline's step (the warm-up on the first frame, then the passes of
        :class:`.passes.ADGIPasses` merged by :class:`.accumulate.ADGIAccumulator`: relocation when due, P, S,
        D); returns its stats (device values on the device path). On the device path (``impl``) a frame
        without the warm-up or a relocation/classification pass reads nothing back to the host here (tests/
        techniques/adgi/test_device_path.py); the counts are read by :meth:`finish_frame`, after the image."""
        self._lights_begin(frame, t)        # lights=: the sampler's per-frame hook before the first probe ray
        self.passes.scene = self.scene      # D's distance rays trace apart from the pipeline's passes
        self.accumulator.frame = frame.index     # the lazy outer count cap's stamps (.sparse.LazyCountCap)
        return self.pipeline.step(self.scene, frame, t)

    def finish_frame(self, t: StageTimer, stats: dict, img, ind) -> FrameResult:
        """The frame's result after :meth:`update_probes` and the primary pass: the timer's stats with the
        update's (device counts read here, after the image: no extra wait), the equal-time measurements."""
        out = t.as_dict()
        out.update(stats)
        if self.device:
            self.passes.finish_frame(out)
        self.passes.measure_time(out)
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
        self.passes.used = used
        return out
