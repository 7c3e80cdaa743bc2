"""G-buffer, motion vectors and disocclusion mask (dyngi.transport.gbuffer)."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.transport.gbuffer import GBufferHistory, render_gbuffer
from dyngi.scene import load_scene

RES = (48, 36)


def _centre(n):
    return mi.Point2f(dr.full(mi.Float, 0.5, n), dr.full(mi.Float, 0.5, n))


def _scene(name):
    """A built-in scene, or ``gltf-box``: the example glTF box (examples/animated_box.py; its lid rotates on a
    hinge while the box translates: an AffineMotion per node)."""
    if name != "gltf-box":
        return load_scene(name)
    import os
    import runpy
    import tempfile

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    path = runpy.run_path(os.path.join(root, "examples", "animated_box.py"))["write"](
        os.path.join(tempfile.mkdtemp(), "box.gltf"))
    return load_scene(path)


def _two_frames(name, t0, t1):
    scene = _scene(name)
    hist = GBufferHistory(scene)
    n = RES[0] * RES[1]
    for t in (t0, t1):
        scene.at(t)
        hist.push(render_gbuffer(scene, scene.camera(t), RES, _centre(n), t))
    return scene, hist, hist.reproject()


@pytest.mark.parametrize("name,t0,t1,moving", [("cornell-moving-box", 0.3, 0.4, "short_box"),
                                               ("glossy-floor", 1.0, 1.2, "statue"),
                                               ("gltf-box", 1.0, 1.15, "lid"),
                                               ("maze", 0.5, 0.6, None)])
def test_motion_reprojects_onto_the_same_surface_point(name, t0, t1, moving):
    """Trace, at the previous time, the previous camera's ray through the reprojected film position:
    it must hit the moved-back point on the same triangle (exact up to float rounding)."""
    scene, hist, r = _two_frames(name, t0, t1)
    gb = hist.cur
    scene.at(t0)
    cam0 = scene.camera(t0)
    n = RES[0] * RES[1]
    xy = r.prev_xy
    pix = mi.UInt32(0) * dr.arange(mi.UInt32, n)
    # film position -> pixel index 0 plus a "jitter" equal to the continuous coordinates
    ray = cam0.sample_rays(RES, pix, mi.Point2f(xy.x, xy.y))
    si = scene.mi_scene.ray_intersect(ray)
    valid = np.asarray(r.valid)
    ids = np.asarray(gb.shape_id)
    sel = valid
    if moving is not None:
        rid = [int(np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr([s])))[0])
               for s in scene.mi_scene.shapes() if s.id() == moving][0]
        sel = valid & (ids == rid)
    assert sel.sum() > 20, "too few reprojected pixels on the tested surface"
    p_hit = np.asarray(si.p).reshape(3, -1).T[sel]
    p_exp = np.asarray(r.prev_pos).reshape(3, -1).T[sel]
    err = np.linalg.norm(p_hit - p_exp, axis=1)
    ext = np.linalg.norm(np.subtract(*scene.meta.bounds))
    # a point visible now may be hidden at t0 (by itself rotating away or another object): those are
    # what the mask must reject; allow none of them among the pixels the mask accepts beyond 2 %
    bad = err > 1e-4 * ext
    assert bad.mean() < 0.02, f"{bad.sum()} of {sel.sum()} accepted pixels do not reproject exactly"
    same_prim = np.asarray(si.prim_index)[sel] == np.asarray(gb.prim)[sel]
    if moving is not None:  # (static mazes have coincident faces; positions are what count there)
        assert same_prim[~bad].mean() > 0.98    # a point on a shared edge may report the neighbour triangle
    if moving is not None:  # the object really moved: motion is not zero
        assert np.abs(np.asarray(r.motion).reshape(2, -1).T[sel]).max() > 0.5


def test_static_scene_has_zero_motion_and_no_disocclusion():
    scene, hist, r = _two_frames("cornell-static", 0.0, 0.1)
    m = np.asarray(r.motion)
    v = np.asarray(hist.cur.valid)
    assert np.abs(m.reshape(2, -1)[:, v]).max() < 1e-3
    assert np.asarray(r.valid)[v].all()


def test_disocclusion_mask_flags_uncovered_floor():
    """Where the Cornell box's short box slid away, the floor was hidden: those pixels are masked."""
    scene, hist, r = _two_frames("cornell-moving-box", 0.2, 0.6)
    v = np.asarray(hist.cur.valid)
    ok = np.asarray(r.valid)
    ids_prev = np.asarray(hist.prev.shape_id)
    ids_cur = np.asarray(hist.cur.shape_id)
    changed = v & (ids_prev != ids_cur)
    # pixels whose visible shape changed and whose reprojection lands on a different shape
    pp = np.asarray(r.prev_pixel)
    lands_elsewhere = changed & (ids_prev[pp] != ids_cur)
    assert lands_elsewhere.sum() > 5
    assert not ok[lands_elsewhere].any()


def test_no_history_means_nothing_reprojects():
    scene = load_scene("cornell-static")
    hist = GBufferHistory(scene)
    n = RES[0] * RES[1]
    hist.push(render_gbuffer(scene, scene.camera(0.0), RES, _centre(n), 0.0))
    assert not np.asarray(hist.reproject().valid).any()
