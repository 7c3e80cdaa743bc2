"""Metropolis instant radiosity (Segovia et al. 2007) as Hedman et al. 2017 run it (Sec. 5.1): ``mir``.

"As the visibility and the materials are not complicated in our test scenes, we
instead generate these paths by resampling paths from our path tracer. We use a
resampling rate of 256:1." Per frame, independently (no temporal coherence):

1. ``resampling_rate * I`` camera paths of our path tracer through random pixel
   positions: primary hit x (diffuse albedo a_x), cosine-sampled y, and one path
   with NEE from y (:func:`dyngi.vpl.radiosity.estimate_radiosity`, one sample,
   ``max_depth - 1`` vertices from y): the path's radiance ``L_j`` leaving y;
2. each path's image contribution ``c_j = lum(a_x * L_j)`` (its estimate f/p for the pixel
   it was traced for: cosine sampling cancels cos/pdf);
3. I paths resampled with replacement in proportion to ``c_j`` (importance resampling:
   the VPLs follow the power they bring to the image, Segovia et al.);
4. VPL ``i`` at y_i emits ``L_i``; its shading weight is the resampling estimator's
   ``flux_i = L_i * mean(c) / (I * c_i * q(y_i))`` where ``q`` is the area density of the
   raw hits y (before resampling), estimated by kNN among them (Eq. 7, k of Eq. 8 for
   their count). Our choice (the paper gives no formula): SIR weights ``mean(c) / c_i`` in
   path space, mapped to area measure through the raw hits' kNN density.

Random numbers are per frame (``(seed, frame)``): the VPL set is redrawn every frame.

All on the device, no host round trip (issue 29): the camera paths keep every lane (an invalid hit
weighs 0), the path radiance comes from the shared path walk
(:func:`dyngi.transport.path_walk.trace_paths_split`, one sample per hit, the emission at y
subtracted as :func:`dyngi.vpl.radiosity.estimate_radiosity` does), ``q`` from the device k-NN
(:class:`dyngi.vpl.density.KNNGrid` over all valid hits, queried only at the I drawn ones, where
``q`` is used; k of Eq. 8 for the number of camera paths, a static count: our choice, it avoids reading
the valid count back) and the resampling from an inverse CDF
(:func:`dyngi.vpl.smc.resample_with_replacement_device`). The frame's only host reads are the shading's
image and stats.

Extra parameter: ``resampling_rate`` (256, the paper's); ``lights=`` chooses the light sampler of the paths'
NEE and of the direct light's (:mod:`~dyngi.techniques.vpl_base`). Bias: the kNN density ``q`` and clamping.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..color import luminance
from ..rays import intersect
from ..sampling.rng import make_sampler
from ..transport.path_walk import trace_paths_split
from ..vpl.density import MIN_RADIUS, KNNGrid, knn_k
from ..vpl.points import raw_candidates_device
from ..vpl.radiosity import RAY_OFFSET
from ..vpl.smc import resample_with_replacement_device
from .base import Frame, Param, StageTimer, register
from .vpl_base import COMMON_PARAMS, VPLTechnique


def path_radiance_device(mscene, pos, nrm, sampler, active, max_depth: int, lights=None):
    """One path-tracer sample of the radiance leaving each y toward -n, without y's own emission
    (the device twin of :func:`dyngi.vpl.radiosity.estimate_radiosity` with one sample and an ordinary
    sampler); returns (L, rays per lane)."""
    eps = dr.opaque(mi.Float, RAY_OFFSET) * (1.0 + dr.max(dr.abs(pos)))
    ray = mi.Ray3f(pos + nrm * eps, -nrm)
    L, _, n_rays, _ = trace_paths_split(mscene, sampler, ray, active, int(max_depth), int(max_depth) + 1, lights,
                                        True, split=False, stage="paths")
    si = intersect(mscene, ray, mi.RayFlags.All, False, active, stage="paths")
    L = L - mi.Color3f(si.emitter(mscene).eval(si, active))
    L = dr.select(active & dr.isfinite(dr.max(L)), dr.maximum(L, 0.0), 0.0)
    return L, n_rays


@register
class MetropolisIR(VPLTechnique):
    name = "mir"
    description = "Metropolis instant radiosity as in Hedman et al. 2017: path-tracer paths resampled 256:1 per frame"
    PARAMS = {**COMMON_PARAMS,
              "resampling_rate": Param(256, "camera paths per VPL, resampled by image contribution", min=1,
                                       max=4096)}

    def walk_lanes(self) -> int:
        return int(self.params["resampling_rate"]) * self.budget

    def update_vpls(self, frame: Frame, t: StageTimer):
        I, p = self.budget, self.params
        if self.bounces <= 0:
            z = np.zeros((16, 3), np.float32)
            return z, z, z, {"vpls_used": 0, "vpl_budget": I}
        n = int(p["resampling_rate"]) * I
        with t.stage("paths"):
            cand = raw_candidates_device(self.scene, frame.camera, frame.res, n, frame.seed, frame.index, 0x31A,
                                         stage="paths")
            ok = cand["ok"]
            sampler = make_sampler(n, frame.seed, frame.index, 0x31C)
            L, n_rays = path_radiance_device(self.scene.mi_scene, cand["pos"], cand["nrm"], sampler, ok,
                                             int(p["max_depth"]) - 1, self.lights)
            c = dr.select(ok, luminance(cand["mailbox_albedo"] * L), 0.0)
            # one kernel for the hits and the walk (cand too: a lazy hit would be re-traced in every later
            # kernel); the ray count after it -- a reduction evaluates its input at once, so summing the
            # lazy ``n_rays`` first would trace all the paths twice
            dr.eval(cand, L, c, n_rays)
            rays = dr.sum(n_rays) + dr.count(cand["okx"]) + n
        t.add_rays("paths", rays)
        with t.stage("resampling"):
            m = dr.maximum(mi.Float(dr.count(ok)), 1.0)
            u = make_sampler(I, frame.seed, frame.index, 0x31B).next_1d()
            sel = resample_with_replacement_device(c, u)
            pos = dr.gather(mi.Point3f, mi.Point3f(cand["pos"]), sel)
            nrm = dr.gather(mi.Vector3f, mi.Vector3f(cand["nrm"]), sel)
            dr.eval(sel, pos, nrm)
        with t.stage("knn"):
            # q only where it is used: at the I drawn hits (each excluding itself), among all valid hits
            k = knn_k(n)
            grid = KNNGrid(cand["pos"], ok)
            r = dr.maximum(grid.kth_distance(pos, k, sel), MIN_RADIUS)
            q = dr.select(dr.isfinite(r), k / (m * dr.pi * r * r), 0.0)
            dr.eval(q)
        with t.stage("resampling"):
            total = dr.sum(c)
            mean_c = total / m        # over the raw hits, the set whose area density q is
            c_s = dr.gather(mi.Float, c, sel)
            w = mean_c / (I * c_s * q)
            w = dr.select((total > 0.0) & (c_s > 0.0) & (q > 0.0) & dr.isfinite(w), w, 0.0)
            flux = dr.gather(mi.Color3f, mi.Color3f(L), sel) * w
            hit = dr.zeros(mi.UInt32, n)
            dr.scatter(hit, mi.UInt32(1), sel, w > 0.0)
            used = dr.sum(hit)
            dr.eval(pos, nrm, flux, used)
        return pos, nrm, flux, {"vpls_used": used, "vpl_budget": I}
