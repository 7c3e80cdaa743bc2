"""Visibility Light Cache: pmfs, sampling frequencies, dedup/buckets, occlusion.

Exact identities: the exploration alias table reproduces its pmf (chi^2); every selector's pmf sums
to 1 over the lights (the VLC: minus the mass of buckets whose lights all have zero importance at the
point, which yield no light, computed independently here); ``sample`` frequencies match ``pmf``
(chi^2, VLC + exploration combined as Algorithm 1 does it); a VLC draw is the two-pass inverse CDF over
its bucket's importances (buckets filled to the capacity: the weights the first traversal keeps); the construction keeps every visible light
of a leaf and its neighbours exactly once, in bucket ``id mod B``, within capacity, with the minimal
power-of-two B (hysteresis included); a light behind a wall never enters a VLC in a closed room.
"""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.backend import dr, mi
from stats import chi2_uniform


# -- scenes ---------------------------------------------------------------------------------------

def many_lights_scene(k: int = 10, outside: bool = False):
    """A closed 10 x 4 x 10 m room with a k x k grid of ceiling quads (2 k^2 lights); with ``outside`` one
    more light above the (closed) ceiling, facing up, that no point in the room can see."""
    from dyngi.scene.builder import SceneBuilder
    from dyngi.scene.camera import Camera
    from dyngi.scene.geometry import box, diffuse, merge, quad

    b = SceneBuilder(f"vlc-test-room-{k}-{outside}")
    b.mesh("room", box((0, 0, 0), (10, 4, 10), inward=True), diffuse((0.6, 0.6, 0.6)))
    b.mesh("block", box((3, 0, 3), (5, 2.5, 6)), diffuse((0.5, 0.4, 0.4)))
    s = 10.0 / k
    quads = [quad(((i + 0.5) * s, 3.99, (j + 0.5) * s), (0.1 * s, 0, 0), (0, 0, 0.1 * s)) for i in range(k)
             for j in range(k)]
    b.mesh("lights", merge(quads), diffuse((0, 0, 0)), (4.0, 4.0, 4.0))
    if outside:   # facing up (normal +y) above the ceiling: outside the closed room
        b.mesh("outside", quad((5.0, 4.5, 5.0), (0, 0, 0.5), (0.5, 0, 0)), diffuse((0, 0, 0)), (50.0, 50.0, 50.0))
    return b.build(Camera((1.0, 1.6, 1.0), (6.0, 1.0, 7.0), (0, 1, 0), 70.0), "vlc test room", duration=1.0)


def _run(tech, sc, frames, res=(32, 24)):
    from dyngi.techniques import Frame
    r = None
    for i in range(frames):
        sc.at(0.0)
        r = tech.step(Frame(i, 0.0, sc.camera(0.0), res, seed=3))
    return r


def _ctx(tech, index=99):
    from dyngi.lights.base import FrameCtx
    return FrameCtx(tech.scene.mi_scene, tech.tris, index, 0.0, tech.octree, tech.bounds,
                    np.asarray(tech.scene.camera(0.0).origin, np.float64))


def _points(n, rng, lo=(0.2, 0.05, 0.2), hi=(9.8, 3.8, 9.8)):
    p = rng.uniform(lo, hi, size=(n, 3))
    nrm = rng.normal(size=(n, 3))
    nrm[:, 1] = np.abs(nrm[:, 1]) + 0.3      # mostly facing up, towards the ceiling lights
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return p, nrm


def _arr(a, cls):
    a = np.asarray(a, np.float32)
    return cls(a[:, 0], a[:, 1], a[:, 2])


# -- alias table -----------------------------------------------------------------------------------

def test_alias_table_reproduces_its_pmf(backend):
    from dyngi.lights.vlc import AliasTable
    rng = np.random.default_rng(1)
    pmf = rng.gamma(0.5, size=37)
    pmf /= pmf.sum()
    t = AliasTable(pmf)
    n = 400_000
    k = np.asarray(t.sample(mi.Float(rng.random(n).astype(np.float32))))
    ok, p = chi2_uniform(np.bincount(k, minlength=37), n * pmf)
    assert ok, p
    assert np.allclose(np.asarray(t.pmf)[:37], pmf, rtol=1e-6)


# -- pmf sums and sampling frequencies -------------------------------------------------------------

@pytest.fixture(scope="module")
def vlc_tech(backend):
    """nee-pt with lights=vlc after 5 frames in a room with 200 lights: several buckets per leaf."""
    from dyngi.techniques import create_technique
    sc = many_lights_scene(10)
    tech = create_technique("nee-pt", sc, {"lights": "vlc", "capacity": 8})
    _run(tech, sc, 5)
    tech.selector.begin_frame(_ctx(tech))      # build from the last frame's records
    return tech


def _all_pmfs(sel, tris, p, n):
    """pmf of every light at every point: (N, L) numpy."""
    N, L = p.shape[0], tris.count
    P = _arr(np.repeat(p, L, 0), mi.Point3f)
    Nn = _arr(np.repeat(n, L, 0), mi.Vector3f)
    ids = mi.UInt32(np.tile(np.arange(L, dtype=np.uint32), N))
    return np.asarray(sel.pmf(P, Nn, ids, mi.Bool(True))).reshape(N, L)


def _importances(tris, p, n):
    from dyngi.lights.importance import triangle_irradiance
    N, L = p.shape[0], tris.count
    ids = mi.UInt32(np.tile(np.arange(L, dtype=np.uint32), N))
    w = triangle_irradiance(_arr(np.repeat(p, L, 0), mi.Point3f), _arr(np.repeat(n, L, 0), mi.Vector3f),
                            dr.gather(mi.Point3f, tris.p0, ids), dr.gather(mi.Vector3f, tris.e1, ids),
                            dr.gather(mi.Vector3f, tris.e2, ids), dr.gather(mi.Color3f, tris.radiance, ids))
    return np.asarray(w).reshape(N, L)


def test_uniform_pmf_sums_to_one_and_matches_frequencies(backend):
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.uniform import UniformSelector
    sc = many_lights_scene(4)
    tris = EmitterTable(sc.mi_scene)
    sel = UniformSelector(tris)
    rng = np.random.default_rng(1)
    p, n = _points(5, rng)
    pm = _all_pmfs(sel, tris, p, n)
    assert np.allclose(pm.sum(1), 1.0, atol=1e-5)
    m = 50_000
    k, pmf = sel.sample(_arr(np.repeat(p[:1], m, 0), mi.Point3f), _arr(np.repeat(n[:1], m, 0), mi.Vector3f),
                        mi.Float(rng.random(m).astype(np.float32)), mi.Bool(True))
    ok, pv = chi2_uniform(np.bincount(np.asarray(k), minlength=tris.count), m * pm[0])
    assert ok, pv
    assert np.allclose(np.asarray(pmf), 1.0 / tris.count)


def test_vlc_pmf_sums_to_one_minus_zero_importance_buckets(vlc_tech):
    """sum_k pmf(k) = 1 - (1 - f) * (#buckets of the leaf whose importance sum is 0) / B, per point."""
    tech = vlc_tech
    sel, tris, oc = tech.selector, tech.tris, tech.octree
    assert sel.stats()["leaves_with_vlc"] > 0 and sel.host_bucket_counts().max() >= 2
    rng = np.random.default_rng(2)
    p, n = _points(40, rng)
    pm = _all_pmfs(sel, tris, p, n)
    imp = _importances(tris, p, n)
    leaves = np.asarray(oc.lookup(_arr(p, mi.Point3f)))
    f = sel.fraction
    for i in range(len(p)):
        buckets = sel.host_buckets(int(leaves[i]))
        B = len(buckets)
        if B == 0:
            want = 1.0
        else:
            zero = sum(1 for b in buckets if imp[i, b].sum() <= 0.0)
            want = 1.0 - (1.0 - f) * zero / B
        assert pm[i].sum() == pytest.approx(want, abs=2e-4), (i, B)
    # a light with zero importance outside the VLC still has its exploration probability (unbiasedness)
    assert np.all(pm > 0.0)


def test_vlc_sampling_frequencies_match_pmf(vlc_tech):
    """Algorithm 1's combined VLC + exploration sampling against the exact MIS pmf (chi^2 per point)."""
    tech = vlc_tech
    sel, tris = tech.selector, tech.tris
    rng = np.random.default_rng(3)
    p, n = _points(4, rng)
    pm = _all_pmfs(sel, tris, p, n)
    m = 60_000
    for i in range(len(p)):
        k, pmf = sel.sample(_arr(np.repeat(p[i:i + 1], m, 0), mi.Point3f),
                            _arr(np.repeat(n[i:i + 1], m, 0), mi.Vector3f),
                            mi.Float(rng.random(m).astype(np.float32)), mi.Bool(True))
        k = np.asarray(k).astype(np.int64)
        valid = k != 0xFFFFFFFF
        counts = np.append(np.bincount(k[valid], minlength=tris.count), (~valid).sum())
        expected = m * np.append(pm[i], max(0.0, 1.0 - pm[i].sum()))
        ok, pv = chi2_uniform(counts, expected)
        assert ok, (i, pv)
        # the pmf returned with each sample is the pmf of the returned light
        assert np.allclose(np.asarray(pmf)[valid], pm[i][k[valid]], rtol=1e-4, atol=1e-9)


# -- construction: dedup, neighbour merge, buckets ----------------------------------------------

@pytest.mark.parametrize("merge, adapt", [(True, "device"), (False, "device"), (True, "host")])
def test_construction_keeps_every_visible_light_once(backend, merge, adapt):
    """Device construction (octree slots, bit sets) and the host pass (dense leaves, NumPy) both."""
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.base import FrameCtx
    from dyngi.directions.octree import AdaptiveOctree
    from dyngi.lights.vlc import VLCSelector
    sc = many_lights_scene(10)        # 200 lights
    tris = EmitterTable(sc.mi_scene)
    lo, hi = (np.asarray(b) for b in sc.meta.bounds)
    oc = AdaptiveOctree(lo, hi, adapt=adapt)       # 8 leaves
    cap = 8
    sel = VLCSelector(tris, octree=oc, capacity=cap, merge_neighbours=merge, adapt=adapt)
    assert sel.adapt == adapt
    rng = np.random.default_rng(4)
    m = 20_000
    p = rng.uniform(lo + 0.01, hi - 0.01, size=(m, 3))
    ids = rng.integers(0, 60, m) * 3 % tris.count          # duplicates on purpose
    vis = rng.random(m) < 0.3
    sel.record(_arr(p, mi.Point3f), mi.Vector3f(0, 1, 0), mi.UInt32(ids.astype(np.uint32)), mi.Bool(vis),
               mi.Bool(True))
    sel.end_frame()
    sel.begin_frame(FrameCtx(sc.mi_scene, tris, 1, 0.0, oc, (lo, hi)))
    leaf = np.asarray(oc.lookup(_arr(p, mi.Point3f)))
    nb = np.asarray(oc.neighbours).reshape(-1, 6)
    caches = sel.host_caches()
    assert not caches[np.setdiff1d(np.arange(oc.leaf_count), np.unique(leaf))].any() or merge
    for c in np.unique(leaf):
        srcs = [c] + ([int(j) for j in nb[c] if j != 0xFFFFFFFF] if merge else [])
        want = np.unique(ids[vis & np.isin(leaf, srcs)])
        got = sel.host_cache(c)
        assert np.array_equal(np.nonzero(caches[c])[0], want)
        assert np.array_equal(got, want), c          # every visible light, exactly once
        buckets = sel.host_buckets(c)
        B = len(buckets)
        if want.size == 0:
            assert B == 0
            continue
        assert B & (B - 1) == 0                      # a power of two (bottom-up merges of a modulo table)
        flat = np.concatenate(buckets)
        assert np.array_equal(np.sort(flat), want) and flat.size == want.size
        for j, b in enumerate(buckets):
            assert len(b) <= cap and np.all(b % B == j) and np.all(np.diff(b) > 0)
        if B > 1:   # minimal: merging once more (B/2) would overflow a bucket
            occ = np.bincount(want % (B // 2), minlength=B // 2)
            assert occ.max() > cap



@pytest.mark.parametrize("adapt", ["device", "host"])
def test_selection_is_the_two_pass_inverse_cdf_over_a_full_bucket(backend, adapt):
    """Algorithm 1's selection (the first traversal keeps the weights, the second scans them): in a VLC draw the
    light is the first of its bucket (increasing id) whose running importance sum exceeds ``u_l * acc``, as a
    NumPy two-pass walk over the bucket's importances gives it, in buckets filled to the capacity (16 lights
    in every leaf, capacity 8: two full buckets). Lanes whose target lies within 1e-4 of a partial sum are left
    out (the two may round the rescaled ``u`` differently there)."""
    from dyngi.directions.octree import AdaptiveOctree
    from dyngi.lights.base import FrameCtx
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.vlc import VLCSelector
    sc = many_lights_scene(4)          # 32 lights
    tris = EmitterTable(sc.mi_scene)
    lo, hi = (np.asarray(b) for b in sc.meta.bounds)
    oc = AdaptiveOctree(lo, hi, adapt=adapt)       # 8 leaves
    sel = VLCSelector(tris, octree=oc, capacity=8, adapt=adapt)
    assert sel.adapt == adapt
    rng = np.random.default_rng(6)
    m = 4000
    pr = rng.uniform(lo + 0.01, hi - 0.01, size=(m, 3))
    sel.record(_arr(pr, mi.Point3f), mi.Vector3f(0, 1, 0), mi.UInt32((np.arange(m) % 16).astype(np.uint32)),
               mi.Bool(True), mi.Bool(True))
    sel.end_frame()
    sel.begin_frame(FrameCtx(sc.mi_scene, tris, 1, 0.0, oc, (lo, hi)))
    p, n = _points(6, rng)
    leaves = np.asarray(oc.lookup(_arr(p, mi.Point3f)))
    k_draws = 3000
    f = np.float32(sel.fraction)
    checked = 0
    for i in range(len(p)):
        buckets = sel.host_buckets(int(leaves[i]))
        assert [len(b) for b in buckets] == [8, 8]
        B = np.float32(len(buckets))
        u = rng.uniform(float(f), 1.0, k_draws).astype(np.float32)       # VLC draws only
        P = _arr(np.repeat(p[i:i + 1], k_draws, 0), mi.Point3f)
        N = _arr(np.repeat(n[i:i + 1], k_draws, 0), mi.Vector3f)
        k = np.asarray(sel.sample(P, N, mi.Float(u), mi.Bool(True))[0]).astype(np.int64)
        # importances of the bucket lights at the point, in traversal order (the selector's own function)
        ids = np.concatenate(buckets)
        w = np.asarray(sel._importance(_arr(np.repeat(p[i:i + 1], ids.size, 0), mi.Point3f),
                                       _arr(np.repeat(n[i:i + 1], ids.size, 0), mi.Vector3f),
                                       mi.UInt32(ids.astype(np.uint32)), mi.Bool(True)), np.float32)
        uv = np.minimum((u - f) / (np.float32(1) - f), np.float32(0.99999994))
        b = np.minimum((uv * B).astype(np.int64), len(buckets) - 1)
        u_l = uv * B - b.astype(np.float32)
        for j, bucket in enumerate(buckets):
            wb = w[j * 8:(j + 1) * 8]
            if wb.sum() <= 0:
                continue
            cum = np.cumsum(wb, dtype=np.float32)       # sequential float32 sums, the traversal's order
            lane = b == j
            tgt = u_l[lane] * cum[-1]
            first = np.argmax((cum[None, :] > tgt[:, None]) & (wb[None, :] > 0), axis=1)
            want = bucket[first]
            clear = np.min(np.abs(cum[None, :] - tgt[:, None]), axis=1) > 1e-4 * cum[-1]
            assert np.array_equal(k[lane][clear], want[clear]), (i, j)
            checked += int(clear.sum())
    assert checked > 0.5 * len(p) * k_draws, checked     # most draws decided away from a boundary

def test_bucket_hysteresis(backend):
    from dyngi.lights.vlc import bucket_counts
    light = np.arange(30)                    # 30 distinct lights
    leaf = np.zeros(30, np.int64)
    assert bucket_counts(leaf, light, 1, np.array([0]), 32, 0.75)[0] == 1      # 30 <= 32
    assert bucket_counts(leaf, light, 1, np.array([1]), 32, 0.75)[0] == 1      # not lower than before
    assert bucket_counts(leaf, light, 1, np.array([2]), 32, 0.75)[0] == 2      # lower needs <= 24: keep 2
    assert bucket_counts(leaf[:20], np.arange(20), 1, np.array([2]), 32, 0.75)[0] == 1   # 20 <= 24: merge
    assert bucket_counts(leaf[:0], light[:0], 1, np.array([4]))[0] == 0        # empty leaf


# -- occlusion ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("adapt", ["device", "host"])
def test_light_behind_a_wall_never_enters_a_vlc(backend, adapt, monkeypatch):
    """Both constructions; the host pass's records also show the outside light explored and occluded."""
    import functools

    from dyngi.lights import vlc as vlc_mod
    from dyngi.techniques import create_technique
    monkeypatch.setattr(vlc_mod.VLCSelector, "__init__", functools.partialmethod(vlc_mod.VLCSelector.__init__,
                                                                                 adapt=adapt))
    sc = many_lights_scene(3, outside=True)
    tech = create_technique("nee-pt", sc, {"lights": "vlc", "exploration": 0.5})
    outside = tech.tris.count - 2       # the last mesh: two triangles above the ceiling
    out_ids = {outside, outside + 1}
    seen_inside = set()
    from dyngi.techniques import Frame
    explored = 0
    for i in range(6):
        sc.at(0.0)
        tech.step(Frame(i, 0.0, sc.camera(0.0), (32, 24), seed=1))
        sel = tech.selector
        assert sel.adapt == adapt
        caches = sel.host_caches()
        assert not caches[:, sorted(out_ids)].any(), f"frame {i}: the outside light is in a VLC"
        seen_inside |= set(np.nonzero(caches.any(0))[0].tolist())
        # the outside light was sampled (by exploration) and recorded as occluded
        rec = sel._records
        if rec:
            ids = np.concatenate([np.asarray(r[1]) for r in rec])
            vis = np.concatenate([np.asarray(r[2]) for r in rec])
            explored += int(np.isin(ids, list(out_ids)).sum())
            assert not np.any(vis & np.isin(ids, list(out_ids)))
    assert explored > 0 or adapt == "device"
    assert len(seen_inside) == tech.tris.count - 2      # every inside light was learnt somewhere


# -- emitter triangles ---------------------------------------------------------------------------------

def test_emitter_triangle_ids_are_stable_when_lights_move(backend):
    """cornell-moving-light: after refresh() every triangle keeps its id; light_id(si) of a ray hitting a
    triangle's centroid from the front returns that id, before and after the move; power = pi A Y(L)."""
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.scene import load_scene
    sc = load_scene("cornell-moving-light")
    sc.at(0.0)
    tris = EmitterTable(sc.mi_scene)
    h0 = tris.host_arrays()
    assert tris.count >= 2
    assert np.allclose(h0["power"], np.pi * h0["area"] * (h0["radiance"] @ [0.212671, 0.715160, 0.072169]))

    def ids_hit():
        c, nrm = tris.host_arrays()["centroid"], tris.host_arrays()["normal"]
        ray = mi.Ray3f(_arr(c + 1e-3 * nrm, mi.Point3f), _arr(-nrm, mi.Vector3f))
        return np.asarray(tris.light_id(sc.mi_scene.ray_intersect(ray)))

    assert np.array_equal(ids_hit(), np.arange(tris.count))
    sc.at(sc.duration / 2)
    tris.refresh(sc.mi_scene)
    h1 = tris.host_arrays()
    assert not np.allclose(h0["centroid"], h1["centroid"])        # the light moved
    assert np.array_equal(ids_hit(), np.arange(tris.count))        # ... and kept its ids
    assert np.allclose(h0["area"], h1["area"], rtol=1e-5)


# -- explorer=lighttree (our extension: a light tree as the exploration strategy) -------------------

@pytest.fixture(scope="module")
def vlc_lh_tech(backend):
    """As ``vlc_tech`` with ``explorer=lighttree``."""
    from dyngi.techniques import create_technique
    sc = many_lights_scene(10)
    tech = create_technique("nee-pt", sc, {"lights": "vlc", "capacity": 8, "explorer": "lighttree"})
    _run(tech, sc, 5)
    tech.selector.begin_frame(_ctx(tech))
    return tech


def test_lighttree_explorer_pmf_is_the_exact_mixture(vlc_lh_tech):
    """sum_k pmf(k) = f * sum_k p_LH(k) + (1 - f) * (1 - zero-importance buckets / B) per point (f = 1 where
    the leaf's VLC is empty), and pmf(k) = f p_LH(k) + (1 - f) p_VLC(k) light by light, with p_LH the
    light tree's own pmf and p_VLC recomputed here from the host buckets and the importances."""
    tech = vlc_lh_tech
    sel, tris, oc = tech.selector, tech.tris, tech.octree
    assert sel._lh is not None and sel.stats()["leaves_with_vlc"] > 0
    rng = np.random.default_rng(5)
    p, n = _points(30, rng)
    pm = _all_pmfs(sel, tris, p, n)
    plh = _all_pmfs(sel._lh, tris, p, n)
    imp = _importances(tris, p, n)
    leaves = np.asarray(oc.lookup(_arr(p, mi.Point3f)))
    assert np.all(plh.sum(1) <= 1.0 + 1e-4) and np.all(plh.sum(1) > 0.5)
    checked = 0
    for i in range(len(p)):
        buckets = sel.host_buckets(int(leaves[i]))
        B = len(buckets)
        f = sel.fraction if B else 1.0
        pv = np.zeros(tris.count)
        for b in buckets:
            acc = imp[i, b].sum()
            if acc > 0:
                pv[b] = imp[i, b] / (acc * B)
        want = f * plh[i] + (1.0 - f) * pv
        assert np.allclose(pm[i], want, rtol=2e-3, atol=1e-7), i
        checked += B > 0
    assert checked >= 10


def test_lighttree_explorer_sampling_frequencies_match_pmf(vlc_lh_tech):
    """Combined VLC + light-tree exploration sampling against the exact mixture pmf (chi^2 per point)."""
    tech = vlc_lh_tech
    sel, tris = tech.selector, tech.tris
    rng = np.random.default_rng(6)
    p, n = _points(3, rng)
    pm = _all_pmfs(sel, tris, p, n)
    m = 60_000
    for i in range(len(p)):
        k, pmf = sel.sample(_arr(np.repeat(p[i:i + 1], m, 0), mi.Point3f),
                            _arr(np.repeat(n[i:i + 1], m, 0), mi.Vector3f),
                            mi.Float(rng.random(m).astype(np.float32)), mi.Bool(True))
        k = np.asarray(k).astype(np.int64)
        valid = k != 0xFFFFFFFF
        counts = np.append(np.bincount(k[valid], minlength=tris.count), (~valid).sum())
        expected = m * np.append(pm[i], max(0.0, 1.0 - pm[i].sum()))
        ok, pv = chi2_uniform(counts, expected)
        assert ok, (i, pv)
        assert np.allclose(np.asarray(pmf)[valid], pm[i][k[valid]], rtol=1e-4, atol=1e-9)
