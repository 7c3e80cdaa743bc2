"""IS-DDGI's device planner (:mod:`dyngi.techniques.isddgi.device_planner`, the default
``impl='device'``): the same rays and state as the host planner where both are deterministic, importance
draws that follow the supplement's allocation pdf (chi^2), the per-set cap, and a steady frame that compiles
nothing and reads back only the two small per-probe buffers (slow)."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.techniques.isddgi.device_planner import DeviceISDDGIPlanner
from dyngi.techniques.isddgi.planner import ISDDGIPlanner
from dyngi.techniques.isddgi.sets import N_SETS, allocation_pdf
from stats import chi2_uniform


def _np(a):
    return np.asarray(a)


def test_device_planner_equals_the_host_planner_without_importance_rays(backend):
    """No importance rays (both planners deterministic): over 14 frames of hits where half the probes change
    every frame, the device plan's rays (directions, weights, shading keys, per-probe counts) are the host
    plan's bit for bit, and after each observe the device state (change f/F, stored samples, references,
    adaptive x_i and hold) equals the host's -- the change measure, peak hold, neighbour share and adaptive
    rule agree, so the uniform count moves (the comparison has something to compare). Both device layouts
    (without draws: from the per-probe offsets; with: per-set counters) are checked."""
    from dyngi.backend import mi
    from dyngi.probes.trace import vector_to_numpy
    P = 16
    args = dict(x_init=16, x_min=8, x_max=32, hold_frames=3, importance_rays=0.0)
    hp, dp = ISDDGIPlanner(P, **args), DeviceISDDGIPlanner(P, **args)
    ids = np.arange(P, dtype=np.uint32)
    rng = np.random.default_rng(5)
    moving = np.arange(P) % 2 == 1
    xs = set()
    for t in range(14):
        a, b = hp.plan(t, 3, ids), dp.plan(t, 3, ids)
        assert np.array_equal(a.offsets, b.offsets), t
        assert np.array_equal(vector_to_numpy(a.direction), vector_to_numpy(b.direction)), t
        assert np.array_equal(_np(a.weight), _np(b.weight)) and np.array_equal(_np(a.shade_key), _np(b.shade_key))
        pid = a.info.ray_slot
        base = ((pid * 131 + a.info.ray_set * 7) % 17) / 8.0 + 0.1
        lum = np.where(moving[pid], rng.random(a.n_rays) * 2.0, base)
        dist = np.where(moving[pid], rng.random(a.n_rays) * 3.0, base)
        hp.observe(a, lum, dist)
        dp.observe(b, mi.Float(lum.astype(np.float32)), mi.Float(dist.astype(np.float32)))
        hs = hp.state
        assert np.array_equal(_np(dp.log2x), hs.log2_x) and np.array_equal(_np(dp.hold), hs.hold), t
        assert np.array_equal(_np(dp.has_sample).reshape(P, N_SETS), hs.has_sample), t
        assert np.array_equal(_np(dp.open_ref).reshape(P, N_SETS), hs.open_ref), t
        assert np.array_equal(_np(dp.ref_key).reshape(P, N_SETS), hs.ref_key), t
        assert np.allclose(_np(dp.sample_lum).reshape(P, N_SETS), hs.sample_lum, rtol=1e-6), t
        assert np.allclose(_np(dp.f).reshape(P, N_SETS), hs.f, rtol=1e-4, atol=1e-6), t
        assert np.allclose(_np(dp.F), hs.F, rtol=1e-4, atol=1e-4), t
        xs |= set(hs.x.tolist())
    assert len(xs) >= 2 and hp.state.F[moving].max() > 0 and hp.state.F[~moving].max() == 0, (xs, hp.state.F)
    # the general path (per-set counters and prefix sums, taken when draws may happen) lays out the same rays
    gen, ref = DeviceISDDGIPlanner(P, **{**args, "importance_rays": 16.0}), ISDDGIPlanner(P, **args)
    a, b = ref.plan(0, 3, ids), gen.plan(0, 3, ids)
    assert gen.any_change and b.info.stats["importance_rays"] == 0
    assert np.array_equal(a.offsets, b.offsets) and np.array_equal(_np(a.shade_key), _np(b.shade_key))
    assert np.array_equal(vector_to_numpy(a.direction), vector_to_numpy(b.direction))


def _device_planner_with_change(P=16, importance_rays=16.0, f=None, variant="multi-rays"):
    rng = np.random.default_rng(3)
    dp = DeviceISDDGIPlanner(P, x_init=8, x_min=8, x_max=8, importance_rays=importance_rays, variant=variant)
    st = dp.host.state
    st.F[:] = rng.random(P) + 0.05
    st.F[3] = 0.0                                       # a probe without change: no importance ray
    st.f[:] = rng.random((P, N_SETS)) if f is None else f
    dp.push(np.zeros(P, np.uint8))
    return dp, st


def test_device_planner_draws_follow_the_allocation_pdf(backend):
    """The device planner's importance rays over 420 frames (~400k draws; the state held fixed) follow
    ``p(i, j) = F_i / sum F * p_f(j | i)`` (chi^2 per (probe, set), per 16-set block and per probe; one
    probe's share 5% too high is rejected); a zero-F probe gets none, and ``importance_rays x`` (probes with
    change) are drawn per frame."""
    P = 16
    dp, st = _device_planner_with_change(P, importance_rays=64.0)
    ids = np.arange(P, dtype=np.uint32)
    counts = np.zeros((P, N_SETS), np.int64)
    dropped = 0
    for t in range(420):
        plan = dp.plan(t, 0, ids)
        counts += plan.info.importance
        dropped += plan.info.dropped
        assert plan.info.stats["importance_rays"] + plan.info.dropped == 64 * (P - 1)
    n = int(counts.sum())
    assert counts[3].sum() == 0 and dropped < 1e-3 * n, (counts[3].sum(), dropped)
    pdf = allocation_pdf(st.F, st.f, 0.1)
    for c, e in ((counts, pdf), (counts.reshape(P, 16, 16).sum(2), pdf.reshape(P, 16, 16).sum(2)),
                 (counts.sum(1), pdf.sum(1))):
        ok, p = chi2_uniform(c, e * n)
        assert ok, p
    bad = pdf.sum(1)
    bad[0] *= 1.05
    assert not chi2_uniform(counts.sum(1), bad / bad.sum() * n)[0]     # the test has power


@pytest.mark.parametrize("variant, limit", [("multi-rays", 4), ("one-ray", 1)])
def test_device_planner_caps_each_set(backend, variant, limit):
    """All of a probe's change on one set (f = 0 elsewhere, eps = 0.1): 16 x 15 draws pile onto few sets; the
    atomic per-set counters keep at most the limit per set (uniform ray included), the piled set reaches
    it in most probes, and the rest is reported dropped."""
    P = 16
    f = np.zeros((P, N_SETS), np.float32)
    f[:, 37] = 1.0
    dp, _ = _device_planner_with_change(P, f=f, variant=variant)
    plan = dp.plan(5, 1, np.arange(P, dtype=np.uint32))
    c = plan.info.counts
    assert c.max() == limit and (c[:, 37] == limit).sum() >= 12 and c[3, 37] <= 1, c[:, 37]
    assert plan.info.dropped > 0
    assert plan.info.stats["importance_rays"] + plan.info.dropped == 16 * (P - 1)
    assert plan.n_rays == c.sum() == 8 * P + plan.info.stats["importance_rays"]


@pytest.mark.slow
def test_steady_isddgi_frame_compiles_nothing_and_reads_back_only_per_probe_counts(backend):
    """cornell-moving-box while the box moves (importance rays drawn), 4^3 probes, two passes over the same
    15 frames: in the second pass a steady probe update (plan, trace, blend, states; re-test frames excluded)
    launches only kernels launched before (the first pass compiles the frames without change -- no draw
    kernels -- and, once, those with change), and every update reads back two buffers of at most ``S + 5``
    integers (``S`` traced probes: the plan's per-probe counts, the new ON flags) and nothing per ray; the host
    impl reads every ray back (the count has power)."""
    import drjit as dr
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    from dyngi.techniques.base import StageTimer
    from tests.helpers import count_host_reads, jit_kernel_hashes
    sc = load_scene("cornell-moving-box")
    reads = {}
    for impl in ("device", "host"):
        tech = create_technique(f"isddgi:probe_counts=4:warmup=1:impl={impl}", sc)
        seen, log, imp = set(), [], 0
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            for i in range(1, 32):          # two passes over frames 11-25 (the box moves back between them)
                sc.at(sc.frame_time(10 + (i - 1) % 16 + 1))
                if not tech.pipeline.warmed:      # the pipeline's warm-up with the technique's update step
                    tech.pipeline.begin_frame(sc, Frame(0, sc.frame_time(10), sc.camera(0.0), (8, 6), seed=0),
                                              StageTimer(), update=tech.update)
                if i % tech.params["reclassify_interval"] == 0:
                    continue
                dr.kernel_history()     # clears
                log.clear()
                with count_host_reads(log):
                    info = tech.update(i, 0, StageTimer())
                hashes = jit_kernel_hashes()
                if impl == "device" and i >= 17:
                    assert hashes and hashes <= seen, f"frame {i} compiled {len(hashes - seen)} new kernels"
                seen |= hashes
                imp += info["importance_rays"]
                reads.setdefault(impl, []).append((list(log), info["probes_traced"], tech.last_plan.n_rays))
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, False)
        if impl == "device":
            assert imp > 0, "the box moved: some importance rays expected"
    for log, S, R in reads["device"]:
        assert len(log) <= 2 and max(log, default=0) <= S + 5 < R, (log, S, R)
    assert any(max(log, default=0) >= R for log, S, R in reads["host"]), reads["host"]
