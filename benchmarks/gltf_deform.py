"""Per-frame cost of moving a glTF mesh: a rigid/affine node (AffineMotion), skinning and morph targets.

Writes a grid mesh of N vertices three ways (an animated node; skinned to two joints, one animated; one
animated morph target), loads each with dyngi's glTF loader and times ``scene.at(t)`` over frames: the host
work (NumPy: the node matrix, or the per-vertex skin / morph blend) plus Mitsuba's BVH rebuild in
``params.update()``. Prints ms per frame for each, and the static scene's ``at`` as the floor.

    .venv/bin/python benchmarks/gltf_deform.py --verts 100000 --frames 20

Recorded in docs/scenes.md ("Cost of moving geometry").
"""
from __future__ import annotations

import argparse
import base64
import json
import os
import sys
import tempfile
import time

import numpy as np


def grid(n):
    k = int(np.sqrt(n))
    x, y = np.meshgrid(np.linspace(0, 1, k), np.linspace(0, 2, k))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(k * k)], 1)
    i = np.arange(k * k).reshape(k, k)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def write(path, kind, V, F):
    blob = bytearray()
    doc = {"asset": {"version": "2.0"}, "bufferViews": [], "accessors": []}

    def acc(a, t, ct=5126):
        a = np.ascontiguousarray(a, {5126: np.float32, 5125: np.uint32, 5121: np.uint8}[ct])
        while len(blob) % 4:
            blob.append(0)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": a.nbytes})
        blob.extend(a.tobytes())
        n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[t]
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": ct,
                                 "count": a.size // n, "type": t})
        return len(doc["accessors"]) - 1

    prim = {"attributes": {"POSITION": acc(V, "VEC3")}, "indices": acc(F.ravel(), "SCALAR", 5125)}
    q = [[0, 0, 0, 1], [0.3826834, 0, 0, 0.9238795]]
    doc["nodes"] = [{"name": "m", "mesh": 0}]
    anim = {"samplers": [{"input": acc([0.0, 1.0], "SCALAR"), "output": acc(q, "VEC4")}],
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "rotation"}}]}
    if kind == "skin":
        w = np.clip(V[:, 1:2] / 2.0, 0, 1)
        prim["attributes"]["JOINTS_0"] = acc(np.tile([0, 1, 0, 0], (len(V), 1)), "VEC4", 5121)
        prim["attributes"]["WEIGHTS_0"] = acc(np.concatenate([1 - w, w, 0 * w, 0 * w], 1), "VEC4")
        doc["nodes"] = [{"name": "m", "mesh": 0, "skin": 0}, {"name": "j0"}, {"name": "j1", "translation": [0, 1, 0]}]
        doc["skins"] = [{"joints": [1, 2]}]
        anim["channels"][0]["target"]["node"] = 2
    elif kind == "morph":
        prim["targets"] = [{"POSITION": acc(np.stack([0 * V[:, 0], 0 * V[:, 0], V[:, 1]], 1), "VEC3")}]
        doc["meshes"] = [{"primitives": [prim], "weights": [0.0]}]
        anim = {"samplers": [{"input": acc([0.0, 1.0], "SCALAR"), "output": acc([0.0, 1.0], "SCALAR")}],
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]}
    doc.setdefault("meshes", [{"primitives": [prim]}])
    if kind != "static":
        doc["animations"] = [anim]
    doc["buffers"] = [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64,"
                       + base64.b64encode(bytes(blob)).decode()}]
    with open(path, "w") as f:
        json.dump(doc, f)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--verts", type=int, default=100_000)
    ap.add_argument("--frames", type=int, default=20)
    a = ap.parse_args(argv)
    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.scene import load_scene

    V, F = grid(a.verts)
    print(f"{len(V)} vertices, {len(F)} triangles, {a.frames} frames; load {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as d:
        for kind in ("static", "affine", "skin", "morph"):
            p = os.path.join(d, f"{kind}.gltf")
            write(p, kind, V, F)
            sc = load_scene(p)
            sc.at(0.0)
            t0 = time.perf_counter()
            for i in range(1, a.frames + 1):
                sc.at(i / a.frames)
            ms = (time.perf_counter() - t0) / a.frames * 1e3
            print(f"{kind:7s} {ms:8.2f} ms/frame (scene.at: host update + BVH rebuild)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
