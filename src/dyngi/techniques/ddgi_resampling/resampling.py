"""DDGI Resampling (technique ``ddgi-resampling``; Majercik et al. 2022, Sec. 3.2, 3.6, 3.7).

One reservoir per pixel resamples the union of two disjoint sample spaces (a partition of the
integrand ``T_f (L_e + L_DDGI+)``, our choice, so that no cross pdf is needed):

* part 0, **emission**: ``M = candidates`` emitter samples of
  :class:`~dyngi.lights.candidates.EmitterCandidates` (area lights in area measure, environment in
  solid angle, delta lights as point masses), target ``p0(y) = lum(L_e(y) cos_y / r^2) cos_x``
  (``restir-pt``'s): the emitted light ``L_e`` of the secondary vertex enters *only* here (it is neither
  dropped nor MIS-weighted: the BSDF candidates below do not carry ``L_e`` of smooth-lobe hits);
* part 1, **probes**: one BSDF-sampled secondary hit ``y`` per pixel, converted to area measure
  (pdf ``p_bsdf(w) cos_y / r^2``), stored with its position, geometric normal and the cached value
  ``L_y = S(y)`` computed at its own pixel (Sec. 3.7, query caching: neighbours reuse ``L_y`` instead
  of querying the probes towards themselves), target
  ``p1_x(y) = lum(L_y) cos_x min(cos_y / r^2, G_max)`` -- the **bounded** geometry term of Sec. 3.6.

**BSDF in the target** (``target_bsdf``, default on): the paper resamples "proportional to the sample
contribution", i.e. to ``T_f (L_e + L_DDGI+)`` with the BSDF ``f_r(x_1)`` inside; both parts' ``cos_x``
becomes ``lum(f_r(x_1, w) cos_x)`` of the domain's own primary vertex (a separable product of
luminances, our choice), so glossy primary surfaces resample towards their lobe. A neighbour's or the
previous frame's target gathers that pixel's surface interaction (the G-buffer keeps it) and evaluates
its BSDF. Off: ``cos_x`` alone (the BSDF-free target ``restir-pt`` uses).

**Visibility in the reservoir** (``visibility_reuse`` of the ReSTIR DI component, default ``'unbiased'``,
chosen by measurement: per-frame MAPE as low as ``'candidate'``'s on villa-sun and room-door, and no
darkening in a window-lit room; docs/techniques/ddgi-resampling.md). ``'candidate'`` (Bitterli et al.
Alg. 5): the emitter
part's chosen candidate gets one shadow ray before it meets the BSDF candidate and before any reuse; an
occluded one weighs 0, so in shadow the reservoir keeps the (always visible) BSDF candidate instead of an
occluded light sample. ``'final'``: the final shadow ray's visibility is written into the stored
reservoir instead (no extra ray, occluded samples are not reused next frame); ``'none'``: neither.
Either way the estimate at the pixel itself stays unbiased (the shading multiplies by the same
visibility); reuse then spreads visibility-weighted samples, a darkening bias at shadow edges that
``tests/techniques/test_restir.py`` bounds for the shared component. ``'unbiased'`` (**unbiased**; Bitterli
et al.'s unbiased variant, the component's option): the candidate's shadow ray of ``'candidate'``, and the
temporal and spatial MIS weights over ``p_hat_j(y) V_j(y)`` of the final sample of either part at each
domain (this pixel, each neighbour, the previous pixel; :meth:`_visible_sample`: a ray to the emitter
sample, or to the point ``y`` of a probe sample), one shadow ray per domain other than the sample's own
(every stored reservoir holds a sample visible from its pixel, or ``W = 0``); it subsumes
``reuse_visibility`` (ignored with it), whose rays it traces only for the final sample.

Visibility of reused probe samples (``reuse_visibility``, default off): a BSDF candidate exists only
where the point is the first hit from its pixel, so strictly a domain's target for a part-1 sample
needs a shadow ray to it, both when it is merged (temporal, spatial) and in the MIS weights of the
other domains (as unbiased ReSTIR GI does); without it a neighbour that cannot see the sample still
takes a share of its MIS weight (a darkening bias where neighbours are occluded). Off by default (our
choice: +50 % frame time; figures in docs/techniques/ddgi-resampling.md), on for the strictly unbiased estimator.

Under the ``exact_radiance`` test hook the cached ``L_y`` is still the probes' ``S(y)`` (one extra probe
shading per pixel), while the residual and the resampled vertex ``z`` are shaded by path tracing
(:mod:`.shading`): the hook takes the probes' bias out of the estimate, not out of the target.

``L_y`` is a random value (glossy recursion, NEE) that can be 0 where its expectation is not; a target that vanishes there would lose that light (the resampled vertex is
shaded with a fresh ``S(z)``). Our choice: a defensive floor, ``lum(L_y) + eps`` with ``eps`` =
``target_floor`` (0.01) x the frame's mean ``lum(L_y)`` (one per frame, the same for every domain of
that frame; the previous frame's is kept for temporal reuse), so the target's support is every
visible surface point and the estimator stays unbiased.

The candidates are combined by RIS with MIS weights ``1/M`` among the emitter candidates and 1 for the
BSDF candidate (the parts are disjoint); then 1 temporal and ``spatial`` (3) neighbours are merged
(unbiased ``'mis'`` combination by default), and one shadow ray goes to the selected sample ``z`` (for
part 1 a full intersection whose hit must be ``z``, giving the surface at ``z`` for shading).

Eq. 9: ``L = L_e(x_1) + [part 0: f L_e G V W] + [part 1: f S(z) min(J, G_max) V W]
+ [residual: beta_1 S(y) max(1 - G_max / J, 0)]`` with ``J = cos_y / r^2`` and ``y`` the same BSDF
sample that made the part-1 candidate (the floor(T_f) term, Fig. 2's "y"). ``S`` is evaluated twice
per pixel (at ``y`` and at ``z``), each with its own glossy recursion, as the paper's Table 2 counts.
Our choice: the bound applies to the probe part only; emitted light keeps ReSTIR DI's unbounded
geometry term (its candidates are area samples of the emitters, whose weights do not blow up in
creases the way BSDF-sampled hits of nearby walls do, Fig. 6).

``G_max`` (not scale invariant, Sec. 3.6), parameter ``gmax_scale``: ``'none'`` (default) the
constant ``G_max = gmax`` (the paper's ``G_max = 1``: "the differential under solid angle measure is
always less than or equal to the differential under area measure"); ``'a0'``
``G_max = gmax * 4 pi / a0(x_1) = gmax cos_1 / |x_0 - x_1|^2`` (the paper's suggestion for scale
invariance, proportional to the inverse camera footprint); ``'probe'`` ``G_max = gmax / s^2`` with
``s`` the mean probe spacing (points closer than about one probe cell go to the BSDF sample; scales
with the scene; our option). ``gmax = 0`` sends all probe light through the BSDF sample (the
unpartitioned estimate the z-test in ``tests/techniques/ddgi_resampling/test_technique.py`` compares against).

Temporal reuse: the M cap (``m_cap``, in multiples of the ``candidates + 1`` a fresh reservoir holds)
defaults to :data:`M_CAP`, chosen for the steady per-frame error (a sweep over {1, 4, 20},
docs/techniques/ddgi-resampling.md); ``restir-pt`` keeps Bitterli's 20. The spatial radius is
``restir-pt``'s: pixels at 1080p, scaled with the image width.
"""
from __future__ import annotations

from ...backend import dr, mi
from ...probes.lookup import diffuse_radiance
from ...rays import intersect, occluded
from ...sampling.diffuse import diffuse_albedo
from ...sampling.reservoir import Reservoir
from ...sampling.rng import make_sampler
from ...transport.restir_di import VISIBILITY_REUSE, initial_candidates, target
from ..base import Frame, FrameResult, Param, StageTimer, register
from .control_variate import NearestRayCV, cube_bin
from .shading import _SHADE_STREAM, SECONDARY_PARAMS, SecondaryShading, camera_footprint

_FINAL_STREAM = 0x5EC1
"""RNG stream of the shading of the resampled vertex z."""
SAME_POINT_TOL = 1e-2
"""The ray towards the resampled point ``z`` sees ``z`` when its first hit is no closer than
``r (1 - tol) - tol s_min`` (relative to the distance and to the smallest probe spacing; the ray
origin's offset moves the hit by ~1e-3 scene units, measured; our choice)."""


def bounded_fraction(J, gmax):
    """(resampled share ``min(J, G_max) / J``, residual share ``max(1 - G_max / J, 0)``) of Eq. 9."""
    ok = J > 0.0
    res = dr.select(ok, dr.maximum(1.0 - gmax / dr.maximum(J, 1e-30), 0.0), 0.0)
    return dr.select(ok, 1.0 - res, 0.0), res



M_CAP = 4.0
"""ddgi-resampling's temporal M cap in multiples of a fresh reservoir's M (our choice, measured for the
steady per-frame error: docs/techniques/ddgi-resampling.md). A larger cap lets the previous frame's
reservoir outweigh the new candidates; where the target changes between the jittered primary points of
two frames (grazing secondary points) the balance heuristic amplifies an old sample's weight up to that
ratio, so a sample sticks for more frames."""


def _resampling_params():
    out = dict(SECONDARY_PARAMS)
    out["m_cap"] = Param(M_CAP, "temporal M cap in multiples of the candidates per pixel (restir-pt: 20; "
                         "see the module docstring)", min=0.0, max=1e4)
    # the unbiased reuse by default (Bitterli et al.'s unbiased variant in both parts): per-frame MAPE at 64x36, 3 seeds,
    # villa-sun 0.271 (+- 0.017) vs 0.280 for 'candidate' and 1.04 for 'none', room-door 0.311 vs 0.317; 'candidate'
    # leaves living-room 16 % dark away from the walls with the probes' bias taken out, 'unbiased' +-2 %
    # (docs/techniques/ddgi-resampling.md)
    out["visibility_reuse"] = Param("unbiased", "visibility in the unified reservoir: 'unbiased' (unbiased; the "
                                    "default: the reuse's MIS weights over p_hat_j V_j of the final sample of "
                                    "either part, one shadow ray per other domain; subsumes reuse_visibility; "
                                    "per-frame MAPE on villa-sun 0.27 vs 0.28 for 'candidate', 1.04 for 'none'), "
                                    "'candidate' (Bitterli Alg. 5: a shadow ray to the initial emitter candidate "
                                    "before reuse, W = 0 if occluded), 'final' (the final shadow ray's visibility "
                                    "written back into the stored reservoir), 'none' (no visibility; 'candidate', "
                                    "'final' and 'none' are biased here: the MIS weights ignore visibility). "
                                    "Ours: the paper traces one shadow ray, to the selected sample (Sec. 3, "
                                    "step 3: 'none'); its paper-literal row runs 'none'",
                                    choices=VISIBILITY_REUSE, ours=True, paper="none")
    out.update({
        "gmax": Param(1.0, "bound G_max of the resampled geometry term cos_y/r^2 (Eq. 9), in the units "
                      "gmax_scale sets; 0: all probe light by the BSDF sample", min=0.0, max=1e9),
        "gmax_scale": Param("none", "how G_max scales with the scene: 'none' the constant gmax (the paper's "
                            "G_max = 1), 'a0' gmax*4pi/a0 (Eq. 8), 'probe' gmax/s^2 (s: mean probe spacing)",
                            choices=("probe", "a0", "none")),
        "target_bsdf": Param(True, "the primary vertex's BSDF in the target: lum(f_r cos) instead of cos "
                             "(glossy primary surfaces resample towards their lobe)"),
        "reuse_visibility": Param(False, "shadow ray per reused probe sample and domain (temporal and spatial "
                                  "merges and their MIS weights): the unbiased reuse of BSDF-sampled points "
                                  "(+50 % frame time at 640x360); off: the supports are approximate"),
        "target_floor": Param(0.01, "defensive floor of the part-1 target, a fraction of the frame's mean "
                              "cached L_y (keeps the support of a noisy cached value full: unbiased)",
                              min=1e-6, max=1e3),
        "control_variate": Param(False, "Sec. 5.1: DDGI+ irradiance at the primary vertex as a control "
                                 "variate of the diffuse transport (may give negative pixels)"),
        "cv_kind": Param("constant", "control variate g of control_variate: 'constant' E_DDGI+(x_1)/pi, "
                         "'nearest-ray' the nearest probe's last update rays binned by direction (Sec. 5.1's "
                         "piecewise-constant one)", choices=("constant", "nearest-ray")),
    })
    return out



@register
class DDGIResamplingTechnique(SecondaryShading):
    """DDGI Resampling: ReSTIR over emitter samples + BSDF-sampled secondary hits, target L_e + L_DDGI+."""

    name = "ddgi-resampling"
    description = ("DDGI Resampling (Majercik et al. 2022): one reservoir over emitter samples and BSDF "
                   "secondary hits (area measure, bounded G, Eq. 9), DDGI+ query caching, 1 temporal + 3 "
                   "spatial neighbours, one shadow ray")
    PARAMS = _resampling_params()

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        self.prev_gmax = None
        self.prev_g = None
        self.prev_eps = 0.0
        self._vis_rays = []
        p = self.params
        self._unbiased = p["visibility_reuse"] == "unbiased"
        self.cvnr = NearestRayCV(self.vol) if p["control_variate"] and p["cv_kind"] == "nearest-ray" else None

    # -- G_max (Sec. 3.6) ---------------------------------------------------------------------------
    def _gmax(self, gb):
        p = self.params
        if p["gmax_scale"] == "a0":
            cos1 = dr.abs(dr.dot(gb.n_geo, gb.ray.d))
            return dr.select(gb.valid, p["gmax"] * 4.0 * dr.pi / camera_footprint(gb.depth, cos1), 0.0)
        g = p["gmax"] / (self.s_mean ** 2) if p["gmax_scale"] == "probe" else p["gmax"]
        return dr.full(mi.Float, float(min(g, 1e9)), dr.width(gb.valid))

    # -- target p_hat (module docstring) --------------------------------------------------------------
    def _visible(self, pos, ng, y, active):
        """Is ``y`` visible from the surface point ``pos`` (geometric normal ``ng``)? One shadow ray."""
        d = y - pos
        side = dr.select(dr.dot(ng, d) >= 0.0, 1.0, -1.0)
        o = pos + ng * (side * 1e-4 * (1.0 + dr.max(dr.abs(pos))))
        d = y - o
        dist = dr.norm(d)
        ray = mi.Ray3f(o, d / dr.maximum(dist, 1e-30))
        ray.maxt = dist * (1.0 - SAME_POINT_TOL)
        return mi.Bool(active) & ~occluded(self.scene.mi_scene, ray, active, stage="spatial")

    def _visible_sample(self, pos, ng, sample, time, active, stage):
        """``visibility_reuse='unbiased'``: is the unified reservoir's ``sample`` (either part) visible from
        the surface point ``pos`` (geometric normal ``ng``)? One shadow ray per ``active`` lane: to the
        emitter sample (part 0; along its direction for lights at infinity) or to the point ``y`` (part 1).
        Returns (visible, lanes that traced a ray)."""
        part, k, pl, y, ny, Ly = sample
        active = mi.Bool(active)
        p0 = active & (part == 0)
        tgt = mi.Point3f(y)
        fin = mi.Bool(True)
        d_inf = mi.Vector3f(0.0)
        if self.cand.count:
            ev = self.cand.evaluate(pos, k, pl, time, p0)
            p0 &= ev.valid
            tgt = dr.select(p0, ev.p_light, tgt)
            fin = ~p0 | dr.isfinite(ev.dist)
            d_inf = ev.wi
        else:
            p0 = mi.Bool(False) & active
        lanes = p0 | (active & (part == 1))
        d = dr.select(fin, tgt - pos, d_inf)
        side = dr.select(dr.dot(ng, d) >= 0.0, 1.0, -1.0)
        o = pos + ng * (side * 1e-4 * (1.0 + dr.max(dr.abs(pos))))
        d = dr.select(fin, tgt - o, d_inf)
        dist = dr.norm(d)
        ray = mi.Ray3f(o, d / dr.maximum(dist, 1e-30))
        ray.maxt = dr.select(fin, dist * (1.0 - SAME_POINT_TOL), dr.inf)
        return lanes & ~occluded(self.scene.mi_scene, ray, lanes, stage=stage), lanes

    def _bsdf_factor(self, sid, w, active):
        """``lum(f_r(x, w) cos)`` at the domain's primary vertex ``sid`` (a surface interaction whose ``wi``
        points to its camera) towards world direction ``w``: the BSDF factor of the target."""
        f = sid.bsdf().eval(mi.BSDFContext(), sid, sid.to_local(w), active)
        return dr.select(active, mi.luminance(mi.Color3f(f)), 0.0)

    def _emitter_target(self, si):
        """The part-0 target of the initial candidates at the primary vertices ``si`` (as :meth:`_target`)."""
        if not self.params["target_bsdf"]:
            return target

        def fn(n, two, ev):
            return dr.select(ev.valid, mi.luminance(ev.Lg) * self._bsdf_factor(si, ev.wi, ev.valid), 0.0)
        return fn

    def _target(self, pos, n, two, gmax, sample, time, active, g=None, eps=0.0, ng=None, sid=None):
        """``p_hat`` of ``sample`` at the domain (pos, n, two, gmax, primary vertex ``sid``); with ``ng``
        (the domain's geometric normal) and ``reuse_visibility``, part-1 samples not visible from ``pos``
        get 0 (one shadow ray). With ``target_bsdf`` the cosine ``cos_x`` becomes ``lum(f_r cos_x)`` of the
        domain's BSDF (module docstring)."""
        part, k, pl, y, ny, Ly = sample
        active = mi.Bool(active)
        p0 = active & (part == 0)
        p1 = active & (part == 1)
        use_f = self.params["target_bsdf"]
        ph = mi.Float(0.0)
        d = y - pos
        r2 = dr.squared_norm(d)
        wdir = d * dr.rsqrt(dr.maximum(r2, 1e-30))
        if self.cand.count:
            ev = self.cand.evaluate(pos, k, pl, time, p0)
            if use_f:
                wdir = dr.select(p0, ev.wi, wdir)
            else:
                ph = dr.select(p0, target(n, two, ev), 0.0)
        if use_f:   # one BSDF evaluation per lane, towards the sample of either part
            fx = self._bsdf_factor(sid, wdir, active)
            if self.cand.count:
                ph = dr.select(p0 & ev.valid, mi.luminance(ev.Lg) * fx, 0.0)
            cx = fx
        else:
            cx = dr.dot(n, wdir)
            cx = dr.select(two, dr.abs(cx), dr.maximum(cx, 0.0))
        J = dr.maximum(dr.dot(ny, -wdir), 0.0) / dr.maximum(r2, 1e-30)
        if g is None:
            val = mi.luminance(Ly) + eps
        else:   # |L_y - g| (Sec. 5.1); nearest-ray: g = (luminance table, probe) looked up towards y
            gl = g if not isinstance(g, tuple) else \
                dr.gather(mi.Float, g[0], g[1] * self.cvnr.B + cube_bin(wdir, self.cvnr.K), p1)
            val = dr.abs(mi.luminance(Ly) - gl) + eps
        ph1 = val * cx * dr.minimum(J, gmax)
        ok1 = p1 & (r2 > 0.0) & dr.isfinite(ph1) & (ph1 > 0.0)
        if ng is not None and self.params["reuse_visibility"] and not self._unbiased:
            ok1 = self._visible(pos, ng, y, ok1)
            self._vis_rays.append(dr.count(ok1))
        return dr.select(ok1, ph1, dr.select(p1, 0.0, ph))

    def _cv_primary(self, gb, bsdf):
        """The control variate of Sec. 5.1 at the primary vertex: (``g``, its exact diffuse integral).

        ``g = E_DDGI+(x_1) / pi``, a constant radiance over the hemisphere (probes read at the primary
        vertex with DDGI's default biases, 0.05 / 0.2 smallest spacings along the normal / towards the
        viewer); its integral against the diffuse lobe is ``rho_1 g`` exactly for a Lambertian lobe
        (``rho_1`` :func:`~dyngi.sampling.diffuse.diffuse_albedo`). ``tests/techniques/ddgi_resampling/test_control_variate.py`` checks that
        the estimator's mean does not move with the control variate, and that a wrong integral (this
        method's second value scaled) is detected."""
        n = gb.n_sh
        albedo1 = diffuse_albedo(bsdf, gb.si, gb.valid)
        if self.cvnr is not None:   # nearest-ray: g is looked up per direction; first value the probe
            probe = self.cvnr.nearest_probe(gb.pos)
            return probe, diffuse_radiance(albedo1, self.cvnr.integral(probe, n, gb.valid), gb.valid)
        E1 = self.query.irradiance(gb.pos + n * (0.05 * self.s_min) - gb.ray.d * (0.2 * self.s_min),
                                   n, -gb.ray.d, active=gb.valid)
        g_col = mi.Color3f(E1 * dr.inv_pi)
        return g_col, dr.select(gb.valid, albedo1 * g_col, 0.0)

    def _cv_value(self, g, w, active):
        """``g(w)`` (Color3f) of the lanes' control variate (``g``: :meth:`_cv_primary`'s first value)."""
        return g if self.cvnr is None else self.cvnr.value(g, w, active)

    def _cv_target_g(self, g):
        """The control variate in the form :meth:`_target` takes (luminance, or (table, probe))."""
        return mi.luminance(g) if self.cvnr is None else (self.cvnr.lum, g)

    def _gather_si(self, si, idx, active):
        """The primary vertices ``si`` at lanes ``idx`` (only with ``target_bsdf``, which evaluates their BSDF)."""
        return dr.gather(mi.SurfaceInteraction3f, si, idx, active) if self.params["target_bsdf"] else None

    @staticmethod
    def _gather_g(g, idx, active):
        if g is None:
            return None
        if isinstance(g, tuple):
            return (g[0], dr.gather(mi.UInt32, g[1], idx, active))
        return dr.gather(mi.Float, g, idx, active)

    def step(self, frame: Frame) -> FrameResult:
        p = self.params
        t = StageTimer()
        mscene = self.scene.mi_scene
        npix = frame.res[0] * frame.res[1]
        pv, a0 = self._begin(frame, t)
        sampler, time, gb, bsdf, smooth = pv.sampler, pv.time, pv.gb, pv.bsdf, pv.smooth
        si, n, two = gb.si, gb.n_sh, gb.transmissive
        gmax = self._gmax(gb)
        ctx = mi.BSDFContext()
        cv = p["control_variate"]

        # -- control variate at the primary vertex (Sec. 5.1): g = E_DDGI+(x_1) / pi --
        g_lum, L_cv = None, mi.Color3f(0.0)
        if cv:
            with t.stage("shade secondary"):
                if self.cvnr is not None:
                    self.cvnr.refresh()
                g_col, L_cv = self._cv_primary(gb, bsdf)
                g_lum = self._cv_target_g(g_col)
                dr.eval(L_cv, g_col)
            if self.cvnr is not None:
                t.add_rays("shade secondary", self.cvnr.extra_rays)

        # -- the BSDF sample y: secondary hit, S(y) (cached L_y), the part-1 candidate --
        with t.stage("bsdf sample"):
            ss = make_sampler(npix, frame.seed, frame.index, _SHADE_STREAM)
            bs, w, ok, ray, si_y, delta = self._bsdf_sample(gb, bsdf, ss)
            S_y, rays_y, rec = self.shade_secondary(si_y, ray, mi.Color3f(1.0), a0, bs.pdf, delta, ss, ok)
            L_y = S_y    # the cached value of the part-1 target (Sec. 3.7)
            if p["exact_radiance"]:   # the hook shades with path tracing; the target keeps the probes' S(y)
                L_y, rays_c, rec = self.shade_secondary(si_y, ray, mi.Color3f(1.0), a0, bs.pdf, delta, ss, ok,
                                                        exact=False)
                rays_y = rays_y + rays_c
            hit_y = ok & si_y.is_valid()
            ny = dr.select(dr.dot(si_y.n, ray.d) > 0.0, -si_y.n, si_y.n)
            r2 = dr.select(hit_y, dr.square(si_y.t), 0.0)
            J_y = dr.select(hit_y, dr.abs(dr.dot(si_y.n, ray.d)) / dr.maximum(r2, 1e-30), 0.0)
            is_cand = smooth & ok & ~delta & hit_y
            _, resid = bounded_fraction(J_y, gmax)
            # defensive floor of the part-1 target (module docstring): a fraction of the frame's mean L_y
            eps = p["target_floor"] * dr.mean(dr.select(is_cand, mi.luminance(L_y), 0.0)) + 1e-12
            dr.eval(S_y, L_y, rays_y, rec, J_y, ny, eps)
        t.add_rays("bsdf sample", dr.count(ok))
        t.add_rays("bsdf sample", dr.sum(rays_y))
        self.last_recursions = rec

        # -- initial candidates: M emitter samples (part 0) + the BSDF hit (part 1) --
        cand_rays = None
        with t.stage("candidates"):
            M_e = p["candidates"] if self.cand.count else 0
            if M_e:
                k, pl, w_sum_e, ph_e = initial_candidates(self.cand, si, n, two, smooth, sampler, M_e, time,
                                                          self._emitter_target(si))
                if self.restir.visibility_reuse in ("candidate", "unbiased"):
                    # Alg. 5: the emitter part's chosen candidate is shadow-tested before it meets the BSDF
                    # candidate and before reuse; an occluded one weighs 0, so the BSDF candidate is kept
                    vis_e, traced_e = self.restir.candidate_visibility(gb, (k, pl), smooth & (w_sum_e > 0.0), time)
                    w_sum_e = dr.select(vis_e, w_sum_e, 0.0)
                    cand_rays = dr.count(traced_e)
            else:
                k, pl = dr.zeros(mi.UInt32, npix), dr.zeros(mi.Vector3f, npix)
                w_sum_e, ph_e = dr.zeros(mi.Float, npix), dr.zeros(mi.Float, npix)
            y = mi.Point3f(si_y.p)
            s1 = (dr.full(mi.UInt32, 1, npix), dr.zeros(mi.UInt32, npix), dr.zeros(mi.Vector3f, npix), y,
                  mi.Vector3f(ny), mi.Color3f(L_y))
            ph_b = self._target(gb.pos, n, two, gmax, s1, time, is_cand, g_lum, eps, sid=si)
            # RIS weight of the BSDF candidate: p_hat / (p_bsdf(w) J)
            w_b = dr.select(is_cand & (ph_b > 0.0), ph_b / dr.maximum(bs.pdf * J_y, 1e-30), 0.0)
            wsum = (w_sum_e / M_e if M_e else 0.0) + w_b
            take_b = (w_b > 0.0) & (sampler.next_1d() * wsum < w_b)
            zero3 = dr.zeros(mi.Point3f, npix)
            sample = (dr.select(take_b, 1, dr.zeros(mi.UInt32, npix)), dr.select(take_b, 0, k),
                      dr.select(take_b, mi.Vector3f(0.0), pl), dr.select(take_b, y, zero3),
                      dr.select(take_b, mi.Vector3f(ny), mi.Vector3f(0.0)),
                      dr.select(take_b, mi.Color3f(L_y), mi.Color3f(0.0)))
            ph = dr.select(take_b, ph_b, ph_e)
            M = float(M_e + 1)
            r = Reservoir(sample, wsum * M, dr.select(smooth, M, 0.0), ph,
                          dr.select(smooth & (ph > 0.0), wsum / dr.maximum(ph, 1e-30), 0.0),
                          dr.zeros(mi.UInt32, npix))
            dr.eval(*r.arrays())
        if cand_rays is not None:
            t.add_rays("candidates", cand_rays)

        # -- temporal reuse (1 neighbour: the reprojected pixel) --
        with t.stage("temporal"):
            def here(sample, ok):
                return self._target(gb.pos, n, two, gmax, sample, time, ok, g_lum, eps, gb.n_geo, si)

            def there_prev(prev, pix, sample, ok):
                ppos = dr.gather(mi.Point3f, prev.pos, pix, ok)
                pn = dr.gather(mi.Vector3f, prev.n_sh, pix, ok)
                ptwo = dr.gather(mi.Bool, prev.transmissive, pix, ok)
                pg = dr.gather(mi.Float, self.prev_gmax, pix, ok)
                pcv = self._gather_g(self.prev_g, pix, ok) if cv else None
                png = dr.gather(mi.Vector3f, prev.n_geo, pix, ok)
                psi = self._gather_si(prev.si, pix, ok)
                return self._target(ppos, pn, ptwo, pg, sample, time, ok, pcv, self.prev_eps, png, psi)

            def vis_here(sample, ok):
                v, traced = self._visible_sample(gb.pos, gb.n_geo, sample, time, ok, "temporal")
                t.add_rays("temporal", dr.count(traced))
                return v

            def vis_prev(prev, pix, sample, ok):
                v, traced = self._visible_sample(dr.gather(mi.Point3f, prev.pos, pix, ok),
                                                 dr.gather(mi.Vector3f, prev.n_geo, pix, ok), sample, time, ok,
                                                 "temporal")
                t.add_rays("temporal", dr.count(traced))
                return v

            self.restir.temporal_reuse(r, gb, pv.reproj, smooth, sampler, M, here, there_prev, vis_here, vis_prev)

        # -- spatial reuse --
        with t.stage("spatial"):
            if p["spatial"] > 0:
                r = self._spatial_r(gb, r, smooth, sampler, time, gmax, g_lum, eps)

        # -- one shadow ray to z; shading: part 0 f Le G W, part 1 f S(z) min(J, G_max) W --
        with t.stage("shadow"):
            part, k, pl, yz, nz, _ = r.sample
            p0 = smooth & (r.W > 0.0) & (part == 0)
            p1 = smooth & (r.W > 0.0) & (part == 1)
            direct = mi.Color3f(0.0)
            shadow_lanes = occluded = mi.Bool(False)
            if self.cand.count:
                direct, shadow_lanes, occluded = self.restir.shade(gb, bsdf, (k, pl), r.W, p0, time,
                                                                   known_visible=self._unbiased)
            dz = yz - gb.pos
            rz = dr.norm(dz)
            wz = dz / dr.maximum(rz, 1e-30)
            # the ray passes exactly through z (spawn_ray_to aims from the offset origin), not stopping
            # short of it: its first hit is z when z is visible, and gives the surface at z for shading
            ray_z = si.spawn_ray_to(yz)
            t_to_z = mi.Float(ray_z.maxt)    # a copy: the assignment below writes into the field
            ray_z.maxt = dr.inf
            si_z = intersect(mscene, ray_z, mi.RayFlags.All, False, p1, stage="shadow")
            vis_z = p1 & si_z.is_valid() & (si_z.t >= t_to_z * (1.0 - SAME_POINT_TOL) - SAME_POINT_TOL * self.s_min)
            # the geometry term of the stored sample (the target's, Eq. 9's integrand in area measure)
            J_z = dr.maximum(dr.dot(nz, -wz), 0.0) / dr.maximum(dr.square(rz), 1e-30)
            f1, pdf1 = bsdf.eval_pdf(ctx, si, si.to_local(wz), vis_z)
            beta_z = dr.select(vis_z, mi.Color3f(f1) * dr.minimum(J_z, gmax) * r.W, 0.0)
            W_shade = r.W
            if self.restir.visibility_reuse == "final":    # occluded samples are not reused next frame
                self.restir.store_visibility(r, occluded | (p1 & ~vis_z))
            dr.eval(direct, vis_z, beta_z, r.W)
        t.add_rays("shadow", dr.count(shadow_lanes | p1))
        with t.stage("shade z"):
            sz = make_sampler(npix, frame.seed, frame.index, _FINAL_STREAM)
            L_z, rays_z, _ = self.shade_secondary(si_z, ray_z, beta_z, a0, pdf1, mi.Bool(False), sz, vis_z)
            if cv:   # the diffuse lobe's share carries the difference to g (Sec. 5.1)
                f1d = bsdf.eval(mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.DiffuseReflection),
                                si, si.to_local(wz), vis_z)
                L_z -= dr.select(vis_z, mi.Color3f(f1d) * dr.minimum(J_z, gmax) * W_shade
                                 * self._cv_value(g_col, wz, vis_z), 0.0)
            dr.eval(L_z, rays_z)
        t.add_rays("shade z", dr.sum(rays_z))

        # -- residual floor(T_f): the BSDF sample y with max(1 - G_max/J, 0); delta lobes: all of it --
        with t.stage("shade secondary"):
            Le_y = mi.Color3f(si_y.emitter(mscene).eval(si_y, ok & (delta | ~smooth)))
            full = ok & (delta | ~smooth)
            share = dr.select(full, 1.0, dr.select(smooth & ok, resid, 0.0))
            L_res = dr.select(ok, w * S_y * share, 0.0)
            L_res_d = dr.select(full, w * Le_y, 0.0)
            if cv:   # -g for the diffuse lobe's residual share (misses included: J = 0 -> share 1)
                share_cv = dr.select(smooth & ok & ~delta, dr.select(hit_y, resid, 1.0), 0.0)
                f_d = bsdf.eval(mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.DiffuseReflection),
                                si, bs.wo, ok & ~delta)
                diff_w = dr.select(ok & ~delta, mi.Color3f(f_d) / dr.maximum(bs.pdf, 1e-30), 0.0)
                L_res -= diff_w * share_cv * self._cv_value(g_col, si.to_world(bs.wo), ok & ~delta)
            dr.eval(L_res, L_res_d)

        if self.record_debug:
            self.debug = {"L_z": L_z, "L_res": L_res, "S_y": S_y, "w": w, "p1": p1, "vis_z": vis_z,
                          "is_cand": is_cand, "W": W_shade, "part": part, "t_z": si_z.t, "r_z": rz,
                          "valid_z": si_z.is_valid()}
        for c in self._vis_rays:
            t.add_rays("spatial", c)
        self._vis_rays = []
        self.restir.prev_res = r
        self.prev_gmax = gmax
        self.prev_g = g_lum
        self.prev_eps = eps
        Le0 = si.emitter(mscene).eval(si, mi.Bool(True))
        L_ind = L_z + L_res + L_cv
        return self._finish(frame, t, Le0 + direct + L_res_d + L_ind, L_ind)

    def _spatial_r(self, gb, r_t, active, sampler, time, gmax, g_lum, eps):
        """Spatial reuse over ``spatial`` neighbours in a disk (Bitterli Alg. 4/5/6) with this target
        (the ReSTIR DI component's :meth:`~dyngi.transport.restir_di.ReSTIRDI.spatial_reuse`)."""
        def here(sample, ok):
            return self._target(gb.pos, gb.n_sh, gb.transmissive, gmax, sample, time, ok, g_lum, eps, gb.n_geo,
                                gb.si)

        def domain(nid, npos, nn, ntwo, act):
            return (npos, nn, ntwo, dr.gather(mi.Float, gmax, nid, act), self._gather_g(g_lum, nid, act),
                    dr.gather(mi.Vector3f, gb.n_geo, nid, act), self._gather_si(gb.si, nid, act))

        def there(dom, sample, ok):
            npos, nn, ntwo, ngmax, ng, nng, nsi = dom
            return self._target(npos, nn, ntwo, ngmax, sample, time, ok, ng, eps, nng, nsi)

        def vis_here(sample, ok):
            v, traced = self._visible_sample(gb.pos, gb.n_geo, sample, time, ok, "spatial")
            self._vis_rays.append(dr.count(traced))
            return v

        def vis_there(nid, sample, ok):
            v, traced = self._visible_sample(dr.gather(mi.Point3f, gb.pos, nid, ok),
                                             dr.gather(mi.Vector3f, gb.n_geo, nid, ok), sample, time, ok, "spatial")
            self._vis_rays.append(dr.count(traced))
            return v

        return self.restir.spatial_reuse(gb, r_t, active, sampler, here, domain, there, vis_here, vis_there)

