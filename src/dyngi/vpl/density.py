"""k-nearest-neighbour surface density of VPLs (Hedman et al. 2017, Sec. 3.2.4).

``p(y) ~ k / (I pi r_k(y)^2)`` (Eq. 7): an unconstrained 3D search whose k
nearest neighbours are assumed to lie on the same plane as ``y`` (photon-mapping
assumption). Eq. 8's k for rendering (:func:`knn_k`, two readings); k = 1 for candidates (against the
current VPLs). Two implementations of one search:
:func:`knn_density` on the host (``scipy.spatial.cKDTree``; a few thousand points: ~1 ms, the CPU
fast path of the host-side selection steps) and :class:`KNNGrid` / :func:`knn_density_device` on the
device (a uniform grid built with Dr.Jit ops, no host round trip), exact alike (tested against a brute
force).
"""
from __future__ import annotations

import math

import numpy as np

from ..backend import dr, mi

MIN_RADIUS = 1e-6
"""Floor of r_k (scene units) so that coincident points do not give an infinite density (our choice)."""


EQ8_READINGS = ("text", "root-of-ratio")
"""The two readings of Eq. 8 (Sec. 3.2.4): ``'text'``, k = max(1, floor(sqrt(I) / 32)) as printed (1 at both
of the paper's budgets, 2048 and 512); ``'root-of-ratio'``, k = max(1, floor(sqrt(I / 32))) (8 and 4)."""


def knn_k(n: int, reading: str = "text") -> int:
    """Eq. 8's k of the rendering density for I = ``n`` VPLs under ``reading`` (:data:`EQ8_READINGS`):
    ``'text'`` max(1, floor(sqrt(I) / 32)) -- 1 for both 2048 and 512 VPLs; ``'root-of-ratio'``
    max(1, floor(sqrt(I / 32))) -- 8 and 4. Both grow as sqrt(I) (k -> inf, k / I -> 0: consistent)."""
    n = max(int(n), 0)
    if reading == "text":
        return max(1, int(math.floor(math.sqrt(n) / 32.0)))
    if reading == "root-of-ratio":
        return max(1, int(math.floor(math.sqrt(n / 32.0))))
    raise ValueError(f"Eq. 8 reading '{reading}' is invalid; valid: {', '.join(EQ8_READINGS)}")


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
    from scipy.spatial import cKDTree   # not a dyngi module: loaded on first use (0.4 s off every CLI start)

    tree = cKDTree(pts)
    d, _ = tree.query(q, k=kk)
    r = (d if d.ndim == 1 else d[:, -1])
    r = np.maximum(r, MIN_RADIUS)
    return k / (max(n, 1) * math.pi * r * r)


# -- device k-NN: a uniform grid built with Dr.Jit ops (issue 29) ---------------------------------------

CELLS_MAX = 1 << 22
"""Cells of the device grid at most (4 n, capped: 4M counters, 16 MB)."""
POINTS_PER_CELL = 8
"""G = sqrt(n / 8): points on surfaces occupy ~ a few G^2 cells (a box's walls ~ 6 G^2), a few points
each (our choice: the search is exact for any G, only its speed depends on it)."""


class KNNGrid:
    """k-nearest-neighbour search on the device over a point set (Dr.Jit has no k-NN; Eq. 7's r_k).

    Build (no host round trip): a cubic grid of G^3 cells over the valid points' bounding box
    (``G = clip(sqrt(n / POINTS_PER_CELL), 2, GRID_MAX)`` from the static width n: VPLs lie on surfaces; cell size from the
    box on the device), one cell id per point (invalid points go to an extra cell that no query
    visits), ``dr.argsort`` by cell, per-cell counts (``dr.scatter_reduce``) and their exclusive prefix
    sum. Query: one symbolic loop per query lane visits the cells of growing Chebyshev rings around the
    query's cell and keeps the k smallest squared distances in a sorted local buffer (an unrolled insertion); after ring R
    every point closer than R h is seen, so the search stops once the k-th distance is <= R h (or the
    rings cover the grid). Exact (the brute-force test: tests/vpl/test_knn_device.py).
    """

    def __init__(self, points, valid=None):
        self.n = n = dr.width(points)
        self.C = C = int(min(CELLS_MAX, max(64, 4 * n)))      # static cell budget
        ok = mi.Bool(True) if valid is None else mi.Bool(valid)
        big = 3.0e38
        lo = mi.Point3f(*(dr.min(dr.select(ok, points[i], big)) for i in range(3)))
        hi = mi.Point3f(*(dr.max(dr.select(ok, points[i], -big)) for i in range(3)))
        ext = dr.maximum(mi.Vector3f(hi - lo), 1e-9)
        # cell size: points on the walls of the box (area ~ 2 (ab + bc + ca)), POINTS_PER_CELL each; if
        # that grid exceeds the budget C, cells of max(ext) / (floor(cbrt C) - 1) (every axis fits)
        area = 2.0 * (ext.x * ext.y + ext.y * ext.z + ext.z * ext.x)
        h = dr.maximum(dr.sqrt(area * POINTS_PER_CELL / max(n, 1)), dr.max(ext) * 1e-6)
        dims = mi.Vector3f(dr.floor(ext / h) + 1.0)
        fits = dims.x * dims.y * dims.z < C
        h = dr.select(fits, h, dr.max(ext) * 1.0001 / (int(math.floor(C ** (1.0 / 3.0) + 1e-9)) - 1))
        self.dims = mi.Vector3i(dr.floor(ext / h) + 1.0)
        self.h = h
        self.lo = lo
        c = self._coords(points)
        cid = dr.select(ok, mi.UInt32(c[0] + self.dims.x * (c[1] + self.dims.y * c[2])), C)
        order = dr.argsort(cid)
        counts = dr.zeros(mi.UInt32, C + 1)
        dr.scatter_reduce(dr.ReduceOp.Add, counts, mi.UInt32(1), cid)
        self.start = dr.prefix_sum(counts)
        self.count = counts
        self.idx = order
        self.pts = dr.gather(mi.Point3f, points, order)
        dr.eval(self.start, self.count, self.idx, self.pts, self.h, self.lo, self.dims)

    def _coords(self, p):
        g = mi.Vector3f(p - self.lo) / self.h
        return [mi.Int32(dr.clip(mi.Int32(dr.floor(g[i])), 0, self.dims[i] - 1)) for i in range(3)]

    def kth_distance(self, queries, k: int, self_index=None):
        """Distance to the k-th nearest point (inf when fewer than k), per query; ``self_index``: each
        query's own index in the point set, excluded (a point's neighbours among the others)."""
        k = int(k)
        if k < 1:
            raise ValueError("k >= 1")
        excl = mi.UInt32(0xFFFFFFFF) if self_index is None else mi.UInt32(self_index)
        c = self._coords(queries)
        d2 = _knn_loop(mi.Point3f(queries), c[0], c[1], c[2], excl, self.pts, self.idx, self.start,
                       self.count, self.h, self.dims, k)
        return dr.sqrt(d2)


@__import__("drjit").syntax
def _knn_loop(q, cx, cy, cz, excl, pts, idx, start, count, h, dims, k: int):
    """The ring search of :meth:`KNNGrid.kth_distance`; returns the k-th smallest squared distance."""
    inf = mi.Float(float("inf"))
    buf = dr.alloc_local(mi.Float, k, inf)
    R = mi.Int32(0)
    ci = mi.Int32(0)
    pj = mi.UInt32(0)
    pend = mi.UInt32(0)
    active = dr.full(mi.Bool, True, dr.width(q))
    while active:
        if pj < pend:
            # -- one point of the current cell: insert its squared distance into the sorted buffer --
            p = dr.gather(mi.Point3f, pts, pj)
            d2 = dr.squared_norm(p - q)
            own = dr.gather(mi.UInt32, idx, pj) == excl
            v = dr.select(own, inf, d2)
            for i in range(k):           # static: carry the larger value forward (k min/max pairs)
                b = buf[i]
                buf[i] = dr.minimum(b, v)
                v = dr.maximum(b, v)
            pj += 1
        else:
            # -- next cell of ring R (cube (2R+1)^3, its interior skipped); a finished ring may stop --
            w = 2 * R + 1
            if ci >= w * w * w:
                rh = mi.Float(R) * h
                if (buf[k - 1] <= rh * rh) | (R >= dr.max(dims)):
                    active = mi.Bool(False)
                R += 1
                ci = mi.Int32(0)
            w = 2 * R + 1
            dx = ci % w - R
            dy = (ci // w) % w - R
            dz = ci // (w * w) - R
            ci += 1
            ring = dr.maximum(dr.maximum(dr.abs(dx), dr.abs(dy)), dr.abs(dz)) == R
            x, y, z = cx + dx, cy + dy, cz + dz
            inside = ring & (x >= 0) & (x < dims.x) & (y >= 0) & (y < dims.y) & (z >= 0) & (z < dims.z) & active
            cell = mi.UInt32(dr.select(inside, x + dims.x * (y + dims.y * z), 0))
            s = dr.gather(mi.UInt32, start, cell, inside)
            pj = s
            pend = s + dr.select(inside, dr.gather(mi.UInt32, count, cell, inside), 0)
    return buf[k - 1]


def knn_density_device(points, queries=None, k: int = 1, n_total=None, valid=None, grid: KNNGrid | None = None):
    """Eq. 7 on the device: ``k / (I pi r_k^2)`` at ``queries`` (None: at the points themselves, each
    excluding itself) among the valid ``points``; ``n_total`` (I) defaults to the number of valid
    points (a device value: no host read). 0 where fewer than k neighbours exist. Returns a Float."""
    g = grid or KNNGrid(points, valid)
    if queries is None:
        # the points in the grid's cell order (neighbouring lanes search neighbouring cells: a SIMD
        # packet's lanes need similar numbers of rings; our choice), results scattered back
        r = dr.empty(mi.Float, g.n)
        dr.scatter(r, g.kth_distance(g.pts, k, g.idx), g.idx)
    else:
        r = g.kth_distance(queries, k)
    if n_total is None:
        n_total = g.n if valid is None else dr.count(mi.Bool(valid))
    r = dr.maximum(r, MIN_RADIUS)
    dens = mi.Float(k) / (dr.maximum(mi.Float(n_total), 1.0) * dr.pi * r * r)
    return dr.select(dr.isfinite(r), dens, 0.0)
