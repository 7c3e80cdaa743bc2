"""The ReSTIR DI component (dyngi.transport.restir_di.ReSTIRDI): its shading is unbiased
against Mitsuba's direct lighting (`path` with max_depth = 2), with temporal and spatial reuse, for the
default target and for another one (the target is a parameter)."""
from __future__ import annotations

import numpy as np
import pytest
from stats import z_test_images

from tests.techniques.test_restir import _without_rare_event_pixels

RES = (24, 18)


def _direct(scene, k, frames, **kw):
    """Independent run ``k``: ``frames`` static frames of L_e + ReSTIR DI at the primary vertex, averaged."""
    from dyngi.backend import mi
    from dyngi.techniques import Frame
    from dyngi.timing import StageTimer
    from dyngi.transport.restir_di import ReSTIRDI

    di = ReSTIRDI(scene, **kw)
    scene.at(0.0)
    npix = RES[0] * RES[1]
    acc = np.zeros((npix, 3))
    for i in range(frames):
        frame = Frame(i, 0.0, scene.camera(0.0), RES, seed=500 + k, static=i > 0)
        t = StageTimer()
        pv = di.begin(frame, t)
        direct = di.direct(pv, t)
        L = mi.Color3f(pv.gb.si.emitter(scene.mi_scene).eval(pv.gb.si) + direct)
        acc += np.stack([np.asarray(L[c]) for c in range(3)], 1)
    return (acc / frames).reshape(RES[1], RES[0], 3).astype(np.float32)


def _mitsuba(scene, spp, k):
    from dyngi.backend import mi

    scene.at(0.0)
    sensor = scene.camera(0.0).to_sensor(RES, spp)
    integ = mi.load_dict({"type": "path", "max_depth": 2})
    return np.asarray(mi.render(scene.mi_scene, sensor=sensor, integrator=integ, spp=spp, seed=9000 + k),
                      np.float32)


def _no_cosine_target(n, two_sided, ev):
    """Another target: the unshadowed light without the cosine (positive wherever the integrand is)."""
    from dyngi.backend import dr, mi

    return dr.select(ev.valid, mi.luminance(ev.Lg), 0.0)


@pytest.mark.parametrize("target", ["default", pytest.param("no-cosine", marks=pytest.mark.slow)])
def test_restir_di_shading_is_unbiased_against_mitsuba_direct_light(backend, target):
    from dyngi.scene import load_scene

    scene = load_scene("cornell-static")
    K, frames = 8, 12
    kw = {"candidates": 8, "spatial": 2, "visibility_reuse": "none"}   # the unbiased option (test_restir.py)
    if target != "default":
        kw["target_fn"] = _no_cosine_target
    a = np.stack([_direct(scene, k, frames, **kw) for k in range(K)])
    b = np.stack([_mitsuba(scene, 16 * frames, k) for k in range(K)])
    assert a.mean() > 0.0
    ok, info = z_test_images(*_without_rare_event_pixels(a, b))
    assert ok, info
    # and the test detects a 5 % bias
    ok_bad, _ = z_test_images(*_without_rare_event_pixels(a * 1.05, b))
    assert not ok_bad


def test_unbiased_visibility_reuse_traces_its_rays_in_the_reuse_stages(backend):
    """``visibility_reuse='unbiased'``: the shadow rays move from the shading to the stages that need them
    (one per candidate, one per temporal merge where the sample changed domain, up to one per spatial
    neighbour), all counted; the stored reservoirs hold only samples visible from their own pixel, so the
    shading traces none. And a reuse stage called without the visibility callables says so."""
    from dyngi.backend import dr, mi
    from dyngi.errors import DyngiError
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame
    from dyngi.timing import StageTimer
    from dyngi.transport.restir_di import ReSTIRDI

    scene = load_scene("cornell-static")
    di = ReSTIRDI(scene, candidates=8, spatial=2, visibility_reuse="unbiased")
    scene.at(0.0)
    for i in range(3):
        t = StageTimer()
        pv = di.begin(Frame(i, 0.0, scene.camera(0.0), RES, seed=1, static=i > 0), t)
        di.direct(pv, t)
    rays = t.as_dict()["rays"]
    npix = RES[0] * RES[1]
    assert rays.get("shadow", 0) == 0, rays
    assert 0 < rays["candidates"] <= npix and 0 < rays["temporal"] <= npix and 0 < rays["spatial"] <= 2 * npix, rays
    # every stored sample with W > 0 is visible from its own pixel
    r = di.prev_res
    keep = pv.smooth & (r.W > 0.0)
    vis, traced = di.visible_at(pv.gb.si, r.sample, pv.time, keep, "shadow")
    assert dr.count(keep) > 0 and dr.count(keep & ~vis) == 0
    with pytest.raises(DyngiError, match="unbiased"):
        di.spatial_reuse(pv.gb, r, pv.smooth, pv.sampler, lambda s, ok: mi.Float(0.0),
                         lambda *a: (), lambda d, s, ok: mi.Float(0.0))
