"""Per-image error metrics against a reference: MSE, relMSE, MAPE, SSIM.

All functions take ``(img, ref)``: H x W x 3 *linear* float images of equal
shape (numpy arrays; validated by :mod:`dyngi.metrics.checks`) and return a
Python float. Averages run over pixels *and* colour channels, so a metric of
an image with the same error in every channel equals that error.

Definitions
-----------
mse     mean (img - ref)^2.
relmse  mean (img - ref)^2 / (ref^2 + eps), eps = 1e-2 (per pixel and channel).
mape    mean |img - ref| / (ref + 0.01)  (DDGI Resampling, Sec. 4).
ssim    mean SSIM of Wang et al. 2004 (Eq. 13) per channel, Gaussian window
        sigma = 1.5, on Reinhard tone-mapped values (see :func:`ssim`).
"""
from __future__ import annotations

import numpy as np

from ..errors import DyngiError
from .checks import as_pair

RELMSE_EPS = 1e-2
"""Denominator offset of :func:`relmse` (in units of squared radiance)."""

MAPE_EPS = 0.01
"""The epsilon of the MAPE definition in DDGI Resampling (Sec. 4)."""


def mse(img, ref) -> float:
    """Mean squared error ``mean((img - ref)^2)`` over pixels and channels."""
    a, b = as_pair(img, ref)
    return float(np.mean((a - b) ** 2))


def relmse(img, ref, eps: float = RELMSE_EPS) -> float:
    """Relative MSE ``mean((img - ref)^2 / (ref^2 + eps))`` over pixels and channels.

    Convention: the per-pixel, per-channel form used in the Monte Carlo
    denoising and adaptive-sampling literature (e.g. Rousselle et al. 2011,
    Bako et al. 2017): the squared error is divided by the squared
    *reference* value, so the metric is scale-aware (an error of 0.1 on a
    pixel of value 10 counts as much as 0.001 on a pixel of value 0.1) and
    independent of any tone mapping. ``eps`` (default 1e-2, i.e. a "noise
    floor" of radiance 0.1) keeps near-black reference pixels from
    dominating: for ref << 0.1 the term tends to (img - ref)^2 / eps.
    Per-channel rather than luminance so that colour shifts count.
    """
    if not (eps > 0 and np.isfinite(eps)):
        raise DyngiError(f"relmse eps must be a positive finite number, got {eps}")
    a, b = as_pair(img, ref)
    return float(np.mean((a - b) ** 2 / (b * b + eps)))


def mape(img, ref) -> float:
    """Mean absolute percentage error exactly as DDGI Resampling (Sec. 4) defines it.

    ``MAPE = 1/N sum_i |v_i - vref_i| / (vref_i + eps)`` with ``eps = 0.01``
    ("prevents near-black pixels from dominating the metric"). The paper does
    not say how colour channels enter; here each channel of each pixel is one
    value ``v_i``, so N = H * W * 3. It is a fraction, not a percentage (the
    paper's Table 1 reports e.g. 0.573). The reference must be non-negative.
    """
    a, b = as_pair(img, ref, ref_nonnegative=True)
    return float(np.mean(np.abs(a - b) / (b + MAPE_EPS)))


def reinhard(x, exposure: float = 1.0) -> np.ndarray:
    """Reinhard et al. 2002 global operator with a fixed key: ``k x / (1 + k x)``, k = exposure.

    Reinhard's Eq. 3 scales by ``a / Lw_avg`` (key over log-average
    luminance); here that scale is an explicit, fixed ``exposure`` so that an
    estimate and its reference (and all frames of a sequence) go through the
    same curve. Applied element-wise: to luminance or to each channel.
    """
    x = np.asarray(x, dtype=np.float64) * float(exposure)
    return x / (1.0 + x)


# SSIM constants of Wang et al. 2004, Sec. III-C
SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_SIGMA = 1.5
SSIM_RADIUS = 5          # 11 x 11 window


def ssim(img, ref, exposure: float = 1.0, sigma: float = SSIM_SIGMA, return_map: bool = False):
    """Mean structural similarity (Wang, Bovik, Sheikh, Simoncelli 2004).

    SSIM(x, y) = (2 mu_x mu_y + C1)(2 sigma_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(sigma_x^2 + sigma_y^2 + C2))
    (Eq. 13) with C1 = (K1 L)^2, C2 = (K2 L)^2, K1 = 0.01, K2 = 0.03. Local
    means, variances and covariance use a circular Gaussian window, sigma =
    1.5, 11 x 11 (radius 5), as in Sec. III-C; the mean over the image is
    their MSSIM (Eq. 17).

    HDR handling (our choice): each channel is first tone-mapped by
    :func:`reinhard` with ``exposure`` so that values lie in [0, 1) and the
    dynamic range is L = 1. Borders use reflected padding (``scipy.ndimage``
    'reflect') instead of Wang's valid-region crop, so tiny test images work.
    The result is the mean over pixels and the three channels; 1 means
    identical. Both images must be non-negative.

    Returns a float, or ``(float, map)`` with the H x W SSIM map (channel
    mean) when ``return_map`` is true.
    """
    from scipy.ndimage import gaussian_filter

    a, b = as_pair(img, ref, nonnegative=True)
    x, y = reinhard(a, exposure), reinhard(b, exposure)
    c1, c2 = (SSIM_K1 * 1.0) ** 2, (SSIM_K2 * 1.0) ** 2
    truncate = SSIM_RADIUS / sigma

    def blur(v):
        return gaussian_filter(v, sigma=(sigma, sigma, 0), mode="reflect", truncate=truncate)

    mx, my = blur(x), blur(y)
    sxx = blur(x * x) - mx * mx
    syy = blur(y * y) - my * my
    sxy = blur(x * y) - mx * my
    smap = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    value = float(np.mean(smap))
    if return_map:
        return value, smap.mean(axis=2).astype(np.float32)
    return value
