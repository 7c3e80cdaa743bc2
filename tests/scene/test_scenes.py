"""Built-in procedural scenes: they build fast, animate in place, return exactly to a
state when asked (idempotent ``at``), render finite non-black images, and hold the
properties their docstrings promise (light counts, hidden lights, gates, probe boxes).
"""
from __future__ import annotations

import time

import numpy as np
import pytest

from dyngi.backend import mi
from dyngi.scene import BUILTINS, ParamTrack, RigidMotion, Scene, SunMotion, builtin_names, load_scene
from dyngi.techniques.base import to_image
from dyngi.techniques.path import render_paths

NAMES = builtin_names()
STATIC = {"cornell-static", "furnace", "living-room-sky"}   # living-room-sky: ReSTIR's static window-lit test room
DARK = {"sealed-rooms"}   # the camera is inside a sealed room, which Mitsuba renders exactly black
SPP = {"storage-cells": 64}   # ~3 of its 512 lights reach a point: 4 spp leaves most pixels without one
PAPER_STAND_INS = {"tunnel-gate", "atrium-sun", "corridor-rooms", "maze", "warehouse-lights", "sky-pit",
                   "covered-lights", "glossy-floor", "rotating-hidden-light",
                   "cornell-moving-light", "cornell-moving-box", "room-door", "villa-sun", "pink-room"}
RES = (48, 36)

_CACHE: dict[str, Scene] = {}


def scene(name: str) -> Scene:
    """One instance per scene for the whole module (each test moves it to the times it needs)."""
    if name not in _CACHE:
        _CACHE[name] = load_scene(name)
    return _CACHE[name]


def render(sc: Scene, t: float, res=RES, spp: int = 4) -> np.ndarray:
    sc.at(t)
    L, _ = render_paths(sc, sc.camera(t), res, spp=spp, seed=0, frame_index=0, max_depth=6, rr_depth=4)
    return to_image(L, res)


def _value(params, key) -> np.ndarray:
    v = params[key]
    if "Transform" in type(v).__name__:  # transforms (sun direction)
        return np.array(v.matrix, np.float64).reshape(4, 4)
    return np.array(v, np.float64).ravel()


def animated_keys(sc: Scene) -> list[str]:
    keys = []
    for a in sc.animators:
        if isinstance(a, RigidMotion):
            keys.append(f"{a.shape}.vertex_positions")
        elif isinstance(a, ParamTrack):
            keys.append(a.key)
        elif isinstance(a, SunMotion):
            keys.append(f"{a.emitter}.to_world")
        else:
            raise AssertionError(f"test does not know animator {type(a).__name__}")
    return keys


def snapshot(sc: Scene) -> dict:
    return {k: _value(sc.params, k) for k in animated_keys(sc)}


def shape_bbox(sc: Scene, sid: str) -> np.ndarray:
    for s in sc.mi_scene.shapes():
        if s.id() == sid:
            bb = s.bbox()
            return np.concatenate([np.array(bb.min), np.array(bb.max)])
    raise AssertionError(f"shape {sid} not in scene")


def occluded(sc: Scene, origins, targets, shorten: float = 1e-3) -> np.ndarray:
    """Shadow-ray test from each origin to each target (stopping just short of the target)."""
    o = np.asarray(origins, np.float64)
    d = np.asarray(targets, np.float64) - o
    dist = np.linalg.norm(d, axis=1)
    d = d / dist[:, None]
    ray = mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32)))
    ray.maxt = mi.Float((dist * (1.0 - shorten)).astype(np.float32))
    return np.array(sc.mi_scene.ray_test(ray), bool)


def toward(sc: Scene, emitter: str, origins, far: float = 1e3):
    """Targets `far` away from each origin towards a directional emitter (against its travel direction)."""
    M = _value(sc.params, f"{emitter}.to_world")
    d = M[:3, 2] / np.linalg.norm(M[:3, 2])
    return np.asarray(origins) - far * d


# -- registry -----------------------------------------------------------------
def test_all_paper_stand_ins_are_registered():
    assert PAPER_STAND_INS | STATIC <= set(NAMES)
    for name in NAMES:
        e = BUILTINS[name]
        assert e.description and e.stands_for, name
        doc = e.factory.__doc__ or ""
        assert len(doc.split()) >= 10, f"{name}: factory needs a docstring saying what it stands for"


# -- build + metadata ------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_builds_fast_and_small(name):
    t0 = time.perf_counter()
    sc = load_scene(name)
    dt = time.perf_counter() - t0
    _CACHE.setdefault(name, sc)
    assert dt < 2.0, f"{name} took {dt:.2f} s to build"
    tris = sum(int(s.face_count()) for s in sc.mi_scene.shapes() if s.is_mesh())
    assert 0 < tris < 50_000
    assert sc.name == name


@pytest.mark.parametrize("name", NAMES)
def test_metadata_is_sane(name):
    sc = scene(name)
    m = sc.meta
    blo, bhi = (np.asarray(a) for a in m.bounds)
    plo, phi = (np.asarray(a) for a in m.probe_box)
    eps = 1e-6
    assert np.all(plo < phi)
    assert np.all(plo >= blo - eps) and np.all(phi <= bhi + eps), f"probe box {m.probe_box} outside {m.bounds}"
    counts = np.asarray(m.probe_counts)
    assert counts.shape == (3,) and np.all(counts >= 2) and 8 <= counts.prod() <= 8192
    assert len(m.emitters) >= 1
    assert len({e["id"] for e in m.emitters}) == len(m.emitters), "emitter ids must be unique"
    assert (1.0 <= sc.duration <= 6.0) and sc.fps > 0
    if name not in STATIC:
        assert 2.0 <= sc.duration <= 6.0
    for t in (0.0, sc.duration):
        cam = sc.camera(t)
        assert np.all(np.isfinite(cam.origin)) and 0 < cam.fov < 180
    assert set(m.dynamic_shapes) == {a.shape for a in sc.animators if isinstance(a, RigidMotion)}


@pytest.mark.parametrize("name, n_lights", [("warehouse-lights", 128), ("corridor-rooms", 14), ("maze", 13),
                                            ("covered-lights", 10)])
def test_light_counts(name, n_lights):
    em = scene(name).meta.emitters
    assert len(em) == n_lights
    if name == "warehouse-lights":
        assert len(em) >= 100  # one emitter per light: NEE must choose among >= 100


@pytest.mark.parametrize("name", ["tunnel-gate", "sky-pit", "atrium-sun", "glossy-floor"])
def test_open_scenes_restrict_probes(name):
    """Scenes open to the sky confine the probe volume to the region of interest."""
    m = scene(name).meta
    vol = lambda lo_hi: float(np.prod(np.subtract(lo_hi[1], lo_hi[0])))  # noqa: E731
    assert vol(m.probe_box) < 0.9 * vol(m.bounds)
    if name in ("tunnel-gate", "sky-pit"):
        assert vol(m.probe_box) < 0.05 * vol(m.bounds)


# -- animation --------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_at_changes_state(name):
    sc = scene(name)
    mid = sc.duration / 2
    if name in STATIC:
        assert not sc.is_animated and sc.signature(0.0) == sc.signature(mid)
        return
    assert sc.is_animated
    assert sc.signature(0.0) != sc.signature(mid)
    assert sc.state_hash(0.0) != sc.state_hash(mid)
    sc.at(0.0)
    a, boxes_a = snapshot(sc), {s: shape_bbox(sc, s) for s in sc.meta.dynamic_shapes}
    sc.at(mid)
    b, boxes_b = snapshot(sc), {s: shape_bbox(sc, s) for s in sc.meta.dynamic_shapes}
    for key in a:
        if key.endswith("vertex_positions"):
            assert not np.array_equal(a[key], b[key]), f"{key} did not move"
    for s in boxes_a:  # the Mitsuba shape itself (not only the parameter dict) moved
        assert not np.allclose(boxes_a[s], boxes_b[s]), f"shape {s} bbox unchanged"
    changed = [k for k in a if not np.array_equal(a[k], b[k])]
    camera_moved = sc.camera(0.0).signature() != sc.camera(mid).signature()
    assert changed or camera_moved


@pytest.mark.parametrize("name", [n for n in NAMES if n not in STATIC])
def test_at_is_idempotent(name):
    sc = scene(name)
    t1, t2 = 0.25 * sc.duration, 0.6 * sc.duration
    sc.at(t1)
    s1 = snapshot(sc)
    sc.at(t2)
    sc.at(t2)
    s2 = snapshot(sc)
    sc.at(t1)
    s1b = snapshot(sc)
    for k in s1:
        assert np.array_equal(s1[k], s1b[k]), f"{k} not restored by at({t1})"
    assert sc.state_hash(t1) == sc.state_hash(t1)
    assert any(not np.array_equal(s1[k], s2[k]) for k in s1) or \
        sc.camera(t1).signature() != sc.camera(t2).signature()


def test_corridor_lights_switch():
    sc = scene("corridor-rooms")
    tracks = [a for a in sc.animators if isinstance(a, ParamTrack)]
    assert len(tracks) >= 3 and all(a.key.endswith("emitter.radiance.value") for a in tracks)
    seen_off = seen_on = 0
    for t in np.linspace(0.0, sc.duration, 9):
        sc.at(float(t))
        vals = [float(np.max(_value(sc.params, a.key))) for a in tracks]
        seen_off += sum(v == 0.0 for v in vals)
        seen_on += sum(v > 1.0 for v in vals)
    assert seen_off > 0 and seen_on > 0


# -- what the docstrings promise -----------------------------------------------------
def test_tunnel_gate_blocks_then_admits_the_sun():
    sc = scene("tunnel-gate")
    g = np.stack(np.meshgrid(np.linspace(-1.8, 1.8, 7), [0.01], np.linspace(-4.0, -0.3, 9)), -1).reshape(-1, 3)
    sc.at(0.0)
    assert occluded(sc, g, toward(sc, "sun", g)).all(), "closed gate must keep the sun out"
    sc.at(sc.duration)
    lit = ~occluded(sc, g, toward(sc, "sun", g))
    assert lit.mean() > 0.2, "open gate must let the sun onto the tunnel floor"
    # the interior walls and ceiling never see the sun directly (indirect-only interior)
    w = np.array([[x, y, z] for x in (-1.99, 1.99) for y in (1.0, 2.5) for z in (-6.0, -9.0)]
                 + [[0.0, 3.49, z] for z in (-2.0, -6.0)])
    assert occluded(sc, w, toward(sc, "sun", w)).all()


def test_rotating_light_is_hidden_from_floor_but_lights_wall():
    sc = scene("rotating-hidden-light")
    r, a = np.meshgrid(np.linspace(0.0, 1.45, 6), np.linspace(0, 2 * np.pi, 12, endpoint=False))
    floor = np.stack([r * np.cos(a), np.full_like(r, 0.005), r * np.sin(a)], -1).reshape(-1, 3)
    ang = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    wall = np.stack([1.99 * np.cos(ang), np.full_like(ang, 0.5), 1.99 * np.sin(ang)], -1)
    centres = []
    for t in (0.0, 1.5, 2.5):
        sc.at(t)
        c = _value(sc.params, "light.vertex_positions").reshape(-1, 3).mean(0)
        centres.append(c)
        assert occluded(sc, floor, np.broadcast_to(c, floor.shape)).all(), f"floor sees the light at t={t}"
        assert (~occluded(sc, wall, np.broadcast_to(c, wall.shape))).sum() >= 3, f"wall unlit at t={t}"
    assert np.linalg.norm(centres[0] - centres[1]) > 1.0, "light did not turn"


def test_warehouse_sees_few_lights():
    sc = scene("warehouse-lights")
    for t in (0.0, sc.duration):
        sc.at(t)
        cams = np.broadcast_to(np.asarray(sc.camera(t).origin, np.float64), (128, 3))
        centres = np.array([_value(sc.params, f"{e['id']}.vertex_positions").reshape(-1, 3).mean(0)
                            for e in sc.meta.emitters]) - [0.0, 0.02, 0.0]
        visible = int((~occluded(sc, cams, centres)).sum())
        assert 1 <= visible <= 32, f"{visible} of 128 lights visible from the camera at t={t}"


def test_sun_moves_in_sunlit_scenes():
    for name in ("atrium-sun", "sky-pit"):
        sc = scene(name)
        d = []
        for t in (0.0, sc.duration):
            sc.at(t)
            d.append(_value(sc.params, "sun.to_world")[:3, 2])
        assert np.degrees(np.arccos(np.clip(np.dot(d[0], d[1]), -1, 1))) > 10.0, name


# -- rendering ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_renders_finite_non_black_and_animation_shows(name):
    sc = scene(name)
    mid = sc.duration / 2
    spp = SPP.get(name, 4)
    a = render(sc, 0.0, spp=spp)
    b = render(sc, mid, spp=spp)
    c = render(sc, 0.0, spp=spp)  # back again: the Mitsuba scene (BVH included) returns to the t=0 state
    for img, t in ((a, 0.0), (b, mid)):
        assert img.shape == (RES[1], RES[0], 3)
        assert np.all(np.isfinite(img)) and img.min() >= 0.0, f"t={t}"
        if name in DARK:
            assert img.max() == 0.0, f"{name} at t={t}: light in a sealed room"
            continue
        assert 3e-3 < img.mean() < 5.0, f"{name} at t={t}: mean {img.mean():.4g}"
        assert (img.sum(-1) > 0).mean() > 0.25, f"{name} at t={t}: mostly black pixels"
    np.testing.assert_allclose(c, a, rtol=1e-5, atol=1e-6)
    if name in STATIC or name in DARK:
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)
    else:
        assert np.abs(b - a).mean() > 1e-4, f"{name}: t=0 and t={mid} render the same image"
