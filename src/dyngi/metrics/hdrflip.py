"""HDR-FLIP (Andersson et al. 2021, "Visualizing Errors in Rendered High
Dynamic Range Images", Eurographics short paper) through the ``flip-evaluator``
package, NVIDIA's reference implementation.

HDR-FLIP tone-maps both images at a range of exposures (ACES by default),
computes LDR-FLIP (Andersson et al. 2020, HPG) at each exposure and keeps the
per-pixel maximum; the exposure range [start, stop] comes from the
*reference*: start = log2(x_max / Y_max), stop = log2(x_max / Y_median).

``flip_evaluator.evaluate`` exits the process (``sys.exit`` or C++
``exit``) on bad arguments, including a black reference (start > stop), so
this wrapper validates first (H x W x 3, equal shapes, finite, >= 0) and
handles the degenerate cases itself:

* identical images: FLIP is 0 (no call);
* a dark reference (max luminance < ``DARK_REFERENCE``): both images are
  scaled by one common factor so the brighter has max luminance 1. With the
  automatic exposure range HDR-FLIP is invariant to such a common scale
  (start and stop shift together), so this changes nothing but avoids the
  exit;
* a reference still (near-)black after that: the exposure range is taken
  from the test image instead (FLIP's own automatic choice for it).
"""
from __future__ import annotations

import numbers
import os

import numpy as np

from ..errors import DyngiError
from .checks import as_pair, luminance

DARK_REFERENCE = 1e-3
"""Reference max luminance below which images are rescaled (see module docstring)."""

def _import_flip():
    """``flip_evaluator`` with its OpenMP threads sleeping, not spinning, while they wait.

    The package ships its own libgomp, which reads ``OMP_WAIT_POLICY`` once,
    when it loads. Its default (spin, then sleep) stalls each call for
    ~0.2 s when the cores are busy (Dr.Jit's thread pool, other jobs):
    measured 820 ms -> 20 ms per 32 x 24 call on the 2-core box under load
    (benchmarks/harness.py). A value the user set is kept.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import flip_evaluator

    return flip_evaluator


def _evaluate(ref32, test32, params):
    flip_evaluator = _import_flip()

    errmap, mean, _ = flip_evaluator.evaluate(ref32, test32, "HDR", applyMagma=False,
                                              computeMeanError=True, parameters=params)
    return float(mean), np.asarray(errmap, dtype=np.float32).reshape(ref32.shape[:2])


def _auto_exposure(img32, params):
    """The exposure range HDR-FLIP picks automatically for ``img32`` used as reference."""
    flip_evaluator = _import_flip()

    _, _, used = flip_evaluator.evaluate(img32, img32, "HDR", applyMagma=False,
                                         computeMeanError=False, parameters=dict(params))
    return {"startExposure": float(used["startExposure"]), "stopExposure": float(used["stopExposure"])}


def flip(img, ref, return_map: bool = False, ppd: float | None = None):
    """Mean HDR-FLIP error of ``img`` against ``ref`` (linear RGB, >= 0), in [0, 1].

    Returns a float, or ``(mean, error_map)`` with the H x W float32 FLIP map
    when ``return_map`` is true. ``ppd`` is the viewing condition in pixels
    per degree; None keeps FLIP's default (about 67: a 0.7 m wide 4K
    monitor seen from 0.7 m).
    """
    a, b = as_pair(img, ref, nonnegative=True)
    if ppd is not None and not (isinstance(ppd, numbers.Real) and np.isfinite(ppd) and ppd > 0):
        raise DyngiError(f"flip ppd (pixels per degree) must be a positive number, got {ppd!r}")
    h, w = b.shape[:2]
    if np.array_equal(a, b):
        return (0.0, np.zeros((h, w), np.float32)) if return_map else 0.0
    params = {} if ppd is None else {"ppd": float(ppd)}
    y_ref, y_img = float(luminance(b).max()), float(luminance(a).max())
    if y_ref < DARK_REFERENCE:
        # common rescale: HDR-FLIP with automatic exposures is scale invariant
        s = 1.0 / max(y_ref, y_img)   # > 0: the images differ and are >= 0
        a, b = a * s, b * s
        if y_ref * s < DARK_REFERENCE:
            params.update(_auto_exposure(np.ascontiguousarray(a, np.float32), params))
    mean, errmap = _evaluate(np.ascontiguousarray(b, np.float32), np.ascontiguousarray(a, np.float32), params)
    if return_map:
        return mean, errmap
    return mean
