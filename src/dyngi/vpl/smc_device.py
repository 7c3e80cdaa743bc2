"""SMC instant radiosity's per-iteration steps on the device (Hedman et al. 2017, Algorithm 1, Sec. 3.2).

The device twins of :mod:`dyngi.vpl.smc` and :func:`dyngi.vpl.points.segment_clear` /
:func:`~dyngi.vpl.points.camera_sees` (the radiosity estimate's own,
:func:`dyngi.vpl.radiosity.estimate_radiosity_device`, lives with its host form): Dr.Jit arrays
in, Dr.Jit arrays out, fixed widths (the VPL budget I, its candidates, I * V validation rays), counts
kept as width-1 device arrays. :class:`DeviceVPLStore` holds the VPL set between iterations, so that an
iteration of ``smcir`` reads nothing back to the host (issue 29); :meth:`DeviceVPLStore.to_host` is the
inspection copy (tests), never called in a frame.

Selections without a host round trip (our choices; the paper draws in parallel with atomics, Sec. 3.2.1):

* weighted sampling without replacement: Efraimidis-Spirakis keys ``log(u) / w`` and a device radix
  sort (``dr.argsort``, stable), the n largest -- exactly the distribution of
  :func:`dyngi.vpl.smc.resample_without_replacement`;
* "the lowest intensities first" (lines 10-13) and "the highest candidate intensities" (lines 14-16):
  ranks from a stable ascending / descending ``dr.argsort`` scattered back to their slots;
* Eq. 9's 95% quantile: the used intensities sorted (unused ones last), NumPy's linear interpolation
  between the two order statistics around ``q (n - 1)``;
* uniform choices among masked elements (a random invalid VPL, a random visible point x): the inverse
  CDF of the mask (:func:`dyngi.vpl.smc.resample_with_replacement_device`).
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..rays import occluded
from .points import RAY_EPS
from .store import VPLStore

_GOLDEN = 0x9E3779B97F4A7C15


def stream_seeds_device(seeds, stream: int):
    """:func:`dyngi.vpl.radiosity.stream_seeds` on a Dr.Jit UInt64 (bit-identical: splitmix64 finaliser of
    ``seed + stream * golden``, 62 bits)."""
    s = mi.UInt64(seeds)
    if int(stream) == 0:
        return s
    x = s + mi.UInt64((int(stream) * _GOLDEN) & ((1 << 64) - 1))
    x = (x ^ (x >> 30)) * mi.UInt64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> 27)) * mi.UInt64(0x94D049BB133111EB)
    x = x ^ (x >> 31)
    return x >> 2


def _segment_clear(mscene, A, na, B, nb, ok):
    d = B - A
    dist = dr.norm(d)
    wdir = d / dr.maximum(dist, 1e-12)
    ok = ok & (dist > 0.0)
    if na is not None:
        ok &= dr.dot(mi.Vector3f(na), wdir) > 0.0
    if nb is not None:
        ok &= dr.dot(mi.Vector3f(nb), wdir) < 0.0
    eps = dr.opaque(mi.Float, RAY_EPS) * (1.0 + dr.maximum(dr.max(dr.abs(A)), dr.max(dr.abs(B))))
    ray = mi.Ray3f(A + wdir * eps, wdir)
    ray.maxt = dr.maximum(dist - 2.0 * eps, 0.0)
    return ok & ~occluded(mscene, ray, ok, stage="visibility")


def segment_clear_device(mscene, a, na, b, nb, active):
    """:func:`dyngi.vpl.points.segment_clear` on the device: per lane, is a -> b unoccluded in ``mscene``,
    with dot(na, b - a) > 0 and dot(nb, a - b) > 0 (a normal of None is not checked)? A Bool."""
    return _segment_clear(mscene, mi.Point3f(a), na, mi.Point3f(b), nb, mi.Bool(active))


def camera_sees_device(mscene, camera, res, pts, nrm, active):
    """:func:`dyngi.vpl.points.camera_sees` on the device: in the view frustum (the camera model of
    :meth:`~dyngi.scene.camera.Camera.sample_rays`, its parameters opaque: a moving camera compiles
    nothing), unoccluded from the camera and facing it. A Bool."""
    left, up, d = camera.frame()
    w, h = res
    tanx = float(np.tan(np.radians(camera.fov) * 0.5))
    tany = tanx / (w / h)

    def op3(cls, v):
        return dr.opaque(cls, [float(c) for c in v])

    O = op3(mi.Point3f, np.asarray(camera.origin, np.float64))
    Lx, Uy, D = op3(mi.Vector3f, left / tanx), op3(mi.Vector3f, up / tany), op3(mi.Vector3f, d)
    p = mi.Point3f(pts)
    v = p - O
    z = dr.dot(v, D)
    zs = dr.select(z > 0.0, z, 1.0)
    px = 0.5 * (1.0 - dr.dot(v, Lx) / zs)
    py = 0.5 * (1.0 - dr.dot(v, Uy) / zs)
    inside = mi.Bool(active) & (z > 0.0) & (px >= 0.0) & (px < 1.0) & (py >= 0.0) & (py < 1.0)
    return _segment_clear(mscene, O + 0.0 * p, None, p, nrm, inside)


def sample_without_replacement_device(weights, u, n: int):
    """Indices (UInt32, width ``n``) of ``n`` elements drawn with probability proportional to ``weights``
    without replacement (Efraimidis-Spirakis keys ``log(u) / w``, the n largest by a stable device sort;
    infinite weights first, zero weights last -- as :func:`dyngi.vpl.smc.resample_without_replacement`)
    and whether each drawn element has a positive weight (a Bool)."""
    w = mi.Float(weights)
    u = mi.Float(u)
    # (a select, not dr.maximum: LLVM cannot select IEEE fmaximum on a scalar tail of some widths)
    keys = dr.select(w > 0.0, dr.log(dr.select(u > 1e-30, u, 1e-30)) / w, -dr.inf)
    keys = dr.select(dr.isinf(w) & (w > 0.0), 0.0, keys)
    order = dr.argsort(keys, descending=True)
    sel = dr.gather(mi.UInt32, order, dr.arange(mi.UInt32, int(n)))
    return sel, dr.gather(mi.Float, w, sel) > 0.0


def ranks(keys, descending: bool = False):
    """Rank of each element in a stable sort of ``keys`` (UInt32, 0 = first)."""
    order = dr.argsort(mi.Float(keys), descending=descending)
    r = dr.zeros(mi.UInt32, dr.width(order))
    dr.scatter(r, dr.arange(mi.UInt32, dr.width(order)), order)
    return r


def quantile_device(values, mask, q: float):
    """``numpy.quantile(values[mask], q)`` (linear interpolation) as a width-1 Float; 0 if the mask is
    empty."""
    vals = mi.Float(values)
    m = mi.Bool(mask)
    s = dr.gather(mi.Float, vals, dr.argsort(dr.select(m, vals, dr.inf)))
    cnt = dr.count(m)
    # selects, not dr.minimum/maximum: a width-1 float min/max is a scalar LLVM fminimum/fmaximum, which
    # LLVM cannot select on x86 when the result is evaluated on its own
    pos = dr.select(cnt > 1, float(q) * (mi.Float(cnt) - 1.0), 0.0)
    lo = mi.UInt32(dr.floor(pos))
    hi = dr.select(lo + 1 < cnt, lo + 1, lo)
    a, b = dr.gather(mi.Float, s, lo), dr.gather(mi.Float, s, hi)
    return dr.select(cnt > 0, a + (b - a) * (pos - mi.Float(lo)), 0.0)


FIELDS3 = ("pos", "nrm", "albedo", "radiosity", "sel_radiosity", "mailbox", "mailbox_n")


class DeviceVPLStore:
    """The VPL store of :class:`dyngi.vpl.store.VPLStore` as Dr.Jit arrays of ``capacity`` lanes (the same
    fields; ``seed`` a UInt64, ``used`` a Bool)."""

    def __init__(self, capacity: int):
        c = self.capacity = int(capacity)
        for k in FIELDS3:
            cls = mi.Point3f if k in ("pos", "mailbox") else (mi.Vector3f if k in ("nrm", "mailbox_n")
                                                                 else mi.Color3f)
            setattr(self, k, dr.zeros(cls, c))
        self.density = dr.full(mi.Float, 1.0, c)
        self.seed = dr.zeros(mi.UInt64, c)
        self.used = dr.full(mi.Bool, False, c)

    def arrays(self):
        return [getattr(self, k) for k in FIELDS3 + ("density", "seed", "used")]

    def eval(self):
        dr.eval(*self.arrays())

    def to_host(self) -> VPLStore:
        """A host copy (reads back: for tests and inspection only)."""
        def h3(v):
            return np.stack([np.asarray(v[i], np.float32) for i in range(3)], axis=1)

        st = VPLStore(self.capacity)
        for k in FIELDS3:
            setattr(st, k, h3(getattr(self, k)))
        st.density = np.asarray(self.density, np.float64)
        st.seed = np.asarray(self.seed, np.uint64)
        st.used = np.asarray(self.used, bool)
        return st
