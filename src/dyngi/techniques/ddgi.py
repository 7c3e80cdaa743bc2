"""DDGI and its baselines: ``ddgi``, ``qddgi``, ``probes-reference``.

``ddgi`` -- Dynamic Diffuse Global Illumination (Majercik et al., JCGT 2019):
a grid of irradiance probes updated every frame by ``rays_per_probe`` rays
along a randomly rotated spherical-Fibonacci set, blended with hysteresis
(Sec. 3), with relocation/classification of Majercik et al. (JCGT 2021,
Sec. 5); the primary vertex is shaded with next-event estimation for direct
light plus ``albedo / pi * E`` from the probe query (Sec. 4) for indirect
light. Pieces live in :mod:`dyngi.probes` and can be replaced one by one.

``qddgi`` -- ADGI's Q-DDGI baseline (Datta et al. 2022, Sec. 5, Table 3):
DDGI with quantised caches (log-nonlinear R11G11B10 irradiance, RG16
visibility), hysteresis 0.94, 32 rays per probe and probes outside the
extended camera frustum not updated.

``probes-reference`` -- ADGI's reference (Sec. 5): fp32 caches of 32x32
texels recomputed from scratch every frame with a true average of
``rays_per_texel`` (64) rays per texel (cosine lobe for irradiance,
cosine-power lobe for the distance moments). Expensive by design. Its probes
are relocated and classified as ``ddgi``'s (32 fixed rays per probe and frame;
issue 22: without it, a grid whose layers start inside slabs kept them there).

Parameters (``ddgi``; the others change the defaults)
----------
probe_counts : str = ''         'nx,ny,nz' or 'n' (n^3); '' = the scene's default grid
rays_per_probe : int = 256
hysteresis : float = 0.97
irradiance_texels : int = 8     per side incl. border
distance_texels : int = 16
distance_power : float = 50
irradiance_gamma : float = 5    perceptual blending space (1: linear)
normal_bias, view_bias : float  in units of the smallest probe spacing
encoding : str = 'fp32'         'fp32' | 'qddgi' | 'adgi'
estimator : str = 'auto'        'matrix' (BLAS) | 'scatter' (Dr.Jit, bit-identical) | 'auto' (matrix on CPU)
hit_lookup : str = 'stochastic' multi-bounce read at probe-ray hits: one stochastically chosen texel
                                (same expectation as the filter) or 'filtered' (8 probes x 4 texels)
direct : str = 'sun'            which light NEE handles, the rest the probes (see :mod:`dyngi.probes.trace`)
update_offscreen : bool = True  False: only probes in the extended camera frustum are updated
relocate, classify : bool = True  relocation never moves a probe through a surface (dyngi.probes.states)
two_sided : str = 'enclosed'    the two-sided rule for probe rays hitting the back of a two-sided surface
                                (dyngi.probes.trace): 'enclosed' | 'front' | 'back'; every probe technique
                                (adgi, isddgi, DDGI+) takes it
jitter : bool = True            jitter primary rays inside the pixel (else pixel centres); True matches
                                the reference's box pixel filter, so edge aliasing is not counted as GI error
lights : str = 'scene'          light sampler of the NEE at the primary hit and at probe-ray hits ('scene':
                                Mitsuba's emitter sampling; :mod:`dyngi.techniques.probe_base`)
glossy : bool = False           primary hit adds Eq. 6's glossy probe lookup of DDGI Resampling (Majercik
                                et al. 2022; :mod:`dyngi.probes.primary`); False: DDGI's diffuse-only shading

Budgets (``dyngi compare --budget equal-rays|equal-time``): ``ddgi`` and
``qddgi`` spend what the frame's budget leaves after primary shading on
probe rays, i.e. they change ``rays_per_probe`` per frame (at least 8); see
:meth:`DDGITechnique._budget_rays_per_probe`.

Bias: the probes lag lighting changes (hysteresis), blur indirect light
spatially (probe spacing) and angularly (8x8 texels), and leak where the
Chebyshev test fails; the perceptual blend and the quantised encodings bias
values slightly low.
"""
from __future__ import annotations

import numpy as np

from ..probes import (DiffuseHitShader, HysteresisBlend, LobeDirections, ProbeStates, TrueAverage,
                      UniformSFDirections)
from ..probes.params import DDGI_SPECS, parse_probe_counts  # noqa: F401  (parse_probe_counts re-exported)
from ..probes.pipeline import UPDATE_STAGES, WARMUP_FRAME_BASE, ProbePipeline, probes_in_frustum  # noqa: F401
from ..probes.debug import render_probe_view  # noqa: F401  (re-exported: the probe view lives in probes)
from ..probes.primary import shade_primary  # noqa: F401  (re-exported: primary shading lives in probes)
from .base import Frame, FrameResult, Param, StageTimer, register
from .probe_base import COMMON_PARAMS, _ProbeTechniqueBase, params_from


@register
class DDGITechnique(_ProbeTechniqueBase):
    """DDGI (Majercik et al. 2019): hysteresis-blended irradiance probes, NEE direct + probe indirect."""

    name = "ddgi"
    BUDGETS = ("equal-rays", "equal-time")
    description = ("DDGI irradiance probes (Majercik et al. 2019): NEE direct + probe indirect at the primary "
                   "hit; indirect light is diffuse only (glossy surfaces get no indirect reflections) unless "
                   "glossy=true (Eq. 6 glossy probe lookup)")
    PARAMS = {**COMMON_PARAMS, **params_from(DDGI_SPECS)}

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        p = self.params
        self._setup_volume(p["irradiance_texels"], p["distance_texels"])
        planner = UniformSFDirections(p["rays_per_probe"])
        self.shader = DiffuseHitShader(p["direct"], lights=self.light_nee, lookup=p["hit_lookup"])
        self.blender = HysteresisBlend(p["hysteresis"], p["distance_power"], p["irradiance_gamma"],
                                       p["change_threshold"], p["brightness_threshold"], p["encoding"],
                                       p["estimator"])
        self.states = ProbeStates(p["relocate"], p["classify"])
        self.pipeline = ProbePipeline(self.volume, planner, self.shader, self.blender, self.states,
                                      self.query, reclassify_interval=p["reclassify_interval"],
                                      warmup=p["warmup"], update_offscreen=p["update_offscreen"])
        self._planners = {planner.n: planner}   # budgets change the rays per probe
        self._rpp = planner.n                   # this frame's rays per probe
        self._ms_per_probe_ray = None    # measured on the last frame, for equal-time budgets
        self._ms_fixed = 0.0
        self._shadow_per_probe_ray = 1.0      # measured (warm-up, then the last frame), for equal-ray budgets

    def step(self, frame: Frame) -> FrameResult:
        p = self.params
        t = StageTimer()
        self._lights_begin(frame, t)
        info = self.pipeline.step(self.scene, frame, t, before_update=lambda mask: self._plan_budget(frame, mask))
        rpp = self._rpp
        img, ind = self._primary(frame, t)
        stats = t.as_dict()
        stats.update({k: v for k, v in info.items() if k != "rays"})
        stats["active_probes"] = int(np.count_nonzero(self.volume.state.states))
        stats["rays_per_probe"] = rpp
        if rpp < GAMMA_BIAS_RAYS and p["irradiance_gamma"] > 1.0:
            stats["warnings"] = [f"{rpp} rays per probe with the perceptual blend (irradiance_gamma="
                                 f"{p['irradiance_gamma']:g}): biased low by ~3% on average, up to ~18% in texels "
                                 "facing a small bright source (docs/techniques/ddgi.md, gamma 5 blend bias); "
                                 "irradiance_gamma=1 is unbiased"]
        self._measure(stats, info["probes_traced"], rpp)
        return FrameResult(image=img, indirect=ind, stats=stats)

    def _plan_budget(self, frame: Frame, mask) -> None:
        """After the warm-up, before the update (:meth:`ProbePipeline.step
        <dyngi.probes.pipeline.ProbePipeline.step>`): learn the warm-up's shadow-ray rate, then set the
        pipeline's planner to this frame's rays per probe (:meth:`_budget_rays_per_probe`)."""
        self._learn_shadow_rate(self.pipeline.last_warmup_rays)
        self._rpp = self._budget_rays_per_probe(frame, mask)
        self.pipeline.planner = self._planner_for(self._rpp)

    # -- comparison budgets ---------------------------------------------------------
    def _planner_for(self, n: int) -> UniformSFDirections:
        """The rotated spherical-Fibonacci planner of ``n`` rays per probe (one per count, kept)."""
        if n not in self._planners:
            self._planners[n] = UniformSFDirections(n)
        return self._planners[n]

    def _budget_rays_per_probe(self, frame: Frame, mask) -> int:
        """Rays per probe this frame: the parameter, or what fits ``frame.ray_budget`` / ``time_budget_ms``.

        Equal rays: the budget minus the primary rays (camera + ``direct_samples``
        shadow rays per pixel, an upper bound that does not change from frame
        to frame) and, on frame 0, the warm-up's rays (charged to it) is shared by the probes that will be traced, each probe ray
        costing itself + the shadow rays per probe ray measured in the warm-up
        and then on the last frame (1 before any is measured). Equal time: the budget minus the
        previous frame's time outside the probe update, divided by the measured
        update time per probe ray. The first frame has nothing measured for
        equal time and runs the parameter (plus its warm-up).
        """
        p = self.params
        n = p["rays_per_probe"]
        up = self.pipeline
        probes = max(len(up.probes_to_trace(mask)), 1)
        if frame.ray_budget is not None:
            other = frame.res[0] * frame.res[1] * (1 + p["direct_samples"])      # camera + NEE rays
            other += len(up.probes_to_reclassify(frame.index, mask)) * up.classify_dirs.n
            other += sum(up.last_warmup_rays.values())       # the warm-up is charged to frame 0
            n = (frame.ray_budget - other) / ((1.0 + self._shadow_per_probe_ray) * probes)
        elif frame.time_budget_ms is not None and self._ms_per_probe_ray:
            n = (frame.time_budget_ms - self._ms_fixed) / (self._ms_per_probe_ray * probes)
        else:
            return n
        return budget_ladder_floor(n)

    def _learn_shadow_rate(self, rays: dict) -> None:
        """Keep the measured NEE shadow rays per probe ray, for equal-ray budgets. It changes only when
        it moves by more than 2%: a budget right at a ladder rung must not flip rungs (and recompile)
        from frame to frame on noise."""
        if rays.get("trace probes"):
            rate = rays.get("shade probes", 0) / rays["trace probes"]
            if abs(rate - self._shadow_per_probe_ray) > 0.02 * self._shadow_per_probe_ray:
                self._shadow_per_probe_ray = rate

    def _measure(self, stats: dict, probes: int, rpp: int) -> None:
        self._learn_shadow_rate(stats["rays"])
        ms = stats["ms"]
        update = sum(ms.get(k, 0.0) for k in UPDATE_STAGES)
        if probes and update > 0.0 and "warmup" not in ms:
            self._ms_per_probe_ray = update / (probes * rpp)
            self._ms_fixed = max(stats["total_ms"] - update, 0.0)


GAMMA_BIAS_RAYS = 32  # below this many rays per probe the gamma-5 blend's low bias exceeds 1% (measured)
MIN_BUDGET_RAYS = 8   # fewest rays per probe a budget can leave (below this the blend has holes)


def budget_ladder_floor(n: float) -> int:
    """The largest of 8, 10, 12, 14, 16, 20, ... (4 steps per octave, up to 2^14) that is <= ``n``.

    Budgeted rays per probe snap to this ladder: kernels that depend on the
    ray count (blend, state reductions) are compiled for a few counts only,
    not once per frame as the budget wobbles; at most 20% of the budget's
    probe rays are left unspent.
    """
    n = min(max(float(n), MIN_BUDGET_RAYS), float(1 << 14))
    octave = 1 << (int(n).bit_length() - 1)          # power of two <= n
    step = max(octave // 4, 1)
    return int(octave + step * int((n - octave) // step))
def _with_defaults(params: dict, defaults: dict) -> dict:
    return {k: (Param(defaults[k], v.doc, v.choices, v.min, v.max) if k in defaults else v)
            for k, v in params.items()}


@register
class QDDGITechnique(DDGITechnique):
    """Q-DDGI (ADGI Sec. 5): "original DDGI [28]" (Majercik et al. 2019) with quantised caches (Table 3),
    hysteresis 0.94, 32 rays/probe and frustum-culled updates (Sec. 4.4). The 2019 paper has no per-texel
    hysteresis drop on a large change, so by default it is off (``change_threshold=1e30``); ``ddgi``'s
    drop (``qddgi:change_threshold=0.25``) is a named option, a stronger baseline than the paper's."""

    name = "qddgi"
    description = "Q-DDGI baseline of ADGI: quantised caches, hysteresis 0.94, 32 rays/probe, frustum culling"
    PARAMS = _with_defaults(DDGITechnique.PARAMS, {"hysteresis": 0.94, "rays_per_probe": 32,
                                                   "encoding": "qddgi", "update_offscreen": False,
                                                   "change_threshold": 1e30})


@register
class ProbesReferenceTechnique(_ProbeTechniqueBase):
    """ADGI's probe reference: fp32 32x32 texels recomputed every frame from 64 rays per texel (true average)."""

    name = "probes-reference"
    description = "fp32 32x32-texel probes recomputed from scratch every frame, 64 rays per texel (ADGI Sec. 5)"
    PARAMS = {
        **COMMON_PARAMS,
        "texels": Param(32, "irradiance and distance texels per side incl. border", min=3, max=64),
        "rays_per_texel": Param(64, "rays per texel per frame for each of irradiance and distance", min=1),
        "distance_power": Param(50.0, "cosine power of the distance lobe", min=1.0),
        "bounces_from_previous": Param(True, "multi-bounce: hits read the previous frame's probes"),
        "relocate": Param(True, "move probes out of geometry (ddgi's relocation, from 32 fixed classification "
                          "rays per probe and frame; never through a surface)"),
        "classify": Param(True, "deactivate probes inside geometry or far from any surface (as ddgi)"),
    }

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        p = self.params
        self._setup_volume(p["texels"], p["texels"])
        self.irr_dirs = LobeDirections(p["texels"], p["rays_per_texel"], 1.0, stream=21)
        self.dist_dirs = LobeDirections(p["texels"], p["rays_per_texel"], p["distance_power"], stream=22)
        self.shader = DiffuseHitShader(p["direct"], lights=self.light_nee,
                                       lookup="filtered")   # the reference filters exactly
        self.blender = TrueAverage()
        # where the probes are is ddgi's decision (issue 22): a reference whose probes stay inside the slabs
        # a grid starts in is no reference for a volume that moves them out; every probe re-tests its state
        # from 32 fixed rays every frame, before its update, and every probe is traced
        self.states = ProbeStates(p["relocate"], p["classify"])
        self.pipeline = ProbePipeline(self.volume, self.irr_dirs, self.shader, self.blender, self.states,
                                      self.query if p["bounces_from_previous"] else None,
                                      distance_planner=self.dist_dirs, state_rays="fixed", trace_inactive=True,
                                      streams=(31, 32))

    def probe_rays_hint(self) -> int:
        p = self.params
        return 2 * p["texels"] ** 2 * p["rays_per_texel"]

    def step(self, frame: Frame) -> FrameResult:
        t = StageTimer()
        self._lights_begin(frame, t)
        self.pipeline.update(self.scene, frame.index, frame.seed, timer=t)
        img, ind = self._primary(frame, t)
        return FrameResult(image=img, indirect=ind, stats=t.as_dict())
