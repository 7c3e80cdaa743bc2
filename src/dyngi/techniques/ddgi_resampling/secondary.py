"""Secondary DDGI (technique ``ddgi-secondary``; Majercik et al. 2022, Sec. 4 item 3).

``L = L_e(x_1) + ReSTIR DI(x_1) + beta_1 * S(x_2)`` with ``x_2`` one full-BSDF sample at the primary
vertex (and ``beta_1 L_e(x_2)`` when that sample went through a delta lobe, which ReSTIR's light
samples cannot reach). The ReSTIR DI stages are the transport layer's component, as in ``restir-pt``
(candidates, temporal, spatial, one shadow ray).
``S`` is :mod:`.shading`'s.

Parameters: ``restir-pt``'s ReSTIR DI settings and ``progressive``, the DDGI+ probes', ``footprint_c``,
``max_glossy``, ``view_path_bias``, ``exact_radiance``/``exact_depth`` (package docstring).
"""
from __future__ import annotations

from ...backend import dr, mi
from ...probes.glossy import has_glossy_lobe
from ...sampling.rng import make_sampler
from ..base import Frame, FrameResult, StageTimer, register
from .shading import _SHADE_STREAM, SECONDARY_PARAMS, SecondaryShading


@register
class DDGISecondaryTechnique(SecondaryShading):
    """Secondary DDGI: ReSTIR DI at the primary vertex, DDGI+ read at the secondary vertex (Sec. 3.3-3.5)."""

    name = "ddgi-secondary"
    description = ("Secondary DDGI (DDGI Resampling paper): ReSTIR DI + one BSDF bounce into DDGI+ probes "
                   "(diffuse + glossy Eq. 6), footprint-terminated glossy recursion, view-path bias")
    PARAMS = SECONDARY_PARAMS

    def step(self, frame: Frame) -> FrameResult:
        t = StageTimer()
        npix = frame.res[0] * frame.res[1]
        pv, a0 = self._begin(frame, t)
        gb, bsdf = pv.gb, pv.bsdf
        do_direct = self.cand.count > 0
        direct = self.restir.direct(pv, t) if do_direct else mi.Color3f(0.0)
        Le0 = gb.si.emitter(self.scene.mi_scene).eval(gb.si, mi.Bool(True))
        with t.stage("shade secondary"):
            ss = make_sampler(npix, frame.seed, frame.index, _SHADE_STREAM)
            bs, w, ok, ray, si2, delta = self._bsdf_sample(gb, bsdf, ss)
            Le2 = mi.Color3f(si2.emitter(self.scene.mi_scene).eval(si2, ok & delta))
            L_d = dr.select(ok & delta, w * Le2, 0.0)
            L_ind, rays, rec = self.shade_secondary(si2, ray, w, a0, bs.pdf, delta, ss, ok)
            dr.eval(L_d, L_ind, rays, rec)
        t.add_rays("shade secondary", dr.count(ok))
        t.add_rays("shade secondary", dr.sum(rays))
        self.last_recursions = rec
        if self.record_debug:
            self.debug = {"x1": gb.pos, "n1": gb.n_geo, "x2": si2.p, "n2": si2.n, "p1": bs.pdf,
                          "ok": ok & si2.is_valid(), "delta": delta, "glossy2": has_glossy_lobe(si2.bsdf()),
                          "rec": rec}
        return self._finish(frame, t, Le0 + direct + L_d + L_ind, L_ind)

