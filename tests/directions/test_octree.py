"""Adaptive octree of Dittebrandt et al. Sec. 6: split/collapse at the thresholds, correspondence to the
previous tree, neighbour links, device traversal against a NumPy brute force, no per-frame recompiles."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import assert_steady_state_compiles_nothing


@pytest.fixture(scope="module")
def oct_mod(backend):
    from dyngi.directions import octree
    return octree


def _pts(mi, P):
    P = np.asarray(P, np.float32).reshape(-1, 3)
    return mi.Point3f(*[mi.Float(np.ascontiguousarray(P[:, k])) for k in range(3)])


def _place_host(o, mi, P):
    o.place(_pts(mi, P))


def _boxes(o, previous=False):
    h = o.host_leaves(previous)
    return h["lo"], h["lo"] + h["size"]


def _inside(lo_in, hi_in, lo_out, hi_out, tol=1e-9):
    return np.all(lo_in >= lo_out - tol, -1) & np.all(hi_in <= hi_out + tol, -1)


def test_initial_tree_is_split_once(oct_mod):
    from dyngi.backend import mi
    o = oct_mod.AdaptiveOctree([0, 0, 0], [4, 2, 8], adapt="host")
    assert o.leaf_count == 8 and o.stats()["leaves"] == 8
    assert np.all(o.host_leaves()["depth"] == 1)
    assert np.array_equal(o.prev_leaf.numpy(), np.arange(8))
    # empty frame: nothing collapses, the root is never a leaf
    o.adapt()
    assert o.leaf_count == 8 and o.stats()["collapses"] == 0
    # 8 leaves fill the bounds exactly once
    lo, hi = _boxes(o)
    assert np.isclose(np.prod(hi - lo, 1).sum(), np.prod(o.bounds_max.astype(float) - o.bounds_min))


def test_split_and_collapse_at_thresholds(oct_mod):
    from dyngi.backend import mi
    o = oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], split_threshold=100, collapse_threshold=40, adapt="host")
    rng = np.random.default_rng(3)
    a = rng.random((100, 3)) * 0.4                 # all in octant 0 (x, y, z < 0.5)
    # exactly at the split threshold: no split (the paper splits when the count goes ABOVE it)
    _place_host(o, mi, a)
    o.adapt()
    assert o.leaf_count == 8 and o.stats()["splits"] == 0
    # one more sample: octant 0 splits into 8, the others stay
    _place_host(o, mi, np.vstack([a, [[0.1, 0.1, 0.1]]]))
    old_lo, old_hi = _boxes(o)
    leaf0 = int(o.lookup(_pts(mi, [[0.1, 0.1, 0.1]])).numpy()[0])
    o.adapt()
    assert o.leaf_count == 15 and o.stats()["splits"] == 1
    h = o.host_leaves()
    assert sorted(np.bincount(h["depth"])[1:].tolist()) == [7, 8]
    prev = o.prev_leaf.numpy()
    lo, hi = _boxes(o)
    # correspondence: every new leaf lies inside its previous leaf (unchanged or split child)
    assert np.all(_inside(lo, hi, old_lo[prev], old_hi[prev]))
    assert np.sum(prev == leaf0) == 8 and len(np.unique(prev)) == 8
    # the previous tree is kept: lookup_prev is the old tree
    P = rng.random((2000, 3))
    assert np.array_equal(o.lookup_prev(_pts(mi, P)).numpy(), o.host_lookup(P, previous=True))
    # collapse: the 8 children with combined count == threshold stay; below it they collapse
    b = rng.random((40, 3)) * 0.45
    _place_host(o, mi, b)
    o.adapt()
    assert o.leaf_count == 15 and o.stats()["collapses"] == 0
    c = np.vstack([rng.random((30, 3)) * 0.45, np.full((9, 3), 0.3)])   # 39 samples; most in the leaf of 0.3
    _place_host(o, mi, c)
    counts = o.counts.numpy().copy()
    old_lo, old_hi = _boxes(o)
    o.adapt()
    assert o.leaf_count == 8 and o.stats()["collapses"] == 1
    prev = o.prev_leaf.numpy()
    lo, hi = _boxes(o)
    child = o.host_lookup(np.array([[0.3, 0.3, 0.3]]), previous=True)[0]
    col = int(o.lookup(_pts(mi, [[0.3, 0.3, 0.3]])).numpy()[0])
    # a collapsed node maps to the former child with the largest count (Sec. 6.2 populate)
    inside_col = np.nonzero(_inside(old_lo, old_hi, lo[col], hi[col]))[0]
    assert len(inside_col) == 8 and prev[col] == child and counts[child] == counts[inside_col].max()
    others = np.arange(8) != col
    assert np.all(_inside(lo[others], hi[others], old_lo[prev[others]], old_hi[prev[others]]))
    assert np.all(_inside(old_lo[prev[col]], old_hi[prev[col]], lo[col], hi[col]))
    # counts reset every frame
    assert o.counts.numpy().sum() == 0


def test_max_depth_bounds_splitting(oct_mod):
    from dyngi.backend import mi
    o = oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], split_threshold=10, collapse_threshold=5, max_depth=3, adapt="host")
    for _ in range(6):
        _place_host(o, mi, np.full((50, 3), 0.2))
        o.adapt()
    assert o.host_leaves()["depth"].max() == 3


def _refined(oct_mod, mi, frames=6, seed=0):
    o = oct_mod.AdaptiveOctree([-1, 0, -2], [3, 2, 2], split_threshold=200, collapse_threshold=80, adapt="host")
    rng = np.random.default_rng(seed)
    for f in range(frames):
        # a surface-like cloud (a tilted plane) plus a dense blob: uneven refinement, levels 1..6
        u = rng.random((6000, 2))
        P = np.c_[-1 + 4 * u[:, 0], 0.3 + 0.5 * u[:, 0] + 0.2 * u[:, 1], -2 + 4 * u[:, 1]]
        B = np.array([2.1, 1.3, 0.7]) + 0.05 * rng.standard_normal((3000, 3))
        _place_host(o, mi, np.vstack([P, B]))
        o.adapt()
    return o


def test_lookup_matches_brute_force(oct_mod):
    from dyngi.backend import mi
    o = _refined(oct_mod, mi)
    assert o.leaf_count > 100 and len(np.unique(o.host_leaves()["depth"])) >= 4
    rng = np.random.default_rng(5)
    P = np.vstack([rng.random((30000, 3)) * [4.4, 2.4, 4.4] - [1.2, 0.2, 2.2],     # incl. outside: clamped
                   np.array([2.1, 1.3, 0.7]) + 0.05 * rng.standard_normal((5000, 3))])
    ref = o.host_lookup(P)
    assert np.all(ref >= 0)
    got = o.lookup(_pts(mi, P)).numpy()
    assert np.array_equal(got, ref)
    # geometric check of the brute force itself for points inside the bounds
    lo, hi = _boxes(o)
    ins = np.all((P > o.bounds_min + 1e-4) & (P < o.bounds_max - 1e-4), 1)
    assert np.all(np.all((P[ins] >= lo[ref[ins]] - 1e-5) & (P[ins] <= hi[ref[ins]] + 1e-5), 1))
    # combined traversal (Sec. 6.3): both leaves equal the separate lookups, for identical and moved points
    Q = P + rng.normal(0, 0.02, P.shape) * (rng.random((len(P), 1)) < 0.5)
    la, lb = o.lookup_pair(_pts(mi, P), _pts(mi, Q))
    assert np.array_equal(la.numpy(), ref) and np.array_equal(lb.numpy(), o.host_lookup(Q))
    # inactive lanes
    act = mi.Bool(np.arange(len(P)) % 2 == 0)
    got = o.lookup(_pts(mi, P), act).numpy()
    assert np.all(got[1::2] == oct_mod.INVALID) and np.array_equal(got[::2], ref[::2])


def test_neighbours(oct_mod):
    from dyngi.backend import mi
    o = _refined(oct_mod, mi)
    L = o.leaf_count
    nb = o.neighbours.numpy().reshape(L, 6).astype(np.int64)
    h = o.host_leaves()
    lo, hi, d = h["lo"], h["lo"] + h["size"], h["depth"]
    size = h["size"]
    INV = oct_mod.INVALID
    opp = [1, 0, 3, 2, 5, 4]
    n_equal = n_coarse = 0
    for f in range(6):
        ax, sgn = f // 2, (1 if f % 2 else -1)
        # brute force: the leaf containing the point just across the face centre
        c = lo + 0.5 * size
        c[:, ax] = (hi[:, ax] + 0.25 * size[:, ax]) if sgn > 0 else (lo[:, ax] - 0.25 * size[:, ax])
        outside = (c[:, ax] < o.bounds_min[ax]) | (c[:, ax] > o.bounds_max[ax])
        bf = o.host_lookup(c)
        expect = np.where(outside | (d[bf] > d), INV, bf)
        assert np.array_equal(nb[:, f], expect), f"face {f}"
        ok = nb[:, f] != INV
        j = nb[ok, f]
        i = np.nonzero(ok)[0]
        # face-adjacent: touching along the axis, overlapping in the other two
        face_i = hi[i, ax] if sgn > 0 else lo[i, ax]
        face_j = lo[j, ax] if sgn > 0 else hi[j, ax]
        assert np.allclose(face_i, face_j, atol=1e-5)
        for o_ax in {0, 1, 2} - {ax}:
            assert np.all((lo[i, o_ax] >= lo[j, o_ax] - 1e-6) & (hi[i, o_ax] <= hi[j, o_ax] + 1e-6))
        # symmetric between equal levels; the coarse side ignores its finer neighbours (Sec. 6.2)
        eq = d[j] == d[i]
        assert np.all(nb[j[eq], opp[f]] == i[eq])
        assert np.all(d[j[~eq]] < d[i[~eq]]) and np.all(nb[j[~eq], opp[f]] == INV)
        n_equal += int(eq.sum())
        n_coarse += int((~eq).sum())
    assert n_equal > 0 and n_coarse > 0


def test_prev_leaf_over_frames_and_reserve(oct_mod):
    """Over many adaptive frames every new leaf nests with its prev_leaf; reserve() hands out unique slots."""
    from dyngi.backend import dr, mi
    o = oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], split_threshold=150, collapse_threshold=60, adapt="host")
    rng = np.random.default_rng(11)
    seen_split = seen_coll = False
    for f in range(14):
        centre = np.array([0.2 + 0.045 * f, 0.5, 0.5])
        P = centre + 0.04 * rng.standard_normal((4000, 3))
        _place_host(o, mi, P)
        leaf = o.lookup(_pts(mi, P))
        dr.eval(leaf)
        slot, fits = o.reserve(leaf)
        dr.eval(slot, fits)
        slot, fits, leaf_np = slot.numpy(), fits.numpy(), leaf.numpy()
        off, cap = o.sample_offset.numpy(), o.sample_capacity.numpy()
        s = slot[fits]
        assert len(np.unique(s)) == len(s) and np.all(s < o.sample_total)
        assert np.all((s >= off[leaf_np[fits]]) & (s < off[leaf_np[fits]] + cap[leaf_np[fits]]))
        # a leaf's reservations succeed up to its capacity
        n_per = np.bincount(leaf_np, minlength=o.leaf_count)
        assert np.array_equal(np.bincount(leaf_np[fits], minlength=o.leaf_count), np.minimum(n_per, cap))
        old_lo, old_hi = _boxes(o)
        o.adapt()
        st = o.stats()
        seen_split |= st["splits"] > 0
        seen_coll |= st["collapses"] > 0
        prev = o.prev_leaf.numpy()
        assert len(prev) == o.leaf_count and np.all(prev < len(old_lo))
        lo, hi = _boxes(o)
        nest = _inside(lo, hi, old_lo[prev], old_hi[prev]) | _inside(old_lo[prev], old_hi[prev], lo, hi)
        assert np.all(nest)
        dr.eval()
    assert seen_split and seen_coll


def test_device_topology_matches_host_fast_path(oct_mod):
    """adapt="device" (pool slots as leaf indices) and adapt="host" (dense NumPy) make, frame by frame, the
    same leaf cells, the same lookups, correspondences (prev_leaf) and face neighbours, up to the numbering;
    the frames split and collapse, so freed blocks are reused."""
    from dyngi.backend import mi
    I = oct_mod.INVALID
    H = oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], 150, 60, max_depth=6, adapt="host")
    D = oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], 150, 60, max_depth=6, node_blocks=64)
    rng = np.random.default_rng(1)

    def slot_of(hh, hd):        # host leaf index -> device slot, by cell
        slots = np.nonzero(hd["leaf"])[0]
        key = {(int(hd["depth"][s]), *map(int, hd["ijk"][s])): s for s in slots}
        assert len(key) == len(hh["depth"])
        return np.array([key[(int(d), *map(int, c))] for d, c in zip(hh["depth"], hh["ijk"])])

    splits = collapses = 0
    for f in range(10):
        P = np.array([0.2 + 0.06 * f, 0.5, 0.5]) + 0.05 * rng.standard_normal((4000 if f % 4 != 3 else 40, 3))
        for o in (H, D):
            o.place(_pts(mi, P))
            o.adapt()
        m = slot_of(H.host_leaves(), D.host_leaves())
        mp = slot_of(H.host_leaves(True), D.host_leaves(True))
        Q = rng.random((2000, 3))
        assert np.array_equal(m[H.lookup(_pts(mi, Q)).numpy()], D.lookup(_pts(mi, Q)).numpy())
        assert np.array_equal(D.host_lookup(Q), D.lookup(_pts(mi, Q)).numpy())
        pd = D.prev_leaf.numpy()
        assert np.array_equal(mp[H.prev_leaf.numpy()], pd[m]) and np.all(np.delete(pd, m) == I)
        nh, nd = H.neighbours.numpy().reshape(-1, 6), D.neighbours.numpy().reshape(-1, 6)
        assert np.array_equal(np.where(nh == I, I, m[np.minimum(nh, len(m) - 1)]), nd[m])
        sh, sd = H.stats(), D.stats()
        assert (sh["leaves"], sh["splits"], sh["collapses"]) == (sd["leaves"], sd["splits"], sd["collapses"])
        splits, collapses = splits + sd["splits"], collapses + sd["collapses"]
    assert splits > 20 and collapses > 10
    lo = np.stack([D.leaf_lo.x.numpy(), D.leaf_lo.y.numpy(), D.leaf_lo.z.numpy()], 1)[m]
    assert np.allclose(lo, H.host_leaves()["lo"], atol=1e-6)


def test_steady_state_compiles_nothing(oct_mod, monkeypatch):
    """place/lookup_pair/adapt with a tree whose size changes every frame compile no new kernels, and the
    default (device) adapt() makes no host transfer (the module's transfers, counted, happen in stats())."""
    from dyngi.backend import dr, mi
    from dyngi.sampling.rng import make_sampler
    o = oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], split_threshold=300, collapse_threshold=100)
    assert o.adapt_mode == "device"
    reads = []
    real = oct_mod._to_host
    monkeypatch.setattr(oct_mod, "_to_host", lambda x: reads.append(1) or real(x))
    sizes = set()

    def step(f):
        # points drawn on the device (opaque per-frame seed), so that no input alignment differs per frame
        smp = make_sampler(5000, 7, f)
        c = 0.5 + 0.3 * dr.sin(dr.opaque(mi.Float, float(f)))
        x, y, z = (0.1 * (smp.next_1d() - 0.5) for _ in range(3))
        p = mi.Point3f(c + x, 0.5 + y, 0.5 + z)
        la, lb = o.lookup_pair(p, p)
        o.place_leaf(lb)
        dr.eval(la, o.counts)
        n = len(reads)
        o.adapt()
        assert len(reads) == n
        sizes.add(o.stats()["leaves"])

    assert_steady_state_compiles_nothing(step, frames=8, warmup=2, nonempty=True)
    assert len(sizes) >= 3        # the tree really changed size while nothing recompiled


def test_thresholds_and_bad_input(oct_mod):
    from dyngi.errors import DyngiError
    assert oct_mod.scaled_thresholds(2 * 1920 * 1080) == (4096, 2048)
    assert oct_mod.scaled_thresholds(2 * 160 * 90) == (512, 256)
    assert oct_mod.scaled_thresholds(2 * 3840 * 2160) == (16384, 8192)
    # nee-pt's rule: the paper's 4096 / 2048 wherever the frame records 8 x 4096 samples, scaled below (ours)
    assert oct_mod.paper_thresholds(2 * 320 * 180) == (4096, 2048)
    assert oct_mod.paper_thresholds(oct_mod.PAPER_MIN_RECORDS) == (4096, 2048)
    assert oct_mod.paper_thresholds(2 * 64 * 36) == (576, 288)
    assert oct_mod.paper_thresholds(2 * 64 * 36, scaling=False) == (4096, 2048)
    assert oct_mod.paper_thresholds(10) == (oct_mod.MIN_SCALED_SPLIT, oct_mod.MIN_SCALED_SPLIT // 2)
    o = oct_mod.make_octree(([0, 0, 0], [1, 1, 1]), 2 * 320 * 180, rule="paper")
    assert (o.split_threshold, o.collapse_threshold) == (4096, 2048)
    with pytest.raises(DyngiError, match="valid choices"):
        oct_mod.make_octree(([0, 0, 0], [1, 1, 1]), 100, rule="nope")
    with pytest.raises(DyngiError, match="collapse_threshold"):
        oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], split_threshold=10, collapse_threshold=10)
    with pytest.raises(DyngiError, match="bounds"):
        oct_mod.AdaptiveOctree([0, 0, 0], [1, 0, 1])
    with pytest.raises(DyngiError, match="max_depth"):
        oct_mod.AdaptiveOctree([0, 0, 0], [1, 1, 1], max_depth=40)



@pytest.mark.parametrize("spec, res, want, adapts", [
    ("path:lights=vlc:directions=cdq", (64, 36), [(576, 288), (576, 288)], True),
    ("path:lights=vlc:leaf_scaling=false", (64, 36), [(4096, 2048), None], False),
    ("restir-pt:lights=vlc:candidates=2:spatial=0", (64, 36), [(576, 288), None], True),
    ("restir-pt:directions=cdq:candidates=2:spatial=0:leaf_samples=1000", (32, 18), [None, (1000, 500)], False)])
def test_path_and_restir_pt_use_nee_pts_threshold_rule(oct_mod, spec, res, want, adapts):
    """path and restir-pt build their strategies' octrees with nee-pt's rule (:func:`paper_thresholds` for 2
    placed vertices per pixel and spp: 576 / 288 at 64x36; leaf_scaling=false: the paper's at every
    resolution; leaf_samples raises the split threshold), one octree per strategy, and adapt them (at 576
    records per leaf the octrees of a 64x36 frame split)."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    sc = load_scene("warehouse-rooms")
    tech = create_technique(spec, sc)
    for i in range(3):
        sc.at(0.0)
        tech.step(Frame(i, 0.0, sc.camera(0.0), res, seed=i))
    assert [None if o is None else (o.split_threshold, o.collapse_threshold) for o in tech.octrees] == want
    leaves = [o.stats()["leaves"] for o in tech.octrees if o is not None]
    assert all(n > 8 for n in leaves) or not adapts, leaves
    assert oct_mod.octree_rule(True) == "paper" and oct_mod.octree_rule(False) == "paper-only"
