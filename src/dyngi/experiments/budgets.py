"""Comparison budgets: equal frames, equal rays, equal time -- and how well each run kept to its budget.

``equal-frames``  every technique renders the same frames with its own settings;
``equal-rays``    frame i of every technique gets ``Frame.ray_budget`` = the rays the *first* technique
                  traced on frame i, minus what the technique overspent (plus what it left unspent) on
                  its earlier steady frames: the budget is for the run, and a technique that can only
                  spend in steps (whole samples per pixel) repays a step taken over the budget on the
                  next frame (our rule, so that rounding is not an advantage);
``equal-time``    every frame gets ``Frame.time_budget_ms`` = the first technique's median steady frame
                  time (frame 0 includes kernel compilation, and single frames on a shared CPU are noisy).

Techniques adapt as their modules document (``Technique.BUDGETS`` lists the budgets a technique honours;
the others run their own settings and the report says so).

Accounting (:func:`budget_accounting`): for every budgeted technique the measured spend over the budget,
per frame and in total. The issue's rule is that no technique overspends by more than 5 %
(:data:`MAX_OVERSPEND`); frame 0 is reported on its own because it holds one-off work that the budget
cannot plan (kernel compilation; a technique's documented warm-up or pilot), and the steady frames are
what is checked: for equal rays their total (``total_ratio``; rays are counted exactly), for equal time
the median frame (wall time on a shared CPU is noisy; reported, never a hard failure). The largest
single-frame ratio is reported beside them.
"""
from __future__ import annotations

import numpy as np

from .runner import SequenceResult, run_sequence

MAX_OVERSPEND = 0.05
"""Largest allowed spend over the budget (fraction) on a steady frame."""


def time_budget_ms(first: SequenceResult) -> float:
    """The equal-time budget: the first technique's median steady frame time (ms)."""
    return float(np.median(first.steady()[1]))


def run_with_budget(scene, tech, frames, res, seed, budget, first: SequenceResult | None, bar=None,
                    label: str | None = None) -> SequenceResult:
    """``run_sequence``, with the first technique's per-frame rays or time as this technique's budget.

    ``first`` None (or ``budget == 'equal-frames'``): a plain run. Otherwise each frame is run on its
    own with the budget set on its :class:`Frame`, the frame index and the static flag restored as
    ``run_sequence`` sets them.
    """
    if first is None or budget == "equal-frames":
        seq = run_sequence(scene, tech, frames, res, seed=seed, progress=bar)
        if label is not None:
            seq.technique = label
        return seq
    merged = SequenceResult(label or tech.name)
    wrapped = _Budgeted(tech, None, None)
    tb = time_budget_ms(first)
    balance = 0.0     # rays spent minus rays budgeted over the steady frames so far
    for i in range(frames):
        if budget == "equal-rays":
            b = first.stats[i].get("total_rays")
            wrapped.rb = None if b is None else max(1, int(round(b - balance)))
        else:
            wrapped.rb = None
        wrapped.tb = tb if budget == "equal-time" else None
        seq = run_sequence(scene, wrapped, 1, res, seed=seed, t0=scene.frame_time(i))
        if budget == "equal-rays" and i > 0 and first.stats[i].get("total_rays") is not None:
            balance += seq.stats[0].get("total_rays", 0) - first.stats[i]["total_rays"]
        merged.times += seq.times
        merged.images += seq.images
        merged.indirect += seq.indirect
        merged.stats += seq.stats
        merged.wall_ms += seq.wall_ms
        if bar is not None:
            bar.update(1)
    return merged


class _Budgeted:
    """Wraps a technique so each step receives a ray or time budget (frame index restored)."""

    def __init__(self, tech, ray_budget, time_budget):
        self.tech, self.rb, self.tb = tech, ray_budget, time_budget
        self.name = tech.name
        self.prev_sig = None

    def step(self, frame):
        frame.ray_budget, frame.time_budget_ms = self.rb, self.tb
        frame.index = int(round(frame.time * self.tech.scene.fps))
        sig = self.tech.scene.signature(frame.time)   # static as in run_sequence: nothing moved since the last frame
        frame.static = sig == self.prev_sig
        self.prev_sig = sig
        return self.tech.step(frame)


def budget_accounting(seq: SequenceResult, first: SequenceResult, budget: str) -> dict | None:
    """How ``seq`` kept to the budget set by ``first``; None for ``equal-frames``.

    Returns ``{'what': 'rays'|'ms', 'budget': per-frame budgets, 'spent': per-frame spend,
    'ratio': spent / budget per frame, 'frame0_ratio', 'steady_max_ratio', 'steady_mean_ratio',
    'total_ratio' (steady frames summed), 'overspent': total_ratio > 1 + MAX_OVERSPEND}``.
    For equal time the spend is the wall time of each frame and ``steady_median_ratio`` (median steady
    frame time over the budget, what the budget targets) is added.
    """
    if budget == "equal-frames":
        return None
    if budget == "equal-rays":
        b = np.array([float(s.get("total_rays", 0)) for s in first.stats])
        x = np.array([float(s.get("total_rays", 0)) for s in seq.stats])
        what = "rays"
    else:
        b = np.full(len(seq.wall_ms), time_budget_ms(first))
        x = np.asarray(seq.wall_ms, np.float64)
        what = "ms"
    ratio = np.where(b > 0, x / np.maximum(b, 1e-30), np.inf)
    steady = ratio[1:] if len(ratio) > 1 else ratio
    sb, sx = (b[1:], x[1:]) if len(b) > 1 else (b, x)
    out = {"what": what, "budget": b.tolist(), "spent": x.tolist(), "ratio": ratio.tolist(),  # budget: first's
           "frame0_ratio": float(ratio[0]), "steady_max_ratio": float(np.max(steady)),
           "steady_mean_ratio": float(np.mean(steady)),
           "total_ratio": float(np.sum(sx) / max(np.sum(sb), 1e-30))}
    if what == "ms":
        out["steady_median_ratio"] = float(np.median(steady))
        out["overspent"] = bool(out["steady_median_ratio"] > 1.0 + MAX_OVERSPEND)
    else:
        out["overspent"] = bool(out["total_ratio"] > 1.0 + MAX_OVERSPEND)
    return out
