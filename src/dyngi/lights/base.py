"""The light-sampler interface (DESIGN.md, ``lights/``; issue 24 item 3), after pbrt-v4's ``LightSampler``
(Pharr et al., *Physically Based Rendering* 4th ed., Sec. 12.6): a light sampler chooses one light for a
shading point and reports the exact probability (pmf) with which it would choose any given light there,
so that emission found by BSDF sampling can be weighted against next-event estimation (Veach 1997, Ch. 9).

A *light* is one emitter triangle of the one emitter table (:class:`EmitterTable`, the VLC paper's
lights, Dittebrandt et al. Sec. 7); the point on it is drawn by plain area sampling. Emitters that are
not triangles (delta lights, analytic area shapes, the environment) are classified once
(:func:`emitter_kind`) and sampled through Mitsuba's emitter sampling restricted to them
(:class:`~dyngi.lights.nee.LightNEE`).

Interface (:class:`LightSampler`)
---------------------------------
* ``sample(p, n, u, active, p_prev=None) -> (light id: UInt32, pmf: Float)``: one light for the shading
  point ``p`` with (side-corrected) normal ``n`` from one uniform number ``u``; ``INVALID`` / 0 where
  none can be chosen. ``p_prev``: the point's previous-frame position (VLC Sec. 6.3).
* ``pmf(p, n, light, active, p_prev=None) -> Float``: the exact probability that ``sample`` returns
  ``light`` there; it sums to 1 over the lights at every point where anything can be chosen
  (``tests/lights/``).
* per-frame hooks for learning samplers: ``begin_frame(ctx: FrameCtx)`` (before a frame: rebuild,
  construct caches), ``record(p, n, light, visible, active)`` (a NEE sample's outcome, VLC Sec. 4.1),
  ``end_frame()``, ``stats() -> dict``.

Implementations register themselves (:func:`register`): one file per sampler in this package is
discovered by :mod:`dyngi.lights` and becomes a valid value of every technique's ``lights=``. A
sampler's options are the keyword arguments of its constructor (after ``tris``, ``mi_scene``,
``bounds``); :func:`make` raises :class:`~dyngi.errors.DyngiError` on an unknown sampler or option.

Examples, simplest first (``docs/lights.md`` explains them): :mod:`dyngi.lights.uniform` (pmf 1/L, no
state), :mod:`dyngi.lights.power` (a table rebuilt per frame in ``begin_frame``),
:mod:`dyngi.lights.lighttree` (a hierarchy traversed per shading point, the pmf along its chain); the
learning one, :mod:`dyngi.lights.vlc`, also uses ``record`` and the shared octree
(:mod:`dyngi.directions.octree`).
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Callable, Protocol

from ..backend import dr, mi
from ..errors import DyngiError
from .emitter_table import INVALID, EmitterTable, emitter_kind

__all__ = ["INVALID", "EmitterTable", "FrameCtx", "LightSampler", "Entry", "register", "make", "names",
           "options", "describe", "emitter_kind", "pmf_inputs"]


@dataclass
class FrameCtx:
    """What a light sampler may look at in ``begin_frame`` (one per frame)."""

    mi_scene: Any
    tris: EmitterTable
    frame_index: int
    time: float
    octree: Any = None          # AdaptiveOctree when lights=vlc or directions=cdq, else None
    bounds: tuple = ()          # scene bounds (lo[3], hi[3]) as NumPy arrays
    camera_pos: Any = None      # (optional addition) camera position, NumPy [3], for camera-distance heuristics


class LightSampler(Protocol):
    """The protocol every light sampler implements (module docstring)."""

    name: str

    def begin_frame(self, ctx: FrameCtx) -> None: ...

    def sample(self, p, n, u, active, p_prev=None) -> tuple: ...   # (mi.UInt32 light id, mi.Float pmf)

    def pmf(self, p, n, light_id, active, p_prev=None): ...        # exact pmf of sample() returning light_id

    def record(self, p, n, light_id, visible, active) -> None: ...

    def end_frame(self) -> None: ...

    def stats(self) -> dict: ...


def pmf_inputs(p, n, light_id, active, count: int):
    """The arguments of a sampler's ``pmf`` as Dr.Jit arrays, ``active`` of the width of ``light_id`` and
    restricted to the ids below ``count``: (p, n, light_id, active). A sampler over no lights returns
    ``dr.zeros(mi.Float, dr.width(light_id))`` after it (the light tree, the SLL)."""
    p, n = mi.Point3f(p), mi.Vector3f(n)
    light_id = mi.UInt32(light_id)
    width = dr.width(light_id)
    active = mi.Bool(active) & (light_id < count) & dr.full(mi.Bool, True, width)
    return p, n, light_id, active


_SKIP = {"self", "tris", "mi_scene", "bounds"}


@dataclass(frozen=True)
class Entry:
    """One registered light sampler: its name, constructor, one-line description and option names."""

    name: str
    factory: Callable
    doc: str
    options: tuple
    learns: bool = False        # records NEE outcomes (the walk then hands it its samples, VLC Sec. 4.1)
    needs_octree: bool = False  # looks points up in an adaptive octree (VLC Sec. 6)


REGISTRY: dict[str, Entry] = {}


def _options(factory) -> tuple:
    sig = inspect.signature(factory)
    return tuple(k for k, p in sig.parameters.items()
                 if k not in _SKIP and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL))


def register(name: str, factory: Callable, doc: str, learns: bool = False, needs_octree: bool = False) -> Entry:
    """Register light sampler ``name`` (called once, at import, by its own module)."""
    e = Entry(name, factory, doc, _options(factory), learns, needs_octree)
    REGISTRY[name] = e
    return e


def _registry() -> dict:
    from . import discover
    discover()
    return REGISTRY


def names() -> tuple:
    """Every registered light sampler's name (sorted)."""
    return tuple(sorted(_registry()))


def entry(name: str) -> Entry:
    reg = _registry()
    if name not in reg:
        raise DyngiError(f"unknown light sampler '{name}'; valid values: {', '.join(sorted(reg))}")
    return reg[name]


def options(name: str) -> tuple:
    """The option keywords light sampler ``name`` accepts."""
    return entry(name).options


def describe() -> dict:
    """name -> one-line description, for ``dyngi techniques``."""
    return {k: e.doc for k, e in sorted(_registry().items())}


def make(name: str, tris: EmitterTable, mi_scene=None, bounds=None, **opts):
    """Construct light sampler ``name`` over the emitter table ``tris``; unknown names or options raise."""
    e = entry(name)
    bad = sorted(set(opts) - set(e.options))
    if bad:
        raise DyngiError(f"light sampler '{name}': unknown option(s) {', '.join(bad)}; valid: "
                         f"{', '.join(e.options) or '(none)'}")
    return e.factory(tris, mi_scene=mi_scene, bounds=bounds, **opts)
