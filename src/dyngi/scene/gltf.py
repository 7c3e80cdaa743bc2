"""glTF 2.0 scenes (``.gltf`` / ``.glb``): geometry, node hierarchy, animations, cameras, lights, materials.

Parsed with ``json`` + NumPy (trimesh ignores animations), following the glTF 2.0 specification
(Khronos, "glTF 2.0 Specification", 2021; section numbers below are its sections):

* **Buffers** (Sec. 3.6): GLB's binary chunk, ``data:`` URIs (base64) and external files; accessors with
  ``byteStride``, ``normalized`` integers and sparse substitution (Sec. 3.6.2.3).
* **Nodes** (Sec. 3.5): ``matrix`` or TRS, ``M = T * R * S``, world = parent world * local.
* **Animations** (Sec. 3.11): channels on ``translation``, ``rotation``, ``scale`` and morph ``weights``
  with ``STEP``, ``LINEAR`` (slerp for rotations, Appendix C) and ``CUBICSPLINE`` (Hermite with the
  file's tangents scaled by the key interval, Appendix C); every animation of the file plays at once.
  ``loop=False`` (default) clamps each channel to its first / last key; ``loop=True`` wraps time by the
  scene's duration, the last keyframe time over all channels (our choice: the spec leaves playback to
  the application). Time ``t = frame / fps``; glTF has no frame rate, the scene's ``fps`` is 30 unless
  given (``--fps``).
* **Cameras** (Sec. 3.10): perspective; the camera looks down the node's -Z with +Y up. glTF's ``yfov``
  is vertical; :class:`~dyngi.scene.camera.Camera`'s ``fov`` is horizontal, so ``fov_x = 2 atan(aspect
  tan(yfov / 2))`` with the camera's ``aspectRatio`` (the scene then carries a film of that aspect, so
  ``dyngi render`` picks a matching default size), else 4:3 (the default 320x240 film). Rendering at
  another aspect keeps ``fov_x``.
* **Lights** (``KHR_lights_punctual``): point -> ``point`` (intensity ``I_cd / 683`` W/sr per unit
  colour), spot -> ``spot`` (``cutoff_angle`` = outer cone, ``beam_width`` = inner cone; Mitsuba's
  falloff between them replaces glTF's), directional -> ``directional`` (irradiance ``E_lux / 683``);
  683 lm/W, the luminous efficacy Blender's glTF exporter uses, so a Blender light round-trips. ``range``
  is ignored (physical inverse-square falloff).
* **Materials** (Sec. 3.9): metallic-roughness -> Mitsuba ``principled`` (base colour sRGB-decoded
  texture x factor, metallic = B channel, roughness = G channel of ``metallicRoughnessTexture`` x
  factors; ``specular`` 0.5 gives glTF's dielectric F0 = 0.04); ``normalTexture`` -> ``normalmap`` (Mitsuba's
  tangent frame: x along ``dp_du``, y = n x x, which is glTF's +Y, up in the image, for an unmirrored UV
  layout; the file's ``TANGENT`` is not read; approximate);
  ``doubleSided`` -> ``twosided`` (else black from behind); ``alphaMode`` MASK -> ``mask`` with opacity
  ``alpha >= alphaCutoff``, BLEND -> ``mask`` with opacity ``alpha`` (stochastic transparency), OPAQUE
  ignores alpha; emissive (x ``KHR_materials_emissive_strength``) -> ``area`` emitter with that
  radiance. A primitive without a material is grey diffuse 0.8 (ours; the spec's default is a white
  rough metal).
* **Skinning and morph targets** (Sec. 3.7.3, 3.8): positions (and normals) rebuilt on the host per frame,
  ``sum_j w_j J_j(t) IBM_j v`` and ``v + sum_i w_i delta_i``; Mitsuba rebuilds that mesh's BVH
  (``O(vertices)`` host work + one BVH build per frame). The G-buffer's reprojection treats a deforming
  mesh as static (approximate; the disocclusion test catches large motion).

Rigid or affine node motion becomes one :class:`~dyngi.scene.animation.AffineMotion` per mesh primitive
(``transform(t)`` = the node's world matrix at ``t`` on the mesh's local vertices), so motion vectors are
exact. Anything not supported raises one :class:`~dyngi.errors.DyngiError` line; a required extension we
do not implement (e.g. ``KHR_draco_mesh_compression``) is named. Extensions used but not required are
ignored, as the spec allows, and listed in the scene's description. Only ``TEXCOORD_0`` is read.
"""
from __future__ import annotations

import base64
import hashlib
import io
import json
import os
import re
import struct
import urllib.parse
from dataclasses import dataclass, field

import numpy as np

from ..backend import mi
from ..errors import DyngiError
from .animation import AffineMotion, Animator
from .camera import CameraPath, PoseCameraPath, camera_from_bounds
from .core import Scene, default_probe_grid, scene_bounds

SUPPORTED_EXTENSIONS = ("KHR_lights_punctual", "KHR_materials_emissive_strength")
"""Extensions read; any other one listed in ``extensionsRequired`` is an error naming it."""
LUMENS_PER_WATT = 683.0
"""Photometric -> Mitsuba units: ``W = lm / 683`` (KHR_lights_punctual candela and lux; Blender's factor)."""
DEFAULT_ASPECT = 4.0 / 3.0
"""Aspect used to turn a camera's vertical ``yfov`` into our horizontal fov when it has no ``aspectRatio``."""
DEFAULT_FPS = 30.0
"""Frame rate of a glTF scene unless given (glTF animations are in seconds, with no frame rate)."""
BOUND_SAMPLES = 65
"""Times sampled (beside every keyframe) for the probe box covering the whole animation."""

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_NORM = {np.int8: 127.0, np.uint8: 255.0, np.int16: 32767.0, np.uint16: 65535.0}
_WRAP = {10497: "repeat", 33648: "mirror", 33071: "clamp"}
_INTERP = ("STEP", "LINEAR", "CUBICSPLINE")


def _err(path, msg) -> DyngiError:
    return DyngiError(f"glTF file '{path}': {msg}")


# -- file, buffers, accessors (Sec. 3.6) ------------------------------------------------------------------

class GltfFile:
    """The JSON document and its binary buffers; :meth:`accessor` reads an accessor as a NumPy array."""

    def __init__(self, path: str):
        self.path = path
        self.dir = os.path.dirname(os.path.abspath(path))
        with open(path, "rb") as f:
            data = f.read()
        bin_chunk = None
        if data[:4] == b"glTF":
            if len(data) < 20:
                raise _err(path, "truncated GLB header")
            _, version, length = struct.unpack_from("<4sII", data, 0)
            if version != 2:
                raise _err(path, f"GLB version {version} is not supported; valid: 2")
            off, js = 12, None
            while off + 8 <= min(length, len(data)):
                clen, ctype = struct.unpack_from("<II", data, off)
                chunk = data[off + 8:off + 8 + clen]
                if ctype == 0x4E4F534A:
                    js = chunk
                elif ctype == 0x004E4942 and bin_chunk is None:
                    bin_chunk = chunk
                off += 8 + clen
            if js is None:
                raise _err(path, "GLB has no JSON chunk")
        else:
            js = data
        try:
            self.doc = json.loads(js.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as e:
            raise _err(path, f"not valid JSON ({e})") from None
        if not isinstance(self.doc, dict):
            raise _err(path, "not a glTF document (top level is not an object)")
        ver = str(self.doc.get("asset", {}).get("version", ""))
        if not ver.startswith("2"):
            raise _err(path, f"asset version '{ver}' is not supported; valid: 2.x")
        for ext in self.doc.get("extensionsRequired", []):
            if ext not in SUPPORTED_EXTENSIONS:
                raise _err(path, f"requires extension {ext}, which dyngi does not support "
                                 f"(supported: {', '.join(SUPPORTED_EXTENSIONS)})")
        #: extensions the file uses that are not required and that we ignore (the spec allows it)
        self.ignored = sorted(set(self.doc.get("extensionsUsed", [])) - set(SUPPORTED_EXTENSIONS))
        self._bin = bin_chunk
        self._buffers: dict[int, bytes] = {}
        self._acc: dict[int, np.ndarray] = {}

    def get(self, kind: str, i: int) -> dict:
        items = self.doc.get(kind, [])
        if not isinstance(i, int) or not 0 <= i < len(items):
            raise _err(self.path, f"{kind}[{i}] does not exist ({len(items)} {kind})")
        return items[i]

    def _uri_bytes(self, uri: str) -> bytes:
        if uri.startswith("data:"):
            head, _, payload = uri.partition(",")
            if not head.endswith(";base64"):
                return urllib.parse.unquote_to_bytes(payload)
            return base64.b64decode(payload)
        fp = os.path.join(self.dir, urllib.parse.unquote(uri))
        if not os.path.isfile(fp):
            raise _err(self.path, f"external file '{uri}' does not exist (looked in {self.dir})")
        with open(fp, "rb") as f:
            return f.read()

    def buffer(self, i: int) -> bytes:
        if i not in self._buffers:
            b = self.get("buffers", i)
            if "uri" in b:
                data = self._uri_bytes(b["uri"])
            elif self._bin is not None:
                data = self._bin
            else:
                raise _err(self.path, f"buffers[{i}] has no uri and the file has no GLB binary chunk")
            if len(data) < b.get("byteLength", 0):
                raise _err(self.path, f"buffers[{i}] holds {len(data)} bytes, fewer than its byteLength "
                                      f"{b['byteLength']}")
            self._buffers[i] = data
        return self._buffers[i]

    def view_bytes(self, i: int) -> tuple[bytes, int, int | None]:
        """(buffer bytes, start offset, byteStride) of bufferView ``i``."""
        v = self.get("bufferViews", i)
        return self.buffer(v["buffer"]), int(v.get("byteOffset", 0)), v.get("byteStride")

    def _read(self, view: int, offset: int, count: int, dtype, ncomp: int) -> np.ndarray:
        data, start, stride = self.view_bytes(view)
        item = np.dtype(dtype).itemsize * ncomp
        start += offset
        stride = stride or item
        end = start + stride * (count - 1) + item if count else start
        if end > len(data):
            raise _err(self.path, f"bufferViews[{view}] is too short for its accessor")
        if stride == item:
            a = np.frombuffer(data, dtype, count * ncomp, start)
        else:
            raw = np.frombuffer(data, np.uint8, end - start, start)
            rows = np.lib.stride_tricks.as_strided(raw, (count, item), (stride, 1))
            a = np.ascontiguousarray(rows).view(dtype).ravel()
        return a.reshape(count, ncomp)

    def accessor(self, i: int) -> np.ndarray:
        """Accessor ``i`` as (count, components): float64 for floats and ``normalized`` integers, int64 else."""
        if i in self._acc:
            return self._acc[i]
        a = self.get("accessors", i)
        dtype = _COMPONENT.get(a.get("componentType"))
        if dtype is None:
            raise _err(self.path, f"accessors[{i}] has componentType {a.get('componentType')}; "
                                  f"valid: {', '.join(map(str, _COMPONENT))}")
        ncomp = _NCOMP.get(a.get("type"))
        if ncomp is None:
            raise _err(self.path, f"accessors[{i}] has type {a.get('type')}; valid: {', '.join(_NCOMP)}")
        count = int(a.get("count", 0))
        if "bufferView" in a:
            out = self._read(a["bufferView"], int(a.get("byteOffset", 0)), count, dtype, ncomp).copy()
        else:
            out = np.zeros((count, ncomp), dtype)
        sp = a.get("sparse")
        if sp:   # Sec. 3.6.2.3: substitute values at indices
            n = int(sp["count"])
            it = _COMPONENT[sp["indices"]["componentType"]]
            idx = self._read(sp["indices"]["bufferView"], int(sp["indices"].get("byteOffset", 0)), n, it, 1)
            val = self._read(sp["values"]["bufferView"], int(sp["values"].get("byteOffset", 0)), n, dtype, ncomp)
            out[idx.ravel().astype(np.int64)] = val
        if dtype == np.float32:
            res = out.astype(np.float64)
        elif a.get("normalized"):
            res = np.maximum(out.astype(np.float64) / _NORM[dtype], -1.0)
        else:
            res = out.astype(np.int64)
        self._acc[i] = res
        return res

    def image(self, i: int) -> np.ndarray:
        """Image ``i`` decoded by Pillow as float32 (H, W, 4) in [0, 1] (no colour conversion)."""
        from PIL import Image

        im = self.get("images", i)
        if "bufferView" in im:
            data, start, _ = self.view_bytes(im["bufferView"])
            raw = data[start:start + self.get("bufferViews", im["bufferView"])["byteLength"]]
        elif "uri" in im:
            raw = self._uri_bytes(im["uri"])
        else:
            raise _err(self.path, f"images[{i}] has neither uri nor bufferView")
        try:
            pic = Image.open(io.BytesIO(raw))
            pic = pic.convert("RGBA")
        except Exception as e:
            raise _err(self.path, f"images[{i}] could not be decoded ({type(e).__name__}: {e})") from None
        return np.asarray(pic, np.float32) / 255.0


# -- TRS, quaternions, interpolation (Sec. 3.5, 3.11, Appendix C) -----------------------------------------

def quat_to_matrix(q) -> np.ndarray:
    """3x3 rotation of a unit quaternion (x, y, z, w), glTF's order."""
    x, y, z, w = np.asarray(q, np.float64) / max(np.linalg.norm(q), 1e-300)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def trs_matrix(t, r, s) -> np.ndarray:
    """4x4 ``T * R * S`` (Sec. 3.5.2)."""
    M = np.eye(4)
    M[:3, :3] = quat_to_matrix(r) * np.asarray(s, np.float64)[None, :]
    M[:3, 3] = t
    return M


def slerp(q0, q1, a: float) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc (Appendix C), normalised."""
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    d = float(np.dot(q0, q1))
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = (1 - a) * q0 + a * q1
    else:
        th = np.arccos(min(d, 1.0))
        q = (np.sin((1 - a) * th) * q0 + np.sin(a * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


@dataclass
class Channel:
    """One animation channel: a node's ``path`` sampled at ``times`` with ``interp``.

    ``values`` is (keys, n) for STEP/LINEAR and (keys, 3, n) = (in-tangent, value, out-tangent) for
    CUBICSPLINE."""

    node: int
    path: str
    times: np.ndarray
    values: np.ndarray
    interp: str

    def __call__(self, t: float) -> np.ndarray:
        T, V = self.times, self.values
        cubic = self.interp == "CUBICSPLINE"
        val = (lambda k: V[k, 1]) if cubic else (lambda k: V[k])
        if len(T) == 1 or t <= T[0]:
            return val(0).copy()
        if t >= T[-1]:
            return val(len(T) - 1).copy()
        k = int(np.searchsorted(T, t, side="right") - 1)
        dt = T[k + 1] - T[k]
        a = (t - T[k]) / dt
        if self.interp == "STEP":
            return val(k).copy()
        if cubic:       # Appendix C: Hermite spline, tangents scaled by the key interval
            a2, a3 = a * a, a * a * a
            out = ((2 * a3 - 3 * a2 + 1) * V[k, 1] + (a3 - 2 * a2 + a) * dt * V[k, 2]
                   + (-2 * a3 + 3 * a2) * V[k + 1, 1] + (a3 - a2) * dt * V[k + 1, 0])
            return out / np.linalg.norm(out) if self.path == "rotation" else out
        if self.path == "rotation":
            return slerp(V[k], V[k + 1], a)
        return (1 - a) * V[k] + a * V[k + 1]


# -- the node graph over time ---------------------------------------------------------------------------

class NodeGraph:
    """Node hierarchy of the file's scene with its animation channels; world matrices at any time."""

    def __init__(self, f: GltfFile, loop: bool):
        self.f = f
        self.loop = loop
        doc = f.doc
        self.nodes = doc.get("nodes", [])
        n = len(self.nodes)
        self.parent = np.full(n, -1)
        for i, nd in enumerate(self.nodes):
            for c in nd.get("children", []):
                if not 0 <= c < n:
                    raise _err(f.path, f"nodes[{i}] has child {c}, which does not exist")
                self.parent[c] = i
        scenes = doc.get("scenes", [])
        if scenes:
            s = doc.get("scene", 0)
            roots = f.get("scenes", s).get("nodes", [])
        else:
            roots = [i for i in range(n) if self.parent[i] < 0]
        self.order: list[int] = []          # parents before children
        stack = list(reversed(roots))
        seen = set()
        while stack:
            i = stack.pop()
            if i in seen:
                raise _err(f.path, f"nodes[{i}] is reached twice (the node graph is not a tree)")
            seen.add(i)
            self.order.append(i)
            stack.extend(reversed(self.nodes[i].get("children", [])))
        self.channels: list[Channel] = []
        for ai, an in enumerate(doc.get("animations", [])):
            samplers = an.get("samplers", [])
            for ci, ch in enumerate(an.get("channels", [])):
                tgt = ch.get("target", {})
                if "node" not in tgt:
                    continue
                path = tgt.get("path")
                if path not in ("translation", "rotation", "scale", "weights"):
                    raise _err(f.path, f"animations[{ai}].channels[{ci}] targets '{path}'; valid: "
                                       "translation, rotation, scale, weights")
                if not 0 <= ch.get("sampler", -1) < len(samplers):
                    raise _err(f.path, f"animations[{ai}].channels[{ci}] names sampler {ch.get('sampler')}, "
                                       "which does not exist")
                smp = samplers[ch["sampler"]]
                interp = smp.get("interpolation", "LINEAR")
                if interp not in _INTERP:
                    raise _err(f.path, f"animations[{ai}] has interpolation '{interp}'; valid: {', '.join(_INTERP)}")
                times = f.accessor(smp["input"]).ravel().astype(np.float64)
                vals = f.accessor(smp["output"]).astype(np.float64)
                if len(times) == 0 or np.any(np.diff(times) < 0):
                    raise _err(f.path, f"animations[{ai}].samplers[{ch['sampler']}] has no keys or "
                                       "decreasing times")
                k = len(times)
                vals = vals.reshape(k, 3, -1) if interp == "CUBICSPLINE" else vals.reshape(k, -1)
                self.channels.append(Channel(int(tgt["node"]), path, times, vals, interp))
        self.duration = max((float(c.times[-1]) for c in self.channels), default=0.0)
        self.by_node: dict[int, list[Channel]] = {}
        for c in self.channels:
            self.by_node.setdefault(c.node, []).append(c)
        self.animated = set(self.by_node)
        # nodes whose world matrix changes: animated TRS or any ancestor of it
        trs = {c.node for c in self.channels if c.path != "weights"}
        self.moving = set()
        for i in self.order:
            if i in trs or (self.parent[i] >= 0 and self.parent[i] in self.moving):
                self.moving.add(i)
        self._cache_t = None
        self._cache = None

    def local_time(self, t: float) -> float:
        if self.loop and self.duration > 0:
            return float(np.mod(t, self.duration))
        return float(t)

    def local(self, i: int, t: float) -> np.ndarray:
        nd = self.nodes[i]
        if "matrix" in nd:
            return np.asarray(nd["matrix"], np.float64).reshape(4, 4).T     # column-major
        tr = np.asarray(nd.get("translation", (0, 0, 0)), np.float64)
        ro = np.asarray(nd.get("rotation", (0, 0, 0, 1)), np.float64)
        sc = np.asarray(nd.get("scale", (1, 1, 1)), np.float64)
        for c in self.by_node.get(i, ()):
            if c.path == "translation":
                tr = c(t)
            elif c.path == "rotation":
                ro = c(t)
            elif c.path == "scale":
                sc = c(t)
        return trs_matrix(tr, ro, sc)

    def world(self, t: float) -> dict[int, np.ndarray]:
        """World matrix (4x4) of every node of the scene at time ``t`` (cached for the last ``t``)."""
        t = self.local_time(t)
        if self._cache_t != t:
            W = {}
            for i in self.order:
                L = self.local(i, t)
                p = self.parent[i]
                W[i] = W[p] @ L if p >= 0 else L
            self._cache, self._cache_t = W, t
        return self._cache

    def weights(self, i: int, mesh: dict, t: float) -> np.ndarray | None:
        """Morph-target weights of node ``i`` at ``t`` (animated, else node's, else mesh's)."""
        t = self.local_time(t)
        for c in self.by_node.get(i, ()):
            if c.path == "weights":
                return c(t).ravel()
        w = self.nodes[i].get("weights", mesh.get("weights"))
        return None if w is None else np.asarray(w, np.float64)

    def sample_times(self) -> np.ndarray:
        ts = [np.linspace(0.0, self.duration, BOUND_SAMPLES)] + [c.times for c in self.channels]
        return np.unique(np.clip(np.concatenate(ts), 0.0, max(self.duration, 0.0)))

    def node_name(self, i: int) -> str:
        return self.nodes[i].get("name") or f"node{i}"


# -- meshes --------------------------------------------------------------------------------------------

@dataclass
class Primitive:
    sid: str
    node: int
    V: np.ndarray            # local positions (rest pose)
    N: np.ndarray | None
    UV: np.ndarray | None
    F: np.ndarray
    material: int | None
    targets: list = field(default_factory=list)    # [(dV, dN or None)]
    joints: np.ndarray | None = None
    weights: np.ndarray | None = None
    mesh: dict = field(default_factory=dict)


def _triangles(path, mode: int, idx: np.ndarray, where: str) -> np.ndarray | None:
    if mode == 4:
        if len(idx) % 3:
            raise _err(path, f"{where}: {len(idx)} indices is not a multiple of 3")
        return idx.reshape(-1, 3)
    if mode == 5:     # strip: alternate winding
        k = np.arange(len(idx) - 2)
        F = np.stack([idx[k], idx[k + 1], idx[k + 2]], 1)
        F[1::2] = F[1::2][:, [1, 0, 2]]
        return F
    if mode == 6:     # fan
        k = np.arange(1, len(idx) - 1)
        return np.stack([np.full(len(k), idx[0]), idx[k], idx[k + 1]], 1)
    return None       # points and lines have no surface


def _sanitize(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]", "_", name) or "mesh"


def _primitives(f: GltfFile, g: NodeGraph) -> list[Primitive]:
    out, used = [], set()
    for i in g.order:
        nd = g.nodes[i]
        if "mesh" not in nd:
            continue
        mesh = f.get("meshes", nd["mesh"])
        for pi, pr in enumerate(mesh.get("primitives", [])):
            where = f"meshes[{nd['mesh']}].primitives[{pi}]"
            att = pr.get("attributes", {})
            if "POSITION" not in att:
                raise _err(f.path, f"{where} has no POSITION attribute")
            V = f.accessor(att["POSITION"])[:, :3].astype(np.float64)
            idx = (f.accessor(pr["indices"]).ravel() if "indices" in pr else np.arange(len(V))).astype(np.int64)
            F = _triangles(f.path, pr.get("mode", 4), idx, where)
            if F is None or len(F) == 0:
                continue
            if F.max() >= len(V) or F.min() < 0:
                raise _err(f.path, f"{where} has indices outside its {len(V)} vertices")
            N = f.accessor(att["NORMAL"])[:, :3] if "NORMAL" in att else None
            UV = f.accessor(att["TEXCOORD_0"])[:, :2] if "TEXCOORD_0" in att else None
            targets = []
            for tg in pr.get("targets", []):
                dV = f.accessor(tg["POSITION"])[:, :3] if "POSITION" in tg else np.zeros_like(V)
                dN = f.accessor(tg["NORMAL"])[:, :3] if ("NORMAL" in tg and N is not None) else None
                targets.append((dV, dN))
            joints = weights = None
            if "skin" in nd and "JOINTS_0" in att and "WEIGHTS_0" in att:
                joints = f.accessor(att["JOINTS_0"]).astype(np.int64)
                weights = f.accessor(att["WEIGHTS_0"]).astype(np.float64)
            base = _sanitize(f"{g.node_name(i)}_{pi}" if len(mesh["primitives"]) > 1 else g.node_name(i))
            sid, k = base, 1
            while sid in used:
                k += 1
                sid = f"{base}_{k}"
            used.add(sid)
            out.append(Primitive(sid, i, V, N, UV, F, pr.get("material"), targets, joints, weights, mesh))
    return out


class Deformer:
    """Skinned / morphed positions of one primitive at a time (Sec. 3.7.3 skins, Sec. 3.8 morph targets)."""

    def __init__(self, f: GltfFile, g: NodeGraph, pr: Primitive):
        self.g, self.pr = g, pr
        nd = g.nodes[pr.node]
        self.skin = f.get("skins", nd["skin"]) if pr.joints is not None else None
        if self.skin is not None:
            self.joint_nodes = list(self.skin["joints"])
            nj = len(self.joint_nodes)
            if "inverseBindMatrices" in self.skin:
                self.ibm = f.accessor(self.skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
            else:
                self.ibm = np.broadcast_to(np.eye(4), (nj, 4, 4))
            if pr.joints.max() >= nj:
                raise _err(f.path, f"mesh primitive '{pr.sid}' names joint {pr.joints.max()} of a skin "
                                   f"with {nj} joints")

    def __call__(self, t: float):
        """(positions, normals or None) in world space at ``t``."""
        pr = self.pr
        V = pr.V.copy()
        N = None if pr.N is None else pr.N.copy()
        w = self.g.weights(pr.node, pr.mesh, t) if pr.targets else None
        if w is not None:
            for wi, (dV, dN) in zip(w, pr.targets):
                V += wi * dV
                if N is not None and dN is not None:
                    N += wi * dN
        W = self.g.world(t)
        if self.skin is not None:      # the mesh node's own transform is ignored (Sec. 3.7.3)
            J = np.stack([W[j] for j in self.joint_nodes]) @ self.ibm           # (nj, 4, 4)
            ws = pr.weights / np.maximum(pr.weights.sum(1, keepdims=True), 1e-12)
            B = np.einsum("vk,vkij->vij", ws, J[pr.joints])                        # (nv, 4, 4)
            P = np.einsum("vij,vj->vi", B[:, :3, :3], V) + B[:, :3, 3]
            if N is not None:
                N = np.einsum("vij,vj->vi", np.linalg.inv(B[:, :3, :3]).transpose(0, 2, 1), N)
        else:
            M = W[pr.node]
            P = V @ M[:3, :3].T + M[:3, 3]
            if N is not None:
                N = N @ np.linalg.inv(M[:3, :3])
        if N is not None:
            N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)
        return P, N


@dataclass
class DeformMotion(Animator):
    """Writes a skinned or morphed mesh's vertices (and normals) per frame; no ``transform``: the G-buffer's
    reprojection treats it as static (approximate, module docstring)."""

    shape: str
    deform: object = None

    def apply(self, params, t):
        P, N = self.deform(t)
        params[f"{self.shape}.vertex_positions"] = P.astype(np.float32).ravel()
        if N is not None and f"{self.shape}.vertex_normals" in params:
            params[f"{self.shape}.vertex_normals"] = N.astype(np.float32).ravel()

    def signature(self, t):
        P, _ = self.deform(t)
        return (hashlib.sha256(np.round(P, 6).tobytes()).hexdigest()[:16],)


def _mi_mesh(sid: str, V, N, UV, F, bsdf, emitter) -> "mi.Mesh":
    props = mi.Properties()
    props["bsdf"] = bsdf if not isinstance(bsdf, dict) else mi.load_dict(bsdf)
    if emitter is not None:
        props["emitter"] = mi.load_dict(emitter)
    m = mi.Mesh(sid, len(V), len(F), props, has_vertex_normals=N is not None,
                has_vertex_texcoords=UV is not None)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(np.asarray(V, np.float32).ravel())
    p["faces"] = mi.UInt32(np.asarray(F, np.uint32).ravel())
    if N is not None:
        p["vertex_normals"] = mi.Float(np.asarray(N, np.float32).ravel())
    if UV is not None:
        p["vertex_texcoords"] = mi.Float(np.asarray(UV, np.float32).ravel())
    p.update()
    return m


# -- materials (Sec. 3.9) ------------------------------------------------------------------------------

def srgb_to_linear(c):
    """The sRGB EOTF (IEC 61966-2-1), elementwise."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class Materials:
    """glTF materials -> Mitsuba BSDF dicts and emitter dicts (module docstring)."""

    def __init__(self, f: GltfFile):
        self.f = f
        self._img: dict[int, np.ndarray] = {}
        self._loaded: dict = {}

    def load(self, mi_index: int | None):
        """(the material's Mitsuba BSDF, loaded once and shared by every primitive using it; its area emitter
        dict or None: an emitter belongs to one shape, so each primitive loads its own)."""
        if mi_index not in self._loaded:
            bsdf, emitter = self.bsdf(mi_index)
            self._loaded[mi_index] = (mi.load_dict(bsdf), emitter)
        return self._loaded[mi_index]

    def _texture(self, info: dict | None):
        """(RGBA float32 (H, W, 4) non-linear as stored, sampler dict) of a textureInfo, or None."""
        if not info:
            return None
        tex = self.f.get("textures", info["index"])
        if "source" not in tex:
            raise _err(self.f.path, f"textures[{info['index']}] has no source image (only PNG/JPEG sources "
                                    "are supported)")
        src = tex["source"]
        if src not in self._img:
            self._img[src] = self.f.image(src)
        smp = self.f.get("samplers", tex["sampler"]) if "sampler" in tex else {}
        opts = {"wrap_mode": _WRAP.get(smp.get("wrapS", 10497), "repeat"),
                "filter_type": "nearest" if smp.get("magFilter") == 9728 else "bilinear"}
        return self._img[src], opts

    @staticmethod
    def _bitmap(arr, opts) -> dict:
        return dict({"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(arr, np.float32)), "raw": True},
                    **opts)

    def bsdf(self, mi_index: int | None) -> tuple[dict, dict | None]:
        """(BSDF dict, area emitter dict or None) for material ``mi_index``."""
        if mi_index is None:
            return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}, None
        m = self.f.get("materials", mi_index)
        pbr = m.get("pbrMetallicRoughness", {})
        fac = np.asarray(pbr.get("baseColorFactor", (1, 1, 1, 1)), np.float64)
        metal, rough = float(pbr.get("metallicFactor", 1.0)), float(pbr.get("roughnessFactor", 1.0))
        alpha_tex = None
        t = self._texture(pbr.get("baseColorTexture"))
        if t is not None:
            img, opts = t
            rgb = srgb_to_linear(img[..., :3]) * fac[:3]
            base = self._bitmap(rgb, opts)
            alpha_tex = (img[..., 3] * fac[3], opts)
        else:
            base = {"type": "rgb", "value": [float(x) for x in fac[:3]]}
        t = self._texture(pbr.get("metallicRoughnessTexture"))
        if t is not None:
            img, opts = t
            metallic = self._bitmap(img[..., 2] * metal, opts)
            roughness = self._bitmap(img[..., 1] * rough, opts)
        else:
            metallic, roughness = metal, rough
        bsdf = {"type": "principled", "base_color": base, "metallic": metallic, "roughness": roughness}
        t = self._texture(m.get("normalTexture"))
        if t is not None:     # tangent space: x along dp_du, y = n x s (up in the image, as glTF's +Y)
            img, opts = t
            s = float(m["normalTexture"].get("scale", 1.0))
            n = img[..., :3] * 2.0 - 1.0
            n[..., :2] *= s
            n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
            bsdf = {"type": "normalmap", "normalmap": self._bitmap(n * 0.5 + 0.5, opts), "bsdf": bsdf}
        if m.get("doubleSided", False):
            bsdf = {"type": "twosided", "bsdf": bsdf}
        mode = m.get("alphaMode", "OPAQUE")
        if mode not in ("OPAQUE", "MASK", "BLEND"):
            raise _err(self.f.path, f"materials[{mi_index}] has alphaMode '{mode}'; valid: OPAQUE, MASK, BLEND")
        if mode != "OPAQUE":
            cut = float(m.get("alphaCutoff", 0.5))
            if alpha_tex is not None:
                a, opts = alpha_tex
                a = (a >= cut).astype(np.float32) if mode == "MASK" else a
                opacity = self._bitmap(a, opts)
            else:
                a = fac[3]
                opacity = float(a >= cut) if mode == "MASK" else float(a)
            if not (isinstance(opacity, float) and opacity >= 1.0):
                bsdf = {"type": "mask", "opacity": opacity, "bsdf": bsdf}
        # -- emission (KHR_materials_emissive_strength) --
        e = np.asarray(m.get("emissiveFactor", (0, 0, 0)), np.float64)
        e = e * float(m.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0))
        emitter = None
        if np.max(e) > 0:
            t = self._texture(m.get("emissiveTexture"))
            if t is not None:
                img, opts = t
                rad = self._bitmap(srgb_to_linear(img[..., :3]) * e, opts)
            else:
                rad = {"type": "rgb", "value": [float(x) for x in e]}
            emitter = {"type": "area", "radiance": rad}
        return bsdf, emitter


# -- lights (KHR_lights_punctual) and cameras (Sec. 3.10) ------------------------------------------------

def _light_dict(path, light: dict, W: np.ndarray) -> dict:
    kind = light.get("type")
    col = np.asarray(light.get("color", (1, 1, 1)), np.float64)
    I = float(light.get("intensity", 1.0)) / LUMENS_PER_WATT
    rgb = {"type": "rgb", "value": [float(x) for x in col * I]}
    o, fwd, up = _frame(W)
    if kind == "point":
        return {"type": "point", "position": [float(x) for x in o], "intensity": rgb}
    if kind == "spot":
        sp = light.get("spot", {})
        outer = np.degrees(float(sp.get("outerConeAngle", np.pi / 4)))
        inner = min(np.degrees(float(sp.get("innerConeAngle", 0.0))), outer * 0.999)
        return {"type": "spot", "to_world": _look_at(o, fwd, up), "intensity": rgb,
                "cutoff_angle": float(outer), "beam_width": float(inner)}
    if kind == "directional":
        return {"type": "directional", "to_world": _look_at(np.zeros(3), fwd, up), "irradiance": rgb}
    raise _err(path, f"light type '{kind}'; valid: point, spot, directional")


def _frame(W):
    """(origin, forward = -Z, up = +Y) of a node's world matrix, normalised."""
    o = W[:3, 3].copy()
    fwd = -W[:3, 2] / max(np.linalg.norm(W[:3, 2]), 1e-30)
    up = W[:3, 1] / max(np.linalg.norm(W[:3, 1]), 1e-30)
    return o, fwd, up


def _look_at(o, fwd, up):
    if abs(np.dot(fwd, up)) > 0.999:
        up = np.array([0.0, 0.0, 1.0]) if abs(fwd[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    return mi.ScalarTransform4f().look_at(origin=[float(x) for x in o], target=[float(x) for x in o + fwd],
                                          up=[float(x) for x in up])


@dataclass
class LightMotion(Animator):
    """A punctual light on an animated node: writes its ``position`` (point) or ``to_world`` (spot,
    directional) from the node's world matrix."""

    emitter: str = ""
    kind: str = "point"
    pose: object = None      # t -> 4x4 world matrix

    def apply(self, params, t):
        o, fwd, up = _frame(self.pose(t))
        if self.kind == "point":
            params[f"{self.emitter}.position"] = [float(x) for x in o]
        else:
            params[f"{self.emitter}.to_world"] = _look_at(np.zeros(3) if self.kind == "directional" else o, fwd, up)

    def signature(self, t):
        return tuple(np.round(self.pose(t)[:3].ravel(), 9))


def _cameras(f: GltfFile, g: NodeGraph):
    """[(name, node, camera dict)] in scene order; a camera is found by its own name or its node's."""
    out = []
    for i in g.order:
        nd = g.nodes[i]
        if "camera" in nd:
            cam = f.get("cameras", nd["camera"])
            out.append((cam.get("name") or g.node_name(i), i, cam))
    return out


def horizontal_fov(yfov_rad: float, aspect: float) -> float:
    """Our horizontal fov (degrees) from glTF's vertical ``yfov`` (radians) and an aspect (width / height)."""
    return float(np.degrees(2.0 * np.arctan(aspect * np.tan(0.5 * yfov_rad))))


# -- the loader -----------------------------------------------------------------------------------------

def load_gltf(path: str, *, name: str | None = None, fps: float | None = None, camera: str | None = None,
              loop: bool = False) -> Scene:
    """A :class:`~dyngi.scene.core.Scene` from a glTF 2.0 file (module docstring)."""
    f = GltfFile(path)
    g = NodeGraph(f, loop)
    W0 = g.world(0.0)
    mats = Materials(f)
    items: dict = {"type": "scene"}
    animators: list = []
    prims = _primitives(f, g)
    if not prims:
        raise _err(path, "contains no triangle meshes")
    has_light = False
    moving_prims = []
    for pr in prims:
        bsdf, emitter = mats.load(pr.material)
        has_light |= emitter is not None
        deforms = pr.joints is not None or (pr.targets and (g.weights(pr.node, pr.mesh, 0.0) is not None))
        F = pr.F
        if deforms:
            dfm = Deformer(f, g, pr)
            P, N = dfm(0.0)
            if pr.joints is not None:       # a skin moves with its joints (its own node's transform is ignored)
                moves = any(j in g.moving for j in dfm.joint_nodes)
            else:
                moves = pr.node in g.moving
            moves |= bool(pr.targets) and any(c.path == "weights" for c in g.by_node.get(pr.node, ()))
            if moves:
                animators.append(DeformMotion(shape=pr.sid, deform=dfm))
                moving_prims.append(("deform", pr, dfm))
        else:
            M = W0[pr.node]
            P = pr.V @ M[:3, :3].T + M[:3, 3]
            N = None
            if pr.N is not None:
                N = pr.N @ np.linalg.inv(M[:3, :3])
                N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)
            if np.linalg.det(M[:3, :3]) < 0:      # Sec. 3.7.2.1: a mirroring transform flips the winding
                F = F[:, ::-1]
            if pr.node in g.moving:
                node = pr.node
                animators.append(AffineMotion(
                    shape=pr.sid, motion=lambda t, node=node: (g.world(t)[node][:3, :3], g.world(t)[node][:3, 3]),
                    base=pr.V, base_normals=pr.N))
                moving_prims.append(("affine", pr, None))
        if not np.all(np.isfinite(P)):
            raise _err(path, f"mesh '{pr.sid}' has vertices with NaN/Inf coordinates")
        items[pr.sid] = _mi_mesh(pr.sid, P, N, pr.UV, F, bsdf, emitter)
    # -- punctual lights --
    lights = f.doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    for i in g.order:
        ext = g.nodes[i].get("extensions", {}).get("KHR_lights_punctual")
        if ext is None:
            continue
        li = ext.get("light")
        if not isinstance(li, int) or not 0 <= li < len(lights):
            raise _err(path, f"nodes[{i}] names light {li}, which does not exist ({len(lights)} lights)")
        lid = _sanitize(f"light_{g.node_name(i)}")
        while lid in items:
            lid += "_"
        items[lid] = _light_dict(path, lights[li], W0[i])
        has_light = True
        if i in g.moving:
            animators.append(LightMotion(emitter=lid, kind=lights[li].get("type"),
                                         pose=lambda t, i=i: g.world(t)[i]))
    if not has_light:
        items["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
    # -- camera --
    cams = _cameras(f, g)
    chosen = None
    if camera is not None:
        hits = [c for c in cams if c[0] == camera or g.node_name(c[1]) == camera]
        if not hits:
            raise _err(path, f"has no camera named '{camera}'; cameras: "
                             f"{', '.join(c[0] for c in cams) if cams else 'none'}")
        chosen = hits[0]
    else:
        chosen = next((c for c in cams if c[2].get("type") == "perspective"), None)
    aspect = DEFAULT_ASPECT
    cam_path = None
    if chosen is not None:
        cname, node, cam = chosen
        if cam.get("type") != "perspective":
            raise _err(path, f"camera '{cname}' is {cam.get('type')}; only perspective cameras are supported")
        per = cam.get("perspective", {})
        aspect = float(per.get("aspectRatio") or DEFAULT_ASPECT)
        fov = horizontal_fov(float(per.get("yfov", 0.8)), aspect)
        if node in g.moving:
            cam_path = PoseCameraPath(lambda t, node=node: g.world(t)[node], fov)
        else:
            cam_path = PoseCameraPath.fixed_pose(W0[node], fov)
        if per.get("aspectRatio"):
            items["sensor"] = {"type": "perspective", "fov": fov, "fov_axis": "x",
                               "film": {"type": "hdrfilm", "width": 320, "height": max(1, int(round(320 / aspect)))}}
    mis = mi.load_dict(items)
    # -- probe box over the whole animation --
    lo, hi = _animation_bounds(mis, g, moving_prims)
    box, counts = default_probe_grid(lo, hi)
    if cam_path is None:
        cam_path = CameraPath.fixed(camera_from_bounds(*scene_bounds(mis)))
    nm = name or os.path.splitext(os.path.basename(path))[0]
    desc = (f"loaded from {path} (glTF: {len(prims)} mesh primitive(s), {len(g.channels)} animation "
            f"channel(s), {len(lights)} punctual light(s), {len(cams)} camera(s)"
            + (f"; ignored extensions: {', '.join(f.ignored)}" if f.ignored else "") + ")")
    return Scene(nm, mis, cam_path, animators, desc, duration=g.duration if g.duration > 0 else 4.0,
                 fps=float(fps) if fps is not None else DEFAULT_FPS, probe_box=box, probe_counts=counts, source=path)


def _animation_bounds(mis, g: NodeGraph, moving) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the scene over the animation: every keyframe time and :data:`BOUND_SAMPLES` times in between,
    each moving mesh's box grown by the largest step of its corners (vertices) between consecutive samples, so
    a curve (slerp, a cubic spline) bulging between samples stays inside."""
    lo, hi = scene_bounds(mis)
    if not moving:
        return lo, hi
    ts = g.sample_times() if not g.loop else np.linspace(0.0, g.duration, BOUND_SAMPLES)
    for kind, pr, dfm in moving:
        if kind == "affine":     # an affine map of the local box's corners bounds the mesh
            a, b = pr.V.min(0), pr.V.max(0)
            C = np.array([[x, y, z] for x in (a[0], b[0]) for y in (a[1], b[1]) for z in (a[2], b[2])])
            pos = lambda t, C=C, node=pr.node: C @ g.world(t)[node][:3, :3].T + g.world(t)[node][:3, 3]  # noqa: E731
        else:
            ts = ts[:: max(1, len(ts) // 17)]
            pos = lambda t, dfm=dfm: dfm(t)[0]  # noqa: E731
        prev, plo, phi, pad = None, lo, hi, np.zeros(3)
        for t in ts:
            P = pos(t)
            plo, phi = np.minimum(plo, P.min(0)), np.maximum(phi, P.max(0))
            if prev is not None:
                pad = np.maximum(pad, np.abs(P - prev).max(0))
            prev = P
        lo, hi = np.minimum(lo, plo - pad), np.maximum(hi, phi + pad)
    return lo, hi
