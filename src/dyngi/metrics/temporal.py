"""Temporal error metrics of SMC Instant Radiosity (Sec. 5.2, Eq. 10, Table 1).

The paper tracks the luminance of a few pixels over a sequence, after
Reinhard tone mapping, and reports

* ``|E|``  -- the average absolute error against a path-traced reference over
  all tracked pixels and frames ("overall error"), and
* ``|E'|`` -- the average absolute finite difference in time of that error,
  ``E' = dError / dt`` (Eq. 10), which measures flicker: a technique whose
  error is constant in time has ``|E'| = 0`` however large ``|E|`` is.

Our conventions (the paper leaves them open):

* value tracked: luminance ``Y`` (:func:`dyngi.color.luminance`, Rec. 709) of linear
  RGB, tone-mapped by Reinhard's global operator with a fixed scale,
  ``T(Y) = k Y / (1 + k Y)``, ``k = exposure`` (:func:`~dyngi.metrics.image.reinhard`);
  the same ``k`` for estimate, reference and all frames. ``exposure='auto'``
  uses Reinhard's key value: ``k = 0.18 / Lw``, ``Lw`` the log-average
  luminance of the whole *reference* sequence (Reinhard et al. 2002, Eqs. 1-2).
* ``Error_t = T(Y_est,t) - T(Y_ref,t)`` (signed); ``|E| = mean_t,p |Error_t|``;
  ``|E'| = mean_t,p |Error_t - Error_t-1| / dt`` over the T-1 frame pairs.
  ``dt`` defaults to 1 (per frame); pass ``1 / fps`` for a rate per second.
* pixels: ``None`` tracks every pixel; the paper tracks 8
  (:func:`pick_pixels` chooses them deterministically).
"""
from __future__ import annotations

import numbers

import numpy as np

from ..errors import DyngiError
from .checks import as_image, as_pair, luminance
from .image import reinhard

REINHARD_KEY = 0.18
"""Reinhard's "middle grey" key value a (Reinhard et al. 2002, Sec. 2.1)."""


def pick_pixels(h: int, w: int, n: int = 8, seed: int = 0) -> np.ndarray:
    """``n`` distinct pixels of an ``h`` x ``w`` image as an (n, 2) int array of (row, col).

    Deterministic in ``seed`` (its own ``numpy`` generator, no global state).
    """
    h, w, n = int(h), int(w), int(n)
    if h < 1 or w < 1:
        raise DyngiError(f"pick_pixels needs a non-empty image, got {h} x {w}")
    if not (1 <= n <= h * w):
        raise DyngiError(f"pick_pixels: n must be in [1, {h * w}] for a {h} x {w} image, got {n}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x7E4D]))
    flat = np.sort(rng.choice(h * w, size=n, replace=False))
    return np.stack([flat // w, flat % w], axis=1).astype(np.int64)


def auto_exposure(refs) -> float:
    """Reinhard's scale ``a / Lw`` for a reference sequence (T x H x W x 3, a list, or one image).

    ``Lw = exp(mean(log(delta + Y)))`` over all pixels and frames, delta = 1e-4.
    """
    seq = ([refs] if refs.ndim == 3 else refs) if isinstance(refs, np.ndarray) else list(refs)
    total, count = 0.0, 0
    for r in seq:
        y = luminance(as_image(r, "reference", nonnegative=True))
        total += float(np.sum(np.log(1e-4 + y)))
        count += y.size
    if count == 0:
        raise DyngiError("auto exposure needs at least one reference frame")
    return REINHARD_KEY / float(np.exp(total / count))


def _check_pixels(pixels, h, w):
    if pixels is None:
        return None
    p = np.asarray(pixels)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 1 or not np.issubdtype(p.dtype, np.integer):
        raise DyngiError(f"pixels must be an (N, 2) integer array of (row, col), got shape {p.shape}")
    if np.any(p < 0) or np.any(p[:, 0] >= h) or np.any(p[:, 1] >= w):
        raise DyngiError(f"pixels out of range for a {h} x {w} image")
    return p


class TemporalTracker:
    """Streaming form of :func:`temporal_errors`: ``add(img, ref)`` per frame, then ``result()``.

    Keeps only the tracked pixels' error of the previous frame, so a runner
    need not hold the sequence in memory. ``exposure`` must be a number here
    (``'auto'`` needs the whole reference sequence; see :func:`auto_exposure`).
    """

    def __init__(self, pixels=None, exposure: float = 1.0, dt: float = 1.0):
        if not (isinstance(exposure, numbers.Real) and np.isfinite(exposure) and exposure > 0):
            raise DyngiError(f"temporal exposure must be a positive number (or 'auto' for temporal_errors), "
                             f"got {exposure!r}")
        if not (isinstance(dt, numbers.Real) and np.isfinite(dt) and dt > 0):
            raise DyngiError(f"temporal dt must be a positive number, got {dt!r}")
        self.pixels = pixels
        self.exposure = float(exposure)
        self.dt = float(dt)
        self.errors: list[np.ndarray] = []   # signed tone-mapped error per frame (tracked pixels)
        self._shape = None
        self._sum_abs = 0.0
        self._sum_abs_diff = 0.0
        self._prev = None

    def add(self, img, ref) -> np.ndarray:
        """Add one frame; return the signed error of the tracked pixels."""
        a, b = as_pair(img, ref, nonnegative=True)
        if self._shape is None:
            self._shape = a.shape
            self._pix = _check_pixels(self.pixels, *a.shape[:2])
        elif a.shape != self._shape:
            raise DyngiError(f"frame shape {a.shape} differs from the first frame's {self._shape}")
        if self._pix is not None:
            a = a[self._pix[:, 0], self._pix[:, 1]]
            b = b[self._pix[:, 0], self._pix[:, 1]]
        err = (reinhard(luminance(a), self.exposure) - reinhard(luminance(b), self.exposure)).ravel()
        self._sum_abs += float(np.sum(np.abs(err)))
        if self._prev is not None:
            self._sum_abs_diff += float(np.sum(np.abs(err - self._prev))) / self.dt
        self._prev = err
        self.errors.append(err)
        return err

    def result(self) -> dict:
        """``{'E': |E|, 'E_prime': |E'|, 'frames': T, 'pixels': N, 'exposure': k, 'error': T x N array}``.

        ``E_prime`` is NaN for a single frame (no finite difference exists).
        """
        t = len(self.errors)
        if t == 0:
            raise DyngiError("temporal metrics need at least one frame")
        n = self.errors[0].size
        e_prime = self._sum_abs_diff / ((t - 1) * n) if t > 1 else float("nan")
        return {"E": self._sum_abs / (t * n), "E_prime": e_prime, "frames": t, "pixels": n,
                "exposure": self.exposure, "error": np.stack(self.errors)}


def temporal_errors(frames, refs, pixels=None, exposure=1.0, dt: float = 1.0) -> dict:
    """SMC-IR temporal metrics |E| and |E'| (Sec. 5.2, Eq. 10) of a sequence against its reference.

    ``frames`` and ``refs``: T x H x W x 3 linear images (arrays or lists of
    H x W x 3). ``pixels``: None (all) or (N, 2) (row, col) indices, e.g.
    :func:`pick_pixels`. ``exposure``: Reinhard scale k, or ``'auto'``
    (:func:`auto_exposure` of ``refs``). ``dt``: time between frames
    (1 = per-frame differences). Returns the dict of :meth:`TemporalTracker.result`.
    """
    if len(frames) != len(refs):
        raise DyngiError(f"temporal metrics: {len(frames)} frames but {len(refs)} reference frames")
    if len(frames) == 0:
        raise DyngiError("temporal metrics need at least one frame")
    if isinstance(exposure, str):
        if exposure != "auto":
            raise DyngiError(f"temporal exposure must be a positive number or 'auto', got '{exposure}'")
        exposure = auto_exposure(refs)
    tr = TemporalTracker(pixels, exposure, dt)
    for img, ref in zip(frames, refs):
        tr.add(img, ref)
    return tr.result()


def pick_tracked_pixels(ref, n: int = 8, grid: tuple[int, int] = (4, 2)) -> np.ndarray:
    """The ``n`` = 8 pixels tracked as in SMC-IR Sec. 5.2, chosen from a reference image (H x W x 3).

    Which and why (our choice; the paper does not say which 8 it tracks): the image is cut into a
    ``grid`` of 4 x 2 cells, one pixel per cell, so the 8 spread over the whole view; in each cell, the
    pixel whose reference luminance is the median of the cell's *lit* pixels (luminance > 0), so each
    tracks a typical surface of its region rather than a dark miss, an emitter or an edge extreme; a cell
    with no lit pixel gives its centre. Deterministic in the reference; every technique gets the same
    pixels. Returns (n, 2) int (row, col).
    """
    img = as_image(ref, "reference", nonnegative=True)
    h, w = img.shape[:2]
    y = luminance(img)
    gx, gy = grid
    out = []
    for cy in range(gy):
        for cx in range(gx):
            r0, r1 = cy * h // gy, max(cy * h // gy + 1, (cy + 1) * h // gy)
            c0, c1 = cx * w // gx, max(cx * w // gx + 1, (cx + 1) * w // gx)
            cell = y[r0:r1, c0:c1]
            lit = np.flatnonzero(cell.ravel() > 0)
            if len(lit) == 0:
                out.append(((r0 + r1) // 2, (c0 + c1) // 2))
                continue
            vals = cell.ravel()[lit]
            k = lit[np.argsort(vals, kind="stable")[len(lit) // 2]]
            out.append((r0 + k // cell.shape[1], c0 + k % cell.shape[1]))
    return np.asarray(out[: int(n)], np.int64)
