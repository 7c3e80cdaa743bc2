"""Ground truth: Mitsuba's own ``path`` integrator, cached on disk.

The reference for a frame is a render of the scene state at time ``t`` by
Mitsuba 3's C++ ``path`` integrator (``{'type': 'path', 'max_depth': D,
'rr_depth': 5}``: BSDF + emitter sampling with power-heuristic MIS, Russian
roulette) through the sensor :meth:`Camera.to_sensor` builds (box filter, so
a pixel is the plain mean over its footprint, as in dyngi's renderers). It is
code independent of dyngi's techniques; dyngi's own ``path`` must agree with
it within noise (tested), every other technique is measured against it.

Default sample count
--------------------
``DEFAULT_REF_SPP = 1024``. Measured on the 2-core dev box (llvm_ad_rgb,
cornell-static, 160 x 120, max_depth 12, other jobs running): ~17 s per
frame (~0.9 us per sample); the direct component of an indirect-only
reference adds ~3 s. The reference's own error, estimated from two
independent seeds (:func:`estimate_reference_noise`: ``relmse(a, b) / 2``,
since two independent references differ by twice the variance of one):

=====================  =========  ===========================================
                       relMSE     for scale (same frame, Mitsuba ``path``)
=====================  =========  ===========================================
reference, 1024 spp    1.6e-4     1 spp: 1.7e-1;  16 spp: 1.1e-2;  256 spp: 6.8e-4
indirect-only, 1024    2.4e-4     (relative to the indirect values)
=====================  =========  ===========================================

MAPE of two independent 1024-spp references is 0.021 (one against the truth
~0.015; a 1-spp frame has 0.40, DDGI Resampling's Table 1 reports 0.14-0.58).
So the reference's noise sits 1-3 orders of magnitude below the errors we
measure; noise scales as 1/spp (256 spp: ~6.5e-4). The numbers above are
from one scene; :func:`estimate_reference_noise` repeats the measurement
for any scene and settings.

``dyngi compare`` measures the noise of the very reference it uses, at no extra
cost: :func:`reference_halves` renders the ``spp`` samples as two independent
cached halves (seeds 0 and 1), uses their sample-weighted mean as the
reference and ``mean((a - b)^2) * n1 n2 / spp^2`` as its MSE (relMSE
likewise), reported per run beside a warning when it is not 10x below the
smallest technique error. :func:`scene_max_depth` gives the default depth
(``--ref-depth``): a scene file's integrator ``max_depth``, else 12.

Indirect-only references
------------------------
Several papers compare indirect illumination only (light that reflected at
least once before reaching the surface seen through the pixel: path
vertices >= 3). Mitsuba's ``path`` has no such mode, so

    indirect = render(max_depth = D, seed) - render(max_depth = 2, seed)

with the *same* seed and pass structure. Both renders draw the same random
numbers in the same order for the shared path prefix (camera sample, NEE and
BSDF sample at the first vertex; the emitter hit at the second vertex needs
no random number), and Mitsuba's sampler does not advance masked-off lanes,
so every sample's emission + direct contribution is bit-identical in both
and cancels: the difference is exactly the depth >= 3 part of each sample.
It is therefore unbiased (a difference of two unbiased estimators is
unbiased even without this correlation) *and* has the variance of a true
indirect-only estimator, not the sum of two variances. Measured on all 13
built-in scenes at 2 spp: no pixel of the shared-seed difference is
negative (with independent seeds 3-27 % are); values below 0 could only
come from float round-off and are clamped to 0. Both components are ordinary cached
references (the direct one is the ``max_depth=2`` reference), so asking for
the full and the indirect image of a frame renders the full one once.

Cache and chunks
----------------
Entries are stored and locked by :mod:`~dyngi.experiments.references.cache` (key, directory, atomic
writes, one renderer per missing entry); the settings that enter the key are :func:`reference_settings`.

A render is a sequence of seeded passes of at most :data:`MAX_SPP_PER_PASS`
samples per pixel; pass i has seed ``mix_seed(seed, i)`` whoever renders it.
:func:`render_passes` renders a contiguous range of them (a chunk) and
:func:`merge_chunks` merges chunks by sample count into the image the serial
render gives. :func:`~dyngi.experiments.reference_job.reference_job` fills the cache for many frames on an
executor (:mod:`~dyngi.experiments.cluster`): one task per chunk of every
missing entry, merged and stored by the caller as soon as an entry's chunks
are in (a lost worker loses its chunk only; the executor retries it).

Note: rendering a reference calls ``scene.at(t)``; the scene stays at ``t``.
"""
from __future__ import annotations

import numbers
import re
import time
from pathlib import Path

import numpy as np

from ...backend import mi
from ...errors import DyngiError
from ...metrics import RELMSE_EPS, mse, relmse
from ...sampling.rng import mix_seed
from .cache import _check_seed, _check_time_res, _entry_paths, get_or_render, reference_key

DEFAULT_REF_SPP = 1024
DEFAULT_MAX_DEPTH = 12
RR_DEPTH = 5
DIRECT_DEPTH = 2            # Mitsuba's max_depth for emission + direct illumination
MAX_SAMPLES_PER_PASS = 1 << 24
"""Samples (pixels x spp) per ``mi.render`` call; larger requests are split into passes."""
MAX_SPP_PER_PASS = 64
"""Samples per pixel per ``mi.render`` call: a reference of 1024 spp is 16 seeded passes, so its frame can
be split into up to 16 chunks on a cluster (:func:`chunk_ranges`); the extra calls cost nothing measurable
(docs/cluster.md, "Measured")."""
FORMAT_VERSION = 3
"""Bump when the way references are computed changes: invalidates every cached entry."""
SENSOR = "perspective+independent"
"""The sensor :meth:`Camera.to_sensor` builds (part of the cache key)."""
PIXEL_FILTER = "box"
"""The film's reconstruction filter: a box, so a pixel is the plain mean over its footprint, the
expectation of a technique whose primary rays are jittered uniformly within the pixel (part of the key)."""
_PASS_STREAM = 0x5EF


# -- settings --------------------------------------------------------------------------------------

def _check_settings(t, res, spp, max_depth, seed):
    w, h = _check_time_res(t, res)
    if not (isinstance(spp, numbers.Integral) and spp >= 1):
        raise DyngiError(f"reference spp must be a positive integer, got {spp!r}")
    if not (isinstance(max_depth, numbers.Integral) and (max_depth >= 1 or max_depth == -1)):
        raise DyngiError(f"reference max_depth must be >= 1 or -1 (unbounded), got {max_depth!r}")
    _check_seed(seed)
    return (w, h)


def _render_settings(scene, t: float, res, spp: int, max_depth: int, seed: int) -> dict:
    """The key entries every cached reference kind shares: scene state at ``t``, resolution, sample
    count, depths, seed, Mitsuba version and variant (settings already validated)."""
    return {
        "state": scene.state_hash(float(t)),
        "res": [int(res[0]), int(res[1])],
        "spp": int(spp),
        "max_depth": int(max_depth),
        "rr_depth": RR_DEPTH,
        "seed": int(seed),
        "mitsuba": mi.__version__,
        "variant": mi.variant(),
    }


def reference_settings(scene, t: float, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                       seed: int = 0) -> dict:
    """The settings that identify one cached reference (all of them enter the key)."""
    w, h = _check_settings(t, res, spp, max_depth, seed)
    return {
        "format": FORMAT_VERSION,
        **_render_settings(scene, t, (w, h), spp, max_depth, seed),
        "integrator": "path",
        "sensor": SENSOR,
        "filter": PIXEL_FILTER,
    }


def reference_paths(scene, settings: dict, cache_dir=None) -> tuple[Path, Path]:
    """(exr, json) paths of the cache entry for ``settings``."""
    return _entry_paths(scene, settings, cache_dir)


# -- rendering ------------------------------------------------------------------

def _passes(res, spp: int, max_samples: int | None = None) -> list[int]:
    """Split ``spp`` into passes of at most ``max_samples`` samples (default: MAX_SAMPLES_PER_PASS, and at
    most MAX_SPP_PER_PASS samples per pixel).

    Depends on res, spp and ``max_samples`` only.
    """
    w, h = res
    if max_samples is None:
        per = max(1, min(spp, MAX_SAMPLES_PER_PASS // (w * h), MAX_SPP_PER_PASS))
    else:
        per = max(1, min(spp, max_samples // (w * h)))
    out = [per] * (spp // per)
    if spp % per:
        out.append(spp % per)
    return out


def _render(scene, t: float, res, spp: int, max_depth: int, seed: int) -> np.ndarray:
    """Render with Mitsuba's ``path`` integrator at time ``t``; H x W x 3 float32 (no cache).

    Pass i uses seed ``mix_seed(seed, i)``; the pass split depends only on
    (res, spp), so two renders with equal (res, spp, seed) but different
    ``max_depth`` use identical random numbers (see the module docstring).
    """
    acc = render_passes(scene, t, res, spp, max_depth, seed)
    return merge_chunks([acc], spp)


def render_passes(scene, t: float, res, spp: int, max_depth: int, seed: int, start: int = 0,
                  stop: int | None = None) -> np.ndarray:
    """Sample-weighted sum (float64 H x W x 3) of passes ``start``..``stop - 1`` of the reference of ``spp``
    samples: one chunk of it (:func:`chunk_ranges`). Pass i holds ``_passes(res, spp)[i]`` samples with
    seed ``mix_seed(seed, i)`` whichever chunk renders it, so the chunks' sums merged by
    :func:`merge_chunks` give the serial render: every pass mean (float32) times its count is exact in
    float64, and so are the sums (a pixel's pass means would have to differ by a factor of ~10^5 for a
    rounding), so the merge equals :func:`_render` bit for bit (tested)."""
    scene.at(float(t))
    camera = scene.camera(float(t))
    integrator = mi.load_dict({"type": "path", "max_depth": int(max_depth), "rr_depth": RR_DEPTH})
    w, h = res
    acc = np.zeros((h, w, 3), np.float64)
    sensors = {}
    passes = _passes(res, spp)
    stop = len(passes) if stop is None else stop
    for i in range(start, stop):
        n = passes[i]
        if n not in sensors:
            sensors[n] = camera.to_sensor(res, n)
        img = mi.render(scene.mi_scene, sensor=sensors[n], integrator=integrator,
                        seed=mix_seed(seed, i, _PASS_STREAM), spp=n)
        acc += np.asarray(img, dtype=np.float64).reshape(h, w, -1)[..., :3] * n
    return acc


def chunk_ranges(res, spp: int, chunks: int) -> list[tuple[int, int]]:
    """Pass index ranges ``(start, stop)`` that split the reference of ``spp`` samples into at most ``chunks``
    contiguous chunks of near-equal size (fewer when it has fewer passes)."""
    n = len(_passes(res, spp))
    k = max(1, min(int(chunks), n))
    bounds = [round(j * n / k) for j in range(k + 1)]
    return [(bounds[j], bounds[j + 1]) for j in range(k)]


def merge_chunks(sums, spp: int) -> np.ndarray:
    """The reference image (float32) from its chunks' sample-weighted sums (:func:`render_passes`), in order."""
    acc = None
    for s in sums:
        acc = np.array(s, np.float64, copy=True) if acc is None else acc + s
    return (acc / spp).astype(np.float32)


# -- cache ------------------------------------------------------------------------


# -- cached references ----------------------------------------------------------------------------

def cached_reference(scene, t: float, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                     cache_dir=None, seed: int = 0) -> tuple[np.ndarray, bool]:
    """(image, was_cached) of the full reference with these settings; renders and stores on a miss.

    Concurrent callers (threads, processes, cluster workers sharing the cache directory) render a missing
    entry once: the first takes the entry's lock (:func:`get_or_render`), the others wait for the entry."""
    settings = reference_settings(scene, t, res, spp, max_depth, seed)
    key = reference_key(settings)
    exr, js = reference_paths(scene, settings, cache_dir)

    def render():
        start = time.perf_counter()
        img = _render(scene, float(t), tuple(settings["res"]), int(spp), int(max_depth), int(seed))
        return img, entry_meta(settings, key, scene.name, t, time.perf_counter() - start)
    (img, _), hit = get_or_render(exr, js, key, settings["res"], render)
    return img, hit


def entry_meta(settings: dict, key: str, scene_name: str, t: float, seconds: float, **extra) -> dict:
    """The JSON sidecar of a reference entry."""
    return dict(settings, key=key, scene=scene_name, time=float(t), variant=mi.variant(),
                render_seconds=round(seconds, 3), created=time.strftime("%Y-%m-%dT%H:%M:%S"), **extra)


def reference_image(scene, t: float, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                    indirect: bool = False, cache_dir=None, seed: int = 0) -> np.ndarray:
    """Ground-truth image (H x W x 3 linear float32) of ``scene`` at time ``t``, from the cache if present.

    ``res`` is (width, height). ``indirect=True`` returns indirect
    illumination only (path vertices >= 3), computed as the difference of
    the ``max_depth`` and the ``max_depth=2`` references with the same seed
    (module docstring); it needs ``max_depth > 2`` or ``-1``.
    """
    if indirect and isinstance(max_depth, numbers.Integral) and 1 <= max_depth <= DIRECT_DEPTH:
        raise DyngiError(f"an indirect-only reference needs max_depth > {DIRECT_DEPTH} or -1, got {max_depth}")
    full, _ = cached_reference(scene, t, res, spp, max_depth, cache_dir, seed)
    if not indirect:
        return full
    direct, _ = cached_reference(scene, t, res, spp, DIRECT_DEPTH, cache_dir, seed)
    return np.maximum(full - direct, 0.0).astype(np.float32)


def half_spp(spp: int) -> tuple[int, int]:
    """Sample counts of the two independent halves of a reference of ``spp`` samples."""
    if not (isinstance(spp, numbers.Integral) and spp >= 2):
        raise DyngiError(f"a reference with a noise estimate needs spp >= 2 (two halves), got {spp!r}")
    return int(spp) // 2, int(spp) - int(spp) // 2


def reference_halves(scene, t: float, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                     cache_dir=None) -> tuple[np.ndarray, dict]:
    """The reference of ``spp`` samples as two independent cached halves, and its own noise.

    Half a (n1 = spp // 2 samples, seed 0) and half b (n2 = spp - n1, seed 1)
    are independent unbiased estimates; the reference is their sample-weighted
    mean r = (n1 a + n2 b) / spp, unbiased with per-pixel variance
    sigma^2 / spp. Since E(a - b)^2 = sigma^2 (1/n1 + 1/n2), the reference's
    own MSE is estimated by ``mean((a - b)^2) * n1 n2 / spp^2`` (1/4 of it for
    equal halves) and its relMSE likewise with the per-pixel relMSE weight
    1 / (r^2 + eps) (r for the unknown truth: fine while the noise is small).
    No extra samples are rendered for the estimate. Returns
    ``(image, {'mse', 'relmse', 'spp', 'halves'})``.
    """
    n1, n2 = half_spp(spp)
    a, _ = cached_reference(scene, t, res, n1, max_depth, cache_dir, seed=0)
    b, _ = cached_reference(scene, t, res, n2, max_depth, cache_dir, seed=1)
    img, noise = combine_halves(a, b, n1, n2)
    noise.update(spp=int(spp), halves=[n1, n2])
    return img.astype(np.float32), noise


def combine_halves(a: np.ndarray, b: np.ndarray, n1: int, n2: int) -> tuple[np.ndarray, dict]:
    """Sample-weighted mean of two independent halves (n1, n2 samples) and its own error.

    Returns ``(m, {'mse', 'relmse'})`` with m = (n1 a + n2 b) / n (float64),
    MSE ``mean((a - b)^2) * n1 n2 / n^2`` and relMSE the same with each term
    divided by ``m^2 + RELMSE_EPS`` (see :func:`reference_halves`).
    """
    a64, b64 = np.asarray(a, np.float64), np.asarray(b, np.float64)
    m = (n1 * a64 + n2 * b64) / (n1 + n2)
    k = n1 * n2 / float(n1 + n2) ** 2
    d2 = (a64 - b64) ** 2
    return m, {"mse": float(np.mean(d2) * k), "relmse": float(np.mean(d2 / (m * m + RELMSE_EPS)) * k)}


def fill_reference_cache(scene, frames, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                         indirect: bool = False, cache_dir=None, seed: int = 0, progress=None,
                         halves: bool = False) -> list[dict]:
    """Make sure the references of ``frames`` are cached; return one record per frame.

    ``frames``: a count N (frames 0..N-1) or an iterable of frame indices;
    frame i is at ``scene.frame_time(i)``. ``progress``: optional callable
    ``progress(record)`` after each frame (e.g. a tqdm update). A record is
    ``{'frame', 'time', 'key', 'path', 'cached'}`` where ``cached`` is True
    when nothing had to be rendered. With ``indirect`` the direct
    (``max_depth=2``) component is cached as well. ``halves``: cache the two
    independent halves that :func:`reference_halves` (and ``dyngi compare``)
    use instead of one render of ``spp`` samples (``key``/``path`` name the first half).
    """
    if indirect and isinstance(max_depth, numbers.Integral) and 1 <= max_depth <= DIRECT_DEPTH:
        raise DyngiError(f"an indirect-only reference needs max_depth > {DIRECT_DEPTH} or -1, got {max_depth}")
    if isinstance(frames, numbers.Integral):
        if frames < 1:
            raise DyngiError(f"number of reference frames must be >= 1, got {frames}")
        frames = range(int(frames))
    out = []
    for i in frames:
        if not (isinstance(i, numbers.Integral) and i >= 0):
            raise DyngiError(f"frame indices must be non-negative integers, got {i!r}")
        t = scene.frame_time(int(i))
        if halves:
            n1, n2 = half_spp(spp)
            _, hit = cached_reference(scene, t, res, n1, max_depth, cache_dir, 0)
            _, hit_b = cached_reference(scene, t, res, n2, max_depth, cache_dir, 1)
            hit = hit and hit_b
            settings = reference_settings(scene, t, res, n1, max_depth, 0)
        else:
            _, hit = cached_reference(scene, t, res, spp, max_depth, cache_dir, seed)
            settings = reference_settings(scene, t, res, spp, max_depth, seed)
        if indirect:
            _, hit_d = cached_reference(scene, t, res, spp, DIRECT_DEPTH, cache_dir, seed)
            hit = hit and hit_d
        rec = {"frame": int(i), "time": float(t), "key": reference_key(settings),
               "path": str(reference_paths(scene, settings, cache_dir)[0]), "cached": hit}
        out.append(rec)
        if progress is not None:
            progress(rec)
    return out


def estimate_reference_noise(scene, t: float, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                             indirect: bool = False, cache_dir=None) -> dict:
    """Error of one reference against the truth, estimated from two independent seeds (0 and 1).

    For independent unbiased a, b: E(a - b)^2 = 2 Var, so ``relmse(a, b) / 2``
    and ``mse(a, b) / 2`` estimate the reference's own relMSE and MSE (the
    relMSE denominator uses the noisy b instead of the truth: fine while the
    noise is small). Both renders are cached like any reference.
    """
    a = reference_image(scene, t, res, spp, max_depth, indirect, cache_dir, seed=0)
    b = reference_image(scene, t, res, spp, max_depth, indirect, cache_dir, seed=1)
    return {"relmse": relmse(a, b) / 2.0, "mse": mse(a, b) / 2.0, "spp": int(spp), "res": list(res)}


_DEPTH_RE = re.compile(r"max_depth\s*=\s*(-?\d+)")


def scene_max_depth(scene) -> int:
    """The scene's own path depth: its file's integrator ``max_depth``, else :data:`DEFAULT_MAX_DEPTH`.

    Read from the loaded integrator's description (Mitsuba resolves ``$max_depth``
    defaults of the XML); built-in scenes have no integrator and get the default.
    Mitsuba prints the depth as an unsigned 32-bit number, so a file's ``-1`` reads
    4294967295: values from 2^31 up are the negative ones they wrap (the wooden
    staircase's -1 reached the reference integrator as 4294967295 and failed).
    """
    integ = scene.mi_scene.integrator() if hasattr(scene.mi_scene, "integrator") else None
    m = _DEPTH_RE.search(str(integ)) if integ is not None else None
    if m:
        d = int(m.group(1))
        if d >= 1 << 31:
            d -= 1 << 32
        if 1 <= d < 1 << 31 or d == -1:
            return d
    return DEFAULT_MAX_DEPTH
