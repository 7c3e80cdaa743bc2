"""Many frames' references on an executor (a cluster): one task per chunk of every missing cache entry.

:func:`reference_job` splits each missing entry of :mod:`~dyngi.experiments.references.path` into chunks of
seeded passes (:func:`~dyngi.experiments.references.path.render_passes`), runs them as tasks of an executor
(:mod:`~dyngi.experiments.cluster`) and merges and stores each entry as soon as its chunks are in (a lost
worker loses its chunk only; the executor retries it). The references know nothing of executors: this
module imports both.
"""
from __future__ import annotations

import numbers
import time
from pathlib import Path

from ..errors import DyngiError
from .cluster import SceneRef, Task, current, failed, scene_ref
from .references.cache import (EntryLock, _check_time_res, _load_entry, _store, default_cache_dir, get_or_render,
                               reference_key)
from .references.indirect import cached_indirect_reference
from .references.path import (DEFAULT_MAX_DEPTH, DEFAULT_REF_SPP, _render, chunk_ranges, entry_meta, half_spp,
                              merge_chunks, reference_paths, reference_settings, render_passes)


def _chunk_task(source, t: float, res, spp: int, max_depth: int, seed: int, start: int, stop: int) -> dict:
    """One chunk of one reference entry (runs on a worker): ``{'state', 'sum', 'seconds'}``; ``source`` is a
    live Scene (in-process executors) or a :class:`~dyngi.experiments.cluster.SceneRef`."""
    scene = source.load_shared() if isinstance(source, SceneRef) else source
    t0 = time.perf_counter()
    acc = render_passes(scene, t, tuple(res), spp, max_depth, seed, start, stop)
    return {"state": scene.state_hash(float(t)), "sum": acc, "seconds": time.perf_counter() - t0}


def _indirect_task(source, t: float, res, spp: int, max_depth: int, cache_dir: str) -> bool:
    """The indirect-only reference of one frame (runs on a worker, caches it itself); True when cached."""
    scene = source.load_shared() if isinstance(source, SceneRef) else source
    return cached_indirect_reference(scene, t, tuple(res), spp, max_depth, cache_dir=cache_dir)[2]


def reference_job(scene, frames, res, spp: int = DEFAULT_REF_SPP, max_depth: int = DEFAULT_MAX_DEPTH,
                  executor=None, halves: bool = True, seed: int = 0, chunks: int | None = None, cache_dir=None,
                  progress=None, indirect: bool = False, source=None, path: bool = True) -> list[dict]:
    """Fill the cache with the references of ``frames`` on ``executor``; one record per frame.

    Like :func:`~dyngi.experiments.references.path.fill_reference_cache` (``frames``, ``halves``, records
    ``{'frame', 'time', 'key', 'path', 'cached'}``), but every missing entry becomes ``chunks`` tasks
    (:func:`~dyngi.experiments.references.path.chunk_ranges`; default: enough to give every worker about two
    tasks, at most one per pass) that the executor runs where it runs them; their sums are merged here
    (:func:`~dyngi.experiments.references.path.merge_chunks`, equal to the serial render) and the entry stored
    as soon as its last chunk is in. This process holds the entry's lock meanwhile, so another job that needs
    the entry waits instead of rendering it too; entries another job holds are awaited at the end.
    ``indirect``: also dyngi's indirect-only reference of every frame (one task per frame,
    :func:`~dyngi.experiments.references.indirect.cached_indirect_reference`); ``path=False``: that one only.
    ``source``: how workers load the scene (default :func:`~dyngi.experiments.cluster.scene_ref` of
    ``scene``). Failed tasks (after the executor's retries) are in ``executor.failures``; their frames'
    records have ``'failed': True``.
    """
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
