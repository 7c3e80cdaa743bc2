"""Sequence runner: animate a scene over frames and step a technique.

``run_sequence`` is used by the CLI and the tests. For each frame index ``i``
the scene is moved to ``t = t0 + i / fps`` (``scene.at``), the camera is read
from the scene's camera path, and ``technique.step`` renders. A frame is
*static* when nothing moved since the previous frame (scene signature equal),
which lets progressive techniques accumulate.

Budgets for comparisons:
* ``equal-frames``: every technique renders the same frames with its own defaults;
* ``equal-rays``: ``Frame.ray_budget`` carries a ray count per frame that a
  technique should spend (techniques that honour it document how);
* ``equal-time``: the runner measures each technique's wall time and the
  comparison pairs frames by time (``time_to_error`` in dyngi.metrics).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import DyngiError
from ..rays import counting
from ..techniques.base import Frame, FrameResult

BUDGETS = ("equal-frames", "equal-rays", "equal-time")


@dataclass
class SequenceResult:
    technique: str
    times: list = field(default_factory=list)          # scene time per frame
    images: list = field(default_factory=list)         # HxWx3 float32
    indirect: list = field(default_factory=list)       # HxWx3 or None
    stats: list = field(default_factory=list)          # per frame dict
    wall_ms: list = field(default_factory=list)        # wall time of step() per frame

    def steady(self) -> tuple[list, list]:
        """(stats, wall_ms) of the frames after the first: cost figures leave out frame 0 (kernel
        compilation, probe warm-up updates) unless it is the only frame."""
        return (self.stats[1:] or self.stats), (self.wall_ms[1:] or self.wall_ms)


def frame_rays(stats: dict) -> int:
    """A frame's rays as the harness counted them (``counted_rays``, :mod:`dyngi.rays`); a technique's own
    ``total_rays`` only for stats that did not come through :func:`run_sequence`."""
    return int(stats.get("counted_rays", stats.get("total_rays", 0)) or 0)


def parse_res(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise DyngiError(f"resolution '{text}' is invalid; use WxH, e.g. 320x240") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise DyngiError(f"resolution '{text}' is out of range (1..16384 per side)")
    return w, h


def run_sequence(scene, technique, frames: int, res: tuple[int, int], seed: int = 0, t0: float = 0.0,
                 ray_budget: int | None = None, progress=None, on_frame=None, keep_images=True,
                 times=None, frame_budget=None) -> SequenceResult:
    """Run ``technique`` over ``frames`` frames of ``scene`` starting at time ``t0``: the one frame loop
    that comparisons, budgets, reproductions and tests share.

    ``times``: the scene time of each frame (a sequence; ``frames`` is then its length), for protocols
    that hold or jump the scene (a static view accumulated, a light that jumps); default
    ``t0 + scene.frame_time(i)``. ``frame_budget(i, out)``: called before frame ``i`` with the result so
    far, returns ``(ray_budget, time_budget_ms)`` for that frame (either None), for budgets that depend
    on what earlier frames spent; otherwise every frame gets ``ray_budget``. ``on_frame(i, frame,
    result)`` is called after each frame; returning True stops the run there (a protocol that stops
    once a target error is reached).

    A frame is *static* when the scene's signature equals the previous frame's (nothing moved); frame
    0 never is. This is the only place that decides it. Every frame's ``stats['counted_rays']`` is the
    number of rays the step traced through :mod:`dyngi.rays` (counted by the harness, not reported by the
    technique; frame 0's warm-up included).
    """
    if times is not None:
        times = list(times)
        frames = len(times)
    if frames < 1:
        raise DyngiError(f"number of frames must be >= 1, got {frames}")
    out = SequenceResult(technique.name)
    prev_sig = None
    for i in range(frames):
        t = times[i] if times is not None else t0 + scene.frame_time(i)
        scene.at(t)
        sig = scene.signature(t)
        rb, tb = (ray_budget, None) if frame_budget is None else frame_budget(i, out)
        frame = Frame(index=i, time=t, camera=scene.camera(t), res=tuple(res), seed=seed,
                      ray_budget=rb, static=(sig == prev_sig))
        if tb is not None:
            frame.time_budget_ms = tb
        prev_sig = sig
        r = step_frame(technique, frame, out, keep_images)
        if progress is not None:
            progress.update(1)
        if on_frame is not None and on_frame(i, frame, r):
            break
    return out


def step_frame(technique, frame: Frame, out: SequenceResult, keep_images: bool = True) -> FrameResult:
    """One timed step of ``technique`` with its rays counted (:mod:`dyngi.rays`), appended to ``out``: the one
    frame step of :func:`run_sequence`, :func:`run_round_robin` and benchmarks that step techniques in turn."""
    w0 = time.perf_counter()
    with counting() as ledger:
        r: FrameResult = technique.step(frame)
    wall = 1e3 * (time.perf_counter() - w0)
    r.stats["counted_rays"] = ledger.total()     # every ray through dyngi.rays (issue 40), after the timing
    if not np.all(np.isfinite(r.image)):
        r.stats["nonfinite_pixels"] = int(np.sum(~np.isfinite(r.image)))
    out.times.append(frame.time)
    out.stats.append(r.stats)
    out.wall_ms.append(wall)
    if keep_images:
        out.images.append(r.image)
        out.indirect.append(r.indirect)
    return r


def run_round_robin(scene, techniques: dict, frames: int, res: tuple[int, int], seed: int = 0, t0: float = 0.0,
                    progress=None) -> tuple[dict, dict]:
    """Step every technique of ``techniques`` (``{label: Technique}``) over the same frames in turn: frame
    ``i`` of each before frame ``i + 1`` of any, in one process (issue 40: timings compared under the same
    machine load, which drifts over a run on a shared CPU; every frame timed). The scene moves once per
    frame. Returns ``({label: SequenceResult}, {label: exception})``: a technique that raises is left out
    of the later frames and named with its error; the others go on.
    """
    if frames < 1:
        raise DyngiError(f"number of frames must be >= 1, got {frames}")
    outs = {lb: SequenceResult(tech.name) for lb, tech in techniques.items()}
    errors: dict = {}
    prev_sig = None
    for i in range(frames):
        t = t0 + scene.frame_time(i)
        scene.at(t)
        sig = scene.signature(t)
        for lb, tech in techniques.items():
            if lb in errors:
                continue
            frame = Frame(index=i, time=t, camera=scene.camera(t), res=tuple(res), seed=seed,
                          ray_budget=None, static=(sig == prev_sig))
            try:
                step_frame(tech, frame, outs[lb])
            except Exception as e:       # noqa: BLE001 -- one technique's failure leaves the others running
                errors[lb] = e
            if progress is not None:
                progress.update(1)
        prev_sig = sig
    return {lb: o for lb, o in outs.items() if lb not in errors}, errors
