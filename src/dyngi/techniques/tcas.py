"""Temporally coherent adaptive sampling (Barák, Bittner, Havran 2013) as a baseline of Hedman et al.
2017 (Sec. 5.1): technique ``tcas``.

Metropolis-Hastings over light-visible surface samples (the texels of a reflective
shadow map: first diffuse hits of photons, :func:`dyngi.vpl.points.photon_first_hits`),
``iterations`` (16; Barak et al. propose 5, Hedman et al. use 16) per frame, single bounce
(the VPLs carry direct light only, whatever ``max_depth``, as the paper's TCAS):

* one chain per VPL, its state a primary sample ``u`` in [0,1)^5 (emitter, position,
  direction); chains persist across frames (the temporal coherence);
* target ``f(u) = lum(L(y(u))) * sum_x max(0, cos_x) max(0, cos_y) / max(d^2, d_min^2)`` over
  ``view_samples`` (64) camera-visible points x -- view-adaptive but blind to the
  visibility between y and x (TCAS does not account for indirect visibility); the x come
  from fixed pixel positions (frame-independent), ``d_min`` the shading clamp distance;
* proposals: with probability 1/2 an independent uniform ``u'``, else a perturbation
  ``u + N(0, 0.02^2)`` wrapped to [0,1) (symmetric: acceptance ``min(1, f'/f)``); each frame
  first re-evaluates the chains' current states under the new light and camera;
* VPL weight ``flux_i = L_i * b / (I f_i)``, with ``b = E_u[f]`` estimated from this frame's
  independent proposals (the normalisation of the MH target).

Our choices where the papers are silent: the perturbation size, the mixture, ``b``.
Extra parameters: ``iterations`` (16), ``view_samples`` (64).
"""
from __future__ import annotations

import numpy as np

from ..sampling.rng import mix_seed
from ..vpl.points import photon_first_hits, raw_candidates
from ..vpl.store import LUMINANCE
from .base import Frame, Param, StageTimer, register
from .vpl_base import COMMON_PARAMS, VPLTechnique

PERTURB_SIGMA = 0.02
"""Standard deviation of the small-step proposal in primary sample space (our choice)."""


@register
class TCAS(VPLTechnique):
    name = "tcas"
    description = "temporally coherent adaptive sampling (Barak et al. 2013): MH over RSM samples, single bounce"
    PARAMS = {**COMMON_PARAMS,
              "iterations": Param(16, "Metropolis-Hastings iterations per frame", min=1, max=1024),
              "view_samples": Param(64, "camera-visible points of the view importance", min=1, max=4096)}
    BATTERY_PARAMS = {"vpls": 32, "iterations": 4, "view_samples": 16}
    FURNACE = False
    FURNACE_REASON = ("TCAS carries a single bounce of indirect light by design (Sec. 5.1), so it cannot "
                      "reach the furnace's multi-bounce value; its max_depth only caps it")

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        self.u = None          # chain states, I x 5
        self.f = None

    def _target(self, hits, xs, ns):
        """f = lum(L) * sum_x cos cos / max(d^2, d_min^2) (no visibility), host NumPy over I x |X|."""
        lum = hits["radiosity"].astype(np.float64) @ LUMINANCE
        if len(xs) == 0:
            return np.where(hits["ok"], lum, 0.0)
        d = xs[None, :, :] - hits["pos"][:, None, :]
        d2 = np.maximum((d * d).sum(-1), 1e-12)
        dn = d / np.sqrt(d2)[..., None]
        cy = np.maximum((dn * hits["nrm"][:, None, :]).sum(-1), 0.0)
        cx = np.maximum(-(dn * ns[None, :, :]).sum(-1), 0.0)
        dmin2 = 1.0 / self.gmax if np.isfinite(self.gmax) else 0.0
        imp = (cx * cy / np.maximum(d2, dmin2)).sum(-1)
        return np.where(hits["ok"], lum * imp, 0.0)

    def update_vpls(self, frame: Frame, t: StageTimer):
        I, p = self.budget, self.params
        z = np.zeros((16, 3), np.float32)
        if self.bounces <= 0:
            return z, z, z, {"vpls_used": 0, "vpl_budget": I}
        rng = np.random.default_rng(mix_seed(frame.seed, frame.index, 0x7CA5))
        rays = 0
        with t.stage("view_samples"):
            _, pts, r = raw_candidates(self.scene, frame.camera, frame.res, p["view_samples"], frame.seed, 0, 0x7CA6)
            xs, ns = pts["x"].astype(np.float64), pts["n"].astype(np.float64)
            rays += r
        with t.stage("metropolis"):
            if self.u is None:
                self.u = rng.random((I, 5))
            hits, r = photon_first_hits(self.scene, self.u)
            rays += r
            f = self._target(hits, xs, ns)
            b_sum, b_n = 0.0, 0
            for _ in range(p["iterations"]):     # a few static MH steps, each vectorised over all chains
                indep = rng.random(I) < 0.5
                prop = np.where(indep[:, None], rng.random((I, 5)),
                                np.mod(self.u + PERTURB_SIGMA * rng.standard_normal((I, 5)), 1.0))
                h2, r = photon_first_hits(self.scene, prop)
                rays += r
                f2 = self._target(h2, xs, ns)
                b_sum += float(f2[indep].sum())
                b_n += int(indep.sum())
                with np.errstate(divide="ignore", invalid="ignore"):
                    acc = np.where(f > 0, f2 / f, np.where(f2 > 0, 1.0, 0.0))
                take = rng.random(I) < acc
                self.u[take] = prop[take]
                f[take] = f2[take]
                for k in hits:
                    hits[k][take] = h2[k][take]
        t.add_rays("metropolis", rays)
        b = b_sum / max(b_n, 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(f > 0, b / (I * f), 0.0)
        flux = (hits["radiosity"] * w[:, None]).astype(np.float32)
        return hits["pos"], hits["nrm"], flux, {"vpls_used": int((f > 0).sum()), "vpl_budget": I}
