"""IS-DDGI integration per direction set (Algorithm 3) and probe states (Algorithm 2) of Liu et al. 2023
(supplement), on a ragged plan of :mod:`dyngi.techniques.isddgi.planner`.

**Storage** (Algorithm 3; issues 13 item 1 and 26): irradiance and visibility (the distance moments) are
stored at ``ddgi``'s sizes by default (``irradiance_texels = 8``, ``distance_texels = 16`` incl. the
1-texel octahedral border that :class:`~dyngi.probes.query.ProbeQuery`'s bilinear read needs, see
:mod:`dyngi.sampling.octahedral`: 6x6 and 14x14 interiors); each texel integrates all of the probe's rays
exactly as a set would (Algorithm 3's integral with the texel's centre direction), and the 16x16 tile of
sets is the unit of ray allocation only. ``18`` for either stores it per set (interior texel ``(j mod 16,
j / 16)`` = set ``j``), Algorithm 3's ``irradiance_tex`` / ``visibility_tex`` read literally. Our reading:
Table 1 lists every texture IS-DDGI adds to DDGI (allocation, hit information, directions, hit samples:
~1 KB per probe plus 40 B per set) and no larger irradiance or visibility texture, and the lobes are
broad next to a set (neighbouring sets' integrals differ little); per-set squares made the blend grow
with texels x probes (the integration's lanes and the merge's per-texel steps) instead of with the rays
(issue 26). Figures: docs/techniques/isddgi.md.

**Integration** (Algorithm 3, Sec. 4.2): every texel ``ds_ij`` integrates over *all* valid rays of its
probe, as DDGI does: ``irr_ij = sum_r w_r <ds_ij, r>^+ L_r / sum_r w_r <ds_ij, r>^+`` with the per-ray
stratified weight ``w_r = Omega_set / n_set`` of the planner (ours, issue 13 item 5). With uniform
hemisphere rays the denominator's expectation is ``|Omega^H| / 2`` (Sec. 4.1) and this is the
supplement's ``2 / |Omega^H| sum <ds, r>^+ L``; with the weights it is the cosine-weighted mean of the
radiance, i.e. ``E / pi`` -- the pi convention of Sec. 4.2 (``r_diff = rho * irr``) and of
:mod:`dyngi.probes.volume`: texels hold ``E / pi``; the query returns ``E = pi * texel`` and primary
shading multiplies by ``albedo / pi``, i.e. ``r_diff = rho * irr``. The distance moments use DDGI's
``cos^distance_power`` lobe with the same weights. Back faces: as the probe core (:mod:`dyngi.probes.estimator`).

The sums are a Dr.Jit loop over the probe's rays (:func:`integrate_sets_dr`: one lane per (probe, pair of
antipodal sets), a ragged ``dr.while_loop`` over ``offsets[slot] .. offsets[slot+1]``; sequential sums per
lane, so bit-identical on reruns with no atomics); :func:`integrate_sets` is the NumPy twin used by tests.

**Probe state** (Algorithm 2): a probe is ON iff it has a front-face hit and its back-face ratio
``backFaceCount / total_i`` is below ``backface_threshold`` (0.25, ours: the value of our DDGI
classification). Line 17 takes the minimum over *all* distances, the negative back-face ones too, so one
back-face hit would make ``closestFrontFaceDist`` negative and count as a front face; we take the minimum
over front-face hits only (``d >= 0`` and finite; a miss is no front face).

**Near-surface test** (issue 26; ours: Algorithm 2 alone kept 1.5-2x more probes ON than ``ddgi``): a probe
is ON only if, in addition, one of its front-face hits lies inside its cell neighbourhood -- DDGI's
classification (Majercik et al. 2021, Sec. 5; :mod:`dyngi.probes.states`), per ray here
(:func:`near_surface_hits`), so a probe far from every surface (which no shading point near a surface
reads with weight) is not updated. A probe traces only ``x_i`` (8-32) rays per frame, a rotating part of
its 256 sets, so one frame's rays can miss its only nearby surface: the test holds over a window --
the probe keeps the near flag while its last near hit is at most ``256 / x_i`` of its traced frames old
(one full rotation of its uniform pattern, i.e. every set visited once; ours, see
:func:`near_window`).
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...probes.arrays import upload
from ...probes.accumulator import BRIGHTNESS_DAMPING, CHANGE_HYSTERESIS_DROP, HysteresisAccumulator, count_sum
from ...probes.blend import HysteresisBlend
from ...probes.estimator import MIN_BLEND_WEIGHT, TexelEstimate, int_power_dr
from ...probes.states import cell_extents
from ...sampling.octahedral import oct_decode_np, oct_encode_np
from .sets import N_SETS

MIN_BUCKET = 8
CHUNK_ELEMENTS = 1 << 22        # probe x ray x texel elements per batched product (memory bound, ours)
BACKFACE_THRESHOLD = 0.25


def _power(c: np.ndarray, p: float) -> np.ndarray:
    if p == 1.0:
        return c
    ip = int(p)
    if ip == p and ip > 0:          # repeated squaring (exact integer powers, no log/exp)
        out, base = None, c
        while ip:
            if ip & 1:
                out = base.copy() if out is None else out * base
            ip >>= 1
            if ip:
                base = base * base
        return out
    return np.power(c, np.float32(p))


def integrate_sets(info, radiance: np.ndarray, dist: np.ndarray, max_distance: float, power: float = 50.0,
                   irr_side: int = 16, dist_side: int = 16):
    """Per traced probe and set: irradiance sums/weights/counts and distance-moment sums/weights/counts.

    ``info`` an :class:`~dyngi.techniques.isddgi.planner.ISDDGIPlanInfo`; ``radiance`` (R, 3), ``dist`` (R,)
    signed distances. Returns ``(irr (S,T,3) means, irr_w (S,T), irr_n (S,T), mom (S,256,2) means,
    mom_w, mom_n)`` with ``T = irr_side^2`` irradiance texels (16: one per set); means are 0 where the
    weight is 0.
    """
    S = len(info.total)
    tdirs = texel_directions(dist_side).astype(np.float32)        # (TD, 3); 16: the sets
    TD = len(tdirs)
    tdirs_i = texel_directions(irr_side).astype(np.float32)       # (T, 3)
    TI = len(tdirs_i)
    total = info.total.astype(np.int64)
    offsets = np.concatenate([[0], np.cumsum(total)])
    bucket = np.maximum(MIN_BUCKET, 1 << np.ceil(np.log2(np.maximum(total, 1))).astype(np.int64))
    cut_i = 0.0
    cut_d = np.float32(MIN_BLEND_WEIGHT ** (1.0 / power))
    d_abs = np.minimum(np.abs(dist), max_distance).astype(np.float32)
    front = (dist >= 0.0)
    L = np.asarray(radiance, np.float32)
    irr = np.zeros((S, TI, 3), np.float32)
    irr_w = np.zeros((S, TI), np.float32)
    irr_n = np.zeros((S, TI), np.int64)
    mom = np.zeros((S, TD, 2), np.float32)
    mom_w = np.zeros((S, TD), np.float32)
    mom_n = np.zeros((S, TD), np.int64)
    vals_d = np.stack([d_abs, d_abs * d_abs], -1)
    for B in np.unique(bucket[total > 0]):
        slots = np.flatnonzero((bucket == B) & (total > 0))
        step = max(1, CHUNK_ELEMENTS // (int(B) * N_SETS))
        for c0 in range(0, len(slots), step):      # chunks of probes (memory), not a per-probe loop
            sl = slots[c0:c0 + step]
            ar = np.arange(B)[None, :]
            valid = ar < total[sl][:, None]
            idx = np.where(valid, offsets[sl][:, None] + ar, 0)
            w = np.where(valid, info.ray_weight[idx], 0.0).astype(np.float32)          # (s, B)
            cos = info.ray_dir[idx] @ tdirs.T                                           # (s, B, 256)
            cos = np.maximum(cos, 0.0)
            cos_i = cos if irr_side == dist_side else np.maximum(info.ray_dir[idx] @ tdirs_i.T, 0.0)
            wi = cos_i * (w * front[idx])[..., None]
            si = np.matmul(wi.transpose(0, 2, 1), L[idx])                               # (s, 256, 3)
            swi = wi.sum(1)
            irr_n[sl] = (wi > cut_i).sum(1)
            cd = np.where(cos > cut_d, cos, 0.0).astype(np.float32)
            wd = _power(cd, power) * w[..., None]
            sd = np.matmul(wd.transpose(0, 2, 1), vals_d[idx])                          # (s, 256, 2)
            swd = wd.sum(1)
            mom_n[sl] = (wd > 0.0).sum(1)
            with np.errstate(divide="ignore", invalid="ignore"):
                irr[sl] = np.where(swi[..., None] > 0, si / swi[..., None], 0.0)
                mom[sl] = np.where(swd[..., None] > 0, sd / swd[..., None], 0.0)
            irr_w[sl], mom_w[sl] = swi, swd
    return irr, irr_w, irr_n, mom, mom_w, mom_n


def _planar(channels, n: int):
    """Channel-planar flat Float (channel ``c`` of entry ``e`` at ``c * n + e``): one plain scatter per
    channel into one array, all in one kernel with the channels' own computation (an earlier gather/select
    form evaluated each channel first and cost ~40% of the estimate)."""
    out = dr.zeros(mi.Float, len(channels) * n)
    e = dr.arange(mi.UInt32, n)
    nn = dr.opaque(mi.UInt32, n)
    for c, ch in enumerate(channels):
        dr.scatter(out, ch, e + nn * c)
    return out


def texel_directions(side: int = 16) -> np.ndarray:
    """(side^2, 3) centre directions of a ``side x side`` octahedral tile (row-major; ``side`` 16: the sets,
    :func:`~.sets.set_directions`)."""
    c = (np.arange(side) + 0.5) / side * 2.0 - 1.0
    py, px = np.meshgrid(c, c, indexing="ij")
    return oct_decode_np(np.stack([px, py], -1)).reshape(-1, 3)


def antipodal_sets(side: int = 16) -> np.ndarray:
    """(side^2,) int64: the texel whose centre direction is the opposite of texel ``j``'s (an involution
    without fixed points on an even octahedral grid: the octahedral fold maps texel centres to texel
    centres); ``side`` 16: the sets."""
    p = (oct_encode_np(-texel_directions(side)) * 0.5 + 0.5) * side - 0.5
    return np.round(p[:, 1]).astype(np.int64) * side + np.round(p[:, 0]).astype(np.int64)


_SIDE_TABLES: dict = {}


def _array4f():
    """The variant's 4-float array type (packet loads of :func:`_packed_rays`)."""
    return dr.cuda.ad.Array4f if mi.variant().startswith("cuda") else dr.llvm.ad.Array4f


def _packed_rays(plan, radiance, dist, dmax):
    """(R * 8,) Float: per ray ``(direction, +-weight, min(|d|, d_max), radiance)``, the weight negative for a
    back-face hit or a miss (weights are positive, so the sign carries the front flag exactly): the
    integration loop reads a ray with two 4-float packet loads instead of eight scalar gathers (ours; the
    loop's gathers were most of its time on the CPU). Cached on ``plan`` for the same ``radiance`` and ``dist``
    (both squares' loops share it)."""
    cached = getattr(plan, "_isddgi_packed", None)
    if cached is not None and cached[0] is radiance and cached[1] is dist:
        return cached[2]
    R = plan.n_rays
    w = plan.weight if plan.weight is not None else dr.full(mi.Float, 1.0, R)
    vals = [plan.direction[0], plan.direction[1], plan.direction[2], dr.select(dist >= 0.0, w, -w),
            dr.minimum(dr.abs(dist), dmax), radiance[0], radiance[1], radiance[2]]
    out = dr.zeros(mi.Float, R * 8)
    i = dr.arange(mi.UInt32, R) * 8
    for c, v in enumerate(vals):
        dr.scatter(out, v, i + c)
    dr.eval(out)
    plan._isddgi_packed = (radiance, dist, out)
    return out


def _side_tables(side: int) -> dict:
    """Device constants of a ``side x side`` tile's antipodal pairing (built once per side and variant):
    ``dirs_first`` the centre directions of the first texel of each pair, ``lane_of`` (T,) the pair of each
    texel, ``side_a`` (T,) whether a texel is its pair's first."""
    key = (side, mi.variant())
    if key not in _SIDE_TABLES:
        T = side * side
        half = T // 2
        anti = antipodal_sets(side)
        first = np.flatnonzero(np.arange(T) < anti)          # half the texels, their antipodes the others
        tdirs = texel_directions(side)[first].astype(np.float32)
        side_a = np.zeros(T, np.uint32)
        side_a[first] = 1
        lane_of = np.zeros(T, np.uint32)
        lane_of[first] = np.arange(half)
        lane_of[anti[first]] = np.arange(half)
        tab = {"dirs_first": mi.Vector3f(*[upload(np.ascontiguousarray(tdirs[:, c]), mi.Float) for c in range(3)]),
               "lane_of": upload(lane_of, mi.UInt32), "side_a": upload(side_a, mi.UInt32) != 0}
        dr.eval(tab["dirs_first"], tab["side_a"])
        _SIDE_TABLES[key] = tab
    return _SIDE_TABLES[key]


def _antipodal_sums(plan, radiance, dist, side: int, irradiance: bool, distance: bool, max_distance: float,
                    power: float) -> dict:
    """Per (slot, texel) of a ``side x side`` tile: the cosine-lobe sums (``e`` Color3f, ``we``) if
    ``irradiance`` and the cosine-power moment sums (``m1``, ``m2``, ``wd``) if ``distance``, one lane per
    (slot, pair of antipodal texels) looping over the slot's rays (see :func:`integrate_sets_dr`)."""
    S = len(plan.probe_ids)
    T = side * side
    half = T // 2
    tab = _side_tables(side)
    offsets = upload(np.asarray(plan.offsets, np.uint32), mi.UInt32)
    k = dr.arange(mi.UInt32, S * half)
    slot = k // half
    t = k - slot * half
    nt = dr.gather(mi.Vector3f, tab["dirs_first"], t)
    r0 = dr.gather(mi.UInt32, offsets, slot)
    r1 = dr.gather(mi.UInt32, offsets, slot + 1)
    dmax = dr.opaque(mi.Float, max_distance)
    cut = MIN_BLEND_WEIGHT ** (1.0 / power) if power > 1.0 else 0.0

    packed = _packed_rays(plan, radiance, dist, dmax)
    _Array4f = _array4f()

    def body(r, ea, wa, eb, wb, ma1, ma2, da, mb1, mb2, db):
        p0 = dr.gather(_Array4f, packed, r * 2)         # (direction, +-weight): two packet loads per ray
        p1 = dr.gather(_Array4f, packed, r * 2 + 1)     # (clamped distance, radiance)
        d = mi.Vector3f(p0[0], p0[1], p0[2])
        w = dr.abs(p0[3])
        c = dr.dot(d, nt)
        pos = c > 0.0
        ac = dr.abs(c)
        if irradiance:
            L = mi.Color3f(p1[1], p1[2], p1[3])
            wf = dr.select(p0[3] > 0.0, ac * w, 0.0)
            wia = dr.select(pos, wf, 0.0)
            wib = dr.select(pos, 0.0, wf)
            ea = dr.fma(L, wia, ea)
            wa += wia
            eb = dr.fma(L, wib, eb)
            wb += wib
        if distance:
            a = p1[0]
            pw = dr.select(ac > cut, int_power_dr(ac, power), 0.0) * w
            pa = dr.select(pos, pw, 0.0)
            pb = dr.select(pos, 0.0, pw)
            ma1 = dr.fma(a, pa, ma1)
            ma2 = dr.fma(a * a, pa, ma2)
            da += pa
            mb1 = dr.fma(a, pb, mb1)
            mb2 = dr.fma(a * a, pb, mb2)
            db += pb
        return r + 1, ea, wa, eb, wb, ma1, ma2, da, mb1, mb2, db

    z = [mi.Float(0.0) for _ in range(8)]
    state = (mi.UInt32(r0), mi.Color3f(0.0), z[0], mi.Color3f(0.0), z[1], *z[2:])
    out = dr.while_loop(state, lambda r, *a: r < r1, body,
                        labels=("r", "ea", "wa", "eb", "wb", "ma1", "ma2", "da", "mb1", "mb2", "db"))
    _, ea, wa, eb, wb, ma1, ma2, da, mb1, mb2, db = out
    keep = ([ea, wa, eb, wb] if irradiance else []) + ([ma1, ma2, da, mb1, mb2, db] if distance else [])
    dr.eval(*keep)         # once: the gathers below would re-run the loop
    # -- back to one entry per (slot, texel): texel j is lane (slot, pos[j]) side a, or its antipode's side b --
    kk = dr.arange(mi.UInt32, S * T)
    sl = kk // T
    j = kk - sl * T
    lane = sl * half + dr.gather(mi.UInt32, tab["lane_of"], j)
    isa = dr.gather(mi.Bool, tab["side_a"], j)

    def pick(va, vb):
        return dr.select(isa, dr.gather(type(va), va, lane), dr.gather(type(vb), vb, lane))

    res = {}
    if irradiance:
        res["e"], res["we"] = pick(ea, eb), pick(wa, wb)
    if distance:
        res["m1"], res["m2"], res["wd"] = pick(ma1, mb1), pick(ma2, mb2), pick(da, db)
    dr.eval(*res.values())
    return res


def integrate_sets_dr(plan, radiance, dist, max_distance: float, power: float = 50.0, irr_side: int = 16,
                      dist_side: int = 16):
    """Dr.Jit version of :func:`integrate_sets` on the device arrays of ``plan`` (direction, weight) and the
    traced ``radiance`` (Color3f) / ``dist`` (Float): returns (irradiance, distance) :class:`TexelEstimate`
    per interior texel of an ``irr_side`` / ``dist_side`` square (16: one texel per set; ``ddgi``'s 6 / 14
    are the technique's defaults, see the module docstring). Equal sides share one loop; otherwise one
    loop per square.

    One lane per probe and *pair of antipodal texels* (ours, exact): a ray's cosine to texel ``j'`` opposite
    ``j`` is ``-cos_j``, so one loop iteration (the ray's gathers, its cosine and its ``|cos|^power``)
    feeds both: the positive lobe to ``j``, the negative to ``j'`` -- half the lanes of one lane per texel
    (measured: integration ~2x faster on 2048 probes x ~30 rays)."""
    n = len(plan.probe_ids) * dist_side * dist_side
    if irr_side == dist_side:
        sums = _antipodal_sums(plan, radiance, dist, dist_side, True, True, max_distance, power)
    else:
        sums = _antipodal_sums(plan, radiance, dist, dist_side, False, True, max_distance, power)
        sums.update(_antipodal_sums(plan, radiance, dist, irr_side, True, False, max_distance, power))
    ni = len(plan.probe_ids) * irr_side * irr_side
    e, we, m1, m2, wd = sums["e"], sums["we"], sums["m1"], sums["m2"], sums["wd"]
    oki, okd = we > 0.0, wd > 0.0
    # counts: 1 per texel that received weight (the accumulator only caps them; per-ray counts would
    # cost two more loop variables, measured ~3x slower)
    ne, nd = mi.UInt32(oki), mi.UInt32(okd)
    z = mi.Float(0.0)
    inv_i = dr.select(oki, dr.rcp(we), z)
    inv_d = dr.select(okd, dr.rcp(wd), z)
    flat_i = _planar([e[0] * inv_i, e[1] * inv_i, e[2] * inv_i], ni)
    flat_d = _planar([m1 * inv_d, m2 * inv_d], n)
    est_i = TexelEstimate(flat_i, ne, oki, ni, 3, per_texel=False, weight=we)
    est_d = TexelEstimate(flat_d, nd, okd, n, 2, per_texel=False, weight=wd)
    dr.eval(flat_i, ne, oki, we, flat_d, nd, okd, wd)
    return est_i, est_d


class LinearMeanHysteresis(HysteresisAccumulator):
    """DDGI's hysteresis accumulator whose running mean is linear in ``E``; the perceptual space
    ``E^(1/gamma)`` only decides *how fast* a texel follows (the change threshold and the brightness
    damping of :class:`~dyngi.probes.accumulator.HysteresisAccumulator`). Ours; the supplement does not
    say in which space IS-DDGI blends.

    Why (the static-scene penalty): DDGI's blend averages ``x^(1/gamma)`` and stores its ``gamma``-th
    power, which converges to ``E[x^(1/gamma)]^gamma <= E[x]`` (Jensen): a noisy per-frame estimate ``x``
    is biased low, by more the fewer rays a texel's estimate has. At DDGI's 256 rays per probe the bias is
    negligible; IS-DDGI's static probes trace ``x_min`` (8) uniform rays, and with gamma 5 its converged
    irradiance was ~9% below ``ddgi``'s (as low as ``ddgi`` itself at 8 rays per probe; with gamma 1 both
    agree within 2%, the sampling is unbiased; the ablation is in docs/techniques/isddgi.md). A linear mean
    removes that bias whatever the ray count, so on a static scene IS-DDGI converges to DDGI's answer at
    the same gamma and hysteresis. With ``gamma = 1`` it is exactly DDGI's accumulator."""

    def irradiance(self, old, new, n_old, m, fresh, cap: int):
        if self.irradiance_gamma == 1.0:
            return super().irradiance(old, new, n_old, m, fresh, cap)
        h = dr.opaque(mi.Float, self.hysteresis)
        inv_g = dr.opaque(mi.Float, 1.0 / self.irradiance_gamma)
        new_c, old_c = dr.maximum(new, 0.0), dr.maximum(old, 0.0)
        delta_g = dr.power(new_c, inv_g) - dr.power(old_c, inv_g)
        h0 = dr.select(fresh, 0.0, h)
        big = dr.max(dr.abs(delta_g)) > dr.opaque(mi.Float, self.change_threshold)
        hh = dr.select(big, dr.maximum(h0 - CHANGE_HYSTERESIS_DROP, 0.0), h0)
        bright = (mi.luminance(delta_g) > dr.opaque(mi.Float, min(self.brightness_threshold, 3e38))) & ~fresh
        delta = new_c - old_c
        delta = dr.select(bright, delta * BRIGHTNESS_DAMPING, delta)
        res = dr.maximum(old_c + (1.0 - hh) * delta, 0.0)
        return res, count_sum(n_old, m, fresh, cap)


class SetBlend(HysteresisBlend):
    """The probe pipeline's blend for IS-DDGI: DDGI's hysteresis and encoding (as
    :class:`~dyngi.probes.blend.HysteresisBlend`) with the per-set estimator of the supplement's
    Algorithm 3 (:func:`integrate_sets_dr`) in place of the texel-kernel one, and with ``linear_mean`` (the
    technique's parameter, ours) the running mean linear (:class:`LinearMeanHysteresis`: no low bias from few
    rays per texel); without it DDGI's own hysteresis blend (gamma space), the supplement's."""

    def __init__(self, *args, linear_mean: bool = True, **kwargs):
        super().__init__(*args, **kwargs)
        a = self.accumulator
        if linear_mean:     # ours (the technique's linear_mean); False: DDGI's gamma-space blend, as the supplement
            self.accumulator = LinearMeanHysteresis(a.hysteresis, a.irradiance_gamma, a.change_threshold,
                                                    a.brightness_threshold)

    def new_estimates(self, volume, results):
        """(irradiance, distance) :class:`~dyngi.probes.estimator.TexelEstimate` of a ragged IS-DDGI plan."""
        self.last_estimator = "sets"
        return integrate_sets_dr(results.plan, results.radiance, results.distance, volume.max_distance,
                                 self.distance_power, irr_side=volume.irradiance_texels - 2,
                                 dist_side=volume.distance_texels - 2)


def to_texel_estimate(means: np.ndarray, weight: np.ndarray, count: np.ndarray) -> TexelEstimate:
    """(S, 256, C) means -> the probe core's :class:`TexelEstimate` (channel-planar, entry ``slot*256+j``)."""
    S, T2, C = means.shape
    n = S * T2
    flat = np.ascontiguousarray(means.reshape(n, C).T).ravel()
    ok = (weight.ravel() > 0.0).astype(np.uint32)
    est = TexelEstimate(upload(flat, mi.Float), upload(count.ravel().astype(np.uint32), mi.UInt32),
                        upload(ok, mi.UInt32) != 0, n, C, per_texel=False,
                        weight=upload(weight.ravel().astype(np.float32), mi.Float))
    dr.eval(est.ok)
    return est


def near_surface_hits(volume, probe_ids, ray_slot, dirs: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(S,) bool per traced probe slot (``probe_ids`` (S,) volume indices): one of its rays hit a front
    face inside the probe's cell neighbourhood (``|t w_a| <= spacing_a`` on every axis, unbounded outwards
    on the grid boundary): DDGI's near-surface classification test
    (:func:`dyngi.probes.states._summaries_numpy`) on a ragged plan, one NumPy pass over the rays
    (``ray_slot`` (R,), ``dirs`` (R, 3), ``dist`` (R,) signed distances)."""
    pid = np.asarray(probe_ids, np.int64)
    S = len(pid)
    lo, hi = cell_extents(volume, pid)                       # (S, 3) each
    slot = np.asarray(ray_slot, np.int64)
    w = np.asarray(dirs, np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        ext = np.where(w > 0, hi[slot], lo[slot]) / np.abs(w)
    t_exit = np.nan_to_num(ext, nan=np.inf, posinf=np.inf).min(1)
    d = np.asarray(dist, np.float32)
    near = (d > 0.0) & np.isfinite(d) & (d <= t_exit)
    return np.bincount(slot, near.astype(np.float64), S) > 0


def near_window(x: np.ndarray) -> np.ndarray:
    """Traced frames a probe with ``x`` uniform rays keeps its near-surface flag after its last near hit:
    ``256 / x`` (its uniform pattern's rotation period; ours)."""
    return np.maximum(N_SETS // np.maximum(np.asarray(x, np.int64), 1), 1)


def probe_states_alg2(info, dist: np.ndarray, backface_threshold: float = BACKFACE_THRESHOLD) -> np.ndarray:
    """Algorithm 2: (S,) bool ON per traced probe from its rays' signed distances (front-face min fixed,
    see the module docstring). Probes without rays are OFF."""
    S = len(info.total)
    back = np.bincount(info.ray_slot, (dist < 0.0).astype(np.float64), S)
    front = np.bincount(info.ray_slot, ((dist >= 0.0) & np.isfinite(dist)).astype(np.float64), S)
    total = np.maximum(info.total, 1)
    return (front > 0) & (back / total < backface_threshold) & (info.total > 0)
