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
  texel ``(t + shift_i + perm_i(c)) mod K`` of cell ``c`` gets one ray (rotation by one texel per frame,
  wrapping inside the cell: every set is revisited every ``K`` frames); ``shift_i`` is a per-probe hash of
  the probe index and ``perm_i(c)`` a hash of it and the cell (random ray shifting, "permute the predefined
  ray allocation pattern differently for every probe"; the per-cell part is ours, see :func:`uniform_keys`).
* **Adaptive uniform strategy** (Sec. 2.1, Table 1's 2 bytes per probe): per probe ``log2 x_i`` and a
  counter of the frames it keeps that count (one byte each). A probe *sees change* iff one of its rays
  this frame was dynamic (change above ``dynamic_threshold``). Rule (ours; the supplement gives none): a
  probe that sees change doubles ``x_i`` (up to ``x_max``) and restarts its counter at ``hold_frames``;
  otherwise the counter counts down and, at 0, ``x_i`` halves (down to ``x_min``) and the counter restarts.
* **Change measure** ``f_ij`` (ours; the main paper's is not available) by **paired visits**: the uniform
  rays of a set alternate between *reference* and *check* visits. A check visit repeats its reference
  exactly: the same jitter and the same random numbers for its NEE sample and its stochastic hit lookup
  (per-ray keys, :mod:`dyngi.techniques.isddgi.shading`), so in a static scene it hits the same point,
  picks the same light point and reads the same probe texel, and its luminance differs from the
  reference's only by the drift of the probes it reads. (Fresh shading noise per visit would make one
  NEE sample over many lights read as change: a ray's luminance is then 0 or many times its mean;
  docs/techniques/isddgi.md has the figure.) Per check ray the larger of the normalised luminance difference
  ``|Y - Y'| / (Y + Y' + Y_floor)`` and distance difference ``|d - d'| / d_max``
  against the reference ``(Y', d')`` (``d`` clamped to ``d_max``, back faces at ``|d|``; ``Y_floor`` =
  1e-3 + 1/4 of the probe's mean hit luminance of this frame, so that a change of a dark set of a bright
  probe is small), soft-thresholded: ``g = max(c - tau, 0) / (1 - tau)``; a check ray with ``g > 0`` is
  *dynamic*. In time a peak hold with exponential decay ``f_ij <- max(g_ij, decay * f_ij)``, and the 8
  neighbouring sets of the tile get ``NEIGHBOUR_SHARE`` (1/4) of a measured change (a change one ray saw is
  a change of a surface its neighbouring directions see too; without it the importance rays pile onto the
  few sets that measured and the per-set limit drops ~60% of them). Only uniform rays measure: importance
  rays keep independent random numbers (repeating theirs would repeat their samples). The price: every
  uniform sample enters the estimate twice (half as many independent uniform samples). A set's first visit
  opens a reference only on the even squares of the tile's checkerboard, so that about half of each frame's
  uniform rays are checks; a relocated probe and the warm-up forget their references.
* **Per-probe change** ``F_i`` (Secs. 4.3-4.4): the balance-heuristic estimate ``F^_i = 1/N sum_r g_r /
  (q_u p_u(j_r) + q_f p_f(j_r))`` (Sec. 4.3, last line) over the *measuring* rays; these are the check
  visits, uniform over the sets (``q_f = 0``), so ``F^_i = 256 x`` their mean ``g`` (it estimates
  ``sum_j g_ij``); ``F_i <- max(F^_i, decay * F_i)``. The mixture of the two strategies remains in the
  allocation pdf below.
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

Host planner (``impl='host'``; the default is its device twin :class:`~.device_planner.DeviceISDDGIPlanner`,
same formulas, issue 26): the per-probe and per-set
state is host NumPy (P x 256 entries; vectorised); a frame's plan is built sparse -- the sorted
``slot * 256 + j`` keys of its uniform rays and importance draws, merged and capped per set -- so no P x 256
table is built per frame (rayHitInfo's dense count/prefix tables are built on first use only), and one
upload per frame (ray hash, set, rays of its pair) lets the device compute directions (Algorithm 1),
weights and shading keys (:func:`device_rays`). The sparse plan is about twice as fast as a dense host
one (docs/techniques/isddgi.md).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ...backend import mi
from ...errors import DyngiError, unknown_choice
from ...sampling.rng import mix_seed
from ...probes.arrays import upload
from ...probes.rays import RayPlan
from .sets import (SETS_PER_SIDE, N_SETS, RAYS_LIMIT, VARIANTS, LUMINANCE_FLOOR, PROBE_MEAN_SHARE, CHANGE_EPS,
                   NEIGHBOUR_SHARE, _NB, BUDGET_REDRAWS, SHADE_STREAM, set_solid_angles, _hash_u32, ray_hash,
                   _noise_from_hash, _dirs_from_noise, probe_shift, allocation_pdf, conditional_pdf, device_rays,
                   uniform_keys, sample_indices, merge_keys)  # noqa: F401  (re-exported)


@dataclass
class ISDDGIState:
    """Temporal state of the planner (host arrays over all probes of the volume).

    log2_x : (P,) uint8      log2 of the uniform rays per probe (Table 1's adaptive-uniform bytes, 1 of 2)
    hold : (P,) uint8        frames left at that count (the other byte)
    shift : (P,) uint64      random ray shift per probe (fixed)
    f : (P, 256) float32     smoothed change per set
    F : (P,) float64         smoothed balance-heuristic change per probe
    sample_lum, sample_dist : (P, 256) float32   the set's last uniform hit sample (luminance, clamped distance)
    has_sample : (P, 256) bool
    ref_key : (P, 256) uint32   the random key of that sample's ray (its frame's key)
    open_ref : (P, 256) bool    that sample awaits its check visit (which reuses ``ref_key``)
    """

    log2_x: np.ndarray
    hold: np.ndarray
    shift: np.ndarray
    f: np.ndarray
    F: np.ndarray
    sample_lum: np.ndarray
    sample_dist: np.ndarray
    has_sample: np.ndarray
    ref_key: np.ndarray
    open_ref: np.ndarray

    @staticmethod
    def new(n_probes: int, x_init: int, hold_frames: int) -> "ISDDGIState":
        P = int(n_probes)
        return ISDDGIState(np.full(P, int(np.log2(x_init)), np.uint8), np.full(P, hold_frames, np.uint8),
                           probe_shift(np.arange(P)), np.zeros((P, N_SETS), np.float32), np.zeros(P),
                           np.zeros((P, N_SETS), np.float32), np.zeros((P, N_SETS), np.float32),
                           np.zeros((P, N_SETS), bool), np.zeros((P, N_SETS), np.uint32),
                           np.zeros((P, N_SETS), bool))

    @property
    def x(self) -> np.ndarray:
        return (1 << self.log2_x.astype(np.int64))


class ISDDGIPlanInfo:
    """Host bookkeeping of one plan (per traced probe slot ``s``, per set ``j``; per ray ``r``).

    Kept sparse (the rays and the sorted pair keys ``slot * 256 + j``); the dense per-set tables of Table 1's
    rayHitInfo are built on first use only (tests, diagnostics), not per frame:

    counts : (S, 256) int64   rays per set this frame (rayHitInfo ``num_ij``)
    prefix : (S, 256) int64   exclusive prefix sum of ``counts`` inside the probe (rayHitInfo ``prefix_ij``)
    total : (S,) int64        rays of the probe (rayHitInfo ``total_i``; always computed)
    uniform : (S, 256) bool   sets with a uniform ray
    importance : (S, 256) int64  importance rays kept per set (after the RAYS_LIMIT cap)
    cond_pdf : (S, 256)       ``p_f(j | i)`` the importance rays were drawn from (uniform outside ``cand``)
    ray_slot, ray_set : (R,) int64   slot and set of each ray
    ray_dir : (R, 3) float32  integration direction per ray (the jittered one)
    ray_weight : (R,) float32 ``Omega_j / n_ij``
    ray_paired : (R,) bool    the set's uniform ray (paired visits: the only rays that measure change)
    ray_check : (R,) bool     a paired ray that repeats its set's open reference (a check visit)
    ray_rkey : (R,) uint32    the random key of each ray (its frame's key; a check: the reference's)
    ray_key : (R,) uint32     shading key: seeds the ray's NEE and hit-lookup random numbers
    ray_hash : (R,) uint64    the ray's hash (jitter and shading key derive from it); ray_npair : rays of its pair
    ``ray_dir``, ``ray_weight``, ``ray_key`` are host copies built on first use: the device computes them
    itself from one upload of (hash, set, rays of the pair) per ray (:func:`device_rays`).
    """

    def __init__(self, S, total, ray_slot, ray_set, ray_hash, ray_npair, omega, ray_paired, ray_check, ray_rkey,
                 cand=None, cand_cond=None):
        self.S = int(S)
        self.total = total
        self.ray_slot, self.ray_set, self.ray_hash, self.ray_npair = ray_slot, ray_set, ray_hash, ray_npair
        self._omega = omega
        self.ray_paired, self.ray_check, self.ray_rkey = ray_paired, ray_check, ray_rkey
        self.cand = np.zeros(0, np.int64) if cand is None else cand
        self.cand_cond = cand_cond
        self.dropped = 0
        self.stats: dict = {}
        self._cache: dict = {}

    def _table(self, name, mask=None):
        if name not in self._cache:
            key = self.ray_slot * N_SETS + self.ray_set
            if mask is not None:
                key = key[mask]
            self._cache[name] = np.bincount(key, minlength=self.S * N_SETS).reshape(self.S, N_SETS)
        return self._cache[name]

    @property
    def ray_dir(self) -> np.ndarray:
        """(R, 3) float32 host copy of the jittered directions (the device computes its own, same formula)."""
        if "dir" not in self._cache:
            self._cache["dir"] = _dirs_from_noise(self.ray_set, _noise_from_hash(self.ray_hash)).astype(np.float32)
        return self._cache["dir"]

    @property
    def ray_weight(self) -> np.ndarray:
        return (self._omega[self.ray_set] / np.maximum(self.ray_npair, 1)).astype(np.float32)

    @property
    def ray_key(self) -> np.ndarray:
        return _hash_u32(self.ray_hash ^ np.uint64(SHADE_STREAM)).astype(np.uint32)

    @property
    def counts(self) -> np.ndarray:
        return self._table("counts")

    @property
    def prefix(self) -> np.ndarray:
        return np.cumsum(self.counts, 1) - self.counts

    @property
    def uniform(self) -> np.ndarray:
        return self._table("uniform", self.ray_paired) > 0

    @property
    def importance(self) -> np.ndarray:
        return self._table("importance", ~self.ray_paired)

    @property
    def cond_pdf(self) -> np.ndarray:
        out = np.full((self.S, N_SETS), 1.0 / N_SETS)
        if self.cand_cond is not None and len(self.cand):
            out[self.cand] = self.cand_cond
        return out


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
        self.repeat_checks = True      # paired-visit repeats (ours; the technique sets its paired_repeats)

    # -- planning -------------------------------------------------------------------
    def plan(self, frame: int, seed: int, probe_ids, previous=None, importance: np.ndarray | None = None,
             n_rays: int | None = None) -> RayPlan:
        """This frame's rays for ``probe_ids``; ``importance`` (bool per id) limits who gets importance rays.

        ``n_rays`` (a comparison budget; ours): trace exactly that many rays where possible. The default
        split (``x_i`` uniform rays per probe + ``importance_rays`` per probe with change) is scaled by
        ``s = n_rays / default``: every ``x_i`` by the power of two ``2^floor(log2 s)`` (clamped to [1, 256]),
        and the importance rays take the rest (draws over a set's limit are drawn again, up to
        :data:`BUDGET_REDRAWS` times, from the sets with room). Without change anywhere the rest goes to
        uniform rays: probes in a per-frame rotating order double their count while the running total fits,
        and the last few rays are drawn uniformly over all (probe, set) pairs."""
        t0 = time.perf_counter()
        st = self.state
        pid = np.asarray(probe_ids, np.int64)
        S = len(pid)
        x = st.x[pid] if self.force_uniform is None else np.full(S, self.force_uniform, np.int64)
        budget = n_rays is not None and self.force_uniform is None and S
        F = cand = None
        if self.force_uniform is None and S:
            F = st.F[pid] * (1.0 if importance is None else np.asarray(importance, bool))
            cand = np.flatnonzero(F > 0.0)               # the pdf is 0 elsewhere: only these are computed
        # the budget follows the probes that saw change (ours): a static scene spends none
        n_imp = int(round(self.importance_rays * len(cand))) if cand is not None else 0
        if budget:
            x, n_imp = self._budget_split(x, n_imp if len(cand) else 0, int(n_rays), frame)
        ukey = uniform_keys(x, frame, st.shift[pid])
        ikey = np.zeros(0, np.int64)
        cc = None
        if cand is not None and n_imp > 0:
            if len(cand):
                fc = st.f[pid[cand]]
                cc = conditional_pdf(fc, self.eps)
                pdf = allocation_pdf(F[cand], fc, self.eps, cc)
            else:       # a budget's rest without change anywhere: uniform over all (probe, set) pairs
                cand = np.arange(S)
                pdf = np.full((S, N_SETS), 1.0 / (S * N_SETS))
            rng = np.random.default_rng(mix_seed(seed, frame, 0x15DD62))
            idx = sample_indices(pdf, n_imp, rng)
            ikey = cand[idx // N_SETS] * N_SETS + idx % N_SETS
        keys, k, is_uni, dropped = merge_keys(ukey, ikey, self.limit)
        drawn = len(ikey)
        if budget and dropped and len(ikey):
            # exact count: draws over a set's limit are drawn again where there is room
            pos = np.full(S, -1, np.int64)
            pos[cand] = np.arange(len(cand))
            for _ in range(BUDGET_REDRAWS):
                short = n_imp - (len(ikey) - dropped)
                if short <= 0:
                    break
                lp = pos[keys // N_SETS]
                cnt = np.bincount(lp[lp >= 0] * N_SETS + keys[lp >= 0] % N_SETS, minlength=pdf.size)
                room = pdf.ravel() * (cnt < self.limit)
                if not room.sum() > 0.0:
                    break
                idx = sample_indices(room / room.sum(), short, rng)
                more = cand[idx // N_SETS] * N_SETS + idx % N_SETS
                ikey = np.sort(np.concatenate([ikey, more]))
                keys, k, is_uni, dropped = merge_keys(ukey, ikey, self.limit)
            drawn = len(ikey)
        info = self._rays_from_keys(pid, keys, k, is_uni, frame, seed)
        info.cand, info.cand_cond = (cand, cc) if cc is not None else (np.zeros(0, np.int64), None)
        kept_imp = int((~is_uni).sum())
        info.dropped = drawn - kept_imp
        info.stats = {"uniform_rays": int(is_uni.sum()), "importance_rays": kept_imp,
                      "importance_dropped": info.dropped}
        direction, weight, shade_key = device_rays(info, self._omega_dr())
        plan = RayPlan.ragged(pid.astype(np.uint32), info.total, direction, weight=weight)
        plan.info = info
        plan.shade_key = shade_key
        info.stats["plan_ms"] = (time.perf_counter() - t0) * 1e3     # the allocation alone (stat; ours)
        return plan

    def _omega_dr(self):
        if getattr(self, "_omega_device", None) is None:
            self._omega_device = upload(self.omega.astype(np.float32), mi.Float)
        return self._omega_device

    def _budget_split(self, x: np.ndarray, n_imp: int, n_rays: int, frame: int) -> tuple:
        """(uniform counts per probe, importance rays) for a budget of ``n_rays`` (see :meth:`plan`)."""
        x = np.asarray(x, np.int64)
        default = int(x.sum()) + n_imp
        s = n_rays / max(default, 1)
        L = int(np.floor(np.log2(s))) if s > 0 else -9
        L = min(max(L, -8), 8)
        xs = np.clip(x << L if L >= 0 else x >> -L, 1, N_SETS)
        rest = n_rays - int(xs.sum())
        if n_imp > 0:
            return xs, max(rest, 0)
        if rest > 0:         # no change anywhere: the rest as doubled uniform counts, rotating over the probes
            S = len(xs)
            order = (np.arange(S) + (frame * 7919) % max(S, 1)) % max(S, 1)
            extra = np.where(xs[order] < N_SETS, xs[order], 0)
            take = np.cumsum(extra) <= rest
            xs[order[take]] += extra[take]
            rest = n_rays - int(xs.sum())
        return xs, max(rest, 0)      # the last few: importance rays drawn uniformly (see plan)

    def _rays(self, pid: np.ndarray, counts: np.ndarray, frame: int, seed: int,
              uni: np.ndarray | None = None) -> ISDDGIPlanInfo:
        """Rays of a dense per-set ``counts`` table (``uni``: the sets whose ray 0 is a uniform ray)."""
        flat = np.asarray(counts, np.int64).ravel()
        keys = np.repeat(np.arange(flat.size), flat)
        k = np.arange(len(keys)) - np.repeat(np.cumsum(flat) - flat, flat)
        is_uni = (k == 0) & (np.asarray(uni).ravel()[keys] if uni is not None else False)
        return self._rays_from_keys(np.asarray(pid, np.int64), keys, k, np.asarray(is_uni, bool), frame, seed)

    def _rays_from_keys(self, pid: np.ndarray, keys: np.ndarray, k: np.ndarray, is_uni: np.ndarray, frame: int,
                        seed: int) -> ISDDGIPlanInfo:
        """Rays of sorted pair ``keys`` (``k``: index inside the pair; ``is_uni``: the pair's uniform ray, its
        ray 0). A uniform ray whose set holds an open reference is a check visit and repeats the
        reference's random key (same jitter, same shading numbers); every other ray draws from (frame, seed)."""
        S = len(pid)
        slot, dset = keys // N_SETS, keys % N_SETS
        R = len(keys)
        total = np.bincount(slot, minlength=S).astype(np.int64)
        key = np.full(R, mix_seed(seed, frame, 0x1DD61), np.uint32)
        check = np.zeros(R, bool)
        pr = np.flatnonzero(is_uni)
        if len(pr):
            gp, gj = pid[slot[pr]], dset[pr]
            c = self.state.open_ref[gp, gj]
            check[pr] = c
            if self.repeat_checks:    # ours: the check repeats its reference; else a fresh, independent sample
                key[pr[c]] = self.state.ref_key[gp[c], gj[c]]
        h = ray_hash(pid[slot], dset, k, key.astype(np.uint64))
        # rays per pair: the run length of its key
        if R:
            start = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
            run = np.diff(np.r_[start, R])
            n_pair = np.repeat(run, run)
        else:
            n_pair = np.zeros(0, np.int64)
        return ISDDGIPlanInfo(S, total, slot, dset, h, n_pair, self.omega, is_uni, check, key)

    # -- the pipeline's warm-up hooks (ours) ------------------------------------------------
    def begin_warmup(self) -> None:
        """Warm-up plans: one ray in every set of every probe, no importance rays."""
        self.force_uniform = N_SETS

    def end_warmup(self) -> None:
        """Back to the allocation; the change measure forgets the warm-up: the bounces it added are no
        scene change, and its samples no reference (the probes they read have changed)."""
        self.force_uniform = None
        st = self.state
        st.f[:] = 0.0
        st.F[:] = 0.0
        st.has_sample[:] = False
        st.open_ref[:] = False

    # -- feedback ---------------------------------------------------------------------
    def forget(self, probes) -> None:
        """Drop the stored samples (references) of ``probes`` (e.g. relocated ones: their next rays start
        elsewhere, so a difference would be no scene change)."""
        st = self.state
        st.has_sample[probes] = False
        st.open_ref[probes] = False

    def ray_change(self, info: ISDDGIPlanInfo, pid: np.ndarray, lum: np.ndarray, dist: np.ndarray):
        """Change of the paired (uniform) rays against their set's open reference (check visits only).

        Returns ``(rays, g, measured)``: the indices of the paired rays, their soft-thresholded change ``g``
        (0 where not measured) and whether the ray was a check visit."""
        st = self.state
        pr = np.flatnonzero(info.ray_paired) if info.ray_paired is not None else np.zeros(0, np.int64)
        gp, j = pid[info.ray_slot[pr]], info.ray_set[pr]
        measured = info.ray_check[pr] & st.has_sample[gp, j]
        y = lum[pr]
        dcl = np.minimum(np.abs(dist[pr]), self.max_distance)
        # the probe's mean hit luminance in the denominator: a change of a dark set of a bright probe is small
        S = len(pid)
        ybar = np.bincount(info.ray_slot, lum, S) / np.maximum(info.total, 1)
        y_old = st.sample_lum[gp, j]
        c_l = np.abs(y - y_old) / (y + y_old + PROBE_MEAN_SHARE * ybar[info.ray_slot[pr]] + LUMINANCE_FLOOR)
        c_d = np.abs(dcl - st.sample_dist[gp, j]) / self.max_distance
        c = np.maximum(c_l, c_d)
        g = np.maximum(c - self.tau, 0.0) / max(1.0 - self.tau, 1e-6)
        return pr, np.where(measured, g, 0.0), measured

    def observe(self, plan: RayPlan, lum: np.ndarray, dist: np.ndarray, adapt: bool = True) -> dict:
        """Update change measure, stored samples, ``F_i`` and the adaptive ``x_i`` from this frame's rays.

        ``lum`` (R,) hit luminance, ``dist`` (R,) signed distances (host arrays, ray order of ``plan``).
        Returns {'dynamic_rays', 'changed_probes', 'check_rays'}.
        """
        st = self.state
        info = plan.info
        pid = np.asarray(plan.probe_ids, np.int64)
        S = len(pid)
        lum = np.asarray(lum, np.float64)
        dist = np.asarray(dist, np.float64)
        pr, g, measured = self.ray_change(info, pid, lum, dist)
        sl = info.ray_slot[pr]
        gp, j = pid[sl], info.ray_set[pr]
        dynamic = g > 0.0                 # a check visit's change is no noise: dynamic at once (paired visits)
        # -- a reference visit's sample becomes its set's open reference (the set's next uniform visit repeats
        #    it: a check); a check closes it. A set's first visit opens one only on the even squares of the tile's
        #    checkerboard (ours): the others start a visit later, so about half of a frame's uniform rays check --
        ref = ~info.ray_check[pr]
        st.open_ref[gp, j] = ref & (st.has_sample[gp, j] | ((j % SETS_PER_SIDE + j // SETS_PER_SIDE) % 2 == 0))
        st.sample_lum[gp, j] = lum[pr]
        st.sample_dist[gp, j] = np.minimum(np.abs(dist[pr]), self.max_distance)
        st.ref_key[gp, j] = info.ray_rkey[pr]
        st.has_sample[gp, j] = True
        # -- smoothed change per set: peak hold with exponential decay --
        if S == len(st.F) and np.array_equal(pid, np.arange(S)):
            np.multiply(st.f, np.float32(self.decay), out=st.f)
        else:
            st.f[pid] *= np.float32(self.decay)
        f = st.f[gp, j]
        f = np.maximum(g, f)
        st.f[gp, j] = np.where(f < CHANGE_EPS * 0.1, 0.0, f)
        # a change one ray saw is the change of a surface that its neighbouring directions see too: the 8
        # neighbouring sets of the tile get NEIGHBOUR_SHARE of it (ours; spreads the importance rays, which
        # the per-set limit would otherwise drop)
        hit = np.flatnonzero(g > 0.0)
        if len(hit):
            jx, jy = j[hit] % SETS_PER_SIDE, j[hit] // SETS_PER_SIDE
            nx = np.clip(jx[:, None] + _NB[None, :, 0], 0, SETS_PER_SIDE - 1)
            ny = np.clip(jy[:, None] + _NB[None, :, 1], 0, SETS_PER_SIDE - 1)
            np.maximum.at(st.f, (np.repeat(gp[hit], len(_NB)), (ny * SETS_PER_SIDE + nx).ravel()),
                          np.repeat(NEIGHBOUR_SHARE * g[hit], len(_NB)).astype(np.float32))
        # -- F_i (Sec. 4.3): the measuring rays are the check visits, uniform over the sets (p_u = 1/256),
        #    so the mixture estimate sum_r g_r / (N q_u p_u) is 256 x their mean change --
        n_meas = np.bincount(sl, measured.astype(np.float64), S)
        est = np.where(n_meas > 0, N_SETS * np.bincount(sl, g, S) / np.maximum(n_meas, 1.0), 0.0)
        F = np.maximum(est, self.decay * st.F[pid])
        st.F[pid] = np.where(F < CHANGE_EPS, 0.0, F)        # a decayed change is no change (no budget)
        # -- adaptive uniform rays (ours) --
        dyn = np.bincount(sl, dynamic.astype(np.float64), S)
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
        return {"dynamic_rays": int(dyn.sum()), "changed_probes": int(changed.sum()),
                "check_rays": int(measured.sum())}
