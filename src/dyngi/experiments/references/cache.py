"""Cache of reference images on disk: keys, directory, atomic entries and the lock that renders a missing
entry once.

Directory: argument ``cache_dir``, else ``$DYNGI_CACHE/reference``, else
``$XDG_CACHE_HOME/dyngi/reference`` (default ``~/.cache/dyngi/reference``).
An entry is ``<scene>-<key>.exr`` (float32 RGB, lossless) plus
``<scene>-<key>.json`` (the settings, for humans and for a consistency check
on load). The key hashes: ``scene.state_hash(t)`` (scene content +
animation state + camera at ``t``), resolution, spp, max_depth, rr_depth,
seed, the Mitsuba version and variant, the sensor and its pixel filter
(:data:`~dyngi.experiments.references.path.SENSOR`, :data:`~dyngi.experiments.references.path.PIXEL_FILTER`)
and a format number. Frames whose state is equal
(a static scene) share one entry. Writes go to a temporary file in the same
directory and are moved into place with ``os.replace`` (EXR first, then the
JSON that marks the entry complete; a reader needs both, with the JSON's key),
so an interrupted run never leaves a half-written entry and no reader ever sees
one. The directory may be shared by many processes and machines (a cluster's
workers; docs/cluster.md): a missing entry is rendered once, by the holder of
its lock file ``<entry>.lock`` (atomic create, heartbeat, stale-lock breaking:
:func:`get_or_render`); the others wait for it.
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

from ...errors import DyngiError
from ..io import read_exr, write_exr


# -- directory, checks and keys --------------------------------------------------------------------

def default_cache_dir() -> Path:
    """``$DYNGI_CACHE/reference``, else ``$XDG_CACHE_HOME/dyngi/reference``, else ``~/.cache/dyngi/reference``."""
    root = os.environ.get("DYNGI_CACHE")
    if root:
        return Path(root).expanduser() / "reference"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "dyngi" / "reference"


def cached_npy(path: Path, shape, compute) -> np.ndarray:
    """``compute()`` as float32, kept at ``path`` (a small ``.npy``): read back when it is there with ``shape``,
    else computed and written atomically; an unwritable cache only costs the recomputation."""
    if path.exists():
        try:
            v = np.load(path)
            if v.shape == tuple(shape):
                return v.astype(np.float32)
        except (OSError, ValueError):
            pass
    v = np.asarray(compute(), np.float32)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.parent / f".{path.stem}.{os.getpid()}.npy"
        np.save(tmp, v)
        os.replace(tmp, path)
    except OSError:
        pass
    return v


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


# -- entries --------------------------------------------------------------------------------------

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
