"""Reference unidirectional path tracer written in Dr.Jit (technique ``path``).

Estimator: BSDF sampling plus next-event estimation, combined by multiple
importance sampling (Veach 1997, Ch. 9; power or balance heuristic); Russian
roulette from ``rr_depth`` on with survival probability
``min(max(beta) * eta^2, 0.95)``; ``max_depth`` counts path vertices as in
Mitsuba (1: emitters seen directly, 2: direct illumination). Light sampling is
Mitsuba's emitter sampling (``lights=scene``, the default) or any light sampler of
:mod:`dyngi.lights` over the emitter triangles (``lights=uniform|power|lighttree|sll|vlc...``,
:class:`dyngi.lights.nee.LightNEE`; other emitters through Mitsuba). The walk is the
transport layer's (:func:`dyngi.transport.path_walk.walk`, from camera rays):
one symbolic ``@dr.syntax`` loop, so a frame is a handful of kernels and a
steady-state frame compiles nothing new.

The estimator is unbiased for ``max_depth = -1``; with a finite depth it
matches Mitsuba's ``path`` integrator with the same ``max_depth`` and
``rr_depth``, which is what the tests check (per-pixel z-test / relMSE).

Parameters
----------
spp : int = 1           samples per pixel per frame
max_depth : int = 12    maximum path length (-1: unbounded)
rr_depth : int = 5      depth at which Russian roulette starts
mis : str = 'power'     MIS heuristic: 'power' (beta = 2) or 'balance'
progressive : bool = True   accumulate across frames while nothing moves
indirect : bool = True  also return ``FrameResult.indirect``: the same paths
                        without the emission and the direct light at the
                        primary vertex (vertices >= 3; :func:`~dyngi.transport.path_walk.trace_paths_split`),
                        unclamped; costs < 1% (measured, cornell-static 160x120)
lights : str = 'scene'  NEE light sampler (``dyngi techniques`` lists the registered ones)
directions : str = 'bsdf'  indirect directions: the BSDF, or 'cdq' (:class:`dyngi.directions.walk.WalkDirections`)
leaf_scaling : bool = True  the octree thresholds of ``lights=vlc`` / ``directions=cdq``: ``nee-pt``'s rule
                        (:func:`dyngi.directions.octree.paper_thresholds`: the VLC paper's 4096 / 2048, Sec. 7,
                        from 8 x 4096 placed vertices per frame; below that scaled down, ours); false: the paper's
                        always. ``leaf_samples > 0`` raises the split threshold to it (collapse: half)
freeze : bool = False   replay the trace of a static frame with ``dr.freeze`` (Dr.Jit's frozen functions: the
                        kernels recorded once, no Python tracing per frame; bit-identical, ``tests/techniques/
                        test_path.py``); only with ``lights=scene``, ``directions=bsdf`` and no budget (our
                        choice: learning samplers change their state between frames). The recording is keyed
                        by the camera (a PyTree of its parameters), resolution, spp and a motion epoch that
                        advances on every non-static frame; at most two recordings are kept. Off by default
                        (our choice): Dr.Jit 1.5 aborted the process once while recording (a garbage
                        collection inside the frozen call, fresh clone, cold kernel cache; docs/harness.md)

Octrees: with ``lights=vlc`` (an octree-based light sampler) or ``directions=cdq`` each of the two strategies
has its own octree, as before, built here at the first frame for 2 placed vertices per path per spp (the
primary and the secondary hit, Sec. 7's count; the walk places one per NEE vertex), handed to the
strategy with ``share_octree`` and adapted here after the strategy's end of frame (what the strategy did when it
built its own).

Budgets: with ``Frame.ray_budget`` the frame's spp is the budget divided by
the rays per sample measured on the previous frame; with
``Frame.time_budget_ms`` it is the budget divided by the measured ms per sample.
On the first budgeted frame nothing is measured yet: a 1-spp pilot (own RNG
stream) measures rays and ms per sample, then the rest of the budget is traced
and both are averaged by sample count, so frame 0 honours the budget too.
"""
from __future__ import annotations

import math

from .. import directions as direction_samplers
from .. import lights as light_samplers
from .. import rays as ray_ledger
from ..directions.walk import WalkDirections
from ..backend import dr, mi
from ..lights.nee import LightNEE, octree_params, share_octrees
from ..lights.emitter_sampling import EmitterSampling
from ..sampling.rng import mix_seed
from ..transport.accumulate import ProgressiveMean
from ..transport.mis import mis_weight
from ..transport.path_walk import render_paths, render_paths_split, trace_paths, trace_paths_split
from .base import Frame, FrameResult, Param, StageTimer, Technique, register, to_image

_PILOT_STREAM = 0x9170
"""RNG stream of the 1-spp pilot on the first budgeted frame (see ``PathTechnique.step``)."""

# the walk lives in dyngi.transport.path_walk (issue 24); its camera-ray entry points stay importable here
__all__ = ["PathTechnique", "mis_weight", "render_paths", "render_paths_split", "trace_paths", "trace_paths_split"]


@register
class PathTechnique(Technique):
    """Reference path tracer (BSDF + NEE with MIS, Russian roulette); progressive on static frames."""

    name = "path"
    description = "reference path tracer in Dr.Jit: BSDF + NEE with MIS, Russian roulette, progressive"
    BUDGETS = ("equal-rays", "equal-time")
    HAS_INDIRECT = True   # FrameResult.indirect unless the parameter 'indirect' is off
    PARAMS = {
        "spp": Param(1, "samples per pixel per frame", min=1, max=1 << 16),
        "max_depth": Param(12, "maximum path depth (-1: unbounded)", min=-1),
        "rr_depth": Param(5, "Russian roulette start depth", min=1),
        "mis": Param("power", "MIS heuristic", choices=("power", "balance")),
        "progressive": Param(True, "accumulate over frames while the scene is static"),
        "indirect": Param(True, "also return the indirect-only image (same paths, vertices >= 3)"),
        "lights": Param("scene", "NEE light sampler: 'scene' (Mitsuba's emitter sampling) or a dyngi.lights "
                        "sampler over the emitter triangles", choices=("scene",) + light_samplers.names()),
        "directions": Param("bsdf", "indirect directions (dyngi.directions): the BSDF's own sampling, or 'cdq' "
                            "(CDQ/BSDF one-sample MIS mixture, learned per octree leaf)",
                            choices=direction_samplers.names()),
        **octree_params("2 per path per spp"),
        "freeze": Param(False, "replay static frames' trace with dr.freeze (lights=scene, directions=bsdf, no budget)"),
    }

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        kind = self.params["lights"]
        self.lights = EmitterSampling() if kind == "scene" else LightNEE(scene, kind)
        # the BSDF's own sampling is the walk's default (None): bit-identical to before
        self.directions = None if self.params["directions"] == "bsdf" else WalkDirections(
            scene, self.params["directions"])
        self.octrees = None            # the strategies' octrees (module docstring "Octrees"), built at frame 0
        self.accum = ProgressiveMean()   # running mean, and its indirect part (with the 'indirect' parameter)
        self._rays_per_sample = None   # measured on the previous frame
        self._ms_per_sample = None
        self._epoch = 0                # advances on every non-static frame (a key of the frozen trace)
        self._frozen = dr.freeze(self._trace_frozen, limit=2)

    def _trace_frozen(self, mi_scene, seed, camera, res, spp, epoch):
        """The trace of one frame as a frozen function's body (``mi_scene``: an input, so that its variables
        are traversed; ``seed``: a mixed ``mi.UInt32``; ``camera`` and the Python arguments key the
        recording)."""
        p = self.params
        return render_paths_split(mi_scene, camera, res, spp, seed, 0, p["max_depth"], p["rr_depth"], None,
                                  p["mis"] == "power", p["indirect"], None, lanes=True)   # counted by step()

    def _share_octrees(self, records: int) -> None:
        """Build each octree-based strategy's octree with ``nee-pt``'s threshold rule for ``records`` placed
        vertices per frame and hand it over (module docstring "Octrees"); ``self.octrees``: (light strategy's or
        None, direction strategy's or None)."""
        p = self.params
        self.octrees = share_octrees(self.lights, self.directions, records, p["leaf_samples"], p["leaf_scaling"])

    def frame_spp(self, frame: Frame) -> int:
        """spp for this frame: the parameter, or what fits the frame's ray/time budget."""
        spp = self.params["spp"]
        npix = frame.res[0] * frame.res[1]
        if frame.ray_budget is not None and self._rays_per_sample:
            spp = frame.ray_budget / (npix * self._rays_per_sample)
        elif frame.time_budget_ms is not None and self._ms_per_sample:
            spp = frame.time_budget_ms / self._ms_per_sample
        # rounded down: a budget is an upper bound (rounding to nearest overspent single frames by up to 26%)
        return int(max(1, min(4096, math.floor(spp + 1e-9))))

    def step(self, frame: Frame) -> FrameResult:
        p = self.params
        t = StageTimer()
        npix = frame.res[0] * frame.res[1]
        spp = self.frame_spp(frame)
        pilot = None
        split = p["indirect"]
        learned = isinstance(self.lights, LightNEE)
        if self.octrees is None:
            self._share_octrees(2 * npix * spp)
        if learned:     # the light sampler's per-frame hook (rebuild, cache construction)
            with t.stage("lights"):
                self.lights.begin_frame(self.scene, frame, 2 * npix * spp)
        if self.directions is not None:
            with t.stage("directions"):
                self.directions.begin_frame(self.scene, frame, 2 * npix * spp)
        if (frame.ray_budget is not None or frame.time_budget_ms is not None) and self._rays_per_sample is None:
            # -- first budgeted frame: nothing measured yet; a 1-spp pilot measures rays and ms per
            #    sample, and its sample counts towards the frame's budget --
            with t.stage("pilot"):
                pilot = render_paths_split(self.scene, frame.camera, frame.res, 1,
                                           mix_seed(frame.seed, 1, _PILOT_STREAM), frame.index, p["max_depth"],
                                           p["rr_depth"], self.lights, p["mis"] == "power", split,
                                           self.directions, stage="pilot")
                dr.eval(*pilot)
            t.add_rays("pilot", int(pilot[2][0]))
            self._rays_per_sample = t.rays["pilot"] / npix
            self._ms_per_sample = t.ms["pilot"]
            spp = self.frame_spp(frame) - 1
        with t.stage("trace"):
            if not frame.static:
                self._epoch += 1
            frozen = (p["freeze"] and frame.static and pilot is None and p["lights"] == "scene"
                      and self.directions is None and frame.ray_budget is None and frame.time_budget_ms is None)
            if spp > 0 and frozen:
                seed = dr.opaque(mi.UInt32, mix_seed(frame.seed, frame.index, 0))
                L, L_ind, rays = self._frozen(self.scene.mi_scene, seed, frame.camera, tuple(frame.res), spp,
                                                self._epoch)
                ray_ledger.add("trace", rays)    # a replayed frame runs no Python: its rays are counted here
            elif spp > 0:
                L, L_ind, rays = render_paths_split(self.scene, frame.camera, frame.res, spp, frame.seed,
                                                    frame.index, p["max_depth"], p["rr_depth"], self.lights,
                                                    p["mis"] == "power", split, self.directions, stage="trace")
                if pilot is not None:   # sample-weighted mean of pilot and trace
                    wp = dr.opaque(mi.Float, 1.0 / (spp + 1))
                    L = dr.fma(pilot[0] - L, wp, L)
                    if split:
                        L_ind = dr.fma(pilot[1] - L_ind, wp, L_ind)
            else:
                L, L_ind, rays = pilot[0], pilot[1], mi.UInt32(0)
            n_new = spp + (pilot is not None)
            # running mean weighted by samples (one kernel for any count)
            self.accum.add(L, L_ind if split else None, samples=n_new,
                           accumulate=p["progressive"] and frame.static)
            dr.eval(rays)
        t.add_rays("trace", int(rays[0]))
        if learned:
            with t.stage("lights adapt"):
                self.lights.end_frame()
                if self.octrees[0] is not None:     # the octree's owner adapts it (module docstring "Octrees")
                    self.octrees[0].adapt()
        if self.directions is not None:
            with t.stage("directions adapt"):
                self.directions.end_frame()
                if self.octrees[1] is not None:
                    self.octrees[1].adapt()
        if spp > 0:
            self._rays_per_sample = t.rays["trace"] / (npix * spp)
            self._ms_per_sample = t.ms["trace"] / spp
        img = to_image(self.accum.mean, frame.res)
        ind = to_image(self.accum.mean_ind, frame.res) if split else None
        stats = t.as_dict()
        stats["accumulated_frames"] = self.accum.frames
        stats["spp"] = n_new
        return FrameResult(image=img, indirect=ind, stats=stats)
