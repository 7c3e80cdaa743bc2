"""Light samplers (DESIGN.md ``lights/``): one interface (:mod:`dyngi.lights.base`), one emitter table and
emitter classification (:mod:`dyngi.lights.emitter_table`); each sampler is one module of this package that
registers itself beside its class, found by :func:`discover` (a new sampler is one new file; examples:
:mod:`~dyngi.lights.uniform`, :mod:`~dyngi.lights.power`, :mod:`~dyngi.lights.lighttree`, ``docs/lights.md``).

Next-event estimation: :class:`~dyngi.lights.nee.LightNEE` turns a sampler into the path walk's light
strategy; :class:`~dyngi.lights.emitter_sampling.EmitterSampling` (Mitsuba's emitter sampling) is the walk's
default one. ReSTIR DI's candidate sources: :mod:`dyngi.lights.candidates`."""
from __future__ import annotations

from ..registry import discover_modules
from .base import (INVALID, REGISTRY, EmitterTable, FrameCtx, LightSampler, describe, emitter_kind, entry, make,
                   names, options, register)

_INFRA = {"base", "candidates", "emitter_sampling", "emitter_table", "importance", "nee"}
_found = False
UNAVAILABLE: dict = {}
"""Sampler modules that failed to import (name -> reason): not registered, so not a valid ``lights=``."""


def discover() -> None:
    """Import every module of this package once (each registers its sampler)."""
    global _found
    if _found:
        return
    _found = True
    discover_modules(__name__, __path__, skip=_INFRA, optional=UNAVAILABLE)


__all__ = ["INVALID", "REGISTRY", "EmitterTable", "FrameCtx", "LightSampler", "describe", "discover",
           "emitter_kind", "entry", "make", "names", "options", "register"]
