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

Cache
-----
Directory: argument ``cache_dir``, else ``$DYNGI_CACHE/reference``, else
``$XDG_CACHE_HOME/dyngi/reference`` (default ``~/.cache/dyngi/reference``).
An entry is ``<scene>-<key>.exr`` (float32 RGB, lossless) plus
``<scene>-<key>.json`` (the settings, for humans and for a consistency check
on load). The key hashes: ``scene.state_hash(t)`` (scene content +
animation state + camera at ``t``), resolution, spp, max_depth, rr_depth,
seed, the Mitsuba version and variant, the sensor and its pixel filter
(:data:`SENSOR`, :data:`PIXEL_FILTER`) and a format number. Frames whose state is equal
(a static scene) share one entry. Writes go to a temporary file in the same
directory and are moved into place with ``os.replace`` (EXR first, then the
JSON that marks the entry complete; a reader needs both, with the JSON's key),
so an interrupted run never leaves a half-written entry and no reader ever sees
one. The directory may be shared by many processes and machines (a cluster's
workers; docs/cluster.md): a missing entry is rendered once, by the holder of
its lock file ``<entry>.lock`` (atomic create, heartbeat, stale-lock breaking:
:func:`get_or_render`); the others wait for it.

Chunks and clusters
-------------------
A render is a sequence of seeded passes of at most :data:`MAX_SPP_PER_PASS`
samples per pixel; pass i has seed ``mix_seed(seed, i)`` whoever renders it.
:func:`render_passes` renders a contiguous range of them (a chunk) and
:func:`merge_chunks` merges chunks by sample count into the image the serial
render gives. :func:`reference_job` fills the cache for many frames on an
executor (:mod:`~dyngi.experiments.cluster`): one task per chunk of every
missing entry, merged and stored by the caller as soon as an entry's chunks
are in (a lost worker loses its chunk only; the executor retries it).

Note: rendering a reference calls ``scene.at(t)``; the scene stays at ``t``.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import numbers
import os
import re
import socket
import threading
import time
import uuid
from pathlib import Path

import numpy as np

from ..backend import mi
from ..errors import DyngiError
from ..sampling.rng import mix_seed
from .io import read_exr, write_exr

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


# -- settings and keys --------------------------------------------------------

def default_cache_dir() -> Path:
    """``$DYNGI_CACHE/reference``, else ``$XDG_CACHE_HOME/dyngi/reference``, else ``~/.cache/dyngi/reference``."""
    root = os.environ.get("DYNGI_CACHE")
    if root:
        return Path(root).expanduser() / "reference"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "dyngi" / "reference"


def _check_time_res(t, res, what: str = "reference") -> tuple[int, int]:
    """Validate a reference's time and (width, height); ``what`` names the kind in the error."""
    if not (isinstance(t, numbers.Real) and np.isfinite(t)):
        raise DyngiError(f"{what} time must be a finite number, got {t!r}")
    try:
        w, h = (int(v) for v in res)
        ok = all(float(v) == int(v) for v in res)
    except (TypeError, ValueError):
        raise DyngiError(f"{what} resolution must be (width, height), got {res!r}") from None
    if not ok or w < 1 or h < 1:
        raise DyngiError(f"{what} resolution must be two positive integers (width, height), got {res!r}")
    return (w, h)


def _check_seed(seed, what: str = "reference") -> None:
    if not (isinstance(seed, numbers.Integral) and 0 <= seed < 2 ** 32):
        raise DyngiError(f"{what} seed must be an integer in [0, 2^32), got {seed!r}")


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


def reference_key(settings: dict) -> str:
    """Hex key of a settings dict (order independent)."""
    blob = json.dumps(settings, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:20]


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name or "scene")[:48]


def _entry_paths(scene, settings: dict, cache_dir=None, kind: str = "") -> tuple[Path, Path]:
    """(exr, json) paths ``<dir>/<scene>-[<kind>-]<key>.{exr,json}`` of a cache entry."""
    d = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    base = f"{_slug(scene.name)}-{kind + '-' if kind else ''}{reference_key(settings)}"
    return d / f"{base}.exr", d / f"{base}.json"


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

def _load_entry(exr: Path, js: Path, key: str, res, meta_ok=None) -> tuple[np.ndarray, dict] | None:
    """(image, metadata) of a cache entry, or None when absent, incomplete or inconsistent.

    ``meta_ok``: optional predicate on the metadata; an entry it rejects counts as absent.
    """
    if not (exr.is_file() and js.is_file()):
        return None
    try:
        meta = json.loads(js.read_text())
        if meta.get("key") != key or (meta_ok is not None and not meta_ok(meta)):
            return None
        img = read_exr(str(exr))
    except Exception:  # corrupt entry: re-render and overwrite
        return None
    w, h = res
    if img.shape != (h, w, 3) or not np.all(np.isfinite(img)):
        return None
    return img, meta


def _load(exr: Path, js: Path, key: str, res) -> np.ndarray | None:
    """The cached image, or None when absent, incomplete or inconsistent."""
    hit = _load_entry(exr, js, key, res)
    return None if hit is None else hit[0]


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _store(exr: Path, js: Path, img: np.ndarray, meta: dict) -> None:
    try:
        exr.parent.mkdir(parents=True, exist_ok=True)
        _atomic_write(exr, lambda p: write_exr(str(p), img))
        _atomic_write(js, lambda p: p.write_text(json.dumps(meta, indent=1, sort_keys=True)))
    except OSError as e:
        raise DyngiError(f"cannot write the reference cache in '{exr.parent}': {e.strerror or e}") from None


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


# -- shared-cache lock ---------------------------------------------------------------------------------
# The cache directory may be shared by many processes and machines (a cluster's workers, two jobs at
# once). Entries are complete or absent (atomic renames above); what the lock adds is that a missing
# entry is rendered once: the renderer holds ``<entry>.lock``, created atomically (O_CREAT | O_EXCL, which
# NFSv3+ honours), refreshed every LOCK_HEARTBEAT_SECONDS while it renders and removed after the entry
# is stored; the others wait for the entry. A lock is stale -- its holder died -- when its holder was on
# this host and its process is gone, or when it has not been refreshed for LOCK_STALE_SECONDS; a waiter
# then breaks it (serialised by a second lock file, ``<entry>.lock.break``) and renders the entry itself.

LOCK_STALE_SECONDS = 120.0
"""A lock not refreshed for this long is stale (``$DYNGI_LOCK_STALE`` overrides; keep it well above the
heartbeat and above the clock skew between machines sharing the cache)."""
LOCK_HEARTBEAT_SECONDS = 10.0
LOCK_POLL_SECONDS = 0.2
_HOST = socket.gethostname()


def _stale_seconds() -> float:
    try:
        return float(os.environ.get("DYNGI_LOCK_STALE", LOCK_STALE_SECONDS))
    except ValueError:
        raise DyngiError(f"DYNGI_LOCK_STALE must be a number of seconds, got '{os.environ['DYNGI_LOCK_STALE']}'")


class EntryLock:
    """The lock of one cache entry (see the section comment); :meth:`acquire` never blocks."""

    _held: dict = {}
    _guard = threading.Lock()
    _thread = None

    def __init__(self, exr: Path):
        self.path = exr.with_name(exr.stem + ".lock")
        self.token = f"{_HOST}:{os.getpid()}:{uuid.uuid4().hex[:12]}"
        self.held = False

    def acquire(self) -> bool:
        """True when this caller now holds the lock; False when someone else does."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise DyngiError(f"cannot write the reference cache in '{self.path.parent}': {e.strerror or e}") from None
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        except OSError as e:
            raise DyngiError(f"cannot write the reference cache in '{self.path.parent}': {e.strerror or e}") from None
        with os.fdopen(fd, "w") as f:
            json.dump({"host": _HOST, "pid": os.getpid(), "token": self.token,
                       "created": time.strftime("%Y-%m-%dT%H:%M:%S")}, f)
        self.held = True
        with EntryLock._guard:
            EntryLock._held[self.token] = self.path
            if EntryLock._thread is None or not EntryLock._thread.is_alive():
                EntryLock._thread = threading.Thread(target=EntryLock._heartbeat, name="dyngi-cache-lock",
                                                     daemon=True)
                EntryLock._thread.start()
        return True

    def release(self) -> None:
        if not self.held:
            return
        self.held = False
        with EntryLock._guard:
            EntryLock._held.pop(self.token, None)
        if _lock_info(self.path).get("token") == self.token:     # still ours (not broken as stale)
            with contextlib.suppress(OSError):
                self.path.unlink()

    def stale(self) -> bool:
        return lock_is_stale(self.path)

    def break_if_stale(self) -> bool:
        return break_stale_lock(self.path)

    @staticmethod
    def _heartbeat():
        while True:
            time.sleep(LOCK_HEARTBEAT_SECONDS)
            with EntryLock._guard:
                paths = list(EntryLock._held.values())
            for p in paths:
                with contextlib.suppress(OSError):
                    os.utime(p)


def _lock_info(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _pid_alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError, TypeError):
        return True
    return True


def lock_is_stale(path: Path) -> bool:
    """True when the lock at ``path`` exists and its holder is gone (see the section comment)."""
    try:
        age = time.time() - path.stat().st_mtime
    except FileNotFoundError:
        return False
    info = _lock_info(path)
    if info.get("host") == _HOST and "pid" in info and not _pid_alive(info["pid"]):
        return True
    return age > _stale_seconds()


def break_stale_lock(path: Path) -> bool:
    """Remove the lock at ``path`` if it is stale; True when this call removed it. Breakers take turns
    through ``<lock>.break`` so that a lock taken afresh after a break is never removed."""
    breaker = path.with_name(path.name + ".break")
    try:
        fd = os.open(breaker, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        with contextlib.suppress(OSError):      # a breaker that died in its few lines below
            if time.time() - breaker.stat().st_mtime > 30.0:
                breaker.unlink()
        return False
    except OSError:
        return False
    os.close(fd)
    try:
        if lock_is_stale(path):
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                return True
        return False
    finally:
        with contextlib.suppress(OSError):
            breaker.unlink()


def get_or_render(exr: Path, js: Path, key: str, res, render, meta_ok=None) -> tuple[tuple[np.ndarray, dict], bool]:
    """((image, metadata), was_cached) of a cache entry: loaded, or rendered by ``render() -> (image, meta)``
    and stored, under the entry's lock, so that concurrent callers render it once."""
    lock = EntryLock(exr)
    while True:
        hit = _load_entry(exr, js, key, res, meta_ok)
        if hit is not None:
            return hit, True
        if lock.acquire():
            break
        if not lock.break_if_stale():
            time.sleep(LOCK_POLL_SECONDS)
    try:
        hit = _load_entry(exr, js, key, res, meta_ok)     # stored while we were taking the lock
        if hit is not None:
            return hit, True
        img, meta = render()
        _store(exr, js, img, meta)
        return (img, meta), False
    finally:
        lock.release()


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
    from ..metrics import RELMSE_EPS

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


# -- many frames on an executor (a cluster) -----------------------------------------------------------

def _chunk_task(source, t: float, res, spp: int, max_depth: int, seed: int, start: int, stop: int) -> dict:
    """One chunk of one reference entry (runs on a worker): ``{'state', 'sum', 'seconds'}``; ``source`` is a
    live Scene (in-process executors) or a :class:`~dyngi.experiments.cluster.SceneRef`."""
    from .cluster import SceneRef

    scene = source.load_shared() if isinstance(source, SceneRef) else source
    t0 = time.perf_counter()
    acc = render_passes(scene, t, tuple(res), spp, max_depth, seed, start, stop)
    return {"state": scene.state_hash(float(t)), "sum": acc, "seconds": time.perf_counter() - t0}


def _indirect_task(source, t: float, res, spp: int, max_depth: int, cache_dir: str) -> bool:
    """The indirect-only reference of one frame (runs on a worker, caches it itself); True when cached."""
    from .cluster import SceneRef
    from .indirect_reference import cached_indirect_reference

    scene = source.load_shared() if isinstance(source, SceneRef) else source
    return cached_indirect_reference(scene, t, tuple(res), spp, max_depth, cache_dir=cache_dir)[2]


def reference_job(scene, frames, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                  executor=None, halves: bool = True, seed: int = 0, chunks: int | None = None, cache_dir=None,
                  progress=None, indirect: bool = False, source=None, path: bool = True) -> list[dict]:
    """Fill the cache with the references of ``frames`` on ``executor``; one record per frame.

    Like :func:`fill_reference_cache` (``frames``, ``halves``, records ``{'frame', 'time', 'key', 'path',
    'cached'}``), but every missing entry becomes ``chunks`` tasks (:func:`chunk_ranges`; default: enough
    to give every worker about two tasks, at most one per pass) that the executor runs where it runs them;
    their sums are merged here (:func:`merge_chunks`, equal to the serial render) and the entry stored as
    soon as its last chunk is in. This process holds the entry's lock meanwhile, so another job that needs
    the entry waits instead of rendering it too; entries another job holds are awaited at the end.
    ``indirect``: also dyngi's indirect-only reference of every frame (one task per frame,
    :func:`~dyngi.experiments.indirect_reference.cached_indirect_reference`); ``path=False``: that one only. ``source``: how workers load
    the scene (default :func:`~dyngi.experiments.cluster.scene_ref` of ``scene``). Failed tasks (after the
    executor's retries) are in ``executor.failures``; their frames' records have ``'failed': True``.
    """
    from .cluster import Task, current, failed, scene_ref

    ex = executor if executor is not None else current()
    if isinstance(frames, numbers.Integral):
        if frames < 1:
            raise DyngiError(f"number of reference frames must be >= 1, got {frames}")
        frames = range(int(frames))
    frames = list(frames)
    for i in frames:
        if not (isinstance(i, numbers.Integral) and i >= 0):
            raise DyngiError(f"frame indices must be non-negative integers, got {i!r}")
    if chunks is not None and not (isinstance(chunks, numbers.Integral) and chunks >= 1):
        raise DyngiError(f"--chunks must be a positive integer, got {chunks!r}")
    cdir = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    src = scene if ex.in_process else (source if source is not None else scene_ref(scene))
    res = _check_time_res(0.0, res)
    parts = list(zip(half_spp(spp), (0, 1))) if halves else [(int(spp), int(seed))]
    if not path:      # the indirect-only references alone
        parts = []

    # -- what each frame needs; missing entries taken (locked) or left to whoever holds them --
    entries, per_frame, held, awaited = {}, [], [], []
    for i in frames:
        t = scene.frame_time(int(i))
        keys = []
        for n, sd in parts:
            st = reference_settings(scene, t, res, n, max_depth, sd)
            key = reference_key(st)
            keys.append(key)
            if key in entries:
                continue
            exr, js = reference_paths(scene, st, cdir)
            e = {"key": key, "settings": st, "exr": exr, "js": js, "t": t, "spp": n, "seed": sd, "frame": int(i),
                 "cached": _load_entry(exr, js, key, st["res"]) is not None, "done": False, "sums": {}}
            entries[key] = e
            if not e["cached"]:
                e["lock"] = EntryLock(exr)
                (held if e["lock"].acquire() else awaited).append(e)
        per_frame.append((int(i), t, keys))
    try:
        if chunks is None:
            chunks = 1 if ex.workers <= 1 or not held else -(-2 * ex.workers // len(held))
        tasks, owner = [], []
        for e in held:
            rngs = chunk_ranges(res, e["spp"], chunks)
            e["n_chunks"] = len(rngs)
            for j, (a, b) in enumerate(rngs):
                tasks.append(Task(f"reference {scene.name} frame {e['frame']} seed {e['seed']} "
                                  f"chunk {j + 1}/{len(rngs)}", _chunk_task,
                                  (src, e["t"], res, e["spp"], max_depth, e["seed"], a, b)))
                owner.append((e, j))
        ind_tasks = []
        if indirect:
            for i, t, _ in per_frame:
                ind_tasks.append(Task(f"indirect reference {scene.name} frame {i}", _indirect_task,
                                      (src, t, res, spp, max_depth, str(cdir))))
        if progress is not None:
            progress.add(len(tasks) + len(ind_tasks) + len(awaited))

        def on_chunk(k, val):
            e, j = owner[k]
            if val["state"] != e["settings"]["state"]:
                raise DyngiError(f"a worker's scene '{scene.name}' at t = {e['t']:g} differs from this one "
                                 "(another version of the scene file or of dyngi on that machine?)")
            e["sums"][j] = val
            if len(e["sums"]) == e["n_chunks"]:
                got = [e["sums"][c] for c in range(e["n_chunks"])]
                img = merge_chunks([g["sum"] for g in got], e["spp"])
                seconds = sum(g["seconds"] for g in got)
                _store(e["exr"], e["js"], img, entry_meta(e["settings"], e["key"], scene.name, e["t"], seconds,
                                                          chunks=e["n_chunks"]))
                e["done"] = True
                e["sums"] = {}
                e["lock"].release()
        outcomes = ex.map(tasks + ind_tasks, on_done=lambda k, v: on_chunk(k, v) if k < len(tasks) else None,
                          progress=progress)
    finally:
        for e in held:
            e["lock"].release()
    ind_failed = {per_frame[k][0] for k, o in enumerate(outcomes[len(tasks):]) if failed(o)}
    # -- entries another job was rendering: wait for them (rendered here if that job died) --
    for e in awaited:
        st, sc_t = e["settings"], e["t"]

        def render(e=e, st=st, sc_t=sc_t):
            t0 = time.perf_counter()
            img = _render(scene, sc_t, res, e["spp"], max_depth, e["seed"])
            return img, entry_meta(st, e["key"], scene.name, sc_t, time.perf_counter() - t0)
        get_or_render(e["exr"], e["js"], e["key"], st["res"], render)
        e["done"] = True
        if progress is not None:
            progress.task_done()
    out = []
    for i, t, keys in per_frame:
        es = [entries[k] for k in keys]
        first = es[0] if es else {"key": None, "exr": None}
        out.append({"frame": i, "time": float(t), "key": first["key"],
                    "path": str(first["exr"]) if first["exr"] is not None else None,
                    "cached": all(e["cached"] for e in es),
                    "failed": any(not (e["cached"] or e["done"]) for e in es) or i in ind_failed})
    return out


def estimate_reference_noise(scene, t: float, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                             indirect: bool = False, cache_dir=None) -> dict:
    """Error of one reference against the truth, estimated from two independent seeds (0 and 1).

    For independent unbiased a, b: E(a - b)^2 = 2 Var, so ``relmse(a, b) / 2``
    and ``mse(a, b) / 2`` estimate the reference's own relMSE and MSE (the
    relMSE denominator uses the noisy b instead of the truth: fine while the
    noise is small). Both renders are cached like any reference.
    """
    from ..metrics import mse, relmse

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
