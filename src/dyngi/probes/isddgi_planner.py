"""IS-DDGI ray allocation per probe direction set (Liu et al., "Importance-Based Ray Strategies for Dynamic
Diffuse Global Illumination", I3D 2023; only the supplement is available here).

Pieces (numbers refer to the supplement; "ours" marks choices the supplement leaves open):

* **Direction sets** (Sec. 2.1): each probe owns a 16x16 octahedral tile; set ``ds_ij`` is the texel at
  tile coordinate ``(j mod 16, j / 16)``. A ray of a set is jittered inside the set's octahedral texel
  by a hash ``noise(i, j, k, t, seed)`` (Algorithm 1; ``k`` = the ray's index inside its set, so that a
  set with several rays gets distinct directions -- ours); the jittered direction is kept per ray and is
  the direction the ray is integrated with (Algorithm 3's ``Direction_int``).
* **Uniform rays** (Sec. 2.1, Fig. 1): ``x_i`` rays per probe (a power of two in ``[x_min, x_max]``,
  <= 256). The tile, read row-major, is cut into ``x_i`` cells of ``K = 256 / x_i`` consecutive texels
  (``x_i / 16`` cells per row; for ``x_i < 16`` a cell spans ``16 / x_i`` rows); in frame ``t`` the
  texel ``(t + shift_i) mod K`` of every cell gets one ray (rotation by one texel per frame, wrapping
  inside the cell: every set is revisited every ``K`` frames); ``shift_i`` is a per-probe hash of the
  probe index (random ray shifting).
* **Adaptive uniform strategy** (Sec. 2.1, Table 1's 2 bytes per probe): per probe ``log2 x_i`` and a
  counter of the frames it keeps that count (one byte each). A probe *sees change* iff one of its rays
  this frame was dynamic (change above ``dynamic_threshold``). Rule (ours; the supplement gives none): a
  probe that sees change doubles ``x_i`` (up to ``x_max``) and restarts its counter at ``hold_frames``;
  otherwise the counter counts down and, at 0, ``x_i`` halves (down to ``x_min``) and the counter restarts.
* **Change measure** ``f_ij`` (ours; the main paper's is not available): per ray, the larger of the
  normalised luminance difference ``|Y - Y'| / (Y + Y' + Y_floor)`` and the normalised distance difference
  ``|d - d'| / d_max`` against the set's previous sample ``(Y', d')`` (``Y_floor`` also holds twice the
  set's running mean of ``|Y - Y'|``, so sets whose texel straddles a luminance edge or whose hits are
  noisy need a larger change) (``d`` clamped to ``d_max``, back
  faces counted at ``|d|``; ``Y_floor`` includes 1/4 of the probe's mean hit luminance of this frame, so that noise
  on dark sets of a bright probe is no change), soft-thresholded: ``g = max(c - tau, 0) / (1 - tau)``; per set the mean
  over its rays of this frame; in time a peak-hold with exponential decay
  ``f_ij <- max(g_ij, decay * f_ij)`` (sets without a ray this frame only decay). A ray is *dynamic* iff
  ``g > 0`` on two successive visits of its set against the same stored sample (on the first the sample
  is kept and the set marked ``pending``): a single visit's change is often shading noise or a depth edge
  under the jitter, while a real change (a light switched) repeats; the importance rays, drawn ∝ f, make
  that second visit come soon. The set's stored sample (Table 1's "ray hit samples") is an exponential average
  (weight ``SAMPLE_BLEND`` = 0.5 for the new mean of its rays; ours), which damps shading noise.
* **Per-probe change** ``F_i`` (Secs. 4.3-4.4): this frame's rays of probe ``i`` come from two strategies,
  uniform over sets (``p_u(j) = 1/256``, ``N_u`` rays) and importance (``p_f(j|i)``, ``N_f`` rays); the
  balance-heuristic estimate ``F^_i = 1/N sum_r g_r / (q_u p_u(j_r) + q_f p_f(j_r))`` with
  ``q_s = N_s / N`` (Sec. 4.3, last line) estimates ``sum_j g_ij``. ``F_i <- max(F^_i, decay * F_i)``.
* **Importance rays** (ours, within the supplement's frame): ``importance_rays x`` (active probes with
  ``F_i > 0``) rays per frame are drawn i.i.d. from the allocation pdf over (probe, set) pairs
  ``p(i, j) = F_i / sum F * p_f(j | i)``, ``p_f(j | i) = (1 - eps) f_ij / sum_j f_ij + eps / 256``
  (a defensive mixture with the uniform strategy, balance-heuristic style, Sec. 4.3; Sec. 4.4's ideal
  ``p ∝ f`` for ``eps = 0``). No change anywhere: no importance rays. **Multi-Rays** (Table 1): a set
  holds at most ``RAYS_LIMIT = 4`` rays per frame, uniform ray included (inferred from Table 1: 16 bytes
  of integration directions and 24 bytes of hit samples per set are 4 rays of 4 and 6 bytes); draws
  above the limit are dropped. **One-Ray**: at most 1 ray per set; importance draws only add a ray to
  sets without a uniform ray. ``rayHitInfo`` (count, prefix, total per probe) is the plan's per-set count
  table, its exclusive prefix sum inside the probe and the probe's total (:class:`ISDDGIPlanInfo`).
* **Ray weights** (issue 13 item 5, ours): ray ``r`` of set ``j`` weighs ``Omega_j / n_ij`` (the set's
  solid angle over the rays it received this frame): stratified, so ``sum_r w_r h(w_r)`` is unbiased for
  ``int h`` over the sets that received rays, whatever their count. The octahedral texels' solid angles
  differ by up to ~5x, so the supplement's plain ``2 / |Omega^H|`` mean (Sec. 4.2, which assumes
  hemisphere-uniform rays) would over-weight the small texels near the octahedron's edges.

Everything per probe or per set is a small host structure (NumPy, vectorised; P x 256 entries); per-ray
arrays are NumPy in, Dr.Jit out (one upload per frame).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError, unknown_choice
from ..sampling.octahedral import oct_decode_np, texel_solid_angles
from ..sampling.rng import mix_seed
from .rays import RayPlan
from .volume import upload

SETS_PER_SIDE = 16
N_SETS = SETS_PER_SIDE * SETS_PER_SIDE      # 256 direction sets per probe
RAYS_LIMIT = 4                              # rays per set per frame (Multi-Rays), inferred from Table 1
VARIANTS = ("multi-rays", "one-ray")
LUMINANCE_FLOOR = 1e-3                      # Y_floor of the change measure (ours)
PROBE_MEAN_SHARE = 0.25                     # share of the probe's mean luminance in Y_floor (ours)
DEV_SHARE = 2.0                             # weight of the set's mean deviation in the denominator (ours)
CHANGE_EPS = 0.05                           # F_i below this (f_ij below a tenth of it) is 0 (ours)
SAMPLE_BLEND = 0.5                          # EMA weight of a set's new sample in its stored one (ours)
SHIFT_STREAM = 0x15DD61                     # hash stream of the per-probe random shift


def set_solid_angles() -> np.ndarray:
    """(256,) float64 solid angle of each direction set (octahedral texel of the 16x16 tile), sums to 4 pi."""
    om = texel_solid_angles(SETS_PER_SIDE + 2, sub=16).ravel()
    return om * (4.0 * np.pi / om.sum())


def set_directions() -> np.ndarray:
    """(256, 3) centre direction of each set (row-major ``j = y * 16 + x``)."""
    c = (np.arange(SETS_PER_SIDE) + 0.5) / SETS_PER_SIDE * 2.0 - 1.0
    py, px = np.meshgrid(c, c, indexing="ij")
    return oct_decode_np(np.stack([px, py], -1)).reshape(-1, 3)


def _hash_u32(x: np.ndarray) -> np.ndarray:
    """Vectorised 32-bit integer hash (lowbias32, Chris Wellons), uint64 in -> uint64 in [0, 2^32)."""
    x = np.asarray(x, np.uint64) & np.uint64(0xFFFFFFFF)
    x ^= x >> np.uint64(16)
    x = (x * np.uint64(0x7FEB352D)) & np.uint64(0xFFFFFFFF)
    x ^= x >> np.uint64(15)
    x = (x * np.uint64(0x846CA68B)) & np.uint64(0xFFFFFFFF)
    x ^= x >> np.uint64(16)
    return x


def noise2d(probe, dset, k, frame: int, seed: int) -> np.ndarray:
    """Algorithm 1's ``noiseFunction(i, j, t)``: (n, 2) float64 in [0, 1)^2 from a hash of
    (probe, set, ray-in-set, frame, seed)."""
    key = mix_seed(seed, frame, 0x1DD61)
    h = _hash_u32(np.asarray(probe, np.uint64) * np.uint64(N_SETS * RAYS_LIMIT)
                  + np.asarray(dset, np.uint64) * np.uint64(RAYS_LIMIT) + np.asarray(k, np.uint64)
                  + np.uint64(key))
    h = _hash_u32(h ^ np.uint64(key))
    h2 = _hash_u32(h + np.uint64(0x9E3779B9))
    return np.stack([h, h2], -1).astype(np.float64) * (1.0 / 4294967296.0)


def jittered_directions(probe, dset, k, frame: int, seed: int) -> np.ndarray:
    """Algorithm 1: (n, 3) unit directions inside the octahedral texels of sets ``dset``."""
    u = noise2d(probe, dset, k, frame, seed)
    dset = np.asarray(dset, np.int64)
    x = (dset % SETS_PER_SIDE + u[:, 0]) / SETS_PER_SIDE * 2.0 - 1.0
    y = (dset // SETS_PER_SIDE + u[:, 1]) / SETS_PER_SIDE * 2.0 - 1.0
    return oct_decode_np(np.stack([x, y], -1))


def probe_shift(probe_ids) -> np.ndarray:
    """Random ray shifting: a per-probe hash of the probe index (uint64)."""
    return _hash_u32(np.asarray(probe_ids, np.uint64) + np.uint64(SHIFT_STREAM))


def uniform_mask(x: np.ndarray, frame: int, shift: np.ndarray) -> np.ndarray:
    """(P, 256) bool: the sets that get a uniform ray in ``frame`` (Fig. 1 cell layout and rotation).

    ``x`` (P,) uniform rays per probe (powers of two <= 256): cells of ``K = 256 / x`` consecutive
    row-major texels; texel ``(frame + shift) mod K`` of each cell.
    """
    x = np.asarray(x, np.int64)
    if np.any((x < 1) | (x > N_SETS) | (x & (x - 1) != 0)):
        raise DyngiError(f"uniform ray counts must be powers of two in [1, {N_SETS}]")
    K = N_SETS // x
    off = (np.uint64(frame) + np.asarray(shift, np.uint64)) % K.astype(np.uint64)
    return (np.arange(N_SETS)[None, :] % K[:, None]) == off.astype(np.int64)[:, None]


def allocation_pdf(F: np.ndarray, f: np.ndarray, eps: float, cond: np.ndarray | None = None) -> np.ndarray:
    """(P, 256) float64 allocation pdf over (probe, set) pairs (module docstring); all zero without change.
    ``cond``: :func:`conditional_pdf` of ``f`` if already computed."""
    F = np.maximum(np.asarray(F, np.float64), 0.0)
    tot = F.sum()
    if not tot > 0.0:
        return np.zeros(f.shape, np.float64)
    return (F / tot)[:, None] * (conditional_pdf(f, eps) if cond is None else cond)


def conditional_pdf(f: np.ndarray, eps: float) -> np.ndarray:
    """(P, 256) ``p_f(j | i) = (1 - eps) f_ij / sum_j f_ij + eps / 256`` (uniform where a probe has no f)."""
    f = np.maximum(np.asarray(f, np.float64), 0.0)
    s = f.sum(1, keepdims=True)
    base = np.where(s > 0.0, f / np.where(s > 0.0, s, 1.0), 1.0 / N_SETS)
    return (1.0 - eps) * base + eps / N_SETS


def sample_allocation(pdf: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(P, 256) int64 counts of ``n`` i.i.d. draws from ``pdf`` (inverse CDF)."""
    flat = pdf.ravel()
    if n <= 0 or not flat.sum() > 0.0:
        return np.zeros(pdf.shape, np.int64)
    cdf = np.cumsum(flat)
    cdf /= cdf[-1]
    # sorted needles: the same multiset of draws, found ~5x faster (cache-friendly binary searches)
    idx = np.minimum(np.searchsorted(cdf, np.sort(rng.random(int(n))), side="right"), flat.size - 1)
    return np.bincount(idx, minlength=flat.size).reshape(pdf.shape)


@dataclass
class ISDDGIState:
    """Temporal state of the planner (host arrays over all probes of the volume).

    log2_x : (P,) uint8      log2 of the uniform rays per probe (Table 1's adaptive-uniform bytes, 1 of 2)
    hold : (P,) uint8        frames left at that count (the other byte)
    shift : (P,) uint64      random ray shift per probe (fixed)
    f : (P, 256) float32     smoothed change per set
    F : (P,) float64         smoothed balance-heuristic change per probe
    sample_lum, sample_dist : (P, 256) float32   the set's previous hit sample (luminance, clamped distance)
    has_sample : (P, 256) bool
    sample_dev : (P, 256) float32   exponential average of |Y - Y'| (the set's noise / edge level)
    pending : (P, 256) bool  the set changed on its last visit, not yet confirmed (its sample was kept)
    """

    log2_x: np.ndarray
    hold: np.ndarray
    shift: np.ndarray
    f: np.ndarray
    F: np.ndarray
    sample_lum: np.ndarray
    sample_dist: np.ndarray
    has_sample: np.ndarray
    pending: np.ndarray
    sample_dev: np.ndarray

    @staticmethod
    def new(n_probes: int, x_init: int, hold_frames: int) -> "ISDDGIState":
        P = int(n_probes)
        return ISDDGIState(np.full(P, int(np.log2(x_init)), np.uint8), np.full(P, hold_frames, np.uint8),
                           probe_shift(np.arange(P)), np.zeros((P, N_SETS), np.float32), np.zeros(P),
                           np.zeros((P, N_SETS), np.float32), np.zeros((P, N_SETS), np.float32),
                           np.zeros((P, N_SETS), bool), np.zeros((P, N_SETS), bool),
                           np.zeros((P, N_SETS), np.float32))

    @property
    def x(self) -> np.ndarray:
        return (1 << self.log2_x.astype(np.int64))


@dataclass
class ISDDGIPlanInfo:
    """Host bookkeeping of one plan (per traced probe slot ``s``, per set ``j``; per ray ``r``).

    counts : (S, 256) int64   rays per set this frame (rayHitInfo ``num_ij``)
    prefix : (S, 256) int64   exclusive prefix sum of ``counts`` inside the probe (rayHitInfo ``prefix_ij``)
    total : (S,) int64        rays of the probe (rayHitInfo ``total_i``)
    uniform : (S, 256) bool   sets with a uniform ray
    importance : (S, 256) int64  importance rays kept per set (after the RAYS_LIMIT cap)
    cond_pdf : (S, 256)       ``p_f(j | i)`` the importance rays were drawn from
    ray_slot, ray_set : (R,) int64   slot and set of each ray
    ray_dir : (R, 3) float32  integration direction per ray (the jittered one)
    ray_weight : (R,) float32 ``Omega_j / n_ij``
    """

    counts: np.ndarray
    prefix: np.ndarray
    total: np.ndarray
    uniform: np.ndarray
    importance: np.ndarray
    cond_pdf: np.ndarray
    ray_slot: np.ndarray
    ray_set: np.ndarray
    ray_dir: np.ndarray
    ray_weight: np.ndarray
    dropped: int = 0
    stats: dict = field(default_factory=dict)


class ISDDGIPlanner:
    """IS-DDGI ray planner (module docstring). ``plan(frame, seed, probe_ids) -> RayPlan`` with ``plan.info``
    an :class:`ISDDGIPlanInfo`; :meth:`observe` feeds the traced results back (change measure, adaptive
    ``x_i``, ``F_i``).

    Parameters
    ----------
    n_probes : int
    x_init, x_min, x_max : int = 32, 8, 32    uniform rays per probe (powers of two <= 256)
    hold_frames : int = 16        frames a probe keeps its uniform count (ours)
    importance_rays : float = 16  importance rays per frame per traced probe (ours)
    variant : str = 'multi-rays'  'multi-rays' (<= RAYS_LIMIT rays per set) | 'one-ray'
    eps : float = 0.1             defensive uniform share of the conditional pdf (ours)
    dynamic_threshold : float = 0.8   tau of the change measure (ours)
    decay : float = 0.9           per-frame decay of f_ij and F_i (ours)
    max_distance : float          d_max of the change measure (the volume's distance clamp)
    """

    name = "isddgi"

    def __init__(self, n_probes: int, x_init: int = 32, x_min: int = 8, x_max: int = 32, hold_frames: int = 16,
                 importance_rays: float = 16.0, variant: str = "multi-rays", eps: float = 0.1,
                 dynamic_threshold: float = 0.8, decay: float = 0.9, max_distance: float = 1.0):
        for nm, v in (("x_init", x_init), ("x_min", x_min), ("x_max", x_max)):
            if v < 1 or v > N_SETS or (v & (v - 1)):
                raise DyngiError(f"parameter '{nm}' must be a power of two in [1, {N_SETS}], got {v}")
        if not x_min <= x_init <= x_max:
            raise DyngiError(f"uniform rays need x_min <= x_init <= x_max, got {x_min}, {x_init}, {x_max}")
        if variant not in VARIANTS:
            raise unknown_choice("IS-DDGI variant", variant, VARIANTS)
        self.x_init, self.x_min, self.x_max = int(x_init), int(x_min), int(x_max)
        self.hold_frames = int(min(max(hold_frames, 1), 255))
        self.importance_rays = float(importance_rays)
        self.variant = variant
        self.limit = RAYS_LIMIT if variant == "multi-rays" else 1
        self.eps = float(eps)
        self.tau = float(dynamic_threshold)
        self.decay = float(decay)
        self.max_distance = float(max_distance)
        self.omega = set_solid_angles()
        self.state = ISDDGIState.new(n_probes, self.x_init, self.hold_frames)
        self.force_uniform: int | None = None     # e.g. 256 during the warm-up: every set, no importance

    # -- planning -------------------------------------------------------------------
    def plan(self, frame: int, seed: int, probe_ids, previous=None, importance: np.ndarray | None = None) -> RayPlan:
        """This frame's rays for ``probe_ids``; ``importance`` (bool per id) limits who gets importance rays."""
        st = self.state
        pid = np.asarray(probe_ids, np.int64)
        S = len(pid)
        x = st.x[pid] if self.force_uniform is None else np.full(S, self.force_uniform, np.int64)
        uni = uniform_mask(x, frame, st.shift[pid])
        imp = np.zeros((S, N_SETS), np.int64)
        cond = np.full((S, N_SETS), 1.0 / N_SETS)     # p_f(j | i); only probes with change get their own
        if self.force_uniform is None and S:
            F = st.F[pid] * (1.0 if importance is None else np.asarray(importance, bool))
            cand = np.flatnonzero(F > 0.0)               # the pdf is 0 elsewhere: only these are computed
            if len(cand):
                fc = st.f[pid[cand]]
                cc = conditional_pdf(fc, self.eps)
                cond[cand] = cc
                pdf = allocation_pdf(F[cand], fc, self.eps, cc)
                # the budget follows the probes that saw change (ours): a static scene spends none
                n = int(round(self.importance_rays * len(cand)))
                rng = np.random.default_rng(mix_seed(seed, frame, 0x15DD62))
                imp[cand] = sample_allocation(pdf, n, rng)
        drawn = int(imp.sum())
        if self.limit == 1:
            counts = (uni | (imp > 0)).astype(np.int64)
        else:
            counts = np.minimum(uni.astype(np.int64) + imp, self.limit)
        kept_imp = counts - uni
        info = self._rays(pid, counts, frame, seed)
        info.uniform, info.importance, info.cond_pdf = uni, kept_imp, cond
        info.dropped = drawn - int(kept_imp.sum())
        info.stats = {"uniform_rays": int(uni.sum()), "importance_rays": int(kept_imp.sum()),
                      "importance_dropped": info.dropped}
        R = len(info.ray_set)
        direction = mi.Vector3f(*[upload(info.ray_dir[:, c].copy(), mi.Float) for c in range(3)]) if R else \
            mi.Vector3f()
        weight = upload(info.ray_weight, mi.Float) if R else mi.Float()
        plan = RayPlan.ragged(pid.astype(np.uint32), info.total, direction, weight=weight)
        plan.info = info
        return plan

    def _rays(self, pid: np.ndarray, counts: np.ndarray, frame: int, seed: int) -> ISDDGIPlanInfo:
        S = len(pid)
        total = counts.sum(1)
        prefix = np.cumsum(counts, 1) - counts
        flat = counts.ravel()
        pair = np.repeat(np.arange(flat.size), flat)                  # (R,) pair index slot * 256 + j
        first = np.repeat(np.cumsum(flat) - flat, flat)
        k = np.arange(len(pair)) - first                              # ray index inside its set
        slot, dset = pair // N_SETS, pair % N_SETS
        dirs = jittered_directions(pid[slot], dset, k, frame, seed).astype(np.float32)
        w = (self.omega[dset] / flat[pair]).astype(np.float32) if len(pair) else np.zeros(0, np.float32)
        return ISDDGIPlanInfo(counts, prefix, total, np.zeros((S, N_SETS), bool), np.zeros((S, N_SETS), np.int64),
                              np.zeros((S, N_SETS)), slot, dset, dirs, w)

    # -- feedback ---------------------------------------------------------------------
    def ray_change(self, info: ISDDGIPlanInfo, pid: np.ndarray, lum: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """(R,) soft-thresholded change ``g`` of each ray against its set's stored sample (0 without one)."""
        st = self.state
        gp = pid[info.ray_slot]
        dcl = np.minimum(np.abs(dist), self.max_distance)
        old_l = st.sample_lum[gp, info.ray_set]
        old_d = st.sample_dist[gp, info.ray_set]
        has = st.has_sample[gp, info.ray_set]
        # the probe's mean hit luminance in the denominator: noise on dark sets of a bright probe is no change
        S = len(pid)
        ybar = np.bincount(info.ray_slot, lum, S) / np.maximum(info.total, 1)
        dev = st.sample_dev[gp, info.ray_set]
        c_l = np.abs(lum - old_l) / (lum + old_l + PROBE_MEAN_SHARE * ybar[info.ray_slot] + DEV_SHARE * dev
                                     + LUMINANCE_FLOOR)
        c_d = np.abs(dcl - old_d) / self.max_distance
        c = np.maximum(c_l, c_d)
        g = np.maximum(c - self.tau, 0.0) / max(1.0 - self.tau, 1e-6)
        return np.where(has, g, 0.0)

    def observe(self, plan: RayPlan, lum: np.ndarray, dist: np.ndarray, adapt: bool = True) -> dict:
        """Update change measure, stored samples, ``F_i`` and the adaptive ``x_i`` from this frame's rays.

        ``lum`` (R,) hit luminance, ``dist`` (R,) signed distances (host arrays, ray order of ``plan``).
        Returns {'dynamic_rays', 'changed_probes'}.
        """
        st = self.state
        info = plan.info
        pid = np.asarray(plan.probe_ids, np.int64)
        S = len(pid)
        lum = np.asarray(lum, np.float64)
        dist = np.asarray(dist, np.float64)
        g = self.ray_change(info, pid, lum, dist)
        pair = info.ray_slot * N_SETS + info.ray_set          # rays come sorted by pair
        R = len(pair)
        # -- the visited (probe, set) pairs only (a few per probe; never the whole P x 256 tables) --
        starts = np.flatnonzero(np.r_[True, pair[1:] != pair[:-1]]) if R else np.zeros(0, np.int64)
        U = len(starts)
        ucnt = np.diff(np.r_[starts, R])
        inv = np.repeat(np.arange(U), ucnt)
        gi, gj = pid[pair[starts] // N_SETS], pair[starts] % N_SETS
        # a ray is dynamic when its set changed on this visit and on the previous one against the same
        # stored sample (ours: one visit's change is often shading noise or a depth edge under the jitter)
        pending = st.pending[gi, gj]
        dynamic = (g > 0.0) & pending[inv]
        # -- per-set mean change and mean sample of this frame --
        g_set = np.bincount(inv, g, U) / ucnt
        lum_set = np.bincount(inv, lum, U) / ucnt
        d_set = np.bincount(inv, np.minimum(np.abs(dist), self.max_distance), U) / ucnt
        if S == len(st.F) and np.array_equal(pid, np.arange(S)):
            np.multiply(st.f, np.float32(self.decay), out=st.f)
        else:
            st.f[pid] *= np.float32(self.decay)
        f = np.maximum(g_set, st.f[gi, gj])
        st.f[gi, gj] = np.where(f < CHANGE_EPS * 0.1, 0.0, f)
        fresh = ~st.has_sample[gi, gj]
        changed_set = g_set > 0.0
        hold_sample = changed_set & ~pending          # first sighting: keep the reference for the next visit
        st.pending[gi, gj] = hold_sample
        upd = ~hold_sample
        ui, uj = gi[upd], gj[upd]
        # the set's mean absolute luminance deviation from its sample (its noise or edge level)
        absdev = np.abs(lum - st.sample_lum[pid[info.ray_slot], info.ray_set])
        dev_set = (np.bincount(inv, absdev, U) / ucnt)[upd]
        keep = (fresh | changed_set)[upd]
        cur = st.sample_dev[ui, uj]
        st.sample_dev[ui, uj] = np.where(fresh[upd], 0.0, np.where(changed_set[upd], cur,
                                         SAMPLE_BLEND * dev_set + (1.0 - SAMPLE_BLEND) * cur))
        for arr, new in ((st.sample_lum, lum_set[upd]), (st.sample_dist, d_set[upd])):
            cur = arr[ui, uj]
            # a confirmed change replaces the reference; otherwise an exponential average damps the noise
            arr[ui, uj] = np.where(keep, new, SAMPLE_BLEND * new + (1.0 - SAMPLE_BLEND) * cur)
        st.has_sample[gi, gj] = True
        # -- balance-heuristic F_i (Sec. 4.3) --
        n_u = info.uniform.sum(1).astype(np.float64)
        n_f = info.importance.sum(1).astype(np.float64)
        N = np.maximum(n_u + n_f, 1.0)
        sl = info.ray_slot
        mix = (n_u / N)[sl] * (1.0 / N_SETS) + (n_f / N)[sl] * info.cond_pdf[sl, info.ray_set]     # per ray
        est = np.bincount(sl, g / mix, S) / N
        F = np.maximum(est, self.decay * st.F[pid])
        st.F[pid] = np.where(F < CHANGE_EPS, 0.0, F)        # a decayed change is no change (no budget)
        # -- adaptive uniform rays (ours) --
        dyn = np.bincount(info.ray_slot, dynamic.astype(np.float64), S)
        changed = dyn > 0
        if adapt:
            lx = st.log2_x[pid].astype(np.int64)
            hold = st.hold[pid].astype(np.int64)
            lo, hi = int(np.log2(self.x_min)), int(np.log2(self.x_max))
            expire = ~changed & (hold <= 1)
            lx = np.where(changed, np.minimum(lx + 1, hi), np.where(expire, np.maximum(lx - 1, lo), lx))
            hold = np.where(changed | expire, self.hold_frames, hold - 1)
            st.log2_x[pid] = lx.astype(np.uint8)
            st.hold[pid] = hold.astype(np.uint8)
        return {"dynamic_rays": int(dyn.sum()), "changed_probes": int(changed.sum())}
