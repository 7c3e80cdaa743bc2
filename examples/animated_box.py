"""Write ``box.gltf``: a glTF 2.0 scene of a box whose lid opens while the box slides across a floor.

A small stand-in for the public animated samples (written here, nothing downloaded): an open box (five
walls) translates along x (LINEAR, 3 s), its lid, a child node hinged on the box's back edge, rotates
open by 100 degrees and settles back to 80 (CUBICSPLINE), a perspective camera watches it and
two KHR_lights_punctual lights (a sun and a point light inside the box's path) light it; the floor is a
metallic-roughness material, the lid's inside glows (emissive strength).

    python examples/animated_box.py out/box.gltf
    dyngi render out/box.gltf --technique ddgi --frames 90 --fps 24 --out out/box
    dyngi compare out/box.gltf --techniques ddgi,path --frames 30 --fps 24 --out out/boxcmp
"""
from __future__ import annotations

import base64
import json
import math
import os
import sys

import numpy as np


def _quat_axis(axis, deg):
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    h = math.radians(deg) / 2
    return [*(a * math.sin(h)).tolist(), math.cos(h)]


def _quad(c, u, v):
    c, u, v = (np.asarray(x, np.float64) for x in (c, u, v))
    return np.array([c - u - v, c + u - v, c + u + v, c - u + v]), np.array([[0, 1, 2], [0, 2, 3]])


def _merge(parts):
    V, F, off = [], [], 0
    for v, f in parts:
        V.append(v)
        F.append(f + off)
        off += len(v)
    return np.concatenate(V), np.concatenate(F)


def build() -> dict:
    """The glTF document (buffers embedded as a data: URI)."""
    blob = bytearray()
    doc = {"asset": {"version": "2.0", "generator": "dyngi examples/animated_box.py"},
           "buffers": [], "bufferViews": [], "accessors": []}

    def acc(arr, type_, ctype=5126):
        a = np.ascontiguousarray(arr, np.float32 if ctype == 5126 else np.uint32)
        while len(blob) % 4:
            blob.append(0)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": a.nbytes})
        blob.extend(a.tobytes())
        n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[type_]
        item = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": ctype, "count": a.size // n,
                "type": type_}
        if ctype == 5126:
            r = a.reshape(-1, n)
            item["min"], item["max"] = r.min(0).tolist(), r.max(0).tolist()
        doc["accessors"].append(item)
        return len(doc["accessors"]) - 1

    def mesh(VF, material):
        V, F = VF
        doc.setdefault("meshes", []).append({"primitives": [{
            "attributes": {"POSITION": acc(V, "VEC3")}, "indices": acc(F.ravel(), "SCALAR", 5125),
            "material": material}]})
        return len(doc["meshes"]) - 1

    doc["materials"] = [
        {"name": "floor", "pbrMetallicRoughness": {"baseColorFactor": [0.55, 0.55, 0.5, 1.0],
                                                   "metallicFactor": 0.0, "roughnessFactor": 0.8}},
        {"name": "wood", "doubleSided": True,
         "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.4, 0.2, 1.0], "metallicFactor": 0.0,
                                  "roughnessFactor": 0.6}},
        {"name": "glow", "pbrMetallicRoughness": {"baseColorFactor": [0.1, 0.1, 0.1, 1.0], "metallicFactor": 0.0},
         "emissiveFactor": [1.0, 0.8, 0.5], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 3.0}}},
    ]
    floor = mesh(_quad([0, 0, 0], [0, 0, 3], [3, 0, 0]), 0)                      # normal +y
    s = 0.4                                                                        # half size of the box
    walls = _merge([_quad([0, s, -s], [s, 0, 0], [0, s, 0]), _quad([0, s, s], [s, 0, 0], [0, s, 0]),
                    _quad([-s, s, 0], [0, 0, s], [0, s, 0]), _quad([s, s, 0], [0, 0, s], [0, s, 0]),
                    _quad([0, 0.01, 0], [s, 0, 0], [0, 0, s])])
    box = mesh(walls, 1)
    lid = mesh(_quad([0, 0.0, s], [s, 0, 0], [0, 0, s]), 1)                       # hinge along the lid's z = 0 edge
    glow = mesh(_quad([0, -0.005, s], [0.6 * s, 0, 0], [0, 0, 0.6 * s]), 2)       # underside, facing down
    doc["cameras"] = [{"name": "watch", "type": "perspective",
                       "perspective": {"yfov": 0.7, "aspectRatio": 4 / 3, "znear": 0.05}}]
    doc["extensionsUsed"] = ["KHR_lights_punctual", "KHR_materials_emissive_strength"]
    doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"name": "sun", "type": "directional", "intensity": 683.0 * 2.5, "color": [1.0, 0.95, 0.85]},
        {"name": "bulb", "type": "point", "intensity": 683.0 * 1.5, "color": [0.8, 0.9, 1.0]}]}}
    doc["nodes"] = [
        {"name": "floor", "mesh": floor},
        {"name": "box", "mesh": box, "children": [2]},
        {"name": "lid", "translation": [0, 2 * s, -s], "children": [3], "mesh": lid},
        {"name": "lid_glow", "mesh": glow},
        {"name": "camera", "camera": 0, "translation": [0.0, 1.6, 3.2], "rotation": _quat_axis([1, 0, 0], -22)},
        {"name": "sun", "rotation": _quat_axis([1, 0.3, 0], -55), "extensions": {"KHR_lights_punctual": {"light": 0}}},
        {"name": "bulb", "translation": [0.0, 1.6, 0.8], "extensions": {"KHR_lights_punctual": {"light": 1}}},
    ]
    doc["scenes"] = [{"name": "box", "nodes": [0, 1, 4, 5, 6]}]
    doc["scene"] = 0
    t_box = acc([0.0, 3.0], "SCALAR")
    v_box = acc([[-0.8, 0, 0], [0.8, 0, 0.2]], "VEC3")
    t_lid = acc([0.0, 2.0, 3.0], "SCALAR")
    v_lid = acc([[0, 0, 0, 0], _quat_axis([1, 0, 0], 0), [0, 0, 0, 0],
                 [0, 0, 0, 0], _quat_axis([1, 0, 0], -100), [0, 0, 0, 0],
                 [0, 0, 0, 0], _quat_axis([1, 0, 0], -80), [0, 0, 0, 0]], "VEC4")
    doc["animations"] = [
        {"name": "slide", "samplers": [{"input": t_box, "output": v_box, "interpolation": "LINEAR"}],
         "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}]},
        {"name": "open", "samplers": [{"input": t_lid, "output": v_lid, "interpolation": "CUBICSPLINE"}],
         "channels": [{"sampler": 0, "target": {"node": 2, "path": "rotation"}}]},
    ]
    doc["buffers"] = [{"byteLength": len(blob),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()}]
    return doc


def write(path: str) -> str:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump(build(), f)
    return path


if __name__ == "__main__":
    print(write(sys.argv[1] if len(sys.argv) > 1 else "box.gltf"))
