"""Scene loading by name or path: built-in names, Mitsuba XML, OBJ, PLY, glTF/GLB.

Every failure (missing file, unknown extension, parse error, NaN/Inf vertices)
raises one :class:`~dyngi.errors.DyngiError` naming the file and the problem.

* XML: loaded by Mitsuba; the first sensor gives the camera (and its ``x_fov``).
* OBJ / PLY: one mesh with a grey diffuse BSDF under a constant white
  environment; the camera looks at the bounding box from its +z side.
* glTF / GLB: every mesh of the trimesh scene graph (transforms applied), base
  colour factor as diffuse albedo, emissive factor as area light.
"""
from __future__ import annotations

import os

import numpy as np

from ..backend import mi
from ..errors import DyngiError
from .camera import Camera, CameraPath
from .core import Scene, scene_bounds
from .geometry import check_finite, diffuse, make_mesh
from .library import BUILTINS, builtin_names, make_builtin

EXTENSIONS = (".xml", ".obj", ".ply", ".gltf", ".glb")


def load_scene(name_or_path: str) -> Scene:
    """A built-in scene by name, or a scene file by path."""
    names = builtin_names()
    if name_or_path in BUILTINS:
        return make_builtin(name_or_path)
    path = os.fspath(name_or_path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in EXTENSIONS:
        raise DyngiError(f"unknown scene '{path}': not a built-in scene ({', '.join(names)}) "
                         f"nor a file with extension {', '.join(EXTENSIONS)}")
    if not os.path.isfile(path):
        raise DyngiError(f"scene file '{path}' does not exist")
    try:
        if ext == ".xml":
            sc = _load_xml(path)
        elif ext in (".obj", ".ply"):
            sc = _load_mesh_file(path, ext)
        else:
            sc = _load_gltf(path)
    except DyngiError:
        raise
    except Exception as e:  # Mitsuba/trimesh parse errors -> one line
        msg = str(e).strip().splitlines()
        raise DyngiError(f"scene file '{path}' could not be loaded: {msg[-1] if msg else type(e).__name__}") from None
    _check_meshes(sc, path)
    return sc


def _check_meshes(sc: Scene, path: str) -> None:
    for k in sc.params.keys():
        if k.endswith("vertex_positions"):
            V = np.asarray(sc.params[k]).reshape(-1, 3)
            if not np.all(np.isfinite(V)):
                bad = int(np.sum(~np.all(np.isfinite(V), axis=1)))
                raise DyngiError(f"scene file '{path}': mesh '{k.rsplit('.', 1)[0]}' has {bad} "
                                 "vertices with NaN/Inf coordinates")


def _camera_from_bbox(mi_scene) -> Camera:
    lo, hi = scene_bounds(mi_scene)
    c = 0.5 * (lo + hi)
    r = 0.5 * np.linalg.norm(hi - lo)
    return Camera(tuple(c + [0.0, 0.2 * r, 2.2 * r]), tuple(c), (0, 1, 0), 45.0)


def _name(path: str) -> str:
    """Scene name from its file; 'scene*.xml' files are named after their folder."""
    stem = os.path.splitext(os.path.basename(path))[0]
    parent = os.path.basename(os.path.dirname(os.path.abspath(path)))
    return parent if stem.startswith("scene") and parent else stem


def _load_xml(path: str) -> Scene:
    mis = mi.load_file(path)
    sensors = mis.sensors()
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


def _load_gltf(path: str) -> Scene:
    import trimesh

    tm = trimesh.load(path, force="scene")
    items: dict = {"type": "scene"}
    has_light = False
    for i, node in enumerate(tm.graph.nodes_geometry):
        T, gname = tm.graph[node]
        g = tm.geometry[gname]
        if not hasattr(g, "faces") or len(g.faces) == 0:
            continue
        V = trimesh.transformations.transform_points(np.asarray(g.vertices, np.float64), T)
        check_finite(V, f"{path}:{node}")
        mat = getattr(getattr(g, "visual", None), "material", None)
        base = np.array(getattr(mat, "baseColorFactor", None) if mat is not None and
                        getattr(mat, "baseColorFactor", None) is not None else [204, 204, 204, 255], np.float64)
        base = base[:3] / (255.0 if base.max() > 1.0 else 1.0)
        emis = getattr(mat, "emissiveFactor", None) if mat is not None else None
        emitter = None
        if emis is not None and np.max(emis) > 0:
            emitter = {"type": "area", "radiance": {"type": "rgb", "value": [float(x) for x in emis[:3]]}}
            has_light = True
        sid = f"mesh{i}"
        items[sid] = make_mesh(sid, V, np.asarray(g.faces), diffuse(base), emitter)
    if len(items) == 1:
        raise DyngiError(f"scene file '{path}' contains no triangle meshes")
    if not has_light:
        items["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
    mis = mi.load_dict(items)
    return Scene(_name(path), mis, CameraPath.fixed(_camera_from_bbox(mis)), [],
                 f"loaded from {path}", source=path)
