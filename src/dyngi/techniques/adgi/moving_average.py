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

Batch rule (ours; Algorithm 4 applies Algorithm 3 once per sample with a compare-and-swap loop, in
whatever order the GPU's threads arrive): when ``m`` samples ``v_j`` hit one texel in one frame they are
merged at once, deterministically (no atomics, no order), as ``m`` sequential Algorithm-3 updates by
samples equal to their mean ``vbar = sum_j v_j / m``::

    V = r o + (1 - r) vbar        N = min(n + m, N_max)

with ``r`` the weight the old value keeps after those ``m`` updates (:func:`retention`): while the count
is below ``N_max`` each update keeps ``c / (c + 1)`` (the product telescopes to ``n / (n + j)`` over the
first ``j = min(m, N_max - n)`` updates), afterwards ``N_max / (N_max + 1)`` each; a stored count above
this ``N_max`` (a static count of 63 met by a dynamic update with ``N_max`` = 10) keeps ``n / (n + 1)``
on the first update and ``N_max / (N_max + 1)`` on the others::

    n < N_max:   r = n / (n + j) * (N_max / (N_max + 1))^(m - j)
    n >= N_max:  r = n / (n + 1) * (N_max / (N_max + 1))^(m - 1)

So the batch equals Algorithm 3 exactly whenever the ``m`` samples are equal, and whenever the count does
not saturate within the batch (then ``r = n / (n + m)``: the exact running mean, whatever the samples);
with unequal samples and a saturating count it gives them equal shares of the weight ``1 - r`` that
sequential updates would give them in total (sequential updates weigh later samples more, by an order the
GPU does not fix either). An earlier rule of ours, ``V = (n o + sum v) / (n + m)`` throughout, kept the
running-mean weights past saturation: at ``n = 63, m = 64`` it gave the new samples 0.504 where Algorithm
3 gives ``1 - (63/64)^64 = 0.635``, and a dynamic batch (``N_max`` = 10) over a static count of 63 only
``m / (63 + m)`` where Algorithm 3 gives ``1 - 63/64 (10/11)^(m-1)`` -- it made the dynamic stage's
updates (Sec. 4.9) several times slower than the paper's (docs/techniques/adgi.md).

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


def retention(n, m, n_max):
    """Weight the old value keeps after ``m`` Algorithm-3 updates from count ``n`` (module docstring; Float,
    1 where ``m = 0``, 0 where ``n = 0 < m``). ``n``, ``m``: UInt32 (Dr.Jit); ``n_max``: a Python int or a
    UInt32 per lane."""
    n, m = mi.UInt32(n), mi.UInt32(m)
    N = mi.UInt32(n_max) if not isinstance(n_max, int) else mi.UInt32(int(n_max))
    Nf = mi.Float(N)
    nf, mf = mi.Float(n), mi.Float(m)
    below = n < N
    j = dr.select(below, dr.minimum(m, N - dr.minimum(n, N)), dr.minimum(m, 1))
    jf = mi.Float(j)
    rest = dr.power(Nf / (Nf + 1.0), mf - jf)
    r = dr.select(jf > 0.0, nf / dr.maximum(nf + jf, 1.0), 1.0) * rest
    return dr.select(m > 0, r, 1.0)


def batch_update(o, n, sum_v, m, n_max: int):
    """The batch rule (module docstring): ``(V, N)`` after ``m`` samples summing to ``sum_v`` (``m = 0``
    keeps ``o, n``); equals ``m`` sequential :func:`moving_average_update` calls by equal samples.
    ``n_max``: a Python int or a UInt32 per lane."""
    mf = mi.Float(m)
    r = retention(n, m, n_max)
    vbar = sum_v / dr.maximum(mf, 1.0)
    V = dr.select(mf > 0.0, r * o + (1.0 - r) * vbar, o)
    N = int(n_max) if isinstance(n_max, int) else mi.UInt32(n_max)
    return V, dr.select(mi.UInt32(m) > 0, dr.minimum(mi.UInt32(n) + mi.UInt32(m), N), mi.UInt32(n))


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
        n0 = dr.select(fresh, 0, mi.UInt32(n_old))
        r = retention(n0, m, cap)
        val = dr.select(mi.UInt32(m) > 0, r * old + (1.0 - r) * new, old)
        return val, dr.select(mi.UInt32(m) > 0, dr.minimum(n0 + mi.UInt32(m), cap), dr.minimum(n0, cap))

    irradiance = _blend
    distance = _blend
