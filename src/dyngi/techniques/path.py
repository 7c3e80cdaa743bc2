"""Reference unidirectional path tracer written in Dr.Jit (technique ``path``).

Estimator: BSDF sampling plus next-event estimation, combined by multiple
importance sampling (Veach 1997, Ch. 9; power or balance heuristic); Russian
roulette from ``rr_depth`` on with survival probability
``min(max(beta) * eta^2, 0.95)``; ``max_depth`` counts path vertices as in
Mitsuba (1: emitters seen directly, 2: direct illumination). Light sampling is
a pluggable strategy (:mod:`dyngi.sampling.lights`). The whole path is one
symbolic ``@dr.syntax`` loop, so a frame is a handful of kernels and a
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
                        primary vertex (vertices >= 3; :func:`trace_paths_split`),
                        unclamped; costs < 1% (measured, cornell-static 160x120)

Budgets: with ``Frame.ray_budget`` the frame's spp is the budget divided by
the rays per sample measured on the previous frame; with
``Frame.time_budget_ms`` it is the budget divided by the measured ms per sample.
On the first budgeted frame nothing is measured yet: a 1-spp pilot (own RNG
stream) measures rays and ms per sample, then the rest of the budget is traced
and both are averaged by sample count, so frame 0 honours the budget too.
"""
from __future__ import annotations

import math

from ..backend import dr, mi
from ..sampling.lights import EmitterSampling, sample_traced
from ..sampling.rng import make_sampler, mix_seed
from .base import Frame, FrameResult, Param, StageTimer, Technique, register, to_image

_PILOT_STREAM = 0x9170
"""RNG stream of the 1-spp pilot on the first budgeted frame (see ``PathTechnique.step``)."""


def mis_weight(pdf_a, pdf_b, power: bool):
    """MIS weight of strategy a against b (power heuristic with beta=2, or balance)."""
    if power:
        a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
        w = a2 / (a2 + b2)
    else:
        w = pdf_a / (pdf_a + pdf_b)
    return dr.detach(dr.select(dr.isfinite(w), w, 0.0))


def trace_paths(scene, sampler, ray, active, max_depth: int, rr_depth: int,
                lights=None, power_heuristic: bool = True, indirect_only: bool = False):
    """Trace one path per lane; return (radiance, rays traced per lane, first-hit validity).

    ``indirect_only`` drops the emission seen at the first vertex and the direct
    light at it (emission reached by the first bounce and NEE at the first
    vertex), leaving light that reflected at least once before reaching the
    first vertex (path vertices >= 3): the "indirect" image the papers compare
    (same definition as the indirect reference: depth-D minus depth-2). Nothing
    is clamped: every term dropped is a non-negative sample contribution.
    """
    L, L_ind, n_rays, first_valid = trace_paths_split(scene, sampler, ray, active, max_depth, rr_depth, lights,
                                                      power_heuristic, split=indirect_only)
    return (L_ind if indirect_only else L), n_rays, first_valid


@dr.syntax
def trace_paths_split(scene, sampler, ray, active, max_depth: int, rr_depth: int,
                      lights=None, power_heuristic: bool = True, split: bool = True):
    """Trace one path per lane; return (radiance, indirect radiance, rays per lane, first-hit validity).

    The indirect part (with ``split``; else it stays 0) sums the same terms as
    the full radiance except the emission seen at the first vertex, the emission
    reached by its BSDF-sampled ray and its NEE sample: light that reflected at
    least once before the first vertex (vertices >= 3). Both come from the same
    paths, so ``full - indirect`` is exactly each sample's emission + direct
    light, and ``indirect <= full`` per sample.
    """
    lights = lights if lights is not None else EmitterSampling()
    max_depth = mi.UInt32(0xFFFFFFFF) if max_depth < 0 else mi.UInt32(max_depth)
    rr_depth_u = mi.UInt32(rr_depth)
    ctx = mi.BSDFContext()
    L = mi.Spectrum(0.0)
    L_ind = mi.Spectrum(0.0)
    beta = mi.Spectrum(1.0)
    depth = mi.UInt32(0)
    n_rays = mi.UInt32(0)
    prev_si = dr.zeros(mi.SurfaceInteraction3f)
    prev_pdf = mi.Float(1.0)
    prev_delta = mi.Bool(True)
    ray = mi.Ray3f(ray)
    active = mi.Bool(active)
    first_valid = mi.Bool(False)

    while dr.hint(active, label="dyngi_path"):
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=(depth == 0), active=active)
        n_rays += 1
        first_valid |= (depth == 0) & si.is_valid()

        # -- emission hit by the BSDF-sampled ray, MIS against NEE --
        ds = mi.DirectionSample3f(scene, si, prev_si)
        em_pdf = mi.Float(0.0)
        if ~prev_delta:
            em_pdf = lights.pdf(scene, prev_si, ds, active & ~prev_delta)
        w_bsdf = mis_weight(prev_pdf, em_pdf, power_heuristic)
        Le = ds.emitter.eval(si, active & (prev_pdf > 0))
        L = dr.fma(beta, Le * w_bsdf, L)
        if split:    # not the first vertex's emission (depth 0) nor the first bounce's (depth 1)
            L_ind[depth >= 2] = dr.fma(beta, Le * w_bsdf, L_ind)

        active_next = active & si.is_valid() & (depth + 1 < max_depth)
        bsdf = si.bsdf(ray)

        # -- next-event estimation --
        active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds_em, em_weight, active_em = sample_traced(lights, scene, si, sampler.next_2d(), active_em)
        n_rays += mi.UInt32(active_em)
        wo = si.to_local(ds_em.d)
        bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo, active_em)
        w_em = dr.select(ds_em.delta, 1.0, mis_weight(ds_em.pdf, bsdf_pdf, power_heuristic))
        L[active_em] = dr.fma(beta, bsdf_val * em_weight * w_em, L)
        if split:    # not NEE at the first vertex (direct light)
            L_ind[active_em & (depth >= 1)] = dr.fma(beta, bsdf_val * em_weight * w_em, L_ind)

        # -- BSDF sampling --
        bs, bsdf_weight = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), active_next)
        ray = si.spawn_ray(si.to_world(bs.wo))
        beta *= bsdf_weight
        prev_si = dr.detach(si, True)
        prev_pdf = bs.pdf
        prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        depth[si.is_valid()] += 1

        # -- Russian roulette --
        beta_max = dr.max(beta)
        rr_active = depth >= rr_depth_u
        rr_prob = dr.minimum(beta_max * dr.square(bs.eta), 0.95)
        rr_continue = sampler.next_1d() < rr_prob
        beta[rr_active] *= dr.rcp(rr_prob)
        active = active_next & (~rr_active | rr_continue) & (beta_max != 0.0) & (bs.pdf > 0.0)

    return L, L_ind, n_rays, first_valid


def render_paths(scene, camera, res, spp: int, seed: int, frame_index: int, max_depth: int,
                 rr_depth: int, lights=None, power_heuristic=True, indirect_only=False):
    """Render ``spp`` paths per pixel; return (mean colour per pixel, total rays as a Dr.Jit UInt32 sum).

    ``indirect_only``: the indirect part only (see :func:`trace_paths`)."""
    L, L_ind, rays = render_paths_split(scene, camera, res, spp, seed, frame_index, max_depth, rr_depth, lights,
                                        power_heuristic, split=indirect_only)
    return (L_ind if indirect_only else L), rays


def render_paths_split(scene, camera, res, spp: int, seed: int, frame_index: int, max_depth: int,
                       rr_depth: int, lights=None, power_heuristic=True, split: bool = True):
    """Render ``spp`` paths per pixel; return (mean colour, mean indirect colour, total rays as a UInt32 sum).

    The indirect image comes from the same paths (:func:`trace_paths_split`);
    without ``split`` it is 0 and costs nothing."""
    w, h = res
    n = w * h * spp
    sampler = make_sampler(n, seed, frame_index)
    idx = dr.arange(mi.UInt32, n)
    pix = idx // dr.opaque(mi.UInt32, spp) if spp > 1 else idx
    ray = camera.sample_rays(res, pix, sampler.next_2d())
    L, L_ind, n_rays, _ = trace_paths_split(scene.mi_scene if hasattr(scene, "mi_scene") else scene, sampler,
                                            ray, mi.Bool(True), max_depth, rr_depth, lights, power_heuristic, split)
    if split:
        dr.eval(L, L_ind, n_rays)  # one kernel for the whole path loop; outputs evaluated together
    else:
        dr.eval(L, n_rays)
    if spp > 1:
        inv = dr.opaque(mi.Float, 1.0 / spp)
        L = dr.block_reduce(dr.ReduceOp.Add, L, spp) * inv
        if split:
            L_ind = dr.block_reduce(dr.ReduceOp.Add, L_ind, spp) * inv
    return L, L_ind, dr.sum(n_rays)


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
    }

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        self.lights = EmitterSampling()
        self.accum = None      # mi.Color3f running mean
        self.accum_ind = None  # its indirect part (with the 'indirect' parameter)
        self.n_accum = 0
        self.n_samples = 0
        self._rays_per_sample = None   # measured on the previous frame
        self._ms_per_sample = None

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
        if (frame.ray_budget is not None or frame.time_budget_ms is not None) and self._rays_per_sample is None:
            # -- first budgeted frame: nothing measured yet; a 1-spp pilot measures rays and ms per
            #    sample, and its sample counts towards the frame's budget --
            with t.stage("pilot"):
                pilot = render_paths_split(self.scene, frame.camera, frame.res, 1,
                                           mix_seed(frame.seed, 1, _PILOT_STREAM), frame.index, p["max_depth"],
                                           p["rr_depth"], self.lights, p["mis"] == "power", split)
                dr.eval(*pilot)
            t.add_rays("pilot", int(pilot[2][0]))
            self._rays_per_sample = t.rays["pilot"] / npix
            self._ms_per_sample = t.ms["pilot"]
            spp = self.frame_spp(frame) - 1
        with t.stage("trace"):
            if spp > 0:
                L, L_ind, rays = render_paths_split(self.scene, frame.camera, frame.res, spp, frame.seed,
                                                    frame.index, p["max_depth"], p["rr_depth"], self.lights,
                                                    p["mis"] == "power", split)
                if pilot is not None:   # sample-weighted mean of pilot and trace
                    wp = dr.opaque(mi.Float, 1.0 / (spp + 1))
                    L = dr.fma(pilot[0] - L, wp, L)
                    if split:
                        L_ind = dr.fma(pilot[1] - L_ind, wp, L_ind)
            else:
                L, L_ind, rays = pilot[0], pilot[1], mi.UInt32(0)
            n_new = spp + (pilot is not None)
            if p["progressive"] and frame.static and self.accum is not None \
                    and dr.width(self.accum) == dr.width(L):
                # running mean weighted by samples, with an opaque weight: one kernel for any count
                a = dr.opaque(mi.Float, n_new / (self.n_samples + n_new))
                self.accum = dr.fma(L - self.accum, a, self.accum)
                if split:
                    self.accum_ind = dr.fma(L_ind - self.accum_ind, a, self.accum_ind)
                self.n_accum += 1
                self.n_samples += n_new
            else:
                self.accum, self.n_accum, self.n_samples = L, 1, n_new
                self.accum_ind = L_ind if split else None
            if split:
                dr.eval(self.accum, self.accum_ind, rays)
            else:
                dr.eval(self.accum, rays)
        t.add_rays("trace", int(rays[0]))
        if spp > 0:
            self._rays_per_sample = t.rays["trace"] / (npix * spp)
            self._ms_per_sample = t.ms["trace"] / spp
        img = to_image(self.accum, frame.res)
        ind = to_image(self.accum_ind, frame.res) if split else None
        stats = t.as_dict()
        stats["accumulated_frames"] = self.n_accum
        stats["spp"] = n_new
        return FrameResult(image=img, indirect=ind, stats=stats)
