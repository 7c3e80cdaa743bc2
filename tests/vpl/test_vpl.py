"""VPL machinery (dyngi.vpl): kNN density (Eq. 7/8), the 95% rule (Eq. 9), weighted resampling,
mailbox visibility (Sec. 3.2.2), per-VPL-seeded radiosity (Sec. 3.2.3), clamped VPL shading."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dyngi.vpl.density import knn_density, knn_k
from dyngi.vpl.smc import clamp_size, grow_invalid, m_min, resample_without_replacement


def test_knn_k_is_eq8():
    assert knn_k(2048) == 1 and knn_k(512) == 1          # the paper: 1 for both budgets
    assert knn_k(4096) == 2 and knn_k(32768) == 5 and knn_k(0) == 1


@pytest.mark.parametrize("k", [1, 5])
def test_knn_density_of_uniform_points_on_a_plane(k):
    """Uniform points on a tilted 2x3 rectangle in 3D: p = 1/6 per unit area. E[1/p_hat] = 1/p exactly
    for Poisson points (E[pi r_k^2] = k / lambda), so the mean of 1/p_hat over interior points must be
    within 4% (measured ~1%); a missing pi or k is off by 3x or more."""
    rng = np.random.default_rng(1)
    n = 20000
    uv = rng.random((n, 2)) * [2.0, 3.0]
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.array([0.0, 0.6, 0.8])
    pts = uv[:, :1] * e1 + uv[:, 1:] * e2 + [0.3, -1.0, 2.0]
    d = knn_density(pts, k=k)
    inner = (uv[:, 0] > 0.2) & (uv[:, 0] < 1.8) & (uv[:, 1] > 0.2) & (uv[:, 1] < 2.8)
    inv = np.mean(1.0 / d[inner])
    assert abs(inv / 6.0 - 1.0) < 0.04, inv
    # against another set (candidates vs current VPLs, k = 1), n_total scales it
    q = pts[:100] + 1e-3
    dq = knn_density(pts, q, k=1, n_total=2 * n)
    assert np.all(dq > 0) and np.all(np.isfinite(dq))


def test_knn_density_needs_k_neighbours():
    assert np.all(knn_density(np.zeros((1, 3)), k=1) == 0.0)


def test_m_min_95_rule():
    cur = np.arange(100.0)                          # 95% quantile: 94.05
    cand = np.array([95.0, 96.0, 10.0, 200.0, 94.0])
    assert m_min(cur, cand, 16) == 3
    assert m_min(cur, cand, 2) == 2                 # clamped by M_max (Eq. 9)
    assert m_min(cur, np.array([1.0, 2.0]), 16) == 0
    assert m_min(np.full(50, 5.0), np.full(20, 5.0), 16) == 0      # equal intensities: nothing stronger
    assert m_min(np.zeros(0), np.ones(40), 16) == 16


def test_grow_invalid_and_clamp_size():
    used = np.array([True, True, True, True, False])
    inten = np.array([5.0, 1.0, 3.0, 2.0, 0.0])
    inv = np.array([True, False, False, False, False])
    grown = grow_invalid(inv, used, inten, 3)
    assert grown.tolist() == [True, True, False, True, False]      # the two lowest valid ones join
    assert clamp_size(grown, inten, 2).tolist() == [1, 3]          # at most M_max, lowest first
    assert grow_invalid(inv, used, inten, 1).tolist() == inv.tolist()


def test_resample_without_replacement_is_proportional():
    """No duplicates; the first pick has probability w_i / sum(w) (z-test on counts, 4 sigma)."""
    w = np.array([1.0, 2.0, 3.0, 0.0, 4.0])
    idx = resample_without_replacement(w, 4, np.random.default_rng(0))
    assert len(set(idx.tolist())) == 4 and 3 not in idx
    trials = 20000
    rng = np.random.default_rng(7)
    first = np.array([resample_without_replacement(w, 2, rng)[0] for _ in range(trials)])
    counts = np.bincount(first, minlength=5)
    p = w / w.sum()
    z = (counts - trials * p) / np.sqrt(trials * p * (1 - p) + 1e-12)
    assert counts[3] == 0 and np.all(np.abs(z[p > 0]) < 4.0), (counts, z)


# -- scenes --------------------------------------------------------------------------------------

def _plane_point_light(intensity=2.0, height=1.0, albedo=0.5):
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.camera import Camera
    from dyngi.scene.geometry import diffuse, quad

    b = SceneBuilder("vpl-plane")
    b.mesh("floor", quad((0, 0, 0), (0, 0, 4), (4, 0, 0)), diffuse((albedo, albedo, albedo)))
    b.add("lamp", {"type": "point", "position": [0.0, height, 0.0],
                   "intensity": {"type": "rgb", "value": [intensity] * 3}})
    return b.build(Camera((0, 2, 3), (0, 0, 0), (0, 1, 0), 50.0), "plane", duration=1.0)


def _two_rooms():
    """Two closed rooms side by side (x < 0: A, x > 0: B) sharing the wall x = 0; camera in room A."""
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.camera import Camera
    from dyngi.scene.geometry import box, diffuse

    b = SceneBuilder("vpl-two-rooms")
    b.mesh("roomA", box((-2, 0, -1), (0, 2, 1), inward=True), diffuse((0.5, 0.5, 0.5)))
    b.mesh("roomB", box((0.001, 0, -1), (2, 2, 1), inward=True), diffuse((0.5, 0.5, 0.5)))
    b.add("lamp", {"type": "point", "position": [1.0, 1.5, 0.0],
                   "intensity": {"type": "rgb", "value": [3.0] * 3}})
    return b.build(Camera((-1.8, 1.0, 0.0), (0.0, 0.8, 0.0), (0, 1, 0), 70.0), "two rooms", duration=1.0)


def test_radiosity_matches_a_point_light_analytically(backend):
    """Direct light only (max_depth 2 from y) on a plane under a point light: L = rho/pi I cos / d^2, exact
    (NEE of a point light is deterministic); bit-identical per seed whatever the lane order."""
    from dyngi.vpl.radiosity import estimate_radiosity

    sc = _plane_point_light(intensity=2.0, height=1.0, albedo=0.5)
    sc.at(0.0)
    pos = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.3], [-1.0, 0.0, 1.2]], np.float32)
    nrm = np.tile(np.array([[0.0, 1.0, 0.0]], np.float32), (3, 1))
    seeds = np.array([11, 12, 13], np.uint64)
    L, rays = estimate_radiosity(sc.mi_scene, pos, nrm, seeds, 4, 2)
    d2 = (pos ** 2).sum(1) + 1.0
    want = 0.5 / math.pi * 2.0 * (1.0 / np.sqrt(d2)) / d2
    assert np.allclose(L[:, 0], want, rtol=1e-3), (L[:, 0], want)
    assert rays > 0
    L2, _ = estimate_radiosity(sc.mi_scene, pos[::-1], nrm, seeds[::-1], 4, 2)
    assert np.array_equal(L2[::-1], L)
    L3, _ = estimate_radiosity(sc.mi_scene, pos, nrm, seeds, 4, 1)   # no bounce at all: nothing
    assert np.all(L3 == 0)


def test_shading_single_vpl_geometry_term_and_clamp(backend):
    """One VPL straight above a receiver: E = flux * G with G = cos cos / d^2, clamped at G_max."""
    from dyngi.backend import mi
    from dyngi.vpl.points import to_point, to_vector, to_numpy3
    from dyngi.vpl.shading import VPLShader

    sc = _plane_point_light()
    sc.at(0.0)
    cam = sc.camera(0.0)
    p = to_point([[0.0, 0.0, 0.0]] * 2)
    n = to_vector([[0.0, 1.0, 0.0]] * 2)
    for h, gmax, want in ((1.0, 1e9, 1.0), (0.5, 1e9, 4.0), (0.1, 10.0, 10.0)):
        pos = np.array([[0.0, h, 0.0]], np.float32)
        nrm = np.array([[0.0, -1.0, 0.0]], np.float32)
        flux = np.array([[0.3, 0.2, 0.1]], np.float32)
        sh = VPLShader(sc, (2, 1), cam, pos, nrm, flux, "exhaustive", gmax)
        E = to_numpy3(sh.irradiance(p, n, None, mi.Bool(True)))
        assert np.allclose(E[0], flux[0] * want, rtol=1e-4), (h, E[0])
    # a VPL facing away (or below the receiver's horizon) adds nothing
    sh = VPLShader(sc, (2, 1), cam, np.array([[0, 1.0, 0]], np.float32), np.array([[0, 1.0, 0]], np.float32),
                   np.ones((1, 3), np.float32), "exhaustive", 1e9)
    assert np.all(to_numpy3(sh.irradiance(p, n, None, mi.Bool(True))) == 0)


def test_mailbox_invalidates_a_vpl_in_a_room_behind_a_wall(backend):
    """Sec. 3.2.2: a VPL in room B (mailbox in B) cannot be verified from room A's camera: invalid, also
    after the random validations; a VPL in room A with its mailbox in view stays valid."""
    from dyngi.techniques import Frame, create_technique
    from dyngi.vpl.points import raw_candidates

    sc = _two_rooms()
    sc.at(0.0)
    tech = create_technique("smcir", sc, {"vpls": 16, "warmup": 0, "impl": "host"})
    st = tech.store
    #                 VPL position           VPL normal     mailbox              mailbox normal
    rows = [((1.0, 2.0 - 1e-3, 0.5), (0, -1, 0), (1.5, 0.0, 0.0), (0, 1, 0)),       # room B ceiling
            ((-1.0, 2.0 - 1e-3, 0.3), (0, -1, 0), (-0.5, 0.0, 0.2), (0, 1, 0))]     # room A ceiling
    for i, (y, ny, m, nm) in enumerate(rows):
        st.put(np.array([i]), pos=np.array([y]), nrm=np.array([ny]), mailbox=np.array([m]),
               mailbox_n=np.array([nm]), radiosity=np.ones((1, 3)), seed=np.array([i], np.uint64))
    frame = Frame(0, 0.0, sc.camera(0.0), (32, 24), seed=0)
    from dyngi.techniques.base import StageTimer
    _, pts, _ = raw_candidates(sc, frame.camera, frame.res, 2048, 0, 0)
    assert len(pts["x"]) > 1000 and np.all(pts["x"][:, 0] <= 1e-5)    # the camera sees room A only
    invalid = tech._invalid(frame, 0, pts, StageTimer())
    assert invalid[0] and not invalid[1]
    # a room-B VPL whose mailbox is stale (in room A, but it cannot see it) is not re-validated either
    st.mailbox[0] = (-0.5, 0.0, 0.0)
    assert tech._invalid(frame, 1, pts, StageTimer())[0]


def test_untextured_mode_replaces_textures_by_their_mean(backend):
    """Sec. 5: untextured scenes with average albedos: a bitmap texture becomes its mean colour."""
    from dyngi.backend import mi
    from dyngi.scene.untextured import make_untextured

    tex = np.random.default_rng(3).random((4, 4, 3)).astype(np.float32)
    s = mi.load_dict({"type": "scene", "r": {"type": "rectangle", "bsdf": {
        "type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(tex), "raw": True}}}})
    assert make_untextured(s) == 1
    data = np.asarray(mi.traverse(s)["r.bsdf.reflectance.data"])
    assert np.allclose(data, tex.reshape(-1, 3).mean(0), atol=1e-6)
    assert make_untextured(mi.load_dict({"type": "scene", "r": {"type": "rectangle"}})) == 0


def test_device_selection_steps_match_the_host_ones(backend):
    """The device twins (:mod:`dyngi.vpl.smc_device`) of the host selection steps: the same draw without
    replacement for the same uniforms (Efraimidis-Spirakis keys; zero weights last, infinite first),
    Eq. 9's quantile as ``numpy.quantile``, and the lowest-intensity ranks of lines 10-13."""
    from dyngi.backend import mi
    from dyngi.vpl.smc_device import quantile_device, ranks, sample_without_replacement_device

    class _U:                          # a Generator stand-in that hands out fixed uniforms
        def __init__(self, u):
            self.u = u

        def random(self, n):
            return self.u[:n]

    rng = np.random.default_rng(11)
    for trial in range(3):
        w = rng.pareto(1.5, 64)
        w[rng.random(64) < 0.25] = 0.0
        w[5] = np.inf if trial == 1 else w[5]
        u = rng.random(64).astype(np.float32).astype(np.float64)
        host = resample_without_replacement(w, 20, _U(u))
        dev, ok = sample_without_replacement_device(mi.Float(w.astype(np.float32)), mi.Float(u.astype(np.float32)), 20)
        assert np.array_equal(np.asarray(dev), host), (np.asarray(dev), host)
        assert np.array_equal(np.asarray(ok), w[host] > 0)
        mask = rng.random(64) < 0.7
        q = float(np.asarray(quantile_device(mi.Float(u.astype(np.float32)),
                                             mi.Bool(mask), 0.95))[0])
        assert q == pytest.approx(np.quantile(u[mask], 0.95), rel=1e-5)
    inten = np.array([5.0, 1.0, 3.0, 2.0, 0.0, 1.0], np.float32)
    r = np.asarray(ranks(mi.Float(inten)))
    assert r.tolist() == [5, 1, 4, 3, 0, 2]                          # stable: equal values keep their order
    assert float(np.asarray(quantile_device(mi.Float(inten), mi.Bool(np.zeros(6, bool)), 0.95))[0]) == 0.0
