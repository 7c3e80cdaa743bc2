"""IS-DDGI's allocation pdf, importance draws and change measure as Dr.Jit kernels (Liu et al., I3D 2023,
supplement Secs. 4.3-4.4; issue 26).

The device twins of :func:`~.sets.allocation_pdf`, :func:`~.sets.sample_indices` and
:meth:`~.planner.ISDDGIPlanner.ray_change`, on device arrays only (no host round trip inside); the per-set
cap and the ray layout are :mod:`.device_planner`'s:

* :func:`allocation_pdf_dr`: ``p(i, j) = F_i / sum F * p_f(j | i)``, ``p_f(j | i) = (1 - eps) f_ij /
  sum_j f_ij + eps / 256`` (uniform where a probe has no ``f``) over the *candidates* (probes with
  ``F_i > 0``: the pdf is 0 elsewhere), one lane per (candidate, set); per-probe sums by ``dr.block_sum``.
* :func:`sample_pairs_dr`: ``n`` i.i.d. draws by inverse CDF: the inclusive prefix sum of the pdf
  (``dr.cumsum``) and, per draw, a binary search (a fixed number of steps) for the first entry whose
  cumulative sum exceeds ``u * total``; ``u`` from a hash of (draw index, seed) with the seed opaque,
  so every frame runs the same kernels. A zero-pdf entry is never drawn (its cumulative sum equals its
  predecessor's). Float32 sums (ours): the relative rounding of the CDF is ~1e-7 x sqrt(entries), far
  below the chi-squared resolution of the tests.
* :func:`change_measure_dr`: the paired-visit change measure of :meth:`~.planner.ISDDGIPlanner.ray_change`
  (the normalised luminance / distance difference of a check visit against its set's stored sample,
  soft-thresholded) and the per-probe balance-heuristic estimate ``F^_i = 256 x`` the check visits' mean
  ``g`` (Sec. 4.3, as :meth:`~.planner.ISDDGIPlanner.observe`), one lane per ray, per-probe sums by
  ``dr.scatter_reduce``; the stored samples are device arrays indexed ``probe * 256 + j``.

The default planner (:class:`~.device_planner.DeviceISDDGIPlanner`) builds each frame's plan and state
update from these kernels; the host planner (:class:`~.planner.ISDDGIPlanner`, ``impl='host'``) keeps the
NumPy twins.
"""
from __future__ import annotations

from ...backend import dr, mi
from .sets import LUMINANCE_FLOOR, N_SETS, PROBE_MEAN_SHARE, _hash_u32_dr

DRAW_STREAM = 0x15DD66          # hash stream of the device draws' uniform numbers (ours)
_LOCAL = dr.ReduceMode.Local    # per-slot sums: Auto picks "expand" for small targets, whose kernel
                                # holds the target's width as a literal (a recompile when it changes)


def allocation_pdf_dr(F, f, eps: float):
    """(S * 256,) Float allocation pdf of ``S`` candidates from ``F`` (S,) Float and ``f`` (S * 256,)
    Float (row ``i`` = candidate ``i``'s sets); all zero if ``sum F == 0``."""
    S = dr.width(F)
    Fc = dr.maximum(F, 0.0)
    fc = dr.maximum(f, 0.0)
    tot = dr.gather(mi.Float, dr.sum(Fc), mi.UInt32(0))
    sf = dr.block_sum(fc, N_SETS)                          # (S,) per-candidate sum of f
    k = dr.arange(mi.UInt32, S * N_SETS)
    slot = k // N_SETS
    s = dr.gather(mi.Float, sf, slot)
    base = dr.select(s > 0.0, fc / dr.select(s > 0.0, s, 1.0), 1.0 / N_SETS)
    e = dr.opaque(mi.Float, eps)
    cond = (1.0 - e) * base + e * (1.0 / N_SETS)
    pdf = dr.select(tot > 0.0, dr.gather(mi.Float, Fc, slot) / dr.select(tot > 0.0, tot, 1.0) * cond, 0.0)
    dr.eval(pdf)
    return pdf


def uniform_numbers_dr(n: int, seed: int):
    """(n,) Float in [0, 1): 24 bits of a hash of (index, seed); ``seed`` is opaque (no recompiles)."""
    i = dr.arange(mi.UInt32, n)
    s = dr.opaque(mi.UInt32, int(seed) & 0xFFFFFFFF)
    h = _hash_u32_dr(_hash_u32_dr(i ^ s) + s + DRAW_STREAM)
    return mi.Float(h >> 8) * (1.0 / 16777216.0)


def sample_pairs_dr(pdf, n: int, seed: int, max_size: int | None = None):
    """(n,) UInt32 flat indices (``candidate * 256 + j``) of ``n`` i.i.d. draws from ``pdf`` (any
    non-negative Float, normalised here): prefix sum + binary search. Empty if ``n == 0`` or the pdf is 0.

    The search runs ``ceil(log2(max_size))`` steps (default: the pdf's width) with the width opaque, so
    pdfs of any width up to ``max_size`` share one kernel (the planner's traced-probe count varies per frame)."""
    size = dr.width(pdf)
    if n <= 0 or size == 0:
        return mi.UInt32()
    cdf = dr.cumsum(pdf)                                  # inclusive prefix sum
    dr.eval(cdf)
    last = dr.opaque(mi.UInt32, size - 1)
    total = dr.gather(mi.Float, cdf, last)
    u = uniform_numbers_dr(n, seed) * total
    steps = max(int(max(size, max_size or 0) - 1).bit_length(), 1)
    lo, hi = mi.UInt32(0), mi.UInt32(last)
    for _ in range(steps):            # first k with cdf[k] > u (fixed step count: no literal of the width)
        go = lo < hi
        mid = (lo + hi) >> 1
        right = dr.gather(mi.Float, cdf, mid, go) <= u
        lo = dr.select(go & right, mid + 1, lo)
        hi = dr.select(go & ~right, mid, hi)
    idx = dr.select(total > 0.0, lo, 0)
    dr.eval(idx)
    return mi.UInt32(idx)


def change_measure_dr(lum, dist, slot, pair, paired, check, sample_lum, sample_dist, has_sample, n_slots: int,
                      max_distance: float, tau: float):
    """Per ray ``g`` (Float, 0 where not a measured check visit) and per slot ``(F^, n_measured)`` (Float).

    ``lum``, ``dist`` (R,) Float: hit luminance and signed distance; ``slot`` (R,) UInt32: the ray's probe
    slot; ``pair`` (R,) UInt32: ``probe * 256 + j`` (the volume's probe index) into ``sample_lum``,
    ``sample_dist`` (Float) and ``has_sample`` (Bool); ``paired``, ``check`` (R,) Bool (see
    :class:`~.planner.ISDDGIPlanInfo`)."""
    ones = dr.full(mi.Float, 1.0, dr.width(lum))
    lum_sum = dr.zeros(mi.Float, n_slots)
    cnt = dr.zeros(mi.Float, n_slots)
    dr.scatter_reduce(dr.ReduceOp.Add, lum_sum, lum, slot, mode=_LOCAL)
    dr.scatter_reduce(dr.ReduceOp.Add, cnt, ones, slot, mode=_LOCAL)
    ybar = dr.gather(mi.Float, lum_sum, slot) / dr.maximum(dr.gather(mi.Float, cnt, slot), 1.0)
    dmax = dr.opaque(mi.Float, max_distance)
    y_old = dr.gather(mi.Float, sample_lum, pair, paired)
    d_old = dr.gather(mi.Float, sample_dist, pair, paired)
    measured = paired & check & dr.gather(mi.Bool, has_sample, pair, paired)
    c_l = dr.abs(lum - y_old) / (lum + y_old + PROBE_MEAN_SHARE * ybar + LUMINANCE_FLOOR)
    c_d = dr.abs(dr.minimum(dr.abs(dist), dmax) - d_old) / dmax
    t = dr.opaque(mi.Float, tau)
    g = dr.maximum(dr.maximum(c_l, c_d) - t, 0.0) / dr.maximum(1.0 - t, 1e-6)
    g = dr.select(measured, g, 0.0)
    g_sum = dr.zeros(mi.Float, n_slots)
    n_meas = dr.zeros(mi.Float, n_slots)
    dr.scatter_reduce(dr.ReduceOp.Add, g_sum, g, slot, mode=_LOCAL)
    dr.scatter_reduce(dr.ReduceOp.Add, n_meas, dr.select(measured, 1.0, 0.0), slot, mode=_LOCAL)
    F_est = dr.select(n_meas > 0.0, N_SETS * g_sum / dr.maximum(n_meas, 1.0), 0.0)
    dr.eval(g, F_est, n_meas)
    return g, F_est, n_meas
