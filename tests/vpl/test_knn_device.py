"""The device k-NN (:class:`dyngi.vpl.density.KNNGrid`) against a brute-force search."""
from __future__ import annotations

import numpy as np
import pytest


def _points(rng, n):
    """Points on three planes (VPLs lie on surfaces) plus a few scattered ones."""
    p = rng.random((n, 3)).astype(np.float32)
    p[: n // 3, 2] = 0.25
    p[n // 3: 2 * n // 3, 0] = 0.8
    p[2 * n // 3: 2 * n // 3 + 20] *= 3.0          # outliers: rings far beyond the first
    return p


def _brute_kth(points, queries, k, exclude_self):
    d2 = ((queries[:, None, :].astype(np.float64) - points[None, :, :]) ** 2).sum(-1)
    if exclude_self:
        np.fill_diagonal(d2, np.inf)
    d2.sort(axis=1)
    return np.sqrt(d2[:, k - 1]) if d2.shape[1] >= k else np.full(len(queries), np.inf)


@pytest.mark.parametrize("k", [1, 4, 16])
def test_device_knn_matches_brute_force(backend, k):
    from dyngi.backend import dr, mi
    from dyngi.vpl.density import KNNGrid, knn_density, knn_density_device
    from dyngi.vpl.points import to_point

    rng = np.random.default_rng(7 + k)
    pts = _points(rng, 1500)
    q = rng.random((400, 3)).astype(np.float32) * 1.2 - 0.1
    grid = KNNGrid(to_point(pts))
    got_self = np.asarray(grid.kth_distance(to_point(pts), k, dr.arange(mi.UInt32, len(pts))))
    got_q = np.asarray(grid.kth_distance(to_point(q), k))
    np.testing.assert_allclose(got_self, _brute_kth(pts, pts, k, True), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(got_q, _brute_kth(pts, q, k, False), rtol=1e-5, atol=1e-6)
    # Eq. 7 on the device equals the host's (cKDTree) density
    np.testing.assert_allclose(np.asarray(knn_density_device(to_point(pts), k=k)), knn_density(pts, k=k),
                               rtol=1e-4)


def test_device_knn_skips_invalid_points(backend):
    """Invalid points are not neighbours; fewer than k valid others give density 0 (as the host's)."""
    from dyngi.backend import mi
    from dyngi.vpl.density import knn_density, knn_density_device
    from dyngi.vpl.points import to_point

    rng = np.random.default_rng(3)
    pts = _points(rng, 600)
    valid = rng.random(600) < 0.5
    got = np.asarray(knn_density_device(to_point(pts), to_point(pts), k=3, valid=mi.Bool(valid)))
    want = knn_density(pts[valid], pts, k=3)
    np.testing.assert_allclose(got, want, rtol=1e-4)
    few = np.zeros(600, bool)
    few[:2] = True
    assert np.all(np.asarray(knn_density_device(to_point(pts), k=3, valid=mi.Bool(few))) == 0.0)
