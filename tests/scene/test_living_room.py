"""The thin-walled sunlit ``living-room``: single-layer walls, and the leak that stays small.

* ``test_walls_are_single_layer`` -- the outer walls, the roof and the floor
  are flat polygons without thickness: every wall triangle lies in one of the
  planes ``x = +-3`` / ``z = +-2.5`` (no second, parallel layer), the ceiling
  and the floor are one quad each; the probe volume lies inside the house
  (no layer of probes outside the walls, in the sun);
* ``test_ddgi_leak_near_the_walls_stays_small`` -- ``ddgi`` and ``ddgi-primary``
  against Mitsuba's ``path``: the luminance error of the pixels within 0.3 m
  of a wall's or the ceiling's inside stays small (measured +8% / +9%; with the
  volume over the whole house, whose outer layers lay in the sun, it was
  +65% / +60%, and this file required it to be above +35%).
"""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.backend import mi
from dyngi.transport.gbuffer import render_gbuffer
from dyngi.scene import load_scene
from dyngi.scene.builtin_living import LIVING_H, LIVING_X, LIVING_Z, near_wall_mask
from dyngi.techniques import Frame, create_technique

LUM = np.array([0.2126, 0.7152, 0.0722])


def _mesh(sc, name):
    V = np.asarray(sc.params[f"{name}.vertex_positions"], np.float64).reshape(-1, 3)
    F = np.asarray(sc.params[f"{name}.faces"], np.int64).reshape(-1, 3)
    return V, F


def test_walls_are_single_layer():
    sc = load_scene("living-room")
    V, F = _mesh(sc, "walls")
    tri = V[F]                                               # (T, 3, 3)
    in_x = np.all(np.isclose(np.abs(tri[..., 0]), LIVING_X), axis=1) & np.all(
        np.isclose(tri[..., 0], tri[:, :1, 0]), axis=1)
    in_z = np.all(np.isclose(np.abs(tri[..., 2]), LIVING_Z), axis=1) & np.all(
        np.isclose(tri[..., 2], tri[:, :1, 2]), axis=1)
    assert np.all(in_x | in_z), "a wall triangle off the four wall planes (a thick wall?)"
    # exactly the four planes, one layer each
    assert sorted(set(np.round(tri[in_x][:, 0, 0], 6))) == [-LIVING_X, LIVING_X]
    assert sorted(set(np.round(tri[in_z][:, 0, 2], 6))) == [-LIVING_Z, LIVING_Z]
    for name, y in (("ceiling", LIVING_H), ("floor", 0.0)):
        V, F = _mesh(sc, name)
        assert len(F) == 2 and np.allclose(V[:, 1], y)
    # the probe volume lies inside the house: no layer of probes outside the walls or above the roof
    lo, hi = (np.asarray(b) for b in sc.meta.probe_box)
    assert lo[0] > -LIVING_X and hi[0] < LIVING_X and lo[2] > -LIVING_Z and hi[2] < LIVING_Z
    assert 0.0 < lo[1] and hi[1] < LIVING_H


def _near_wall_mask(sc, res):
    gb = render_gbuffer(sc, sc.camera(0.0), res, mi.Point2f(0.5, 0.5))
    pos = np.stack([np.asarray(gb.pos[i]) for i in range(3)], -1).reshape(res[1], res[0], 3)
    return near_wall_mask(pos, 0.3)


def _leak(tech, sc, ref, near, far, frames=12, res=(64, 36)):
    cam = sc.camera(0.0)
    acc = [tech.step(Frame(i, 0.0, cam, res, seed=3, static=i > 0)).image for i in range(frames)]
    img = np.mean(acc[frames // 2:], 0)
    e = img @ LUM - ref @ LUM
    r = ref @ LUM
    return e[near].mean() / r[near].mean(), e[far].mean() / r[far].mean()


@pytest.mark.slow   # CI budget (10-30 s on a cold cache); runs in CI's slow subset
def test_ddgi_leak_near_the_walls_stays_small():
    sc = load_scene("living-room")
    res = (64, 36)
    ref = np.asarray(mi.render(sc.mi_scene, sensor=sc.camera(0.0).to_sensor(res, 256),
                               integrator=mi.load_dict({"type": "path", "max_depth": -1}), spp=256, seed=1),
                     np.float64)
    near, far = _near_wall_mask(sc, res)
    assert near.mean() > 0.2 and far.mean() > 0.1
    # measured (64x36, frames 6-11): ddgi +0.08 near the walls' inside, +0.03 elsewhere;
    # ddgi-primary +0.09 / +0.01 (with the volume over the whole house: +0.65 / +0.11 and +0.60 / +0.08)
    for spec, params in (("ddgi", {}), ("ddgi-primary", {"candidates": 8})):
        lk, rest = _leak(create_technique(spec, sc, params), sc, ref, near, far)
        print(f"living-room leak {spec}: {lk:+.3f} near walls, {rest:+.3f} elsewhere")
        assert abs(lk) < LEAK_NEAR, (spec, lk, rest)
        assert abs(rest) < LEAK_REST, (spec, lk, rest)


LEAK_NEAR, LEAK_REST = 0.2, 0.1
"""Bounds of the relative luminance error near the walls' inside and elsewhere (see the test)."""


def test_sky_variant_is_lit_only_by_the_sky_through_its_window():
    """``living-room-sky`` (the room of the restir-pt ablation, docs/techniques/restir-pt.md): the same single-layer
    walls, one emitter (the environment), a glossy floor, nothing animated."""
    sc = load_scene("living-room-sky")
    ems = sc.mi_scene.emitters()
    assert len(ems) == 1 and mi.has_flag(ems[0].flags(), mi.EmitterFlags.Infinite)
    floor = [s for s in sc.mi_scene.shapes() if s.id() == "floor"][0]
    assert mi.has_flag(floor.bsdf().flags(), mi.BSDFFlags.GlossyReflection)
    assert not sc.animators
    V, _ = _mesh(sc, "walls")
    V0, _ = _mesh(load_scene("living-room"), "walls")
    assert np.array_equal(V, V0)
