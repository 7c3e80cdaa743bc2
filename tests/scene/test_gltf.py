"""glTF 2.0 scenes written by the tests themselves (not by trimesh, which ignores animations):

* an animated hierarchy (two meshes under an animated parent; translation and rotation channels in STEP,
  LINEAR and CUBICSPLINE; an animated camera; a point light; an emissive mesh) places every vertex where
  this file's own evaluation of the keyframes puts them (scipy's Slerp and Rotation, the spec's Hermite
  formula), its normals by the inverse transpose, clamped or looping;
* rendered at chosen times it matches, in distribution, a Mitsuba scene this file builds at those poses
  (per-pixel and whole-image z-tests, tests/stats.py), and the same test rejects a wrong pose;
* a textured metallic-roughness sphere matches Mitsuba's ``principled`` with Mitsuba's own PNG decoding, at
  equal spp;
* the G-buffer's motion map of an affine (scaled, rotating) node takes vertices at t to their place at t';
* skinning and morph targets move vertices as the test's own blend puts them;
* bad files give one clear line naming the problem.
"""
from __future__ import annotations

import base64
import json
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from dyngi.backend import mi
from dyngi.errors import DyngiError
from dyngi.scene import load_scene
from stats import z_test_images

FLOAT, UINT32 = 5126, 5125


class Writer:
    """A minimal glTF 2.0 writer: one buffer, one bufferView per accessor."""

    def __init__(self):
        self.blob = bytearray()
        self.doc = {"asset": {"version": "2.0"}, "buffers": [], "bufferViews": [], "accessors": []}

    def acc(self, arr, type_, ctype=FLOAT):
        a = np.ascontiguousarray(arr, np.float32 if ctype == FLOAT else {UINT32: np.uint32, 5123: np.uint16,
                                                                           5121: np.uint8}[ctype])
        while len(self.blob) % 4:
            self.blob.append(0)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": a.nbytes})
        self.blob += a.tobytes()
        n = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}[type_]
        acc = {"bufferView": len(self.doc["bufferViews"]) - 1, "componentType": ctype, "count": a.size // n,
               "type": type_}
        if ctype == FLOAT:
            r = a.reshape(-1, n)
            acc["min"], acc["max"] = r.min(0).tolist(), r.max(0).tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def mesh(self, V, F, material=None, N=None, UV=None, extra=None):
        att = {"POSITION": self.acc(V, "VEC3")}
        if N is not None:
            att["NORMAL"] = self.acc(N, "VEC3")
        if UV is not None:
            att["TEXCOORD_0"] = self.acc(UV, "VEC2")
        prim = {"attributes": att, "indices": self.acc(np.asarray(F).ravel(), "SCALAR", UINT32)}
        if material is not None:
            prim["material"] = material
        prim.update(extra or {})
        self.doc.setdefault("meshes", []).append({"primitives": [prim]})
        return len(self.doc["meshes"]) - 1

    def save(self, path, mode="embedded"):
        doc = json.loads(json.dumps(self.doc))
        blob = bytes(self.blob)
        if mode == "glb":
            doc["buffers"] = [{"byteLength": len(blob)}]
            js = json.dumps(doc).encode()
            js += b" " * (-len(js) % 4)
            blob += b"\0" * (-len(blob) % 4)
            body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + blob
            path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
            return path
        if mode == "external":
            (path.parent / "data.bin").write_bytes(blob)
            doc["buffers"] = [{"byteLength": len(blob), "uri": "data.bin"}]
        else:
            doc["buffers"] = [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64,"
                               + base64.b64encode(blob).decode()}]
        path.write_text(json.dumps(doc))
        return path


def box24(half):
    """A box of 24 vertices (flat normals per face) and 12 triangles, outward."""
    h = np.asarray(half, np.float64)
    V, N, F = [], [], []
    for ax in range(3):
        for s in (-1.0, 1.0):
            n = np.zeros(3); n[ax] = s
            u = np.zeros(3); u[(ax + 1) % 3] = 1.0
            v = np.cross(n, u)
            c = n * h
            k = len(V)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                V.append(c + a * u * h + b * v * h)
                N.append(n)
            F += [[k, k + 1, k + 2], [k, k + 2, k + 3]]
    return np.array(V), np.array(N), np.array(F)


def quat_y(deg):
    return Rotation.from_euler("y", deg, degrees=True).as_quat()      # (x, y, z, w), glTF's order


def quat_x(deg):
    return Rotation.from_euler("x", deg, degrees=True).as_quat()


# -- the animated hierarchy: keyframes, and this file's own evaluation of them --------------------------
RIG_T = dict(times=[0.0, 1.0, 2.0], values=[[0, 0, 0], [0.5, 0, 0], [0.5, 0, -0.5]])
RIG_R = dict(times=[0.0, 1.0, 2.0], values=[quat_y(0), quat_y(60), quat_y(150)])
A_T = dict(times=[0.0, 0.5, 1.5], values=[[-0.6, 0.3, 0], [-0.6, 0.6, 0], [-0.4, 0.3, 0.2]])
A_R = dict(times=[0.0, 0.7], values=[quat_x(0), quat_x(40)])
A_S = [0.8, 1.5, 0.6]                      # static non-uniform scale: the motion is affine, not rigid
B_T = dict(times=[0.0, 1.2, 2.4], values=[[0.6, 0.3, 0], [0.7, 0.8, 0.1], [0.6, 0.4, 0.3]],
           tin=[[0, 0, 0], [0.3, -0.2, 0.1], [0.1, 0.1, 0]], tout=[[0.5, 0.4, 0], [-0.2, 0.1, 0.3], [0, 0, 0]])
B_R = dict(times=[0.0, 2.4], values=[quat_y(0), quat_y(90)], tin=[[0, 0, 0, 0], [0, 0.2, 0, 0]],
           tout=[[0, 0.3, 0, 0], [0, 0, 0, 0]])
CAM_T = dict(times=[0.0, 2.4], values=[[0, 1.2, 3.2], [0.4, 1.3, 3.0]])
CAM_R = quat_x(-12)
YFOV, ASPECT = 0.75, 4.0 / 3.0
LIGHT_CD, LIGHT_POS = 683.0 * 3.0, [0.0, 2.5, 1.5]
EMISSIVE, STRENGTH = [1.0, 0.5, 0.2], 2.0


def step(k, t):
    i = int(np.clip(np.searchsorted(k["times"], t, side="right") - 1, 0, len(k["times"]) - 1))
    return np.asarray(k["values"][i], np.float64)


def lerp(k, t):
    tt = np.clip(t, k["times"][0], k["times"][-1])
    return np.array([np.interp(tt, k["times"], np.asarray(k["values"])[:, j]) for j in range(3)])


def slerp(k, t):
    tt = float(np.clip(t, k["times"][0], k["times"][-1]))
    return Slerp(k["times"], Rotation.from_quat(k["values"]))(tt).as_matrix()


def hermite(k, t, rotation=False):
    """glTF 2.0 Appendix C, written out: p(s) = (2s^3-3s^2+1) v_k + (s^3-2s^2+s) dt b_k + (-2s^3+3s^2) v_k+1
    + (s^3-s^2) dt a_k+1."""
    T = k["times"]
    v, a, b = (np.asarray(k[x], np.float64) for x in ("values", "tin", "tout"))
    if t <= T[0]:
        p = v[0]
    elif t >= T[-1]:
        p = v[-1]
    else:
        i = int(np.searchsorted(T, t, side="right") - 1)
        dt = T[i + 1] - T[i]
        s = (t - T[i]) / dt
        p = ((2 * s**3 - 3 * s**2 + 1) * v[i] + (s**3 - 2 * s**2 + s) * dt * b[i]
             + (-2 * s**3 + 3 * s**2) * v[i + 1] + (s**3 - s**2) * dt * a[i + 1])
    return Rotation.from_quat(p / np.linalg.norm(p)).as_matrix() if rotation else p


def affine(R, T, S=(1, 1, 1)):
    M = np.eye(4)
    M[:3, :3] = R @ np.diag(S)
    M[:3, 3] = T
    return M


def expected_worlds(t):
    """World matrices of 'a', 'b' and the camera at t, by this file's own evaluation."""
    rig = affine(slerp(RIG_R, t), lerp(RIG_T, t))
    a = rig @ affine(Rotation.from_quat(step(A_R, t)).as_matrix(), step(A_T, t), A_S)
    b = rig @ affine(hermite(B_R, t, rotation=True), hermite(B_T, t))
    cam = affine(Rotation.from_quat(CAM_R).as_matrix(), lerp(CAM_T, t))
    return {"a": a, "b": b, "cam": cam}


def channel(w, anim, node, path, k, interp):
    times = w.acc(k["times"], "SCALAR")
    vals = np.asarray(k["values"], np.float64)
    if interp == "CUBICSPLINE":
        vals = np.stack([np.asarray(k["tin"]), vals, np.asarray(k["tout"])], 1)
    out = w.acc(vals.ravel(), "VEC4" if path == "rotation" else "VEC3")
    anim["samplers"].append({"input": times, "output": out, "interpolation": interp})
    anim["channels"].append({"sampler": len(anim["samplers"]) - 1, "target": {"node": node, "path": path}})


A_HALF, B_HALF = (0.2, 0.15, 0.25), (0.15, 0.15, 0.15)
FLOOR_V = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]], np.float64)
FLOOR_F = np.array([[0, 2, 1], [0, 3, 2]])                 # normal +y


def write_rig(path, mode="embedded"):
    w = Writer()
    d = w.doc
    d["materials"] = [
        {"name": "grey", "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.7, 0.7, 1], "metallicFactor": 0.0,
                                                  "roughnessFactor": 0.6}},
        {"name": "red", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.2, 0.1, 1], "metallicFactor": 0.3,
                                                 "roughnessFactor": 0.4}},
        {"name": "lamp", "pbrMetallicRoughness": {"baseColorFactor": [0.1, 0.1, 0.1, 1], "metallicFactor": 0.0},
         "emissiveFactor": EMISSIVE, "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": STRENGTH}}},
    ]
    Va, Na, Fa = box24(A_HALF)
    Vb, _, Fb = box24(B_HALF)
    m_floor = w.mesh(FLOOR_V, FLOOR_F, 0)
    m_a = w.mesh(Va, Fa, 1, N=Na)
    m_b = w.mesh(Vb, Fb, 2)
    d["extensionsUsed"] = ["KHR_lights_punctual", "KHR_materials_emissive_strength"]
    d["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": LIGHT_CD,
                                                           "color": [1.0, 0.9, 0.8]}]}}
    d["cameras"] = [{"name": "main", "type": "perspective",
                     "perspective": {"yfov": YFOV, "aspectRatio": ASPECT, "znear": 0.01}},
                    {"name": "side", "type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.01}}]
    d["nodes"] = [
        {"name": "floor", "mesh": m_floor},
        {"name": "rig", "children": [2, 3]},
        {"name": "a", "mesh": m_a, "scale": A_S},
        {"name": "b", "mesh": m_b},
        {"name": "cam", "camera": 0, "rotation": list(CAM_R)},
        {"name": "lamp", "translation": LIGHT_POS, "extensions": {"KHR_lights_punctual": {"light": 0}}},
        {"name": "sidecam", "camera": 1, "translation": [3, 1, 0], "rotation": list(quat_y(90))},
    ]
    d["scenes"] = [{"nodes": [0, 1, 4, 5, 6]}]
    d["scene"] = 0
    anim = {"samplers": [], "channels": []}
    channel(w, anim, 1, "translation", RIG_T, "LINEAR")
    channel(w, anim, 1, "rotation", RIG_R, "LINEAR")
    channel(w, anim, 2, "translation", A_T, "STEP")
    channel(w, anim, 2, "rotation", A_R, "STEP")
    anim2 = {"samplers": [], "channels": []}           # a second animation: every one plays at once
    channel(w, anim2, 3, "translation", B_T, "CUBICSPLINE")
    channel(w, anim2, 3, "rotation", B_R, "CUBICSPLINE")
    channel(w, anim2, 4, "translation", CAM_T, "LINEAR")
    d["animations"] = [anim, anim2]
    return w.save(path, mode), (Va, Na, Vb)


def positions(sc, sid):
    return np.asarray(sc.params[f"{sid}.vertex_positions"], np.float64).reshape(-1, 3)


TIMES = (0.0, 0.35, 0.6, 1.1, 1.7, 2.2, 3.0)       # between keys of every channel, and past the last (clamped)


@pytest.mark.parametrize("mode", ["embedded", "glb", "external"])
def test_vertices_follow_the_tests_own_keyframe_evaluation(tmp_path, mode):
    path, (Va, Na, Vb) = write_rig(tmp_path / ("rig.glb" if mode == "glb" else "rig.gltf"), mode)
    sc = load_scene(str(path))
    assert sc.duration == pytest.approx(2.4)                  # the last keyframe over all channels
    assert sc.fps == 30.0 and set(sc.meta.dynamic_shapes) == {"a", "b"}
    for t in TIMES:
        sc.at(t)
        E = expected_worlds(t)
        for sid, V in (("a", Va), ("b", Vb)):
            M = E[sid]
            np.testing.assert_allclose(positions(sc, sid), V @ M[:3, :3].T + M[:3, 3], atol=2e-5,
                                       err_msg=f"{sid} at t={t}")
        n = np.asarray(sc.params["a.vertex_normals"], np.float64).reshape(-1, 3)
        n_exp = Na @ np.linalg.inv(E["a"][:3, :3])
        n_exp /= np.linalg.norm(n_exp, axis=1, keepdims=True)
        np.testing.assert_allclose(n, n_exp, atol=2e-5)
        np.testing.assert_allclose(positions(sc, "floor"), FLOOR_V, atol=1e-6)
        cam = sc.camera(t)
        C = E["cam"]
        np.testing.assert_allclose(cam.origin, C[:3, 3], atol=1e-9)
        np.testing.assert_allclose(np.subtract(cam.target, cam.origin), -C[:3, 2], atol=1e-9)
        assert cam.fov == pytest.approx(np.degrees(2 * np.arctan(ASPECT * np.tan(YFOV / 2))))


def test_loop_wraps_at_the_last_keyframe_and_fps_sets_frame_times(tmp_path):
    path, (Va, _, _) = write_rig(tmp_path / "rig.gltf")
    sc = load_scene(str(path), loop=True, fps=24)
    assert sc.frame_time(30) == pytest.approx(30 / 24)
    sc.at(2.4 + 0.6)
    M = expected_worlds(0.6)["a"]
    np.testing.assert_allclose(positions(sc, "a"), Va @ M[:3, :3].T + M[:3, 3], atol=2e-5)


def test_probe_box_covers_the_whole_animation(tmp_path):
    path, (Va, _, Vb) = write_rig(tmp_path / "rig.gltf")
    sc = load_scene(str(path))
    lo, hi = (np.asarray(a) for a in sc.meta.probe_box)
    ext = hi - lo
    # the box is inset by 5 % of the bounds (default_probe_grid): undo it to get the bounds it covers
    blo, bhi = lo - ext * 0.05 / 0.9, hi + ext * 0.05 / 0.9
    for t in np.linspace(0, 2.4, 49):
        E = expected_worlds(t)
        for sid, V in (("a", Va), ("b", Vb)):
            P = V @ E[sid][:3, :3].T + E[sid][:3, 3]
            assert np.all(P >= blo - 1e-6) and np.all(P <= bhi + 1e-6), (sid, t)


def test_camera_by_name_and_unknown_name(tmp_path):
    path, _ = write_rig(tmp_path / "rig.gltf")
    sc = load_scene(str(path), camera="side")
    cam = sc.camera(0.0)
    np.testing.assert_allclose(cam.origin, [3, 1, 0], atol=1e-9)
    np.testing.assert_allclose(np.subtract(cam.target, cam.origin), [-1, 0, 0], atol=1e-9)   # -Z turned by +90 deg about y
    assert cam.fov == pytest.approx(np.degrees(2 * np.arctan(4 / 3 * np.tan(0.25))))          # no aspectRatio: 4:3
    with pytest.raises(DyngiError, match="no camera named 'nope'.*main, side"):
        load_scene(str(path), camera="nope")


# -- renders against Mitsuba scenes built here ------------------------------------------------------------
RES, SPP, K = (40, 30), 16, 8


def _mesh(name, V, F, bsdf, emitter=None):
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    if emitter is not None:
        props["emitter"] = mi.load_dict(emitter)
    m = mi.Mesh(name, len(V), len(F), props)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(np.asarray(V, np.float32).ravel())
    p["faces"] = mi.UInt32(np.asarray(F, np.uint32).ravel())
    p.update()
    return m


def _sensor(C, yfov, res, spp):
    o = C[:3, 3]
    return mi.load_dict({
        "type": "perspective", "fov": float(np.degrees(yfov)), "fov_axis": "y",
        "to_world": mi.ScalarTransform4f().look_at(origin=o.tolist(), target=(o - C[:3, 2]).tolist(),
                                                   up=C[:3, 1].tolist()),
        "near_clip": 1e-3, "far_clip": 1e5, "sampler": {"type": "independent", "sample_count": spp},
        "film": {"type": "hdrfilm", "width": res[0], "height": res[1], "rfilter": {"type": "box"},
                 "pixel_format": "rgb"}})


def _renders(mscene, sensor, seeds):
    integ = mi.load_dict({"type": "path", "max_depth": 4})
    return np.stack([np.asarray(mi.render(mscene, sensor=sensor, integrator=integ, seed=s, spp=SPP))[..., :3]
                     for s in seeds])


def _rig_by_hand(t, Va, Fa, Vb, Fb):
    E = expected_worlds(t)
    pr = lambda c, m, r: {"type": "principled", "base_color": {"type": "rgb", "value": c}, "metallic": m,   # noqa: E731
                          "roughness": r}
    return mi.load_dict({
        "type": "scene",
        "floor": _mesh("floor", FLOOR_V, FLOOR_F, pr([0.7, 0.7, 0.7], 0.0, 0.6)),
        "a": _mesh("a", Va @ E["a"][:3, :3].T + E["a"][:3, 3], Fa, pr([0.8, 0.2, 0.1], 0.3, 0.4)),
        "b": _mesh("b", Vb @ E["b"][:3, :3].T + E["b"][:3, 3], Fb, pr([0.1, 0.1, 0.1], 0.0, 1.0),
                   {"type": "area", "radiance": {"type": "rgb", "value": [e * STRENGTH for e in EMISSIVE]}}),
        "lamp": {"type": "point", "position": LIGHT_POS,
                 "intensity": {"type": "rgb", "value": [c * LIGHT_CD / 683.0 for c in (1.0, 0.9, 0.8)]}},
    }), E["cam"]


def test_render_matches_mitsuba_scene_built_at_the_tests_poses(tmp_path):
    path, (Va, _, Vb) = write_rig(tmp_path / "rig.gltf")
    _, _, Fa = box24(A_HALF)
    _, _, Fb = box24(B_HALF)
    sc = load_scene(str(path))
    for t in (0.6, 1.7):
        sc.at(t)
        ours = _renders(sc.mi_scene, sc.camera(t).to_sensor(RES, SPP), range(K))
        ms, C = _rig_by_hand(t, Va, Fa, Vb, Fb)
        theirs = _renders(ms, _sensor(C, YFOV, RES, SPP), range(100, 100 + K))
        assert ours.mean() > 0.02
        ok, info = z_test_images(ours, theirs)
        assert ok, (t, info)
    # the same test tells a wrong pose apart (the scene at another time)
    ms, C = _rig_by_hand(0.6, Va, Fa, Vb, Fb)
    wrong = _renders(ms, _sensor(C, YFOV, RES, SPP), range(200, 200 + K))
    ok, _ = z_test_images(ours, wrong)
    assert not ok


def _sphere(n_th=24, n_ph=48):
    th = np.linspace(0, np.pi, n_th + 1)
    ph = np.linspace(0, 2 * np.pi, n_ph + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(T) * np.cos(P), np.cos(T), -np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    UV = np.stack([P / (2 * np.pi), T / np.pi], -1).reshape(-1, 2)
    idx = np.arange((n_th + 1) * (n_ph + 1)).reshape(n_th + 1, n_ph + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])
    A, B, Cc = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    F = F[np.linalg.norm(np.cross(B - A, Cc - A), axis=1) > 1e-12]
    return V, UV, F


def test_textured_metallic_roughness_sphere_matches_principled(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(3)
    base = (rng.random((8, 16, 3)) * 255).astype(np.uint8)
    rough = (40 + rng.random((8, 16)) * 200).astype(np.uint8)
    metal = np.where(rng.random((8, 16)) < 0.5, 255, 0).astype(np.uint8)
    Image.fromarray(base).save(tmp_path / "base.png")
    Image.fromarray(np.stack([np.zeros_like(rough), rough, metal], -1)).save(tmp_path / "mr.png")
    Image.fromarray(rough).save(tmp_path / "rough.png")
    Image.fromarray(metal).save(tmp_path / "metal.png")
    V, UV, F = _sphere()
    w = Writer()
    d = w.doc
    d["images"] = [{"uri": "base.png"}, {"uri": "mr.png"}]
    d["samplers"] = [{"magFilter": 9728, "minFilter": 9728}]            # nearest: the same lookup in both
    d["textures"] = [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}]
    d["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                "metallicRoughnessTexture": {"index": 1}}}]
    d["nodes"] = [{"mesh": w.mesh(V, F, 0, N=V, UV=UV)},
                  {"camera": 0, "translation": [0, 0.3, 3.0]}]
    d["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 4 / 3, "znear": 0.01}}]
    d["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": 683.0 * 2}]}}
    d["nodes"].append({"rotation": list(Rotation.from_euler("xy", [-50, 30], degrees=True).as_quat()),
                       "extensions": {"KHR_lights_punctual": {"light": 0}}})
    d["extensionsUsed"] = ["KHR_lights_punctual"]
    path = w.save(tmp_path / "sphere.gltf", "external")
    sc = load_scene(str(path))
    sc.at(0.0)
    ours = _renders(sc.mi_scene, sc.camera(0.0).to_sensor(RES, SPP), range(K))
    # Mitsuba decodes the PNGs itself (base colour as sRGB, roughness and metallic raw)
    tex = lambda f, raw: {"type": "bitmap", "filename": str(tmp_path / f), "raw": raw,   # noqa: E731
                          "filter_type": "nearest", "wrap_mode": "repeat"}

    def sphere(bsdf):
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(bsdf)
        mesh = mi.Mesh("s", len(V), len(F), props, has_vertex_normals=True, has_vertex_texcoords=True)
        p = mi.traverse(mesh)
        p["vertex_positions"] = mi.Float(V.astype(np.float32).ravel())
        p["vertex_normals"] = mi.Float(V.astype(np.float32).ravel())
        p["vertex_texcoords"] = mi.Float(UV.astype(np.float32).ravel())
        p["faces"] = mi.UInt32(F.astype(np.uint32).ravel())
        p.update()
        return mesh

    light_dir = Rotation.from_euler("xy", [-50, 30], degrees=True).apply([0, 0, -1])
    ms = mi.load_dict({"type": "scene",
                       "s": sphere({"type": "principled", "base_color": tex("base.png", False),
                                    "roughness": tex("rough.png", True), "metallic": tex("metal.png", True)}),
                       "sun": {"type": "directional", "direction": light_dir.tolist(),
                               "irradiance": {"type": "rgb", "value": [2.0, 2.0, 2.0]}}})
    C = np.eye(4)
    C[:3, 3] = [0, 0.3, 3.0]
    theirs = _renders(ms, _sensor(C, 0.8, RES, SPP), range(100, 100 + K))
    assert ours.mean() > 0.02
    ok, info = z_test_images(ours, theirs)
    assert ok, info
    # and it can fail: the same sphere with roughness and metallic swapped differs
    ms2 = mi.load_dict({"type": "scene",
                        "s": sphere({"type": "principled", "base_color": tex("base.png", False),
                                     "roughness": tex("metal.png", True), "metallic": tex("rough.png", True)}),
                        "sun": {"type": "directional", "direction": light_dir.tolist(),
                                "irradiance": {"type": "rgb", "value": [2.0, 2.0, 2.0]}}})
    wrong = _renders(ms2, _sensor(C, 0.8, RES, SPP), range(200, 200 + K))
    assert not z_test_images(ours, wrong)[0]


# -- motion vectors of an affine node ---------------------------------------------------------------------
def test_shape_motion_maps_affine_node_vertices_back_in_time(tmp_path):
    from dyngi.transport.gbuffer import ShapeMotion

    path, (Va, Na, _) = write_rig(tmp_path / "rig.gltf")
    sc = load_scene(str(path))
    sm = ShapeMotion(sc)
    rid = int(sm.ids[sm.names.index("a")])
    t1, t0 = 1.7, 1.1
    E1, E0 = expected_worlds(t1)["a"], expected_worlds(t0)["a"]
    P1 = Va @ E1[:3, :3].T + E1[:3, 3]
    N1 = Na @ np.linalg.inv(E1[:3, :3])
    N1 /= np.linalg.norm(N1, axis=1, keepdims=True)
    table = sm.table(t1, t0)
    ids = mi.UInt32(np.full(len(P1), rid, np.uint32))
    p, n = ShapeMotion.apply(table, ids, mi.Point3f(*(P1.T.astype(np.float32))),
                             mi.Vector3f(*(N1.T.astype(np.float32))))
    P0 = Va @ E0[:3, :3].T + E0[:3, 3]
    N0 = Na @ np.linalg.inv(E0[:3, :3])
    N0 /= np.linalg.norm(N0, axis=1, keepdims=True)
    np.testing.assert_allclose(np.array(p).T, P0, atol=1e-4)
    np.testing.assert_allclose(np.array(n).T, N0, atol=1e-4)


# -- skinning and morph targets ---------------------------------------------------------------------------
def test_skinning_and_morph_targets_follow_the_tests_blend(tmp_path):
    w = Writer()
    d = w.doc
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], np.float64)
    F = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
    J = np.array([[0, 1, 0, 0]] * 6, np.uint8)
    Wt = np.array([[1, 0, 0, 0], [1, 0, 0, 0], [0.5, 0.5, 0, 0], [0.5, 0.5, 0, 0], [0, 1, 0, 0], [0, 1, 0, 0]])
    m_skin = w.mesh(V, F, extra={})
    prim = d["meshes"][m_skin]["primitives"][0]
    prim["attributes"]["JOINTS_0"] = w.acc(J.ravel(), "VEC4", 5121)
    prim["attributes"]["WEIGHTS_0"] = w.acc(Wt.ravel(), "VEC4")
    IBM = np.stack([np.eye(4), np.linalg.inv(affine(np.eye(3), [0, 1, 0]))])
    d["skins"] = [{"joints": [1, 2], "inverseBindMatrices": w.acc(IBM.transpose(0, 2, 1).ravel(), "MAT4")}]
    dV = np.zeros_like(V); dV[:, 2] = [0, 0, 0.5, 0.5, 1, 1]
    m_morph = w.mesh(V + [3, 0, 0], F)
    d["meshes"][m_morph]["primitives"][0]["targets"] = [{"POSITION": w.acc(dV, "VEC3")}]
    d["meshes"][m_morph]["weights"] = [0.0]
    d["nodes"] = [{"name": "skinned", "mesh": m_skin, "skin": 0}, {"name": "root", "children": [2]},
                  {"name": "bone", "translation": [0, 1, 0]}, {"name": "morphed", "mesh": m_morph}]
    d["scenes"] = [{"nodes": [0, 1, 3]}]
    anim = {"samplers": [], "channels": []}
    channel(w, anim, 2, "rotation", dict(times=[0.0, 1.0], values=[quat_x(0), quat_x(90)]), "LINEAR")
    anim["samplers"].append({"input": w.acc([0.0, 1.0], "SCALAR"), "output": w.acc([0.0, 1.0], "SCALAR"),
                             "interpolation": "LINEAR"})
    anim["channels"].append({"sampler": len(anim["samplers"]) - 1, "target": {"node": 3, "path": "weights"}})
    d["animations"] = [anim]
    sc = load_scene(str(w.save(tmp_path / "skin.gltf")))
    assert set(sc.meta.dynamic_shapes) == {"skinned", "morphed"}
    for t in (0.0, 0.4, 1.0):
        sc.at(t)
        bone = affine(Rotation.from_euler("x", 90 * t, degrees=True).as_matrix(), [0, 1, 0])
        J1 = bone @ IBM[1]
        P1 = V @ J1[:3, :3].T + J1[:3, 3]
        exp = Wt[:, :1] * V + Wt[:, 1:2] * P1
        np.testing.assert_allclose(positions(sc, "skinned"), exp, atol=1e-5)
        np.testing.assert_allclose(positions(sc, "morphed"), V + [3, 0, 0] + t * dV, atol=1e-5)


# -- bad files: one line naming the problem ---------------------------------------------------------------
def _one_line(path, *fragments, **kw):
    with pytest.raises(DyngiError) as ei:
        load_scene(str(path), **kw)
    msg = str(ei.value)
    assert "\n" not in msg.strip()
    for f in fragments:
        assert f.lower() in msg.lower(), msg
    return msg


def test_bad_files_give_one_clear_line(tmp_path):
    path, _ = write_rig(tmp_path / "rig.gltf")
    doc = json.loads(path.read_text())
    doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    (tmp_path / "draco.gltf").write_text(json.dumps(doc))
    _one_line(tmp_path / "draco.gltf", "KHR_draco_mesh_compression", "not support")
    (tmp_path / "broken.gltf").write_text("{ not json")
    _one_line(tmp_path / "broken.gltf", "broken.gltf", "JSON")
    doc = json.loads(path.read_text())
    doc["buffers"][0] = {"byteLength": 10, "uri": "missing.bin"}
    (tmp_path / "nobuf.gltf").write_text(json.dumps(doc))
    _one_line(tmp_path / "nobuf.gltf", "missing.bin", "does not exist")
    doc = json.loads(path.read_text())
    doc["meshes"][0]["primitives"][0]["indices"] = 999
    (tmp_path / "badacc.gltf").write_text(json.dumps(doc))
    _one_line(tmp_path / "badacc.gltf", "accessors[999]")
    doc = json.loads(path.read_text())
    doc["animations"][0]["samplers"][0]["interpolation"] = "BEZIER"
    (tmp_path / "interp.gltf").write_text(json.dumps(doc))
    _one_line(tmp_path / "interp.gltf", "BEZIER", "STEP, LINEAR, CUBICSPLINE")
    doc = json.loads(path.read_text())
    doc["asset"]["version"] = "1.0"
    (tmp_path / "v1.gltf").write_text(json.dumps(doc))
    _one_line(tmp_path / "v1.gltf", "version", "2.x")
    _one_line(path, "--animation", "XML", animation=str(path))
    _one_line(path, "--fps", fps=-1.0)


# -- normal maps --------------------------------------------------------------------------------------------
def _normal_floor(tmp_path, rgb, light_dir):
    """A floor (normal +y; u along +x, v along +z, so the image's up is -z) with a constant normal map, lit by a
    directional light travelling along ``light_dir``; the mean radiance the camera above it sees."""
    from PIL import Image

    Image.fromarray(np.full((4, 4, 3), rgb, np.uint8)).save(tmp_path / "n.png")
    w = Writer()
    d = w.doc
    d["images"] = [{"uri": "n.png"}]
    d["textures"] = [{"source": 0}]
    d["materials"] = [{"pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0},
                       "normalTexture": {"index": 0}}]
    UV = (FLOOR_V[:, [0, 2]] + 2) / 4
    d["nodes"] = [{"mesh": w.mesh(FLOOR_V, FLOOR_F, 0, N=np.tile([0, 1, 0], (4, 1)), UV=UV)},
                  {"camera": 0, "translation": [0, 3, 0], "rotation": list(quat_x(-90))},
                  {"rotation": list(Rotation.align_vectors([light_dir], [[0, 0, -1]])[0].as_quat()),
                   "extensions": {"KHR_lights_punctual": {"light": 0}}}]
    d["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.5, "aspectRatio": 1.0}}]
    d["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": 683.0}]}}
    sc = load_scene(str(w.save(tmp_path / "nm.gltf")))
    sc.at(0.0)
    return float(_renders(sc.mi_scene, sc.camera(0.0).to_sensor((8, 8), SPP), [0]).mean())


def test_normal_map_tilts_follow_gltf_axes(tmp_path):
    """glTF tangent space: red = +U (world +x here), green = up in the image (world -z here). A normal tilted
    30 degrees towards a light 45 degrees up is brighter than the flat one, tilted away darker."""
    tilt = np.round(127.5 + 127.5 * np.sin(np.radians(30))).astype(np.uint8)
    flat_c = np.round(127.5 + 127.5 * np.cos(np.radians(30))).astype(np.uint8)
    s = np.sqrt(0.5)
    for light_from, rgb_towards, rgb_away in (
            ([1, 0, 0], [tilt, 128, flat_c], [255 - tilt, 128, flat_c]),      # red: +x
            ([0, 0, -1], [128, tilt, flat_c], [128, 255 - tilt, flat_c])):    # green: image up = -z
        travel = -(np.array([0, 1, 0]) + np.asarray(light_from)) * s
        flat = _normal_floor(tmp_path, [128, 128, 255], travel)
        towards = _normal_floor(tmp_path, rgb_towards, travel)
        away = _normal_floor(tmp_path, rgb_away, travel)
        assert towards > 1.2 * flat and away < 0.6 * flat, (light_from, towards, flat, away)


# -- alpha modes and double-sided ---------------------------------------------------------------------------
def _quad_under_sky(tmp_path, material, behind=False):
    """The mean radiance of a quad (facing +z) filling the view, under the white sky added to
    unlit files; seen from the front, or from ``behind``."""
    w = Writer()
    d = w.doc
    V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64)
    d["materials"] = [material]
    d["nodes"] = [{"mesh": w.mesh(V, [[0, 1, 2], [0, 2, 3]], 0)},
                  {"camera": 0, "translation": [0, 0, -2.0 if behind else 2.0],
                   "rotation": list(quat_y(180 if behind else 0))}]
    d["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.3, "aspectRatio": 1.0}}]
    sc = load_scene(str(w.save(tmp_path / "q.gltf")))
    sc.at(0.0)
    return float(_renders(sc.mi_scene, sc.camera(0.0).to_sensor((6, 6), SPP), range(4)).mean())


def test_alpha_modes_and_double_sided(tmp_path):
    pbr = lambda a: {"baseColorFactor": [0.5, 0.5, 0.5, a], "metallicFactor": 0.0}   # noqa: E731
    opaque = _quad_under_sky(tmp_path, {"pbrMetallicRoughness": pbr(0.3)})
    assert 0.05 < opaque < 0.9                                   # OPAQUE ignores alpha: the grey quad
    assert _quad_under_sky(tmp_path, {"pbrMetallicRoughness": pbr(0.3), "alphaMode": "MASK"}) == \
        pytest.approx(1.0, abs=1e-4)                             # below the 0.5 cut-off: the sky shows
    assert _quad_under_sky(tmp_path, {"pbrMetallicRoughness": pbr(0.7), "alphaMode": "MASK"}) == \
        pytest.approx(opaque, rel=0.1)
    blend = _quad_under_sky(tmp_path, {"pbrMetallicRoughness": pbr(0.5), "alphaMode": "BLEND"})
    assert blend == pytest.approx(0.5 * opaque + 0.5, rel=0.1)   # stochastic transparency: the mix on average
    assert _quad_under_sky(tmp_path, {"pbrMetallicRoughness": pbr(1.0)}, behind=True) < 1e-6
    assert _quad_under_sky(tmp_path, {"pbrMetallicRoughness": pbr(1.0), "doubleSided": True},
                           behind=True) == pytest.approx(opaque, rel=0.1)


# -- spot light, and the reference cache's key ------------------------------------------------------------
def test_spot_light_cone_and_intensity(tmp_path):
    """A spot 2 m above a floor pointing down (its node's -Z): inside the inner cone the floor is lit as by a
    point light of the same intensity (candela / 683) that this test builds; beyond the outer cone it is dark."""
    w = Writer()
    d = w.doc
    V = FLOOR_V * 2
    d["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [0.6, 0.6, 0.6, 1], "metallicFactor": 0.0}}]
    d["nodes"] = [{"mesh": w.mesh(V, FLOOR_F, 0)},
                  {"camera": 0, "translation": [0, 3, 0], "rotation": list(quat_x(-90))},
                  {"translation": [0, 2, 0], "rotation": list(quat_x(-90)),
                   "extensions": {"KHR_lights_punctual": {"light": 0}}}]
    d["cameras"] = [{"type": "perspective", "perspective": {"yfov": 1.2, "aspectRatio": 1.0}}]
    d["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "spot", "intensity": 683.0 * 5, "spot": {"innerConeAngle": 0.3, "outerConeAngle": 0.4}}]}}
    sc = load_scene(str(w.save(tmp_path / "spot.gltf")))
    sc.at(0.0)
    res = (32, 32)
    ours = _renders(sc.mi_scene, sc.camera(0.0).to_sensor(res, SPP), range(K))
    pt = mi.load_dict({"type": "scene", "floor": _mesh("floor", V, FLOOR_F, {
        "type": "principled", "base_color": {"type": "rgb", "value": [0.6, 0.6, 0.6]}, "metallic": 0.0,
        "roughness": 1.0}), "p": {"type": "point", "position": [0, 2, 0], "intensity": {"type": "rgb", "value": [5, 5, 5]}}})
    C = affine(Rotation.from_quat(quat_x(-90)).as_matrix(), [0, 3, 0])
    theirs = _renders(pt, _sensor(C, 1.2, res, SPP), range(100, 100 + K))
    # pixel centres -> floor points: the camera 3 m up sees 3 tan(0.6) m either side
    x = (np.arange(res[0]) + 0.5) / res[0] * 2 - 1
    r = np.hypot(*np.meshgrid(x, x)) * 3 * np.tan(0.6)
    ang = np.arctan(r / 2.0)
    inner, outer = ang < 0.3 - 0.05, ang > 0.4 + 0.05
    assert inner.sum() > 20 and outer.sum() > 20
    ok, info = z_test_images(ours[:, inner][:, :, None, :], theirs[:, inner][:, :, None, :])     # (K, n, 1, 3)
    assert ok, info
    assert ours[:, outer].max() == 0.0 and theirs[:, outer].mean() > 0.01


def test_reference_key_includes_the_animation(tmp_path):
    path, _ = write_rig(tmp_path / "rig.gltf")
    doc = json.loads(path.read_text())
    a = load_scene(str(path))
    doc2 = json.loads(path.read_text())
    # the same file with the rig's last translation key moved: the same first pose, another animation
    w = Writer()
    w.blob = bytearray(base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1]))
    w.doc = doc2
    k = doc2["animations"][0]["samplers"][0]["output"]
    doc2["animations"][0]["samplers"][0]["output"] = w.acc([[0, 0, 0], [0.5, 0, 0], [0.9, 0, -0.5]], "VEC3")
    assert k != doc2["animations"][0]["samplers"][0]["output"]
    b = load_scene(str(w.save(tmp_path / "rig2.gltf")))
    assert a.state_hash(0.5) == load_scene(str(path)).state_hash(0.5)
    assert a.state_hash(1.7) != b.state_hash(1.7)
    assert load_scene(str(path), loop=True).state_hash(3.0) != a.state_hash(3.0)     # wrapped vs held


# -- accessor layouts and primitive modes ------------------------------------------------------------------
def test_interleaved_sparse_strip_fan_and_mirrored_nodes(tmp_path):
    w = Writer()
    d = w.doc
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float64)
    N = np.tile([0.0, 0.0, 1.0], (4, 1))
    # interleaved POSITION + NORMAL in one bufferView with byteStride 24
    inter = np.concatenate([V, N], 1).astype(np.float32)
    while len(w.blob) % 4:
        w.blob.append(0)
    d["bufferViews"].append({"buffer": 0, "byteOffset": len(w.blob), "byteLength": inter.nbytes, "byteStride": 24})
    w.blob += inter.tobytes()
    bv = len(d["bufferViews"]) - 1
    d["accessors"] += [{"bufferView": bv, "byteOffset": 0, "componentType": FLOAT, "count": 4, "type": "VEC3",
                        "min": [0, 0, 0], "max": [1, 1, 0]},
                       {"bufferView": bv, "byteOffset": 12, "componentType": FLOAT, "count": 4, "type": "VEC3"}]
    pos, nrm = len(d["accessors"]) - 2, len(d["accessors"]) - 1
    # sparse: the same positions with vertex 3 moved to (2, 2, 0)
    sp_idx, sp_val = w.acc(np.array([3], np.uint32), "SCALAR", UINT32), w.acc([[2.0, 2.0, 0.0]], "VEC3")
    sparse = dict(d["accessors"][pos])
    sparse["sparse"] = {"count": 1, "indices": {"bufferView": d["accessors"][sp_idx]["bufferView"],
                                                 "componentType": UINT32},
                        "values": {"bufferView": d["accessors"][sp_val]["bufferView"]}}
    d["accessors"].append(sparse)
    sp = len(d["accessors"]) - 1
    strip = w.acc(np.array([0, 1, 2, 3], np.uint32), "SCALAR", UINT32)
    fan = w.acc(np.array([0, 1, 3, 2], np.uint32), "SCALAR", UINT32)
    d["meshes"] = [{"primitives": [{"attributes": {"POSITION": pos, "NORMAL": nrm}, "indices": strip, "mode": 5}]},
                   {"primitives": [{"attributes": {"POSITION": sp}, "indices": fan, "mode": 6}]}]
    d["nodes"] = [{"name": "strip", "mesh": 0}, {"name": "fan", "mesh": 1, "translation": [0, 0, -1]},
                  {"name": "mirror", "mesh": 0, "scale": [-1, 1, 1], "translation": [0, 0, -2]}]
    sc = load_scene(str(w.save(tmp_path / "layouts.gltf")))

    def tris(sid):
        P = positions(sc, sid)
        F = np.asarray(sc.params[f"{sid}.faces"]).reshape(-1, 3)
        return P, F, np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])

    P, F, n = tris("strip")
    np.testing.assert_allclose(P, V, atol=1e-7)
    np.testing.assert_allclose(np.asarray(sc.params["strip.vertex_normals"]).reshape(-1, 3), N, atol=1e-7)
    assert len(F) == 2 and np.all(n[:, 2] > 0)                  # a strip alternates winding: both face +z
    P, F, n = tris("fan")
    np.testing.assert_allclose(P, np.array([[0, 0, -1], [1, 0, -1], [0, 1, -1], [2, 2, -1]]), atol=1e-7)
    assert len(F) == 2 and np.all(n[:, 2] > 0)
    P, F, n = tris("mirror")
    np.testing.assert_allclose(P, V * [-1, 1, 1] + [0, 0, -2], atol=1e-7)
    assert np.all(n[:, 2] > 0)                                  # a mirroring node flips the winding back
