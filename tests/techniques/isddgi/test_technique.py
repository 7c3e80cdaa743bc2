"""IS-DDGI (Liu et al. 2023, supplement Secs. 1-4): allocation pdf, rotation, stratified weights,
importance after a light switch, integration, static convergence to ``ddgi``, and the quick reproduction (slow)."""
from __future__ import annotations

import numpy as np
import pytest

from stats import chi2_uniform

from dyngi.techniques.isddgi.estimator import integrate_sets, integrate_sets_dr, probe_states_alg2
from dyngi.techniques.isddgi.planner import ISDDGIPlanner
from dyngi.techniques.isddgi.sets import (N_SETS, RAYS_LIMIT, allocation_pdf, jittered_directions,
                                         probe_shift, sample_allocation, set_solid_angles, uniform_mask)


def _assert_draws_follow(counts, pdf, n, P):
    """``counts`` of ``n`` draws follow ``pdf`` (chi^2 at 16 cells per probe -- odd grids are pooled by
    chi2_uniform's low-cell rule -- and per (probe, set)), and the test can fail: a 5% wrong pdf is rejected."""
    ok, p = chi2_uniform(counts.reshape(P, 16, 16).sum(2), pdf.reshape(P, 16, 16).sum(2) * n)
    assert ok, p
    ok, p = chi2_uniform(counts, pdf * n)
    assert ok, p
    bad = pdf.copy()
    bad[0] *= 1.05
    bad /= bad.sum()
    assert not chi2_uniform(counts.reshape(P, 16, 16).sum(2), bad.reshape(P, 16, 16).sum(2) * n)[0]


def test_set_solid_angles_sum_to_4pi_and_differ():
    om = set_solid_angles()
    assert om.shape == (N_SETS,)
    assert abs(om.sum() - 4 * np.pi) < 1e-9
    assert om.max() / om.min() > 3.0          # why the per-set weights matter (Algorithm 3)


def test_jittered_directions_stay_in_their_set():
    from dyngi.sampling.octahedral import oct_encode_np
    j = np.arange(N_SETS).repeat(8)
    d = jittered_directions(np.zeros_like(j), j, np.tile(np.arange(8) % RAYS_LIMIT, N_SETS), 3, 1)
    p = (oct_encode_np(d) * 0.5 + 0.5) * 16
    back = np.clip(p[:, 1].astype(int), 0, 15) * 16 + np.clip(p[:, 0].astype(int), 0, 15)
    assert np.mean(back == j) > 0.999          # (points exactly on an edge may round either way)


def test_allocation_pdf_sums_to_one_and_sampling_matches_it():
    rng = np.random.default_rng(3)
    P = 6
    f = rng.random((P, N_SETS)) ** 4
    f[2] = 0.0                               # a probe with no measured change
    F = np.array([1.0, 0.5, 0.2, 0.0, 2.0, 0.1])
    pdf = allocation_pdf(F, f, eps=0.1)
    assert abs(pdf.sum() - 1.0) < 1e-12 and np.all(pdf >= 0)
    assert np.all(pdf[3] == 0)               # F = 0: no importance rays
    n = 400_000
    counts = sample_allocation(pdf, n, np.random.default_rng(11))
    assert counts.sum() == n
    _assert_draws_follow(counts, pdf, n, P)


def test_device_allocation_pdf_and_draws_match_the_supplement(backend):
    """The device kernels (:mod:`dyngi.techniques.isddgi.device`): the Dr.Jit pdf equals the supplement's
    allocation (NumPy twin), and 400k prefix-sum + binary-search draws match it (chi^2, 16 cells per
    probe and every (probe, set) pair; a 5% wrong pdf is rejected); a zero-F probe gets no draw. The
    planner's per-set cap and its draws: tests/techniques/isddgi/test_device.py."""
    from dyngi.backend import mi
    from dyngi.techniques.isddgi.device import allocation_pdf_dr, sample_pairs_dr
    rng = np.random.default_rng(3)
    P = 6
    f = (rng.random((P, N_SETS)) ** 4).astype(np.float32)
    f[2] = 0.0
    F = np.array([1.0, 0.5, 0.2, 0.0, 2.0, 0.1], np.float32)
    pdf = allocation_pdf(F, f, eps=0.1)
    pd = allocation_pdf_dr(mi.Float(F), mi.Float(f.ravel()), 0.1)
    assert np.allclose(np.asarray(pd), pdf.ravel(), rtol=1e-5, atol=1e-9)
    n = 400_000
    idx = sample_pairs_dr(pd, n, seed=7)
    counts = np.bincount(np.asarray(idx), minlength=P * N_SETS).reshape(P, N_SETS)
    assert counts.sum() == n and counts[3].sum() == 0
    _assert_draws_follow(counts, pdf, n, P)


def test_allocation_is_zero_without_change():
    pdf = allocation_pdf(np.zeros(4), np.zeros((4, N_SETS)), 0.1)
    assert pdf.sum() == 0
    assert sample_allocation(pdf, 100, np.random.default_rng(0)).sum() == 0


@pytest.mark.parametrize("x", [1, 4, 8, 16, 32, 64, 128, 256])
def test_rotation_visits_every_set_within_256_over_x_frames(x):
    P = 7
    shift = probe_shift(np.arange(P))
    K = N_SETS // x
    seen = np.zeros((P, N_SETS), int)
    for t in range(100, 100 + K):
        m = uniform_mask(np.full(P, x), t, shift)
        assert np.all(m.sum(1) == x)          # x uniform rays per probe per frame
        seen += m
    assert np.all(seen == 1)                  # every set exactly once in 256/x frames
    # cells: x cells of K consecutive row-major texels, one ray each (Fig. 1)
    m = uniform_mask(np.full(P, x), 5, shift)
    assert np.all(m.reshape(P, x, K).sum(2) == 1)
    # random shifting: probes differ
    if K > 1:
        assert len({tuple(np.flatnonzero(r)) for r in m}) > 1


def _dense_integral(fn):
    """int_S2 fn(w) dw by midpoint quadrature on the octahedral square (64 x 64 sub-texels per set)."""
    from dyngi.sampling.octahedral import oct_decode_np, texel_solid_angles
    m = 16 * 16
    om = texel_solid_angles(m + 2, sub=2).ravel()
    c = (np.arange(m) + 0.5) / m * 2 - 1
    py, px = np.meshgrid(c, c, indexing="ij")
    d = oct_decode_np(np.stack([px, py], -1)).reshape(-1, 3)
    return float(np.sum(fn(d) * om) * 4 * np.pi / om.sum())


def test_stratified_weights_are_unbiased():
    """sum_r (Omega_set / n_set) h(w_r) over every set (1..4 rays each) is unbiased for int h: mean over
    seeds vs a dense quadrature, z-test (|z| < 3.5); and a plain mean without the solid angles is not."""
    def h(d):
        return np.exp(3 * d[:, 0]) * (1.5 + d[:, 2]) + 4 * (d[:, 1] > 0.6)
    truth = _dense_integral(h)
    pl = ISDDGIPlanner(1)
    rng = np.random.default_rng(5)
    counts = rng.integers(1, RAYS_LIMIT + 1, (1, N_SETS))
    ests, naive = [], []
    for seed in range(300):
        info = pl._rays(np.array([0]), counts, frame=seed, seed=seed)
        v = h(info.ray_dir.astype(np.float64))
        ests.append(np.sum(info.ray_weight * v))
        naive.append(4 * np.pi * np.mean(v))
    ests, naive = np.array(ests), np.array(naive)
    z = (ests.mean() - truth) / (ests.std(ddof=1) / np.sqrt(len(ests)))
    assert abs(z) < 3.5, (ests.mean(), truth, z)
    zn = (naive.mean() - truth) / (naive.std(ddof=1) / np.sqrt(len(naive)))
    assert abs(zn) > 3.5, (naive.mean(), truth, zn)     # the test has power: unweighted rays are biased


def _feed(pl, plan, lum_fn, dist=1.0):
    info = plan.info
    lum = lum_fn(np.asarray(plan.probe_ids, np.int64)[info.ray_slot], info.ray_set)
    return pl.observe(plan, lum, np.full(len(lum), dist))


def test_importance_rays_concentrate_after_a_light_switch():
    """Scripted switch: at frame 20 a light lights the sets j < 32 of probes 0..3 (of 64), luminance 0.1 -> 2
    (5% noise on every ray); a few frames later
    most importance rays go to those (probe, set) pairs (1/128 of all pairs), and probes 0..3 raise x_i."""
    P = 64
    pl = ISDDGIPlanner(P, x_init=32, x_min=16, x_max=64, importance_rays=8)
    ids = np.arange(P, dtype=np.uint32)
    lit = np.zeros((P, N_SETS), bool)
    lit[:4, :32] = True
    rng = np.random.default_rng(0)

    def lum(on):
        return lambda p, j: (1.0 + 0.05 * rng.standard_normal(len(j))) * np.where(on & lit[p, j], 2.0, 0.1)
    for t in range(20):
        plan = pl.plan(t, 0, ids)
        _feed(pl, plan, lum(False))
    assert plan.info.stats["importance_rays"] == 0          # static: no change, no importance rays
    hits, tot = 0, 0
    for t in range(20, 30):
        plan = pl.plan(t, 0, ids)
        if t >= 23:
            imp = plan.info.importance
            hits += imp[lit].sum()
            tot += imp.sum()
        _feed(pl, plan, lum(True))
    assert tot > 0
    assert hits / tot > 0.7, hits / tot
    assert np.all(pl.state.x[:4] > 32) and np.all(pl.state.x[4:] <= 32)


def test_one_ray_variant_has_at_most_one_ray_per_set():
    pl = ISDDGIPlanner(8, variant="one-ray", importance_rays=64)
    pl.state.F[:] = 1.0
    pl.state.f[:, :8] = 1.0
    plan = pl.plan(0, 0, np.arange(8, dtype=np.uint32))
    assert plan.info.counts.max() == 1 and plan.info.stats["importance_rays"] > 0
    pl2 = ISDDGIPlanner(8, importance_rays=64)
    pl2.state.F[:] = 1.0
    pl2.state.f[:, :8] = 1.0
    c = pl2.plan(0, 0, np.arange(8, dtype=np.uint32)).info.counts
    assert c.max() == RAYS_LIMIT
    # rayHitInfo: prefix and total agree with the counts
    info = pl2.plan(1, 0, np.arange(8, dtype=np.uint32)).info
    assert np.all(info.prefix[:, 1:] == np.cumsum(info.counts, 1)[:, :-1]) and np.all(info.total == info.counts.sum(1))


def test_integration_drjit_matches_numpy_and_holds_e_over_pi(backend):
    """Algorithm 3 on a constant-radiance sphere: every set stores L (E/pi convention); Dr.Jit == NumPy."""
    from dyngi.backend import dr, mi
    pl = ISDDGIPlanner(3, x_init=64, x_max=64)
    pl.state.F[:] = 1.0
    pl.state.f[:, ::7] = 1.0
    plan = pl.plan(4, 2, np.arange(3, dtype=np.uint32))
    R = plan.n_rays
    rng = np.random.default_rng(1)
    L = (0.5 + rng.random((R, 3))).astype(np.float32)
    d = (0.2 + rng.random(R)).astype(np.float32)
    d[::11] *= -0.2                                       # back faces: out of the irradiance
    Ldr = mi.Color3f(*[mi.Float(L[:, c].copy()) for c in range(3)])
    for side in (16, 6):          # irradiance per set, and at ddgi's 6x6 interior texels (the default)
        irr, irr_w, irr_n, mom, mom_w, mom_n = integrate_sets(plan.info, L, d, 1.0, irr_side=side)
        ei, ed = integrate_sets_dr(plan, Ldr, mi.Float(d), 1.0, irr_side=side)
        T = side * side
        vi = np.asarray(ei.value).reshape(3, 3 * T).T.reshape(3, T, 3)
        vd = np.asarray(ed.value).reshape(2, 3 * N_SETS).T.reshape(3, N_SETS, 2)
        assert np.allclose(vi, irr, rtol=2e-4, atol=1e-5)
        assert np.allclose(vd, mom, rtol=2e-4, atol=1e-5)
        assert np.array_equal(np.asarray(ei.count).reshape(3, T), (irr_w > 0).astype(np.uint32))
    # constant radiance: the self-normalised cosine mean is L in every set that received weight
    Lc = np.ones((R, 3), np.float32) * 0.7
    irr_c = integrate_sets(plan.info, Lc, np.abs(d), 1.0)[0]
    assert np.allclose(irr_c, 0.7, rtol=1e-4)


def test_probe_state_algorithm_2():
    class Info:
        total = np.array([4, 4, 4, 0])
        ray_slot = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2])
    d = np.array([1, 2, np.inf, -0.1,  -0.1, -0.2, 1, 1,  np.inf, np.inf, np.inf, np.inf])
    on = probe_states_alg2(Info, d, 0.3)
    # probe 0: front hits, 1/4 back < 0.3 -> ON; probe 1: 2/4 back -> OFF; probe 2: misses only -> OFF
    # (line 17's min over negative distances would have called probe 1's back faces "front"); 3: no rays
    assert on.tolist() == [True, False, False, False]
    # DDGI's near-surface test on ragged rays: spacing 1, probe 0 inside the grid (neighbourhood
    # |t w| <= 1), probe 1 on its low-x boundary (unbounded towards -x)
    from types import SimpleNamespace
    from dyngi.techniques.isddgi.estimator import near_surface_hits, near_window
    grid = SimpleNamespace(spacing_np=np.ones(3, np.float32), counts=(3, 3, 3),
                           probe_coords=lambda pid: np.array([[1, 1, 1], [0, 1, 1]])[np.asarray(pid) - 5])
    vol = SimpleNamespace(grid=grid)
    s2 = 1 / np.sqrt(2)
    dirs = np.array([[1, 0, 0], [s2, s2, 0], [-1, 0, 0], [-1, 0, 0], [0, 1, 0]], np.float32)
    slot = np.array([0, 0, 1, 1, 1])
    # probe 0: 1.2 along +x leaves the cell (far), 1.3 along the diagonal is inside (|1.3 * 0.707| <= 1);
    # probe 1: a back face and a far -x hit (boundary: near), or only far hits
    near = near_surface_hits(vol, [5, 6], slot, dirs, np.array([1.2, 1.3, -0.1, 7.0, 3.0]))
    assert near.tolist() == [True, True]
    near = near_surface_hits(vol, [5, 6], slot, dirs, np.array([1.2, np.inf, -0.1, np.inf, 3.0]))
    assert near.tolist() == [False, False]
    assert near_window(np.array([8, 32, 256])).tolist() == [32, 8, 1]


def test_linear_mean_accumulator_removes_the_few_ray_gamma_bias(backend):
    """The static-scene penalty's cause, in isolation: 400 blends (hysteresis 0.8, gamma 5) of noisy
    per-frame estimates with mean 1 (gamma-distributed, shape 2: a few-ray estimate). DDGI's perceptual
    accumulator converges ~10% low (Jensen: the mean of ``x^(1/5)``, to the 5th power); IS-DDGI's
    :class:`LinearMeanHysteresis` to the mean within 3%; and it is DDGI's accumulator at gamma 1."""
    from dyngi.backend import dr, mi
    from dyngi.probes.accumulator import HysteresisAccumulator
    from dyngi.techniques.isddgi.estimator import LinearMeanHysteresis
    rng = np.random.default_rng(4)
    n, frames = 4096, 400
    x = rng.gamma(2.0, 0.5, (frames, n)).astype(np.float32)
    out = {}
    for name, acc in (("ddgi", HysteresisAccumulator(0.8, 5.0, 0.25, float("inf"))),
                      ("linear", LinearMeanHysteresis(0.8, 5.0, 0.25, float("inf")))):
        old = mi.Color3f(1.0)
        tail = []
        for f in range(frames):
            new = mi.Color3f(mi.Float(x[f]))
            old, _ = acc.irradiance(old, new, mi.UInt32(1), mi.UInt32(1), mi.Bool(False), 1000)
            dr.eval(old)
            if f >= 100:
                tail.append(np.asarray(old[0]).mean())
        out[name] = float(np.mean(tail))
    assert out["ddgi"] < 0.95, out                      # the bias exists (the test has power)
    assert abs(out["linear"] - 1.0) < 0.03, out
    one = LinearMeanHysteresis(0.8, 1.0, 0.25, float("inf"))
    ref = HysteresisAccumulator(0.8, 1.0, 0.25, float("inf"))
    a = mi.Color3f(mi.Float(x[0]))
    b = mi.Color3f(mi.Float(x[1]))
    ra = one.irradiance(a, b, mi.UInt32(1), mi.UInt32(1), mi.Bool(False), 1000)[0]
    rb = ref.irradiance(a, b, mi.UInt32(1), mi.UInt32(1), mi.Bool(False), 1000)[0]
    assert np.allclose(np.asarray(ra[0]), np.asarray(rb[0]))


def _static_mean_indirect(scene, spec, frames=24, tail=12, res=(32, 24)):
    from dyngi.techniques import Frame, create_technique
    t = scene.frame_time(0)
    scene.at(t)
    tech = create_technique(spec, scene)
    acc = 0
    for i in range(frames):
        r = tech.step(Frame(i, t, scene.camera(t), res, seed=0))
        if i >= frames - tail:
            acc = acc + r.indirect
    return acc / tail


@pytest.mark.slow
def test_isddgi_static_scene_converges_to_ddgi(backend):
    """Static Cornell box (4^3 probes, hysteresis 0.8, 32x24, mean indirect image of frames 12-23): with
    no change detected IS-DDGI's uniform rays converge to DDGI's answer: within 3% of ``ddgi`` (256 rays)
    at the default perceptual blend (gamma 5) and the same hysteresis, and within 3% of
    ``probes-reference`` (8x8 texels, 16 rays per texel: the irradiance texels of ``ddgi``) with
    ``irradiance_gamma=1``; per-pixel relative RMS difference to ``ddgi`` under 0.35. Before the linear
    running mean (:class:`~dyngi.techniques.isddgi.estimator.LinearMeanHysteresis`) the gamma-5 ratio was
    ~0.91 (figures: docs/techniques/isddgi.md)."""
    from dyngi.scene import load_scene
    scene = load_scene("cornell-moving-box")
    isd = _static_mean_indirect(scene, "isddgi:probe_counts=4:hysteresis=0.8")
    dd = _static_mean_indirect(scene, "ddgi:probe_counts=4:hysteresis=0.8")
    isd1 = _static_mean_indirect(scene, "isddgi:probe_counts=4:hysteresis=0.8:irradiance_gamma=1")
    ref = _static_mean_indirect(scene, "probes-reference:probe_counts=4:texels=8:rays_per_texel=16")
    ratio, ratio_ref = isd.mean() / dd.mean(), isd1.mean() / ref.mean()
    mask = dd.sum(-1) > 0.05 * dd.sum(-1).max()
    rel = np.sqrt(np.mean(((isd - dd).sum(-1)[mask] / dd.sum(-1)[mask]) ** 2))
    print(f"isddgi/ddgi (gamma 5) {ratio:.4f}, isddgi/reference (gamma 1) {ratio_ref:.4f}, rel. RMS {rel:.3f}")
    assert abs(ratio - 1) < 0.03, ratio
    assert abs(ratio_ref - 1) < 0.03, ratio_ref
    assert rel < 0.35, rel


@pytest.mark.slow
def test_isddgi_update_does_less_work_than_ddgi_with_the_same_stages(backend):
    """Static Cornell box, 4^3 probes, defaults (``ddgi``: 256 rays per probe): both report the pipeline's
    stages (``trace probes``, ``shade probes``, ``blend``, ``states``: the stage table compares like with
    like), and on a steady frame isddgi traces fewer probe rays and its estimator does fewer ray x texel
    products (rays x interior irradiance and distance texels; isddgi stores ddgi's squares, so its merge
    touches as many texels per probe); on tunnel-gate it keeps no more probes active than ddgi
    (near-surface test). Counts, not timings."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    scene = load_scene("cornell-moving-box")
    t = scene.frame_time(0)
    scene.at(t)
    stages, rays, products = {}, {}, {}
    for name in ("isddgi", "ddgi"):
        tech = create_technique(f"{name}:probe_counts=4:warmup=1", scene)
        for i in range(2):
            r = tech.step(Frame(i, t, scene.camera(t), (16, 12), seed=0))
        stages[name] = set(r.stats["ms"]) - {"primary"}
        rays[name] = r.stats["rays"]["trace probes"]
        vol = tech.volume       # both lobes over the interior texels; isddgi: ddgi's squares
        products[name] = rays[name] * ((vol.irradiance_texels - 2) ** 2 + (vol.distance_texels - 2) ** 2)
        if name == "isddgi":
            assert (vol.irradiance_texels, vol.distance_texels) == (8, 16)
    assert stages["isddgi"] == stages["ddgi"] == {"trace probes", "shade probes", "blend", "states"}, stages
    assert 0 < rays["isddgi"] < 0.5 * rays["ddgi"], rays
    assert products["isddgi"] < 0.5 * products["ddgi"], products
    # probe states: on tunnel-gate (open space above and beside the tunnel) Algorithm 2 alone keeps
    # ~2x ddgi's probes ON; with DDGI's near-surface test isddgi updates no more probes than ddgi
    scene = load_scene("tunnel-gate")
    t = scene.frame_time(0)
    scene.at(t)
    active = {}
    for spec in ("isddgi", "isddgi:near_surface=false", "ddgi"):
        tech = create_technique(f"{spec}:warmup=1", scene)
        for i in range(2):
            r = tech.step(Frame(i, t, scene.camera(t), (16, 12), seed=0))
        active[spec] = (r.stats["active_probes"], r.stats.get("probes_traced"))
    assert active["isddgi"][0] <= active["ddgi"][0], active
    assert active["isddgi:near_surface=false"][0] > 1.5 * active["ddgi"][0], active    # the test has power


@pytest.mark.slow
def test_reproduce_isddgi_quick(tmp_path):
    import json
    import os
    from dyngi.experiments.reproduce import run_experiment
    out = run_experiment("isddgi", str(tmp_path / "rep"), quick=True)
    with open(os.path.join(out, "paper.json")) as f:
        rows = json.load(f)["rows"]
    assert any("trace" in r["quantity"] for r in rows)


@pytest.mark.slow
def test_rendered_light_switch_concentrates_importance_rays(backend):
    """corridor-rooms: the ceiling light of room 1 north (x in [4, 8], z in [1, 5]) switches off at t = 1 s
    (nothing else changes before 1.5 s). Frames at t = 0.9 (light on), then at t = 1.2: within 2-6 frames
    after the switch most importance rays go to the probes of that room (the probes inside it or on its
    walls, lattice points within 0.1 m: relocation may move those to either side; ~9% of the probes); bound
    0.7. Measured 2026-12-02 with paired visits (keyed NEE randomness, :mod:`dyngi.techniques.isddgi.shading`):
    0.94-0.98 on frames 12-16 (before them, per-frame NEE noise gave ~0.05: the old strict xfail)."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    scene = load_scene("corridor-rooms")
    tech = create_technique("isddgi:probe_counts=16,3,8", scene)
    pos = tech.volume.grid.base_positions()
    room = (pos[:, 0] > 3.9) & (pos[:, 0] < 8.1) & (pos[:, 2] > 0.9) & (pos[:, 2] < 5.1)
    assert 0.03 < room.mean() < 0.12
    res = (16, 12)
    fr = 0
    static_imp, after = 0, []
    for t, n in ((0.9, 10), (1.2, 7)):
        scene.at(t)
        for _ in range(n):
            r = tech.step(Frame(fr, t, scene.camera(t), res, seed=0))
            if t < 1.0:
                static_imp += r.stats["importance_rays"]
            if t > 1.0 and fr >= 12:
                after.append(r.stats["importance_rays"])
                plan = tech.last_plan
                imp = plan.info.importance.sum(1)
                ids = plan.probe_ids.astype(np.int64)
                frac = imp[room[ids]].sum() / max(imp.sum(), 1)
                print(f"frame {fr}: importance rays {imp.sum()}, in the room {frac:.2f}")
                assert imp.sum() > 0 and frac > 0.7, frac
            fr += 1
    # static frames: a static set's paired visits agree, so (almost) no importance rays (measured: 16 in total
    # over frames 0-9, from one probe on a wall, vs ~300-550 per frame after the switch)
    assert static_imp < 0.2 * np.mean(after), (static_imp, after)
