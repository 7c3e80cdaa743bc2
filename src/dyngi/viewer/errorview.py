"""The error view: HDR-FLIP of the viewer's frames against a reference, both computed at low priority.

A reference at the viewer's camera and time is Mitsuba's ``path`` integrator through
:func:`dyngi.experiments.references.path.cached_reference` (the same disk cache as ``dyngi compare``), and
the error is :func:`dyngi.metrics.hdrflip.flip`. Both run in a child process (``python -m
dyngi.viewer.errorview``) started at ``nice 19``, because

* a thread would share Dr.Jit's thread pool, and with it the CPU, equally with the technique's frames
  (measured: a 256-spp reference at 320x180 takes ~13 s of both cores), while a niced process yields
  the cores to the viewer's own renders and takes them when the view holds still;
* HDR-FLIP at 320x180 takes ~1.5 s of CPU in one call; in the server's process it would hold the
  interpreter and the page would stall.

Protocol: one JSON job per line on the child's stdin, ``{"id", "t", "origin", "target", "up", "fov",
"res", "spp", "max_depth", "frames": {slot: "x.npy"}, "out": dir}``; the child answers JSON lines on
stdout prefixed ``DYNGI-ERRORVIEW`` (``{"id", "stage": "reference"|"flip"}`` when a stage starts, then
``{"id", "flip": {slot: mean}, "maps": {slot: "map.npy"}, "ref_cached", "ref_seconds"}`` or ``{"id",
"error"}``) and exits when its stdin closes. :class:`ErrorViewWorker` is the parent side: one job in
the child at a time, the newest waiting job replaces an older waiting one, and a job whose reference is
still rendering for a view that changed meanwhile is abandoned by restarting the child.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from .. import backend
from ..experiments.references.path import cached_reference
from ..metrics.hdrflip import flip
from ..scene import load_scene
from ..scene.camera import Camera, CameraPath

TAG = "DYNGI-ERRORVIEW "


class ErrorViewWorker:
    """Parent side of the low-priority reference + FLIP process (see the module docstring)."""

    def __init__(self, scene_name: str, device: str, on_result, on_stage=None, cache_dir=None):
        self.scene_name = scene_name
        self.device = device
        self.on_result = on_result          # fn(job dict, result dict)
        self.on_stage = on_stage            # fn(job dict, stage str)
        self.tmp = tempfile.mkdtemp(prefix="dyngi-view-")
        self.cache_dir = cache_dir
        self._lock = threading.Lock()
        self._proc: subprocess.Popen | None = None
        self._reader: threading.Thread | None = None
        self._current: dict | None = None
        self._stage: str | None = None
        self._pending: dict | None = None
        self._next_id = 0
        self._closed = False

    # -- child process ------------------------------------------------------------------------
    def _start(self) -> None:
        env = dict(os.environ)
        if self.cache_dir is not None:
            env["DYNGI_CACHE"] = str(self.cache_dir)
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "dyngi.viewer.errorview", self.scene_name, self.device],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1,
            env=env, start_new_session=True)
        self._reader = threading.Thread(target=self._read, args=(self._proc,), name="dyngi-errorview-reader",
                                        daemon=True)
        self._reader.start()

    def _kill(self) -> None:
        p, self._proc = self._proc, None
        if p is None:
            return
        try:
            p.stdin.close()
        except OSError:
            pass
        try:
            p.terminate()
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=5)
        except OSError:
            pass

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def _read(self, proc) -> None:
        for line in proc.stdout:
            if not line.startswith(TAG):
                continue
            try:
                msg = json.loads(line[len(TAG):])
            except ValueError:
                continue
            with self._lock:
                job = self._current
                if job is None or msg.get("id") != job["id"]:
                    continue
                if "stage" in msg:
                    self._stage = msg["stage"]
                else:
                    self._current, self._stage = None, None
            if "stage" in msg:
                if self.on_stage is not None:
                    self.on_stage(job, msg["stage"])
                continue
            self.on_result(job, msg)
            self._send_pending()
        # the child ended (killed on a restart, or crashed): a job it held gets an error
        with self._lock:
            job = self._current if self._proc is proc or self._proc is None else None
            if job is not None:
                self._current, self._stage = None, None
        if job is not None and not self._closed:
            self.on_result(job, {"id": job["id"], "error": "the reference process ended unexpectedly"})

    def _send_pending(self) -> None:
        with self._lock:
            if self._closed or self._current is not None or self._pending is None:
                return
            job, self._pending = self._pending, None
            if self._proc is None or self._proc.poll() is not None:
                self._start()
            self._current, self._stage = job, "queued"
            proc = self._proc
        try:
            proc.stdin.write(json.dumps(job["wire"]) + "\n")
            proc.stdin.flush()
        except OSError:
            with self._lock:
                self._current = None
            self.on_result(job, {"id": job["id"], "error": "could not reach the reference process"})

    # -- API ------------------------------------------------------------------------------------
    def submit(self, key, t: float, camera, res, spp: int, max_depth: int, frames: dict, info=None) -> None:
        """Queue FLIP of ``frames`` ({slot: H x W x 3}) against the reference of view ``key``."""
        if self._closed:
            return
        with self._lock:
            self._next_id += 1
            jid = self._next_id
        paths = {}
        for slot, img in frames.items():
            paths[slot] = os.path.join(self.tmp, f"job{jid}-{slot}.npy")
            np.save(paths[slot], np.ascontiguousarray(img, np.float32))
        wire = {"id": jid, "t": float(t), "origin": list(map(float, camera.origin)),
                "target": list(map(float, camera.target)), "up": list(map(float, camera.up)),
                "fov": float(camera.fov), "res": [int(res[0]), int(res[1])], "spp": int(spp),
                "max_depth": int(max_depth), "frames": paths, "out": self.tmp}
        job = {"id": jid, "key": key, "wire": wire, "info": info, "submitted": time.perf_counter()}
        restart = False
        with self._lock:
            old = self._pending
            self._pending = job
            cur = self._current
            if cur is not None and cur["key"] != key and self._stage in ("queued", "reference"):
                restart = True          # its reference is for a view the user has left
                self._current, self._stage = None, None
        if old is not None:
            self._cleanup(old)
        if restart:
            self._kill()
        self._send_pending()

    def busy(self) -> tuple[dict | None, str | None]:
        with self._lock:
            return self._current, self._stage

    def _cleanup(self, job) -> None:
        for p in job["wire"]["frames"].values():
            try:
                os.remove(p)
            except OSError:
                pass

    def close(self) -> None:
        self._closed = True
        self._kill()
        if self._reader is not None:
            self._reader.join(timeout=5)
        import shutil

        shutil.rmtree(self.tmp, ignore_errors=True)


# -- child ---------------------------------------------------------------------------------------

def _emit(msg: dict) -> None:
    sys.stdout.write(TAG + json.dumps(msg) + "\n")
    sys.stdout.flush()


def child_main(argv) -> int:
    """The child: ``python -m dyngi.viewer.errorview SCENE DEVICE``; jobs on stdin (module docstring)."""
    try:
        os.nice(19)
    except OSError:
        pass
    scene_name, device = argv[0], argv[1]
    backend.set_device(device)
    scene = load_scene(scene_name)
    for line in sys.stdin:
        try:
            job = json.loads(line)
        except ValueError:
            continue
        jid = job["id"]
        try:
            cam = Camera(tuple(job["origin"]), tuple(job["target"]), tuple(job["up"]), job["fov"])
            scene.camera_path = CameraPath.fixed(cam)     # the viewer's camera, also in the cache key
            _emit({"id": jid, "stage": "reference"})
            t0 = time.perf_counter()
            ref, cached = cached_reference(scene, job["t"], tuple(job["res"]), job["spp"], job["max_depth"])
            secs = time.perf_counter() - t0
            _emit({"id": jid, "stage": "flip"})
            means, maps = {}, {}
            for slot, path in job["frames"].items():
                img = np.load(path)
                os.remove(path)
                img = np.nan_to_num(np.maximum(img, 0.0), nan=0.0, posinf=0.0)
                m, emap = flip(img, ref, return_map=True)
                maps[slot] = os.path.join(job["out"], f"job{jid}-{slot}.flip.npy")
                np.save(maps[slot], np.asarray(emap, np.float32))
                means[slot] = float(m)
            _emit({"id": jid, "flip": means, "maps": maps, "ref_cached": bool(cached), "ref_seconds": secs})
        except Exception as e:  # noqa: BLE001  (reported to the page as one line)
            _emit({"id": jid, "error": f"{type(e).__name__}: {e}".splitlines()[0]})
    return 0


if __name__ == "__main__":
    sys.exit(child_main(sys.argv[1:]))
