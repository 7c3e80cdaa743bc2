"""Shading a secondary vertex, ``S(x_n)`` (Majercik et al. 2022, Sec. 3.4-3.5; both techniques).

The rest of the path after the secondary vertex is replaced by the DDGI+ probes of
:class:`~dyngi.probes.ddgi_plus.DDGIPlusVolume` (Sec. 3.3, Eq. 5: the probes hold ``L_DDGI+ ~ T_f L``,
direct light from emitting surfaces and the sky included; delta lights and a sunsky's sun are added by
NEE at every point where the probes are read, since no probe ray can hit them).

At a vertex ``x_n`` (n >= 2) reached from ``x_{n-1}``:

* footprint (Eq. 7): ``a = (sum_i sqrt(|x_i - x_{i+1}|^2 / (p_i cos_{i+1})))^2`` with ``p_1`` the full
  BSDF's pdf at the primary vertex and ``p_i`` (i > 1) the glossy lobes' pdf; a delta lobe adds 0
  (no spread; our choice: Mitsuba reports pdf 1 for a delta lobe, which would add a spread in metres);
* diffuse part, always: ``rho / pi * E(q, n)`` (the recursion "terminates into the probes when the
  diffuse portion is sampled"; we evaluate the diffuse part in closed form instead of sampling the lobe
  choice, same expectation, less noise -- our choice);
* glossy part: one sample of the glossy reflection lobes (:func:`dyngi.probes.glossy`); if the footprint
  exceeds ``c * a0`` (Eq. 8, ``a0 = 4 pi |x_0 - x_1|^2 / cos_1``, ``c`` = ``footprint_c`` = 0.2) or the
  recursion reached ``max_glossy``, Eq. 6's estimate ``weight * E(q, w_i) / pi`` (the ``/ pi`` that
  H4's glossy furnace test settled); else the path continues along that same sample (glossy
  recursion), and the next vertex adds its emission ``L_e`` (and the environment on a miss);
* NEE for the light the probes cannot carry (delta lights, the sun): one sample, full BSDF;
* the recursion is one call of the transport layer's path walk (:func:`dyngi.transport.path_walk.walk`)
  from ``x_n``: its directions from the glossy reflection lobes only
  (:class:`~dyngi.directions.lobes.LobeDirections`), emission counted from the first recursion vertex on,
  no MIS (NEE and the recursion see disjoint light), no Russian roulette, and a shade hook that reads the
  probes, keeps Eq. 7's running sum as its state and stops the path where Eq. 8 (or ``max_glossy``) says;
  where it stops, Eq. 6's lookup draws its own glossy sample (our choice: the continuation's sample is
  drawn by the walk only where the path goes on; one sample is used per vertex either way);
* **view-path self-shadow bias** (Sec. 3.5): the probes are read at ``q = x_n - d * w_in``, moved back
  along the incoming path segment, with ``d = min(view_path_bias * s_min, 0.5 |x_n - x_{n-1}|)``,
  ``s_min`` the smallest probe spacing ("proportional to the probe size"; default factor 0.2 =
  DDGI's ``view_bias``, our choice; the clamp to half the segment keeps ``q`` in free space, which is
  the point of the method). DDGI's own normal/view biases are off by default (``normal_bias`` and
  ``view_bias`` stay available for a Fig. 5 comparison).

Test hook ``exact_radiance=True``: ``S(x_n)`` is replaced by a path-traced estimate of the reflected
radiance at ``x_n`` (Mitsuba-style path tracing with NEE and MIS from ``x_{n-1}`` along the segment,
``exact_depth`` vertices, minus the emission of ``x_n``); the estimator is then unbiased, which the
convergence test checks against Mitsuba's ``path``. The hook replaces ``S`` where an estimate is
*shaded*; ``ddgi-resampling``'s resampling target keeps the probes' ``S(y)`` (its cached ``L_y``, as
without the hook), since any target with full support leaves the estimate unbiased (Sec. 3.7: "using
approximate values in the resampling step does not introduce additional bias"), while a single
path-traced sample as the target is 0 for most points ``y`` of a room lit through a window: those
samples sit at the target's floor with contribution weights ~1/floor, and a fresh ``S(z)`` that finds
the light makes fireflies that carry most of the energy (the accumulated image then reads 10-30 %
dark; docs/techniques/ddgi-resampling.md).

:class:`SecondaryShading` is the frame set-up both techniques share (not a technique itself): the
ReSTIR DI component (:class:`~dyngi.transport.restir_di.ReSTIRDI`), the DDGI+ volume, the G-buffer and
its reprojection, one full-BSDF sample at the primary vertex, progressive accumulation.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ...backend import dr, mi
from ...probes.ddgi_plus import DDGIPlusVolume
from ...probes.params import DDGI_PLUS_SPECS
from ...directions.base import Vertex
from ...directions.bsdf import BSDFDirections
from ...directions.lobes import LobeDirections
from ...probes.glossy import GLOSSY_LOBES, GLOSSY_NORMALISATION, sample_glossy
from ...probes.lookup import diffuse_radiance
from ...rays import intersect
from ...scene.surface import shading_side
from ...sampling.diffuse import diffuse_albedo
from ...transport.accumulate import ProgressiveMean
from ...transport.path_walk import trace_paths, walk
from ...transport.restir_di import PARAM_SPECS, ReSTIRDI
from ..base import FrameResult, Param, Technique, to_image
from ..probe_base import params_from

_SHADE_STREAM = 0x5EC0
"""RNG stream of the secondary-vertex shading (the ReSTIR stages use stream 0)."""

FOOTPRINT_C = 0.2
"""Eq. 8's threshold c (Sec. 3.4: "we empirically set the threshold c = 0.2")."""
PDF_FLOOR = 1e-12

UPDATE_STAGES = ("warmup", "trace probes", "shade probes", "blend", "states")
RESAMPLING_STAGES = ("candidates", "temporal", "spatial")
TRACE_STAGES = ("gbuffer", "bsdf sample", "shadow", "shade z", "shade secondary")

def camera_footprint(depth, cos1):
    """Eq. 8: ``a0 = 4 pi |x_0 - x_1|^2 / cos_1`` (area seen by the camera, up to constants)."""
    return 4.0 * dr.pi * dr.square(depth) / dr.maximum(cos1, 1e-4)


def footprint_term(seg_len, pdf, cos_next, delta):
    """One summand of Eq. 7: ``sqrt(|x_i - x_{i+1}|^2 / (p_i cos_{i+1}))`` (0 for a delta lobe)."""
    v = dr.sqrt(dr.square(seg_len) / dr.maximum(pdf * dr.maximum(cos_next, 1e-4), PDF_FLOOR))
    return dr.select(delta, 0.0, v)


def footprint_np(points, pdfs, normals):
    """NumPy reference of Eq. 7 for one path ``x_1..x_n`` (``pdfs[i]`` at ``x_{i+1}``, solid angle)."""
    points = np.asarray(points, np.float64)
    s = 0.0
    for i in range(len(points) - 1):
        d = points[i + 1] - points[i]
        r = np.linalg.norm(d)
        cos = abs(np.dot(normals[i + 1], d / r))
        s += np.sqrt(r * r / (pdfs[i] * max(cos, 1e-4)))
    return s * s



def _probe_params():
    spec = params_from(DDGI_PLUS_SPECS)
    spec.pop("direct", None)
    spec["normal_bias"] = Param(0.0, "DDGI's query offset along the normal (probe spacings); 0: Sec. 3.5's "
                                "view-path bias replaces it", min=0.0)
    spec["view_bias"] = Param(0.0, "DDGI's query offset towards the viewer (probe spacings); 0: Sec. 3.5's "
                              "view-path bias replaces it", min=0.0)
    return spec


PROBE_KEYS = tuple(_probe_params())

SECONDARY_PARAMS = {
    **{k: Param(**v) for k, v in PARAM_SPECS.items()},
    "progressive": Param(True, "accumulate over frames while the scene is static"),
    **_probe_params(),
    "footprint_c": Param(FOOTPRINT_C, "Eq. 8 threshold c of the footprint termination", min=0.0, max=1e6),
    "max_glossy": Param(3, "most glossy recursion steps after the secondary vertex", min=0, max=16),
    "view_path_bias": Param(0.2, "Sec. 3.5: probe query moved back along the path by this many smallest "
                            "probe spacings (at most half the segment)", min=0.0, max=10.0),
    "exact_radiance": Param(False, "TEST HOOK: path-trace the secondary-vertex radiance where it is shaded "
                            "instead of reading the probes (ddgi-resampling's resampling target keeps the "
                            "probes' value)"),
    "exact_depth": Param(-1, "path depth of the exact_radiance hook (-1: unbounded, Russian roulette)", min=-1),
}



class SecondaryShading(Technique):
    """What ``ddgi-secondary`` and ``ddgi-resampling`` share (module docstring); not registered."""

    HAS_INDIRECT = True
    PROBE_TECHNIQUE = True    # its DDGI+ volume traces probes (dyngi.probes.ddgi_plus)

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        p = self.params
        # -- ReSTIR DI at the primary vertex (the transport layer's component) --
        self.restir = ReSTIRDI.from_params(scene, p)
        self.cand = self.restir.cand
        self.hist = self.restir.hist
        self.accum = ProgressiveMean()
        self.vol = DDGIPlusVolume(scene, {k: p[k] for k in PROBE_KEYS}, mode="plus")
        self.query = self.vol.query
        self.nee = self.vol.nee_lights
        self.s_min = float(np.min(self.vol.probe_spacing))
        self.s_mean = float(np.exp(np.mean(np.log(self.vol.probe_spacing))))
        mscene = scene.mi_scene
        self._has_glossy = any(sh.bsdf() is not None and (
            mi.has_flag(sh.bsdf().flags(), mi.BSDFFlags.GlossyReflection)
            or mi.has_flag(sh.bsdf().flags(), mi.BSDFFlags.DeltaReflection)) for sh in mscene.shapes())
        self.max_glossy = p["max_glossy"] if self._has_glossy else 0
        self.last_recursions = None     # per pixel: glossy recursion steps of the last frame's S(x_2)
        self.record_debug = False       # tests: keep the last frame's per-pixel intermediates in ``debug``
        self.debug = {}

    # -- S(x_n): shading of a secondary vertex (module docstring) ---------------------------------
    def shade_secondary(self, si, ray, beta, a0, pdf_prev, delta_prev, sampler, active, cv=None, exact=None):
        """``beta * S(x_n)`` at the vertices ``si`` reached by ``ray``; returns (L, rays, recursions).

        ``pdf_prev``/``delta_prev``: the sampling pdf (solid angle) and delta flag of the direction that
        led to ``si`` (Eq. 7); ``a0``: Eq. 8's camera footprint per lane. ``cv``: (g, diffuse share)
        for the control variate (Sec. 5.1; the diffuse share of ``beta`` carries ``-g``). ``exact``: the
        ``exact_radiance`` hook on / off for this call (default: the parameter; ``ddgi-resampling`` reads
        the probes for its resampling target under the hook)."""
        p = self.params
        mscene = self.scene.mi_scene
        active = mi.Bool(active)
        beta = mi.Color3f(beta)
        rec = dr.zeros(mi.UInt32, dr.width(active))
        if p["exact_radiance"] if exact is None else exact:
            hit = active & si.is_valid()
            Lp, n_rays, _ = trace_paths(mscene, sampler, ray, hit, p["exact_depth"], 5)
            Le = mi.Color3f(si.emitter(mscene).eval(si, hit))
            return dr.select(hit, beta * (Lp - Le), 0.0), mi.UInt32(n_rays), rec
        thresh = p["footprint_c"] * a0
        bias_len = p["view_path_bias"] * self.s_min
        pdf0 = mi.Float(pdf_prev)
        delta0 = mi.Bool(delta_prev)
        query = self.query
        max_glossy = mi.UInt32(self.max_glossy)

        def shade(v):
            """The probes at ``x_n`` (diffuse part; Eq. 6's glossy lookup where the recursion stops)."""
            si, ray, bsdf = v.si, v.ray, v.bsdf
            wo = -ray.d
            front, n = shading_side(si, ray, bsdf, v.active)
            first = v.depth == 0
            # -- footprint (Eq. 7) and the termination test (Eq. 8) --
            seg = dr.select(v.active, si.t, 0.0)
            sum_sqrt = v.state + footprint_term(seg, dr.select(first, pdf0, v.prev_pdf),
                                                dr.abs(dr.dot(si.n, ray.d)), dr.select(first, delta0, v.prev_delta))
            stop = (dr.square(sum_sqrt) > thresh) | (v.depth >= max_glossy)
            # -- the probes, read at the view-path-biased point (Sec. 3.5) --
            q = si.p - ray.d * dr.minimum(bias_len, 0.5 * seg)
            albedo = diffuse_albedo(bsdf, si, front)
            diff = front & dr.any(albedo > 0.0)
            E = query.irradiance(q, n, wo, active=diff)
            L_v = diffuse_radiance(albedo, E, diff)
            # -- Eq. 6's estimate where the footprint is large (one glossy sample) --
            d_g, w_g, g_end = sample_glossy(bsdf, si, v.sampler.next_1d(), v.sampler.next_2d(), front & stop)
            g_end &= mi.Frame3f.cos_theta(si.to_local(d_g)) * mi.Frame3f.cos_theta(si.wi) > 0.0   # reflection only
            Eg = query.irradiance(q, n, wo, direction=d_g, active=g_end)
            L_v += dr.select(g_end, w_g * Eg * (1.0 / GLOSSY_NORMALISATION), 0.0)
            return L_v, stop | ~front, sum_sqrt

        # the probes' device arrays and fallback table, evaluated before the walk's symbolic loop reads them
        query.fallback_table()
        dev = query.volume.device
        dr.eval(*[a for a in vars(dev).values() if a is not None])
        # -- the glossy recursion: the transport layer's walk from x_n (module docstring) --
        r = walk(mscene, sampler, ray, active, self.max_glossy + 2, -1, self.nee, si=si,
                 emission=lambda depth, prev_delta: depth >= 1, nee=None if self.nee.count else False,
                 shade=shade, state=mi.Float(0.0), mis=False,
                 directions=LobeDirections(GLOSSY_LOBES, reflection_only=True))
        L = dr.select(active, beta * mi.Color3f(r.L), 0.0)
        return L, mi.UInt32(r.n_rays), mi.UInt32(r.bounces)

    # -- probes -------------------------------------------------------------------------
    def _update_probes(self, frame, t):
        self.vol.update(frame, timer=t)

    def _begin(self, frame, t):
        """Probe update, then the ReSTIR DI component's frame set-up (G-buffer, reprojection); returns
        (:class:`~dyngi.transport.restir_di.PrimaryVertex`, Eq. 8's camera footprint ``a0`` per pixel)."""
        self._update_probes(frame, t)
        self.restir.lights_begin(frame, t)
        pv = self.restir.begin(frame, t)
        gb = pv.gb
        return pv, camera_footprint(gb.depth, dr.abs(dr.dot(gb.n_geo, gb.ray.d)))

    def _bsdf_sample(self, gb, bsdf, sampler):
        """One full-BSDF sample at the primary vertex and its hit (the secondary vertex)."""
        mscene = self.scene.mi_scene
        si = gb.si
        v = Vertex(si, si.sh_frame.n, bsdf, None, None, gb.valid)
        d = BSDFDirections().sample(v, None, sampler.next_1d(), sampler.next_2d(), gb.valid)
        w = mi.Color3f(d.weight)
        ok = gb.valid & (d.pdf > 0.0) & dr.all(dr.isfinite(w))
        ray = si.spawn_ray(d.wo)
        si2 = intersect(mscene, ray, mi.RayFlags.All, False, ok, stage="bsdf sample")
        bs = SimpleNamespace(pdf=d.pdf, wo=si.to_local(d.wo))     # the sample's pdf and local direction
        return bs, mi.Color3f(dr.select(ok, w, 0.0)), ok, ray, si2, mi.Bool(d.delta)

    def _finish(self, frame, t, L, L_ind):
        p = self.params
        self.restir.lights_end(t)
        with t.stage("accumulate"):
            self.accum.add(mi.Color3f(L), mi.Color3f(L_ind), accumulate=p["progressive"] and frame.static)
        stats = t.as_dict()
        ms = stats["ms"]
        stats["table2_ms"] = {
            "trace & shade": float(sum(ms.get(k, 0.0) for k in TRACE_STAGES)),
            "resampling": float(sum(ms.get(k, 0.0) for k in RESAMPLING_STAGES)),
            "update": float(sum(ms.get(k, 0.0) for k in UPDATE_STAGES))}
        stats["accumulated_frames"] = self.accum.frames
        stats["spp"] = 1
        return FrameResult(image=to_image(self.accum.mean, frame.res),
                           indirect=to_image(self.accum.mean_ind, frame.res), stats=stats)
