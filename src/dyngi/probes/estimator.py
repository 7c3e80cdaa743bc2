"""Estimators: one frame's probe rays -> per-texel means, weights and counts (accumulation, first half).

An estimator turns the rays of a :class:`~dyngi.probes.rays.RayPlan` and their
:class:`~dyngi.probes.trace.ProbeRayResults` into a :class:`TexelEstimate`
for the *interior* texels of every traced probe; a temporal accumulator
(:mod:`dyngi.probes.accumulator`) then merges it with the stored texels.

Two ways a ray reaches texels:

* ``kernel`` -- DDGI (Majercik et al., JCGT 2019, Sec. 3.2): ray ``r`` adds to
  every texel ``t`` of its probe with weight ``w_r max(0, n_t . w_r)^p``
  (``p = 1`` irradiance, ``p = distance_power`` moments; ``w_r`` the plan's
  per-ray weight, ``1 / pdf``); the texel value is the self-normalised mean
  ``sum w x / sum w``. Cosines below ``MIN_BLEND_WEIGHT^(1/p)`` count as 0.
* ``bin`` -- each ray adds to one texel only: the one the plan names
  (``plan.texel``, per-texel lobe plans) or the one its direction falls in
  (ADGI's per-sample updates, Datta et al. 2022, Sec. 4.5 and Algorithm 3).

**Back-face hits** (negative distance) do not enter the irradiance estimate
(issue 11 item 2, as RTXGI's blend skips them); they still enter the distance
moments with ``|d| = 0.2 t`` as DDGI/RTXGI do (that makes probes near back
faces see the wall close by, which the visibility test wants).

Implementations:

* :class:`MatrixEstimator` -- the CPU fast path for a shared direction set:
  the kernel weights form one matrix ``W[N x (T-2)^2]`` for every probe and the
  estimate is ``radiance[P x N] @ W`` (NumPy/BLAS; DESIGN.md has the
  measurements). Probes with back-face hits get their irradiance row
  renormalised over their front-face rays.
* :class:`ScatterEstimator` -- the general path, all Dr.Jit (no host round
  trip; the path used on ``cuda_ad_rgb``): one lane per (ray, texel) pair
  (kernel) or per ray (bin), summed with ``dr.scatter_reduce``. The sums are
  **fixed-point integers** (``UInt64``, ``FIXED_POINT_BITS`` fractional bits):
  integer addition is associative, so reruns are bit-identical on every backend
  (float atomics are not), and a texel that receives many samples gets their
  exact mean (to ``2^-30`` per term). Terms above ``MAX_TERM`` saturate (a
  radiance x weight of 1.3e8; ours, far above any scene we run).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError, unknown_choice
from ..sampling.octahedral import direction_to_texel_coords, texel_directions
from .trace import ProbeRayResults

MIN_BLEND_WEIGHT = 1e-12
FIXED_POINT_BITS = 30                   # fractional bits of the fixed-point sums
FIXED_SCALE = float(1 << FIXED_POINT_BITS)
MAX_TERM = float(1 << 27)               # a term w * x above this saturates (2^57 of 2^64: room for 128 of them)
ESTIMATORS = ("auto", "matrix", "scatter")
SCATTER_MODES = ("auto", "kernel", "bin")
LOCAL = dr.ReduceMode.Local           # see fixed_point_sum


@dataclass
class TexelEstimate:
    """This frame's estimate for the interior texels of the traced probes.

    value : Float      channel-planar flat means ``sum w x / sum w``: channel ``c`` of entry ``e``
                       at ``c * n + e``; entry ``e = slot * (T-2)^2 + t`` (``t`` row-major interior)
    count : UInt32     samples with non-zero weight, per entry (or per interior texel if ``per_texel``)
    ok : Bool          the entry received weight (same indexing as ``count``)
    n : int            entries (``P_traced * (T-2)^2``)
    channels : int     3 (irradiance, E/pi) or 2 (distance moments)
    per_texel : bool   ``count``/``ok`` are shared by all probes (the matrix path), indexed by ``t``
    weight : Float | None   sums of weights per entry (scatter path only)
    """

    value: "mi.Float"
    count: "mi.UInt32"
    ok: "mi.Bool"
    n: int
    channels: int
    per_texel: bool = False
    weight: "mi.Float" = None

    def means(self) -> np.ndarray:
        """(n, C) float32 host copy of the means (for tests and inspection)."""
        return np.asarray(self.value, np.float32).reshape(self.channels, self.n).T


def is_cpu_backend() -> bool:
    return not mi.variant().startswith("cuda")


def choose_estimator(name: str, plan, distance_power: float = 50.0, mode: str = "auto"):
    """``'auto'``: the matrix path for a shared set on the CPU backend, the scatter path otherwise."""
    if name not in ESTIMATORS:
        raise unknown_choice("estimator", name, ESTIMATORS)
    matrix_ok = plan.shared_directions is not None and plan.texel is None
    if name == "matrix" and not matrix_ok:
        raise DyngiError("estimator 'matrix' needs a plan whose probes share one direction set; "
                         "use estimator 'scatter' (or 'auto')")
    if name == "matrix" or (name == "auto" and matrix_ok and is_cpu_backend()):
        return MatrixEstimator(distance_power)
    return ScatterEstimator(distance_power, mode)


# -- matrix path (CPU, shared direction set) --------------------------------------

def blend_matrix(ray_dirs: np.ndarray, texels: int, power: float,
                 interior: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Normalised blend weights (N, T*T) float32 and a (T*T,) mask of texels that received weight.

    ``W[r, t] = max(0, n_t . w_r)^power / sum_r' max(0, n_t . w_r')^power``.
    With ``interior`` only the ``(T-2)^2`` interior texels are columns (the
    border texels copy them; see :func:`interior_source_index`).

    Rebuilt every frame (the rays rotate), so it is computed in float32 with
    cosines below ``MIN_BLEND_WEIGHT^(1/power)`` set to 0 first: their weights
    would be cut anyway, and no float32 denormal (slow in the power and in the
    BLAS products) can arise.
    """
    tdirs = _texel_directions_table(int(texels), bool(interior))
    c = np.asarray(ray_dirs, np.float32) @ tdirs.T
    cut = _cosine_cut(power)
    c[c <= cut] = 0.0
    w = _power(c, power)
    s = w.sum(axis=0, dtype=np.float64)
    ok = s > 0.0
    w[:, ok] *= (1.0 / s[ok]).astype(np.float32)
    w[w < MIN_BLEND_WEIGHT] = 0.0
    return w, ok


def _cosine_cut(power: float) -> float:
    return MIN_BLEND_WEIGHT ** (1.0 / power) if power > 1.0 else 0.0


@functools.lru_cache(maxsize=None)
def _texel_directions_table(texels: int, interior: bool) -> np.ndarray:
    """(T*T or (T-2)^2, 3) float32 texel directions (read-only, shared)."""
    tdirs = texel_directions(texels, with_border=not interior)
    tdirs = (tdirs[1:-1, 1:-1] if interior else tdirs).reshape(-1, 3).astype(np.float32)
    tdirs.flags.writeable = False
    return tdirs


def _power(c: np.ndarray, p: float) -> np.ndarray:
    """``c ** p``; integer powers by repeated squaring (the per-frame matrix rebuild is ~4x faster)."""
    if p == 1.0:
        return c
    if p != int(p) or p < 1 or p > 1024:
        return c ** np.float32(p)
    n, out, sq = int(p), None, c
    while n:
        if n & 1:
            out = sq.copy() if out is None else np.multiply(out, sq, out=out)
        n >>= 1
        if n:
            sq = sq * sq
    return out


class MatrixEstimator:
    """Kernel estimate of a shared direction set as dense products (NumPy/BLAS); see the module docstring.

    ``count`` is per interior texel: the rays with non-zero weight in ``W``
    (back-face rays of a probe included; the scatter path counts exactly).
    """

    name = "matrix"

    def __init__(self, distance_power: float = 50.0):
        self.distance_power = float(distance_power)
        self._cache_key = None
        self._cache = None

    def _matrices(self, dirs: np.ndarray, volume):
        key = (dirs.shape, hash(dirs.tobytes()), volume.irradiance_texels, volume.distance_texels,
               self.distance_power)
        if key != self._cache_key:
            out = []
            for T, p in ((volume.irradiance_texels, 1.0), (volume.distance_texels, self.distance_power)):
                W, ok = blend_matrix(dirs, T, p, interior=True)
                out.append((W, mi.Bool(ok), mi.UInt32(np.count_nonzero(W, axis=0).astype(np.uint32))))
            self._cache = tuple(out)
            self._cache_key = key
        return self._cache

    def _check(self, results: ProbeRayResults):
        plan = results.plan
        if plan.shared_directions is None:
            raise DyngiError("the matrix estimator needs a shared direction set (use the scatter estimator)")
        return plan

    def irradiance(self, volume, results: ProbeRayResults) -> TexelEstimate:
        """Interior irradiance texels ``E/pi`` (3 channels) of the traced probes."""
        plan = self._check(results)
        (Wi, ok_i, cnt_i), _ = self._matrices(plan.shared_directions, volume)
        P, N = len(plan.probe_ids), plan.rays_per_probe
        rad_host, dist_host = results.host()
        rad = rad_host.reshape(3 * P, N)
        irr = rad @ Wi
        # -- back-face hits leave the irradiance estimate: renormalise those probes over their front rays --
        back = dist_host.reshape(P, N) < 0.0
        rows = np.flatnonzero(back.any(axis=1))
        if len(rows):
            front = (~back[rows]).astype(np.float32)
            denom = front @ Wi
            num = (rad.reshape(3, P, N)[:, rows] * front) @ Wi
            with np.errstate(divide="ignore", invalid="ignore"):
                irr.reshape(3, P, -1)[:, rows] = num / denom     # 0/0 = NaN: no front ray, keep the old texel
        return TexelEstimate(mi.Float(irr.ravel()), cnt_i, ok_i, irr.shape[1] * P, 3, per_texel=True)

    def distance(self, volume, results: ProbeRayResults) -> TexelEstimate:
        """Interior distance moments (mean |d| clamped to ``max_distance``, mean square) of the traced probes."""
        plan = self._check(results)
        _, (Wd, ok_d, cnt_d) = self._matrices(plan.shared_directions, volume)
        P, N = len(plan.probe_ids), plan.rays_per_probe
        dist_host = results.host()[1]
        # the moments' rays: (|d| clamped, its square) stacked, built in place (no concatenation)
        dd = np.empty((2 * P, N), np.float32)
        np.abs(dist_host.reshape(P, N), out=dd[:P])
        np.minimum(dd[:P], np.float32(volume.max_distance), out=dd[:P])
        np.multiply(dd[:P], dd[:P], out=dd[P:])
        mom = dd @ Wd
        return TexelEstimate(mi.Float(mom.ravel()), cnt_d, ok_d, Wd.shape[1] * P, 2, per_texel=True)


# -- scatter path (any plan, any backend) ------------------------------------------

def int_power_dr(c, p: float):
    """Dr.Jit ``c ** p`` (``c >= 0``); integer powers by repeated squaring."""
    if p == 1.0:
        return c
    if p != int(p) or p < 1 or p > 1024:
        return dr.power(c, p)
    n, out, sq = int(p), None, c
    while n:
        if n & 1:
            out = sq if out is None else out * sq
        n >>= 1
        if n:
            sq = sq * sq
    return out


@functools.lru_cache(maxsize=None)
def _texel_directions_dr(texels: int):
    return mi.Float(_texel_directions_table(texels, True).ravel())


def fixed_point_sum(values, weight, entry, n: int, active):
    """Deterministic sums per entry: ``(sum w * x_c for each channel, sum w, count)``.

    ``values`` a list of Float channels, ``weight`` Float, ``entry`` UInt32 target
    per lane. Terms are rounded to ``FIXED_POINT_BITS`` fractional bits and added
    as UInt64 (associative: the same bits whatever the order of the atomics).
    Returns (list of Float64 sums, Float64 weight sum, UInt32 counts).

    ``ReduceMode.Local``: on the LLVM backend ``Auto`` picks ``Expand`` for targets of up to
    ``dr.expand_threshold()`` entries, which bakes ``n`` into the kernel as a literal; ``n`` follows the
    probes a frame traces (ragged plans, budgets), so that would compile new kernels on steady frames.
    """
    active = active & (weight > 0.0)

    def fixed(x):   # NaN -> 0 (clip keeps a NaN, and its integer conversion is undefined)
        return mi.UInt64(dr.round(dr.select(x > 0.0, dr.minimum(x, MAX_TERM), 0.0) * FIXED_SCALE))

    sw = dr.zeros(mi.UInt64, n)
    dr.scatter_reduce(dr.ReduceOp.Add, sw, fixed(weight), entry, active, mode=LOCAL)
    sums = []
    for v in values:
        s = dr.zeros(mi.UInt64, n)
        dr.scatter_reduce(dr.ReduceOp.Add, s, fixed(weight * v), entry, active, mode=LOCAL)
        sums.append(s)
    cnt = dr.zeros(mi.UInt32, n)
    dr.scatter_reduce(dr.ReduceOp.Add, cnt, mi.UInt32(1), entry, active, mode=LOCAL)
    inv = 1.0 / FIXED_SCALE
    return [mi.Float64(s) * inv for s in sums], mi.Float64(sw) * inv, cnt


class ScatterEstimator:
    """Kernel or binned estimate of any plan with ``dr.scatter_reduce`` (see the module docstring).

    Parameters
    ----------
    distance_power : float = 50   cosine power of the distance kernel
    mode : str = 'auto'           'kernel' (DDGI weights), 'bin' (one texel per ray), 'auto': 'bin'
                                  when the plan names a texel per ray, else 'kernel'
    """

    name = "scatter"

    def __init__(self, distance_power: float = 50.0, mode: str = "auto"):
        if mode not in SCATTER_MODES:
            raise unknown_choice("scatter estimator mode", mode, SCATTER_MODES)
        self.distance_power = float(distance_power)
        self.mode = mode

    def _mode(self, plan) -> str:
        if self.mode == "auto":
            return "bin" if plan.texel is not None else "kernel"
        return self.mode

    def _estimate(self, volume, results: ProbeRayResults, texels: int, power: float, values, active):
        plan = results.plan
        P = len(plan.probe_ids)
        T2 = (texels - 2) ** 2
        n = P * T2
        R = plan.n_rays
        if self._mode(plan) == "bin":
            # -- one texel per ray --
            if plan.texel is not None:
                if plan.texel_res != texels:
                    raise DyngiError(f"the plan's texels are for {plan.texel_res}x{plan.texel_res} probes, "
                                     f"the atlas has {texels}x{texels}")
                t = plan.texel
            else:
                c = direction_to_texel_coords(plan.direction, texels)
                ix = dr.clip(mi.Int32(dr.floor(c.x)) - 1, 0, texels - 3)
                iy = dr.clip(mi.Int32(dr.floor(c.y)) - 1, 0, texels - 3)
                t = mi.UInt32(iy * (texels - 2) + ix)
            w = mi.Float(1.0) if plan.weight is None else plan.weight
            w = w + dr.zeros(mi.Float, R)
            entry = plan.slot * T2 + t
            sums, sw, cnt = fixed_point_sum(values, w, entry, n, active)
        else:
            # -- DDGI kernel: one lane per (ray, texel) pair --
            k = dr.arange(mi.UInt32, R * T2)
            r = k // T2
            t = k - r * T2
            d = dr.gather(mi.Vector3f, plan.direction, r)
            nt = dr.gather(mi.Vector3f, _texel_directions_dr(texels), t)
            c = dr.dot(d, nt)
            w = dr.select(c > _cosine_cut(power), int_power_dr(dr.maximum(c, 0.0), power), 0.0)
            if plan.weight is not None:
                w = w * dr.gather(mi.Float, plan.weight, r)
            entry = dr.gather(mi.UInt32, plan.slot, r) * T2 + t
            vals = [dr.gather(mi.Float, v, r) for v in values]
            sums, sw, cnt = fixed_point_sum(vals, w, entry, n, dr.gather(mi.Bool, active, r))
        ok = sw > 0.0
        inv = dr.select(ok, dr.rcp(sw), 0.0)
        means = [mi.Float(s * inv) for s in sums]
        flat = dr.empty(mi.Float, len(values) * n)
        for ci, m in enumerate(means):
            dr.scatter(flat, m, dr.arange(mi.UInt32, n) + dr.opaque(mi.UInt32, ci * n))
        est = TexelEstimate(flat, cnt, ok, n, len(values), per_texel=False, weight=mi.Float(sw))
        dr.eval(est.value, est.count, est.ok, est.weight)
        return est

    def irradiance(self, volume, results: ProbeRayResults) -> TexelEstimate:
        L = results.radiance
        front = results.distance >= 0.0          # back-face hits stay out of the irradiance
        return self._estimate(volume, results, volume.irradiance_texels, 1.0, [L.x, L.y, L.z], front)

    def distance(self, volume, results: ProbeRayResults) -> TexelEstimate:
        d = dr.minimum(dr.abs(results.distance), dr.opaque(mi.Float, volume.max_distance))
        return self._estimate(volume, results, volume.distance_texels, self.distance_power, [d, d * d],
                              d >= 0.0)    # every ray (|d| >= 0): back faces count here
