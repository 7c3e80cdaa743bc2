"""``lights=`` on the VPL techniques: the radiosity of ``smcir``'s and
``mir``'s VPLs is estimated by the path walk, whose NEE goes through a light sampler
(:class:`dyngi.lights.nee.LightNEE`); ``ir`` and ``tcas`` carry radiosity on photons, whose lights the
sampler chooses (:mod:`dyngi.vpl.emission`: 'uniform' and 'power', samplers without a shading point)."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.errors import DyngiError
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.color import luminance


def test_photon_techniques_take_point_free_samplers_and_unknown_names_list_the_choices(backend):
    sc = load_scene("cornell-static")
    for spec in ("ir", "tcas"):
        assert create_technique(spec, sc, {"lights": "power"}).lights.kind == "power"
        with pytest.raises(DyngiError, match="power"):      # a point-dependent sampler: the valid ones named
            create_technique(spec, sc, {"lights": "lighttree"})
    with pytest.raises(DyngiError, match="power"):
        create_technique("smcir", sc, {"lights": "brightest"})


@pytest.mark.slow
def test_photons_through_a_light_sampler_carry_the_same_power(backend):
    """maze (11 area lights of unequal power + 2 point lights: both branches of the emission), 16384
    photons: the first-bounce radiosity per photon (emitted power / pdf x albedo / pi) with the lights
    chosen by ``lights=power`` and ``lights=uniform`` has the mean of Mitsuba's ``sample_emitter_ray``
    (two-sample z-test, |z| < 4, independent seeds); the same seeds give other photons (the sampler is in
    use); ``tcas``'s photon hits (:func:`photon_first_hits_device`) agree the same way; then one frame of
    ``ir:lights=power`` and ``tcas:lights=uniform`` is finite and lit."""
    from dyngi.lights.nee import LightNEE
    from dyngi.vpl.points import photon_first_hits, trace_photons

    sc = load_scene("maze")
    sc.at(0.0)
    cam = sc.camera(0.0)
    n = 16384

    def first_bounce(lights, seed):
        v, _ = trace_photons(sc, n, 1, seed, lights=lights)
        return luminance(v["radiosity"][:n])

    def z(a, b):
        return (a.mean() - b.mean()) / np.sqrt((a.var() + b.var()) / len(a))

    base = first_bounce(None, 11)
    assert base.mean() > 0 and base.std() > 0
    u = np.random.default_rng(3).random((n, 5))
    hits_base = luminance(photon_first_hits(sc, u)[0]["radiosity"])
    u2 = np.random.default_rng(4).random((n, 5))
    for kind in ("power", "uniform"):
        nee = LightNEE(sc, kind)
        assert 0.0 < nee.p_tri < 1.0 and nee.others is not None       # triangles and point lights
        nee.begin_frame(sc, Frame(0, 0.0, cam, (32, 18), seed=0), 0)
        got = first_bounce(nee, 12)
        assert not np.array_equal(first_bounce(nee, 11), base)
        assert abs(z(got, base)) < 4.0, (kind, z(got, base), got.mean(), base.mean())
        hits = luminance(photon_first_hits(sc, u2, nee)[0]["radiosity"])
        assert abs(z(hits, hits_base)) < 4.0, (kind, "tcas hits", z(hits, hits_base))
    for spec, params in (("ir", {"vpls": 64, "lights": "power"}),
                         ("tcas", {"vpls": 64, "iterations": 2, "view_samples": 8, "lights": "uniform"})):
        r = create_technique(spec, sc, params).step(Frame(0, 0.0, cam, (32, 18), seed=0))
        assert np.all(np.isfinite(r.indirect)) and r.indirect.mean() > 0, spec


@pytest.mark.slow
def test_radiosity_through_a_light_sampler_has_the_same_mean(backend):
    """maze (13 lights; a point on a wall), 1024 VPL seeds x 4 paths: the radiosity estimate with NEE by
    ``lights=power`` and by ``lights=uniform`` has the mean of Mitsuba's emitter sampling (two-sample
    z-test, |z| < 4); then one frame of ``smcir:lights=power`` and ``mir:lights=uniform`` is finite and lit."""
    from dyngi.lights.nee import LightNEE
    from dyngi.vpl.radiosity import estimate_radiosity

    sc = load_scene("maze")
    sc.at(0.0)
    cam = sc.camera(0.0)
    n = 1024
    from dyngi.vpl.points import raw_candidates
    cand, _, _ = raw_candidates(sc, cam, (32, 18), 4096, 0, 0)
    pos = np.repeat(cand["pos"][:1], n, axis=0)
    nrm = np.repeat(cand["nrm"][:1], n, axis=0)
    seeds = np.random.default_rng(2).integers(0, 1 << 62, n, dtype=np.uint64)

    def lum(lights, s):
        L, _ = estimate_radiosity(sc.mi_scene, pos, nrm, s, 4, 4, lights)
        return luminance(L)

    base = lum(None, seeds)
    assert base.mean() > 0 and base.std() > 0
    for kind in ("power", "uniform"):
        nee = LightNEE(sc, kind)
        nee.begin_frame(sc, Frame(0, 0.0, cam, (32, 18), seed=0), 16 * n)
        got = lum(nee, seeds ^ np.uint64(0x5A5A))
        assert not np.array_equal(lum(nee, seeds), base)       # the sampler is in use (same seeds differ)
        nee.end_frame()
        z = (got.mean() - base.mean()) / np.sqrt((got.var() + base.var()) / n)
        assert abs(z) < 4.0, (kind, z, got.mean(), base.mean())
    for spec, params in (("smcir", {"vpls": 64, "warmup": 2, "radiosity_spp": 4, "lights": "power"}),
                         ("mir", {"vpls": 64, "resampling_rate": 8, "lights": "uniform"})):
        r = create_technique(spec, sc, params).step(Frame(0, 0.0, cam, (32, 18), seed=0))
        assert np.all(np.isfinite(r.indirect)) and r.indirect.mean() > 0, spec


@pytest.mark.slow
def test_direct_light_through_a_light_sampler_has_the_same_mean(backend):
    """maze at 32x18 (13 lights, area and point), ``ir`` with one VPL budget: the direct light at the camera's
    hit (image - indirect) through ``lights=power`` (:class:`~dyngi.lights.nee.TracedNEE`, the
    light sampler's NEE) against Mitsuba's emitter sampling (``lights=scene``), 16 seeds each of 16 NEE
    samples per pixel: per-pixel two-sample z-test (|z| < 4.5, about Sidak's bound for 1728
    pixel-channels at alpha 0.01) and the image means (|z| < 4; a sampler whose weights were 10 % high gave
    z = -5.2); the same seed gives another image (the sampler is in use)."""
    sc = load_scene("maze")
    sc.at(0.0)
    cam = sc.camera(0.0)
    techs = {k: create_technique("ir", sc, {"vpls": 16, "direct_samples": 16, "lights": k})
             for k in ("scene", "power")}

    def direct(kind, seed):
        r = techs[kind].step(Frame(0, 0.0, cam, (32, 18), seed=seed))
        return r.image - r.indirect

    n = 16
    a = np.stack([direct("scene", s) for s in range(n)])
    b = np.stack([direct("power", 100 + s) for s in range(n)])
    assert a.mean() > 0 and not np.array_equal(direct("power", 0), a[0])
    va, vb = a.var(0, ddof=1), b.var(0, ddof=1)
    se = np.sqrt((va + vb) / n)
    lit = se > 0
    z = (a.mean(0) - b.mean(0))[lit] / se[lit]
    assert np.abs(z).max() < 4.5, (np.abs(z).max(), int((np.abs(z) > 4.5).sum()))
    ma, mb = a.mean((1, 2, 3)), b.mean((1, 2, 3))
    zm = (ma.mean() - mb.mean()) / np.sqrt((ma.var(ddof=1) + mb.var(ddof=1)) / n)
    assert abs(zm) < 4.0, (zm, ma.mean(), mb.mean())
