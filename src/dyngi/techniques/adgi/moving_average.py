"""ADGI's count-based moving average, exactly as Algorithm 3 (Datta et al. 2022, Sec. 4.7), with a batch rule.

Algorithm 3, per sample ``v`` into a texel holding value ``o`` and count ``n``::

    V = v / (n + 1) + n o / (n + 1)        N = min(n + 1, N_max)

so sample ``k`` (1-based) gets weight ``1/k`` while ``k <= N_max + 1``: the texel
holds the exact mean of its first ``N_max + 1`` samples, then an exponential
moving average with new-sample weight ``1 / (N_max + 1)`` (hysteresis
``N_max / (N_max + 1)``).

N_max: **63** for the static caches and **10** for the dynamic ones (Table 3:
hysteresis 0.98 ~ 63/64 and 0.91 ~ 10/11, both ``N_max / (N_max + 1)``). The
paper wavers between 63 and 64 (Algorithm 4 calls ``MovingAvgUpdate(x, v,
64)``); we take 63 because it is what a 6-bit count field can hold and what
Table 3's hysteresis gives -- Algorithm 4's 64 would store a count of 64 in
6 bits.

Batch rule (ours, the issue's): when ``m`` samples ``v_j`` hit one texel in
one frame they are merged at once, deterministically (no atomics, no order)::

    V = (n o + sum_j v_j) / (n + m)        N = min(n + m, N_max)

It equals ``m`` sequential Algorithm-3 updates exactly while ``n + m <=
N_max + 1`` (the count does not saturate within the batch). Once it does, it
differs: the batch gives the ``m`` new samples the weight ``m / (n + m)`` in
total and equal shares, while sequential updates would give later samples more
weight (``1 / (N_max + 1)`` each, compounding) -- e.g. ``n = 63, m = 64``:
batch 0.504, sequential ``1 - (63/64)^64 = 0.635``.

:class:`Algorithm3Accumulator` is the same rule behind the temporal
accumulator interface of :mod:`dyngi.probes.accumulator` (``new`` is the
frame's mean of ``m`` samples, so ``sum v = m * new``), usable with
:func:`dyngi.probes.accumulator.merge_into_volume`.
Note: :class:`dyngi.probes.accumulator.CappedMeanAccumulator` is not
Algorithm 3: it gives sample ``k`` the weight ``1 / min(k, cap)`` (the mean of
the first ``cap`` samples, then weight ``1/cap``), one sample off Algorithm 3.
"""
from __future__ import annotations

from ...backend import dr, mi
from ...errors import DyngiError

N_MAX_STATIC = 63
N_MAX_DYNAMIC = 10


def moving_average_update(o, n, v, n_max: int):
    """Algorithm 3 (one sample): returns ``(V, N)``; works on Python floats and Dr.Jit arrays alike."""
    V = v / (n + 1) + n * o / (n + 1)
    N = dr.minimum(n + 1, n_max) if not isinstance(n, int) else min(n + 1, n_max)
    return V, N


def batch_update(o, n, sum_v, m, n_max: int):
    """The batch rule: ``(V, N)`` after ``m`` samples summing to ``sum_v`` (``m = 0`` keeps ``o, n``)."""
    nf, mf = mi.Float(n), mi.Float(m)
    den = nf + mf
    V = dr.select(den > 0.0, (nf * o + sum_v) / dr.maximum(den, 1.0), o)
    return V, dr.minimum(mi.UInt32(n) + mi.UInt32(m), n_max)


class Algorithm3Accumulator:
    """Temporal accumulator (``irradiance`` / ``distance`` as in :mod:`dyngi.probes.accumulator`) applying
    the batch rule of Algorithm 3 with count cap ``min(n_max, the encoding's cap)``.

    n_max : int = 63   N_max (10 for ADGI's dynamic caches)
    """

    name = "algorithm-3"

    def __init__(self, n_max: int = N_MAX_STATIC):
        if int(n_max) < 1:
            raise DyngiError(f"moving-average N_max must be >= 1, got {n_max}")
        self.n_max = int(n_max)

    def _blend(self, old, new, n_old, m, fresh, cap: int):
        cap = min(int(cap), self.n_max)
        n0 = dr.select(fresh, 0, dr.minimum(n_old, cap))
        mf = mi.Float(m)
        nf = mi.Float(n0)
        den = nf + mf
        val = dr.select(den > 0.0, (nf * old + mf * new) / dr.maximum(den, 1.0), old)
        return val, dr.minimum(n0 + m, cap)

    irradiance = _blend
    distance = _blend
