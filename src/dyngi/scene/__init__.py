"""Scenes: animated ``mi.Scene`` wrappers, built-in procedural scenes, loaders."""
from .animation import ParamTrack, RigidMotion, SunMotion, Track
from .camera import Camera, CameraPath
from .core import Scene, SceneMeta
from .library import BUILTINS, builtin_names, make_builtin
from .loaders import load_scene

__all__ = ["Track", "RigidMotion", "ParamTrack", "SunMotion", "Camera", "CameraPath", "Scene",
           "SceneMeta", "BUILTINS", "builtin_names", "make_builtin", "load_scene"]
