"""Points that VPL techniques trace: camera-visible points, candidate hits, photon paths, visibility.

All per-ray work is one Dr.Jit kernel per call. The ``*_device`` functions keep their results as
Dr.Jit arrays over every lane (``smcir``'s default device path, ``mir``, ``tcas``); the others bring
the valid lanes back to the host as NumPy arrays (``smcir:impl=host``'s selection works on them).

* :func:`raw_candidates` -- Algorithm 1 lines 3 and 5 (Sec. 3.2.1): camera rays
  through random pixel positions find directly visible points ``x``; one
  cosine-distributed ray from each finds ``y``. A hit counts when both ``x`` and
  ``y`` are front-facing (:func:`dyngi.scene.surface.shading_side`) diffuse
  surfaces (diffuse albedo > 0): VPLs live on diffuse surfaces only (Sec. 3.1).
* :func:`segment_clear` -- two-sided visibility between point pairs (shadow ray,
  both cosines > 0): the mailbox test of Sec. 3.2.2.
* :func:`camera_sees` -- a point lies in the view frustum and the camera ray to it is unoccluded.
* :func:`trace_photons` -- Keller's instant radiosity (1997): photons from the
  lights (``scene.sample_emitter_ray``: area, point, spot, directional, environment;
  or a light sampler, :mod:`dyngi.vpl.emission`), a VPL at each diffuse bounce; the
  photon set is drawn per ``frame`` key.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..rays import occluded
from ..scene.surface import diffuse_surface
from ..sampling.rng import make_sampler
from .emission import sample_photon_ray

RAY_EPS = 1e-4
"""Shadow-ray shortening at both ends, relative to 1 + max|p| (our choice; Mitsuba's own offset is ~1e-6)."""


MIN_LANES = 16
"""Per-point kernels run on at least this many lanes (padded): a width-1 Dr.Jit array is a scalar
broadcast, whose kernel differs from the vector one, so a frame with one invalid VPL compiled anew."""


def padded(a: np.ndarray | None, n: int | None = None):
    """``a`` (rows) padded with copies of its last row (or zeros) to ``max(len, MIN_LANES)`` rows."""
    if a is None:
        return None
    a = np.asarray(a)
    want = max(len(a), MIN_LANES) if n is None else n
    if len(a) >= want:
        return a
    fill = np.repeat(a[-1:], want - len(a), axis=0) if len(a) else np.zeros((want,) + a.shape[1:], a.dtype)
    return np.concatenate([a, fill])


def aligned(a: np.ndarray, dtype=np.float32) -> np.ndarray:
    """A 64-byte-aligned contiguous copy of ``a``: Dr.Jit maps NumPy memory as it is, and an unaligned
    array compiles a kernel of its own (``align 1`` loads), so per-frame host arrays recompiled."""
    a = np.asarray(a, dtype)
    item = np.dtype(dtype).itemsize
    buf = np.empty(a.size + 64 // item, dtype)
    off = (-buf.ctypes.data % 64) // item
    out = buf[off:off + a.size].reshape(a.shape)
    out[...] = a
    return out


def to_float(a: np.ndarray):
    return mi.Float(aligned(np.ravel(a)))


def _vec3(cls, a):
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return cls(*(mi.Float(aligned(a[:, i])) for i in range(3)))


def to_point(a: np.ndarray):
    return _vec3(mi.Point3f, a)


def to_vector(a: np.ndarray):
    return _vec3(mi.Vector3f, a)


def to_color(a: np.ndarray):
    return _vec3(mi.Color3f, a)


def to_numpy3(v) -> np.ndarray:
    return np.stack([np.asarray(v[i], np.float32) for i in range(3)], axis=1)


def _mscene(scene):
    return scene.mi_scene if hasattr(scene, "mi_scene") else scene


def raw_candidates_device(scene, camera, res, n: int, seed: int, frame: int, stream: int = 0x51C, *,
                          stage: str = "candidates"):
    """:func:`raw_candidates` on the device, every lane kept (no compaction, no host round trip): a dict
    of Dr.Jit arrays over the ``n`` camera rays -- ``pos``, ``nrm``, ``albedo`` (at y), ``mailbox``,
    ``mailbox_n``, ``mailbox_albedo`` (at x), ``ok`` (a valid candidate y) and ``okx`` (a valid x). Its rays
    are counted under ``stage`` (:mod:`dyngi.rays`)."""
    mscene = _mscene(scene)
    w, h = res
    sampler = make_sampler(n, seed, frame, stream)
    pix = mi.UInt32(dr.minimum(sampler.next_1d() * (w * h), w * h - 1))
    ray = camera.sample_rays(res, pix, sampler.next_2d())
    si, okx, nx, alb_x = diffuse_surface(mscene, ray, mi.Bool(True), stage=stage)
    frame_x = mi.Frame3f(nx)
    d = frame_x.to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
    ray2 = si.spawn_ray(d)
    si2, oky, ny, alb = diffuse_surface(mscene, ray2, okx, stage=stage)
    oky &= okx
    return {"pos": si2.p, "nrm": ny, "albedo": alb, "mailbox": si.p, "mailbox_n": nx, "mailbox_albedo": alb_x,
            "ok": oky, "okx": okx}


def raw_candidates(scene, camera, res, n: int, seed: int, frame: int, stream: int = 0x51C):
    """``n`` camera rays -> visible points x -> one cosine ray each -> hits y (Sec. 3.2.1).

    Returns (dict of NumPy arrays over the valid candidates: ``pos``, ``nrm``, ``albedo``,
    ``mailbox``, ``mailbox_n``, ``mailbox_albedo`` (the diffuse albedo at x); dict of the valid visible points ``x``/``n``; rays traced).
    The host form of :func:`raw_candidates_device` (the same random numbers and lanes).
    """
    c = raw_candidates_device(scene, camera, res, n, seed, frame, stream)
    dr.eval(c)
    return candidates_to_host(c, n)


def candidates_to_host(c: dict, n: int, extra: dict | None = None):
    """:func:`raw_candidates`' host result from :func:`raw_candidates_device`'s evaluated dict ``c``;
    ``extra``: more per-lane device Floats to carry into the candidate dict (e.g. a density)."""
    okx_n, oky_n = np.asarray(c["okx"], bool), np.asarray(c["ok"], bool)
    Xn, NXn = to_numpy3(c["mailbox"]), to_numpy3(c["mailbox_n"])
    cand = {"pos": to_numpy3(c["pos"])[oky_n], "nrm": to_numpy3(c["nrm"])[oky_n],
            "albedo": to_numpy3(c["albedo"])[oky_n], "mailbox": Xn[oky_n], "mailbox_n": NXn[oky_n],
            "mailbox_albedo": to_numpy3(c["mailbox_albedo"])[oky_n]}
    for k, v in (extra or {}).items():
        cand[k] = np.asarray(v, np.float64)[oky_n]
    pts = {"x": Xn[okx_n], "n": NXn[okx_n]}
    return cand, pts, n + int(okx_n.sum())


def segment_clear(scene, a: np.ndarray, na: np.ndarray | None, b: np.ndarray, nb: np.ndarray | None):
    """Per pair: is the segment a -> b unoccluded, with dot(na, b - a) > 0 and dot(nb, a - b) > 0
    (a normal of None is not checked)? Returns (bool array, rays traced)."""
    if len(a) == 0:
        return np.zeros(0, bool), 0
    mscene = _mscene(scene)
    n_in = len(a)
    a, na, b, nb = padded(a), padded(na), padded(b), padded(nb)
    A, B = to_point(a), to_point(b)
    d = B - A
    dist = dr.norm(d)
    wdir = d / dr.maximum(dist, 1e-12)
    ok = dist > 0.0
    if na is not None:
        ok &= dr.dot(to_vector(na), wdir) > 0.0
    if nb is not None:
        ok &= dr.dot(to_vector(nb), wdir) < 0.0
    eps = dr.opaque(mi.Float, RAY_EPS) * (1.0 + dr.maximum(dr.max(dr.abs(A)), dr.max(dr.abs(B))))
    ray = mi.Ray3f(A + wdir * eps, wdir)
    ray.maxt = dr.maximum(dist - 2.0 * eps, 0.0)   # (o, d, x): x would be the time
    ok &= ~occluded(mscene, ray, ok, stage="visibility")
    dr.eval(ok)
    okn = np.asarray(ok, bool)[:n_in]
    return okn, n_in


def in_frustum(camera, res, pts: np.ndarray) -> np.ndarray:
    """Host: does each point project inside the image (:meth:`Camera.project <dyngi.scene.camera.Camera.project>`)?"""
    x, y, z = camera.project(res, pts)
    with np.errstate(invalid="ignore"):
        px = 0.5 * (1.0 - x)
        py = 0.5 * (1.0 - y)
        return (z > 0) & (px >= 0) & (px < 1) & (py >= 0) & (py < 1)


def camera_sees(scene, camera, res, pts: np.ndarray, nrm: np.ndarray | None = None):
    """In the frustum and unoccluded from the camera (and facing it, given normals). (bool array, rays)."""
    inside = in_frustum(camera, res, pts)
    out = np.zeros(len(pts), bool)
    if inside.any():
        o = np.broadcast_to(np.asarray(camera.origin, np.float32), (int(inside.sum()), 3))
        ok, _ = segment_clear(scene, o, None, pts[inside], None if nrm is None else nrm[inside])
        out[inside] = ok
    return out, int(inside.sum())


class PointSetSampler:
    """``next_1d`` / ``next_2d`` over the columns of an (n, d) point set in [0, 1)^d, one column per
    dimension in order: a deterministic (QMC) point set as the sampler of a walk that otherwise draws from
    :func:`dyngi.sampling.rng.make_sampler`. The data are new arrays per call, not literals: a new point
    set compiles nothing. A walk that asks for more than d dimensions is an error."""

    def __init__(self, u: np.ndarray):
        self.u = np.asarray(u, np.float64)
        self.j = 0

    def _col(self):
        if self.j >= self.u.shape[1]:
            raise ValueError(f"the point set has {self.u.shape[1]} dimensions; the walk asked for more")
        c = mi.Float(aligned(np.minimum(self.u[:, self.j], np.nextafter(1.0, 0.0)), np.float32))
        self.j += 1
        return c

    def next_1d(self):
        return self._col()

    def next_2d(self):
        return mi.Point2f(self._col(), self._col())


def photon_dimensions(bounces: int) -> int:
    """Dimensions of one photon path of :func:`trace_photons`: emitter choice (1), position (2), direction
    (2), and a cosine direction (2) after each of the ``bounces`` hits."""
    return 5 + 2 * int(bounces)


HALTON_PRIMES = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53, 59, 61, 67, 71, 73, 79, 83, 89, 97)
"""Bases of the Halton dimensions (the first primes: 25 dimensions, photons of up to 10 bounces)."""


def radical_inverse(index: np.ndarray, base: int) -> np.ndarray:
    """Van der Corput's radical inverse of the integers ``index`` in ``base``: the digits mirrored about the
    radix point (one vectorised step per digit). float64 in [0, 1)."""
    i = np.asarray(index, np.uint64).copy()
    out = np.zeros(i.shape, np.float64)
    f = 1.0 / base
    b = np.uint64(base)
    while np.any(i > 0):
        out += (i % b).astype(np.float64) * f
        i //= b
        f /= base
    return out


def halton_photon_points(n_photons: int, bounces: int, start: int) -> np.ndarray:
    """Points ``start .. start + n_photons - 1`` of the (unscrambled) Halton sequence in
    :func:`photon_dimensions` dimensions (radical inverses in bases 2, 3, 5, ...), the deterministic
    low-discrepancy set of Keller's instant radiosity (1997: Halton points for the photons; that paper is not
    among papers/, Hedman et al. cite it as [3]); ``start >= 1`` skips the origin. A (n, d) float64 array."""
    d = photon_dimensions(bounces)
    if d > len(HALTON_PRIMES):
        raise ValueError(f"Halton photons support at most {len(HALTON_PRIMES)} dimensions; {d} asked")
    idx = np.arange(int(start), int(start) + int(n_photons), dtype=np.uint64)
    return np.stack([radical_inverse(idx, p) for p in HALTON_PRIMES[:d]], axis=1)


def sobol_photon_points(n_photons: int, bounces: int, seed: int) -> np.ndarray:
    """A scrambled Sobol' set of ``n_photons`` points in :func:`photon_dimensions` dimensions (SciPy's
    linear matrix scrambling + digital shift, keyed by ``seed``): a randomised QMC set, a new scrambling per
    ``seed``. A (n, d) float64 array. (N is rarely a power of 2: the set keeps most, not all, of its
    stratification; SciPy's warning about it is silenced.)"""
    import warnings

    from scipy.stats import qmc   # not a dyngi module: loaded on first use

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return qmc.Sobol(d=photon_dimensions(bounces), scramble=True, seed=int(seed)).random(int(n_photons))


def trace_photons(scene, n_photons: int, bounces: int, seed: int, stream: int = 0x1A, frame: int = 0,
                  lights=None, points: np.ndarray | None = None):
    """Keller's instant radiosity: ``n_photons`` light paths, a VPL at each of the first ``bounces``
    diffuse hits. Slot ``b * n_photons + j`` is bounce ``b + 1`` of photon ``j``.

    A photon ``j`` leaves a light with weight ``w_j`` (:func:`dyngi.vpl.emission.sample_photon_ray` through
    ``lights``, by default Mitsuba's ``sample_emitter_ray``: power / pdf, so ``mean(w)`` is the scene's
    emitted power); at its b-th diffuse hit y (albedo rho) it leaves a VPL of
    radiance-like value ``L = beta rho / pi`` (beta: w_j times the albedos before y), to be weighted by
    ``1 / n_photons`` in shading. It continues by cosine sampling (weight rho). Returns dict of NumPy
    arrays (``pos``, ``nrm``, ``albedo``, ``radiosity``, ``used``) and the rays traced.

    The random numbers come from ``(seed, frame, stream)`` (an opaque seed: a new ``frame`` compiles
    nothing): ``ir`` passes the frame index (a new photon set per frame, the paper's IR) or 0 (one
    fixed set for the whole sequence, ``photons='fixed'``). ``points``: an (n_photons,
    :func:`photon_dimensions`) point set in [0, 1) used instead (``ir``'s ``photons='qmc'``: a scrambled
    Sobol' set, :func:`sobol_photon_points`; ``'halton'``: Halton points, :func:`halton_photon_points`);
    ``seed``, ``frame`` and ``stream`` are then unused.
    """
    mscene = _mscene(scene)
    sampler = make_sampler(n_photons, seed, frame, stream) if points is None else PointSetSampler(points)
    ray, beta = sample_photon_ray(mscene, lights, sampler.next_1d(), sampler.next_2d(), sampler.next_2d())
    alive = dr.isfinite(dr.max(beta)) & (dr.max(beta) > 0.0)
    cols = {k: [] for k in ("pos", "nrm", "albedo", "radiosity", "used")}
    rays = 0
    for _ in range(int(bounces)):    # a few static bounces, each one kernel over all photons
        si, ok, n, alb = diffuse_surface(mscene, ray, alive, stage="photons")
        ok &= alive
        L = dr.select(ok, beta * alb * dr.inv_pi, 0.0)
        dr.eval(si.p, n, alb, L, ok)
        for k, v in (("pos", si.p), ("nrm", n), ("albedo", alb), ("radiosity", L)):
            cols[k].append(to_numpy3(v))
        cols["used"].append(np.asarray(ok, bool))
        rays += n_photons
        d = mi.Frame3f(n).to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
        ray = si.spawn_ray(d)
        beta = beta * alb
        alive = ok
    out = {k: np.concatenate(v) for k, v in cols.items()}
    out["radiosity"] = np.where(np.isfinite(out["radiosity"]), out["radiosity"], 0.0)
    out["used"] &= out["radiosity"].max(axis=1) > 0.0
    return out, rays


def photon_first_hits_device(scene, U, lights=None, *, stage: str = "photons", lanes: bool = False):
    """Photons from primary samples ``U`` (five Dr.Jit Floats: emitter choice, 2D position, 2D direction;
    the light chosen by ``lights``, :func:`dyngi.vpl.emission.sample_photon_ray`) to their first hit, on
    the device: dict of ``pos``, ``nrm``, ``albedo``, ``radiosity`` (= w rho / pi,
    as :func:`trace_photons`'s first bounce; 0 where invalid) and ``ok`` (a front-facing diffuse hit
    with a finite, positive radiosity). Its rays are counted under ``stage`` (:mod:`dyngi.rays`); with
    ``lanes`` (a caller inside a symbolic loop) they are not, and the dict also holds ``traced``: the lanes
    that traced a ray, for the caller's per-lane counter."""
    mscene = _mscene(scene)
    ray, beta = sample_photon_ray(mscene, lights, U[0], mi.Point2f(U[1], U[2]), mi.Point2f(U[3], U[4]))
    alive = dr.isfinite(dr.max(beta)) & (dr.max(beta) > 0.0)
    si, ok, n, alb = diffuse_surface(mscene, ray, alive, stage=stage, lanes=lanes)
    ok &= alive
    L = dr.select(ok, beta * alb * dr.inv_pi, 0.0)
    L = dr.select(dr.isfinite(dr.max(L)), L, 0.0)
    ok &= dr.max(L) > 0.0
    out = {"pos": mi.Point3f(si.p), "nrm": mi.Vector3f(n), "albedo": mi.Color3f(alb), "radiosity": mi.Color3f(L),
           "ok": ok}
    if lanes:
        out["traced"] = alive
    return out


def photon_first_hits(scene, u: np.ndarray, lights=None):
    """Photons from primary samples ``u`` (n x 5: emitter choice, 2D position, 2D direction) to their first
    hit: NumPy ``pos``, ``nrm``, ``albedo``, ``radiosity`` (= w rho / pi, as :func:`trace_photons`'s first
    bounce) and ``ok`` (a front-facing diffuse hit). The light-visible surface samples of a reflective
    shadow map, with the primary-sample parametrisation that Metropolis chains move in (the host form
    of :func:`photon_first_hits_device`)."""
    n_in = len(u)
    u = padded(np.asarray(u, np.float32))
    h = photon_first_hits_device(scene, [mi.Float(aligned(u[:, i])) for i in range(5)], lights)
    dr.eval(h)
    out = {"pos": to_numpy3(h["pos"]), "nrm": to_numpy3(h["nrm"]), "albedo": to_numpy3(h["albedo"]),
           "radiosity": to_numpy3(h["radiosity"]), "ok": np.asarray(h["ok"], bool)}
    return {k: v[:n_in] for k, v in out.items()}, n_in
