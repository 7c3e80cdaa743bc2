"""A direction sampler inside the path walk (``path:directions=NAME``; issue 24 item 3).

:class:`WalkDirections` gives :func:`dyngi.transport.path_walk.walk` its indirect directions and the
BSDF-side pdf of its MIS weights from a registered direction sampler (:mod:`dyngi.directions`). For
``directions=cdq`` it owns an adaptive octree (VLC paper Sec. 6) and a CDQ per leaf
(:class:`~dyngi.directions.cdq.CDQDirections`, Sec. 5): every path vertex is placed in the octree, and
every sampled direction is recorded with the luminance of ``f cos L_i / p`` where ``L_i`` is what the
rest of *this* path gathered after the vertex (``(L_final - L_vertex) / beta_vertex``, from per-lane
buffers scattered inside the loop; our choice: nee-pt's record excludes the emission of lights, NEE's
job, which a general walk's sum does not separate). The octree adapts and the CDQ migrates at the end
of the frame. Unbiased for any learned state (the mixture's pdf is exact, ``tests/directions/``).
"""
from __future__ import annotations

from ..backend import dr, mi
from ..errors import DyngiError
from ..scene.surface import shading_normal
from .base import Vertex, make, names
from .octree import make_octree, octree_bounds

RECORD_VERTICES = 3
"""Path vertices per lane whose sampled directions the CDQ learns from."""




class WalkDirections:
    """The walk's direction strategy for direction sampler ``kind`` (module docstring)."""

    def __init__(self, scene, kind: str, bits: int = 128, stability: float = 0.1, memory: float = 0.0,
                 leaf_samples: int = 0):
        """``leaf_samples``: the octree's split threshold per leaf (collapse: half; 0: the paper's scaled and
        floored, :func:`~dyngi.directions.octree.make_octree`)."""
        if kind not in names():
            raise DyngiError(f"unknown direction sampler '{kind}'; valid values: {', '.join(names())}")
        self.kind = kind
        self._ms = scene.mi_scene if hasattr(scene, "mi_scene") else scene
        self.bounds = octree_bounds(scene)
        self.cdq_opts = dict(bits=bits, stability=stability, memory=memory)
        self.leaf_samples = int(leaf_samples)
        self.octree = self.cdq = None
        self.sampler = make(kind) if kind != "cdq" else None
        self._walks: list = []

    # -- per frame ------------------------------------------------------------------------------
    def begin_frame(self, scene, frame, vertices_per_frame: int = 0) -> None:
        if self.kind == "cdq" and self.cdq is None:
            from .cdq import CDQDirections     # optional module (FUNCTION_IMPORTS_WHY)
            self.octree = make_octree(self.bounds, vertices_per_frame, self.leaf_samples)
            self.cdq = CDQDirections(self.octree, **self.cdq_opts)
            self.sampler = make("cdq", guide=self.cdq)
        if self.cdq is not None:
            self.cdq.begin_frame(None)

    def end_frame(self) -> None:
        if self.cdq is not None:
            for leaf, wo, ok, value in self._walks:
                self.cdq.record(leaf, wo, value, ok != 0)
            self.cdq.end_frame()
            self.octree.adapt()
        self._walks = []

    def stats(self) -> dict:
        return self.cdq.stats() if self.cdq is not None else {}

    # -- inside the walk -------------------------------------------------------------------------
    def begin_walk(self, n: int) -> None:
        if self.cdq is None:
            return
        size = n * RECORD_VERTICES
        self._n = n
        self._lane = dr.arange(mi.UInt32, n)
        self._buf = dict(leaf=dr.full(mi.UInt32, 0xFFFFFFFF, size), ok=dr.zeros(mi.UInt32, size),
                         wo=dr.zeros(mi.Vector3f, size), snap=dr.zeros(mi.Color3f, size),
                         beta=dr.zeros(mi.Color3f, size))
        dr.make_opaque(*self._buf.values())

    def vertex(self, si, bsdf, active) -> Vertex:
        leaf = None
        if self.octree is not None:
            leaf = self.octree.lookup(si.p, active)
            self.octree.place_leaf(leaf, active)
        return Vertex(si, shading_normal(si), bsdf, None, leaf, mi.Bool(active))

    def pdf(self, v: Vertex, wo, active):
        return self.sampler.pdf(v, wo, active)

    def sample(self, v: Vertex, sampler, active):
        u_sel = sampler.next_1d()
        u1 = sampler.next_1d()
        u2 = sampler.next_2d()
        return self.sampler.sample(v, u_sel, u1, u2, active)

    def record(self, v: Vertex, d, L, beta, depth) -> None:
        """Scatter this vertex's sample (leaf, direction, the path's sum so far, beta) into the buffers."""
        if self.cdq is None:
            return
        rec = mi.Bool(d.ok) & ~mi.Bool(d.delta) & (mi.UInt32(depth) < RECORD_VERTICES)
        slot = self._lane * RECORD_VERTICES + mi.UInt32(depth)
        b = self._buf
        dr.scatter(b["leaf"], v.leaf, slot, rec)
        dr.scatter(b["ok"], mi.UInt32(1), slot, rec)
        dr.scatter(b["wo"], d.wo, slot, rec)
        dr.scatter(b["snap"], mi.Color3f(L), slot, rec)
        dr.scatter(b["beta"], mi.Color3f(beta), slot, rec)

    def end_walk(self, L) -> None:
        """After the walk: each recorded sample's ``lum(f cos L_i / p) = lum((L_final - L_vertex) / beta)``."""
        if self.cdq is None:
            return
        b = self._buf
        idx = dr.arange(mi.UInt32, self._n * RECORD_VERTICES) // RECORD_VERTICES
        L_final = dr.gather(mi.Color3f, mi.Color3f(L), idx)
        diff = L_final - b["snap"]
        c = dr.select(b["beta"] > 0.0, diff / b["beta"], 0.0)
        value = dr.maximum(mi.luminance(c), 0.0)
        value = dr.select(dr.isfinite(value) & (b["ok"] != 0), value, 0.0)
        self._walks.append((b["leaf"], b["wo"], b["ok"], value))
