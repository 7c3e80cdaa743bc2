"""k-nearest-neighbour surface density of VPLs (Hedman et al. 2017, Sec. 3.2.4).

``p(y) ~ k / (I pi r_k(y)^2)`` (Eq. 7): an unconstrained 3D search whose k
nearest neighbours are assumed to lie on the same plane as ``y`` (photon-mapping
assumption). ``k = max(1, floor(sqrt(I) / 32))`` (Eq. 8) for rendering; k = 1
for candidates (against the current VPLs). Host side, ``scipy.spatial.cKDTree``
(a few thousand points: ~1 ms).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

MIN_RADIUS = 1e-6
"""Floor of r_k (scene units) so that coincident points do not give an infinite density (our choice)."""


def knn_k(n: int) -> int:
    """k = max(1, floor(sqrt(I) / 32)) (Eq. 8): 1 for both 2048 and 512 VPLs."""
    return max(1, int(math.floor(math.sqrt(max(int(n), 0)) / 32.0)))


def knn_density(points: np.ndarray, queries: np.ndarray | None = None, k: int | None = None,
                n_total: int | None = None) -> np.ndarray:
    """Density per unit area (Eq. 7) at ``queries`` of the point set ``points``.

    ``queries=None``: at the points themselves, each excluding itself (the k-th
    neighbour among the *others*). ``k`` defaults to Eq. 8 of ``len(points)``;
    ``n_total`` (the I of Eq. 7) defaults to ``len(points)``. With fewer than k
    other points, r_k is infinite and the density 0.
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    n = len(pts) if n_total is None else int(n_total)
    k = knn_k(len(pts)) if k is None else int(k)
    self_query = queries is None
    q = pts if self_query else np.asarray(queries, np.float64).reshape(-1, 3)
    if len(q) == 0:
        return np.zeros(0)
    kk = k + 1 if self_query else k
    if len(pts) < kk:
        return np.zeros(len(q))
    tree = cKDTree(pts)
    d, _ = tree.query(q, k=kk)
    r = (d if d.ndim == 1 else d[:, -1])
    r = np.maximum(r, MIN_RADIUS)
    return k / (max(n, 1) * math.pi * r * r)
