"""``lights=sll``: Quake 2 RTX's static light lists from a conservative potentially-visible set.

The PVS is conservative: no light that an unoccluded segment from a point of a leaf reaches is missing from
that leaf's list (random segments on ``warehouse-rooms``); a closed room's light never enters the lists of
the leaves on the other side of a solid wall; the lists hold many more lights than are visible (the
paper's "potentially visible but occluded"); a moved light is re-listed; its pmf sums to 1 and matches
its sampling frequencies (tests/sampling/test_lightselect_baselines.py runs the shared checks on it).
"""
from __future__ import annotations

import numpy as np
import pytest


def _v(mi, A, cls=None):
    cls = cls or mi.Point3f
    A = np.asarray(A, np.float64).reshape(-1, 3)
    return cls(*[mi.Float(np.ascontiguousarray(A[:, k], np.float32)) for k in range(3)])


@pytest.fixture(scope="module")
def rooms(backend):
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.pvs import PVSLightLists
    from dyngi.scene.library import make_builtin
    sc = make_builtin("warehouse-rooms")
    tris = EmitterTable(sc.mi_scene)
    return sc, tris, PVSLightLists(tris, mi_scene=sc.mi_scene, bounds=sc.meta.bounds)


def _visible_pairs(mi, sc, tris, n, seed):
    """n random (point in the bounds, point on a random light) segments: (P, light, unoccluded & front)."""
    h = tris.host_arrays()
    rng = np.random.default_rng(seed)
    lo, hi = (np.asarray(b, np.float64) for b in sc.meta.bounds)
    P = lo + rng.random((n, 3)) * (hi - lo)
    L = rng.integers(0, tris.count, n)
    u = rng.random((n, 2))
    su = np.sqrt(u[:, 0])
    Y = h["p0"][L] + (1 - su)[:, None] * h["e1"][L] + (u[:, 1] * su)[:, None] * h["e2"][L]
    d = Y - P
    dist = np.linalg.norm(d, axis=1)
    front = np.einsum("ij,ij->i", np.cross(h["e1"][L], h["e2"][L]), -d) > 0
    ray = mi.Ray3f(_v(mi, P), _v(mi, d / dist[:, None], mi.Vector3f))
    ray.maxt = mi.Float((dist * (1 - 1e-4)).astype(np.float32))
    return P, L, front & ~sc.mi_scene.ray_test(ray).numpy()


def test_pvs_is_conservative(rooms):
    """Every light that a random unoccluded segment from a leaf reaches is in that leaf's list (200k segments,
    ~28k of them unoccluded, lines through two doors in a row included)."""
    from dyngi.backend import mi
    sc, tris, sll = rooms
    P, L, vis = _visible_pairs(mi, sc, tris, 200_000, seed=11)
    assert vis.sum() > 10_000
    missing = vis & ~sll._host_vis[sll.cell_index(P), L]
    assert not missing.any(), f"{missing.sum()} visible (leaf, light) pairs missing, e.g. {P[missing][:3]}, " \
                              f"lights {L[missing][:3]}"


def test_sampled_pvs_is_not_conservative_and_flood_is_wider(rooms):
    """The ablation pvs=sampled (segments between leaf pairs, one ring of neighbours) misses visible lights that
    the portal flood keeps: the reason the flood is the default (a test that the conservativeness check can fail)."""
    from dyngi.backend import mi
    from dyngi.lights.pvs import PVSLightLists
    sc, tris, sll = rooms
    samp = PVSLightLists(tris, mi_scene=sc.mi_scene, bounds=sc.meta.bounds, pvs="sampled", pair_samples=16, dilate=0)
    P, L, vis = _visible_pairs(mi, sc, tris, 200_000, seed=12)
    assert (vis & ~samp._host_vis[samp.cell_index(P), L]).sum() > 0
    assert samp.stats()["mean_list"] < sll.stats()["mean_list"]


def test_lists_hold_occluded_lights(rooms):
    """Potentially visible is much more than visible: the mean list is >= 2x the lights a leaf really sees
    (sampled), and every leaf of room (0, 0) lists lamps on the far face of its walls (close but occluded)."""
    from dyngi.backend import mi
    sc, tris, sll = rooms
    P, L, vis = _visible_pairs(mi, sc, tris, 200_000, seed=13)
    cells = sll.cell_index(P)
    seen = np.zeros((sll.n_cells, tris.count), bool)
    seen[cells[vis], L[vis]] = True
    occupied = seen.any(1)
    assert sll._host_vis[occupied].sum(1).mean() >= 2.0 * seen[occupied].sum(1).mean()
    assert sll.stats()["max_list"] > 32          # so the stride traversal (<= 32 considered) is exercised


def test_solid_wall_separates_closed_rooms(backend):
    """Two closed rooms whose shared solid wall lies on a leaf boundary: neither room's leaves list the other's
    light, and the sampler never picks it (pmf 0)."""
    from dyngi.backend import mi
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.pvs import PVSLightLists
    from tests.lights.test_lightselect_baselines import _two_rooms
    scene, bounds = _two_rooms()         # x in [-0.1, 4.3]; the wall x in [2.0, 2.2]
    tris = EmitterTable(scene)
    sl = {s[0]: np.arange(s[1], s[1] + s[2]) for s in tris.shape_slices()}
    A, B = sl["lightA"], sl["lightB"]
    sll = PVSLightLists(tris, mi_scene=scene, bounds=bounds, cells=4)   # 1.1 m leaves: a boundary at x = 2.1
    lo, hi, _ = sll._boxes()
    room_a, room_b = hi[:, 0] <= 2.11, lo[:, 0] >= 2.09
    assert room_a.any() and room_b.any()
    for c in np.nonzero(room_a)[0]:
        assert not np.isin(B, sll.lights_of_cell(c)).any(), c
    for c in np.nonzero(room_b)[0]:
        assert not np.isin(A, sll.lights_of_cell(c)).any(), c
    assert sll.closed_faces > 0
    rng = np.random.default_rng(3)
    n = 20000
    P = np.c_[0.1 + 1.8 * rng.random(n), np.full(n, 1e-3), 0.1 + 1.8 * rng.random(n)]
    lid, _ = sll.sample(_v(mi, P), _v(mi, np.tile([0.0, 1.0, 0.0], (n, 1)), mi.Vector3f),
                        mi.Float(rng.random(n).astype(np.float32)), True)
    assert np.isin(lid.numpy(), A).all()


def test_moved_light_is_relisted(backend):
    """A light that moves into the other closed room is listed there (and no longer in its old room) after
    begin_frame, without new rays (the leaf PVS is static)."""
    from dyngi.backend import mi
    from dyngi.lights.emitter_table import EmitterTable
    from dyngi.lights.base import FrameCtx
    from dyngi.lights.pvs import PVSLightLists
    from tests.lights.test_lightselect_baselines import _two_rooms
    scene, bounds = _two_rooms()
    tris = EmitterTable(scene)
    sl = {s[0]: np.arange(s[1], s[1] + s[2]) for s in tris.shape_slices()}
    sll = PVSLightLists(tris, mi_scene=scene, bounds=bounds, cells=4)
    pa = sll.cell_index(np.array([[1.0, 1.0, 1.0]]))[0]
    pb = sll.cell_index(np.array([[3.2, 1.0, 1.0]]))[0]
    assert np.isin(sl["lightA"], sll.lights_of_cell(pa)).all()
    params = mi.traverse(scene)
    params["lightA.to_world"] = mi.ScalarTransform4f().translate([3.2, 1.95, 1.0]).rotate([1, 0, 0], 90).scale(0.2)
    params.update()                       # lightA moves into room B
    tris.refresh(scene)
    sll.begin_frame(FrameCtx(scene, tris, 1, 0.0))
    assert sll.moved_lights == len(sl["lightA"])
    assert np.isin(sl["lightA"], sll.lights_of_cell(pb)).all()
    assert not np.isin(sl["lightA"], sll.lights_of_cell(pa)).any()


def test_bad_parameters(backend):
    from dyngi.errors import DyngiError
    from dyngi.lights.pvs import PVSLightLists
    from tests.lights.test_lightselect_baselines import _two_rooms
    from dyngi.lights.emitter_table import EmitterTable
    scene, bounds = _two_rooms()
    tris = EmitterTable(scene)
    for kw in ({"pvs": "exact"}, {"cells": 0}, {"face_samples": 0}):
        with pytest.raises(DyngiError):
            PVSLightLists(tris, mi_scene=scene, bounds=bounds, **kw)
    with pytest.raises(DyngiError):
        PVSLightLists(tris, mi_scene=None)
