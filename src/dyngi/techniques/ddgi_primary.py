"""Primary DDGI (technique ``ddgi-primary``): the DDGI Resampling paper's Eq. 2 at the primary vertex.

``L ~= L_e + T_fd L_e + L_DDGI + T_fg L``  (Majercik et al. 2022, Sec. 3.1, Eq. 2; the "Primary DDGI"
column of its Fig. 3 / 8 and Table 1):

* ``L_e`` at the primary vertex, and **direct light by ReSTIR DI** -- exactly
  ``restir-pt``'s G-buffer, candidates, temporal and spatial reuse and shadow
  ray (the transport layer's :class:`~dyngi.transport.restir_di.ReSTIRDI`, as
  ``restir-pt`` with ``max_depth = 2``), which covers ``T_f L_e`` through
  every smooth lobe of the primary BSDF (diffuse and glossy), plus the
  emission seen through a delta lobe of the primary vertex
  (:meth:`~dyngi.transport.restir_di.ReSTIRDI.path_after` to depth 2);
* ``L_DDGI``: ``albedo / pi * E_probe(x, n)`` from a plain DDGI volume
  (:class:`~dyngi.probes.ddgi_plus.DDGIPlusVolume` in ``'ddgi'`` mode) whose
  probe rays do NEE for **every** emitter (``direct='nee'``): the probes then
  hold bounced light only (``sum_{i>=2} T_fd^i L_e``), since ReSTIR already
  delivers the environment's and every light's direct part;
* ``T_fg L``: the **glossy recursion**, path traced by the transport layer's
  walk (:func:`glossy_recursion`): at the primary vertex one sample of the
  glossy and delta lobes (:class:`~dyngi.directions.lobes.LobeDirections`); at
  each following vertex ``y``: NEE (one light sample, full BSDF) +
  ``albedo / pi * E_probe(y)`` + the next glossy sample, up to ``glossy_depth``
  glossy bounces. Emission hit by a glossy sample is not counted where the
  lobe was smooth (NEE at the vertex before covered it: ReSTIR at the primary
  vertex, NEE after) but is counted behind a delta lobe (which NEE cannot
  sample; at the primary vertex that is ReSTIR's path part). No MIS, no
  Russian roulette (our choice: the recursion is short and its throughput
  falls with every glossy albedo).

Unlike ``ddgi`` (diffuse indirect only), glossy surfaces reflect indirect
light (through the recursion). On a scene without any diffuse lobe the
technique is an unbiased path tracer of depth ``glossy_depth + 2`` (Mitsuba's
``max_depth``; ``tests/probes/test_ddgi_plus.py`` z-tests it against Mitsuba's ``path``).

Conventions as ``ddgi``: the first frame warms the probes up (``warmup``
updates without hysteresis), one jittered primary ray per pixel, no
accumulation over frames. Differences: the primary ray does not pass through
glass (restir-pt's G-buffer; glass reflects and refracts through the glossy
recursion's delta lobes instead). ``FrameResult.indirect`` = the probe term +
the recursion's light from vertices >= 3 (light that reflected at least once
before the primary vertex).

Parameters
----------
candidates, temporal, m_cap, spatial, radius, combine, lights
                            ReSTIR DI, as ``restir-pt`` (32, True, 20, 3, 30, 'mis', 'scene'); ``lights``
                            also samples the NEE of the path after the primary vertex and of the recursion
glossy_depth : int = 4      glossy bounces of the T_fg L recursion (0: none, i.e. ``ddgi``'s diffuse-only indirect)
probe parameters            ``ddgi``'s (probe_counts, rays_per_probe, hysteresis, warmup, ...), through
                            :data:`dyngi.probes.params.DDGI_PLUS_SPECS`; the probes' ``direct`` routing is
                            fixed to ``'nee'`` (see above)

Bias: the probes' (lag, spatial and angular blur, leaks: ``living-room``);
none in the ReSTIR part (``combine='mis'``) and in the recursion, which is
truncated at ``glossy_depth`` glossy bounces.

Stats per stage: restir-pt's (``gbuffer``, ``candidates``, ``temporal``,
``spatial``, ``shadow``, ``path``, ``accumulate``), the probe update's
(``warmup``, ``trace probes``, ``shade probes``, ``blend``, ``states``),
``probe query`` and ``glossy``.
"""
from __future__ import annotations

from ..backend import dr, mi
from ..probes.ddgi_plus import DDGIPlusVolume
from ..directions.lobes import LobeDirections
from ..probes.glossy import GLOSSY_LOBES
from ..probes.lookup import diffuse_radiance
from ..probes.params import DDGI_PLUS_SPECS
from ..scene.surface import shading_side
from ..sampling.diffuse import diffuse_albedo
from ..sampling.rng import make_sampler
from ..transport.path_walk import walk
from ..transport.restir_di import PARAM_SPECS, ReSTIRDI
from .base import Frame, FrameResult, Param, StageTimer, Technique, register, to_image
from .probe_base import params_from

_GLOSSY_STREAM = 0x6C05
_PROBE_SKIP = ("direct", "emission_attenuation", "emission_scale", "probe_glossy", "update_view_path_bias")


def _params() -> dict:
    out = {k: Param(**v) for k, v in PARAM_SPECS.items()}
    out.update(params_from({k: v for k, v in DDGI_PLUS_SPECS.items() if k not in _PROBE_SKIP}))
    out["glossy_depth"] = Param(4, "glossy bounces of the path-traced T_fg L recursion (0: none)", min=0, max=64)
    return out


def glossy_recursion(scene, volume, lights, si, ray, front, sampler, depth_max: int):
    """``T_fg L`` at the primary vertex ``si`` (module docstring). Returns (L, rays traced per lane).

    One call of the transport layer's path walk (:func:`dyngi.transport.path_walk.walk`) from ``si``
    (vertex 0) with per-vertex choices: directions from the glossy and delta lobes only
    (:class:`~dyngi.directions.lobes.LobeDirections`, :data:`~dyngi.probes.glossy.GLOSSY_LOBES`); NEE
    (``lights``, full BSDF) at vertices 1 .. ``depth_max``; the emission reached through a delta lobe at
    vertices 2 .. ``depth_max`` (vertex 1's is ReSTIR's path part; behind a smooth lobe it was NEE's at the
    vertex before: no MIS); the shade hook adds ``albedo / pi * E_probe`` at vertices >= 1 and ends the
    path at vertex ``depth_max`` or on a surface not facing the ray; no Russian roulette.
    ``volume``: the :class:`~dyngi.probes.ddgi_plus.DDGIPlusVolume` whose query gives the diffuse
    indirect light; ``front``: lanes whose primary vertex faces the camera; ``depth_max``: glossy bounces
    (a Python int: fixed per technique instance). All of ``L`` is indirect light (it reflected at vertex
    >= 2 before the primary vertex)."""
    depth_u = mi.UInt32(depth_max)

    def emission(depth, prev_delta):
        return prev_delta & (depth >= 2) & (depth <= depth_u)

    def nee(depth):
        return depth >= 1

    def shade(v):
        fr, nn = shading_side(v.si, v.ray, v.bsdf, v.active)
        alb = diffuse_albedo(v.bsdf, v.si, fr)
        dif = fr & dr.any(alb > 0.0) & (v.depth >= 1)
        E = volume.query.irradiance(v.si.p, nn, -v.ray.d, active=dif)
        L = diffuse_radiance(alb, E, dif)
        return L, (v.depth >= depth_u) | ~fr, v.state

    r = walk(scene, sampler, ray, mi.Bool(front), depth_max + 2, -1, lights, si=si, emission=emission, nee=nee,
             shade=shade, directions=LobeDirections(GLOSSY_LOBES), mis=False, stage="glossy")
    return mi.Color3f(r.L), r.n_rays


@register
class DDGIPrimaryTechnique(Technique):
    """Primary DDGI (DDGI Resampling Sec. 3.1, Eq. 2): ReSTIR direct + probe diffuse indirect + T_fg L."""

    name = "ddgi-primary"
    PROBE_TECHNIQUE = True    # its DDGI+ volume traces probes (dyngi.probes.ddgi_plus)
    description = ("Primary DDGI (Majercik et al. 2022, Eq. 2): ReSTIR DI at the primary vertex, DDGI probe "
                   "diffuse indirect, path-traced glossy recursion T_fg L")
    HAS_INDIRECT = True
    INDIRECT_INCLUDES_PROBE_SKY = False   # the probes' rays NEE every emitter: they hold bounced light only
    PARAMS = _params()

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        p = self.params
        self.restir = ReSTIRDI.from_params(scene, p)
        probe = {k: p[k] for k in DDGI_PLUS_SPECS if k in p}
        probe["direct"] = "nee"
        self.probes = DDGIPlusVolume(scene, probe, mode="ddgi")
        self.lights = self.restir.lights       # ``lights``: ReSTIR's candidates, the path's and the recursion's NEE

    def _direct(self, frame: Frame, t: StageTimer):
        """``L_e + T_f L_e`` at the primary vertex (an H x W x 3 image): ReSTIR DI through the smooth lobes,
        the emission behind a delta lobe by the path walk (``restir-pt`` at ``max_depth = 2``)."""
        pv = self.restir.begin(frame, t)
        direct = mi.Color3f(0.0)
        if self.restir.cand.count > 0:
            direct = self.restir.direct(pv, t)
        Le0, L_d, _ = self.restir.path_after(pv, frame, self.lights, 2, 5, t)
        with t.stage("accumulate"):
            L = mi.Color3f(Le0 + direct + L_d)
            dr.eval(L)
        return to_image(L, frame.res)

    def step(self, frame: Frame) -> FrameResult:
        p = self.params
        t = StageTimer()
        self.probes.update(frame, timer=t)
        self.restir.lights_begin(frame, t)
        direct_img = self._direct(frame, t)       # G-buffer, ReSTIR DI, delta-lobe emission: L_e + T_f L_e
        gb = self.restir.hist.cur
        si, ray = gb.si, gb.ray
        mscene = self.scene.mi_scene
        bsdf = si.bsdf(ray)
        front, n = shading_side(si, ray, bsdf, gb.valid)     # n: the shading normal on the camera's side
        with t.stage("probe query"):
            alb = diffuse_albedo(bsdf, si, front)
            E = self.probes.query.irradiance(si.p, n, -ray.d, active=front & dr.any(alb > 0.0))
            ind = diffuse_radiance(alb, E, front)
            dr.eval(ind)
        gl = mi.Color3f(0.0)
        if p["glossy_depth"] > 0:
            with t.stage("glossy"):
                npix = frame.res[0] * frame.res[1]
                sampler = make_sampler(npix, frame.seed, frame.index, _GLOSSY_STREAM)
                gl, rays = glossy_recursion(mscene, self.probes, self.lights, si, ray, front, sampler,
                                            p["glossy_depth"])
                gl = dr.select(dr.all(dr.isfinite(gl)), gl, 0.0)
                dr.eval(gl, rays)
            t.add_rays("glossy", dr.sum(rays))
        self.restir.lights_end(t)
        indirect = to_image(ind + gl, frame.res)
        img = direct_img + indirect
        stats = t.as_dict()
        st = self.probes.stats()
        stats.update({k: v for k, v in st.items() if k not in ("ms", "rays", "total_ms", "total_rays")})
        return FrameResult(image=img, indirect=indirect, stats=stats)
