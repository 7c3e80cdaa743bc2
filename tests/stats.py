"""Statistical helpers shared by the tests (z-tests against a reference, chi^2)."""
from __future__ import annotations

import numpy as np
from scipy import stats as sst


def luminance(img: np.ndarray) -> np.ndarray:
    return 0.2126 * img[..., 0] + 0.7152 * img[..., 1] + 0.0722 * img[..., 2]


def per_pixel_moments(images: np.ndarray):
    """images: K x H x W x 3 independent estimates -> (mean, variance of the mean) per pixel, per channel."""
    k = images.shape[0]
    mean = images.mean(0)
    var = images.var(0, ddof=1) / k
    return mean, var


def two_sample_z(a_images: np.ndarray, b_images: np.ndarray, floor: float = 1e-12):
    """Per-pixel, per-channel z scores of mean(a) - mean(b) with estimated variances."""
    ma, va = per_pixel_moments(a_images)
    mb, vb = per_pixel_moments(b_images)
    den = np.sqrt(va + vb)
    z = np.where(den > floor, (ma - mb) / np.maximum(den, floor), 0.0)
    # exactly equal deterministic pixels (both zero variance) count as agreement when equal
    z = np.where((den <= floor) & (np.abs(ma - mb) > 1e-6), np.inf, z)
    return z


def z_test_images(a_images: np.ndarray, b_images: np.ndarray, alpha: float = 0.01):
    """Do two stacks of K independent renders (K x H x W x 3) estimate the same image?

    Three tests on luminance, each at level ``alpha``:
    1. per pixel, a two-sample t-test (Welch statistic, t with 2K-2 dof), Sidak
       corrected over all pixels (catches a few badly wrong pixels);
    2. the count of pixels rejected at ``alpha`` uncorrected is consistent with
       Binomial(n, alpha) (catches a small bias spread over many pixels);
    3. a Welch t-test on the per-image mean luminance (catches a global bias).
    Returns (ok, info dict).
    """
    a, b = luminance(a_images), luminance(b_images)
    k = min(a.shape[0], b.shape[0])
    z = two_sample_z(a, b)
    p = 2.0 * sst.t.sf(np.abs(z), df=max(2 * k - 2, 1))
    n = p.size
    thr = 1.0 - (1.0 - alpha) ** (1.0 / n)
    n_rej = int(np.sum(p < alpha))
    max_rej = int(sst.binom.ppf(1.0 - alpha, n, alpha))
    ma, mb = a.reshape(a.shape[0], -1).mean(1), b.reshape(b.shape[0], -1).mean(1)
    p_mean = float(sst.ttest_ind(ma, mb, equal_var=False).pvalue)
    info = {"min_p": float(p.min()), "sidak_threshold": thr, "rejected": n_rej, "max_rejected": max_rej,
            "p_mean": p_mean, "rel_mean_diff": float(abs(ma.mean() - mb.mean()) / max(mb.mean(), 1e-12))}
    ok = p.min() >= thr and n_rej <= max_rej and p_mean >= alpha
    return bool(ok), info


def chi2_uniform(counts: np.ndarray, expected: np.ndarray, alpha: float = 0.01, min_expected: float = 5.0):
    """Pearson chi^2 test with low-expectation cells pooled; returns (ok, p-value)."""
    counts = np.asarray(counts, np.float64).ravel()
    expected = np.asarray(expected, np.float64).ravel()
    low = expected < min_expected
    if low.any():
        counts = np.append(counts[~low], counts[low].sum())
        expected = np.append(expected[~low], expected[low].sum())
    stat = np.sum((counts - expected) ** 2 / np.maximum(expected, 1e-300))
    p = float(sst.chi2.sf(stat, df=len(counts) - 1))
    return p >= alpha, p
