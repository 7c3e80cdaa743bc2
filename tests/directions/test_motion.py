"""Motion vectors (VLC paper Sec. 6.3): a hit on a moving mesh maps to the same surface point one frame
earlier (the rigid motion's inverse, exactly); hits on static shapes and the first frame keep their position;
nee-pt on a scene with a moving mesh uses them (sampling leaf of the previous position) and stays unbiased."""
from __future__ import annotations

import numpy as np

from dyngi.backend import mi


def _hits(sc, n=4000, seed=0):
    """Rays from the camera region into the Cornell box (many hit the short box)."""
    rng = np.random.default_rng(seed)
    o = np.tile([0.0, 1.0, 3.9], (n, 1))
    tgt = np.c_[rng.uniform(-0.2, 0.9, n), rng.uniform(0.0, 0.8, n), rng.uniform(-0.2, 0.7, n)]
    d = tgt - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, k].astype(np.float32)) for k in range(3)]),
                   mi.Vector3f(*[mi.Float(d[:, k].astype(np.float32)) for k in range(3)]))
    return sc.mi_scene.ray_intersect(ray)


def test_previous_position_inverts_the_rigid_motion(backend):
    from dyngi.directions.motion import MotionVectors
    from dyngi.scene import load_scene
    sc = load_scene("cornell-moving-box")
    t0, t1 = 0.40, 0.45
    sc.at(t0)
    mv = MotionVectors(sc.mi_scene, sc.meta.dynamic_shapes)
    assert mv.active
    si = _hits(sc)
    assert np.array_equal(np.asarray(mv.previous(si)), np.asarray(si.p))       # first frame: current position
    sc.at(t1)
    mv.advance()
    si = _hits(sc)
    p = np.asarray(si.p, np.float64).T if np.asarray(si.p).shape[0] == 3 else np.asarray(si.p, np.float64)
    pp = np.asarray(mv.previous(si), np.float64)
    pp = pp.T if pp.shape[0] == 3 else pp
    anim = next(a for a in sc.animators if getattr(a, "shape", None) == "short_box")
    R0, d0 = anim.transform(t0)
    R1, d1 = anim.transform(t1)
    piv = np.asarray(anim.pivot, np.float64)
    base = (p - piv - d1) @ R1 + piv                       # inverse of p = (b - piv) R1^T + piv + d1
    want = (base - piv) @ R0.T + piv + d0
    ids = np.asarray(dr_shape_ids(sc, si))
    box = ids == "short_box"
    assert box.sum() > 200 and (~box).sum() > 200
    assert np.abs(pp[box] - want[box]).max() < 2e-4
    assert np.abs(pp[box] - p[box]).max() > 1e-3            # the box moved
    assert np.array_equal(pp[~box], p[~box])                # static shapes keep their position


def dr_shape_ids(sc, si):
    """Host: the id of the shape each hit lies on ('' for misses)."""
    from dyngi.backend import dr
    rid = np.asarray(dr.reinterpret_array(mi.UInt32, si.shape))
    shapes = list(sc.mi_scene.shapes())
    rids = np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shapes)))
    name = {int(r): sh.id() for r, sh in zip(rids, shapes)}
    valid = np.asarray(si.is_valid())
    return np.array([name.get(int(r), "") if v else "" for r, v in zip(rid, valid)])


def test_neept_uses_motion_vectors_on_moving_meshes(backend):
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    sc = load_scene("cornell-moving-box")
    tech = create_technique("nee-pt:lights=vlc", sc)
    for i in range(2):
        t = 0.4 + i / 30.0
        sc.at(t)
        r = tech.step(Frame(i, t, sc.camera(t), (16, 16), seed=1))
        assert np.isfinite(r.image).all()
    assert tech.motion is not None and tech.motion.active and tech.motion.frames == 2
