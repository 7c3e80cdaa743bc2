"""Direction samplers (DESIGN.md ``directions/``): one interface (:mod:`dyngi.directions.base`); ``bsdf``,
the CDQ (:mod:`dyngi.directions.cdq`) and their one-sample MIS mixture (:mod:`dyngi.directions.mixture`).
Each registered sampler is one module of this package, found by :func:`discover`. The adaptive octree
(:mod:`dyngi.directions.octree`, one construction: :func:`~dyngi.directions.octree.make_octree`) is shared
with the VLC (``lights/`` may import ``directions/``, never the reverse); motion vectors for its
previous-frame lookup: :mod:`dyngi.directions.motion`."""
from __future__ import annotations

from ..registry import discover_modules
from .base import REGISTRY, DirectionSampler, DirSample, Vertex, make, names, register

_INFRA = {"base", "cdq", "lobes", "motion", "octree", "walk"}
_found = False


def discover() -> None:
    """Import every module of this package once (each registers its sampler)."""
    global _found
    if _found:
        return
    _found = True
    discover_modules(__name__, __path__, skip=_INFRA)


__all__ = ["REGISTRY", "DirectionSampler", "DirSample", "Vertex", "discover", "make", "names", "register"]
