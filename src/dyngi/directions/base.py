"""The direction-sampler interface (DESIGN.md ``directions/``; issue 24 item 3): how a path vertex draws
its next (indirect) direction, after pbrt-v4's ``BSDF::Sample_f`` / ``PDF`` pair (Sec. 9.1.2) extended to
learned guiding distributions mixed with the BSDF by one-sample MIS (Veach 1997, Sec. 9.2.4; the VLC
paper's CDQ, Dittebrandt et al. Sec. 5 and Sec. 7: "brdf fraction of 50%").

A :class:`Vertex` is what a sampler may look at: the surface interaction, its shading normal turned to
the side of ``wi``, its real BSDF (or ``None`` with a diffuse stand-in ``albedo``, nee-pt after the
primary hit), the octree leaf of a learned distribution, and the vertex's active lanes.

Interface (:class:`DirectionSampler`)
-------------------------------------
* ``sample(v, u_sel, u1, u2, active) -> DirSample``: world direction ``wo``, ``weight = f cos / pdf``,
  the solid-angle ``pdf``, ``delta`` (a delta lobe was sampled: no pdf), ``ok`` (a usable sample);
  ``u_sel`` chooses a mixture component, ``u1``/``u2`` the direction (as Mitsuba's ``bsdf.sample``);
* ``pdf(v, wo, active) -> Float``: the density with which ``sample`` produces ``wo`` (the BSDF side of
  the NEE/BSDF MIS weight).

Samplers are registered by name (:func:`register`, one module each; ``directions=`` of a technique):
``bsdf`` and ``cdq`` (the CDQ/BSDF mixture). Unknown names raise :class:`~dyngi.errors.DyngiError`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol

from ..errors import DyngiError


@dataclass
class Vertex:
    """A path vertex as a direction sampler sees it (module docstring)."""

    si: Any
    n: Any                 # shading normal on the side of wi
    bsdf: Any = None       # the real BSDF, or None: a diffuse stand-in with ``albedo``
    albedo: Any = None
    leaf: Any = None       # octree leaf of a learned distribution (CDQ), else None
    active: Any = True


@dataclass
class DirSample:
    """A sampled direction: ``wo`` (world), ``weight`` = f cos / pdf, ``pdf`` (solid angle), ``delta``, ``ok``,
    ``node`` (where a guide located ``wo`` while sampling: its record reuses it)."""

    wo: Any
    weight: Any
    pdf: Any
    delta: Any
    ok: Any
    node: Any = None       # a learned distribution's cell of ``wo`` (the CDQ's quadtree leaf node), else None


class DirectionSampler(Protocol):
    name: str

    def sample(self, v: Vertex, u_sel, u1, u2, active) -> DirSample: ...

    def pdf(self, v: Vertex, wo, active): ...


REGISTRY: dict[str, tuple[Callable, str]] = {}


def register(name: str, factory: Callable, doc: str) -> None:
    """Register direction sampler ``name``: ``factory(guide=None)`` builds it (``guide``: a learned
    distribution such as :class:`~dyngi.directions.cdq.CDQDirections`, for the samplers that need one)."""
    REGISTRY[name] = (factory, doc)


def names() -> tuple:
    from . import discover
    discover()
    return tuple(sorted(REGISTRY))


def make(name: str, guide=None, **opts):
    """Direction sampler ``name`` built with ``opts`` (e.g. the mixture's ``fraction``); unknown names raise."""
    if name not in names():
        raise DyngiError(f"unknown direction sampler '{name}'; valid values: {', '.join(names())}")
    return REGISTRY[name][0](guide=guide, **opts)
