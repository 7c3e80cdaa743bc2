"""Indirect-only reference: light that reflected at least once before the surface seen through a pixel.

Definition (the one the papers compare, and :mod:`dyngi.experiments.references.path`'s):
the radiance of all paths with >= 3 vertices (camera - x1 - x2 - ... - light),
i.e. the full image without the emission seen at the primary vertex x1 and
without the direct light at x1. For Mitsuba's ``path`` this is
``render(max_depth=D) - render(max_depth=2)``.

Renderer (our choice; issue 11 item 6 allows this or Mitsuba full minus
Mitsuba direct): **dyngi's own path tracer in its indirect-only mode**
(:func:`dyngi.transport.path_walk.render_paths` with ``indirect_only=True``):
BSDF sampling + NEE with power-heuristic MIS and Russian roulette from
``rr_depth = 5``, exactly Mitsuba's ``path`` estimator, with the terms of the
first vertex (its emission, the emission its BSDF-sampled ray reaches, its NEE
sample) left out and everything from the second vertex on kept. Why:

* unbiased and unclamped: each term left out is a whole non-negative sample
  contribution, so every pixel is a plain mean of non-negative samples; no
  difference of two images, nothing to clamp (:mod:`~dyngi.experiments.references.path`'s difference
  relies on both Mitsuba renders drawing identical random numbers for the
  shared prefix and clamps float round-off at 0);
* one render instead of two, and the noise is that of a true indirect-only
  estimator;
* validated against Mitsuba: per-pixel z-tests against ``Mitsuba(D) -
  Mitsuba(2)`` and ``indirect + Mitsuba(2) == Mitsuba(D)``
  (``tests/techniques/test_path.py``, ``tests/experiments/test_indirect_reference.py``), and the
  full-image mode of the same tracer is z-tested against Mitsuba on the
  built-in and real scenes.

Camera samples are jittered uniformly inside the pixel (box filter), like the
Mitsuba reference's sensor (:meth:`Camera.to_sensor`), so aliasing at the
primary hit is not counted as GI error.

Noise: the ``spp`` samples are rendered as two independent halves a and b
(``spp // 2`` and ``spp - spp // 2`` samples, independent RNG streams); the
image is their sample-weighted mean m. For unbiased halves
E[(a - b)^2] = s^2 (1/na + 1/nb) with s^2 the per-sample variance, and
Var(m) = s^2 / n, so the image's own MSE against the truth is estimated by
``mean((a - b)^2) * na * nb / n^2`` (1/4 of it for equal halves), and its
relMSE by the same with each term divided by ``m^2 + RELMSE_EPS``
(:func:`dyngi.metrics.relmse`'s convention, with m standing in for the truth).

Cost, measured (cornell-static, 160x90, 256 spp, max_depth 12, 2-core box with
other jobs running, two runs): 1.5-1.7 s, against 0.9-1.6 s for Mitsuba's full
reference plus 0.2-0.5 s for its ``max_depth=2`` render, i.e. about the price of
the difference; noise estimate relMSE 9.4e-4 to 9.9e-4 (mean indirect / full = 0.386
for both renderers).
"""
from __future__ import annotations

import numbers
import time
from pathlib import Path

import numpy as np

from ...backend import dr
from ...errors import DyngiError
from ...sampling.rng import mix_seed
from ...techniques.base import to_image
from ...transport.path_walk import render_paths
from .cache import _check_seed, _check_time_res, _entry_paths, get_or_render, reference_key
from .path import (DEFAULT_MAX_DEPTH, DEFAULT_REF_SPP, DIRECT_DEPTH, RR_DEPTH, _passes, _render_settings,
                   combine_halves, half_spp)

INDIRECT_FORMAT = 1
"""Bump when the way indirect references are computed changes (invalidates their cache entries)."""
MAX_SAMPLES_PER_PASS = 1 << 22
"""Samples (pixels x spp) per path-tracer launch; larger requests are split into passes."""
_HALF_STREAMS = (0x1A1, 0x1A2)
"""RNG streams of the two independent halves."""


def _check(t, res, spp, max_depth, seed) -> tuple[int, int]:
    w, h = _check_time_res(t, res, "indirect reference")
    if not (isinstance(spp, numbers.Integral) and spp >= 2):
        raise DyngiError(f"indirect reference spp must be an integer >= 2 (two independent halves), got {spp!r}")
    if not (isinstance(max_depth, numbers.Integral) and (max_depth > DIRECT_DEPTH or max_depth == -1)):
        raise DyngiError(f"an indirect-only reference needs max_depth > {DIRECT_DEPTH} or -1 (unbounded), "
                         f"got {max_depth!r}")
    _check_seed(seed, "indirect reference")
    return w, h


def _render_half(scene, camera, res, spp: int, max_depth: int, seed: int) -> np.ndarray:
    """Mean of ``spp`` indirect-only samples per pixel (float64 H x W x 3), in passes of bounded size."""
    w, h = res
    acc = np.zeros((h, w, 3), np.float64)
    for i, n in enumerate(_passes(res, spp, MAX_SAMPLES_PER_PASS)):
        L, _ = render_paths(scene, camera, res, n, seed=seed, frame_index=i, max_depth=int(max_depth),
                            rr_depth=RR_DEPTH, power_heuristic=True, indirect_only=True)
        dr.eval(L)
        acc += to_image(L, res).astype(np.float64) * n
    return acc / spp


def indirect_reference_image(scene, t: float, res, spp: int = DEFAULT_REF_SPP,
                             max_depth: int = DEFAULT_MAX_DEPTH, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Indirect-only ground truth of ``scene`` at time ``t`` and its own noise (not cached).

    Parameters
    ----------
    scene : dyngi.scene.Scene   moved to ``t`` (``scene.at(t)``) and left there
    t : float                   scene time (``scene.frame_time(i)`` for frame i)
    res : (width, height)
    spp : int >= 2              samples per pixel, split into two independent halves
    max_depth : int             path vertices as in Mitsuba (> 2, or -1 for unbounded); use the
                                full reference's depth (``--ref-depth``) so the two match
    seed : int                  in [0, 2^32); another seed gives an independent image

    Returns
    -------
    image : H x W x 3 float32   linear radiance of paths with >= 3 vertices; unclamped, unbiased,
                                every value >= 0 (a mean of non-negative samples)
    noise : dict                the image's own error against the truth, from the two halves:
                                ``{'mse', 'relmse', 'spp', 'res': [w, h], 'method': 'two independent halves'}``
                                (``relmse`` in :func:`dyngi.metrics.relmse`'s convention)

    Raises :class:`DyngiError` on bad settings. See the module docstring for
    the definition, the choice of renderer and the noise estimator.
    """
    w, h = _check(t, res, spp, max_depth, seed)
    scene.at(float(t))
    camera = scene.camera(float(t))
    na, nb = half_spp(spp)
    a = _render_half(scene, camera, (w, h), na, max_depth, mix_seed(seed, 0, _HALF_STREAMS[0]))
    b = _render_half(scene, camera, (w, h), nb, max_depth, mix_seed(seed, 0, _HALF_STREAMS[1]))
    m, noise = combine_halves(a, b, na, nb)
    noise.update(spp=int(spp), res=[w, h], method="two independent halves")
    return m.astype(np.float32), noise


# -- cache ---------------------------------------------------------------------------------

def indirect_reference_settings(scene, t: float, res, spp: int = DEFAULT_REF_SPP,
                                max_depth: int = DEFAULT_MAX_DEPTH, seed: int = 0) -> dict:
    """The settings that identify one cached indirect reference (all of them enter the key)."""
    w, h = _check(t, res, spp, max_depth, seed)
    return {
        "format": INDIRECT_FORMAT,
        "kind": "indirect",
        "renderer": "dyngi-path-indirect-only",
        **_render_settings(scene, t, (w, h), spp, max_depth, seed),
        "filter": "box",              # camera samples uniform in the pixel
    }


def indirect_reference_paths(scene, settings: dict, cache_dir=None) -> tuple[Path, Path]:
    """(exr, json) paths of the cache entry for ``settings`` (same directory as the full references)."""
    return _entry_paths(scene, settings, cache_dir, kind="indirect")


def cached_indirect_reference(scene, t: float, res, spp: int = DEFAULT_REF_SPP,
                              max_depth: int = DEFAULT_MAX_DEPTH, seed: int = 0,
                              cache_dir=None) -> tuple[np.ndarray, dict, bool]:
    """(image, noise, was_cached): :func:`indirect_reference_image`, cached on disk.

    Cache directory and atomic-write rules as :func:`dyngi.experiments.references.path.cached_reference`
    (``cache_dir``, else ``$DYNGI_CACHE/reference``, ...); an entry is
    ``<scene>-indirect-<key>.exr`` plus a JSON with the settings and the noise
    estimate. The key hashes :func:`indirect_reference_settings` (scene state
    at ``t``, resolution, spp, depths, seed, filter, variant, Mitsuba version, format).
    """
    settings = indirect_reference_settings(scene, t, res, spp, max_depth, seed)
    key = reference_key(settings)
    exr, js = indirect_reference_paths(scene, settings, cache_dir)

    def render():
        start = time.perf_counter()
        img, noise = indirect_reference_image(scene, t, res, spp, max_depth, seed)
        meta = dict(settings, key=key, scene=scene.name, time=float(t), noise=noise,
                    render_seconds=round(time.perf_counter() - start, 3),
                    created=time.strftime("%Y-%m-%dT%H:%M:%S"))
        return img, meta
    (img, meta), hit = get_or_render(exr, js, key, settings["res"], render,
                                     meta_ok=lambda meta: isinstance(meta.get("noise"), dict))
    return img, meta["noise"], hit
