"""Input validation shared by every metric.

Metrics take H x W x 3 linear float images (numpy arrays or anything
``np.asarray`` accepts). Bad input raises :class:`~dyngi.errors.DyngiError`
with one line; this matters most for FLIP, whose Python wrapper calls
``sys.exit`` on bad arguments instead of raising.
"""
from __future__ import annotations

import numpy as np

from ..color import luminance  # noqa: F401  (dyngi.metrics.luminance: the one luminance, dyngi.color)
from ..errors import DyngiError


def as_image(x, what: str = "image", nonnegative: bool = False) -> np.ndarray:
    """Return ``x`` as a float64 H x W x 3 array, or raise DyngiError naming the problem."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise DyngiError(f"{what} is not a numeric array (got {type(x).__name__})") from None
    if a.ndim != 3 or a.shape[2] != 3:
        raise DyngiError(f"{what} must be an H x W x 3 array, got shape {a.shape}")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise DyngiError(f"{what} is empty (shape {a.shape})")
    if not np.all(np.isfinite(a)):
        n = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
        raise DyngiError(f"{what} has {n} NaN/Inf values")
    if nonnegative and np.any(a < 0):
        raise DyngiError(f"{what} has negative values (min {a.min():.3g}); radiance must be >= 0")
    return a


def as_pair(img, ref, nonnegative: bool = False, ref_nonnegative: bool = False):
    """Validate an (image, reference) pair: both H x W x 3, equal shapes, finite.

    ``nonnegative`` requires both to be >= 0; ``ref_nonnegative`` only the reference.
    """
    a = as_image(img, "image", nonnegative)
    b = as_image(ref, "reference", nonnegative or ref_nonnegative)
    if a.shape != b.shape:
        raise DyngiError(f"image shape {a.shape} differs from reference shape {b.shape}")
    return a, b


