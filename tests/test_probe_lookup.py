"""Stochastic probe lookups at probe-ray hits and the coherent ray order of the direction set."""
import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.probes import (DiffuseHitShader, HysteresisBlend, ProbeGrid, ProbeQuery, ProbeStates, ProbeUpdater,
                          ProbeVolume, UniformSFDirections)
from dyngi.sampling.fibonacci import coherent_order, spherical_fibonacci_np
from dyngi.sampling.rng import make_sampler
from dyngi.scene import load_scene
from dyngi.techniques.base import Frame, create_technique
from dyngi.errors import DyngiError


@pytest.fixture(scope="module")
def cornell_volume():
    """A Cornell-box volume after a few updates, and probe-ray hit points (position, normal, towards probe)."""
    sc = load_scene("cornell-static")
    vol = ProbeVolume(ProbeGrid.from_scene(sc, (5, 5, 5)))
    q = ProbeQuery(vol)
    up = ProbeUpdater(vol, UniformSFDirections(64), DiffuseHitShader(), HysteresisBlend(0.5), ProbeStates(), q)
    for f in range(6):
        up.update(sc, f, 0)
    plan = UniformSFDirections(64).plan(9, 1, vol.active_indices())
    origin = dr.gather(mi.Point3f, vol.device.positions, plan.probe)
    ray = mi.Ray3f(origin, plan.direction)
    si = sc.mi_scene.ray_intersect(ray, mi.RayFlags.All, False)
    front = np.asarray(si.is_valid() & (dr.dot(si.n, ray.d) < 0.0))
    rng = np.random.default_rng(0)
    pick = rng.choice(np.flatnonzero(front), 300, replace=False)
    pts = np.asarray(si.p).T[pick]
    nrm = np.asarray(si.sh_frame.n).T[pick]
    wo = -np.asarray(ray.d).T[pick]
    return vol, q, pts, nrm, wo


def _lookup(q, pts, nrm, wo, reps=1, sampler=None):
    rep = lambda a: mi.Vector3f(np.repeat(a, reps, axis=0).T)   # noqa: E731
    E = q.irradiance(mi.Point3f(rep(pts)), rep(nrm), rep(wo), sampler=sampler)
    return np.asarray(E).T.reshape(len(pts), reps, 3)


def test_stochastic_lookup_has_the_filtered_expectation(cornell_volume):
    """z-test per point and channel: the mean of K stochastic lookups estimates the filtered lookup."""
    vol, q, pts, nrm, wo = cornell_volume
    K = 512
    exact = _lookup(q, pts, nrm, wo)[:, 0]
    sto = _lookup(q, pts, nrm, wo, K, make_sampler(len(pts) * K, 7, 0, 3))
    mean, sd = sto.mean(1), sto.std(1, ddof=1)
    assert np.all(np.isfinite(sto)) and exact.max() > 0.0
    # the samples really vary (one texel of one of up to 8 probes), or the test would prove nothing
    assert np.mean(sd.max(1) > 1e-3 * exact.max()) > 0.5
    tiny = 1e-5 * exact.max()
    random = sd > tiny
    assert np.allclose(mean[~random], exact[~random], rtol=1e-4, atol=tiny)
    z = (mean[random] - exact[random]) / (sd[random] / np.sqrt(K))
    n = z.size
    # chi^2 of all z (Gaussian by the CLT at K = 512), and no single point far off (Sidak-like bound)
    assert abs(np.sum(z * z) - n) < 5.0 * np.sqrt(2.0 * n), (np.sum(z * z), n)
    assert np.max(np.abs(z)) < 5.5


def test_stochastic_lookup_rejects_a_wrong_selection(cornell_volume):
    """Power check of the z-test above: picking the corner uniformly (ignoring the weights) is detected."""
    vol, q, pts, nrm, wo = cornell_volume
    K = 512
    exact = _lookup(q, pts, nrm, wo)[:, 0]
    # a wrong estimator: the unweighted mean of the 8 corners' bilinear irradiance (what uniform selection gives)
    wrong = ProbeQuery(vol, visibility=False, wrap=False)
    biased = _lookup(wrong, pts, nrm, wo, K, make_sampler(len(pts) * K, 7, 0, 3))
    mean, sd = biased.mean(1), biased.std(1, ddof=1)
    random = sd > 1e-5 * exact.max()
    z = (mean[random] - exact[random]) / (sd[random] / np.sqrt(K))
    assert np.sum(z * z) - z.size > 5.0 * np.sqrt(2.0 * z.size)


def test_ddgi_hit_lookups_converge_to_the_same_probes():
    """DDGI with stochastic and with filtered hit lookups: the same converged indirect light.

    Mean indirect image over frames 10-39, for 3 seeds each; the seeds spread
    by ~0.3% (measured), the two modes agreed within 0.2% per seed.
    """
    sc = load_scene("cornell-static")
    means = {}
    for mode in ("stochastic", "filtered"):
        runs = []
        for seed in (3, 5, 7):
            tech = create_technique("ddgi", sc, {"probe_counts": "6", "rays_per_probe": 128, "hit_lookup": mode})
            vals = [tech.step(Frame(f, 0.0, sc.camera(0.0), (48, 27), seed=seed)).indirect.mean()
                    for f in range(40)]
            runs.append(np.mean(vals[10:]))
        means[mode] = np.array(runs)
    a, b = means["stochastic"], means["filtered"]
    assert b.mean() > 0.0
    spread = np.sqrt((a.var(ddof=1) + b.var(ddof=1)) / 3)
    assert abs(a.mean() - b.mean()) < max(4.0 * spread, 0.01 * b.mean()), (a, b)


def test_hit_lookup_parameter_is_validated():
    with pytest.raises(DyngiError, match="stochastic"):
        create_technique("ddgi", load_scene("cornell-static"), {"hit_lookup": "nearest"})
    with pytest.raises(DyngiError, match="filtered"):
        DiffuseHitShader(lookup="bogus")


def test_coherent_order_is_a_permutation_with_close_neighbours():
    d = spherical_fibonacci_np(256)
    perm = coherent_order(d)
    assert np.array_equal(np.sort(perm), np.arange(256))
    step = lambda x: np.mean(np.arccos(np.clip(np.sum(x[1:] * x[:-1], 1), -1, 1)))   # noqa: E731
    # consecutive rays (one SIMD packet) leave the probe in nearby directions, unlike the index order
    assert step(d[perm]) < 0.4 * step(d)
    assert np.array_equal(np.sort(UniformSFDirections(256).base, axis=0), np.sort(d, axis=0))


@pytest.mark.parametrize("stochastic", [False, True])
def test_query_ignores_non_finite_inactive_lanes(stochastic):
    """Misses carry non-finite positions and normals: masked-off lanes must read nothing out of bounds
    and return exactly 0; a non-finite position is treated as inactive even when the mask says active."""
    sc = load_scene("cornell-static")
    vol = ProbeVolume(ProbeGrid.from_scene(sc, (4, 4, 4)))
    vol.state.irradiance[...] = 1.0
    vol.sync(("irradiance",))
    n = 1 << 16
    p = np.full((3, n), np.nan, np.float32)
    p[:, ::3] = np.inf
    p[0, ::5] = -3e38
    nrm = np.full((3, n), np.nan, np.float32)
    nrm[:, ::7] = 3e38
    s = make_sampler(n, 0, 0, 1) if stochastic else None
    E = np.asarray(ProbeQuery(vol).irradiance(mi.Point3f(p), mi.Vector3f(nrm), mi.Vector3f(nrm), sampler=s,
                                              active=mi.Bool(np.arange(n) % 2 == 0)))
    assert np.all(E[:, 1::2] == 0.0)
    assert np.all(np.isfinite(E))


def test_stochastic_lookup_loop_matches_unrolled(cornell_volume):
    """The symbolic corner loop and its unrolled twin draw the same texel from the same random numbers."""
    vol, q, pts, nrm, wo = cornell_volume
    n = len(pts)
    a = _lookup(ProbeQuery(vol, unroll=False), pts, nrm, wo, 4, make_sampler(n * 4, 2, 0, 3))
    b = _lookup(ProbeQuery(vol, unroll=True), pts, nrm, wo, 4, make_sampler(n * 4, 2, 0, 3))
    assert a.max() > 0.0
    assert np.allclose(a, b, rtol=1e-5, atol=1e-7)
