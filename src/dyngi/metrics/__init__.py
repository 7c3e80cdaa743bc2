"""Image and sequence error metrics against a reference.

Every metric is a small pure function on H x W x 3 *linear* float images
(numpy), validated first (bad input raises :class:`~dyngi.errors.DyngiError`):

=========  ==================================================================
mse        mean squared error
relmse     mean (img - ref)^2 / (ref^2 + 1e-2), per pixel and channel
mape       mean |img - ref| / (ref + 0.01) -- DDGI Resampling, Sec. 4
flip       mean HDR-FLIP (Andersson et al. 2021) via ``flip-evaluator``
ssim       mean SSIM (Wang et al. 2004), Gaussian window, tone-mapped channels
=========  ==================================================================

Sequence metrics: :func:`temporal_errors` (|E| and |E'| of SMC Instant
Radiosity, Sec. 5.2) and :func:`time_to_error` (time to equal error, DDGI
Resampling Table 1). :data:`METRICS` maps names to the per-image functions;
:func:`compute_all` evaluates several at once. For all metrics lower is
better, except SSIM (1 = identical); :data:`HIGHER_IS_BETTER` lists those.
"""
from __future__ import annotations

from ..errors import unknown_choice
from .checks import as_image, as_pair, luminance
from .convergence import time_to_error
from .hdrflip import flip
from .image import MAPE_EPS, RELMSE_EPS, mape, mse, reinhard, relmse, ssim
from .temporal import TemporalTracker, auto_exposure, pick_pixels, temporal_errors

METRICS = {
    "mse": mse,
    "relmse": relmse,
    "mape": mape,
    "flip": flip,
    "ssim": ssim,
}
"""Per-image metrics by name: ``f(img, ref) -> float``."""

HIGHER_IS_BETTER = frozenset({"ssim"})


def compute_all(img, ref, names=None) -> dict:
    """``{name: metric(img, ref)}`` for ``names`` (default: every metric in :data:`METRICS`).

    Unknown names raise DyngiError listing the valid ones. The pair is
    validated once up front, so a bad image fails before any metric runs.
    """
    if names is None:
        names = list(METRICS)
    elif isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    for n in names:
        if n not in METRICS:
            raise unknown_choice("metric", n, METRICS)
    a, b = as_pair(img, ref)
    return {n: METRICS[n](a, b) for n in names}


__all__ = ["METRICS", "HIGHER_IS_BETTER", "compute_all", "mse", "relmse", "mape", "flip", "ssim",
           "reinhard", "luminance", "as_image", "as_pair", "temporal_errors", "TemporalTracker",
           "pick_pixels", "auto_exposure", "time_to_error", "RELMSE_EPS", "MAPE_EPS"]
