"""IS-DDGI's allocation pdf and importance draws as Dr.Jit kernels (Liu et al., I3D 2023,
supplement Secs. 4.3-4.4; issue 26).

The device twins of :func:`~.sets.allocation_pdf` and :func:`~.sets.sample_indices`, on device arrays only (no
host round trip inside); the per-set cap, the ray layout and the change measure are :mod:`.device_planner`'s:

* :func:`allocation_pdf_dr`: ``p(i, j) = F_i / sum F * p_f(j | i)``, ``p_f(j | i) = (1 - eps) f_ij /
  sum_j f_ij + eps / 256`` (uniform where a probe has no ``f``) over the *candidates* (probes with
  ``F_i > 0``: the pdf is 0 elsewhere), one lane per (candidate, set); per-probe sums by ``dr.block_sum``.
* :func:`sample_pairs_dr`: ``n`` i.i.d. draws by inverse CDF: the inclusive prefix sum of the pdf
  (``dr.cumsum``) and, per draw, a binary search (a fixed number of steps) for the first entry whose
  cumulative sum exceeds ``u * total``; ``u`` from a hash of (draw index, seed) with the seed opaque,
  so every frame runs the same kernels. A zero-pdf entry is never drawn (its cumulative sum equals its
  predecessor's). Float32 sums (ours): the relative rounding of the CDF is ~1e-7 x sqrt(entries), far
  below the chi-squared resolution of the tests.

The default planner (:class:`~.device_planner.DeviceISDDGIPlanner`) builds each frame's plan and state
update with these kernels; the host planner (:class:`~.planner.ISDDGIPlanner`, ``impl='host'``) keeps the
NumPy twins.
"""
from __future__ import annotations

from ...backend import dr, mi
from .sets import N_SETS, _hash_u32_dr

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
