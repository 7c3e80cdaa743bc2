"""Host-side selection steps of SMC instant radiosity (Hedman et al. 2017, Algorithm 1, Sec. 3.2).

Small NumPy functions over a few thousand VPLs and candidates; every random
choice takes a ``numpy.random.Generator`` seeded from (seed, frame, stream). They serve
``smcir:impl=host`` (the CPU fast path); the default ``impl='device'`` runs their twins in
:mod:`dyngi.vpl.smc_device`. :func:`resample_with_replacement_device` is MIR's device resampling.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi


def m_min(current_intensity: np.ndarray, candidate_intensity: np.ndarray, m_max: int,
          quantile: float = 0.95) -> int:
    """Eq. 9: ``M_min = min(M_max, M_strong)``, ``M_strong`` = the number of candidates whose intensity
    exceeds that of 95% of the current VPLs (strictly above their ``quantile``; linear interpolation)."""
    cur = np.asarray(current_intensity, np.float64)
    cand = np.asarray(candidate_intensity, np.float64)
    if len(cur) == 0:
        return min(int(m_max), len(cand))
    q = np.quantile(cur, quantile)
    return int(min(int(m_max), int(np.sum(cand > q))))


def resample_without_replacement(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``n`` elements drawn with probability proportional to ``weights`` without replacement.

    Exact weighted sampling without replacement by Efraimidis-Spirakis keys ``log(u) / w``, the n largest
    (our choice: the paper draws in parallel with atomics and up to 8 retries, Sec. 3.2.1, which
    approximates the same). Zero weights are drawn last; infinite ones first.
    """
    w = np.asarray(weights, np.float64)
    n = int(min(n, len(w)))
    if n <= 0:
        return np.zeros(0, np.int64)
    u = rng.random(len(w))
    with np.errstate(divide="ignore", invalid="ignore"):
        keys = np.where(w > 0, np.log(np.maximum(u, 1e-300)) / w, -np.inf)
    keys = np.where(np.isinf(w) & (w > 0), 0.0, keys)
    idx = np.argpartition(-keys, n - 1)[:n] if n < len(w) else np.arange(len(w))
    return idx[np.argsort(-keys[idx], kind="stable")]


def grow_invalid(invalid: np.ndarray, used: np.ndarray, intensity: np.ndarray, m_min_: int) -> np.ndarray:
    """Algorithm 1 lines 10-12: add the lowest-intensity valid VPLs to INVALID until |INVALID| >= M_min."""
    invalid = invalid.copy()
    need = int(m_min_) - int(invalid.sum())
    if need > 0:
        cand = np.flatnonzero(used & ~invalid)
        order = cand[np.argsort(intensity[cand], kind="stable")]
        invalid[order[:need]] = True
    return invalid


def clamp_size(invalid: np.ndarray, intensity: np.ndarray, m_max: int) -> np.ndarray:
    """Line 13's CLAMPSIZE(INVALID, M_max): at most ``m_max`` slots, the lowest intensities first (our
    choice of which; the paper does not say)."""
    idx = np.flatnonzero(invalid)
    return idx[np.argsort(intensity[idx], kind="stable")][: int(m_max)]


# -- device resampling (issue 29) ----------------------------------------------------------------------

def resample_with_replacement_device(weights, u):
    """Indices drawn with replacement with probability ``w_i / sum(w)``, one per uniform ``u`` (a Dr.Jit
    Float of the wanted count): the inclusive prefix sum of ``weights`` on the device and a binary
    search for the first entry above ``u * sum`` (inverse-CDF sampling; no host round trip). MIR's
    importance resampling (Segovia et al. 2007, as Hedman et al. run it, Sec. 5.1). Zero weights are
    never drawn; all-zero weights give index 0 (the caller masks them by the total)."""
    w = dr.maximum(mi.Float(weights), 0.0)
    n = dr.width(w)
    cdf = dr.prefix_sum(w) + w                    # inclusive
    total = dr.sum(w)
    target = mi.Float(u) * total
    idx = dr.binary_search(0, n - 1, lambda i: dr.gather(mi.Float, cdf, i) <= target)
    return mi.UInt32(dr.minimum(idx, n - 1))
