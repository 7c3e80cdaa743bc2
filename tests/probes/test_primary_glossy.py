"""The glossy probe lookup at the primary vertex (``glossy`` of the probe techniques; :mod:`dyngi.probes.primary`).

* ``test_glossy_off_is_todays_image`` -- ``glossy=false`` (the default) is bit-identical to the spec
  without it, and on a diffuse-only scene ``glossy=true`` is bit-identical too: its extra sampler draws
  come after the NEE draws and a BSDF without a rough glossy lobe adds exactly 0;
* ``test_glossy_closes_the_gap_to_mitsuba`` -- a rough-conductor floor (no diffuse lobe) and a rough-plastic
  block under a constant sky (``direct='sun'``: the sky is the probes' light, so without the glossy lookup the
  floor gets no light at all): ``ddgi:glossy=true``'s mean is within a recorded bound of Mitsuba's ``path``,
  ``glossy=false``'s is far below it;
* ``test_delta_lobes_keep_todays_handling`` -- a smooth mirror floor is shaded as today with ``glossy=true``;
* ``test_glossy_steady_state_compiles_nothing`` -- ``ddgi:glossy=true`` on the animated glossy floor compiles
  no new kernel in steady state (the lookup's sample numbers come from the frame's seeded sampler);
* ``test_bad_glossy_values`` -- one ``DyngiError`` naming ``glossy`` for every probe technique that has it.
"""
from __future__ import annotations

import numpy as np
import pytest
from helpers import assert_steady_state_compiles_nothing

from dyngi.backend import mi
from dyngi.errors import DyngiError
from dyngi.scene import load_scene
from dyngi.scene.builder import SceneBuilder
from dyngi.scene.builtin_default import _floor
from dyngi.scene.camera import Camera
from dyngi.scene.geometry import box, diffuse
from dyngi.techniques import Frame, create_technique, get_technique

RES = (32, 24)
PROBE_TECHNIQUES = ("ddgi", "qddgi", "probes-reference", "adgi", "isddgi")
SMALL = {"ddgi": {"probe_counts": "3", "rays_per_probe": 32, "warmup": 2},
         "qddgi": {"probe_counts": "3", "warmup": 2},
         "probes-reference": {"probe_counts": "3", "texels": 6, "rays_per_texel": 2},
         "adgi": {"probe_counts": "3", "static_chains": 256, "dynamic_chains": 64, "iterations": 6,
                  "warmup": 2}}


def _frames(tech, sc, n, res=RES, seed=3):
    out = []
    for i in range(n):
        t = sc.frame_time(i) if not getattr(sc, "_static_test", False) else 0.0
        sc.at(t)
        r = tech.step(Frame(i, t, sc.camera(t), res, seed=seed, static=False))
        out.append((np.asarray(r.image), np.asarray(r.indirect)))
    return out


@pytest.mark.parametrize("name", ["ddgi", "adgi"])
def test_glossy_off_is_todays_image(backend, name):
    sc = load_scene("glossy-floor")
    base = _frames(create_technique(name, sc, SMALL[name]), sc, 3)
    off = _frames(create_technique(name, sc, {**SMALL[name], "glossy": False}), sc, 3)
    on = _frames(create_technique(name, sc, {**SMALL[name], "glossy": True}), sc, 3)
    for (a, ai), (b, bi), (c, ci) in zip(base, off, on):
        assert np.array_equal(a, b) and np.array_equal(ai, bi)
        assert not np.array_equal(a, c)           # the glossy floor does change with the lookup
        assert np.all(ci >= ai - 1e-6)            # ... only by adding (non-negative) glossy light
    cb = load_scene("cornell-static")             # no glossy lobe anywhere: glossy=true adds exactly 0
    cb._static_test = True
    a = _frames(create_technique(name, cb, SMALL[name]), cb, 2)
    c = _frames(create_technique(name, cb, {**SMALL[name], "glossy": True}), cb, 2)
    for (x, xi), (y, yi) in zip(a, c):
        assert np.array_equal(x, y) and np.array_equal(xi, yi)


SKY = (0.6, 0.7, 0.9)


def _sky_floor_scene(floor_bsdf: dict, block: bool = True):
    """A 4 x 4 m floor and a 1 m rough-plastic block (black diffuse lobe) under a constant sky (no other
    light): glossy only."""
    b = SceneBuilder("sky-glossy-floor")
    b.mesh("floor", _floor(-2, 2, -2, 2), floor_bsdf)
    if block:
        b.mesh("block", box((-0.5, 0.0, -0.9), (0.5, 0.8, -0.1)),
               {"type": "roughplastic", "distribution": "ggx", "alpha": 0.15,
                "diffuse_reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}})
    b.add("sky", {"type": "constant", "radiance": {"type": "rgb", "value": list(SKY)}})
    sc = b.build(Camera((0.0, 2.2, 2.2), (0.0, 0.0, -0.2), (0, 1, 0), 60.0), "glossy floor under a sky",
                 duration=1.0, probe_box=((-2, 0.1, -2), (2, 2.0, 2)), probe_counts=(4, 3, 4))
    sc._static_test = True
    return sc


METAL = {"type": "roughconductor", "material": "none", "alpha": 0.3,
         "specular_reflectance": {"type": "rgb", "value": [0.8, 0.6, 0.4]}}
GLOSSY_BOUND = 0.10
"""|mean(ddgi:glossy=true) / mean(path) - 1| bound on the sky-lit metal floor (measured: see the test)."""


def _lum(img):
    return float(np.mean(np.asarray(img, np.float64)[..., :3] @ [0.2126, 0.7152, 0.0722]))


def test_glossy_closes_the_gap_to_mitsuba(backend):
    """Measured (load ~7): glossy=true -4.0 % of the reference's mean luminance, glossy=false -66 % (the sky
    seen directly is all it has); the lookup's bias is the cosine prefilter of the 8x8 texels (a tilted
    lobe reads some of the dark floor) and the block's glossy reflection missing from the probes."""
    sc = _sky_floor_scene(METAL)
    ref = mi.render(sc.mi_scene, sensor=sc.camera(0.0).to_sensor(RES, 256),
                    integrator=mi.load_dict({"type": "path", "max_depth": 8}), seed=1, spp=256)
    ref = _lum(ref)
    got = {}
    for g in (True, False):
        tech = create_technique("ddgi", sc, {"probe_counts": "4,3,4", "rays_per_probe": 64, "warmup": 4,
                                             "glossy": g, "hysteresis": 0.5})
        imgs = [im for im, _ in _frames(tech, sc, 6)]
        got[g] = _lum(np.mean(imgs[2:], axis=0)) / ref - 1.0
    print("relative mean luminance error vs path:", got)
    assert abs(got[True]) < GLOSSY_BOUND, got
    assert got[False] < -0.3 and abs(got[False]) > abs(got[True]) + 0.2, got


def test_delta_lobes_keep_todays_handling(backend):
    """A smooth conductor (delta lobe only) floor: glossy=true adds nothing (the module docstring's choice)."""
    sc = _sky_floor_scene({"type": "conductor", "material": "none",
                           "specular_reflectance": {"type": "rgb", "value": [0.9, 0.9, 0.9]}}, block=False)
    kw = {"probe_counts": "4,3,4", "rays_per_probe": 16, "warmup": 1}
    a = _frames(create_technique("ddgi", sc, kw), sc, 2)
    b = _frames(create_technique("ddgi", sc, {**kw, "glossy": True}), sc, 2)
    for (x, xi), (y, yi) in zip(a, b):
        assert np.array_equal(x, y) and np.array_equal(xi, yi) and not np.any(yi)


def test_glossy_steady_state_compiles_nothing(backend):
    sc = load_scene("glossy-floor")
    tech = create_technique("ddgi", sc, {**SMALL["ddgi"], "glossy": True})

    def step(f):
        t = sc.frame_time(f)
        sc.at(t)
        tech.step(Frame(f, t, sc.camera(t), RES, seed=3, static=False))

    assert_steady_state_compiles_nothing(step, frames=6, warmup=3, nonempty=True)


@pytest.mark.parametrize("name", PROBE_TECHNIQUES)
def test_bad_glossy_values(backend, name):
    assert "glossy" in get_technique(name).PARAMS
    sc = load_scene("cornell-static")
    for bad in ("maybe", "1.5", "glossy"):
        with pytest.raises(DyngiError, match="glossy"):
            create_technique(name, sc, {"glossy": bad})
