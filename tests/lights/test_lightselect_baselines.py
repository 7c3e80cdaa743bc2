"""Baseline light selectors of the VLC paper (Sec. 7): the light hierarchy (lighttree) and Static Light Lists
(``sll-pvs``: the paper's PVS lists, ``lights=sll``; ``sll``: the ray-cast oracle lists, ``lights=sll-oracle``). Their pmfs sum to 1 over all lights, equal the pmf that sample() returns, match sampling
frequencies (chi^2), the tree has the widths the paper configures, and a light behind the wall of a closed
room never enters the lists of the other room's cells."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import assert_steady_state_compiles_nothing
from stats import chi2_uniform

INVALID = 0xFFFFFFFF


def _v(mi, A, cls=None):
    cls = cls or mi.Point3f
    A = np.asarray(A, np.float32).reshape(-1, 3)
    return cls(*[mi.Float(np.ascontiguousarray(A[:, k])) for k in range(3)])


@pytest.fixture(scope="module")
def warehouse(backend):
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.scene.library import make_builtin
    sc = make_builtin("warehouse-lights")
    return sc, EmitterTable(sc.mi_scene)


@pytest.fixture(scope="module")
def selectors(warehouse):
    from dyngi.lights.lighttree import LightTreeSelector
    from dyngi.lights.pvs import PVSLightLists
    from dyngi.lights.sll import SLLSelector
    sc, tris = warehouse
    return {"lighttree": LightTreeSelector(tris, mi_scene=sc.mi_scene, bounds=sc.meta.bounds),
            "sll": SLLSelector(tris, mi_scene=sc.mi_scene, bounds=sc.meta.bounds, cells=20),
            "sll-pvs": PVSLightLists(tris, mi_scene=sc.mi_scene, bounds=sc.meta.bounds)}


def _points(rng, k):
    """Receivers in the warehouse: floor points (normal up), shelf-top/wall-ish points (random normals)."""
    P = np.c_[rng.random(k) * 40, np.where(rng.random(k) < 0.5, 0.0, rng.random(k) * 5.5 + 0.2), rng.random(k) * 20]
    N = rng.normal(size=(k, 3))
    N /= np.linalg.norm(N, axis=1)[:, None]
    N[P[:, 1] == 0.0] = [0.0, 1.0, 0.0]
    return P, N


def _all_pmfs(mi, sel, P, N, L):
    K = len(P)
    pm = sel.pmf(_v(mi, np.repeat(P, L, 0)), _v(mi, np.repeat(N, L, 0), mi.Vector3f),
                 mi.UInt32(np.tile(np.arange(L, dtype=np.uint32), K)), True)
    return pm.numpy().reshape(K, L).astype(np.float64)


@pytest.mark.parametrize("name", ["lighttree", "sll", "sll-pvs"])
def test_pmf_sums_to_one(warehouse, selectors, name):
    from dyngi.backend import mi
    sc, tris = warehouse
    sel = selectors[name]
    rng = np.random.default_rng(1)
    P, N = _points(rng, 60)
    pm = _all_pmfs(mi, sel, P, N, tris.count)
    s = pm.sum(1)
    if name == "lighttree":
        assert np.allclose(s, 1.0, atol=2e-5)
    else:
        nonempty = np.array([len(sel.lights_of_cell(c)) > 0 for c in sel.cell_index(P)])
        assert nonempty.mean() > 0.9
        assert np.allclose(s[nonempty], 1.0, atol=2e-5) and np.all(s[~nonempty] == 0.0)
        # a light outside the cell's list has pmf exactly 0
        for i, c in enumerate(sel.cell_index(P)):
            out = np.setdiff1d(np.arange(tris.count), sel.lights_of_cell(c))
            assert np.all(pm[i, out] == 0.0)
    assert np.all(pm >= 0.0)


@pytest.mark.parametrize("name", ["lighttree", "sll", "sll-pvs"])
def test_sampling_frequencies_chi2(warehouse, selectors, name):
    """sample() draws light l with frequency pmf(l), and returns that pmf (chi^2, Sidak over 4 points)."""
    from dyngi.backend import mi
    sc, tris = warehouse
    sel = selectors[name]
    L = tris.count
    P = np.array([[5.0, 0.0, 5.0], [9.5, 0.0, 5.2], [10.6, 1.5, 5.0], [23.0, 2.6, 13.0]])
    N = np.array([[0, 1, 0], [0, 1, 0], [1, 0, 0], [0.3, 0.9, -0.3]], np.float64)
    N /= np.linalg.norm(N, axis=1)[:, None]
    pm = _all_pmfs(mi, sel, P, N, L)
    M = 200_000
    rng = np.random.default_rng(7)
    alpha = 1.0 - (1.0 - 0.01) ** (1.0 / len(P))
    for i in range(len(P)):
        lid, pmf = sel.sample(_v(mi, np.repeat(P[i:i + 1], M, 0)), _v(mi, np.repeat(N[i:i + 1], M, 0), mi.Vector3f),
                              mi.Float(rng.random(M).astype(np.float32)), True)
        lid, pmf = lid.numpy(), pmf.numpy()
        assert np.all(lid != INVALID)
        # returned pmf equals pmf() of the chosen light
        assert np.allclose(pmf, pm[i, lid], rtol=1e-5, atol=0)
        ok, p = chi2_uniform(np.bincount(lid, minlength=L), pm[i] * M, alpha=alpha)
        assert ok, f"{name} point {i}: chi2 p = {p:.3g}"
        assert (pm[i] > 0).sum() >= 4      # a real choice, not a forced one


def test_lighttree_structure(warehouse, selectors):
    """8 children per node at most, at most 2 lights per leaf, every light in exactly one leaf, rebuilt per frame."""
    sc, tris = warehouse
    t = selectors["lighttree"]
    h = t._host
    ll = h["leaf_lights"]
    assert ll.shape[1] == 2
    ids = ll[ll != INVALID]
    assert np.array_equal(np.sort(ids), np.arange(tris.count))
    child = h["child"].reshape(-1, 8)
    used = child != INVALID
    assert np.all(used.sum(1) >= 1) and child.shape[0] == t.nodes
    # wide: the tree over 256 lights needs few levels (a binary one would need 7)
    assert t.depth <= 4 and used.sum() > 2 * t.nodes
    # children's boxes lie inside their parent's slot box
    par = h["node_parent"]
    for n in range(1, t.nodes):
        pn, ps = par[n]
        j = pn * 8 + ps
        k = np.nonzero(used[n])[0] + 8 * n
        assert np.all(h["lo"][k] >= h["lo"][j] - 1e-9) and np.all(h["hi"][k] <= h["hi"][j] + 1e-9)
    assert t.stats()["build_ms"] > 0


def test_lighttree_small_counts(backend):
    """1, 2 and 3 lights (root leaf, split root) and no lights at all."""
    from dyngi.backend import mi
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.lighttree import LightTreeSelector
    for quads in (0, 1, 2):
        d = {"type": "scene", "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90)
                                        .scale(5)}}
        for q in range(quads):
            d[f"l{q}"] = {"type": "rectangle", "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1 + q}},
                          "to_world": mi.ScalarTransform4f().translate([q * 2.0, 2, 0]).rotate([1, 0, 0], 90)
                          .scale(0.3)}
        tris = EmitterTable(mi.load_dict(d))
        t = LightTreeSelector(tris)
        P = np.array([[0.5, 0.0, 0.3]] * 5000)
        N = np.array([[0.0, 1.0, 0.0]] * 5000)
        lid, pmf = t.sample(_v(mi, P), _v(mi, N, mi.Vector3f), mi.Float(np.linspace(0, 1, 5000, endpoint=False)), True)
        if tris.count == 0:
            assert np.all(lid.numpy() == INVALID) and np.all(pmf.numpy() == 0)
            continue
        pm = _all_pmfs(mi, t, P[:1], N[:1], tris.count)[0]
        assert np.isclose(pm.sum(), 1.0, atol=1e-6)
        assert np.allclose(pmf.numpy(), pm[lid.numpy()], rtol=1e-5)


def test_lighttree_rebuilds_for_moving_lights(backend):
    """Lights that move (EmitterTable.refresh) are re-clustered in begin_frame: the tree bounds follow them
    and the pmf stays normalised and matches sample()."""
    from dyngi.backend import dr, mi
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.base import FrameCtx
    from dyngi.lights.lighttree import LightTreeSelector
    T = mi.ScalarTransform4f
    d = {"type": "scene", "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(5)}}
    for q in range(5):
        d[f"l{q}"] = {"type": "rectangle", "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 2.0}},
                      "to_world": T().translate([q - 2.0, 2, 0]).rotate([1, 0, 0], 90).scale(0.2)}
    scene = mi.load_dict(d)
    tris = EmitterTable(scene)
    t = LightTreeSelector(tris)
    prm = mi.traverse(scene)
    prm["l4.to_world"] = T().translate([28.0, 2, 0]).rotate([1, 0, 0], 90).scale(0.2)    # the last light quad
    prm.update()
    tris.refresh(scene)
    moved = {sl[0]: np.arange(sl[1], sl[1] + sl[2]) for sl in tris.shape_slices()}["l4"]
    V = tris.host_arrays()["centroid"][moved]
    assert V[:, 0].min() > 27.0
    t.begin_frame(FrameCtx(scene, tris, 1, 1 / 30.0))
    h = t._host
    root = h["child"][:8] != INVALID
    assert h["hi"][:8][root, 0].max() >= V[:, 0].max() - 1e-5
    P, N = np.array([[27.5, 0.0, 0.1], [0.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]] * 2)
    pm = _all_pmfs(mi, t, P, N, tris.count)
    assert np.allclose(pm.sum(1), 1.0, atol=1e-5)
    assert pm[0, moved].sum() > 0.9        # the light next to the point is now the one that moved there
    lid, pmf = t.sample(_v(mi, P), _v(mi, N, mi.Vector3f), mi.Float([0.3, 0.7]), True)
    assert np.allclose(pmf.numpy(), pm[[0, 1], lid.numpy()], rtol=1e-5)


def _two_rooms():
    """Two closed 2 x 2 x 2 m rooms side by side (x in [0, 2] and [2.2, 4.2]) sharing a solid 0.2 m wall, one
    ceiling light (a quad = 2 lights) per room. Returns (mi_scene, bounds)."""
    from dyngi.backend import mi
    T = mi.ScalarTransform4f

    def cube(lo, hi):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return {"type": "cube", "to_world": T().translate(((lo + hi) / 2).tolist()).scale(((hi - lo) / 2).tolist())}

    t = 0.1
    d = {"type": "scene",
         "floor": cube([-t, -t, -t], [4.2 + t, 0, 2 + t]), "ceil": cube([-t, 2, -t], [4.2 + t, 2 + t, 2 + t]),
         "wx0": cube([-t, 0, -t], [0, 2, 2 + t]), "wx1": cube([4.2, 0, -t], [4.2 + t, 2, 2 + t]),
         "wz0": cube([0, 0, -t], [4.2, 2, 0]), "wz1": cube([0, 0, 2], [4.2, 2, 2 + t]),
         "mid": cube([2.0, 0, 0], [2.2, 2, 2])}
    for name, x in (("lightA", 1.0), ("lightB", 3.2)):
        d[name] = {"type": "rectangle", "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 5.0}},
                   "to_world": T().translate([x, 1.95, 1.0]).rotate([1, 0, 0], 90).scale(0.2)}
    return mi.load_dict(d), (np.array([-t, -t, -t]), np.array([4.2 + t, 2 + t, 2 + t]))


def test_sll_light_behind_wall_not_listed(backend):
    from dyngi.backend import mi
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.sll import SLLSelector
    scene, bounds = _two_rooms()
    tris = EmitterTable(scene)
    sl = {s[0]: np.arange(s[1], s[1] + s[2]) for s in tris.shape_slices()}
    A, B = sl["lightA"], sl["lightB"]
    sll = SLLSelector(tris, mi_scene=scene, bounds=bounds, cells=22)
    res = sll.res
    c = np.arange(sll.n_cells)
    ijk = np.stack([c // (res[2] * res[1]), (c // res[2]) % res[1], c % res[2]], 1)
    lo = sll.lo + ijk * sll.cell
    hi = lo + sll.cell
    in_room = np.all((lo >= [0.0, 0.0, 0.0]) & (hi <= [4.2, 1.94, 2.0]), 1)
    room_a = in_room & (hi[:, 0] <= 2.0)
    room_b = in_room & (lo[:, 0] >= 2.2)
    assert room_a.sum() > 20 and room_b.sum() > 20
    for cell in np.nonzero(room_a)[0]:
        lst = sll.lights_of_cell(cell)
        assert np.all(np.isin(A, lst)) and not np.any(np.isin(B, lst)), f"cell {cell}: {lst}"
    for cell in np.nonzero(room_b)[0]:
        lst = sll.lights_of_cell(cell)
        assert np.all(np.isin(B, lst)) and not np.any(np.isin(A, lst)), f"cell {cell}: {lst}"
    # and the device sampler never picks the other room's light: floor points of room A
    rng = np.random.default_rng(3)
    n = 20000
    P = np.c_[0.1 + 1.8 * rng.random(n), np.zeros(n) + 1e-3, 0.1 + 1.8 * rng.random(n)]
    lid, pmf = sll.sample(_v(mi, P), _v(mi, np.tile([0.0, 1.0, 0.0], (n, 1)), mi.Vector3f),
                          mi.Float(rng.random(n).astype(np.float32)), True)
    lid = lid.numpy()
    assert np.all(np.isin(lid, A))
    pmB = sll.pmf(_v(mi, P[:100].repeat(len(B), 0)), _v(mi, np.tile([0.0, 1.0, 0.0], (100 * len(B), 1)), mi.Vector3f),
                  mi.UInt32(np.tile(B.astype(np.uint32), 100)), True).numpy()
    assert np.all(pmB == 0.0)


def test_sll_dynamic_shapes_do_not_occlude(backend):
    """A PVS knows only static geometry: with the separating wall declared dynamic, room B's light is listed
    in room A's cells (and the sampler still has an exact pmf there)."""
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.sll import SLLSelector
    scene, bounds = _two_rooms()
    tris = EmitterTable(scene)
    sl = {s[0]: np.arange(s[1], s[1] + s[2]) for s in tris.shape_slices()}
    sll = SLLSelector(tris, mi_scene=scene, bounds=bounds, cells=22, dynamic_shapes=["mid"])
    P = np.array([[0.5, 0.2, 1.0], [1.5, 1.0, 0.5]])
    for c in sll.cell_index(P):
        assert np.all(np.isin(sl["lightB"], sll.lights_of_cell(c)))


def test_lighttree_importance_is_conservative(warehouse, selectors):
    """Wherever a light's unoccluded irradiance is positive its pmf is positive: the cone/box bounds of the
    node importance never cut off a light that can reach the receiver (NEE can sample every such light)."""
    from dyngi.backend import dr, mi
    from dyngi.lights.importance import triangle_irradiance
    sc, tris = warehouse
    t = selectors["lighttree"]
    L = tris.count
    rng = np.random.default_rng(9)
    P, N = _points(rng, 80)
    pm = _all_pmfs(mi, t, P, N, L)
    ids = mi.UInt32(np.tile(np.arange(L, dtype=np.uint32), len(P)))
    E = triangle_irradiance(_v(mi, np.repeat(P, L, 0)), _v(mi, np.repeat(N, L, 0), mi.Vector3f),
                            dr.gather(mi.Point3f, tris.p0, ids), dr.gather(mi.Vector3f, tris.e1, ids),
                            dr.gather(mi.Vector3f, tris.e2, ids), dr.gather(mi.Color3f, tris.radiance, ids))
    E = E.numpy().reshape(len(P), L)
    lit = E > 1e-6 * E.max(1, keepdims=True)
    assert lit.sum() > 1000
    assert np.all(pm[lit] > 0.0)


def test_sll_updates_moving_lights(backend):
    """A light that moves from room B into room A is re-listed in begin_frame: room A's cells list it, room B's
    no longer do, and the lists equal a fresh precompute with the light at its new place."""
    from dyngi.backend import mi
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.base import FrameCtx
    from dyngi.lights.sll import SLLSelector
    scene, bounds = _two_rooms()
    tris = EmitterTable(scene)
    B = {s[0]: np.arange(s[1], s[1] + s[2]) for s in tris.shape_slices()}["lightB"]
    sll = SLLSelector(tris, mi_scene=scene, bounds=bounds, cells=22)
    pa, pb = np.array([[0.5, 0.3, 1.0]]), np.array([[3.5, 0.3, 1.0]])
    ca, cb = sll.cell_index(pa)[0], sll.cell_index(pb)[0]
    assert not np.any(np.isin(B, sll.lights_of_cell(ca))) and np.all(np.isin(B, sll.lights_of_cell(cb)))
    prm = mi.traverse(scene)
    prm["lightB.to_world"] = mi.ScalarTransform4f().translate([0.6, 1.95, 1.4]).rotate([1, 0, 0], 90).scale(0.2)
    prm.update()
    tris.refresh(scene)
    sll.begin_frame(FrameCtx(scene, tris, 1, 1 / 30.0))
    assert sll.stats()["moved_lights"] == len(B)
    assert np.all(np.isin(B, sll.lights_of_cell(ca))) and not np.any(np.isin(B, sll.lights_of_cell(cb)))
    fresh = SLLSelector(tris, mi_scene=scene, bounds=bounds, cells=22)
    assert np.array_equal(fresh._host_vis, sll._host_vis)
    sll.begin_frame(FrameCtx(scene, tris, 2, 2 / 30.0))
    assert sll.stats()["moved_lights"] == 0


def test_sll_stride_traversal_pmf(backend):
    """More than 32 lights in a list: stride traversal with a random offset keeps the pmf exact (chi^2)."""
    from dyngi.backend import mi
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.sll import SLLSelector
    T = mi.ScalarTransform4f
    d = {"type": "scene", "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(6)}}
    for q in range(40):            # 80 triangle lights on an 8 x 5 grid (no overlap), all visible from the floor
        x, z = -3.5 + (q % 8), -2.0 + (q // 8)
        d[f"l{q}"] = {"type": "rectangle", "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1 + q % 5}},
                      "to_world": T().translate([x, 2.0, z]).rotate([1, 0, 0], 90).scale(0.2)}
    scene = mi.load_dict(d)
    tris = EmitterTable(scene)
    sll = SLLSelector(tris, mi_scene=scene, bounds=(np.array([-6, 0, -6]), np.array([6, 3, 6])), cells=4,
                      cell_samples=8, light_samples=2)
    p = np.array([[0.3, 0.01, -0.2]])
    cell = sll.cell_index(p)[0]
    assert len(sll.lights_of_cell(cell)) == tris.count == 80       # stride 3: groups of 27, 27, 26
    nrm = np.array([[0.0, 1.0, 0.0]])
    pm = _all_pmfs(mi, sll, p, nrm, tris.count)[0]
    assert np.isclose(pm.sum(), 1.0, atol=1e-5)
    # 900k draws in three independent streams, pooled. The emitter order (so pm) differs between processes;
    # the former single stream (seed 0, 300k) gave p 0.0015-0.11 over six orders while 3M draws of another
    # stream gave p 0.47-0.76 and 12 pooled 300k streams p 0.55-0.99: no bias found, one unlucky stream
    M = 900_000
    lid, pmf = sll.sample(_v(mi, p.repeat(M, 0)), _v(mi, nrm.repeat(M, 0), mi.Vector3f),
                          mi.Float(np.concatenate([np.random.default_rng(s).random(M // 3) for s in range(3)])
                                   .astype(np.float32)), True)
    lid = lid.numpy()
    assert np.allclose(pmf.numpy(), pm[lid], rtol=1e-5)
    ok, pv = chi2_uniform(np.bincount(lid, minlength=tris.count), pm * M)
    assert ok, pv


def test_steady_state_compiles_nothing(warehouse, selectors):
    """Per-frame rebuild (lighttree) and sampling with opaque per-frame randoms compile nothing new."""
    from dyngi.backend import dr, mi
    from dyngi.lights.base import FrameCtx
    from dyngi.sampling.rng import make_sampler
    sc, tris = warehouse
    P = np.c_[np.linspace(1, 39, 4000), np.zeros(4000), np.linspace(1, 19, 4000)]
    p, n = _v(mi, P), _v(mi, np.tile([0.0, 1.0, 0.0], (4000, 1)), mi.Vector3f)
    dr.eval(p, n)

    def step(f):
        for sel in selectors.values():
            sel.begin_frame(FrameCtx(sc.mi_scene, tris, f, f / 30.0))
            smp = make_sampler(4000, 3, f)
            lid, pmf = sel.sample(p, n, smp.next_1d(), True)
            q = sel.pmf(p, n, lid, lid != INVALID)
            dr.eval(lid, pmf, q)

    assert_steady_state_compiles_nothing(step, frames=4, warmup=1, nonempty=True)


def test_lighttree_rebuild_on_change_only(backend):
    """rebuild="change" (ours) skips the build while no light changed and rebuilds when one moves, giving the
    same tree as the per-frame rebuild (the paper's baseline, default); a bad policy is a DyngiError."""
    from dyngi.backend import mi
    from dyngi.errors import DyngiError
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.base import FrameCtx
    from dyngi.lights.lighttree import LightTreeSelector
    from dyngi.scene import load_scene
    sc = load_scene("cornell-moving-light")
    sc.at(0.0)
    tris = EmitterTable(sc.mi_scene)
    lazy = LightTreeSelector(tris, rebuild="change")
    eager = LightTreeSelector(tris)
    for i in range(3):
        ctx = FrameCtx(sc.mi_scene, tris, i, 0.0)
        lazy.begin_frame(ctx)
        eager.begin_frame(ctx)
    assert lazy.builds == 1 and eager.builds == 4
    sc.at(0.5)
    tris.refresh(sc.mi_scene)
    ctx = FrameCtx(sc.mi_scene, tris, 3, 0.5)
    lazy.begin_frame(ctx)
    eager.begin_frame(ctx)
    assert lazy.builds == 2
    P = _v(mi, [[0.1, 0.01, 0.2], [-0.5, 0.5, 0.3]])
    N = _v(mi, [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], mi.Vector3f)
    for k in range(tris.count):
        a = lazy.pmf(P, N, mi.UInt32([k, k]), True).numpy()
        b = eager.pmf(P, N, mi.UInt32([k, k]), True).numpy()
        assert np.allclose(a, b)
    with pytest.raises(DyngiError):
        LightTreeSelector(tris, rebuild="sometimes")


def test_lighttree_device_build(warehouse):
    """build="device" (Dr.Jit SAH levels): a valid 8-wide tree over every light (<= 2 per leaf, nested boxes), the
    same node and leaf counts as the host build, pmfs summing to 1 and matching sampling frequencies (chi^2)."""
    from dyngi.backend import mi
    from dyngi.lights.lighttree import LightTreeSelector
    sc, tris = warehouse
    dev = LightTreeSelector(tris, build="device")
    host = LightTreeSelector(tris, build="host")
    assert dev.device_build and not host.device_build
    assert (dev.nodes, dev.leaves) == (host.nodes, host.leaves)
    ll = dev._host["leaf_lights"]
    assert np.array_equal(np.sort(ll[ll != INVALID]), np.arange(tris.count))
    child = dev._host["child"].reshape(-1, 8)
    used = child != INVALID
    par = dev._host["node_parent"]
    for n in range(1, dev.nodes):
        j = par[n][0] * 8 + par[n][1]
        k = np.nonzero(used[n])[0] + 8 * n
        assert np.all(dev._host["lo"][k] >= dev._host["lo"][j] - 1e-4)
        assert np.all(dev._host["hi"][k] <= dev._host["hi"][j] + 1e-4)
    rng = np.random.default_rng(5)
    P, N = _points(rng, 6)
    pm = _all_pmfs(mi, dev, P, N, tris.count)
    assert np.allclose(pm.sum(1), 1.0, atol=1e-4)
    M = 200_000
    p, nrm = P[:1], N[:1]
    lid, pmf = dev.sample(_v(mi, p.repeat(M, 0)), _v(mi, nrm.repeat(M, 0), mi.Vector3f),
                          mi.Float(rng.random(M).astype(np.float32)), True)
    ok, pv = chi2_uniform(np.bincount(lid.numpy(), minlength=tris.count), pm[0] * M)
    assert ok, pv
