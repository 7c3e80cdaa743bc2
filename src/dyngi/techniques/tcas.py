"""Temporally coherent adaptive sampling (Barák, Bittner, Havran 2013) as a baseline of Hedman et al.
2017 (Sec. 5.1): technique ``tcas``.

Metropolis-Hastings over light-visible surface samples (the texels of a reflective
shadow map: first diffuse hits of photons, :func:`dyngi.vpl.points.photon_first_hits_device`),
``iterations`` (16; Barak et al. propose 5, Hedman et al. use 16) per frame, single bounce
(the VPLs carry direct light only, whatever ``max_depth``, as the paper's TCAS):

* one chain per VPL, its state a primary sample ``u`` in [0,1)^5 (emitter, position,
  direction; the emitter chosen by ``lights``, :mod:`dyngi.vpl.emission`); chains persist across frames (the temporal coherence);
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

All on the device (issue 29): chain states, targets and the per-chain hits are Dr.Jit arrays kept
across frames; the target's sum over view samples is one symbolic loop per chain; random numbers come
from a per-chain PCG32 seeded by (seed, frame). The ``iterations`` MH steps are one symbolic loop (one
kernel); a frame reads nothing back before the image.
Extra parameters: ``iterations`` (16), ``view_samples`` (64); ``lights`` ('scene', 'uniform', 'power')
chooses the photons' lights.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..color import luminance
from ..sampling.rng import make_sampler, mix_seed
from ..rays import add as add_rays
from ..vpl.points import photon_first_hits_device, raw_candidates_device
from .base import Frame, Param, StageTimer, register
from .vpl_base import COMMON_PARAMS, EMISSION_LIGHTS, VPLTechnique

PERTURB_SIGMA = 0.02
"""Standard deviation of the small-step proposal in primary sample space (our choice)."""
_S_VIEW, _S_INIT, _S_ITER = 0x7CA6, 0x7CA7, 0x7CA8


def _pick(take, a, b):
    """``select(take, a, b)`` over matching lists or dicts of arrays."""
    if isinstance(a, dict):
        return {k: dr.select(take, a[k], b[k]) for k in a}
    return [dr.select(take, x, y) for x, y in zip(a, b)]


@dr.syntax
def _view_importance(p, n, ok, xs, ns, okx, count, dmin2):
    """sum_x okx max(0, cos_x) max(0, cos_y) / max(d^2, d_min^2) over the view samples, per chain."""
    acc = mi.Float(0.0)
    j = mi.UInt32(0)
    while ok & (j < count):
        x = dr.gather(mi.Point3f, xs, j)
        nx = dr.gather(mi.Vector3f, ns, j)
        vx = dr.gather(mi.Bool, okx, j)
        d = x - p
        d2 = dr.maximum(dr.squared_norm(d), 1e-12)
        dn = d * dr.rsqrt(d2)
        cy = dr.maximum(dr.dot(dn, n), 0.0)
        cx = dr.maximum(-dr.dot(dn, nx), 0.0)
        acc += dr.select(vx, cx * cy / dr.maximum(d2, dmin2), 0.0)
        j += 1
    return acc


@register
class TCAS(VPLTechnique):
    name = "tcas"
    description = "temporally coherent adaptive sampling (Barak et al. 2013): MH over RSM samples, single bounce"
    PARAMS = {**COMMON_PARAMS, "lights": EMISSION_LIGHTS,
              "iterations": Param(16, "Metropolis-Hastings iterations per frame", min=1, max=1024),
              "view_samples": Param(64, "camera-visible points of the view importance", min=1, max=4096)}
    FURNACE = False
    FURNACE_REASON = ("TCAS carries a single bounce of indirect light by design (Sec. 5.1), so it cannot "
                      "reach the furnace's multi-bounce value; its max_depth only caps it")

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        self.u = None          # chain states: five Floats of I lanes (device)
        self.f = None
        self.hits = None

    def _target(self, hits, view):
        """f = lum(L) * sum_x cos cos / max(d^2, d_min^2) (no visibility), per chain on the device."""
        lum = luminance(hits["radiosity"])
        dmin2 = dr.opaque(mi.Float, 1.0 / self.gmax if np.isfinite(self.gmax) else 0.0)
        imp = _view_importance(hits["pos"], hits["nrm"], hits["ok"], view["x"], view["n"], view["ok"],
                               dr.opaque(mi.UInt32, view["count"]), dmin2)
        return dr.select(hits["ok"], lum * imp, 0.0)

    @dr.syntax
    def _chains(self, u, f, hits, rng, view, iterations):
        """``iterations`` MH steps of every chain in one symbolic loop (one kernel per frame); returns the
        new states, targets, hits, the sums over independent proposals that estimate ``b`` and the photon rays
        traced per chain (:mod:`dyngi.rays`: counted per lane in the loop, added by the caller)."""
        b_sum = dr.zeros(mi.Float, dr.width(f))
        n_rays = dr.zeros(mi.UInt32, dr.width(f))
        b_n = dr.zeros(mi.Float, dr.width(f))
        sigma = dr.opaque(mi.Float, PERTURB_SIGMA)
        it = mi.UInt32(0)
        while it < iterations:
            indep = rng.next_float32() < 0.5
            g0 = mi.warp.square_to_std_normal(mi.Point2f(rng.next_float32(), rng.next_float32()))
            g1 = mi.warp.square_to_std_normal(mi.Point2f(rng.next_float32(), rng.next_float32()))
            g2 = mi.warp.square_to_std_normal(mi.Point2f(rng.next_float32(), rng.next_float32()))
            gauss = [g0.x, g0.y, g1.x, g1.y, g2.x]
            prop = []
            for i in range(5):       # static: the five primary-sample dimensions
                small = u[i] + sigma * gauss[i]
                prop.append(dr.select(indep, rng.next_float32(), small - dr.floor(small)))
            h2 = photon_first_hits_device(self.scene, prop, self.lights, stage="metropolis", lanes=True)
            n_rays += mi.UInt32(h2.pop("traced"))
            f2 = self._target(h2, view)
            b_sum += dr.select(indep, f2, 0.0)
            b_n += dr.select(indep, 1.0, 0.0)
            acc = dr.select(f > 0.0, f2 / f, dr.select(f2 > 0.0, 1.0, 0.0))
            take = rng.next_float32() < acc
            u = _pick(take, prop, u)
            f = dr.select(take, f2, f)
            hits = _pick(take, h2, hits)
            it += 1
        return u, f, hits, dr.sum(b_sum), dr.sum(b_n), n_rays

    def update_vpls(self, frame: Frame, t: StageTimer):
        I, p = self.budget, self.params
        if self.bounces <= 0:
            z = np.zeros((16, 3), np.float32)
            return z, z, z, {"vpls_used": 0, "vpl_budget": I}
        with t.stage("view_samples"):
            nv = int(p["view_samples"])
            c = raw_candidates_device(self.scene, frame.camera, frame.res, nv, frame.seed, 0, _S_VIEW,
                                      stage="view_samples")
            view = {"x": mi.Point3f(c["mailbox"]), "n": mi.Vector3f(c["mailbox_n"]), "ok": c["okx"], "count": nv}
            dr.eval(view["x"], view["n"], view["ok"])
        t.add_rays("view_samples", nv + dr.count(c["okx"]))
        with t.stage("metropolis"):
            if self.u is None:
                s0 = make_sampler(I, frame.seed, 0, _S_INIT)
                self.u = [s0.next_1d() for _ in range(5)]
                dr.eval(self.u)
            hits = photon_first_hits_device(self.scene, self.u, self.lights, stage="metropolis")
            f = self._target(hits, view)
            dr.eval(hits, f)
            rng = mi.PCG32(size=I, initstate=mi.UInt64(dr.opaque(mi.UInt32, mix_seed(frame.seed, frame.index,
                                                                                     _S_ITER))))
            self.u, f, hits, b_sum, b_n, n_rays = self._chains(self.u, f, hits, rng, view,
                                                               dr.opaque(mi.UInt32, int(p["iterations"])))
            dr.eval(self.u, f, hits, b_sum, b_n, n_rays)     # n_rays too: its sum would re-run the chains
        add_rays("metropolis", dr.sum(n_rays))     # the chains' photon rays (counted per lane in the loop)
        t.add_rays("metropolis", I * (int(p["iterations"]) + 1))
        with t.stage("weights"):
            b = b_sum / dr.maximum(b_n, 1.0)
            w = dr.select(f > 0.0, b / (I * f), 0.0)
            flux = hits["radiosity"] * w
            used = dr.count(f > 0.0)
            dr.eval(flux, used)
        self.f, self.hits = f, hits
        return hits["pos"], hits["nrm"], flux, {"vpls_used": used, "vpl_budget": I}
