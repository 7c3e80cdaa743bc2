"""Scene loading by name or path: built-in names, Mitsuba XML, OBJ, PLY, glTF/GLB.

Every failure (missing file, unknown extension, parse error, NaN/Inf vertices)
raises one :class:`~dyngi.errors.DyngiError` naming the file and the problem.

* XML: loaded by Mitsuba; the first sensor gives the camera (and its ``x_fov``).
* OBJ / PLY: one mesh with a grey diffuse BSDF under a constant white
  environment; the camera looks at the bounding box from its +z side.
* glTF / GLB: :mod:`dyngi.scene.gltf` (node hierarchy, animations, cameras,
  punctual lights, metallic-roughness materials, skinning and morph targets).

Options every scene command passes (``--fps``, ``--camera``, ``--animation``,
``--loop``): :func:`load_scene`'s keywords, or :func:`scene_options` around code
that loads the scene itself (a runner, the viewer and its child process, which
reads them from the environment).
"""
from __future__ import annotations

import contextlib
import json
import os

import numpy as np

from ..backend import mi
from ..errors import DyngiError
from . import keyframes
from .camera import Camera, CameraPath, camera_from_bounds
from .core import Scene, scene_bounds
from .geometry import diffuse
from .gltf import load_gltf
from .library import BUILTINS, builtin_names, make_builtin

EXTENSIONS = (".xml", ".obj", ".ply", ".gltf", ".glb")


OPTIONS_ENV = "DYNGI_SCENE_OPTIONS"
"""Environment variable holding :func:`scene_options` as JSON (child processes inherit it)."""


@contextlib.contextmanager
def scene_options(**opts):
    """Within the block, :func:`load_scene` uses ``opts`` (``fps``, ``camera``, ``animation``, ``loop``) where
    its caller gives none; set in the environment so a child process (the viewer's error view, local cluster
    workers) loads the same scene. ``None`` values are dropped."""
    opts = {k: v for k, v in opts.items() if v is not None and v is not False}
    old = os.environ.get(OPTIONS_ENV)
    os.environ[OPTIONS_ENV] = json.dumps(opts)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(OPTIONS_ENV, None)
        else:
            os.environ[OPTIONS_ENV] = old


def ambient_options() -> dict:
    """The options :func:`scene_options` set (``{}`` outside its block)."""
    try:
        return json.loads(os.environ.get(OPTIONS_ENV, "") or "{}")
    except ValueError:
        return {}


def load_scene(name_or_path: str, *, fps: float | None = None, camera: str | None = None,
               animation: str | None = None, loop: bool | None = None) -> Scene:
    """A built-in scene by name, or a scene file by path.

    ``fps``: frames per second (time of frame i is ``i / fps``; default the scene's own ``fps``).
    ``camera``: a camera by name (glTF camera or its node; Mitsuba XML sensor id); default the first.
    ``animation``: a keyframe sidecar (TOML) for a Mitsuba XML scene; without it, ``NAME.anim.toml``
    beside ``NAME.xml`` is used when present (``animation: FILE`` is printed).
    ``loop``: glTF animations wrap at the last keyframe instead of holding it.
    Keywords left ``None`` fall back to :func:`scene_options`."""
    amb = ambient_options()
    fps = amb.get("fps") if fps is None else fps
    camera = amb.get("camera") if camera is None else camera
    animation = amb.get("animation") if animation is None else animation
    loop = bool(amb.get("loop", False)) if loop is None else bool(loop)
    if fps is not None and not (isinstance(fps, (int, float)) and np.isfinite(fps) and fps > 0):
        raise DyngiError(f"--fps must be a positive number of frames per second, got {fps!r}")
    names = builtin_names()
    if name_or_path in BUILTINS:
        if animation is not None:
            raise DyngiError(f"--animation applies to Mitsuba XML scene files, not the built-in scene "
                             f"'{name_or_path}'")
        if camera is not None:
            raise DyngiError(f"--camera picks a camera of a scene file; the built-in scene '{name_or_path}' "
                             "has one camera path")
        sc = make_builtin(name_or_path)
        if fps is not None:
            sc.fps = float(fps)
        return sc
    path = os.fspath(name_or_path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in EXTENSIONS:
        raise DyngiError(f"unknown scene '{path}': not a built-in scene ({', '.join(names)}) "
                         f"nor a file with extension {', '.join(EXTENSIONS)}")
    if not os.path.isfile(path):
        raise DyngiError(f"scene file '{path}' does not exist")
    if animation is not None and ext != ".xml":
        raise DyngiError(f"--animation applies to Mitsuba XML scene files (a keyframe sidecar), not '{path}'; "
                         "glTF files carry their own animations")
    if animation is not None and not os.path.isfile(animation):
        raise DyngiError(f"animation file '{animation}' does not exist")
    if camera is not None and ext in (".obj", ".ply"):
        raise DyngiError(f"--camera picks a camera of a glTF or XML scene; '{path}' has none")
    try:
        if ext == ".xml":
            sc = _load_xml(path, camera)
        elif ext in (".obj", ".ply"):
            sc = _load_mesh_file(path, ext)
        else:
            sc = load_gltf(path, name=_name(path), fps=fps, camera=camera, loop=loop)
    except DyngiError:
        raise
    except Exception as e:  # Mitsuba parse errors -> one line
        msg = str(e).strip().splitlines()
        raise DyngiError(f"scene file '{path}' could not be loaded: {msg[-1] if msg else type(e).__name__}") from None
    _check_meshes(sc, path)
    if ext == ".xml":
        sc = _attach_keyframes(sc, path, animation)
    if fps is not None:       # after the sidecar: --fps wins over a sidecar's own fps
        sc.fps = float(fps)
    return sc


def _attach_keyframes(sc: Scene, path: str, animation: str | None) -> Scene:
    """The keyframe sidecar (:mod:`dyngi.scene.keyframes`) of an XML scene: ``animation`` or the one found
    beside ``path``."""
    if animation is None:
        animation = keyframes.sidecar_for(path)
        if animation is None:
            return sc
        print(f"animation: {animation}")
    return keyframes.attach(sc, animation)


def _check_meshes(sc: Scene, path: str) -> None:
    for k in sc.params.keys():
        if k.endswith("vertex_positions"):
            V = np.asarray(sc.params[k]).reshape(-1, 3)
            if not np.all(np.isfinite(V)):
                bad = int(np.sum(~np.all(np.isfinite(V), axis=1)))
                raise DyngiError(f"scene file '{path}': mesh '{k.rsplit('.', 1)[0]}' has {bad} "
                                 "vertices with NaN/Inf coordinates")


def _camera_from_bbox(mi_scene) -> Camera:
    return camera_from_bounds(*scene_bounds(mi_scene))


def _name(path: str) -> str:
    """Scene name from its file; 'scene*.xml' files are named after their folder."""
    stem = os.path.splitext(os.path.basename(path))[0]
    parent = os.path.basename(os.path.dirname(os.path.abspath(path)))
    return parent if stem.startswith("scene") and parent else stem


def _load_xml(path: str, camera: str | None = None) -> Scene:
    mis = mi.load_file(path)
    sensors = mis.sensors()
    if camera is not None:
        hits = [s for s in sensors if s.id() == camera]
        if not hits:
            raise DyngiError(f"scene file '{path}' has no sensor with id '{camera}'; sensors: "
                             f"{', '.join(s.id() or '(no id)' for s in sensors) or 'none'}")
        sensors = hits
    if sensors:
        s = sensors[0]
        T = np.array(s.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        o = T[:3, 3]
        d = T[:3, 2]
        up = T[:3, 1]
        fov = float(mi.traverse(s)["x_fov"][0]) if "x_fov" in mi.traverse(s) else 45.0
        cam = Camera(tuple(o), tuple(o + d), tuple(up), fov)
    else:
        cam = _camera_from_bbox(mis)
    return Scene(_name(path), mis, CameraPath.fixed(cam), [], f"loaded from {path}", source=path)


def _load_mesh_file(path: str, ext: str) -> Scene:
    if ext == ".obj":
        with open(path, "rb") as f:
            lines = f.read().splitlines()
        if not any(l.startswith(b"v ") for l in lines) or not any(l.startswith(b"f ") for l in lines):
            raise DyngiError(f"scene file '{path}' contains no vertices/faces")
    mis = mi.load_dict({
        "type": "scene",
        "mesh": {"type": ext[1:], "filename": path, "bsdf": diffuse((0.6, 0.6, 0.6))},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
    })
    return Scene(_name(path), mis, CameraPath.fixed(_camera_from_bbox(mis)), [],
                 f"loaded from {path} (grey diffuse, white sky)", source=path)
