"""Time to equal error: how long a progressive technique needs to reach a target error.

DDGI Resampling's Table 1 ("time to converge to equal MAPE") reports, per
technique, the frames and milliseconds needed to reach about the same MAPE.
:func:`time_to_error` computes that from a measured convergence curve.
"""
from __future__ import annotations

import numpy as np

from ..errors import DyngiError


def time_to_error(times, errors, target: float) -> float:
    """Wall time at which the error curve first reaches ``target`` (``error <= target``).

    ``times``: cumulative wall time of each sample (non-decreasing, e.g. the
    time after frame i of a progressive render); ``errors``: the error at
    those times (any metric, lower is better). Between the last sample above
    the target and the first one at or below it, the crossing time is
    interpolated linearly. Returns ``times[0]`` if the first sample already
    meets the target and ``inf`` if no sample does. The first crossing
    counts, even if noise later lifts the error above the target again.
    """
    t = np.asarray(times, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    if t.ndim != 1 or e.ndim != 1 or t.size != e.size:
        raise DyngiError(f"time_to_error needs two 1-D sequences of equal length, got shapes {t.shape} and {e.shape}")
    if t.size == 0:
        raise DyngiError("time_to_error needs at least one (time, error) sample")
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) >= 0)):
        raise DyngiError("time_to_error: times must be finite and non-decreasing")
    if np.any(np.isnan(e)):
        raise DyngiError("time_to_error: errors contain NaN")
    target = float(target)
    if not np.isfinite(target):
        raise DyngiError(f"time_to_error: target must be finite, got {target}")
    hit = np.nonzero(e <= target)[0]
    if hit.size == 0:
        return float("inf")
    i = int(hit[0])
    if i == 0:
        return float(t[0])
    e0, e1, t0, t1 = e[i - 1], e[i], t[i - 1], t[i]
    if not np.isfinite(e0):       # the error before was infinite: no interpolation possible
        return float(t1)
    f = (e0 - target) / (e0 - e1)  # e0 > target >= e1, so 0 < f <= 1
    return float(t0 + f * (t1 - t0))
