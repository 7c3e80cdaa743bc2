"""Scene = ``mi.Scene`` + animation + metadata.

``Scene.at(t)`` writes every animated parameter for time ``t`` into the
scene's ``mi.traverse`` dictionary and calls ``update()`` once, in place (no
reload; Mitsuba rebuilds the BVH of moved meshes). Metadata gives the bounds,
a default probe volume (box and grid counts, ~2048 probes as in DDGI's
default), the emitters with stable ids, and which shapes move.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from ..backend import mi
from ..errors import DyngiError
from .animation import Animator
from .camera import Camera, CameraPath



def scene_bounds(mi_scene) -> tuple[np.ndarray, np.ndarray]:
    """(lo[3], hi[3]) float64: the bounds of every shape of ``mi_scene``.

    Not ``mi_scene.bbox()``: Mitsuba 3.9 merges shapes that share a BSDF (e.g. the rectangles and cubes
    of a room in an XML file) into one mesh whose ``bbox()`` covers only part of it (or is invalid), and
    the scene's box then misses them (measured: a room of six rectangles and a cube came out as the
    cube's box, so every probe sat in the cube). Meshes contribute the box of their vertex positions.
    """
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for sh in mi_scene.shapes():
        if sh.is_mesh():
            if sh.vertex_count() == 0:
                continue
            v = np.asarray(sh.vertex_positions_buffer(), np.float64).reshape(-1, 3)
            a, b = v.min(axis=0), v.max(axis=0)
        else:
            bb = sh.bbox()
            if not bb.valid():
                continue
            a, b = np.array(bb.min, np.float64), np.array(bb.max, np.float64)
        lo, hi = np.minimum(lo, a), np.maximum(hi, b)
    return lo, hi

@dataclass
class SceneMeta:
    bounds: tuple            # (lo[3], hi[3])
    probe_box: tuple         # (lo[3], hi[3])
    probe_counts: tuple      # (nx, ny, nz)
    emitters: list           # [{'id':..., 'type':...}]
    dynamic_shapes: list     # shape ids that move

    @property
    def probe_spacing(self) -> np.ndarray:
        lo, hi = (np.asarray(a, np.float64) for a in self.probe_box)
        n = np.maximum(np.asarray(self.probe_counts) - 1, 1)
        return (hi - lo) / n


def default_probe_grid(lo, hi, target: int = 2048, margin: float = 0.05):
    """A probe box inset by ``margin`` of the extent and counts ~ ``target`` probes, proportional to extent."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    ext = hi - lo
    inset = ext * margin
    blo, bhi = lo + inset, hi - inset
    e = np.maximum(bhi - blo, 1e-6)
    s = (np.prod(e) / target) ** (1.0 / 3.0)
    counts = np.clip(np.round(e / s), 2, 64).astype(int)
    return (tuple(blo), tuple(bhi)), tuple(int(c) for c in counts)


def _emitter_kind(e) -> str:
    """'area', 'environment', 'point' (delta position), 'directional' (delta direction) or 'other'."""
    f = e.flags()
    if mi.has_flag(f, mi.EmitterFlags.DeltaDirection):
        return "directional"
    if mi.has_flag(f, mi.EmitterFlags.DeltaPosition):
        return "point"
    if mi.has_flag(f, mi.EmitterFlags.Infinite):
        return "environment"
    if mi.has_flag(f, mi.EmitterFlags.Surface):
        return "area"
    return "other"


@dataclass
class Scene:
    """An animated scene; see module docstring."""

    name: str
    mi_scene: "mi.Scene"
    camera_path: CameraPath
    animators: list[Animator] = field(default_factory=list)
    description: str = ""
    stands_for: str = ""
    duration: float = 4.0    # seconds the animation lasts (glTF: its last keyframe)
    fps: float = 30.0        # frame i shows time i / fps; every scene command's --fps sets it (load_scene(fps=))
    probe_box: tuple | None = None
    probe_counts: tuple | None = None
    source: str = "builtin"

    def __post_init__(self):
        self.params = mi.traverse(self.mi_scene)
        for a in self.animators:
            a.bind(self.params)
        self.time: float | None = None
        self._base_hash: str | None = None
        lo, hi = scene_bounds(self.mi_scene)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise DyngiError(f"scene '{self.name}' has no finite geometry bounds")
        if self.probe_box is None or self.probe_counts is None:
            box, counts = default_probe_grid(lo, hi)
            self.probe_box = self.probe_box or box
            self.probe_counts = self.probe_counts or counts
        emitters = []
        for i, e in enumerate(self.mi_scene.emitters()):
            sh = e.get_shape() if hasattr(e, "get_shape") else None
            eid = e.id() or (sh.id() if sh is not None else "") or f"emitter{i}"
            emitters.append({"id": eid, "type": _emitter_kind(e), "index": i})
        self.meta = SceneMeta((tuple(lo), tuple(hi)), tuple(self.probe_box), tuple(self.probe_counts),
                              emitters, sorted({a.shape for a in self.animators if a.shape}))

    # -- time --------------------------------------------------------------
    @property
    def is_animated(self) -> bool:
        return bool(self.animators) or len({self.camera_path(0).signature(),
                                            self.camera_path(self.duration).signature()}) > 1

    def frame_time(self, index: int) -> float:
        return index / self.fps

    def at(self, t: float) -> "Scene":
        """Move the scene to time ``t`` in place; no-op if already there."""
        if self.time is not None and self.time == t:
            return self
        if self.animators:
            self.content_hash()  # capture the base content before the first change
            for a in self.animators:
                a.apply(self.params, t)
            self.params.update()
        self.time = t
        return self

    def camera(self, t: float) -> Camera:
        return self.camera_path(t)

    def signature(self, t: float) -> tuple:
        """State of everything that moves (lights, shapes, camera) at ``t``."""
        return tuple(a.signature(t) for a in self.animators) + (self.camera(t).signature(),)

    # -- identity for caches -----------------------------------------------
    def content_hash(self) -> str:
        """Hash of the scene's base content (all traversable parameters before animation)."""
        if self._base_hash is None:
            h = hashlib.sha256(self.name.encode())
            for k in sorted(self.params.keys()):
                try:
                    v = np.asarray(self.params[k])
                except Exception:  # non-array parameters (e.g. textures objects)
                    v = np.asarray(str(self.params[k]).encode())
                if v.dtype == object:  # e.g. a Transform4f: its bytes would be a pointer; hash its value
                    v = np.asarray(str(self.params[k]).encode())
                h.update(k.encode())
                h.update(np.ascontiguousarray(v).tobytes())
            self._base_hash = h.hexdigest()[:16]
        return self._base_hash

    def state_hash(self, t: float) -> str:
        """Hash identifying the scene state (content + animation + camera) at ``t``."""
        h = hashlib.sha256(self.content_hash().encode())
        h.update(repr(self.signature(t)).encode())
        return h.hexdigest()[:16]

    def __repr__(self):
        return f"Scene('{self.name}', {len(self.meta.emitters)} emitters, animated={self.is_animated})"
