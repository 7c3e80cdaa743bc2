"""Direction samplers (DESIGN.md ``directions/``): one interface (:mod:`dyngi.directions.base`); ``bsdf``,
the CDQ (:mod:`dyngi.directions.cdq`) and their one-sample MIS mixture (:mod:`dyngi.directions.mixture`).
Each registered sampler is one module of this package, found by :func:`discover`."""
from __future__ import annotations

from ..registry import discover_modules
from .base import REGISTRY, DirectionSampler, DirSample, Vertex, make, names, register

_INFRA = {"base", "walk", "lobes"}
_found = False


def discover() -> None:
    """Import every module of this package once (each registers its sampler)."""
    global _found
    if _found:
        return
    _found = True
    discover_modules(__name__, __path__, skip=_INFRA)


__all__ = ["REGISTRY", "DirectionSampler", "DirSample", "Vertex", "discover", "make", "names", "register"]
