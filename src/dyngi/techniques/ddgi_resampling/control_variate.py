"""The control variates of DDGI Resampling (Majercik et al. 2022, Sec. 5.1; ``ddgi-resampling`` only).

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
solution", Sec. 5.1): ``tests/techniques/ddgi_resampling/test_control_variate.py`` (Welch t-tests on frozen probes, and the rejection of a
control variate whose integral is scaled by 1.5). The exact integral assumes a Lambertian diffuse lobe
(``rho = diffuse_albedo``); for lobes whose diffuse part is not ``rho / pi`` (e.g. plastic's
Fresnel-weighted one) the correction is approximate.

Spherical geometry of the nearest-ray control variate: cube-map direction bins (:func:`cube_bin`,
their corners :func:`cube_texel_corners`) and the exact integral of a clipped cosine over a spherical
quadrilateral (:func:`clipped_cosine_integral`, Lambert's formula).
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...probes.ddgi_plus import DDGIPlusVolume
from ...rays import intersect

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
        """Bin the probe pipeline's most recent rays (its ``last_results``: per-ray radiance, direction, probe) into
        the table."""
        res = self.vol.pipeline.last_results
        if res is None:
            return
        plan = res.plan
        idx = plan.probe * self.B + cube_bin(plan.direction, self.K)
        ray_bin = idx % self.B
        rad = mi.Color3f(res.radiance)
        if self.exclude_emitters:   # rays that hit an emitter (or the sky) carry L_e, which part 1 does not
            mscene = self.vol.scene.mi_scene
            o = dr.gather(mi.Point3f, self.vol.volume.device.positions, plan.probe)
            si = intersect(mscene, mi.Ray3f(o, plan.direction), mi.RayFlags.Minimal, False,
                           stage="shade secondary")
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

