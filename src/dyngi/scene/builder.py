"""SceneBuilder: the small fluent API the built-in procedural scenes are written in."""
from __future__ import annotations

from ..backend import mi
from ..errors import DyngiError
from .animation import Animator
from .camera import Camera, CameraPath
from .core import Scene
from .geometry import area_light, diffuse, make_mesh


class SceneBuilder:
    def __init__(self, name: str):
        self.name = name
        self.items: dict = {"type": "scene"}
        self.animators: list[Animator] = []

    def mesh(self, sid: str, VF, bsdf=None, emitter=None) -> str:
        """Add a triangle mesh with id ``sid``; ``bsdf`` a dict (default grey diffuse), ``emitter`` rgb or dict."""
        if sid in self.items:
            raise DyngiError(f"duplicate shape id '{sid}' in scene '{self.name}'")
        V, F = VF
        if bsdf is None:
            bsdf = diffuse((0.6, 0.6, 0.6))
        if emitter is not None and not isinstance(emitter, dict):
            emitter = area_light(emitter)
        self.items[sid] = make_mesh(sid, V, F, bsdf, emitter)
        return sid

    def add(self, sid: str, spec: dict) -> str:
        """Add any other Mitsuba object (point/spot/directional/constant/envmap emitter) by dict."""
        if sid in self.items:
            raise DyngiError(f"duplicate id '{sid}' in scene '{self.name}'")
        self.items[sid] = spec
        return sid

    def animate(self, animator: Animator) -> None:
        self.animators.append(animator)

    def build(self, camera: Camera | CameraPath, description: str, stands_for: str = "",
              duration: float = 4.0, fps: float = 30.0, probe_box=None, probe_counts=None) -> Scene:
        path = camera if isinstance(camera, CameraPath) else CameraPath.fixed(camera)
        return Scene(self.name, mi.load_dict(self.items), path, self.animators, description,
                     stands_for, duration, fps, probe_box, probe_counts)
