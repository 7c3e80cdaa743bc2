"""Secondary DDGI and DDGI Resampling (Majercik, Mueller, Keller, Nowrouzezahrai, McGuire 2022).

Both techniques are the ``restir-pt`` base (G-buffer, ReSTIR reservoirs, area-measure light
candidates) with the rest of the path after the secondary vertex replaced by the DDGI+ probes of
:class:`~dyngi.probes.ddgi_plus.DDGIPlusVolume` (Sec. 3.3, Eq. 5: the probes hold ``L_DDGI+ ~ T_f L``,
direct light from emitting surfaces and the sky included; delta lights and a sunsky's sun are added by
NEE at every point where the probes are read, since no probe ray can hit them).

Shading a secondary vertex, ``S(x_n)`` (Sec. 3.4-3.5; used by both techniques)
-------------------------------------------------------------------------------
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
* **view-path self-shadow bias** (Sec. 3.5): the probes are read at ``q = x_n - d * w_in``, moved back
  along the incoming path segment, with ``d = min(view_path_bias * s_min, 0.5 |x_n - x_{n-1}|)``,
  ``s_min`` the smallest probe spacing ("proportional to the probe size"; default factor 0.2 =
  DDGI's ``view_bias``, our choice; the clamp to half the segment keeps ``q`` in free space, which is
  the point of the method). DDGI's own normal/view biases are off by default (``normal_bias`` and
  ``view_bias`` stay available for a Fig. 5 comparison).

``ddgi-secondary`` (Secondary DDGI, Sec. 4 item 3)
-------------------------------------------------
``L = L_e(x_1) + ReSTIR DI(x_1) + beta_1 * S(x_2)`` with ``x_2`` one full-BSDF sample at the primary
vertex (and ``beta_1 L_e(x_2)`` when that sample went through a delta lobe, which ReSTIR's light
samples cannot reach). The ReSTIR DI stages are ``restir-pt``'s (candidates, temporal, spatial, one
shadow ray).

``ddgi-resampling`` (DDGI Resampling, Sec. 3.2, 3.6, 3.7)
-------------------------------------------------------
One reservoir per pixel resamples the union of two disjoint sample spaces (a partition of the
integrand ``T_f (L_e + L_DDGI+)``, our choice, so that no cross pdf is needed):

* part 0, **emission**: ``M = candidates`` emitter samples of
  :class:`~dyngi.sampling.candidates.EmitterCandidates` (area lights in area measure, environment in
  solid angle, delta lights as point masses), target ``p0(y) = lum(L_e(y) cos_y / r^2) cos_x``
  (``restir-pt``'s): the emitted light ``L_e`` of the secondary vertex enters *only* here (it is neither
  dropped nor MIS-weighted: the BSDF candidates below do not carry ``L_e`` of smooth-lobe hits);
* part 1, **probes**: one BSDF-sampled secondary hit ``y`` per pixel, converted to area measure
  (pdf ``p_bsdf(w) cos_y / r^2``), stored with its position, geometric normal and the cached value
  ``L_y = S(y)`` computed at its own pixel (Sec. 3.7, query caching: neighbours reuse ``L_y`` instead
  of querying the probes towards themselves), target
  ``p1_x(y) = lum(L_y) cos_x min(cos_y / r^2, G_max)`` -- the **bounded** geometry term of Sec. 3.6.

Visibility in reuse (``reuse_visibility``, default off): a BSDF candidate exists only where the point
is the first hit from its pixel, so strictly a domain's target for a part-1 sample needs a shadow ray
to it, both when it is merged (temporal, spatial) and in the MIS weights of the other domains (as
unbiased ReSTIR GI does); without it a neighbour that cannot see the sample still takes a share of
its MIS weight (a darkening bias where neighbours are occluded). Measured (cornell-static, exact hook,
10 runs x 24 frames): the region means agree with Mitsuba either way (mean over the unlit pixels
+1.0 % off, +1.3 % on; p 0.17-0.64), while the rays cost +52 % frame time at 640x360 (1365 vs 898 ms,
load 7) -- so off by default (our choice), on for the strictly unbiased estimator. Part-0 candidates
need no ray: emitter samples are drawn irrespective of visibility.

``L_y`` is a random value (glossy recursion, NEE, or the exact hook's path tracing) that can be 0 where
its expectation is not; a target that vanishes there would lose that light (the resampled vertex is
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

``G_max`` (not scale invariant, Sec. 3.6), parameter ``gmax_scale``: ``'probe'`` (default)
``G_max = gmax / s^2`` with ``s`` the mean probe spacing (points closer than about one probe cell,
which the probes cannot resolve anyway, go to the BSDF sample; scales with the scene; our choice),
``'a0'`` ``G_max = gmax * 4 pi / a0(x_1) = gmax cos_1 / |x_0 - x_1|^2`` (the paper's suggestion,
proportional to the inverse camera footprint), ``'none'`` the constant ``G_max = gmax`` (the paper's 1).
``gmax = 0`` sends all probe light through the BSDF sample (the unpartitioned estimate the z-test in
``tests/techniques/test_ddgi_resampling.py`` compares against).

Control variate (Sec. 5.1), ``control_variate=True`` (``ddgi-resampling`` only): the primary vertex
gets the exact integral of a control variate ``g`` against its diffuse lobe, and the diffuse lobe's
part of the secondary-vertex light is replaced by its difference to ``g``. Part 1's target becomes
``|L_y - g(w_y)|`` (plus the floor); shading adds the signed difference, so pixels can be negative (the
paper's "negative fireflies"). It applies to the probe part (part 1 and the residual); directions that
miss the scene carry ``-g`` through the residual sample. ``cv_kind`` chooses ``g``:

* ``'constant'`` (default): the constant radiance ``E_DDGI+(x_1) / pi`` over the hemisphere (probes read
  at the primary vertex with DDGI's biases, interpolated), whose diffuse integral is exactly
  ``rho_1 / pi * E_DDGI+(x_1)``, the paper's primary term (our choice: needs no probe rays);
* ``'nearest-ray'``: the paper's spatio-directionally piecewise-constant ``g``
  (:class:`NearestRayCV`): nearest probe of ``x_1`` without interpolation, and per direction the mean
  radiance of that probe's most recent update rays in a cube-map bin (24 bins; the issue's "binning per
  texel" approximation of the nearest ray, with cube texels instead of octahedral ones because their
  edges are great circles); its integral ``rho_1 / pi sum_t g_t C_t(n)`` is computed exactly (Lambert's
  formula on the horizon-clipped texels) instead of the paper's "their average, E_DDGI+", which is an
  exact integral only in the limit. Rays that hit an emitter or miss the scene enter their bins with
  radiance 0 (one extra ray per probe ray finds them, counted in ``shade secondary``; our choice): they
  carry ``L_e`` (or the environment), which our part 1 never does (emission is part 0's); with their
  radiance the CV run was 5x noisier than plain resampling on cornell-static (per-frame image-mean std
  0.0132 vs 0.0024; as 0: 0.0029), and leaving them out of the bins instead raised the 1-spp MAPE
  (cornell-static 64x48: 0.310 vs 0.265; /tmp/figs/cv.md).

Both keep the mean of plain resampling given the same probes ("converges to the same (biased)
solution", Sec. 5.1): ``tests/techniques/test_ddgi_cv.py`` (Welch t-tests on frozen probes, and the rejection of a
control variate whose integral is scaled by 1.5). The exact integral assumes a Lambertian diffuse lobe
(``rho = diffuse_albedo``); for lobes whose diffuse part is not ``rho / pi`` (e.g. plastic's
Fresnel-weighted one) the correction is approximate.

Test hook ``exact_radiance=True``: ``S(x_n)`` is replaced by a path-traced estimate of the reflected
radiance at ``x_n`` (Mitsuba-style path tracing with NEE and MIS from ``x_{n-1}`` along the segment,
``exact_depth`` vertices, minus the emission of ``x_n``); the estimator is then unbiased, which the
convergence test checks against Mitsuba's ``path``.

Stats: per stage (``ms``/``rays``) and ``table2_ms`` = {trace & shade, resampling, update} as the
paper's Table 2 groups them.

Parameters (both; ``ddgi-resampling`` adds ``gmax``, ``gmax_scale``, ``control_variate``, ``cv_kind``)
-----------------------------------------------------------------------------------------------------
candidates, temporal, m_cap, spatial, radius, combine, progressive : as ``restir-pt``
footprint_c : float = 0.2      Eq. 8 threshold c
max_glossy : int = 3           most glossy recursion steps after the secondary vertex
view_path_bias : float = 0.2   Sec. 3.5 offset, in units of the smallest probe spacing
exact_radiance, exact_depth    the test hook above
probe parameters               those of :func:`dyngi.probes.ddgi_plus.plus_params` (DDGI's, the
                               emission heuristic, ...); ``normal_bias``/``view_bias`` default 0

Temporal reuse (``ddgi-resampling``): the M cap defaults to 1 (:data:`M_CAP`, measured), not
``restir-pt``'s 20.

Measured (2-core box shared with other jobs, load 10-15, 2026-12-02; /tmp/figs/resampling.md):
640x360 cornell-static frame (load 7): ddgi-resampling 898 ms (1365 with ``reuse_visibility``),
ddgi-secondary 597 ms, restir-pt 576 ms: 1.56x (2.4x) and 1.04x. MAPE after 8 accumulated frames,
cornell-static 96x54: restir-pt 0.174,
ddgi-secondary 0.148, ddgi-resampling 0.159. atrium-sun 64x36, 30 animated frames: MAPE 0.951 / 0.651 /
0.818 (restir-pt / secondary / resampling); ddgi-resampling shares its one shadow ray between the sun
and the probe light, so it is noisier than ddgi-secondary there (the paper's ordering is not
reproduced on that scene). The DDGI+ default emission heuristic ('ratio') makes cornell-static 6.6 %
dark (``emission_attenuation='none'``: +2.5 %; the exact-radiance hook: -0.5 %). living-room leaks:
+74 % / +78 % image mean (secondary / resampling).

Bias: the probes' (blur at the probe spacing, leaks through thin walls, hysteresis lag), hidden behind
one diffuse bounce (or a footprint-limited glossy chain); temporal reuse of part-1 samples keeps the
cached ``L_y`` of the previous frame (an approximation only in the resampling weights, Sec. 3.7).
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..probes.ddgi_plus import DDGIPlusVolume, plus_params
from ..probes.glossy import GLOSSY_NORMALISATION, glossy_context, has_glossy_lobe
from ..sampling.diffuse import diffuse_albedo
from ..sampling.lights import sample_traced
from ..sampling.reservoir import Reservoir
from ..sampling.rng import make_sampler
from ..transport.accumulate import ProgressiveMean
from ..transport.path_walk import trace_paths
from ..transport.restir_di import PARAM_SPECS, ReSTIRDI, initial_candidates, target
from .base import Frame, FrameResult, Param, StageTimer, Technique, register, to_image

_SHADE_STREAM = 0x5EC0
"""RNG stream of the secondary-vertex shading (the ReSTIR stages use stream 0)."""
_FINAL_STREAM = 0x5EC1
"""RNG stream of the shading of the resampled vertex z."""

FOOTPRINT_C = 0.2
"""Eq. 8's threshold c (Sec. 3.4: "we empirically set the threshold c = 0.2")."""
SAME_POINT_TOL = 1e-2
"""The ray towards the resampled point ``z`` sees ``z`` when its first hit is no closer than
``r (1 - tol) - tol s_min`` (relative to the distance and to the smallest probe spacing; the ray
origin's offset moves the hit by ~1e-3 scene units, measured; our choice)."""
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


def bounded_fraction(J, gmax):
    """(resampled share ``min(J, G_max) / J``, residual share ``max(1 - G_max / J, 0)``) of Eq. 9."""
    ok = J > 0.0
    res = dr.select(ok, dr.maximum(1.0 - gmax / dr.maximum(J, 1e-30), 0.0), 0.0)
    return dr.select(ok, 1.0 - res, 0.0), res


CV_FACE_RES = 2
"""Texels per cube-face edge of the nearest-ray control variate's direction bins (``6 K^2`` per probe;
K = 2: 24 bins, about 2.7 rays of 64 each; our choice)."""


def _cube_face_axes(face):
    """(major axis, sign, u axis, v axis) of cube face ``face`` (0..5: +x, -x, +y, -y, +z, -z)."""
    a = face // 2
    return a, (1.0 if face % 2 == 0 else -1.0), (a + 1) % 3, (a + 2) % 3


def cube_bin(w, K=CV_FACE_RES):
    """Cube-map bin ``face K^2 + iv K + iu`` of the direction ``w`` (cube texels: their edges are
    great-circle arcs, so the cosine integral over a texel is Lambert's polygon formula)."""
    a = dr.abs(w)
    fx = (a.x >= a.y) & (a.x >= a.z)
    fy = ~fx & (a.y >= a.z)
    face = dr.select(fx, dr.select(w.x > 0.0, 0, 1),
                     dr.select(fy, dr.select(w.y > 0.0, 2, 3), dr.select(w.z > 0.0, 4, 5)))
    m = dr.maximum(dr.select(fx, a.x, dr.select(fy, a.y, a.z)), 1e-30)
    u = dr.select(fx, w.y, dr.select(fy, w.z, w.x)) / m
    v = dr.select(fx, w.z, dr.select(fy, w.x, w.y)) / m
    iu = dr.clip(mi.Int32(dr.floor((u + 1.0) * (0.5 * K))), 0, K - 1)
    iv = dr.clip(mi.Int32(dr.floor((v + 1.0) * (0.5 * K))), 0, K - 1)
    return mi.UInt32(mi.Int32(face) * (K * K) + iv * K + iu)


def cube_texel_corners(K=CV_FACE_RES):
    """(6 K^2, 4, 3) float64 unit corner directions of every bin of :func:`cube_bin`, in order."""
    out = []
    for face in range(6):
        ax, sgn, au, av = _cube_face_axes(face)
        for iv in range(K):
            for iu in range(K):
                quad = []
                for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    d = np.zeros(3)
                    d[ax] = sgn
                    d[au] = -1.0 + 2.0 * (iu + du) / K
                    d[av] = -1.0 + 2.0 * (iv + dv) / K
                    quad.append(d / np.linalg.norm(d))
                out.append(quad)
    return np.asarray(out)


def _safe_normalize(v):
    ln = dr.norm(v)
    return dr.select(ln > 1e-12, v / dr.maximum(ln, 1e-30), 0.0)


def clipped_cosine_integral(n, corners):
    """``int_{texel} max(0, n . w) dw`` exactly, for the spherical quadrilateral ``corners`` (4 unit
    vectors, host constants, edges great-circle arcs) and unit normals ``n`` (per lane): Lambert's
    formula ``1/2 |sum_e theta_e n . u_e|`` over the texel clipped by the horizon ``n . w = 0``
    (an edge crossing the horizon is cut at its crossing, the horizon arc between the exit and the
    entry point closes the polygon)."""
    h = [dr.dot(n, mi.Vector3f(*map(float, c))) for c in corners]
    total = mi.Float(0.0)
    c_exit = dr.zeros(mi.Vector3f, dr.width(n))
    c_entry = dr.zeros(mi.Vector3f, dr.width(n))
    crossed = mi.Bool(False)

    def edge(a, b):
        return dr.acos(dr.clip(dr.dot(a, b), -1.0, 1.0)) * dr.dot(n, _safe_normalize(dr.cross(a, b)))

    for i in range(4):
        a = mi.Vector3f(*map(float, corners[i]))
        b = mi.Vector3f(*map(float, corners[(i + 1) % 4]))
        ha, hb = h[i], h[(i + 1) % 4]
        up_a, up_b = ha > 0.0, hb > 0.0
        out = up_a & ~up_b
        into = ~up_a & up_b
        # the edge's horizon crossing (signs differ), the positive combination of a and b
        c = _safe_normalize(dr.select(out, b * ha - a * hb, a * hb - b * ha))
        theta = float(np.arccos(np.clip(np.dot(corners[i], corners[(i + 1) % 4]), -1, 1)))
        u = np.cross(corners[i], corners[(i + 1) % 4])
        u = u / np.linalg.norm(u)
        e_ab = theta * dr.dot(n, mi.Vector3f(*map(float, u)))
        total += dr.select(up_a & up_b, e_ab, dr.select(out, edge(a, c), dr.select(into, edge(c, b), 0.0)))
        c_exit = dr.select(out, c, c_exit)
        c_entry = dr.select(into, c, c_entry)
        crossed |= out
    total += dr.select(crossed, edge(c_exit, c_entry), 0.0)
    return 0.5 * dr.abs(total)


class NearestRayCV:
    """The paper's piecewise-constant control variate (Sec. 5.1), ``cv_kind='nearest-ray'``.

    "the spatio-directionally nearest DDGI update ray among those that were traced while rendering the
    last frame": nearest probe of the primary vertex without interpolation (the grid cell's lattice
    probe: relocation offsets ignored), and, as an approximation of "nearest ray direction" (our choice,
    as the issue allows), the mean radiance of that probe's most recent update rays in the cube-map bin
    (:func:`cube_bin`, ``6 K^2`` bins) of the direction (rays that hit an emitter or miss count as 0:
    module docstring); a bin no ray fell in holds 0. The most recent
    update is this frame's (our probe update runs before shading). Its exact integral against a
    Lambertian lobe, ``rho / pi sum_t g_t C_t(n)`` with ``C_t`` :func:`clipped_cosine_integral`, replaces
    the paper's ``E_DDGI+`` (which is exact only in the limit of many rays), so the estimator's mean is
    plain resampling's."""

    def __init__(self, volume: DDGIPlusVolume, K: int = CV_FACE_RES, exclude_emitters: bool = True):
        self.vol = volume
        self.exclude_emitters = bool(exclude_emitters)
        self.extra_rays = 0
        self.K = K
        self.B = 6 * K * K
        self.corners = cube_texel_corners(K)
        g = volume.volume.grid
        self.origin = [float(v) for v in g.origin]
        self.inv_spacing = [1.0 / float(v) for v in g.spacing]
        self.counts = [int(c) for c in g.counts]
        self.P = g.n_probes
        self.table = dr.zeros(mi.Color3f, self.P * self.B)
        self.lum = dr.zeros(mi.Float, self.P * self.B)

    def refresh(self):
        """Bin the updater's most recent rays (per-ray radiance, direction, probe) into the table."""
        res = self.vol.updater.last_results
        if res is None:
            return
        plan = res.plan
        idx = plan.probe * self.B + cube_bin(plan.direction, self.K)
        ray_bin = idx % self.B
        rad = mi.Color3f(res.radiance)
        if self.exclude_emitters:   # rays that hit an emitter (or the sky) carry L_e, which part 1 does not
            mscene = self.vol.scene.mi_scene
            o = dr.gather(mi.Point3f, self.vol.volume.device.positions, plan.probe)
            si = mscene.ray_intersect(mi.Ray3f(o, plan.direction), ray_flags=mi.RayFlags.Minimal,
                                      coherent=False)
            rad = dr.select(si.is_valid() & (si.shape.emitter() == None), rad, 0.0)    # noqa: E711
            self.extra_rays = dr.width(plan.probe)
        # per (traced probe, bin) lane a loop over that probe's rays (CSR): a fixed summation order, so
        # reruns are bit-identical (a float scatter-add into the bins is not, test_battery's note)
        B = self.B
        slots = len(plan.probe_ids)
        lane = dr.arange(mi.UInt32, slots * B)
        slot, b = lane // B, lane % B
        offs = mi.UInt32(np.asarray(plan.offsets, np.uint32))
        start = dr.gather(mi.UInt32, offs, slot)
        end = dr.gather(mi.UInt32, offs, slot + 1)

        def body(k, acc, cnt):
            m = dr.gather(mi.UInt32, ray_bin, k) == b
            acc += dr.gather(mi.Color3f, rad, k, m)
            cnt += dr.select(m, 1.0, 0.0)
            return k + 1, acc, cnt

        state = (mi.UInt32(start), dr.zeros(mi.Color3f, slots * B), dr.zeros(mi.Float, slots * B))
        _, acc, cnt = dr.while_loop(state, lambda k, acc, cnt: k < end, body)
        table = dr.zeros(mi.Color3f, self.P * B)
        probe = mi.UInt32(np.asarray(plan.probe_ids, np.uint32))
        dr.scatter(table, acc / dr.maximum(cnt, 1.0), dr.gather(mi.UInt32, probe, slot) * B + b)
        self.table = table
        self.lum = mi.luminance(self.table)
        dr.eval(self.table, self.lum)

    def nearest_probe(self, pos):
        c = []
        for k in range(3):
            f = dr.round((pos[k] - self.origin[k]) * self.inv_spacing[k])
            c.append(dr.clip(mi.Int32(f), 0, self.counts[k] - 1))
        return mi.UInt32(c[0] + self.counts[0] * (c[1] + self.counts[1] * c[2]))

    def value(self, probe, w, active=True):
        """``g(w)`` (Color3f) of the lanes' probes towards the world directions ``w``."""
        return dr.gather(mi.Color3f, self.table, probe * self.B + cube_bin(w, self.K), active)

    def integral(self, probe, n, active=True):
        """``sum_t g_t C_t(n)`` (Color3f): the cosine integral of ``g`` over the hemisphere of ``n``."""
        out = mi.Color3f(0.0)
        base = probe * self.B
        for t in range(self.B):
            gt = dr.gather(mi.Color3f, self.table, base + t, active)
            out += gt * clipped_cosine_integral(n, self.corners[t])
        return out


def _probe_params():
    spec = plus_params()
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
    "exact_radiance": Param(False, "TEST HOOK: path-trace the secondary-vertex radiance instead of reading "
                            "the probes"),
    "exact_depth": Param(-1, "path depth of the exact_radiance hook (-1: unbounded, Russian roulette)", min=-1),
}


@register
class DDGISecondaryTechnique(Technique):
    """Secondary DDGI: ReSTIR DI at the primary vertex, DDGI+ read at the secondary vertex (Sec. 3.3-3.5)."""

    name = "ddgi-secondary"
    description = ("Secondary DDGI (DDGI Resampling paper): ReSTIR DI + one BSDF bounce into DDGI+ probes "
                   "(diffuse + glossy Eq. 6), footprint-terminated glossy recursion, view-path bias")
    HAS_INDIRECT = True
    PARAMS = SECONDARY_PARAMS
    BATTERY_PARAMS = {"candidates": 4, "spatial": 2, "probe_counts": "4", "rays_per_probe": 64, "warmup": 2,
                      "max_glossy": 1}
    # the furnace runs without the emission heuristic of Sec. 3.3: (t / (t + d))^2 is a deliberate bias
    # for small emitters and darkens a closed emitting shell (the probes' E then lies ~25% low)
    FURNACE_PARAMS = {"candidates": 8, "hysteresis": 0.5, "warmup": 16, "rays_per_probe": 128,
                      "irradiance_gamma": 1.0, "emission_attenuation": "none"}
    FURNACE_TOL = 0.03

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
    def shade_secondary(self, si, ray, beta, a0, pdf_prev, delta_prev, sampler, active, cv=None):
        """``beta * S(x_n)`` at the vertices ``si`` reached by ``ray``; returns (L, rays, recursions).

        ``pdf_prev``/``delta_prev``: the sampling pdf (solid angle) and delta flag of the direction that
        led to ``si`` (Eq. 7); ``a0``: Eq. 8's camera footprint per lane. ``cv``: (g, diffuse share)
        for the control variate (Sec. 5.1; the diffuse share of ``beta`` carries ``-g``)."""
        p = self.params
        mscene = self.scene.mi_scene
        active = mi.Bool(active)
        beta = mi.Color3f(beta)
        L = dr.zeros(mi.Color3f, dr.width(active))
        rays = dr.zeros(mi.UInt32, dr.width(active))
        rec = dr.zeros(mi.UInt32, dr.width(active))
        if p["exact_radiance"]:
            hit = active & si.is_valid()
            Lp, n_rays, _ = trace_paths(mscene, sampler, ray, hit, p["exact_depth"], 5)
            Le = mi.Color3f(si.emitter(mscene).eval(si, hit))
            return dr.select(hit, beta * (Lp - Le), 0.0), mi.UInt32(n_rays), rec
        ctx = mi.BSDFContext()
        gctx = glossy_context()
        thresh = p["footprint_c"] * a0
        bias_len = p["view_path_bias"] * self.s_min
        sum_sqrt = mi.Float(0.0)
        pdf_prev = mi.Float(pdf_prev)
        delta_prev = mi.Bool(delta_prev)
        for it in range(self.max_glossy + 1):
            if it > 0:    # emission at a glossy-recursion vertex (and the environment on a miss)
                L += dr.select(active, beta * mi.Color3f(si.emitter(mscene).eval(si, active)), 0.0)
            hit = active & si.is_valid()
            bsdf = si.bsdf()
            wo = -ray.d
            geo_front = dr.dot(si.n, wo) > 0.0
            two = mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide) & (bsdf != None)   # noqa: E711
            front = hit & (geo_front | two)
            n = dr.select(geo_front, si.sh_frame.n, -si.sh_frame.n)
            # -- footprint (Eq. 7) and the termination test (Eq. 8) --
            seg = dr.select(hit, si.t, 0.0)
            sum_sqrt += footprint_term(seg, pdf_prev, dr.abs(dr.dot(si.n, ray.d)), delta_prev)
            stop = (dr.square(sum_sqrt) > thresh) | (it == self.max_glossy)
            # -- the probes, read at the view-path-biased point (Sec. 3.5) --
            q = si.p - ray.d * dr.minimum(bias_len, 0.5 * seg)
            albedo = diffuse_albedo(bsdf, si, front)
            diff = front & dr.any(albedo > 0.0)
            E = self.query.irradiance(q, n, wo, active=diff)
            L += dr.select(diff, beta * albedo * dr.inv_pi * E, 0.0)
            # -- one glossy sample: Eq. 6's estimate where the footprint is large, else the recursion --
            g_ok = front & has_glossy_lobe(bsdf)
            bs, w_g = bsdf.sample(gctx, si, sampler.next_1d(), sampler.next_2d(), g_ok)
            w_g = mi.Color3f(w_g)
            g_ok &= (bs.pdf > 0.0) & (mi.Frame3f.cos_theta(bs.wo) * mi.Frame3f.cos_theta(si.wi) > 0.0) \
                & dr.all(dr.isfinite(w_g))
            d_g = si.to_world(bs.wo)
            g_end = g_ok & stop
            Eg = self.query.irradiance(q, n, wo, direction=d_g, active=g_end)
            L += dr.select(g_end, beta * w_g * Eg * (1.0 / GLOSSY_NORMALISATION), 0.0)
            # -- NEE for what no probe ray can hit (delta lights, the sun): full BSDF --
            if self.nee.count:
                ds, w, ok = sample_traced(self.nee, mscene, si, sampler.next_2d(), front)
                f = bsdf.eval(ctx, si, si.to_local(ds.d), front & ok)
                L += dr.select(front & ok, beta * mi.Color3f(f) * w, 0.0)
                rays += mi.UInt32(front & ok)
            if it == self.max_glossy:
                break
            # -- glossy recursion --
            go = g_ok & ~stop
            ray = si.spawn_ray(d_g)
            beta = dr.select(go, beta * w_g, 0.0)
            pdf_prev = bs.pdf
            delta_prev = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            si = mscene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=go)
            rays += mi.UInt32(go)
            rec += mi.UInt32(go)
            active = go
        return L, rays, rec

    # -- probes -------------------------------------------------------------------------
    def _update_probes(self, frame, t):
        self.vol.update(frame, timer=t)

    def _begin(self, frame, t):
        """Probe update, G-buffer, reprojection; returns the per-frame context."""
        p = self.params
        w, h = frame.res
        npix = w * h
        self._update_probes(frame, t)
        sampler = make_sampler(npix, frame.seed, frame.index)
        time = dr.opaque(mi.Float, float(frame.time))
        self.restir.begin_frame(frame)
        gb, reproj = self.restir.gbuffer(frame, sampler, t)
        bsdf = gb.si.bsdf(gb.ray)
        smooth = gb.valid & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        a0 = camera_footprint(gb.depth, dr.abs(dr.dot(gb.n_geo, gb.ray.d)))
        return sampler, time, gb, reproj, bsdf, smooth, a0

    def _bsdf_sample(self, gb, bsdf, sampler):
        """One full-BSDF sample at the primary vertex and its hit (the secondary vertex)."""
        mscene = self.scene.mi_scene
        si = gb.si
        bs, w = bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(), sampler.next_2d(), gb.valid)
        ok = gb.valid & (bs.pdf > 0.0) & dr.all(dr.isfinite(mi.Color3f(w)))
        ray = si.spawn_ray(si.to_world(bs.wo))
        si2 = mscene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=ok)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        return bs, mi.Color3f(dr.select(ok, w, 0.0)), ok, ray, si2, delta

    def _finish(self, frame, t, L, L_ind):
        p = self.params
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

    def step(self, frame: Frame) -> FrameResult:
        t = StageTimer()
        npix = frame.res[0] * frame.res[1]
        sampler, time, gb, reproj, bsdf, smooth, a0 = self._begin(frame, t)
        do_direct = self.cand.count > 0
        direct = self.restir.direct(gb, reproj, bsdf, smooth, sampler, time, t) if do_direct else mi.Color3f(0.0)
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


M_CAP = 1.0
"""ddgi-resampling's temporal M cap (our choice, measured): with restir-pt's 20 the previous frame's
reservoir outweighs the new candidates 20:1, and where the target changes between the jittered
primary points of two frames (grazing secondary points) the balance heuristic amplifies the old
sample's weight up to that ratio; a sample then sticks for many frames. Battery furnace (ellipsoid,
24x16, 8 runs x 32 frames, indirect 0.2025): run-to-run std of the mean 0.038 (cap 20), 0.015 (4),
0.0035 (1), 0.0010 (no temporal reuse); the means agree (0.198 +- 0.013, 0.207 +- 0.005, 0.2026 +- 0.0012)."""


def _resampling_params():
    out = dict(SECONDARY_PARAMS)
    out["m_cap"] = Param(M_CAP, "temporal M cap in multiples of the candidates per pixel (restir-pt: 20; "
                         "see the module docstring)", min=0.0, max=1e4)
    out.update({
        "gmax": Param(1.0, "bound G_max of the resampled geometry term cos_y/r^2 (Eq. 9), in the units "
                      "gmax_scale sets; 0: all probe light by the BSDF sample", min=0.0, max=1e9),
        "gmax_scale": Param("probe", "how G_max scales with the scene: 'probe' gmax/s^2 (s: mean probe "
                            "spacing), 'a0' gmax*4pi/a0 (Eq. 8), 'none' the constant gmax",
                            choices=("probe", "a0", "none")),
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
class DDGIResamplingTechnique(DDGISecondaryTechnique):
    """DDGI Resampling: ReSTIR over emitter samples + BSDF-sampled secondary hits, target L_e + L_DDGI+."""

    name = "ddgi-resampling"
    description = ("DDGI Resampling (Majercik et al. 2022): one reservoir over emitter samples and BSDF "
                   "secondary hits (area measure, bounded G, Eq. 9), DDGI+ query caching, 1 temporal + 3 "
                   "spatial neighbours, one shadow ray")
    PARAMS = _resampling_params()
    BATTERY_PARAMS = DDGISecondaryTechnique.BATTERY_PARAMS
    FURNACE_PARAMS = DDGISecondaryTechnique.FURNACE_PARAMS
    FURNACE_TOL = 0.03

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        self.prev_gmax = None
        self.prev_g = None
        self.prev_eps = 0.0
        self._vis_rays = []
        p = self.params
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
        return mi.Bool(active) & ~self.scene.mi_scene.ray_test(ray, active)

    def _target(self, pos, n, two, gmax, sample, time, active, g=None, eps=0.0, ng=None):
        """``p_hat`` of ``sample`` at the domain (pos, n, two, gmax); with ``ng`` (the domain's geometric
        normal) and ``reuse_visibility``, part-1 samples not visible from ``pos`` get 0 (one shadow ray)."""
        part, k, pl, y, ny, Ly = sample
        active = mi.Bool(active)
        p0 = active & (part == 0)
        p1 = active & (part == 1)
        ph = mi.Float(0.0)
        if self.cand.count:
            ev = self.cand.evaluate(pos, k, pl, time, p0)
            ph = dr.select(p0, target(n, two, ev), 0.0)
        d = y - pos
        r2 = dr.squared_norm(d)
        wdir = d * dr.rsqrt(dr.maximum(r2, 1e-30))
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
        if ng is not None and self.params["reuse_visibility"]:
            ok1 = self._visible(pos, ng, y, ok1)
            self._vis_rays.append(dr.count(ok1))
        return dr.select(ok1, ph1, dr.select(p1, 0.0, ph))

    def _cv_primary(self, gb, bsdf):
        """The control variate of Sec. 5.1 at the primary vertex: (``g``, its exact diffuse integral).

        ``g = E_DDGI+(x_1) / pi``, a constant radiance over the hemisphere (probes read at the primary
        vertex with DDGI's default biases, 0.05 / 0.2 smallest spacings along the normal / towards the
        viewer); its integral against the diffuse lobe is ``rho_1 g`` exactly for a Lambertian lobe
        (``rho_1`` :func:`~dyngi.sampling.diffuse.diffuse_albedo`). ``tests/techniques/test_ddgi_cv.py`` checks that
        the estimator's mean does not move with the control variate, and that a wrong integral (this
        method's second value scaled) is detected."""
        n = gb.n_sh
        albedo1 = diffuse_albedo(bsdf, gb.si, gb.valid)
        if self.cvnr is not None:   # nearest-ray: g is looked up per direction; first value the probe
            probe = self.cvnr.nearest_probe(gb.pos)
            return probe, dr.select(gb.valid, albedo1 * dr.inv_pi * self.cvnr.integral(probe, n, gb.valid), 0.0)
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
        sampler, time, gb, reproj, bsdf, smooth, a0 = self._begin(frame, t)
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
            hit_y = ok & si_y.is_valid()
            ny = dr.select(dr.dot(si_y.n, ray.d) > 0.0, -si_y.n, si_y.n)
            r2 = dr.select(hit_y, dr.square(si_y.t), 0.0)
            J_y = dr.select(hit_y, dr.abs(dr.dot(si_y.n, ray.d)) / dr.maximum(r2, 1e-30), 0.0)
            is_cand = smooth & ok & ~delta & hit_y
            _, resid = bounded_fraction(J_y, gmax)
            # defensive floor of the part-1 target (module docstring): a fraction of the frame's mean L_y
            eps = p["target_floor"] * dr.mean(dr.select(is_cand, mi.luminance(S_y), 0.0)) + 1e-12
            dr.eval(S_y, rays_y, rec, J_y, ny, eps)
        t.add_rays("bsdf sample", dr.count(ok))
        t.add_rays("bsdf sample", dr.sum(rays_y))
        self.last_recursions = rec

        # -- initial candidates: M emitter samples (part 0) + the BSDF hit (part 1) --
        with t.stage("candidates"):
            M_e = p["candidates"] if self.cand.count else 0
            if M_e:
                k, pl, w_sum_e, ph_e = initial_candidates(self.cand, si, n, two, smooth, sampler, M_e, time)
            else:
                k, pl = dr.zeros(mi.UInt32, npix), dr.zeros(mi.Vector3f, npix)
                w_sum_e, ph_e = dr.zeros(mi.Float, npix), dr.zeros(mi.Float, npix)
            y = mi.Point3f(si_y.p)
            s1 = (dr.full(mi.UInt32, 1, npix), dr.zeros(mi.UInt32, npix), dr.zeros(mi.Vector3f, npix), y,
                  mi.Vector3f(ny), mi.Color3f(S_y))
            ph_b = self._target(gb.pos, n, two, gmax, s1, time, is_cand, g_lum, eps)
            # RIS weight of the BSDF candidate: p_hat / (p_bsdf(w) J)
            w_b = dr.select(is_cand & (ph_b > 0.0), ph_b / dr.maximum(bs.pdf * J_y, 1e-30), 0.0)
            wsum = (w_sum_e / M_e if M_e else 0.0) + w_b
            take_b = (w_b > 0.0) & (sampler.next_1d() * wsum < w_b)
            zero3 = dr.zeros(mi.Point3f, npix)
            sample = (dr.select(take_b, 1, dr.zeros(mi.UInt32, npix)), dr.select(take_b, 0, k),
                      dr.select(take_b, mi.Vector3f(0.0), pl), dr.select(take_b, y, zero3),
                      dr.select(take_b, mi.Vector3f(ny), mi.Vector3f(0.0)),
                      dr.select(take_b, mi.Color3f(S_y), mi.Color3f(0.0)))
            ph = dr.select(take_b, ph_b, ph_e)
            M = float(M_e + 1)
            r = Reservoir(sample, wsum * M, dr.select(smooth, M, 0.0), ph,
                          dr.select(smooth & (ph > 0.0), wsum / dr.maximum(ph, 1e-30), 0.0),
                          dr.zeros(mi.UInt32, npix))
            dr.eval(*r.arrays())

        # -- temporal reuse (1 neighbour: the reprojected pixel) --
        with t.stage("temporal"):
            def here(sample, ok):
                return self._target(gb.pos, n, two, gmax, sample, time, ok, g_lum, eps, gb.n_geo)

            def there_prev(prev, pix, sample, ok):
                ppos = dr.gather(mi.Point3f, prev.pos, pix, ok)
                pn = dr.gather(mi.Vector3f, prev.n_sh, pix, ok)
                ptwo = dr.gather(mi.Bool, prev.transmissive, pix, ok)
                pg = dr.gather(mi.Float, self.prev_gmax, pix, ok)
                pcv = self._gather_g(self.prev_g, pix, ok) if cv else None
                png = dr.gather(mi.Vector3f, prev.n_geo, pix, ok)
                return self._target(ppos, pn, ptwo, pg, sample, time, ok, pcv, self.prev_eps, png)

            self.restir.temporal_reuse(r, gb, reproj, smooth, sampler, M, here, there_prev)

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
            shadow_lanes = mi.Bool(False)
            if self.cand.count:
                direct, shadow_lanes = self.restir.shade(gb, bsdf, (k, pl), r.W, p0, time)
            dz = yz - gb.pos
            rz = dr.norm(dz)
            wz = dz / dr.maximum(rz, 1e-30)
            # the ray passes exactly through z (spawn_ray_to aims from the offset origin), not stopping
            # short of it: its first hit is z when z is visible, and gives the surface at z for shading
            ray_z = si.spawn_ray_to(yz)
            t_to_z = mi.Float(ray_z.maxt)    # a copy: the assignment below writes into the field
            ray_z.maxt = dr.inf
            si_z = mscene.ray_intersect(ray_z, ray_flags=mi.RayFlags.All, coherent=False, active=p1)
            vis_z = p1 & si_z.is_valid() & (si_z.t >= t_to_z * (1.0 - SAME_POINT_TOL) - SAME_POINT_TOL * self.s_min)
            # the geometry term of the stored sample (the target's, Eq. 9's integrand in area measure)
            J_z = dr.maximum(dr.dot(nz, -wz), 0.0) / dr.maximum(dr.square(rz), 1e-30)
            f1, pdf1 = bsdf.eval_pdf(ctx, si, si.to_local(wz), vis_z)
            beta_z = dr.select(vis_z, mi.Color3f(f1) * dr.minimum(J_z, gmax) * r.W, 0.0)
            dr.eval(direct, vis_z, beta_z)
        t.add_rays("shadow", dr.count(shadow_lanes | p1))
        with t.stage("shade z"):
            sz = make_sampler(npix, frame.seed, frame.index, _FINAL_STREAM)
            L_z, rays_z, _ = self.shade_secondary(si_z, ray_z, beta_z, a0, pdf1, mi.Bool(False), sz, vis_z)
            if cv:   # the diffuse lobe's share carries the difference to g (Sec. 5.1)
                f1d = bsdf.eval(mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.DiffuseReflection),
                                si, si.to_local(wz), vis_z)
                L_z -= dr.select(vis_z, mi.Color3f(f1d) * dr.minimum(J_z, gmax) * r.W
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
                          "is_cand": is_cand, "W": r.W, "part": part, "t_z": si_z.t, "r_z": rz,
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
        p = self.params

        def here(sample, ok):
            return self._target(gb.pos, gb.n_sh, gb.transmissive, gmax, sample, time, ok, g_lum, eps, gb.n_geo)

        def domain(nid, npos, nn, ntwo, act):
            return (npos, nn, ntwo, dr.gather(mi.Float, gmax, nid, act), self._gather_g(g_lum, nid, act),
                    dr.gather(mi.Vector3f, gb.n_geo, nid, act))

        def there(dom, sample, ok):
            npos, nn, ntwo, ngmax, ng, nng = dom
            return self._target(npos, nn, ntwo, ngmax, sample, time, ok, ng, eps, nng)

        return self.restir.spatial_reuse(gb, r_t, active, sampler, here, domain, there)


__all__ = ["DDGISecondaryTechnique", "DDGIResamplingTechnique", "camera_footprint", "footprint_term",
           "footprint_np", "bounded_fraction", "NearestRayCV", "cube_bin", "cube_texel_corners",
           "clipped_cosine_integral"]
