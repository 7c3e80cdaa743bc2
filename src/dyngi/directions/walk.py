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

``record="vertex"`` (the VLC paper's evaluation path tracer, Sec. 7; ``nee-pt``): for a walk unrolled over
``vertices`` vertices, :meth:`WalkDirections.vertex_hook` is the walk's vertex hook and this object keeps
the per-vertex records (``vx``: the vertex, its placing leaf, its NEE mask and estimate, its sampled
direction; ``env``: the environment's radiance reached) that a :class:`~dyngi.lights.nee.LightNEE` with
``estimator="separate"`` shares. The hook places every vertex that records (all but the last, which only
collects emission) in the octree, so the octree's counts are the records its leaves learn from (the paper's
two placed vertices per path, Sec. 7);
with ``stand_in`` every vertex after the first is a diffuse stand-in (the diffuse-lobe albedo of its BSDF,
:func:`~dyngi.sampling.diffuse.diffuse_albedo`); with motion vectors the first vertex samples with its
previous position's leaf and records into its current one (Sec. 6.3). The CDQ learns inside the kernel at
the end of the walk: at each vertex but the last, the luminance of ``f cos L_i / p`` where ``L_i`` excludes
the emission of lights (NEE's job, Sec. 5.1) but includes the environment and everything reflected at the
next vertex. The octree is shared (:meth:`WalkDirections.share_octree`): its owner adapts it.
"""
from __future__ import annotations

from ..backend import dr, mi
from ..color import luminance
from ..errors import DyngiError
from ..sampling.diffuse import diffuse_albedo
from ..scene.surface import shading_normal
from .base import Vertex, make, names
from .octree import make_octree, octree_bounds

RECORD_VERTICES = 3
"""Path vertices per lane whose sampled directions the CDQ learns from."""


def _cdq_class():
    """:class:`~dyngi.directions.cdq.CDQDirections`, or a clear error where its module cannot be imported."""
    try:
        from .cdq import CDQDirections     # optional module (FUNCTION_IMPORTS_WHY)
    except ImportError as e:
        raise DyngiError(f"directions=cdq needs dyngi.directions.cdq ({e}); valid values: "
                         f"{', '.join(names())}") from None
    return CDQDirections


def diffuse_stand_in(si, bsdf, active):
    """(albedo, side-corrected shading normal) of the diffuse stand-in of a vertex (nee-pt after the primary
    hit, the VLC paper's Sec. 7): the diffuse-lobe albedo of its BSDF, 0 seen from a back side it lacks."""
    cos_wi = mi.Frame3f.cos_theta(si.wi)
    back_ok = mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide)
    a = diffuse_albedo(bsdf, si, active)
    a = dr.select((cos_wi > 0.0) | back_ok, a, 0.0)
    return a, shading_normal(si)


class WalkDirections:
    """The walk's direction strategy for direction sampler ``kind`` (module docstring)."""

    def __init__(self, scene, kind: str, bits: int = 128, stability: float = 0.1, memory: float = 0.0,
                 leaf_samples: int = 0, *, min_records: float = 0.0, fraction=None, record: str = "path", vertices: int = RECORD_VERTICES,
                 stand_in: bool = False):
        """``leaf_samples``: the octree's split threshold per leaf (collapse: half; 0: the paper's scaled and
        floored, :func:`~dyngi.directions.octree.make_octree`); ``fraction``: the mixture's CDQ probability
        (None: its default); ``record``: ``"path"`` (the path's sum after the vertex, handed to the CDQ at the
        end of the frame) or ``"vertex"`` (per-vertex records of a walk unrolled over ``vertices`` vertices,
        :meth:`vertex_hook`, module docstring); ``stand_in``: a diffuse stand-in after the first vertex;
        ``min_records``: the CDQ's evidence for a migration (:class:`~dyngi.directions.cdq.CDQDirections`)."""
        if kind not in names():
            raise DyngiError(f"unknown direction sampler '{kind}'; valid values: {', '.join(names())}")
        if record not in ("path", "vertex"):
            raise DyngiError(f"WalkDirections: record must be 'path' or 'vertex', got '{record}'")
        self.kind = kind
        self._ms = scene.mi_scene if hasattr(scene, "mi_scene") else scene
        self.bounds = octree_bounds(scene)
        self.cdq_opts = dict(bits=bits, stability=stability, memory=memory, min_records=min_records)
        self.sampler_opts = {} if fraction is None else {"fraction": float(fraction)}
        self.leaf_samples = int(leaf_samples)
        self.per_vertex = record == "vertex"
        self.vertices = int(vertices)
        self.stand_in = bool(stand_in)
        self.octree = self.cdq = self.motion = None
        self._owns_octree = True
        self._cdq_cls = _cdq_class() if kind == "cdq" else None
        self.sampler = make(kind) if kind != "cdq" else None
        self._walks: list = []
        self.vx: dict = {}
        self.env: dict = {}

    def share_octree(self, octree, motion=None) -> None:
        """Use ``octree`` (owned by the caller, who adapts it; None: none) and ``motion`` (a
        :class:`~dyngi.directions.motion.MotionVectors` for the first vertex's previous position, Sec. 6.3;
        advanced in :meth:`begin_frame`) from the next frame on; the CDQ is built anew over it."""
        self.octree, self.motion = octree, motion
        self._owns_octree = False
        if self.kind == "cdq":
            self.cdq = self.sampler = None

    # -- per frame ------------------------------------------------------------------------------
    def begin_frame(self, scene, frame, vertices_per_frame: int = 0) -> None:
        if self.motion is not None:
            self.motion.advance()
        if self.kind == "cdq" and self.cdq is None:
            if self._owns_octree:
                self.octree = make_octree(self.bounds, vertices_per_frame, self.leaf_samples)
            self.cdq = self._cdq_cls(self.octree, **self.cdq_opts)
            self.sampler = make("cdq", guide=self.cdq, **self.sampler_opts)
        if self.cdq is not None:
            self.cdq.begin_frame(None)

    def end_frame(self) -> None:
        if self.cdq is not None:
            for leaf, wo, ok, value in self._walks:
                self.cdq.record(leaf, wo, value, ok != 0)
            self.cdq.end_frame()
            if self._owns_octree:
                self.octree.adapt()
        self._walks = []

    def stats(self) -> dict:
        return self.cdq.stats() if self.cdq is not None else {}

    # -- inside the walk -------------------------------------------------------------------------
    def begin_walk(self, n: int) -> None:
        if self.per_vertex:            # the per-vertex records of this walk
            self.vx, self.env = {}, {}
            return
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

    def vertex_hook(self, c):
        """The walk's vertex hook (``record="vertex"``): the :class:`Vertex` NEE and the direction sampler see
        at vertex ``c.depth`` (None at the last one, which records nothing and is not placed), its octree placement
        and per-vertex record (module docstring)."""
        oc, si, valid = self.octree, c.si, c.active
        if c.depth >= self.vertices - 1:          # the last vertex: emission only, records nothing: not placed
            return None
        if c.depth == 0 or not self.stand_in:     # the first vertex keeps its real BSDF
            n, albedo, bsdf, on = shading_normal(si), None, c.bsdf, valid
        else:                                     # after it: the diffuse stand-in
            albedo, n = diffuse_stand_in(si, c.bsdf, valid)
            bsdf, on = None, valid & (dr.max(albedo) > 0.0)
        leaf = leaf_s = None
        if oc is not None:
            if c.depth == 0 and self.motion is not None and self.motion.active:   # Sec. 6.3: previous / current
                leaf_s, leaf = oc.lookup_pair(self.motion.previous(si, valid), si.p, valid)
            else:
                leaf = leaf_s = oc.lookup(si.p, valid)
            oc.place_leaf(leaf, valid)
        v = Vertex(si, n, bsdf, albedo, leaf_s, on)
        self.vx[c.depth] = {"v": v, "leaf": leaf, "nee_on": mi.Bool(False), "L_nee": mi.Color3f(0.0)}
        return v

    def pdf(self, v: Vertex, wo, active):
        return self.sampler.pdf(v, wo, active)

    def sample(self, v: Vertex, sampler, active):
        u_sel = sampler.next_1d()
        u1 = sampler.next_1d()
        u2 = sampler.next_2d()
        if self.per_vertex:
            active = mi.Bool(active) & v.active
        return self.sampler.sample(v, u_sel, u1, u2, active)

    def record(self, v: Vertex, d, L, beta, depth) -> None:
        """Scatter this vertex's sample (leaf, direction, the path's sum so far, beta) into the buffers
        (``record="vertex"``: keep its sampled direction for :meth:`end_walk`)."""
        if self.per_vertex:
            self.vx[depth]["d"] = d
            return
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
        """After the walk: each recorded sample's ``lum(f cos L_i / p) = lum((L_final - L_vertex) / beta)``
        (``record="vertex"``: from the per-vertex records, recorded now, module docstring)."""
        if self.cdq is None:
            return
        if self.per_vertex:
            self._end_walk_vertices()
            return
        b = self._buf
        idx = dr.arange(mi.UInt32, self._n * RECORD_VERTICES) // RECORD_VERTICES
        L_final = dr.gather(mi.Color3f, mi.Color3f(L), idx)
        diff = L_final - b["snap"]
        c = dr.select(b["beta"] > 0.0, diff / b["beta"], 0.0)
        value = dr.maximum(mi.luminance(c), 0.0)
        value = dr.select(dr.isfinite(value) & (b["ok"] != 0), value, 0.0)
        self._walks.append((b["leaf"], b["wo"], b["ok"], value))

    def _end_walk_vertices(self) -> None:
        """The CDQ record of ``record="vertex"``: at each vertex but the last, the luminance of the indirect
        sample ``f cos L_i / p_mix`` without the path's prefix, ``L_i`` without the emission of lights (NEE's
        job) but with the environment and the next vertex's NEE and reflected light."""
        last = self.vertices - 1
        inner = self.env[last]      # radiance arriving along vertex d's sample, from the far end back
        recs = []
        for d in range(last - 1, -1, -1):
            x = self.vx[d]
            val = x["d"].weight * inner
            node = x["d"].node     # located while sampling, in the sampling leaf: reused where it records too
            if node is not None:
                node = dr.select(x["leaf"] == x["v"].leaf, mi.UInt32(node), mi.UInt32(0xFFFFFFFF))
            recs.append((x["leaf"], x["d"].wo, luminance(val), x["d"].ok, node))
            if d > 0:
                inner = self.env[d] + x["L_nee"] + val
        for leaf, wo, lum, ok, node in reversed(recs):
            self.cdq.record(leaf, wo, lum, ok, node=node)
