"""Denoising for any technique's output with Intel Open Image Denoise (issue 14, item 5).

The DDGI Resampling paper denoises with the OptiX denoiser (Sec. 5, Fig. 1,
"+Denoising"); we substitute OIDN (``pyoidn`` from PyPI, CPU), which also
takes the albedo and normal auxiliary images. :func:`aux_buffers` renders those
from the screen-space G-buffer (:mod:`dyngi.transport.gbuffer`): diffuse albedo
(Mitsuba's ``eval_diffuse_reflectance``) and the viewer-facing shading normal
of the primary hit, averaged over ``spp`` jittered rays per pixel (box filter,
like the rendered image), so any technique can be denoised with no AOVs of its own.

``denoise(image, albedo, normal)`` returns the filtered H x W x 3 float32
image (HDR mode; NaN/negative inputs are zeroed, albedo clipped to [0, 1],
normals to [-1, 1]). Without ``pyoidn`` installed it raises one
:class:`~dyngi.errors.DyngiError` saying how to install it; :func:`available`
tells beforehand.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError
from ..transport.gbuffer import render_gbuffer
from ..sampling.rng import make_sampler
from ..techniques.base import to_image

QUALITIES = ("high", "balanced", "fast")


def require() -> None:
    """Raise one clear error when the OIDN binding is missing (before any work is done)."""
    if not available():
        raise DyngiError("--denoise needs Intel Open Image Denoise's Python binding: "
                         "pip install 'pyoidn>=2.5.1' (or reinstall dyngi with the 'denoise' extra)")


def available() -> bool:
    """Whether the OIDN binding (``pyoidn``) can be imported."""
    try:
        import pyoidn  # noqa: F401
    except Exception:   # ImportError, or a broken native library
        return False
    return True


def _rgb(name, a, shape=None):
    a = np.asarray(a, np.float32)
    if a.ndim != 3 or a.shape[2] < 3:
        raise DyngiError(f"denoise: {name} must be an H x W x 3 image, got shape {a.shape}")
    a = np.ascontiguousarray(a[..., :3])
    if shape is not None and a.shape != shape:
        raise DyngiError(f"denoise: {name} has shape {a.shape}, the image {shape}")
    return np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)


def denoise(image, albedo=None, normal=None, quality: str = "high") -> np.ndarray:
    """OIDN's ``RT`` filter on a linear HDR ``image``, guided by ``albedo`` and ``normal`` when given."""
    if quality not in QUALITIES:
        raise DyngiError(f"unknown denoise quality '{quality}'; valid: {', '.join(QUALITIES)}")
    if not available():
        raise DyngiError("denoising needs Intel Open Image Denoise: pip install pyoidn")
    import pyoidn

    img = np.maximum(_rgb("image", image), 0.0)
    alb = None if albedo is None else np.clip(_rgb("albedo", albedo, img.shape), 0.0, 1.0)
    nrm = None if normal is None else np.clip(_rgb("normal", normal, img.shape), -1.0, 1.0)
    if nrm is not None and alb is None:
        raise DyngiError("denoise: OIDN needs the albedo whenever a normal image is given")
    out = pyoidn.denoise(img, alb, nrm, hdr=True, quality=quality)
    return np.asarray(out, np.float32)


def aux_buffers(scene, camera, res, spp: int = 4, seed: int = 0):
    """(albedo, normal) H x W x 3 images of the primary hits, averaged over ``spp`` jittered rays per pixel."""
    w, h = res
    alb = np.zeros((h, w, 3), np.float64)
    nrm = np.zeros((h, w, 3), np.float64)
    for s in range(max(1, int(spp))):
        sampler = make_sampler(w * h, seed, s, 0xA0C5)
        gb = render_gbuffer(scene, camera, res, sampler.next_2d(), getattr(scene, "time", 0.0) or 0.0)
        alb += to_image(gb.albedo, res)
        nrm += to_image(dr.select(gb.valid, gb.n_sh, mi.Vector3f(0.0)), res)
    alb /= max(1, int(spp))
    nrm /= max(1, int(spp))
    return alb.astype(np.float32), nrm.astype(np.float32)
