"""ADGI's Metropolis-guided ray planner (Datta et al. 2022, Secs. 4.8-4.9): a planner of the probe pipeline.

:class:`ADGIChainPlanner` owns the persistent chains and turns one frame's samples into ragged
:class:`~dyngi.probes.rays.RayPlan` s (``plan(frame, seed, probe_ids, stage=..., ...)``, the
:class:`~dyngi.probes.protocols.RayPlanner` protocol with ADGI's hints):

* ``stage='static'`` -- ``static_chains`` chains over continuous probe-grid coordinates (a probe owns
  the unit cell around it) x direction, target ``h = exp(min(g / f_s, 1)) f_s`` on probes of ``V_in``
  (0 elsewhere), ``g`` the luminance of the previous frame's cached irradiance at mip ``guide_mip``
  (:meth:`ADGIChainPlanner.guide_feedback`; Sec. 4.8 "from the previous frame and from a higher
  mip-level", the level is ours). Samples in entries with ``f_d > 0`` are snapped to the centre of
  their irradiance texel (Sec. 4.9). A state repeated by rejected moves is traced once with its
  multiplicity as the plan's weight (:func:`multiplicity`). Under a ray budget ``n_run`` chains run,
  starting where the last frame's stopped (the chains rotate, so a budget spreads over all of them),
  and a device prefix sum caps the traced samples at what the budget pays for (ours).
* ``stage='dynamic'`` -- ``dynamic_chains`` chains over 3x3x3 virtual proxies with 8 octant directions,
  target the max of ``f_d`` over the proxy's 27 probes; each chain marks at most one proxy octant per
  frame (its last sample's: Sec. 4.9's fixed bound), and every marked octant traces, for each of its
  probes in ``V_in``, one ray through each irradiance-texel centre of the octant and, in a second plan
  (:attr:`ADGIChainPlanner.distance_plan`, traced unshaded), one through each distance-texel centre of
  the opposite octant (:func:`octant_texel_centres`; ``dynamic_rays`` > 0: equal-area strata with their
  ``-w`` rays instead, ours). Under a budget the octants with the highest table value go first
  (:func:`budget_keep`: a counting sort by f_d's 10-bit level with prefix sums, on the device), each
  costing its pairs' rays (:meth:`ADGIChainPlanner.pair_cost`).

The hints: ``vin`` (per probe, 1 in V_in), ``fs`` / ``fd`` (per probe octant, from the 6-10-10 word),
``rays`` (the stage's ray allowance or None) and ``shadow_rate`` (measured NEE shadow rays per probe
ray). :attr:`last_samples` is the stage's sample (static) or proxy-octant (dynamic) count. The
pipeline traces each plan along ``w`` (radiance) and ``-w`` (:meth:`RayPlan.reversed
<dyngi.probes.rays.RayPlan.reversed>`, the distance rays; :class:`.passes.ADGIPasses`).

Two implementations of the same sampling (``device``, ours): the host one sizes ragged plans
(``dr.compress`` and a host sort of the probe ids: one read per plan); the device one
(``device=True``) returns masked plans (:meth:`RayPlan.masked <dyngi.probes.rays.RayPlan.masked>`) of a
width fixed on the host -- static: the chains' samples, at most what the stage's allowance ``rays_max``
pays for, without a budget at most 1.25x the samples the last frame wanted (in steps of 4096; the early
iterations' samples first, as a budget's cap); dynamic: (octant, probe) pairs, at most 27 per chain, and
what a budget pays for, or without one 1.25x the last frame's pairs (in steps of 8 proxy octants' worth;
:meth:`ADGIChainPlanner.dynamic_capacity`) -- and takes the stage's exact cap as a device value (``limit``:
samples for S, rays for D). The counts
(:attr:`last_samples`, the unique share, the lanes each stage wanted) stay device values until
:meth:`ADGIChainPlanner.finish_frame` reads them after the frame's image. A change of guide that needs
more dynamic lanes than the capacity is traced, highest guide first, up to it, and fully from the next
frame.
"""
from __future__ import annotations

import numpy as np

from ...backend import dr, mi
from ...errors import unknown_choice
from ...probes.arrays import upload
from ...probes.rays import RayPlan, compact
from ...sampling.metropolis import ChainState, MetropolisChains
from ...sampling.octahedral import direction_to_texel_coords, texel_directions
from .heuristics import OCTANTS, octant_of, octant_of_np, static_guide
from .sparse import SparseKeys

PROXY = 3                 # 3x3x3 probes per virtual proxy (Sec. 4.9)
GUIDE_LEVELS = 1024       # f_d's levels in the 6-10-10 word (Sec. 4.3): the budget's sort keys
STAGES = ("static", "dynamic")


def _ray_cap(rays, shadow_rate: float) -> int:
    """Primary rays a budget of ``rays`` (each with ``shadow_rate`` shadow rays and its continuation) allows,
    as a UInt32: an equal-time budget far above a frame's cost converts to more rays than 2^32 - 1 (it
    overflowed ``dr.opaque(UInt32, ...)``), and a budget below zero to none."""
    r = float(rays)
    if r != r or r <= 0.0:
        return 0
    return int(min(r / (2.0 + shadow_rate), 2.0 ** 32 - 1))


def _ray_total(rays) -> int:
    """A ray allowance as a UInt32 value: clipped to ``[0, 2^32 - 1]`` (NaN: 0)."""
    r = float(rays)
    if r != r or r <= 0.0:
        return 0
    return int(min(r, 2.0 ** 32 - 1))


def sorted_plan(probe, direction, weight, n_probes: int) -> RayPlan:
    """A ragged :class:`RayPlan` from unordered per-sample probe ids: samples grouped by probe with a stable
    host sort (one host copy of the ids; deterministic order). Directions/weights follow the sort."""
    pid = np.asarray(probe, np.uint32)
    order = np.argsort(pid, kind="stable").astype(np.uint32)
    counts = np.bincount(pid, minlength=n_probes)
    ids = np.flatnonzero(counts).astype(np.uint32)
    idx = upload(order, mi.UInt32)
    d = dr.gather(mi.Vector3f, direction, idx)
    w = None if weight is None else dr.gather(mi.Float, weight, idx)
    dr.eval(d, w)
    return RayPlan.ragged(ids, counts[ids], d, weight=w)


def multiplicity(accepted, n_chains: int, samples_per_chain: int):
    """Per sample lane (``j * n + c``: chain ``c`` after its ``j``-th kept iteration, :class:`ChainSamples
    <dyngi.sampling.metropolis.ChainSamples>`), how many of this frame's samples are the same state:
    a *head* (the chain's first kept sample, or an accepted move) gets ``1 +`` the number of rejected
    moves that follow it in its chain, every other lane 0. A rejected Metropolis move repeats the
    previous state (Algorithm 5); tracing it once with weight ``m`` equals ``m`` samples of one ray
    (our choice: the paper traces every sample). One kernel: ``samples_per_chain - 1`` gathers per lane."""
    S = int(samples_per_chain)
    n = dr.opaque(mi.UInt32, int(n_chains))
    lane = dr.arange(mi.UInt32, int(n_chains) * S)
    j = lane // n
    head = accepted | (j == 0)
    run = mi.Bool(head)
    mult = mi.UInt32(head)
    for d in range(1, S):
        nxt = j + d
        inside = nxt < S
        run &= inside & ~dr.gather(mi.Bool, accepted, lane + d * n, inside & run)
        mult += mi.UInt32(run)
    return dr.select(head, mult, 0)


def guide_level(values, levels: int):
    """``values`` (>= 0) as integer keys in ``[0, levels)``: ``round(v / max v * (levels - 1))``, the max
    a device reduction (no host read). With ``levels`` = 1024 this recovers f_d's 10-bit level of the
    6-10-10 word (Sec. 4.3) exactly."""
    top = dr.max(values)
    rel = dr.select(top > 0.0, values / dr.maximum(top, 1e-30), 0.0)
    return mi.UInt32(dr.round(dr.clip(rel, 0.0, 1.0) * (int(levels) - 1)))


def budget_keep(key, cost, budget, levels: int):
    """Which items to keep so that the sum of their ``cost`` stays within ``budget``, highest ``key`` first
    (ties in index order): a device counting sort by key with prefix sums (no host read, no sort).

    ``key``: UInt32 in ``[0, levels)`` per item (higher: first); ``cost``: UInt32 per item; ``budget``:
    UInt32 (opaque: a per-frame value). Whole key levels are kept while their total cost fits; of the
    first level that does not fit, the items in index order while the budget lasts (an exclusive prefix
    sum over the items of that level). Returns a Bool per item."""
    L = int(levels)
    rank = mi.UInt32(L - 1) - key                                  # 0: the highest key
    hist = dr.zeros(mi.UInt32, L)
    dr.scatter_reduce(dr.ReduceOp.Add, hist, cost, rank)
    before = dr.prefix_sum(hist)                   # cost of all higher levels
    lo = dr.gather(mi.UInt32, before, rank)
    hi = lo + dr.gather(mi.UInt32, hist, rank)
    whole = hi <= budget
    boundary = (lo <= budget) & ~whole
    pre = dr.prefix_sum(dr.select(boundary, cost, 0))
    return whole | (boundary & (lo + pre + cost <= budget))


_OCTANT_SIGNS_NP = np.array([[-1.0 if o & 1 else 1.0, -1.0 if o & 2 else 1.0, -1.0 if o & 4 else 1.0]
                             for o in range(OCTANTS)])


def octant_strata(k: int) -> np.ndarray:
    """(k*k, 3) directions in the +++ octant: centres of an equal-area k x k stratification (``z = (i + 1/2) /
    k``, ``phi = (j + 1/2) / k * pi / 2``; ours, ``dynamic_rays`` > 0)."""
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    z = (i.ravel() + 0.5) / k
    phi = (j.ravel() + 0.5) / k * np.pi / 2
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def octant_texel_centres(texels: int, opposite: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The interior texel centres of a ``texels`` x ``texels`` octahedral map (DDGI border), by octant (Sec.
    4.9: D's "ray-direction is deterministic, passing through the center of a texel"): ``(dirs (8, R, 3),
    valid (8, R))``, row ``o`` the centres whose direction lies in octant ``o`` (:func:`.heuristics.octant_of`'s
    signs; centres on an octant plane go to the octant of their signs, so each interior texel is in exactly
    one row), padded to the longest row. ``opposite``: row ``o`` holds the centres ``d`` with ``-d`` in ``o``
    (the distance texels an octant's ``-w`` rays reach). At 8x8 an octant holds 3-6 of the 36 centres, at
    16x16 21-28 of the 196."""
    d = texel_directions(texels)[1:-1, 1:-1].reshape(-1, 3).astype(np.float64)
    oc = octant_of_np(-d if opposite else d)
    rows = [d[oc == o] for o in range(OCTANTS)]
    R = max(len(r) for r in rows)
    dirs = np.zeros((OCTANTS, R, 3))
    valid = np.zeros((OCTANTS, R), bool)
    for o, r in enumerate(rows):
        dirs[o, :len(r)] = r
        dirs[o, len(r):] = r[0] if len(r) else (0.0, 0.0, 1.0)
        valid[o, :len(r)] = True
    return dirs, valid


def _table(dirs: np.ndarray):
    """An (8, R, 3) direction table as a flat Vector3f (entry ``o * R + r``)."""
    flat = np.ascontiguousarray(dirs.reshape(-1, 3), np.float32)
    return mi.Vector3f(*[upload(flat[:, c]) for c in range(3)])


class ADGIChainPlanner:
    """Static and dynamic Metropolis chains of ADGI as one ray planner; see the module docstring.

    ``params``: the ``adgi`` technique's (chains, iterations, burn-in, steps, ``dynamic_rays``,
    ``guide_mip``).
    """

    def __init__(self, volume, params: dict):
        p = params
        self.volume = volume
        self.counts = tuple(int(c) for c in volume.grid.counts)
        n = np.asarray(self.counts, np.float64)
        self.proxies = tuple(int(c) for c in np.ceil(n / PROXY).astype(int))
        step = p["position_step"]
        self.static = MetropolisChains(-0.5 * np.ones(3), n - 0.5, step, p["direction_step"], p["burn_in"],
                                       p["iterations"], stream=0xAD61)
        npx = np.asarray(self.proxies, np.float64)
        self.dynamic = MetropolisChains(-0.5 * np.ones(3), npx - 0.5, step * p["dynamic_position_scale"] / PROXY,
                                        min(p["direction_step"] * p["dynamic_direction_scale"], 3.0),
                                        p["burn_in"], p["iterations"], stream=0xAD62)
        self.static_state = self.static.initial_state(p["static_chains"], 0)
        self.dynamic_state = self.dynamic.initial_state(p["dynamic_chains"], 1) if p["dynamic_chains"] else None
        self._setup_guide_mip(p["guide_mip"])
        self._texel_dirs = mi.Float(texel_directions(volume.irradiance_texels)[1:-1, 1:-1]
                                    .reshape(-1).astype(np.float32))
        self._setup_dynamic_directions(int(p["dynamic_rays"]))
        self._entry_keys = SparseKeys(int(np.prod(self.proxies)) * OCTANTS)    # D's marked (proxy, octant) entries
        self.n_run = self.static_state.n
        self.last_samples = 0
        self._first = 0              # the first static chain to run under a budget (rotates, ours)
        self._unique = 1.0           # traced / kept samples of the last budgeted static frame (measured)
        self.device = False          # masked plans, no host read (set by the technique's ``impl``)
        self._pending = {}           # device counts of this frame, read by finish_frame()
        self._dyn_pairs = 0          # (octant, probe) pairs the last frame's dynamic stage wanted (device, measured)
        self.distance_plan = None    # D's distance rays of the last dynamic plan (None: the plan's reversed)
        self.dynamic_wanted = None   # rays the last D wanted before a budget cut (device path: after finish_frame)
        self._static_lanes = 0       # samples the last frame's static stage wanted (device path, measured)

    def plan(self, frame: int, seed: int, probe_ids=None, previous=None, stage: str = "static", vin=None,
             fs=None, fd=None, rays=None, shadow_rate: float = 1.0, rays_max=None, limit=None) -> RayPlan | None:
        """This stage's rays (None: no sample this frame). ``probe_ids`` is unused: the chains choose the
        probes (those of ``vin``). Device path only: ``rays_max`` (host) bounds the plan's width under a
        budget, ``limit`` (device UInt32) is the stage's exact cap (module docstring)."""
        if stage == "static":
            return self._static_plan(frame, seed, vin, fs, fd, rays, shadow_rate, rays_max, limit)
        if stage == "dynamic":
            if self.dynamic_state is None:
                self.last_samples = 0
                return None
            return self._dynamic_plan(frame, seed, vin, fd, rays, shadow_rate, rays_max, limit)
        raise unknown_choice("ADGI planner stage", stage, STAGES)

    def _setup_dynamic_directions(self, dynamic_rays: int) -> None:
        """D's per-octant direction tables (Sec. 4.9): with ``dynamic_rays`` = 0 (the paper's) the radiance rays
        of octant ``o`` are the irradiance-texel centres in ``o`` and the distance rays the distance-texel
        centres in ``-o`` (:func:`octant_texel_centres`); else ``dynamic_rays`` equal-area strata per octant
        (:func:`octant_strata`; ours, the earlier default) with the distances along their ``-w``. Also the
        rays one (octant, probe) pair costs per octant, less the NEE shadow rays (:meth:`pair_cost`)."""
        vol = self.volume
        if dynamic_rays == 0:
            d_irr, ok_irr = octant_texel_centres(vol.irradiance_texels)
            d_dist, ok_dist = octant_texel_centres(vol.distance_texels, opposite=True)
        else:
            k = int(round(np.sqrt(dynamic_rays)))
            d_irr = octant_strata(k)[None] * _OCTANT_SIGNS_NP[:, None, :]
            ok_irr = np.ones(d_irr.shape[:2], bool)
            d_dist = ok_dist = None
        self._R_irr = d_irr.shape[1]
        self._n_irr = ok_irr.sum(1)                          # radiance rays per octant
        self._dir_irr = _table(d_irr)
        self._ok_irr = mi.Bool(upload(ok_irr.ravel().astype(np.uint32), mi.UInt32) != 0)
        if d_dist is None:                                   # the -w of each radiance ray
            self._R_dist, self._n_dist, self._dir_dist, self._ok_dist = 0, self._n_irr, None, None
        else:
            self._R_dist = d_dist.shape[1]
            self._n_dist = ok_dist.sum(1)                    # distance rays per octant
            self._dir_dist = _table(d_dist)
            self._ok_dist = mi.Bool(upload(ok_dist.ravel().astype(np.uint32), mi.UInt32) != 0)

    def pair_cost(self, shadow_rate: float) -> np.ndarray:
        """Rays one (proxy octant, probe) pair of D costs, per octant (8 ints, rounded up): its radiance rays
        with ``shadow_rate`` NEE shadow rays each, and its distance rays."""
        return np.ceil(self._n_irr * (1.0 + float(shadow_rate)) + self._n_dist).astype(np.int64)

    def rays_per_pair(self) -> tuple[np.ndarray, np.ndarray]:
        """(radiance rays, distance rays) per octant of one (proxy octant, probe in V_in) pair of D."""
        return self._n_irr.copy(), self._n_dist.copy()

    def _chains_to_run(self, rays, shadow_rate: float) -> int:
        n = self.static_state.n
        if rays is None:
            return n
        # 15% more chains than the last frame's share of unique samples pays for (ours): the device cap on
        # the traced samples keeps the budget, so the margin only fills it when the share moves
        per_chain = self.static.samples_per_chain * self._unique * (2.0 + shadow_rate)
        return int(min(max(1.15 * rays // per_chain, 1), n))

    def _probe_of(self, x, counts):
        """Lattice point (probe or proxy index) nearest to continuous grid coordinates ``x``."""
        nx, ny, nz = counts
        i = dr.clip(mi.Int32(dr.round(x.x)), 0, nx - 1)
        j = dr.clip(mi.Int32(dr.round(x.y)), 0, ny - 1)
        k = dr.clip(mi.Int32(dr.round(x.z)), 0, nz - 1)
        return mi.UInt32(i + nx * (j + ny * k))

    def _texel_of(self, w):
        T = self.volume.irradiance_texels
        c = direction_to_texel_coords(w, T)
        ix = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, T - 3)
        iy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, T - 3)
        return mi.UInt32(iy * (T - 2) + ix), mi.UInt32((iy + 1) * T + ix + 1)

    # -- the guide's feedback at a coarser mip (Sec. 3.2, 4.8) --
    def _setup_guide_mip(self, level: int) -> None:
        """Mip ``level`` of the irradiance maps' interiors: ``(T-2) / 2^level`` texels per side (rounded
        up), each the mean luminance of the ``2^level x 2^level`` interior texels it covers (fewer at an odd
        edge). Our choice: level 1 (3x3 per probe for the 8x8 maps), the first level coarser than the
        texels the samples update; the paper says only "a higher mip-level" (Sec. 4.8)."""
        T = self.volume.irradiance_texels
        n = T - 2
        self._mip_level = int(level)
        self._mip_n = m = -(-n // (1 << self._mip_level))
        iy, ix = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        cell = ((iy >> self._mip_level) * m + (ix >> self._mip_level)).ravel()
        self._mip_cell = upload(cell.astype(np.uint32), mi.UInt32)                  # interior texel -> mip cell
        self._mip_src = upload(((iy + 1) * T + ix + 1).ravel().astype(np.uint32), mi.UInt32)   # -> atlas texel
        self._mip_norm = upload((1.0 / np.bincount(cell, minlength=m * m)).astype(np.float32), mi.Float)

    def guide_feedback(self):
        """Per probe and mip cell (``P * m * m`` Floats): the luminance of the irradiance atlas at mip
        ``guide_mip``, read at the start of the static stage, i.e. the previous frame's convolved
        irradiance (this frame's samples reach the atlas only at the end of the frame). Luminance is our
        scalar of the RGB cache (Rec. 709 weights)."""
        vol = self.volume
        T = vol.irradiance_texels
        n_int = (T - 2) ** 2
        mm = self._mip_n * self._mip_n
        lane = dr.arange(mi.UInt32, vol.n_probes * n_int)
        probe = lane // n_int
        k = lane - probe * n_int
        lum = mi.luminance(dr.gather(mi.Color3f, vol.device.irradiance,
                                     probe * (T * T) + dr.gather(mi.UInt32, self._mip_src, k)))
        cell = dr.gather(mi.UInt32, self._mip_cell, k)
        g = dr.zeros(mi.Float, vol.n_probes * mm)
        dr.scatter_reduce(dr.ReduceOp.Add, g, lum * dr.gather(mi.Float, self._mip_norm, cell), probe * mm + cell)
        dr.eval(g)
        return g

    def guide_at(self, probe, w):
        """The static guide's feedback ``g`` for samples at ``probe`` along ``w``: :meth:`guide_feedback`'s
        value of the mip cell ``w`` falls in, computed per sample from the irradiance atlas (the mean luminance
        of the cell's ``2^level x 2^level`` interior texels; fewer at an odd edge) -- work that follows the
        chains' samples, not the grid's probes."""
        vol = self.volume
        T = vol.irradiance_texels
        n = T - 2
        L = self._mip_level
        c = direction_to_texel_coords(w, T)
        cx = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, n - 1) >> L
        cy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, n - 1) >> L
        base = probe * (T * T)
        total = mi.Float(0.0)
        count = mi.Float(0.0)
        for dy in range(1 << L):
            for dx in range(1 << L):
                ix, iy = (cx << L) + dx, (cy << L) + dy
                ok = (ix < n) & (iy < n)
                v = dr.gather(mi.Color3f, vol.device.irradiance, base + mi.UInt32((iy + 1) * T + ix + 1), ok)
                total += dr.select(ok, mi.luminance(v), 0.0)
                count += dr.select(ok, 1.0, 0.0)
        return total / dr.maximum(count, 1.0)

    def _mip_cell_of(self, w):
        """Mip cell (row-major in the ``m x m`` mip) that direction ``w`` falls in."""
        T = self.volume.irradiance_texels
        c = direction_to_texel_coords(w, T)
        ix = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, T - 3)
        iy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, T - 3)
        L = self._mip_level
        return mi.UInt32((iy >> L) * self._mip_n + (ix >> L))

    def _static_plan(self, frame: int, seed: int, vin_dr, fs, fd, rays, shadow_rate: float, rays_max=None,
                     limit=None):
        """S (Sec. 4.8): run the static chains (the first ``n_run`` under a ray budget), one ray per sample
        with ``h > 0``; ``fs`` is f_s from the 6-10-10 word (Sec. 4.3)."""
        vol = self.volume

        def target(x, w):
            probe = self._probe_of(x, self.counts)
            e = probe * OCTANTS + octant_of(w)
            f = dr.gather(mi.Float, fs, e) * dr.gather(mi.Float, vin_dr, probe)
            # g: the previous frame's irradiance at mip guide_mip, read per sample (guide_at), only where f > 0
            g = dr.select(f > 0.0, self.guide_at(probe, w), 0.0)
            return static_guide(f, g)

        n_run = self.n_run = self._chains_to_run(rays, shadow_rate)
        st = self.static_state
        n_all = st.n
        if rays is not None:     # a budget runs n_run chains from a rotating first one (ours: each frame
            # starts where the last stopped, so a budget spreads over all chains); the others keep their
            # states. This path even when n_run is all of them: one set of kernels whatever the budget
            # (the offset and the modulus are opaque)
            lane = (dr.arange(mi.UInt32, n_run) + dr.opaque(mi.UInt32, self._first)) % dr.opaque(mi.UInt32, n_all)
            self._first = (self._first + n_run) % n_all
            sub = ChainState(dr.gather(mi.Vector3f, st.position, lane), dr.gather(mi.Vector3f, st.direction, lane))
            sub, s = self.static.run(sub, target, seed, frame)
            pos, dirs = mi.Vector3f(st.position), mi.Vector3f(st.direction)
            dr.scatter(pos, sub.position, lane)
            dr.scatter(dirs, sub.direction, lane)
            dr.eval(pos, dirs)
            self.static_state = ChainState(pos, dirs)
        else:
            self.static_state, s = self.static.run(st, target, seed, frame)
        # a repeated state (rejected move) is traced once, weighted by its multiplicity
        mult = multiplicity(s.accepted, n_run, self.static.samples_per_chain)
        ok = (s.value > 0.0) & (mult > 0)
        if self.device:
            return self._static_masked(s, mult, ok, fd, n_run, rays, shadow_rate, rays_max, limit)
        if rays is not None:     # never more samples than the budget pays for (lane order: early iterations first)
            cap = int(max(rays // (2.0 + shadow_rate), 0))
            ok &= dr.prefix_sum(mi.UInt32(ok)) < dr.opaque(mi.UInt32, cap)
        idx = dr.compress(ok)          # (its width is the sample count: the one sync of the stage's sizes)
        n = self.last_samples = dr.width(idx)
        if n == 0:
            return None
        x = dr.gather(mi.Vector3f, s.position, idx)
        w = dr.gather(mi.Vector3f, s.direction, idx)
        m = mi.Float(dr.gather(mi.UInt32, mult, idx))
        kept_dr = dr.sum(m)            # = the samples with h > 0 (a state's repeats share its h), read below
        probe = self._probe_of(x, self.counts)
        # samples in entries with f_d > 0 go through their irradiance texel's centre (Sec. 4.9)
        snap = dr.gather(mi.Float, fd, probe * OCTANTS + octant_of(w)) > 0.0
        ti, _ = self._texel_of(w)
        w = dr.select(snap, dr.gather(mi.Vector3f, self._texel_dirs, ti), w)
        dr.eval(probe, w, m, kept_dr)
        plan = sorted_plan(probe, w, m, vol.n_probes)
        kept = float(kept_dr[0])       # already computed: no further wait
        if kept > 0 and (rays is None or n < cap):   # the traced share of the samples, for the next budget
            self._unique = min(max(n / kept, 0.05), 1.0)
        return plan

    def _static_masked(self, s, mult, ok, fd, n_run: int, rays, shadow_rate: float, rays_max, limit):
        """The device path's static plan (module docstring): the same samples as the host path's, capped on
        the device (``limit`` samples, else the host cap of ``rays``), packed into a masked plan of at most
        the samples ``rays_max`` pays for; no host read."""
        width = n_run * self.static.samples_per_chain
        # the cap always applies (no budget: none can bind), as an evaluated value: one set of kernels
        # whether or not this frame has a budget, and of which kind
        cap = dr.opaque(mi.UInt32, 0xFFFFFFFF)
        if rays is None and self._static_lanes:    # 1.25x the last frame's samples (ours: early iterations first)
            width = min(width, max(-(-int(1.25 * self._static_lanes) // 4096), 1) * 4096)
        if rays is not None:
            cap = limit if limit is not None else dr.opaque(mi.UInt32, _ray_cap(rays, shadow_rate))
            bound = rays if rays_max is None else rays_max
            width = min(width, int(max(bound // (2.0 + shadow_rate), 0)) + 1)
        ok &= dr.prefix_sum(mi.UInt32(ok)) < cap
        idx, lane_ok = compact(ok, width)
        x = dr.gather(mi.Vector3f, s.position, idx)
        w = dr.gather(mi.Vector3f, s.direction, idx)
        m = dr.select(lane_ok, mi.Float(dr.gather(mi.UInt32, mult, idx)), 0.0)
        probe = self._probe_of(x, self.counts)
        snap = dr.gather(mi.Float, fd, probe * OCTANTS + octant_of(w), lane_ok) > 0.0
        ti, _ = self._texel_of(w)
        w = dr.select(snap, dr.gather(mi.Vector3f, self._texel_dirs, ti), w)
        n = dr.count(lane_ok)
        self.last_samples = n
        self._pending["static_lanes"] = dr.count(ok)
        self._pending["static"] = (n, dr.sum(m), None if rays is None else
                                   (limit if limit is not None else mi.UInt32(int(max(rays // (2.0 + shadow_rate),
                                                                                       0)))))
        return RayPlan.masked(probe, w, lane_ok, self.volume.n_probes, weight=m)

    def dynamic_capacity(self, rays_max, shadow_rate: float) -> int:
        """(Proxy octant, probe) pairs of the device path's dynamic plans: at most 27 per chain (one proxy octant
        per chain per frame, Sec. 4.9's fixed bound); under a budget also what ``rays_max`` pays for at the
        cheapest octant; without one 1.25x the pairs the last frame wanted (the bound before any was measured), rounded up
        to a multiple of 8 proxy octants' worth (ours, module docstring: a width is no kernel parameter, so it may change every frame)."""
        bound = PROXY ** 3 * max(self.dynamic_state.n, 1)
        if rays_max is not None:
            return max(min(int(rays_max // max(int(self.pair_cost(shadow_rate).min()), 1)) + 1, bound), 1)
        if not self._dyn_pairs:      # nothing measured yet: the fixed bound
            return bound
        step = 8 * PROXY ** 3
        return max(min(-(-int(1.25 * self._dyn_pairs) // step) * step, bound), step)

    def finish_frame(self) -> None:
        """Read this frame's device counts (after the frame's image: no extra wait): :attr:`last_samples` as
        ints, the static stage's unique share (for the next budget) and the lanes the dynamic stage wanted."""
        st = self._pending.pop("static", None)
        if st is not None:
            n, kept, cap = (float(np.asarray(v).ravel()[0]) if v is not None else None for v in st)
            if kept > 0 and (cap is None or n < cap):
                self._unique = min(max(n / kept, 0.05), 1.0)
        lanes = self._pending.pop("static_lanes", None)
        if lanes is not None:
            self._static_lanes = int(np.asarray(lanes).ravel()[0])
        dyn = self._pending.pop("dynamic", None)
        if dyn is not None:
            self._dyn_pairs = int(np.asarray(dyn).ravel()[0])
        wanted = self._pending.pop("dynamic_wanted", None)
        if wanted is not None:
            self.dynamic_wanted = int(np.asarray(wanted).ravel()[0])
        self._pending.clear()

    def _dynamic_plan(self, frame: int, seed: int, vin_dr, fd, rays, shadow_rate: float, rays_max=None,
                      limit=None):
        """D (Sec. 4.9): run the dynamic chains on the proxy table; every proxy octant they visit traces
        ``dynamic_rays`` strata per probe of it in V_in. Under a budget: whole octants, those with the highest
        proxy-table value (the guide) first, while ``rays`` last (:func:`budget_keep`, on the device; ours:
        the paper's chains visit proxies in proportion to the guide, a budget cut keeps the largest)."""
        vol = self.volume
        # -- the proxy table: max of f_d over the proxy's 27 probes in V_in, per (proxy, octant) entry, evaluated
        # where the chains and the budget read it (work that follows the chains, not the grid) --
        def table(ent):
            return self.proxy_value(ent, vin_dr, fd)

        def target(x, w):
            return table(self._probe_of(x, self.proxies) * OCTANTS + octant_of(w))

        self.dynamic_state, s = self.dynamic.run(self.dynamic_state, target, seed, frame)
        # -- one proxy octant per chain per frame (Sec. 4.9: "the first invocation to update the octant marks
        # it", a fixed bound of the stage's work): the chain's last sample of the frame, if h > 0 there --
        n = self.dynamic_state.n
        last = dr.arange(mi.UInt32, n) + (self.dynamic.samples_per_chain - 1) * n
        pos = dr.gather(mi.Vector3f, s.position, last)
        w = dr.gather(mi.Vector3f, s.direction, last)
        ent = self._probe_of(pos, self.proxies) * OCTANTS + octant_of(w)
        hot = dr.gather(mi.Float, s.value, last) > 0.0
        # the chains' entries made unique (an owner table reset on use: chain-sized work, .sparse.SparseKeys)
        ukey, u_ok, _, _, _, _ = self._entry_keys.reduce(ent, [], mi.Float(1.0) + dr.zeros(mi.Float, n), hot,
                                                         device=self.device)
        cost = upload(self.pair_cost(shadow_rate).astype(np.uint32), mi.UInt32)     # rays per pair, by octant
        self.distance_plan = None
        if self.device:
            return self._dynamic_masked(table, ukey, u_ok, vin_dr, cost, rays, rays_max, limit)
        # the marked entries in index order (the budget's ties go in index order; <= n_chains of them)
        marked = upload(np.sort(np.asarray(ukey, np.uint32)), mi.UInt32)
        n_marked = self.last_samples = dr.width(marked)
        if n_marked == 0:
            self.dynamic_wanted = 0
            return None
        # -- (marked proxy octant, sub-probe of 27) pairs; then the rays of the pairs in V_in: the octants'
        # invalid sub-probes never get ray lanes (27x fewer planning lanes at a large grid; same plan) --
        probe, ok, oo, m = self._pairs(marked, None, vin_dr)
        pair_cost = dr.select(ok, dr.gather(mi.UInt32, cost, oo), 0)
        self.dynamic_wanted = int(dr.sum(pair_cost)[0])      # (the host path reads its sizes anyway)
        if rays is not None:    # budget: whole proxy octants, the highest guide value first
            # pairs of one proxy octant are contiguous: a block sum, not a scatter into n_marked slots
            # (on LLVM that bakes n_marked into the kernel, a new kernel whenever it changes)
            per = dr.block_reduce(dr.ReduceOp.Add, pair_cost, 27)
            key = guide_level(table(marked), GUIDE_LEVELS)
            keep_m = budget_keep(key, per, dr.opaque(mi.UInt32, _ray_total(rays)), GUIDE_LEVELS)
            ok &= dr.gather(mi.Bool, keep_m, m)
            dr.eval(ok)
        keep = dr.compress(ok)
        if dr.width(keep) == 0:
            return None
        pair_probe = dr.gather(mi.UInt32, probe, keep)
        pair_oct = dr.gather(mi.UInt32, oo, keep)
        plan = self._host_rays(pair_probe, pair_oct, self._dir_irr, self._ok_irr, self._R_irr)
        if self._dir_dist is not None:
            self.distance_plan = self._host_rays(pair_probe, pair_oct, self._dir_dist, self._ok_dist, self._R_dist)
        return plan

    def proxy_value(self, ent, vin_dr, fd):
        """Sec. 4.9's virtual-proxy table at entries ``ent`` (``proxy * 8 + octant``): the max of ``f_d`` over
        the proxy's 3x3x3 probes in ``V_in`` along the octant (0 outside the grid)."""
        nx, ny, nz = self.counts
        px, py, _ = self.proxies
        q = ent // OCTANTS
        o = ent - q * OCTANTS
        qi, qj, qk = mi.Int32(q % px), mi.Int32((q // px) % py), mi.Int32(q // (px * py))
        out = mi.Float(0.0)
        for di in range(PROXY):
            for dj in range(PROXY):
                for dk in range(PROXY):
                    i, j, k = qi * PROXY + di, qj * PROXY + dj, qk * PROXY + dk
                    inside = (i < nx) & (j < ny) & (k < nz)
                    pr = mi.UInt32(dr.select(inside, i + nx * (j + ny * k), 0))
                    v = dr.gather(mi.Float, fd, pr * OCTANTS + o, inside) * dr.gather(mi.Float, vin_dr, pr, inside)
                    out = dr.maximum(out, v)
        return out

    def _host_rays(self, pair_probe, pair_oct, dirs, dirs_ok, R: int) -> RayPlan:
        """A ragged plan of the table rays of each (probe, octant) pair: ``dirs[o * R + r]`` where valid."""
        lane = dr.arange(mi.UInt32, dr.width(pair_probe) * R)
        pair = lane // R
        e = dr.gather(mi.UInt32, pair_oct, pair) * R + (lane - pair * R)
        idx = dr.compress(dr.gather(mi.Bool, dirs_ok, e))
        d = dr.gather(mi.Vector3f, dirs, dr.gather(mi.UInt32, e, idx))
        return sorted_plan(dr.gather(mi.UInt32, pair_probe, dr.gather(mi.UInt32, pair, idx)), d, None,
                           self.volume.n_probes)

    def _pairs(self, marked, m_ok, vin_dr):
        """Per (proxy octant ``marked[m]``, sub-probe ``s`` of its 27) lane ``27 m + s``: (probe, in V_in (and
        ``m_ok[m]``), octant, m)."""
        nx, ny, nz = self.counts
        px, py, _ = self.proxies
        lane = dr.arange(mi.UInt32, dr.width(marked) * 27)
        m = lane // 27
        sub = lane - m * 27
        ent = dr.gather(mi.UInt32, marked, m)
        q = ent // OCTANTS
        oo = ent - q * OCTANTS
        i = mi.Int32(q % px) * PROXY + mi.Int32(sub % PROXY)
        j = mi.Int32((q // px) % py) * PROXY + mi.Int32((sub // PROXY) % PROXY)
        k = mi.Int32(q // (px * py)) * PROXY + mi.Int32(sub // (PROXY * PROXY))
        inside = (i < nx) & (j < ny) & (k < nz)
        if m_ok is not None:
            inside &= dr.gather(mi.Bool, m_ok, m)
        probe = mi.UInt32(dr.select(inside, i + nx * (j + ny * k), 0))
        ok = inside & (dr.gather(mi.Float, vin_dr, probe, inside) > 0.0)
        dr.eval(probe, ok, oo)
        return probe, ok, oo, m

    def _dynamic_masked(self, table, marked, m_ok, vin_dr, cost, rays, rays_max, limit):
        """The device path's dynamic plans (module docstring): the marked proxy octants packed on the device (at
        most one per chain), their (octant, probe) pairs, whole octants kept highest guide first while the cap
        lasts (``limit`` rays under a budget, the plans' width without one), packed into masked plans of
        :meth:`dynamic_capacity` pairs (the radiance rays; the distance rays in :attr:`distance_plan`); no host
        read."""
        self.last_samples = dr.count(m_ok)
        probe, ok, oo, m = self._pairs(marked, m_ok, vin_dr)
        self._pending["dynamic"] = dr.count(ok)
        pair_cost = dr.select(ok, dr.gather(mi.UInt32, cost, oo), 0)
        self._pending["dynamic_wanted"] = dr.sum(pair_cost)
        n_pairs = self.dynamic_capacity(rays_max if rays is not None else None, 0.0)
        per = dr.block_reduce(dr.ReduceOp.Add, pair_cost, 27)
        key = guide_level(dr.select(m_ok, table(marked), 0.0), GUIDE_LEVELS)
        # whole octants, highest guide first, while the plans' width (pairs) and, under a budget, the rays last
        keep_m = budget_keep(key, dr.block_reduce(dr.ReduceOp.Add, mi.UInt32(ok), 27),
                             dr.opaque(mi.UInt32, n_pairs), GUIDE_LEVELS)
        if rays is not None:
            budget = limit if limit is not None else dr.opaque(mi.UInt32, _ray_total(rays))
            keep_m &= budget_keep(key, per, budget, GUIDE_LEVELS)
        ok &= dr.gather(mi.Bool, keep_m, m)
        pairs, p_ok = compact(ok, n_pairs)
        pair_probe = dr.gather(mi.UInt32, probe, pairs)
        pair_oct = dr.gather(mi.UInt32, oo, pairs)
        plan = self._masked_rays(pair_probe, pair_oct, p_ok, self._dir_irr, self._ok_irr, self._R_irr)
        if self._dir_dist is not None:
            self.distance_plan = self._masked_rays(pair_probe, pair_oct, p_ok, self._dir_dist, self._ok_dist,
                                                   self._R_dist)
        return plan

    def _masked_rays(self, pair_probe, pair_oct, pair_ok, dirs, dirs_ok, R: int) -> RayPlan:
        """A masked plan of ``R`` lanes per pair slot: ``dirs[o * R + r]`` where the pair and the entry are valid."""
        lane = dr.arange(mi.UInt32, dr.width(pair_probe) * R)
        pair = lane // R
        e = dr.gather(mi.UInt32, pair_oct, pair) * R + (lane - pair * R)
        lane_ok = dr.gather(mi.Bool, pair_ok, pair) & dr.gather(mi.Bool, dirs_ok, e)
        return RayPlan.masked(dr.gather(mi.UInt32, pair_probe, pair), dr.gather(mi.Vector3f, dirs, e), lane_ok,
                              self.volume.n_probes)
