"""Comparison budgets: equal frames, equal rays, equal time -- and how well each run kept to its budget.

``equal-frames``  every technique renders the same frames with its own settings;
``equal-rays``    frame i of every technique gets ``Frame.ray_budget`` = the rays the *first* technique
                  traced on frame i, minus what the technique overspent (plus what it left unspent) on
                  its earlier frames, frame 0 included (issue 40: every ray of every frame, warm-up
                  included): the budget is for the run, and a technique that can only spend in steps
                  (whole samples per pixel) or spends a warm-up on frame 0 repays it on the next frames
                  (our rule, so that rounding or a warm-up is not an advantage);
``equal-time``    every frame gets ``Frame.time_budget_ms`` = the first technique's median steady frame
                  time (frame 0 includes kernel compilation, and single frames on a shared CPU are noisy).

Techniques adapt as their modules document (``Technique.BUDGETS`` lists the budgets a technique honours;
the others run their own settings and the report says so).

Accounting (:func:`budget_accounting`): for every budgeted technique the measured spend over the budget,
per frame and in total, in the rays the harness counted (``counted_rays``, :mod:`dyngi.rays`: a technique's
own report may leave rays out). The rule is that no technique overspends by more than 5 % (:data:`MAX_OVERSPEND`):
for equal rays over every frame from frame 0 (``total_ratio``; issue 40: a warm-up, a pilot, relocation
and re-tests are rays like any other; the steady frames' ratio is reported beside it), for equal time the
median steady frame (frame 0 holds the kernel compilation; wall time on a shared CPU is noisy; reported,
never a hard failure). The largest single-frame ratio and frame 0's are reported beside them.
"""
from __future__ import annotations

import numpy as np

from .runner import SequenceResult, frame_rays, run_sequence

MAX_OVERSPEND = 0.05
"""Largest allowed spend over the budget (fraction) on a steady frame."""


def time_budget_ms(first: SequenceResult) -> float:
    """The equal-time budget: the first technique's median steady frame time (ms)."""
    return float(np.median(first.steady()[1]))


def run_with_budget(scene, tech, frames, res, seed, budget, first: SequenceResult | None, bar=None,
                    label: str | None = None) -> SequenceResult:
    """``run_sequence``, with the first technique's per-frame rays or time as this technique's budget.

    ``first`` None (or ``budget == 'equal-frames'``): a plain run. Otherwise frame ``i`` gets
    :func:`frame_budget`'s budget on its :class:`Frame` (one run, the runner's frame loop).
    """
    if first is None or budget == "equal-frames":
        seq = run_sequence(scene, tech, frames, res, seed=seed, progress=bar)
    else:
        seq = run_sequence(scene, tech, frames, res, seed=seed, progress=bar,
                           frame_budget=frame_budget(budget, [frame_rays(s) for s in first.stats],
                                                     time_budget_ms(first)))
    if label is not None:
        seq.technique = label
    return seq


def frame_budget(budget: str, rays: list, ms: float | None = None):
    """The per-frame budget callback of :func:`~dyngi.experiments.runner.run_sequence` for ``budget``.

    ``equal-rays``: frame ``i`` gets ``rays[i]`` minus what the run overspent (plus what it left unspent)
    on its earlier frames, frame 0 included; a frame whose budget is unknown (``rays[i]`` None) gets none.
    ``equal-time``: every frame gets ``ms``.
    """
    def budget_of(i: int, so_far: SequenceResult):
        if budget == "equal-time":
            return None, ms
        if i >= len(rays) or rays[i] is None:
            return None, None
        spent = [frame_rays(st) for st in so_far.stats]
        return carried_budgets(rays[:i + 1], spent + [0])[i], None

    return budget_of


def carried_budgets(rays: list, spent: list) -> list:
    """The ray budget each frame is given under the carried balance (:func:`frame_budget`): ``rays[i]`` less
    what frames ``0 .. i-1`` spent over (plus what they left under) theirs, at least 1; None where ``rays[i]``
    is None (that frame has no budget and moves no balance). A frame's spend over *this* budget is its own
    overspend; over ``rays[i]`` it may be a balance the earlier frames left."""
    out, balance = [], 0.0
    for r, s in zip(rays, spent):
        if r is None:
            out.append(None)
            continue
        out.append(max(1, int(round(r - balance))))
        balance += s - r
    return out


def budget_accounting(seq: SequenceResult, first: SequenceResult, budget: str) -> dict | None:
    """How ``seq`` kept to the budget set by ``first``; None for ``equal-frames``.

    Returns ``{'what': 'rays'|'ms', 'budget': per-frame budgets, 'spent': per-frame spend,
    'ratio': spent / budget per frame, 'frame0_ratio', 'steady_max_ratio', 'steady_mean_ratio',
    'total_ratio' (every frame from frame 0 summed), 'steady_total_ratio' (frames 1.. summed),
    'overspent': total_ratio > 1 + MAX_OVERSPEND}``; for equal rays also 'given' (each frame's budget under
    the carried balance, :func:`carried_budgets`) and 'max_given_ratio' (the largest spend over it).
    For equal time the spend is the wall time of each frame and ``steady_median_ratio`` (median steady
    frame time over the budget, what the budget targets) is added.
    """
    if budget == "equal-frames":
        return None
    if budget == "equal-rays":
        b = np.array([float(frame_rays(s)) for s in first.stats])
        x = np.array([float(frame_rays(s)) for s in seq.stats])
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
           "steady_total_ratio": float(np.sum(sx) / max(np.sum(sb), 1e-30)),
           "total_ratio": float(np.sum(x) / max(np.sum(b), 1e-30))}
    if what == "ms":
        out["steady_median_ratio"] = float(np.median(steady))
        out["overspent"] = bool(out["steady_median_ratio"] > 1.0 + MAX_OVERSPEND)
    else:
        out["overspent"] = bool(out["total_ratio"] > 1.0 + MAX_OVERSPEND)
        given = np.asarray(carried_budgets(b.tolist(), x.tolist()), np.float64)
        out["given"] = given.tolist()
        out["max_given_ratio"] = float(np.max(x / given))
    return out
