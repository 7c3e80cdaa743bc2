"""The viewer's render loop: one worker thread steps the techniques frame by frame, as ``run_sequence`` does.

:class:`RenderSession` owns the scene, up to two techniques (slot ``a``, and ``b`` for the split view),
the animation clock, the interactive camera and the display settings. The server's event loop calls its
setters (thread-safe: a lock and a condition variable); the worker thread is the only one that touches
Dr.Jit: it creates the techniques, animates the scene (``scene.at``), builds each
:class:`~dyngi.techniques.base.Frame` (the viewer's camera, ``static`` when nothing moved since that
technique's previous frame, as :func:`dyngi.experiments.runner.run_sequence` decides it), calls
``step``, draws the overlay, tonemaps and JPEG-encodes the image and hands it, with the
:class:`~dyngi.techniques.base.FrameResult`'s per-stage milliseconds and rays, to ``publish``.

Clock: while playing, scene time advances by the wall time between frames (at most 0.25 s a frame, and
not at all across the first frame of a new technique, which compiles its kernels), looping over the
scene's duration. When nothing changes (paused, camera still, same settings) the loop renders
``still_frames`` more frames (progressive techniques keep converging) and then sleeps until a change,
leaving the CPU to the error view's reference (:mod:`dyngi.viewer.errorview`).

Errors never stop the loop: a bad spec is refused by :meth:`RenderSession.set_technique` before it
reaches the worker; a technique that fails to build or to render is reported with one line through
``publish('error', ...)``, a failed switch keeps the previous technique, a failed frame stops that slot
until the next change.
"""
from __future__ import annotations

import io
import math
import threading
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from ..errors import DyngiError
from ..experiments.io import tonemap_srgb
from ..experiments.references.path import scene_max_depth
from ..techniques.base import Frame, create_technique, get_technique, parse_spec, technique_names
from . import overlays
from .camera import ViewCamera
from .errorview import ErrorViewWorker

SLOTS = ("a", "b")
MAX_DT = 0.25


def one_line(e: BaseException) -> str:
    if isinstance(e, DyngiError):
        return str(e).splitlines()[0] if str(e) else "error"
    text = f"{type(e).__name__}: {e}".strip()
    return text.splitlines()[0]


def encode_jpeg(img_u8: np.ndarray, quality: int = 85) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img_u8)).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()


def _jsonable_stats(stats: dict) -> dict:
    """The numeric parts of ``FrameResult.stats`` (ms and rays per stage, scalars; one level of dicts)."""
    def num(v):
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        if isinstance(v, (int, np.integer)):
            return int(v)
        if isinstance(v, (float, np.floating)):
            f = float(v)
            return f if math.isfinite(f) else None
        return None

    out = {}
    for k, v in (stats or {}).items():
        if isinstance(v, dict):
            d = {str(k2): num(v2) for k2, v2 in v.items() if num(v2) is not None}
            if d:
                out[str(k)] = d
        elif num(v) is not None:
            out[str(k)] = num(v)
    return out


@dataclass
class Slot:
    spec: str = ""
    tech: object = None
    frames: int = 0              # frames this technique has rendered
    prev_sig: tuple | None = None
    failed: str | None = None    # one-line error of its last frame
    image: np.ndarray | None = None
    requested_at: float | None = None   # when the page asked for this technique (switch latency)
    first_frame_ms: float | None = None
    build_ms: float | None = None       # creating the technique (before its first frame)
    wall_ms: list = field(default_factory=list)
    sent: list = field(default_factory=list)   # perf_counter of recent frames (fps)


class RenderSession:
    """Scene + techniques + clock + camera, rendered by one worker thread (see the module docstring)."""

    def __init__(self, scene, specs: list[str], res: tuple[int, int], publish, device: str = "cpu",
                 ref_spp: int = 128, still_frames: int = 32, jpeg_quality: int = 85, seed: int = 0,
                 error_worker_factory=None):
        self.scene = scene
        self.res = (int(res[0]), int(res[1]))
        self.publish = publish
        self.device = device
        self.ref_spp = int(ref_spp)
        self.still_frames = int(still_frames)
        self.jpeg_quality = int(jpeg_quality)
        self.seed = int(seed)
        for s in specs:
            parse_spec(s)                 # bad specs fail here, on the command line
        self.specs = list(specs)          # the choices offered on the page
        self._cond = threading.Condition()
        self._stop = False
        self._dirty = True
        self._want = {"a": specs[0], "b": specs[1] if len(specs) > 1 else None}   # two specs: side by side
        self.slots = {"a": Slot(), "b": Slot()}
        self.playing = scene.is_animated
        self.t = 0.0
        self.speed = 1.0
        lo, hi = (np.asarray(x, np.float64) for x in scene.meta.bounds)
        self.view = ViewCamera(scene.camera(0.0), float(np.linalg.norm(hi - lo)))
        self.follow = True                # the camera follows the scene's camera path until moved
        self.overlay = "none"
        self.error_view = False
        self.exposure = 1.0
        self.busy: dict | None = None
        self.frame_counter = 0
        self.ready = threading.Event()
        self.startup_error: str | None = None
        self._error_worker_factory = error_worker_factory
        self._errview = None
        self._errview_key = None         # the view the error view is for now
        self._errview_ready = None       # the view whose reference is ready
        self._errview_last = None
        self.still = 0
        self._last_tick: float | None = None
        self._thread = threading.Thread(target=self._run, name="dyngi-view-render", daemon=True)

    # -- lifecycle --------------------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> bool:
        """Stop the worker (after the frame in flight) and the error-view process; True when all ended."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout)
        if self._errview is not None:
            self._errview.close()
        return not self._thread.is_alive()

    @property
    def thread(self) -> threading.Thread:
        return self._thread

    def _changed(self) -> None:
        self._dirty = True
        self.still = 0
        self._cond.notify_all()

    # -- setters (any thread) --------------------------------------------------------------------
    def set_technique(self, slot: str, spec: str | None) -> None:
        """Ask for technique ``spec`` in ``slot`` ('a', or 'b' = the split's right side; None/'' ends the split).

        A bad spec raises :class:`DyngiError` here; errors building it are published by the worker."""
        if slot not in SLOTS:
            raise DyngiError(f"unknown view slot '{slot}'; valid: a, b")
        spec = (spec or "").strip() or None
        if spec is None and slot == "a":
            raise DyngiError("empty technique spec; use NAME[:KEY=VALUE...], e.g. ddgi:hysteresis=0.9")
        if spec is not None:
            parse_spec(spec)
        with self._cond:
            self._want[slot] = spec
            self.slots[slot].requested_at = time.perf_counter()
            self._changed()

    def set_playing(self, playing: bool) -> None:
        with self._cond:
            self.playing = bool(playing)
            self._last_tick = None
            self._changed()

    def seek(self, t: float) -> None:
        t = float(t)
        if not math.isfinite(t):
            raise DyngiError(f"time must be a finite number of seconds, got {t}")
        with self._cond:
            self.t = self._wrap(t)
            self._last_tick = None
            self._changed()

    def camera(self, msg: dict) -> None:
        with self._cond:
            if msg.get("op") == "reset":
                self.follow = True
                self.view.set(self.scene.camera(self.t))
            else:
                if self.follow:
                    self.view.set(self.scene.camera(self.t))
                    self.follow = False
                try:
                    self.view.apply(msg)
                except (ValueError, KeyError, TypeError) as e:
                    raise DyngiError(f"bad camera move: {e}") from None
            self._changed()

    def set_overlay(self, name: str) -> None:
        if name not in overlays.OVERLAYS:
            raise DyngiError(f"unknown overlay '{name}'; valid overlays: {', '.join(overlays.OVERLAYS)}")
        with self._cond:
            self.overlay = name
            self._changed()

    def set_error_view(self, on: bool) -> None:
        with self._cond:
            self.error_view = bool(on)
            self._errview_last = None
            self._changed()

    def set_exposure(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and 0 < value < 1e6):
            raise DyngiError(f"exposure must be a positive number, got {value}")
        with self._cond:
            self.exposure = value
            self._changed()

    def state(self) -> dict:
        """What the page shows of the settings (sent on connect and after every change)."""
        with self._cond:
            a, b = self.slots["a"], self.slots["b"]
            cam = self.view.camera() if not self.follow else self.scene.camera(self.t)
            return {
                "type": "state", "scene": self.scene.name, "res": list(self.res),
                "duration": float(self.scene.duration), "fps": float(self.scene.fps),
                "animated": bool(self.scene.is_animated), "playing": self.playing, "t": self.t,
                "spec_a": a.spec or self._want["a"], "spec_b": self._want["b"],
                "want_a": self._want["a"], "want_b": self._want["b"],
                "choices": self.specs, "techniques": technique_names(),
                "params": self._params(a.spec or self._want["a"]),
                "overlay": self.overlay, "overlays": overlays.available(a.tech),
                "error_view": self.error_view, "exposure": self.exposure, "follow": self.follow,
                "camera": {"origin": list(map(float, cam.origin)), "target": list(map(float, cam.target)),
                           "fov": float(cam.fov)},
                "ref_spp": self.ref_spp,
            }

    @staticmethod
    def _params(spec: str | None) -> list[dict]:
        """The technique's parameters with their values in ``spec`` (for the page's parameter panel)."""
        if not spec:
            return []
        try:
            s = parse_spec(spec)
        except DyngiError:
            return []

        out = []
        for k, p in get_technique(s.name).PARAMS.items():
            v = s.params.get(k, p.default)
            out.append({"name": k, "value": v if isinstance(v, (bool, int, float, str)) else str(v),
                        "default": p.default if isinstance(p.default, (bool, int, float, str)) else str(p.default),
                        "doc": p.doc, "choices": list(p.choices) if p.choices else None,
                        "type": type(p.default).__name__})
        return out

    # -- worker ------------------------------------------------------------------------------------
    def _wrap(self, t: float) -> float:
        d = float(self.scene.duration)
        if d <= 0:
            return max(t, 0.0)
        return t % d if (t < 0 or t > d) else t

    def _run(self) -> None:
        try:
            self._sync_techniques()
            if self.slots["a"].tech is None:
                raise DyngiError(self.startup_error or "the technique could not be built")
        except Exception as e:  # noqa: BLE001
            self.startup_error = self.startup_error or one_line(e)
            self.ready.set()
            return
        self.ready.set()
        self.publish("state", self.state())
        while True:
            with self._cond:
                while not self._stop and not self._dirty and self.still >= self.still_frames:
                    self._cond.wait(0.5)
                if self._stop:
                    return
                self._dirty = False
            try:
                self._frame()
            except Exception as e:  # noqa: BLE001  (never let the loop die)
                self.publish("error", {"message": "viewer: " + one_line(e), "detail": traceback.format_exc()})
                with self._cond:
                    self.still = self.still_frames       # wait for the next change
            finally:
                self.busy = None

    def _build(self, slot: str, spec: str):
        s = parse_spec(spec)
        self.busy = {"slot": slot, "spec": spec, "what": "building", "since": time.perf_counter(),
                     "expected_ms": None, "frame": 0}
        tech = create_technique(s.name, self.scene, s.params)
        overlays.capture_vpls(tech)
        return tech

    def _sync_techniques(self) -> bool:
        """Build the techniques the page asked for; True when a slot changed."""
        changed = False
        for slot in SLOTS:
            with self._cond:
                want = self._want[slot]
            cur = self.slots[slot]
            if want == cur.spec or (want is None and cur.tech is None and not cur.spec):
                continue
            changed = True
            if want is None:
                self.slots[slot] = Slot()
                continue
            b0 = time.perf_counter()
            try:
                tech = self._build(slot, want)
            except Exception as e:  # noqa: BLE001
                msg = f"technique '{want}': {one_line(e)}"
                if not self.ready.is_set():
                    self.startup_error = msg
                    raise DyngiError(msg) from None
                self.publish("error", {"message": msg})
                with self._cond:
                    if self._want[slot] == want:
                        self._want[slot] = cur.spec or None
                continue
            finally:
                self.busy = None
            self.slots[slot] = Slot(spec=want, tech=tech, requested_at=cur.requested_at or time.perf_counter(),
                                    build_ms=1e3 * (time.perf_counter() - b0))
        if changed:
            self._last_tick = None
            self.publish("state", self.state())
        return changed

    def _frame(self) -> None:
        switched = self._sync_techniques()
        with self._cond:
            now = time.perf_counter()
            new_tech = switched or any(s.tech is not None and s.frames == 0 for s in self.slots.values())
            if self.playing and self.scene.is_animated:
                if self._last_tick is not None and not new_tech:
                    self.t = self._wrap(self.t + min(now - self._last_tick, MAX_DT) * self.speed)
                self._last_tick = now
            t = self.t
            if self.follow:
                self.view.set(self.scene.camera(t))
            cam = self.view.camera()
            overlay, exposure, error_view = self.overlay, self.exposure, self.error_view
        self.scene.at(t)
        sig = self.scene.signature(t)[:-1] + (cam.signature(),)
        self.frame_counter += 1
        active = [(name, s) for name, s in self.slots.items() if s.tech is not None and not s.failed]
        all_static = True
        republish = False
        for name, s in active:
            static = sig == s.prev_sig
            all_static &= static
            frame = Frame(index=s.frames, time=t, camera=cam, res=self.res, seed=self.seed, static=static)
            self.busy = {"slot": name, "spec": s.spec, "what": "compiling" if s.frames == 0 else "rendering",
                         "since": time.perf_counter(), "frame": s.frames,
                         "expected_ms": float(np.median(s.wall_ms[-5:])) if s.wall_ms else None}
            w0 = time.perf_counter()
            try:
                r = s.tech.step(frame)
            except Exception as e:  # noqa: BLE001
                s.failed = one_line(e)
                self.publish("error", {"message": f"technique '{s.spec}' failed on frame {s.frames}: {s.failed}",
                                       "detail": traceback.format_exc()})
                continue
            finally:
                self.busy = None
            wall = 1e3 * (time.perf_counter() - w0)
            s.prev_sig = sig
            s.frames += 1
            s.wall_ms = (s.wall_ms + [wall])[-30:]
            s.image = r.image

            e0 = time.perf_counter()
            u8 = tonemap_srgb(np.nan_to_num(r.image, nan=0.0, posinf=0.0, neginf=0.0), exposure)
            ov_ms = 0.0
            if overlay != "none" and overlay in overlays.available(s.tech):
                o0 = time.perf_counter()
                u8 = overlays.draw(overlay, s.tech, self.scene, cam, self.res, u8, exposure)
                ov_ms = 1e3 * (time.perf_counter() - o0)
            jpeg = encode_jpeg(u8, self.jpeg_quality)
            now = time.perf_counter()
            encode_ms = 1e3 * (now - e0) - ov_ms      # tonemap + JPEG: the viewer's own cost per frame
            s.sent = [x for x in s.sent[-29:] if now - x < 3.0] + [now]
            fps = (len(s.sent) - 1) / (s.sent[-1] - s.sent[0]) if len(s.sent) > 2 else None
            switch_ms = None
            if s.frames == 1:
                s.first_frame_ms = wall
                republish = True      # overlays a technique builds on its first frame (an octree)
                if s.requested_at is not None:
                    switch_ms = 1e3 * (now - s.requested_at)
            nonfinite = int(np.sum(~np.isfinite(r.image)))
            header = {"slot": name, "spec": s.spec, "frame": s.frames - 1, "t": t, "seq": self.frame_counter,
                      "w": self.res[0], "h": self.res[1]}
            self.publish("frame", (header, jpeg))
            self.publish("stats", {"type": "stats", "slot": name, "spec": s.spec, "frame": s.frames - 1, "t": t,
                                   "static": static, "wall_ms": wall, "overlay_ms": ov_ms, "encode_ms": encode_ms, "fps": fps,
                                   "first_frame_ms": s.first_frame_ms, "build_ms": s.build_ms,
                                   "switch_ms": switch_ms,
                                   "nonfinite_pixels": nonfinite, "playing": self.playing,
                                   "stats": _jsonable_stats(r.stats)})
        if republish:
            self.publish("state", self.state())
        with self._cond:
            if all_static and active and not self._dirty:
                self.still += 1
            elif not self._dirty:
                self.still = 0
        if error_view:
            self._error_view(t, cam, all_static and bool(active))

    # -- error view ----------------------------------------------------------------------------
    def _error_view(self, t, cam, still: bool) -> None:
        if not still:
            self._errview_status("moving", "hold the view still (pause, stop moving) for the error view")
            return
        key = (round(float(t), 9), cam.signature(), self.res, self.ref_spp)
        self._errview_key = key
        if self._errview is None:
            factory = self._error_worker_factory or self._default_error_worker
            self._errview = factory()
        cur, _ = self._errview.busy()
        if cur is not None and cur["key"] == key:
            return                     # one FLIP at a time; the newest frame goes next time
        frames = {name: s.image for name, s in self.slots.items()
                  if s.tech is not None and not s.failed and s.image is not None}
        if not frames:
            return
        self._errview.submit(key, t, cam, self.res, self.ref_spp, scene_max_depth(self.scene), frames,
                             info={"frame": {n: self.slots[n].frames - 1 for n in frames},
                                   "specs": {n: self.slots[n].spec for n in frames}})
        if self._errview_ready != key:
            self._errview_status("working", f"waiting for the reference ({self.ref_spp} spp) at low priority")

    def _errview_status(self, state: str, text: str, **extra) -> None:
        """Publish the error view's state when it changed (and every result)."""
        if state != "ready" and (state, text) == self._errview_last:
            return
        self._errview_last = (state, text)
        if state == "moving":
            self._errview_ready = self._errview_key = None
        self.publish("errorview", {"type": "errorview", "state": state, "text": text, **extra})

    def _default_error_worker(self):
        src = getattr(self.scene, "source", "builtin")
        name = self.scene.name if src == "builtin" else src
        return ErrorViewWorker(name, self.device, on_result=self._on_error_result, on_stage=self._on_error_stage)

    def _on_error_stage(self, job, stage) -> None:
        if stage == "reference" and job["key"] != self._errview_ready and job["key"] == self._errview_key:
            self._errview_status("working", f"rendering the reference ({self.ref_spp} spp) at low priority "
                                            "(cached on disk), then HDR-FLIP")

    def _on_error_result(self, job, res) -> None:
        if job["key"] != self._errview_key:
            return                      # the view has moved on
        if "error" in res:
            self._errview_status("error", "error view: " + res["error"])
            return
        self._errview_ready = job["key"]
        import matplotlib

        cmap = matplotlib.colormaps["magma"]
        for slot, path in res.get("maps", {}).items():
            try:
                emap = np.load(path)
                import os

                os.remove(path)
            except OSError:
                continue
            u8 = (cmap(np.clip(emap, 0.0, 1.0))[..., :3] * 255.0 + 0.5).astype(np.uint8)
            header = {"slot": "err-" + slot, "spec": job["info"]["specs"].get(slot), "w": self.res[0],
                      "h": self.res[1], "frame": job["info"]["frame"].get(slot), "flip": res["flip"].get(slot),
                      "t": job["wire"]["t"]}
            self.publish("frame", (header, encode_jpeg(u8, self.jpeg_quality)))
        self._errview_status("ready", f"HDR-FLIP against Mitsuba's path, {self.ref_spp} spp",
                             flip=res.get("flip"), ref_cached=res.get("ref_cached"),
                             ref_seconds=res.get("ref_seconds"), frame=job["info"]["frame"],
                             specs=job["info"]["specs"])
