"""ADGI's moving average equals Algorithm 3 (Datta et al. 2022) on scripted sequences, also with many
same-frame hits (the batch rule), and merges through the probe core's accumulator interface."""
import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.errors import DyngiError
from dyngi.probes import ProbeGrid, ProbeVolume, RayPlan, ScatterEstimator
from dyngi.probes.arrays import upload
from dyngi.probes.accumulator import merge_into_volume
from dyngi.probes.encoding import Fp32Encoding
from dyngi.probes.trace import ProbeRayResults
from dyngi.sampling.octahedral import texel_directions
from dyngi.techniques.adgi.moving_average import (N_MAX_DYNAMIC, N_MAX_STATIC, Algorithm3Accumulator,
                                                  batch_update, moving_average_update)


def algorithm3(samples, n_max, o=0.0, n=0):
    """Sequential Algorithm 3, literally (scalar test reference)."""
    for v in samples:
        V = v / (n + 1) + n * o / (n + 1)
        N = min(n + 1, n_max)
        o, n = V, N
    return o, n


def test_algorithm3_is_exact_mean_then_ema():
    rng = np.random.default_rng(0)
    for n_max in (N_MAX_STATIC, N_MAX_DYNAMIC):
        s = rng.uniform(0, 4, 300)
        k = n_max + 1
        V, N = algorithm3(s[:k], n_max)
        assert np.isclose(V, s[:k].mean()) and N == n_max
        # afterwards: EMA with new-sample weight 1 / (N_max + 1) (Table 3: 0.98 / 0.91)
        V2, _ = algorithm3(s[k:k + 1], n_max, V, N)
        assert np.isclose(V2, V + (s[k] - V) / (n_max + 1))
    assert round(N_MAX_STATIC / (N_MAX_STATIC + 1), 2) == 0.98 and round(N_MAX_DYNAMIC / 11, 2) == 0.91


def test_drjit_update_matches_sequential_reference(backend):
    rng = np.random.default_rng(1)
    lanes, steps, n_max = 16, 90, 10
    seq = rng.exponential(1.0, (steps, lanes)).astype(np.float32)
    o, n = dr.zeros(mi.Float, lanes), dr.zeros(mi.UInt32, lanes)
    for t in range(steps):
        o, n = moving_average_update(o, n, mi.Float(seq[t]), n_max)
    ref = [algorithm3(seq[:, i].astype(np.float64), n_max) for i in range(lanes)]
    assert np.allclose(np.asarray(o), [r[0] for r in ref], rtol=2e-5)
    assert np.array_equal(np.asarray(n), [r[1] for r in ref])


@pytest.mark.parametrize("n0,m", [(0, 1), (0, 64), (5, 40), (30, 34), (63, 1), (10, 1)])
def test_batch_equals_sequential_while_count_fits(backend, n0, m):
    """Many same-frame hits on one texel: while n + m <= N_max + 1 the batch rule is the exact running mean
    (n o + sum v) / (n + m) and equals m sequential updates whatever the samples."""
    rng = np.random.default_rng(n0 * 100 + m)
    n_max = N_MAX_STATIC
    o0 = 0.7
    v = rng.uniform(0, 3, m)
    V, N = batch_update(mi.Float(o0), mi.UInt32(n0), mi.Float(v.sum()), mi.UInt32(m), n_max)
    Vs, Ns = algorithm3(v, n_max, o0, n0)
    assert int(N[0]) == Ns == min(n0 + m, n_max)
    if n0 + m <= n_max + 1:
        assert np.isclose(V[0], (n0 * o0 + v.sum()) / (n0 + m), rtol=1e-6)
        assert np.isclose(V[0], Vs, rtol=1e-5)


@pytest.mark.parametrize("n_max", [N_MAX_STATIC, N_MAX_DYNAMIC])
def test_batch_equals_sequential_by_the_mean_once_saturated(backend, n_max):
    """Past saturation the batch equals m sequential Algorithm-3 updates by samples equal to their mean,
    also for a stored count above this N_max (a static 63 met by a dynamic update, N_max = 10): e.g.
    n = 63, m = 64 samples of 1 over a texel of 0 gives 1 - (63/64)^64 (the old running-mean rule: 64/127)."""
    n0s = np.array([0, 3, 9, 10, 11, 40, 62, 63], np.uint32)
    ms = np.array([1, 2, 7, 64, 130], np.uint32)
    n0, m = (x.ravel() for x in np.meshgrid(n0s, ms, indexing="ij"))
    rng = np.random.default_rng(n_max)
    o = rng.uniform(0, 2, n0.size)
    vbar = rng.uniform(0, 2, n0.size)
    V, N = batch_update(mi.Float(o), mi.UInt32(n0), mi.Float(vbar * m), mi.UInt32(m), n_max)
    ref = [algorithm3(np.full(int(mm), vb), n_max, oo, int(nn)) for oo, nn, mm, vb in zip(o, n0, m, vbar)]
    assert np.allclose(np.asarray(V), [r[0] for r in ref], rtol=2e-5, atol=1e-6)
    assert np.array_equal(np.asarray(N), [r[1] for r in ref])
    V1, _ = batch_update(mi.Float(0.0), mi.UInt32(63), mi.Float(64.0), mi.UInt32(64), N_MAX_STATIC)
    assert np.isclose(V1[0], 1 - (63 / 64) ** 64, rtol=1e-5)
    # m = 0 keeps the texel
    V0, N0 = batch_update(mi.Float(0.3), mi.UInt32(7), mi.Float(0.0), mi.UInt32(0), 63)
    assert V0[0] == pytest.approx(0.3) and int(N0[0]) == 7


def test_accumulator_interface_and_fresh_probes(backend):
    acc = Algorithm3Accumulator(N_MAX_DYNAMIC)
    old = mi.Color3f(1.0, 2.0, 3.0)
    new = mi.Color3f(3.0, 0.0, 1.0)
    val, cnt = acc.irradiance(old, new, mi.UInt32([4, 4, 9]), mi.UInt32([2, 2, 5]), mi.Bool([False, True, False]),
                              63)
    # lane 0: (4*old + 2*new)/6; lane 1 fresh: new; lane 2: 9 -> 10 keeps 9/10, then 4 updates at the cap
    # N_max = 10 keep 10/11 each (Algorithm 3 by equal samples), count capped at 10
    r = 0.9 * (10 / 11) ** 4
    assert np.allclose(np.asarray(val.x), [(4 + 6) / 6, 3.0, r * 1.0 + (1 - r) * 3.0])
    assert np.array_equal(np.asarray(cnt), [6, 2, 10])
    with pytest.raises(DyngiError, match="N_max"):
        Algorithm3Accumulator(0)


def test_merge_into_volume_applies_the_batch_rule(backend):
    """Binned per-sample updates through the probe core (scatter estimator 'bin', fp32 encoding): each
    texel becomes (n o + sum v) / (n + m) over two frames with several hits per texel."""
    grid = ProbeGrid((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (2, 2, 2))
    vol = ProbeVolume(grid, 8, 16)
    enc = Fp32Encoding()
    acc = Algorithm3Accumulator(N_MAX_STATIC)
    est = ScatterEstimator(mode="bin")
    T = 8
    tdirs = texel_directions(T)[1:-1, 1:-1].reshape(-1, 3)      # 36 interior texel centres
    rng = np.random.default_rng(3)
    pids = np.array([0, 5], np.uint32)
    ref_sum = np.zeros((2, 36))
    ref_n = np.zeros((2, 36))
    ref_v = np.zeros((2, 36))
    for frame in range(2):
        texel = rng.integers(0, 12, size=(2, 30))               # texels 0..11 get 0..many hits
        rad = rng.uniform(0.1, 2.0, size=(2, 30)).astype(np.float32)
        dirs = tdirs[texel].reshape(-1, 3).astype(np.float32)
        plan = RayPlan.ragged(pids, [30, 30], mi.Vector3f(*[upload(dirs[:, c]) for c in range(3)]))
        L = upload(rad.ravel())
        res = ProbeRayResults(mi.Color3f(L, L, L), upload(np.ones(60, np.float32)), plan)
        merge_into_volume(vol, est.irradiance(vol, res), None, acc, enc, pids, plan.counts)
        for p in range(2):
            s = np.bincount(texel[p], weights=rad[p].astype(np.float64), minlength=36)
            m = np.bincount(texel[p], minlength=36)
            hit = m > 0
            ref_v[p, hit] = (ref_n[p, hit] * ref_v[p, hit] + s[hit]) / (ref_n[p, hit] + m[hit])
            ref_n[p] = np.minimum(ref_n[p] + m, N_MAX_STATIC)
    irr = vol.state.irradiance.reshape(vol.n_probes, T, T, 3)
    got = irr[pids][:, 1:-1, 1:-1, 0].reshape(2, 36)
    assert np.allclose(got, ref_v, rtol=1e-5, atol=1e-6)
    cnt = vol.state.irradiance_count.reshape(vol.n_probes, T, T)[pids][:, 1:-1, 1:-1].reshape(2, 36)
    assert np.array_equal(cnt, ref_n)
