"""ddgi-secondary / ddgi-resampling (dyngi.techniques.ddgi_resampling).

* Eq. 7's footprint as the kernels sum it equals a NumPy transcription on random paths;
* footprint termination: on the glossy floor, the glossy recursion continues exactly where Eq. 8 says
  (footprint of x_1 x_2 recomputed in NumPy from the recorded vertices <= c a0);
* the G_max partition (Eq. 9): the bounded resampled part plus the residual BSDF sample estimates the
  same indirect light as the unpartitioned BSDF estimate (G_max = 0) and as resampling alone
  (G_max = 1e9), frozen probes, z-test on the per-frame image means;
* the exact-radiance hook: ddgi-resampling with the probes replaced by path-traced radiance agrees with
  Mitsuba's ``path`` with the unbiased options (the default among them), and the bias of Alg. 5's
  visibility reuse (``visibility_reuse='candidate'``, approximate supports of reused probe samples) stays
  bounded (region and image-mean t-tests; a fast image-mean version and a slow one; per region on the
  window-lit room: test_regions.py);
* the leak on the thin-walled room stays small, when that scene exists.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sst
from stats import luminance

from dyngi.backend import dr, mi
from dyngi.scene import builtin_names, load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.techniques.ddgi_resampling import camera_footprint, footprint_np, footprint_term

RES = (24, 18)
PROBES = {"probe_counts": "4", "rays_per_probe": 64, "warmup": 4}


def _run(tech, scene, frames, seed=0, static=True):
    scene.at(0.0)
    out = []
    for i in range(frames):
        out.append(tech.step(Frame(i, 0.0, scene.camera(0.0), RES, seed=seed, static=static and i > 0)))
    return out


def test_footprint_matches_eq7(backend):
    rng = np.random.default_rng(3)
    for n in (2, 3, 5):
        pts = rng.normal(size=(64, n, 3))
        nrm = rng.normal(size=(64, n, 3))
        nrm /= np.linalg.norm(nrm, axis=2, keepdims=True)
        pdf = rng.uniform(0.05, 50.0, size=(64, n - 1))
        want = np.array([footprint_np(pts[i], pdf[i], nrm[i]) for i in range(64)])
        s = mi.Float(0.0)
        for k in range(n - 1):
            d = pts[:, k + 1] - pts[:, k]
            r = np.linalg.norm(d, axis=1)
            cos = np.abs(np.einsum("ij,ij->i", nrm[:, k + 1], d / r[:, None]))
            s += footprint_term(mi.Float(r), mi.Float(pdf[:, k]), mi.Float(cos), mi.Bool(False))
        got = np.asarray(dr.square(s))
        assert np.allclose(got, want, rtol=1e-4)
    # a delta lobe adds no spread
    assert float(footprint_term(mi.Float(1.0), mi.Float(1.0), mi.Float(1.0), mi.Bool(True))[0]) == 0.0


@pytest.mark.parametrize("c", [0.2, pytest.param(0.05, marks=pytest.mark.slow)])
def test_footprint_termination_where_eq8_says(backend, c):
    """glossy-floor (rough plastic floor, GGX alpha 0.04): after one frame, the pixels whose secondary
    vertex x_2 continued the glossy recursion are exactly those with a(x_1 x_2) <= c a0, recomputed here
    from the recorded vertices (Eq. 7 with the primary BSDF's pdf, Eq. 8 with the camera position)."""
    scene = load_scene("glossy-floor")
    tech = create_technique("ddgi-secondary", scene, {**PROBES, "footprint_c": c, "max_glossy": 1})
    tech.record_debug = True
    _run(tech, scene, 1)
    d = {k: np.asarray(v) for k, v in tech.debug.items()}
    x0 = np.asarray(scene.camera(0.0).origin, np.float64)
    x1, x2, n1, n2 = (d[k].reshape(3, -1).T if d[k].ndim == 2 and d[k].shape[0] == 3 else d[k]
                      for k in ("x1", "x2", "n1", "n2"))
    ok = d["ok"] & d["glossy2"] & ~d["delta"]
    seg = np.linalg.norm(x2 - x1, axis=1)
    cos2 = np.abs(np.einsum("ij,ij->i", n2, (x2 - x1) / np.maximum(seg, 1e-12)[:, None]))
    a = seg ** 2 / np.maximum(d["p1"] * np.maximum(cos2, 1e-4), 1e-12)
    cam = x1 - x0
    depth = np.linalg.norm(cam, axis=1)
    cos1 = np.abs(np.einsum("ij,ij->i", n1, cam / np.maximum(depth, 1e-12)[:, None]))
    a0 = 4 * np.pi * depth ** 2 / np.maximum(cos1, 1e-4)
    go = d["rec"] > 0
    margin = np.abs(a / (c * a0) - 1.0) > 1e-2
    below = ok & (a <= c * a0) & margin
    above = ok & (a > c * a0) & margin
    assert below.sum() > 5 and above.sum() > 5, (below.sum(), above.sum())
    assert not np.any(go & above), "a path continued although Eq. 8's footprint exceeded c a0"
    assert not np.any(go & ~ok), "a path continued from a vertex without a glossy lobe"
    # below the threshold the recursion continues unless the one glossy sample failed (grazing)
    assert go[below].mean() > 0.9, go[below].mean()
    assert np.allclose(np.asarray(camera_footprint(mi.Float(depth), mi.Float(cos1))), a0, rtol=1e-4)


def _indirect_means(scene, frames, seed, **params):
    base = {**PROBES, "temporal": False, "progressive": False, "hysteresis": 1.0, "change_threshold": 1e30,
            "relocate": False, "classify": False}
    tech = create_technique("ddgi-resampling", scene, {**base, **params})
    rs = _run(tech, scene, frames, seed=seed)
    ind = np.stack([luminance(r.indirect) for r in rs])       # frames x H x W
    h, w = ind.shape[1:]
    quads = [ind[:, :h // 2, :w // 2], ind[:, :h // 2, w // 2:], ind[:, h // 2:, :w // 2], ind[:, h // 2:, w // 2:]]
    return np.stack([ind.mean((1, 2))] + [q.mean((1, 2)) for q in quads], 1)   # frames x 5


@pytest.mark.slow   # CI budget: seconds on a cold cache; runs in CI's slow subset
def test_gmax_partition_sums_to_the_unpartitioned_estimate(backend):
    """Eq. 9 on cornell-static with frozen probes (hysteresis 1 after the warm-up), independent frames
    (no temporal reuse, no accumulation): the indirect image's mean and quadrant means with the partition
    (the default constant G_max = 1) agree with the BSDF-only estimate (G_max = 0) and with resampling only (G_max = 1e9)
    -- Welch t-tests, Bonferroni over 2 x 5 statistics at alpha = 0.01. The same seed gives the same
    probes, so only the estimator differs."""
    scene = load_scene("cornell-static")
    n = 48
    part = _indirect_means(scene, n, 1, gmax=1.0)
    bsdf_only = _indirect_means(scene, n, 1, gmax=0.0)
    resampled = _indirect_means(scene, n, 1, gmax=1e9)
    alpha = 0.01 / 10
    for other in (bsdf_only, resampled):
        for j in range(5):
            p = sst.ttest_ind(part[:, j], other[:, j], equal_var=False).pvalue
            assert p > alpha, (j, part[:, j].mean(), other[:, j].mean(), p)
    # the partition does something: both of its parts carry light (checked on the last frame)
    tech = create_technique("ddgi-resampling", scene, {**PROBES, "temporal": False, "gmax": 1.0})
    tech.record_debug = True
    _run(tech, scene, 1)
    lz = float(np.mean(np.asarray(tech.debug["L_z"])))
    lr = float(np.mean(np.asarray(tech.debug["L_res"])))
    assert lz > 0.1 * (lz + lr) and lr > 0.02 * (lz + lr), (lz, lr)


def _mitsuba(scene, spp, k, max_depth):
    scene.at(0.0)
    sensor = scene.camera(0.0).to_sensor(RES, spp)
    integ = mi.load_dict({"type": "path", "max_depth": max_depth, "rr_depth": 5})
    return np.asarray(mi.render(scene.mi_scene, sensor=sensor, integrator=integ, spp=spp, seed=9100 + k),
                      np.float32)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["unbiased", "visibility-unbiased", "candidate"])
def test_exact_radiance_hook_converges_to_the_reference(backend, mode):
    """ddgi-resampling with ``exact_radiance`` (S(x) path-traced, max depth D - 1 from the secondary
    vertex): K independent accumulated runs (temporal and spatial reuse on) vs K Mitsuba ``path`` renders
    of depth D, compared on the mean of 6 image regions (3 x 2) and of all pixels that do not see the
    light (Welch t-tests, Bonferroni over 7 at alpha = 0.01).

    ``unbiased``: shadow rays for reused probe samples (``reuse_visibility``) and no visibility in the
    reservoirs (``visibility_reuse='none'``): every statistic must agree. ``visibility-unbiased``:
    ``visibility_reuse='unbiased'`` (visibility in the reuse's MIS weights, both parts), pinned: every
    statistic must agree (the default). ``candidate``: Alg. 5's visibility
    reuse (pinned) and approximate supports of reused probe samples are biased but bounded (the paper trades
    bias for noise): a statistic may differ significantly only by under 15 % (measured: the floor's region
    beside the tall box -8.6 %, p 3e-5; image mean +1.2 %), and the image mean by under 5 %.

    Not per pixel: the per-pixel run means are right-skewed (measured 2026-12-02, 10 runs x 24 frames:
    median skewness 0.46 vs 0.04 for Mitsuba's; the median per-pixel difference -2 % while the mean
    over the unlit pixels is +1.3 % +- 1.7 %), so the per-pixel t-test of ``restir-pt``'s test rejects
    28 of 432 pixels (expected <= 10) although the region means agree (p 0.33-0.60)."""
    scene = load_scene("cornell-static")
    D, K, frames = 5, 10, 24
    extra = {"unbiased": {"reuse_visibility": True, "visibility_reuse": "none"},
             "visibility-unbiased": {"visibility_reuse": "unbiased"},
             "candidate": {"visibility_reuse": "candidate"}}[mode]
    a = []
    for k in range(K):
        tech = create_technique("ddgi-resampling", scene, {**PROBES, "exact_radiance": True, "exact_depth": D - 1,
                                                           **extra})
        a.append(luminance(_run(tech, scene, frames, seed=300 + k)[-1].image))
    a = np.stack(a)
    b = np.stack([luminance(_mitsuba(scene, 16 * frames, k, D)) for k in range(K)])
    H, W = a.shape[1:]
    stats_a, stats_b = [], []
    for i in range(2):
        for j in range(3):
            sl = (slice(None), slice(i * H // 2, (i + 1) * H // 2), slice(j * W // 3, (j + 1) * W // 3))
            stats_a.append(a[sl].mean((1, 2)))
            stats_b.append(b[sl].mean((1, 2)))
    unlit = b.mean(0) < 1.0
    stats_a.append(a[:, unlit].mean(1))
    stats_b.append(b[:, unlit].mean(1))
    for sa, sb in zip(stats_a, stats_b):
        p = sst.ttest_ind(sa, sb, equal_var=False).pvalue
        rel = sa.mean() / sb.mean() - 1.0
        if mode != "candidate":
            assert p > 0.01 / len(stats_a), (mode, sa.mean(), sb.mean(), p)
        else:
            assert p > 0.01 / len(stats_a) or abs(rel) < 0.15, (sa.mean(), sb.mean(), p)
    if mode == "candidate":
        assert abs(a.mean() / b.mean() - 1.0) < 0.05, (a.mean(), b.mean())


@pytest.mark.slow   # CI budget: seconds on a cold cache; runs in CI's slow subset
def test_exact_radiance_hook_image_mean(backend):
    """Fast version of the convergence test: the image mean of the exact hook over independent frames
    (no temporal reuse, no accumulation) agrees with a 256-spp Mitsuba ``path`` render (z < 3.3)."""
    scene = load_scene("cornell-static")
    D = 5
    tech = create_technique("ddgi-resampling", scene, {**PROBES, "exact_radiance": True, "exact_depth": D - 1,
                                                       "temporal": False, "progressive": False})
    m = np.array([luminance(r.image).mean() for r in _run(tech, scene, 40, seed=11)])
    ref = luminance(_mitsuba(scene, 256, 0, D)).mean()
    z = (m.mean() - ref) / (m.std(ddof=1) / np.sqrt(len(m)))
    assert abs(z) < 3.3, (m.mean(), ref, z)


LEAK_SCENE = "living-room"


@pytest.mark.skipif(LEAK_SCENE not in builtin_names(), reason="thin-walled room scene not available yet")
@pytest.mark.slow   # CI budget: seconds on a cold cache; runs in CI's slow subset
@pytest.mark.parametrize("name", ["ddgi-secondary", "ddgi-resampling"])
def test_leak_on_the_thin_walled_room_stays_small(backend, name):
    """The thin sunlit walls of ``living-room`` leak little now that its probe
    volume lies inside the house. The image mean after 16 frames (48x36, 64 rays per probe) against a
    256-spp reference stays within LEAK_MAX of it (measured 2026-12-02: +1.8% / +4.0% for ddgi-secondary /
    ddgi-resampling; with the volume over the whole house, outer layers in the sun: +74% / +78%, which
    this test used to require)."""
    from dyngi.experiments.references.path import reference_image, scene_max_depth

    scene = load_scene(LEAK_SCENE)
    res = (48, 36)
    tech = create_technique(name, scene, {"rays_per_probe": 64})
    scene.at(0.0)
    r = None
    for i in range(16):
        r = tech.step(Frame(i, 0.0, scene.camera(0.0), res, seed=0, static=i > 0))
    ref = reference_image(scene, 0.0, res, 256, scene_max_depth(scene))
    ratio = float(luminance(r.image).mean() / max(luminance(ref).mean(), 1e-9))
    print(f"{name} living-room mean ratio {ratio:.3f}")
    assert np.isfinite(ratio) and abs(ratio - 1.0) < LEAK_MAX, ratio


LEAK_MAX = 0.2
"""Bound of the relative error of the image mean on the thin-walled room, see the test."""


def test_reproduction_is_registered_and_counts_frames(backend):
    """``dyngi reproduce ddgi-resampling`` exists; Table 1's frame count is the first frame at or below
    the target MAPE (1-based), None when never reached."""
    from dyngi.experiments.reproduce import experiment_names
    from dyngi.experiments.reproductions.ddgi_resampling import frames_to_reach, steady_ms

    assert "ddgi-resampling" in experiment_names()
    assert frames_to_reach([0.5, 0.41, 0.4, 0.3], 0.4) == 3
    assert frames_to_reach([0.5, float("nan"), 0.45], 0.4) is None
    assert steady_ms([900.0, 300.0, 10.0, 12.0, 11.0]) == 11.0


@pytest.mark.slow
def test_reproduction_protocol_on_a_tiny_scene(backend):
    """``reproduce ddgi-resampling``'s per-scene protocol at a tiny size (the CLI's smoke run is
    tests/experiments/test_reproduce_smoke.py; the protocol's arithmetic
    tests/experiments/test_ddgi_resampling_protocol.py): the three noisy methods with frames and time per
    seed, a finite target taken from one of them, the reference's spp grown from its start and its noise,
    the emission calibration, the probe rays per pixel, and the tables format."""
    from dyngi.experiments.reproductions import ddgi_resampling as rep

    cfg = {"res": (16, 9), "max_frames": 6, "ref_spp": 4, "ref_spp_max": 64, "seeds": 3, "warm_frames": 3,
           "steady_frames": 2, "calib_frames": 4}
    f = rep.run_scene("cornell-static", cfg)
    assert set(f["techniques"]) == set(rep.METHODS)
    assert np.isfinite(f["target_mape"]) and f["target_method"] in f["techniques"]
    assert f["target_mape"] == pytest.approx(min(np.mean(v) for v in f["one_frame_mape"].values()))
    assert all(len(t["seeds"]) == 3 for t in f["techniques"].values())
    assert 4 <= f["reference"]["spp"] <= 64 and np.isfinite(f["reference"]["noise_mape"])
    assert f["reference"]["ok"] or f["reference"]["spp"] == 64
    assert f["calibration"]["scale"] >= 0 and f["probe_rays_per_pixel"] > 0
    t1, prot, fits, _ = rep._tables([f])
    assert "cornell-static (RED BALL)" in t1 and "cornell-static" in prot


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ddgi-primary", "ddgi-secondary", "ddgi-resampling"])
def test_lights_parameter_keeps_the_estimate(backend, name):
    """``lights=power`` (ReSTIR DI's candidates, and ddgi-primary's NEE, from a dyngi.lights sampler) and the
    default (Mitsuba's emitter sampling) estimate the same image: per-pixel z-test over 12 seeds."""
    from stats import z_test_images
    from dyngi.experiments.runner import run_sequence
    from dyngi.scene import load_scene
    from dyngi.techniques.base import create_technique

    params = {"candidates": 4, "probe_counts": "3", "rays_per_probe": 16, "warmup": 1}
    if name != "ddgi-primary":
        params["progressive"] = False

    def renders(lights, seed0):
        out = []
        for s in range(12):
            sc = load_scene("cornell-static")
            tech = create_technique(name, sc, dict(params, lights=lights))
            out.append(run_sequence(sc, tech, 2, (32, 18), seed=seed0 + s).images[-1])
        return np.stack(out)

    a, b = renders("power", 100), renders("scene", 0)
    assert np.all(np.isfinite(a)) and a.mean() > 0
    ok, info = z_test_images(a, b)
    assert ok, f"{name}:lights=power disagrees with the default: {info}"
