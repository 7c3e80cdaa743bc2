"""Every ray a technique traces goes through here, and is counted here (issue 40, bottom layer).

The harness decides equal-rays comparisons from this count, not from what a technique reports about itself:
a technique cannot leave its warm-up, relocation, re-tests, NEE shadow rays or extra layers out of its spend.
:func:`intersect`, :func:`intersect_preliminary` and :func:`occluded` wrap Mitsuba's ``ray_intersect``,
``ray_intersect_preliminary`` and ``ray_test``; ``tests/test_rays.py`` fails on a call of those (or on
``test_visibility=True``, whose shadow rays no wrapper sees) anywhere else in ``src/``.

Counting: while a :class:`RayLedger` is open (:func:`counting`; the runner opens one around every
``Technique.step``, :func:`dyngi.experiments.runner.run_sequence`), each call adds ``dr.count(active)`` to
it, lazily (a Dr.Jit reduction read once when the frame's total is asked for: no wait inside the frame, the
state stays on the device). Inside a symbolic loop (the path walk's recorded loop) a reduction cannot run:
there the caller keeps a per-lane counter, as the walk does, and adds its sum after the loop with
:func:`add`, passing ``lanes=True`` to the wrapper to say so (a wrapper called in a symbolic scope without
it raises).
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from .backend import dr, mi


class RayLedger:
    """Rays counted while open, per stage name: ints, or Dr.Jit masks / per-lane counts that are scheduled
    (:func:`_defer`) and reduced only when the ledger is read, so counting adds no kernel and no second
    evaluation of the rays a mask depends on."""

    def __init__(self):
        self._parts: list = []

    def add(self, stage: str, n) -> None:
        self._parts.append((stage, n))

    def by_stage(self) -> dict:
        """``{stage: rays}`` (reads the lazy counts: one host read per call)."""
        out: dict = {}
        for stage, n in self._parts:
            out[stage] = out.get(stage, 0) + _reduce(n)
        self._parts = [(k, v) for k, v in out.items()]
        return out

    def total(self) -> int:
        return int(sum(self.by_stage().values()))


_OPEN: list = []


@contextmanager
def counting():
    """Open a :class:`RayLedger` for the block (nested ledgers all count the block's rays)."""
    led = RayLedger()
    _OPEN.append(led)
    try:
        yield led
    finally:
        _OPEN.remove(led)


def _reduce(n) -> int:
    """An entry's rays: an int as it is; a Dr.Jit mask counted, a per-lane (or already reduced) count summed."""
    if isinstance(n, (int, np.integer, np.bool_)):      # bool is an int
        return int(n)
    if dr.is_array_v(n):
        v = dr.count(n) if dr.type_v(n) == dr.VarType.Bool else dr.sum(n)
        return int(np.asarray(v).ravel()[0]) if dr.width(v) else 0
    return int(np.asarray(n).ravel().sum())


def _defer(n):
    """Schedule a Dr.Jit entry so that it is evaluated with the frame's next kernel (dr.count or dr.sum now
    would launch a kernel of their own and re-evaluate everything the entry depends on, rays included)."""
    if dr.is_array_v(n) and dr.width(n) > 1 and not _symbolic():
        dr.schedule(n)
    return n


def add(stage: str, n) -> None:
    """Add ``n`` rays to every open ledger: an int, or a Dr.Jit per-lane count (the counter a symbolic loop
    keeps, after the loop) or an already reduced count; reduced when the ledger is read."""
    if not _OPEN:
        return
    n = _defer(n)
    for led in _OPEN:
        led.add(stage, n)


def _symbolic() -> bool:
    return bool(dr.flag(dr.JitFlag.SymbolicScope))


def _count(ray, active, stage: str, lanes: bool) -> None:
    if not _OPEN:
        return
    if _symbolic():
        if not lanes:
            raise RuntimeError(f"rays ({stage}): a ray traced in a symbolic loop needs lanes=True and a per-lane "
                               "counter added after the loop (dyngi.rays.add)")
        return
    if lanes:
        return
    # the ray's width, not its origin's: camera rays share one origin (a width-1 literal)
    w = dr.width(ray)
    if active is None:
        add(stage, w)
        return
    m = mi.Bool(active)
    if dr.width(m) == 1 and w > 1:     # a width-1 mask (a literal True) broadcasts to every lane
        add(stage, w if bool(m[0]) else 0)
        return
    add(stage, m)                      # the mask, scheduled; counted when the ledger is read


def intersect(scene, ray, ray_flags=None, coherent: bool = False, active=None, *, stage: str = "trace",
              lanes: bool = False):
    """``scene.ray_intersect`` (a Mitsuba scene), counted: one ray per active lane."""
    _count(ray, active, stage, lanes)
    flags = mi.RayFlags.All if ray_flags is None else ray_flags
    if active is None:
        return scene.ray_intersect(ray, ray_flags=flags, coherent=coherent)
    return scene.ray_intersect(ray, ray_flags=flags, coherent=coherent, active=active)


def intersect_preliminary(scene, ray, coherent: bool = False, active=None, *, stage: str = "trace",
                          lanes: bool = False):
    """``scene.ray_intersect_preliminary``, counted."""
    _count(ray, active, stage, lanes)
    if active is None:
        return scene.ray_intersect_preliminary(ray, coherent=coherent)
    return scene.ray_intersect_preliminary(ray, coherent=coherent, active=active)


def occluded(scene, ray, active=None, *, stage: str = "shadow", lanes: bool = False):
    """``scene.ray_test`` (is the segment blocked?), counted: a shadow ray per active lane."""
    _count(ray, active, stage, lanes)
    if active is None:
        return scene.ray_test(ray)
    return scene.ray_test(ray, active)


__all__ = ["RayLedger", "add", "counting", "intersect", "intersect_preliminary", "occluded"]
