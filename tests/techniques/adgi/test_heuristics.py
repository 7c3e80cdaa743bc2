"""ADGI heuristics (Datta et al. 2022, Sec. 4.1-4.4): pilot rays in the AABBCCDD pattern, f_v / f_r, the
temporal trigger and the 5x5x5 x octant convolution respond to a scripted visibility change and decay."""
import numpy as np
import pytest

from dyngi.backend import mi
from dyngi.errors import DyngiError
from dyngi.probes import ProbeGrid, ProbeVolume
from dyngi.techniques.adgi.heuristics import (OCTANTS, ADGIHeuristics, PilotRays, camera_falloff, frusta,
                                              octant_of_np, static_guide)
from dyngi.probes.trace import vector_to_numpy
from dyngi.scene import load_scene

N = 7
GRID = ProbeGrid((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (N, N, N))
P = GRID.n_probes
CENTRE = int(GRID.probe_index((3, 3, 3)))
THETA = 8.0


def run(heur, state, frame, dist, lum):
    pids = np.arange(P, dtype=np.uint32)
    return heur.update(state, frame, pids, mi.Float(dist.astype(np.float32)), mi.Float(lum.astype(np.float32)))


def table(x):
    return np.asarray(x).reshape(P, OCTANTS)


def test_pilot_rays_one_per_octant_in_pairs(backend):
    pr = PilotRays()
    pids = np.array([0, 5, 9, 20], np.uint32)

    def dirs(frame, ids=pids):
        plan = pr.plan(frame, 3, ids)
        assert plan.rays_per_probe == OCTANTS and plan.n_rays == len(ids) * OCTANTS
        return vector_to_numpy(plan.direction).T.reshape(len(ids), OCTANTS, 3)

    d4, d5, d6 = dirs(4), dirs(5), dirs(6)
    assert np.allclose(np.linalg.norm(d4, axis=-1), 1.0, atol=1e-5)
    assert np.array_equal(octant_of_np(d4), np.tile(np.arange(OCTANTS), (len(pids), 1)))
    assert np.array_equal(d4, d5)                       # A A: identical rays within a pair
    assert np.abs(d6 - d5).max() > 1e-3                 # B: new rays for the next pair
    # keyed on the probe id, not on the lane: another probe set gives the same rays for probe 9
    other = dirs(5, np.array([9, 1], np.uint32))
    assert np.array_equal(other[0], d5[2])


def test_visibility_change_triggers_and_decays(backend):
    heur = ADGIHeuristics(GRID, theta=THETA)
    st = heur.initial_state()
    dist = np.ones((P, OCTANTS))
    lum = np.full((P, OCTANTS), 0.5)
    for f in range(7):
        st = run(heur, st, f, dist.ravel(), lum.ravel())
    assert np.all(np.asarray(st.fdv) == 0) and np.all(np.asarray(st.fdr) == 0)
    s = GRID.cell_diagonal
    assert np.allclose(np.asarray(st.fv), np.exp(-2.0 / s), rtol=1e-5)
    # -- frame 7 (second of a pair): the pilot ray of octant 0 of the centre probe hits something close --
    dist2 = dist.copy()
    dist2[CENTRE, 0] = 0.1
    st = run(heur, st, 7, dist2.ravel(), lum.ravel())
    pulse = np.exp(-0.2 / s) - np.exp(-2.0 / s)
    fv = table(st.fv)
    assert np.isclose(fv[CENTRE, 7], np.exp(-0.2 / s), rtol=1e-5)  # -w of octant 7 is octant 0's ray
    fdv = table(st.fdv)
    coords = GRID.probe_coords()
    near = np.all(np.abs(coords - 3) <= 2, axis=1)
    oct_ok = np.isin(np.arange(OCTANTS), [7, 6, 5, 3])      # 7 and its three edge neighbours
    expect = np.where(near[:, None] & oct_ok[None, :], pulse, 0.0)
    assert np.allclose(fdv, expect, rtol=1e-5, atol=1e-7)
    assert np.all(np.asarray(st.fdr) == 0)
    fd = table(st.fd())
    assert np.all((fd > 0) == (expect > 0))
    # -- the trigger decays linearly over theta frames while nothing changes --
    seen = []
    for f in range(8, 8 + int(THETA) + 2):
        st = run(heur, st, f, dist2.ravel(), lum.ravel())
        seen.append(table(st.fdv)[CENTRE, 7])
    expect_decay = np.maximum(pulse * (1.0 - np.arange(1, len(seen) + 1) / THETA), 0.0)
    assert np.allclose(seen, expect_decay, atol=1e-6), (seen, expect_decay)
    assert np.all(np.asarray(st.fdv) == 0) and np.all(st.fd().numpy() == 0)


def test_change_between_pairs_and_untraced_probes_are_not_gradients(backend):
    heur = ADGIHeuristics(GRID, theta=THETA)
    st = heur.initial_state()
    dist = np.ones((P, OCTANTS))
    lum = np.full((P, OCTANTS), 0.5)
    for f in range(4):
        st = run(heur, st, f, dist.ravel(), lum.ravel())
    dist2 = dist.copy()
    dist2[CENTRE, 2] = 0.2
    st = run(heur, st, 4, dist2.ravel(), lum.ravel())    # first of a pair: other rays, no difference taken
    st = run(heur, st, 5, dist2.ravel(), lum.ravel())    # same rays as frame 4: nothing changed
    assert np.all(np.asarray(st.fdv) == 0)
    # a probe not traced on frame 6 has no gradient on frame 7 even if its value changes
    pids = np.setdiff1d(np.arange(P), [CENTRE]).astype(np.uint32)
    rows = dist2[pids].ravel()
    st = heur.update(st, 6, pids, mi.Float(rows.astype(np.float32)), mi.Float(lum[pids].ravel().astype(np.float32)))
    dist3 = dist2.copy()
    dist3[CENTRE, 2] = 0.05
    st = run(heur, st, 7, dist3.ravel(), lum.ravel())
    assert np.all(np.asarray(st.fdv) == 0)


def test_radiance_change_enters_f_d_with_mu(backend):
    heur = ADGIHeuristics(GRID, theta=THETA, mu=2.0)
    st = heur.initial_state()
    dist = np.full((P, OCTANTS), 0.5)
    lum = np.full((P, OCTANTS), 1.0)
    for f in range(3):
        st = run(heur, st, f, dist.ravel(), lum.ravel())
    lum2 = lum.copy()
    lum2[CENTRE, 4] = 6.0                      # clipped at beta = 5
    st = run(heur, st, 3, dist.ravel(), lum2.ravel())
    fdr = table(st.fdr)
    pulse = (5.0 - 1.0) / 5.0
    assert np.isclose(fdr[CENTRE, 4], pulse, rtol=1e-5) and np.isclose(fdr[CENTRE, 0], pulse, rtol=1e-5)
    assert fdr[CENTRE, 3] == 0.0               # octant 3 differs from 4 in three signs
    fs = table(st.fs)
    assert np.allclose(table(st.fd()), fs * (table(st.fdv) + 2.0 * fdr), rtol=1e-5)


def test_frusta_and_camera_falloff(backend):
    sc = load_scene("cornell-moving-light")
    vol = ProbeVolume(ProbeGrid.from_scene(sc, (6, 6, 6)), 8, 16)
    cam = sc.camera(0.0)
    dist = np.linalg.norm(vol.positions() - np.asarray(cam.origin), axis=1)
    k = float(np.median(dist))
    fc, v_in, v_out = frusta(vol, cam, (64, 48), k=k)
    assert np.allclose(fc, camera_falloff(dist, k))
    assert not v_in.all()                      # the far half is cut by f_c >= 0.75 or by the clip test
    assert v_in.any() and np.all(v_out[v_in]) and v_out.sum() >= v_in.sum()
    assert np.all(fc[v_in] >= 0.75) and np.all(fc[v_out] >= 0.5)
    assert np.allclose(camera_falloff([0.5, 1.0, 2.0], 1.0), [1.0, 1.0, np.exp(-1.0)])
    # a far threshold keeps only the clip test
    _, v_in_far, _ = frusta(vol, cam, (64, 48), k=1e3)
    assert v_in_far.sum() >= v_in.sum()


def test_static_guide(backend):
    fs = mi.Float([0.0, 0.5, 0.5, 1.0])
    g = mi.Float([1.0, 0.25, 2.0, 0.0])
    h = np.asarray(static_guide(fs, g))
    assert np.allclose(h, [0.0, np.exp(0.5) * 0.5, np.e * 0.5, 1.0])


def test_bad_heuristic_parameters_raise():
    with pytest.raises(DyngiError, match="theta"):
        ADGIHeuristics(GRID, theta=0.0)
    with pytest.raises(DyngiError, match="mu"):
        ADGIHeuristics(GRID, mu=-1.0)


def test_camera_threshold_default_varies_fc_over_the_view(backend):
    """Eq. 10's default k (ours): the 0.9 quantile of the camera distances of the probes in view, so that
    f_c falls off over the farthest tenth of every view while V_out keeps the rest (on the Cornell-box analog,
    camera outside the probe volume as in the real cornell-box); without a view the probe box diagonal plus
    the camera's distance to the box (f_c = 1 everywhere); a user k is kept."""
    from dyngi.probes import ProbeGrid
    from dyngi.techniques.adgi.heuristics import ADGIHeuristics, camera_falloff, view_distances
    from dyngi.probes.pipeline import probes_in_frustum
    g = ProbeGrid.from_box((0, 0, 0), (2, 1, 3), (3, 2, 4))
    h = ADGIHeuristics(g)
    diag = np.linalg.norm([2, 1, 3])
    assert np.isclose(h.k_for((1, 0.5, 1)), diag)
    assert np.isclose(h.k_for((1, 0.5, -5)), diag + 5)
    assert np.isclose(h.k_for((5, 4, 3)), diag + np.linalg.norm([3, 3, 0]))
    far = np.linalg.norm(g.positions() - np.array([1, 0.5, -5]), axis=1)
    assert np.all(camera_falloff(far, h.k_for((1, 0.5, -5))) == 1.0)
    assert ADGIHeuristics(g, k=0.5).k_for((1, 0.5, -5), far) == 0.5
    # -- from the view: f_c varies over the probes in view, V_out keeps at least 90% of them --
    sc = load_scene("cornell-static")
    vol = ProbeVolume(ProbeGrid.from_scene(sc, (8, 8, 8)), 8, 16)
    cam, res = sc.camera(0.0), (32, 24)
    hv = ADGIHeuristics(vol.grid)
    view = view_distances(vol, cam, res)
    k = hv.k_for(cam.origin, view)
    fc, v_in, v_out = frusta(vol, cam, res, k)
    seen = probes_in_frustum(vol, cam, res, 1.4)
    assert seen.sum() == len(view) > 100
    assert 0.05 <= np.mean(fc[seen] < 1.0) <= 0.15 and fc[seen].min() < 0.95, (k, fc[seen].min())
    assert v_in.any() and v_out.sum() >= 0.9 * seen.sum()
    assert k < hv.k_for(cam.origin)          # the fallback would give f_c = 1 to every probe
