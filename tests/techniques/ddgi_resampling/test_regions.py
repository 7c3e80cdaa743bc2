"""ddgi-resampling per region on the window-lit ``living-room``, the probes' bias taken out.

With the ``exact_radiance`` hook (the secondary vertex's radiance path-traced where it is shaded; the
resampling target keeps the probes' cached ``S(y)``, :mod:`dyngi.techniques.ddgi_resampling.shading`) the
estimator is unbiased with ``visibility_reuse='unbiased'``: its region means (the 4x4 blocks, near the
walls / away, sunlit / shadowed of ``tests/techniques/test_restir.py``) must agree with Mitsuba's ``path``
(unbounded depth, both sides' variances, Sidak over the regions), and the mean away from the walls must be
within 3 % of it (issue: "ddgi-resampling's darkening away from the walls bounded at 3 %"). Its power: with
the hook's old target (one path-traced sample, 0 for most points of this room) the same test fails.
"""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from tests.techniques.test_restir import _mitsuba_at, _region_masks, region_z_test

RES = (48, 27)
RUNS, FRAMES = 8, 24
AWAY_MAX = 0.03
"""Bound of the relative error of the mean away from the walls (the issue's 3 %)."""
PARAMS = {"exact_radiance": True, "visibility_reuse": "unbiased", "combine": "mis", "rays_per_probe": 64}


@pytest.fixture(scope="module")
def living_reference():
    scene = load_scene("living-room")
    names, masks = _region_masks(scene, RES)
    ref_a = _mitsuba_at(scene, RES, 1024, 21, -1)
    ref_b = _mitsuba_at(scene, RES, 1024, 22, -1)
    return scene, names, masks, ref_a, ref_b


def _runs(scene, params, runs=RUNS, frames=FRAMES, seed0=900):
    out = []
    for k in range(runs):
        tech = create_technique("ddgi-resampling", scene, params)
        scene.at(0.0)
        r = None
        for i in range(frames):
            r = tech.step(Frame(i, 0.0, scene.camera(0.0), RES, seed=seed0 + k, static=i > 0))
        out.append(r.image.astype(np.float64))
    return np.stack(out)


def _check(living_reference, params):
    scene, names, masks, ref_a, ref_b = living_reference
    ok, info = region_z_test(_runs(scene, params), ref_a, ref_b, masks)
    rel = dict(zip(names, info["rel"]))
    return ok and abs(rel["away"]) < AWAY_MAX, rel, info


@pytest.mark.slow
def test_exact_radiance_agrees_with_mitsuba_per_region(backend, living_reference):
    """``exact_radiance=true``, ``visibility_reuse='unbiased'`` pinned, 8 independent runs of 24 accumulated
    frames at 48x27 against Mitsuba's 2 x 1024 spp: every region mean passes the z-test and the mean away
    from the walls is within 3 %."""
    ok, rel, info = _check(living_reference, PARAMS)
    assert ok, (rel, info)


@pytest.mark.slow
def test_region_test_fails_the_single_sample_target(backend, living_reference, monkeypatch):
    """The test has power: with the hook's old resampling target (``S(y)`` path-traced too: one sample,
    usually 0 here, so the samples at the target's floor make fireflies that carry most of the energy)
    the accumulated images are dark and the test fails."""
    from dyngi.techniques.ddgi_resampling.shading import SecondaryShading

    shade = SecondaryShading.shade_secondary

    def always_exact(self, *a, exact=None, **k):
        return shade(self, *a, **k)

    monkeypatch.setattr(SecondaryShading, "shade_secondary", always_exact)
    ok, rel, info = _check(living_reference, PARAMS)
    assert not ok, (rel, info)
