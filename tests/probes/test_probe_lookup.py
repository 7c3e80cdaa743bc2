"""Stochastic probe lookups at probe-ray hits and the coherent ray order of the direction set."""
import numpy as np
import pytest

from dyngi.backend import dr, mi
from dyngi.probes import (DiffuseHitShader, HysteresisBlend, ProbeGrid, ProbeQuery, ProbeStates, ProbePipeline,
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
    up = ProbePipeline(vol, UniformSFDirections(64), DiffuseHitShader(), HysteresisBlend(0.5), ProbeStates(), q)
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


# -- fallback when the 8 probes of a cell carry no weight --------------------------------

def _dead_cell_volume(values=None, seed=0):
    """A 4x4x4 unit grid whose centre cell (probes (1..2)^3) is all inactive; the other probes hold
    ``values`` (default: random per probe and texel) as stored E/pi, and distance moments of open space
    (nothing nearer than the clamp): the fallback reads only candidates that the visibility test accepts
    (a wall between), and zero moments would put every point behind a wall."""
    vol = ProbeVolume(ProbeGrid.from_box((0.0, 0.0, 0.0), (3.0, 3.0, 3.0), (4, 4, 4)))
    vol.state.distance[..., 0] = vol.max_distance
    vol.state.distance[..., 1] = vol.max_distance ** 2
    rng = np.random.default_rng(seed)
    if values is None:
        vol.state.irradiance[...] = rng.uniform(0.5, 2.0, vol.state.irradiance.shape).astype(np.float32)
    else:
        vol.state.irradiance[...] = values
    c = vol.grid.probe_coords()
    dead = np.all((c >= 1) & (c <= 2), axis=1)
    vol.state.states[dead] = 0
    vol.sync()
    return vol, dead


def _points_in_centre_cell(n, seed=1):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(1.05, 1.95, (n, 3))
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return pts, nrm, nrm.copy()


@pytest.mark.parametrize("visibility", [True, False])
def test_cell_of_inactive_probes_reads_the_nearest_active_ones(visibility):
    """All 8 probes of the cell inactive: the lookup returns the neighbours' irradiance, not black
    (before the fallback it returned exactly 0 here)."""
    vol, _ = _dead_cell_volume(values=0.75)
    pts, nrm, wo = _points_in_centre_cell(200)
    q = ProbeQuery(vol, normal_bias=0.0, view_bias=0.0, visibility=visibility)
    for sampler in (None, make_sampler(len(pts), 3, 0, 3)):
        E = _lookup(q, pts, nrm, wo, sampler=sampler)[:, 0]
        assert np.allclose(E, 0.75 * np.pi, rtol=1e-5), E.min()
    # the candidates are active probes next to the cell
    table = np.asarray(q.fallback_table()).reshape(-1, 4)
    cell = 1 + 3 * (1 + 3 * 1)
    cand = vol.positions()[table[cell]]
    assert np.all(vol.state.states[table[cell]] == 1)
    assert np.all(np.linalg.norm(cand - 1.5, axis=1) < 1.7)


def test_fallback_is_a_weighted_mean_of_the_candidates_and_only_where_needed():
    """The fallback blends the candidates' values (within their range); cells with a live corner are untouched."""
    vol, dead = _dead_cell_volume(seed=4)
    pts, nrm, wo = _points_in_centre_cell(300)
    q = ProbeQuery(vol, normal_bias=0.0, view_bias=0.0)
    E = _lookup(q, pts, nrm, wo)[:, 0]
    table = np.asarray(q.fallback_table()).reshape(-1, 4)[1 + 3 * (1 + 3 * 1)]
    vals = vol.state.irradiance[table] * np.pi
    assert np.all(E > vals.min(axis=(0, 1, 2)) - 1e-4) and np.all(E < vals.max(axis=(0, 1, 2)) + 1e-4)
    # a neighbouring cell with 4 live corners gives the DDGI blend, identical with and without a dead centre
    rng = np.random.default_rng(2)
    p2 = rng.uniform([0.05, 1.05, 1.05], [0.95, 1.95, 1.95], (300, 3))
    a = _lookup(q, p2, nrm, wo)[:, 0]
    vol.state.states[:] = 1
    vol.sync(("states",))
    b = _lookup(q, p2, nrm, wo)[:, 0]
    # with the centre probes alive the cell's blend changes (4 more corners); all it must not do is go black
    assert np.all(a > 0.1) and np.all(b > 0.1)
    assert q.fallback_table() is q.fallback_table()        # cached until the states change


def test_stochastic_fallback_has_the_filtered_expectation():
    """z-test as above on lanes that take the fallback: one stochastic texel of one candidate probe."""
    vol, _ = _dead_cell_volume(seed=5)
    pts, nrm, wo = _points_in_centre_cell(200, seed=6)
    q = ProbeQuery(vol, normal_bias=0.0, view_bias=0.0)
    K = 512
    exact = _lookup(q, pts, nrm, wo)[:, 0]
    sto = _lookup(q, pts, nrm, wo, K, make_sampler(len(pts) * K, 8, 0, 3))
    mean, sd = sto.mean(1), sto.std(1, ddof=1)
    assert np.all(np.isfinite(sto)) and exact.min() > 0.0
    random = sd > 1e-5 * exact.max()
    assert np.mean(random) > 0.9
    z = (mean[random] - exact[random]) / (sd[random] / np.sqrt(K))
    assert abs(np.sum(z * z) - z.size) < 5.0 * np.sqrt(2.0 * z.size), (np.sum(z * z), z.size)
    assert np.max(np.abs(z)) < 5.5


def test_fallback_follows_state_changes_and_an_empty_volume_reads_zero():
    vol, dead = _dead_cell_volume(values=1.0)
    q = ProbeQuery(vol, normal_bias=0.0, view_bias=0.0)
    pts, nrm, wo = _points_in_centre_cell(50)
    t0 = q.fallback_table()
    vol.state.irradiance[dead] = 3.0
    vol.state.states[:] = 0
    vol.sync()
    assert q.fallback_table() is not t0
    for sampler in (None, make_sampler(len(pts), 3, 0, 3)):
        E = _lookup(q, pts, nrm, wo, sampler=sampler)
        assert np.all(E == 0.0)
    vol.state.states[dead] = 1            # the cell's own probes wake up: the normal blend again
    vol.sync(("states",))
    assert np.allclose(_lookup(q, pts, nrm, wo)[:, 0], 3.0 * np.pi, rtol=1e-5)
