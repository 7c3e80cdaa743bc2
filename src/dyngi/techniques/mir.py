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
Extra parameter: ``resampling_rate`` (256). Bias: the kNN density ``q`` and clamping.
"""
from __future__ import annotations

import numpy as np

from ..sampling.rng import mix_seed
from ..vpl.density import knn_density, knn_k
from ..vpl.points import raw_candidates
from ..vpl.radiosity import estimate_radiosity
from ..vpl.store import LUMINANCE
from .base import Frame, Param, StageTimer, register
from .vpl_base import COMMON_PARAMS, VPLTechnique


@register
class MetropolisIR(VPLTechnique):
    name = "mir"
    description = "Metropolis instant radiosity as in Hedman et al. 2017: path-tracer paths resampled 256:1 per frame"
    PARAMS = {**COMMON_PARAMS,
              "resampling_rate": Param(256, "camera paths per VPL, resampled by image contribution", min=1,
                                       max=4096)}
    BATTERY_PARAMS = {"vpls": 32, "resampling_rate": 16}
    FURNACE_PARAMS = {"vpls": 512, "resampling_rate": 32, "shading": "exhaustive"}
    FURNACE_TOL = 0.05
    """One VPL set per frame, shared by all pixels, and the kNN density of the raw hits."""

    def update_vpls(self, frame: Frame, t: StageTimer):
        I, p = self.budget, self.params
        z = np.zeros((16, 3), np.float32)
        if self.bounces <= 0:
            return z, z, z, {"vpls_used": 0, "vpl_budget": I}
        with t.stage("paths"):
            cand, _, rays = raw_candidates(self.scene, frame.camera, frame.res, p["resampling_rate"] * I,
                                           frame.seed, frame.index, 0x31A)
            m = len(cand["pos"])
            rng = np.random.default_rng(mix_seed(frame.seed, frame.index, 0x31B))
            seeds = rng.integers(0, 1 << 62, m, dtype=np.uint64)
            L, r2 = estimate_radiosity(self.scene.mi_scene, cand["pos"], cand["nrm"], seeds, 1,
                                       int(p["max_depth"]) - 1)
        t.add_rays("paths", rays + r2)
        with t.stage("resampling"):
            c = (cand["mailbox_albedo"].astype(np.float64) * L) @ LUMINANCE
            if m == 0 or not np.any(c > 0):
                return z, z, z, {"vpls_used": 0, "vpl_budget": I}
            q = knn_density(cand["pos"], k=knn_k(m))
            sel = rng.choice(m, size=I, replace=True, p=c / c.sum())
            mean_c = c.sum() / m        # over the raw hits, the set whose area density q is
            with np.errstate(divide="ignore", invalid="ignore"):
                w = mean_c / (I * c[sel] * q[sel])
            w = np.where(np.isfinite(w), w, 0.0)
            flux = (L[sel] * w[:, None]).astype(np.float32)
        return cand["pos"][sel], cand["nrm"][sel], flux, {"vpls_used": int(len(np.unique(sel))), "vpl_budget": I}
