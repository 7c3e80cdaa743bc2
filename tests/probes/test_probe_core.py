"""Probe core for any update strategy: ragged ray plans, estimators (BLAS / scatter), temporal
accumulators (hysteresis, moving average, mean), device encodings and texel counts."""
import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.errors import DyngiError
from dyngi.probes import (DiffuseHitShader, HysteresisBlend, MatrixEstimator, CappedMeanBlend, ProbeBlend,
                          ProbeGrid, ProbeQuery, ProbePipeline, ProbeVolume, RayPlan, ScatterEstimator,
                          TrueAverage, UniformSFDirections)
from dyngi.probes.arrays import upload
from dyngi.probes.accumulator import MeanAccumulator
from dyngi.probes.encoding import (IRR_BETA, IRR_GAMMA, SQ_BETA, SQ_GAMMA, ADGIEncoding, Fp32Encoding,
                                   QDDGIEncoding, log_step)
from dyngi.probes.trace import ProbeRayResults
from dyngi.sampling.octahedral import texel_directions
from dyngi.scene import load_scene
from helpers import assert_steady_state_compiles_nothing


def small_volume(counts=(2, 2, 2), Ti=8, Td=16):
    sc = load_scene("furnace")
    return ProbeVolume(ProbeGrid.from_scene(sc, counts), Ti, Td)


def results_for(plan, radiance: np.ndarray, distance: np.ndarray) -> ProbeRayResults:
    """Synthetic traced results: radiance (n, 3), distance (n,) (uploaded copies, see arrays.upload)."""
    rad = np.asarray(radiance, np.float32)
    return ProbeRayResults(mi.Color3f(*[upload(rad[:, c]) for c in range(3)]),
                           upload(np.asarray(distance, np.float32)), plan)


def random_results(plan, rng, back_fraction=0.1):
    n = plan.n_rays
    rad = rng.exponential(0.5, (n, 3))
    dist = rng.uniform(0.05, 3.0, n)
    back = rng.random(n) < back_fraction
    rad[back] = 0.0                         # the shader's convention for back faces
    dist[back] *= -0.2
    dist[rng.random(n) < 0.05] = np.inf     # misses
    return results_for(plan, rad, dist)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def ddgi_reference(dirs, rad, dist, Ti, Td, power, max_distance):
    """Float64 DDGI kernel estimate of one probe's rays for the interior texels: (irr (Ti2, 3), mom (Td2, 2))."""
    tdirs = texel_directions(Ti)[1:-1, 1:-1].reshape(-1, 3)
    wi = np.maximum(dirs @ tdirs.T, 0.0) * (dist >= 0)[:, None]
    irr = (wi.T @ rad) / wi.sum(0)[:, None]
    wd = np.maximum(dirs @ texel_directions(Td)[1:-1, 1:-1].reshape(-1, 3).T, 0.0) ** power
    d = np.minimum(np.abs(dist), max_distance)
    mom = (wd.T @ np.stack([d, d * d], -1)) / wd.sum(0)[:, None]
    return irr, mom


# -- ray plans --------------------------------------------------------------------

def test_shared_plan_is_a_csr_plan():
    plan = UniformSFDirections(32).plan(3, 1, np.array([4, 1, 7], np.uint32))
    assert plan.rays_per_probe == 32 and plan.shared_directions.shape == (32, 3)
    assert np.array_equal(plan.offsets, [0, 32, 64, 96]) and np.array_equal(plan.counts, [32, 32, 32])
    assert np.array_equal(np.asarray(plan.slot), np.repeat([0, 1, 2], 32))
    assert np.array_equal(np.asarray(plan.probe), np.repeat([4, 1, 7], 32))
    assert plan.weight is None and plan.n_rays == 96


def test_ragged_plan_offsets_pdf_and_errors():
    rng = np.random.default_rng(0)
    counts = np.array([3, 0, 5])
    d = unit(rng.normal(size=(8, 3)))
    plan = RayPlan.ragged([2, 5, 6], counts, mi.Vector3f(d.T.astype(np.float32)), pdf=mi.Float(np.full(8, 0.25)))
    assert np.array_equal(plan.offsets, [0, 3, 3, 8]) and plan.rays_per_probe is None
    assert np.array_equal(np.asarray(plan.probe), [2, 2, 2, 6, 6, 6, 6, 6])
    assert np.allclose(np.asarray(plan.weight), 4.0)
    with pytest.raises(DyngiError):
        RayPlan.ragged([1, 2], [1, -1], mi.Vector3f(0, 0, 1))
    with pytest.raises(DyngiError, match="either"):
        RayPlan.ragged([1], [1], mi.Vector3f(0, 0, 1), weight=mi.Float(1.0), pdf=mi.Float(1.0))
    with pytest.raises(DyngiError, match="matrix"):
        HysteresisBlend(estimator="matrix").update(small_volume(), results_for(plan, np.ones((8, 3)), np.ones(8)))
    with pytest.raises(DyngiError, match="estimator"):
        HysteresisBlend(estimator="blas")


def test_planner_receives_previous_results():
    sc = load_scene("cornell-static")
    vol = ProbeVolume(ProbeGrid.from_scene(sc, (3, 3, 3)))
    seen = []

    class Recording(UniformSFDirections):
        def plan(self, frame, seed, probe_ids, previous=None):
            seen.append(previous)
            return super().plan(frame, seed, probe_ids)

    up = ProbePipeline(vol, Recording(16), DiffuseHitShader(), HysteresisBlend(), None, ProbeQuery(vol))
    up.update(sc, 0, 0)
    up.update(sc, 1, 0)
    assert seen[0] is None
    prev = seen[1]
    assert isinstance(prev, ProbeRayResults) and prev is not up.last_results
    assert dr.width(prev.distance) == prev.plan.n_rays == 27 * 16
    assert np.isfinite(np.asarray(prev.radiance[0])).all()


# -- estimators -----------------------------------------------------------------------

@pytest.mark.parametrize("back_fraction", [0.0, 0.2])
def test_scatter_estimator_equals_matrix_on_a_shared_set(back_fraction):
    vol = small_volume()
    rng = np.random.default_rng(1)
    plan = UniformSFDirections(64).plan(2, 0, np.arange(vol.n_probes, dtype=np.uint32))
    res = random_results(plan, rng, back_fraction)
    mat, sca = MatrixEstimator(50.0), ScatterEstimator(50.0)
    for kind in ("irradiance", "distance"):
        a, b = getattr(mat, kind)(vol, res), getattr(sca, kind)(vol, res)
        va, vb = a.means(), b.means()
        ok_b = np.asarray(b.ok)
        ok_a = np.isfinite(va).all(1) & np.tile(np.asarray(a.ok), vol.n_probes)
        assert np.array_equal(ok_a, ok_b)
        assert np.allclose(va[ok_a], vb[ok_b], rtol=2e-5, atol=2e-6), kind
    # and the float64 DDGI definition, per probe (back faces out of the irradiance)
    rad, dist = res.to_numpy()
    dirs = plan.shared_directions
    irr_b = sca.irradiance(vol, res).means().reshape(vol.n_probes, -1, 3)
    mom_b = sca.distance(vol, res).means().reshape(vol.n_probes, -1, 2)
    for p in range(vol.n_probes):
        irr, mom = ddgi_reference(dirs, rad[p].astype(np.float64), dist[p].astype(np.float64), 8, 16, 50.0,
                                  vol.max_distance)
        assert np.allclose(irr_b[p], irr, rtol=1e-5, atol=1e-6)
        assert np.allclose(mom_b[p], mom, rtol=1e-4, atol=1e-6)
    # the whole update: the same atlases either way
    vols = [small_volume(), small_volume()]
    for v, e in zip(vols, ("matrix", "scatter")):
        b = HysteresisBlend(0.9, encoding="fp32", estimator=e)
        for f in range(3):
            b.update(v, random_results(UniformSFDirections(64).plan(f, 0, np.arange(v.n_probes, dtype=np.uint32)),
                                       np.random.default_rng(f), back_fraction))
        assert b.last_estimator == e
    assert np.allclose(vols[0].state.irradiance, vols[1].state.irradiance, rtol=1e-4, atol=1e-6)
    assert np.allclose(vols[0].state.distance, vols[1].state.distance, rtol=1e-4, atol=1e-6)


def test_auto_estimator_is_matrix_for_shared_sets_on_the_cpu_and_scatter_otherwise():
    vol = small_volume()
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    b = HysteresisBlend()
    b.update(vol, random_results(UniformSFDirections(16).plan(0, 0, ids), np.random.default_rng(0)))
    assert b.last_estimator == ("scatter" if mi.variant().startswith("cuda") else "matrix")
    d = unit(np.random.default_rng(1).normal(size=(16 * len(ids), 3))).astype(np.float32)
    plan = RayPlan.ragged(ids, np.full(len(ids), 16), mi.Vector3f(d.T))
    b.update(vol, random_results(plan, np.random.default_rng(2)))
    assert b.last_estimator == "scatter"


def test_exact_mean_when_many_samples_fall_in_one_texel():
    """10^5 binned samples in one texel: their mean exactly (fixed-point sums), not a float atomic's."""
    vol = small_volume(Ti=8, Td=8)
    rng = np.random.default_rng(5)
    n = 100_000
    tdir = texel_directions(8)[3, 4]                       # interior texel (x=4, y=3)
    d = unit(tdir + 1e-3 * rng.normal(size=(n, 3))).astype(np.float32)
    plan = RayPlan.ragged([3], [n], mi.Vector3f(d.T))
    rad = rng.lognormal(0.0, 1.5, (n, 3))
    dist = rng.uniform(0.1, 1.0, n)
    res = results_for(plan, rad, dist)
    est = ScatterEstimator(mode="bin").irradiance(vol, res)
    t = (3 - 1) * 6 + (4 - 1)
    got = est.means()[t]
    want = rad.astype(np.float32).astype(np.float64).mean(0)
    assert np.allclose(got, want, rtol=2e-7, atol=1e-9), (got, want)
    cnt = np.asarray(est.count)
    assert cnt[t] == n and cnt.sum() == n
    # through the plain-mean accumulator into the atlas (and its border copies)
    TrueAverage_like = ProbeBlend(MeanAccumulator(), "fp32", "scatter", scatter_mode="bin")
    TrueAverage_like.update(vol, res)
    assert np.allclose(vol.state.irradiance[3, 3, 4], want, rtol=2e-7)
    assert vol.state.irradiance_count[3, 3, 4] == min(n, Fp32Encoding.count_max)   # capped
    assert vol.state.irradiance_count[2].sum() == 0


def test_scatter_path_reruns_are_bit_identical():
    vol = small_volume(counts=(3, 3, 3))
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    rng = np.random.default_rng(9)
    counts = rng.integers(0, 300, len(ids))
    d = unit(rng.normal(size=(counts.sum(), 3))).astype(np.float32)
    plan = RayPlan.ragged(ids, counts, mi.Vector3f(d.T), weight=mi.Float(rng.uniform(0.5, 2.0, counts.sum())))
    res = random_results(plan, rng, 0.1)
    outs = []
    for _ in range(3):
        for mode in ("kernel", "bin"):
            e = ScatterEstimator(mode=mode)
            outs.append((mode, np.asarray(e.irradiance(vol, res).value).tobytes(),
                         np.asarray(e.distance(vol, res).value).tobytes()))
    for mode in ("kernel", "bin"):
        runs = [o[1:] for o in outs if o[0] == mode]
        assert all(r == runs[0] for r in runs)


def test_ragged_plan_with_varying_counts_blends_correctly():
    """Probes with 0, 1, 7, 64 and 500 rays of a random (non-shared) plan with weights: each probe's
    texels are the float64 DDGI estimate of its own rays; the probe with no ray keeps its texels."""
    vol = small_volume()
    ids = np.array([0, 2, 3, 5, 6], np.uint32)
    counts = np.array([64, 0, 1, 7, 500])
    rng = np.random.default_rng(3)
    n = counts.sum()
    d = unit(rng.normal(size=(n, 3)))
    w = rng.uniform(0.2, 3.0, n)
    plan = RayPlan.ragged(ids, counts, mi.Vector3f(d.T.astype(np.float32)), weight=mi.Float(w.astype(np.float32)))
    res = random_results(plan, rng, 0.1)
    vol.state.irradiance[2] = 0.5           # a probe with history and no rays this frame
    vol.state.updates[2] = 4
    vol.sync(("irradiance",))
    b = HysteresisBlend(0.0, irradiance_gamma=1.0, change_threshold=1e30, brightness_threshold=1e30)
    b.update(vol, res)
    assert b.last_estimator == "scatter"
    rad = np.stack([np.asarray(res.radiance[c], np.float64) for c in range(3)], -1)
    dist = np.asarray(res.distance, np.float64)
    irr_atlas = vol.state.irradiance[:, 1:-1, 1:-1].reshape(vol.n_probes, -1, 3)
    mom_atlas = vol.state.distance[:, 1:-1, 1:-1].reshape(vol.n_probes, -1, 2)
    for i, (p, lo, hi) in enumerate(zip(ids, plan.offsets[:-1], plan.offsets[1:])):
        if hi == lo:
            assert np.all(vol.state.irradiance[p] == 0.5) and vol.state.updates[p] == 4
            continue
        tdirs = texel_directions(8)[1:-1, 1:-1].reshape(-1, 3)
        c = np.maximum(d[lo:hi] @ tdirs.T, 0.0) * w[lo:hi, None] * (dist[lo:hi] >= 0)[:, None]
        got = c.sum(0) > 0
        want = (c.T @ rad[lo:hi]) / np.maximum(c.sum(0), 1e-300)[:, None]
        assert np.allclose(irr_atlas[p][got], want[got], rtol=1e-4, atol=1e-6), counts[i]
        assert np.all(irr_atlas[p][~got] == 0.0)           # no weight: the old (empty) texel stays
        if counts[i] >= 64:
            td = texel_directions(16)[1:-1, 1:-1].reshape(-1, 3)
            wd = np.where(d[lo:hi] @ td.T > 1e-12 ** (1 / 50), np.maximum(d[lo:hi] @ td.T, 0) ** 50, 0) * w[lo:hi, None]
            dd = np.minimum(np.abs(dist[lo:hi]), vol.max_distance)
            ok = wd.sum(0) > 1e-6
            m = (wd.T @ np.stack([dd, dd * dd], -1))[ok] / wd.sum(0)[ok][:, None]
            assert np.allclose(mom_atlas[p][ok], m, rtol=1e-3, atol=1e-5)
        assert vol.state.updates[p] == 1


def test_back_faces_do_not_darken_the_irradiance():
    """Constant radiance 2 on front-face rays, 30% back-face hits: the irradiance stays 2 on both paths
    (before, back-face rays entered the blend as black)."""
    vol = small_volume()
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    plan = UniformSFDirections(128).plan(0, 0, ids)
    rng = np.random.default_rng(2)
    n = plan.n_rays
    back = rng.random(n) < 0.3
    rad = np.where(back[:, None], 0.0, 2.0) * np.ones((n, 3))
    dist = np.where(back, -0.2 * 0.5, 0.5)
    for e in ("matrix", "scatter"):
        v = small_volume()
        HysteresisBlend(estimator=e).update(v, results_for(plan, rad, dist))
        assert np.allclose(v.state.irradiance, 2.0, rtol=1e-4), e
        # the distance moments keep the back-face hits (|d| = 0.1), as DDGI does
        m1 = v.state.distance[..., 0]
        assert m1.min() >= 0.1 - 1e-5 and m1.max() <= 0.5 + 1e-5 and m1.mean() < 0.45


# -- temporal accumulators -------------------------------------------------------------

def _one_texel_plan(vol, values, probe=0):
    """A binned plan putting ``len(values)`` samples of radiance ``values`` into texel (x=3, y=2) of ``probe``."""
    T = vol.irradiance_texels
    tdir = texel_directions(T)[2, 3]
    k = len(values)
    plan = RayPlan.ragged([probe], [k], mi.Vector3f(np.tile(tdir.astype(np.float32), (k, 1)).T))
    return results_for(plan, np.repeat(np.asarray(values, np.float64)[:, None], 3, 1), np.full(k, 0.5))


def test_capped_mean_with_counts_converges_to_the_mean_and_saturates():
    rng = np.random.default_rng(11)
    x = rng.uniform(0.0, 4.0, 200)
    # uncapped (fp32 keeps 16-bit counts): the running mean of all samples, one per frame
    vol = small_volume()
    b = CappedMeanBlend("fp32", scatter_mode="bin")
    for i in range(100):
        b.update(vol, _one_texel_plan(vol, x[i:i + 1]))
    assert vol.state.irradiance_count[0, 2, 3] == 100
    assert vol.state.irradiance[0, 2, 3, 0] == pytest.approx(x[:100].mean(), rel=1e-5)
    # several samples per frame merge like that many sequential updates
    vol2 = small_volume()
    for i in range(0, 100, 10):
        b.update(vol2, _one_texel_plan(vol2, x[i:i + 10]))
    assert vol2.state.irradiance[0, 2, 3, 0] == pytest.approx(x[:100].mean(), rel=1e-5)
    # capped at 8 (n = min(n + 1, cap); old += (x - old) / n: not Algorithm 3, whose weight is 1/(n + 1)),
    # one sample per frame
    vol3 = small_volume()
    b8 = CappedMeanBlend("fp32", max_count=8, scatter_mode="bin")
    want = 0.0
    for i in range(60):
        b8.update(vol3, _one_texel_plan(vol3, x[i:i + 1]))
        want += (x[i] - want) / min(i + 1, 8)
    assert vol3.state.irradiance_count[0, 2, 3] == 8
    assert vol3.state.irradiance[0, 2, 3, 0] == pytest.approx(want, rel=1e-5)
    # the ADGI encoding's 6 count bits cap the count at 63; the stored value is within a step of the mean
    vol4 = small_volume()
    ba = CappedMeanBlend("adgi", scatter_mode="bin")
    for i in range(0, 200, 2):
        ba.update(vol4, _one_texel_plan(vol4, np.full(2, 1.3)))
    assert vol4.state.irradiance_count[0, 2, 3] == 63 and vol4.state.distance_count.max() == 63
    stored = vol4.state.irradiance[0, 2, 3, 0]
    assert abs(stored - 1.3) <= log_step(1.3, 9, IRR_BETA, IRR_GAMMA)
    from dyngi.sampling.octahedral import border_source_index
    c = vol4.state.irradiance_count[0].ravel()
    assert np.array_equal(c, c[border_source_index(8).ravel()])   # border texels copy their source's count
    assert vol4.state.irradiance_count[1].sum() == 0


def test_hysteresis_counts_track_samples_and_reset_for_fresh_probes():
    vol = small_volume()
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    b = HysteresisBlend()
    plan = UniformSFDirections(64).plan(0, 0, ids)
    b.update(vol, random_results(plan, np.random.default_rng(0), 0.0))
    c1 = vol.state.irradiance_count.copy()
    assert c1.min() > 0 and c1.max() <= 64
    b.update(vol, random_results(plan, np.random.default_rng(1), 0.0))
    assert np.array_equal(vol.state.irradiance_count, 2 * c1)
    vol.state.updates[3] = 0                                    # woke up: stale history
    b.update(vol, random_results(plan, np.random.default_rng(2), 0.0))
    assert np.array_equal(vol.state.irradiance_count[3], c1[3])


# -- encodings on the device --------------------------------------------------------------

@pytest.mark.parametrize("enc", [Fp32Encoding(), QDDGIEncoding(), ADGIEncoding()], ids=lambda e: e.name)
def test_device_store_load_round_trip_within_the_step(enc):
    rng = np.random.default_rng(6)
    n = 20000
    rgb = np.concatenate([rng.exponential(0.5, (n, 3)), [[0.0, 1e-6, 9.0]]])
    count = rng.integers(0, 200, len(rgb)).astype(np.uint32)
    stored = enc.store_irradiance(mi.Color3f(rgb.T.astype(np.float32)), mi.UInt32(count))
    back, n_back = enc.load_irradiance(stored)
    back = np.stack([np.asarray(back[c]) for c in range(3)], -1)
    assert np.array_equal(np.asarray(n_back), np.minimum(count, enc.count_max))
    diag = 0.8
    mom = np.stack([rng.uniform(0, 1.5, len(rgb)), np.zeros(len(rgb))], -1)
    mom[:, 1] = mom[:, 0] ** 2 + rng.uniform(0, 0.1, len(rgb))
    smom = enc.store_distance(mi.Vector2f(mom.T.astype(np.float32)), mi.UInt32(count), diag)
    mback, _ = enc.load_distance(smom, diag)
    mback = np.stack([np.asarray(mback[c]) for c in range(2)], -1)
    # load(store(load(store(x)))) == load(store(x)): stored values are fixed points
    again = enc.roundtrip_irradiance(mi.Color3f(back.T), mi.UInt32(count))[0]
    assert np.array_equal(np.stack([np.asarray(again[c]) for c in range(3)], -1), back)
    if enc.name == "fp32":
        assert np.array_equal(back, rgb.astype(np.float32)) and np.array_equal(mback, mom.astype(np.float32))
        return
    bits = enc.IRR_BITS
    for c in range(3):
        step = log_step(rgb[:, c], bits[c], IRR_BETA, IRR_GAMMA)
        err = back[:, c] - rgb[:, c]
        assert np.all(err <= 2e-3 * step + 1e-6) and np.all(-err <= 1.01 * step + 1e-6)   # floor
    vb = enc.VIS_BITS[0]
    f = 1.01 if enc.VIS_FLOOR else 0.51
    assert np.all(np.abs(mback[:, 0] - mom[:, 0])
                  <= f * diag * log_step(mom[:, 0] / diag, vb, IRR_BETA, IRR_GAMMA) + 1e-6)
    assert np.all(np.abs(mback[:, 1] - mom[:, 1])
                  <= f * diag ** 2 * log_step(mom[:, 1] / diag ** 2, vb, SQ_BETA, SQ_GAMMA) + 1e-6)
    # the device words are the host codec's words (float32 vs float64 may pick a neighbouring code rarely)
    word = stored[0] if isinstance(stored, tuple) else stored
    host = enc.encode_irradiance(rgb) if enc.name == "qddgi" else enc.encode_irradiance(rgb, count)
    assert np.mean(np.asarray(word) == host) > 0.99


@pytest.mark.parametrize("start", [0.1, 1.5])
def test_qddgi_minimum_step_rule_reaches_a_constant_input(start):
    """h = 0.94, constant input 0.37 after a start at ``start``: the stored R11G11B10 irradiance and the RG16
    moments end within one step of the input (round-down storage used to stall ~16 steps below it)."""
    vol = small_volume(counts=(2, 2, 2))
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    b = HysteresisBlend(0.94, encoding="qddgi")
    x, dist = 0.37, 0.6
    for f in range(250):
        plan = UniformSFDirections(32).plan(f, 0, ids)
        v = start if f == 0 else x
        b.update(vol, results_for(plan, np.full((plan.n_rays, 3), v), np.full(plan.n_rays, dist)))
    irr = vol.state.irradiance
    for c, bits in enumerate(QDDGIEncoding.IRR_BITS):
        step = log_step(x, bits, IRR_BETA, IRR_GAMMA)
        assert np.all(np.abs(irr[..., c] - x) <= 1.001 * step), (c, irr[..., c].min(), irr[..., c].max())
    diag = vol.grid.cell_diagonal
    m = vol.state.distance
    assert np.all(np.abs(m[..., 0] - dist) <= 1.001 * diag * log_step(dist / diag, 16, IRR_BETA, IRR_GAMMA))
    assert np.all(np.abs(m[..., 1] - dist ** 2)
                  <= 1.001 * diag ** 2 * log_step(dist ** 2 / diag ** 2, 16, SQ_BETA, SQ_GAMMA))


def test_query_reads_the_stored_value():
    """The device atlas the query gathers from holds load(store(x)) of the encoding."""
    vol = small_volume()
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    plan = UniformSFDirections(64).plan(0, 0, ids)
    res = random_results(plan, np.random.default_rng(4), 0.0)
    HysteresisBlend(encoding="adgi").update(vol, res)
    dev = np.asarray(vol.device.irradiance).reshape(-1, 3)
    enc = ADGIEncoding()
    words = enc.encode_irradiance(dev, np.zeros(len(dev), np.uint32))
    assert np.allclose(enc.decode_irradiance(words)[0], dev, rtol=1e-5, atol=1e-7)   # already on the code grid


def test_true_average_matches_per_texel_means():
    from dyngi.probes import LobeDirections
    vol = small_volume(Ti=6, Td=6)
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    k = 16
    lob = LobeDirections(6, k, 1.0)
    plan = lob.plan(0, 0, ids)
    rng = np.random.default_rng(8)
    res = random_results(plan, rng, 0.0)
    TrueAverage().update(vol, res, res, k, k)
    rad, dist = res.to_numpy()
    want = rad.reshape(vol.n_probes, 16, k, 3).mean(2)
    got = vol.state.irradiance[:, 1:-1, 1:-1].reshape(vol.n_probes, 16, 3)
    assert np.allclose(got, want, rtol=1e-5)
    d = np.minimum(np.abs(dist), vol.max_distance).reshape(vol.n_probes, 16, k)
    assert np.allclose(vol.state.distance[:, 1:-1, 1:-1, 0].reshape(vol.n_probes, 16), d.mean(2), rtol=1e-5)


def test_scatter_blend_compiles_no_new_kernels_in_steady_state():
    vol = small_volume()
    ids = np.arange(vol.n_probes, dtype=np.uint32)
    b = CappedMeanBlend("adgi")
    rng = np.random.default_rng(0)

    def frame(f, counts):
        d = unit(rng.normal(size=(counts.sum(), 3))).astype(np.float32)
        plan = RayPlan.ragged(ids, counts, mi.Vector3f(*[upload(d[:, i]) for i in range(3)]))
        b.update(vol, random_results(plan, rng, 0.1))
        dr.eval(vol.device.irradiance)

    assert_steady_state_compiles_nothing(lambda f: frame(f, rng.integers(0 if f else 1, 40, len(ids))),
                                         frames=5, warmup=2)


def test_ddgi_technique_same_probes_with_either_estimator():
    """``ddgi:estimator=scatter`` (the path of the GPU backend) gives the probes of the BLAS path, and
    reruns of it are bit-identical."""
    from dyngi.techniques.base import Frame, create_technique
    sc = load_scene("cornell-static")
    res = (32, 24)
    atlases = []
    for est in ("matrix", "scatter", "scatter"):
        tech = create_technique("ddgi", sc, {"probe_counts": "4", "rays_per_probe": 32, "warmup": 2,
                                             "estimator": est})
        for f in range(3):
            r = tech.step(Frame(f, 0.0, sc.camera(0.0), res, seed=0))
        assert np.isfinite(r.image).all()
        atlases.append((tech.volume.state.irradiance.copy(), tech.volume.state.distance.copy()))
    (ia, da), (ib, db), (ic, dc) = atlases
    assert ia.max() > 0.0
    assert np.allclose(ia, ib, rtol=1e-3, atol=1e-5) and np.allclose(da, db, rtol=1e-3, atol=1e-5)
    assert np.array_equal(ib, ic) and np.array_equal(db, dc)
