"""Temporal sample-adaptive world-space octree (Dittebrandt et al., Sec. 6).

Each leaf is a region that owns per-region estimators (the VLC of Sec. 4, the CDQ
of Sec. 5). The tree adapts once per frame to the number of samples each leaf
received in that frame (Sec. 6.2): a leaf *splits* when its count exceeds the
upper threshold, an inner node whose eight children are all leaves *collapses*
when their combined count falls below the lower threshold. Initially the tree is
split once (8 leaves, Sec. 7.2: "we cannot represent a single leaf node"); the
root never collapses.

Frame protocol
--------------
* during the frame: ``lookup(p)`` / ``lookup_pair(p_sample, p_place)`` give leaf
  indices of the *current* tree, ``place(p)`` counts a sample at ``p`` (a device
  ``scatter_reduce``; counts stay on the device);
* ``adapt()`` at the end of the frame runs the four steps of Sec. 6.2 (Fig. 7):
  **mark** (split/collapse decisions from the counts), **rebuild** (the new
  topology), **augment** (parent links of nodes; per leaf: face neighbours and
  the correspondence ``prev_leaf`` to the tree the frame used), **allocate**
  (per-leaf sample-buffer offsets/capacities from the observed counts). The tree
  the frame used becomes the *previous* tree (``lookup_prev``); counts reset.

CPU fast path (documented): the topology update runs in NumPy on the host; the
per-leaf counts are read back once per frame inside ``adapt()`` (one host round
trip of ``leaf_count`` integers) and the new node/leaf arrays are uploaded once.
The trees hold thousands of nodes, so this costs well under a millisecond of
NumPy; all per-sample work (traversal, counting) is Dr.Jit on the device.

Memory layout (our choice, a simplification of Fig. 6): one node buffer
``nodes`` (UInt32) in breadth-first order; an inner node stores the index of its
first child (the 8 children are contiguous, in octant order x | y<<1 | z<<2),
a leaf stores ``LEAF_BIT | leaf_index``. Leaves are numbered densely 0..L-1 (in
breadth-first order) instead of implicitly by parent index, so per-leaf arrays
(VLC caches, CDQ bit fields) have no holes.

Traversal works on the normalised position q = (p - bounds_min) / extent in
[0, 1)^3: each level doubles q and subtracts the octant bit, which is exact in
floating point, so the device traversal and a NumPy brute force
(``floor(q * 2**depth)``) agree bit for bit. Points outside the bounds are
clamped into the boundary leaves (our choice: a lookup never fails).

Thresholds: the paper uses 4096 (split) / 2048 (collapse) at 1080p (Sec. 7). At
our resolutions :func:`scaled_thresholds` scales them by the number of path
vertices placed per frame relative to 1080p with two placed vertices per path
(primary and secondary hit), but never below 512 / 256 samples per leaf so that
a leaf's VLC stays meaningful (issue 17 item 2). Splits are limited to
``max_depth`` levels (our choice, default 12: a leaf of a 40 m scene is then
~1 cm; protects against all samples landing at one point).

Neighbours (Sec. 6.2, augment): for each leaf and face (-x,+x,-y,+y,-z,+z) the
leaf that contains the cell of the same size across that face, if that leaf is
of the same size or coarser; ``INVALID`` outside the bounds and where the other
side is finer (unboundedly many neighbours: "we currently ignore this case",
Sec. 6.2). Hence the relation is symmetric between leaves of equal depth, and a
fine leaf links to its coarser neighbour while the coarse one has ``INVALID``
on that side.

Correspondence ``prev_leaf`` (Sec. 6.2, populate): an unchanged leaf maps to
itself in the previous tree, a split child to its former (parent) leaf, a
collapsed node to the former child with the largest observed sample count
(the paper's choice; ties -> the lowest index).
"""
from __future__ import annotations

import time

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError

INVALID = 0xFFFFFFFF
LEAF_BIT = 0x80000000
MAX_DEPTH_LIMIT = 16          # 3 * 16 coordinate bits + depth fit the int64 keys below
PAPER_SPLIT, PAPER_COLLAPSE = 4096, 2048          # Sec. 7, at 1080p
PAPER_VERTICES = 2 * 1920 * 1080                   # samples placed per frame at 1080p (primary + secondary hit)
MIN_SPLIT, MIN_COLLAPSE = 512, 256                 # issue 17 item 2: floor per leaf
_ONE_MINUS = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
_FACES = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], np.int64)


def scaled_thresholds(vertices_per_frame: int) -> tuple[int, int]:
    """(split, collapse) thresholds for ``vertices_per_frame`` placed samples per frame.

    The paper's 4096 / 2048 at 1080p (Sec. 7; 2 placed vertices per path there)
    scaled by ``vertices_per_frame / (2 * 1920 * 1080)``, floored at 512 / 256
    (issue 17 item 2: fewer samples per leaf make a meaningless VLC).
    """
    s = float(vertices_per_frame) / PAPER_VERTICES
    return max(MIN_SPLIT, int(round(PAPER_SPLIT * s))), max(MIN_COLLAPSE, int(round(PAPER_COLLAPSE * s)))


def _pack(depth, ix, iy, iz):
    """Unique int64 key of the cell (depth, ix, iy, iz)."""
    depth = np.asarray(depth, np.int64)
    ix, iy, iz = (np.asarray(a, np.int64) for a in (ix, iy, iz))
    return (depth << 48) | (ix << 32) | (iy << 16) | iz


class _Tree:
    """Host topology of one tree (arrays over leaves in leaf-index order, and the node buffer)."""

    __slots__ = ("depth", "ijk", "keys", "order", "nodes", "node_parent", "node_depth")

    def __init__(self, depth: np.ndarray, ijk: np.ndarray):
        self.depth = depth.astype(np.int64)
        self.ijk = ijk.astype(np.int64)
        self.keys = _pack(self.depth, *self.ijk.T)
        self.order = np.argsort(self.keys)     # for searchsorted lookups by key
        self.nodes = None
        self.node_parent = None
        self.node_depth = None

    @property
    def count(self) -> int:
        return len(self.depth)

    def find(self, keys: np.ndarray) -> np.ndarray:
        """Leaf index of each key, -1 where the key is not a leaf."""
        sk = self.keys[self.order]
        pos = np.clip(np.searchsorted(sk, keys), 0, len(sk) - 1)
        hit = sk[pos] == keys
        return np.where(hit, self.order[pos], -1)


def _build_nodes(depth: np.ndarray, ijk: np.ndarray):
    """Rebuild step (Fig. 7 c): breadth-first node buffer from a complete leaf set.

    Returns (nodes, node_parent, node_depth, leaf_perm): ``leaf_perm[k]`` is the
    input row of the k-th leaf in breadth-first order (the new leaf numbering).
    """
    maxd = int(depth.max())
    leaf_keys = _pack(depth, *ijk.T)
    # inner cells per level: all proper ancestors of the leaves
    inner = []
    for d in range(maxd):
        sel = depth > d
        sh = (depth[sel] - d)[:, None]
        a = ijk[sel] >> sh
        inner.append(np.unique(_pack(np.full(len(a), d), *a.T)))
    nodes, parent, ndepth, perm = [], [], [], []
    level = np.zeros((1, 3), np.int64)          # the root cell
    level_parent = np.array([INVALID], np.int64)
    start = 0
    sort_leaf = np.argsort(leaf_keys)
    sorted_leaf = leaf_keys[sort_leaf]
    leaf_counter = 0
    for d in range(maxd + 1):
        keys = _pack(np.full(len(level), d), *level.T)
        is_inner = np.isin(keys, inner[d]) if d < maxd else np.zeros(len(level), bool)
        n = len(level)
        code = np.zeros(n, np.int64)
        n_in = int(is_inner.sum())
        nxt = start + n
        code[is_inner] = nxt + 8 * np.arange(n_in)
        lv = ~is_inner
        n_lv = int(lv.sum())
        code[lv] = LEAF_BIT | (leaf_counter + np.arange(n_lv))
        pos = np.searchsorted(sorted_leaf, keys[lv])
        if n_lv and not np.all(sorted_leaf[np.minimum(pos, len(sorted_leaf) - 1)] == keys[lv]):
            raise DyngiError("octree: leaf set is not a complete octree (internal error)")
        perm.append(sort_leaf[pos])
        leaf_counter += n_lv
        nodes.append(code)
        parent.append(level_parent)
        ndepth.append(np.full(n, d))
        # next level: 8 children of each inner node, octant order x | y<<1 | z<<2
        oct_ = np.arange(8)
        offs = np.stack([oct_ & 1, (oct_ >> 1) & 1, (oct_ >> 2) & 1], 1)
        level = (2 * level[is_inner][:, None, :] + offs[None]).reshape(-1, 3)
        level_parent = np.repeat(start + np.nonzero(is_inner)[0], 8)
        start = nxt
        if not len(level):
            break
    return (np.concatenate(nodes), np.concatenate(parent), np.concatenate(ndepth), np.concatenate(perm))


class AdaptiveOctree:
    """World-space octree over [bounds_min, bounds_max) whose leaves adapt to per-frame sample counts.

    Parameters
    ----------
    bounds_min, bounds_max : 3-vectors   the scene bounds (slightly enlarged, our choice, so that
                                         surfaces on the boundary fall inside)
    split_threshold : int = 512          a leaf with more samples in a frame splits (paper 4096 at 1080p)
    collapse_threshold : int = 256       8 sibling leaves with fewer samples in total collapse (paper 2048)
    max_depth : int = 12                 deepest level a leaf may reach (our choice)
    capacity_slack : float = 1.5         allocate: per-leaf sample capacity = slack x expected count (our choice)
    min_capacity : int = 64              allocate: at least this many sample slots per leaf (our choice)
    """

    def __init__(self, bounds_min, bounds_max, split_threshold=MIN_SPLIT, collapse_threshold=MIN_COLLAPSE,
                 max_depth: int = 12, capacity_slack: float = 1.5, min_capacity: int = 64, **_ignored):
        lo = np.asarray(bounds_min, np.float64).reshape(3)
        hi = np.asarray(bounds_max, np.float64).reshape(3)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise DyngiError(f"octree: bounds must be finite with max > min, got {lo.tolist()} .. {hi.tolist()}")
        split_threshold, collapse_threshold = int(split_threshold), int(collapse_threshold)
        if collapse_threshold < 0 or split_threshold <= collapse_threshold:
            raise DyngiError(f"octree: need 0 <= collapse_threshold < split_threshold, got "
                             f"{collapse_threshold} / {split_threshold}")
        if not 1 <= int(max_depth) <= MAX_DEPTH_LIMIT:
            raise DyngiError(f"octree: max_depth must be in 1..{MAX_DEPTH_LIMIT}, got {max_depth}")
        # enlarge by a relative epsilon so the scene's own bounding surfaces are strictly inside
        pad = 1e-4 * (hi - lo) + 1e-5
        self.bounds_min = (lo - pad).astype(np.float32)
        self.bounds_max = (hi + pad).astype(np.float32)
        ext = self.bounds_max.astype(np.float64) - self.bounds_min.astype(np.float64)
        self.inv_extent = (1.0 / ext).astype(np.float32)
        self.split_threshold = split_threshold
        self.collapse_threshold = collapse_threshold
        self.max_depth = int(max_depth)
        self.capacity_slack = float(capacity_slack)
        self.min_capacity = int(min_capacity)
        self._bmin = mi.Point3f(*[float(v) for v in self.bounds_min])
        self._inv = mi.Vector3f(*[float(v) for v in self.inv_extent])
        self.frame = 0
        self.splits = self.collapses = 0
        self.adapt_ms = 0.0
        self.count_ms = 0.0
        self.placed_last = 0
        # -- initial tree: split once (8 leaves), empty caches --
        oct_ = np.arange(8)
        ijk = np.stack([oct_ & 1, (oct_ >> 1) & 1, (oct_ >> 2) & 1], 1)
        tree, _ = self._finish(np.ones(8, np.int64), ijk)
        self._tree = tree
        self._prev_tree = tree
        ident = np.arange(tree.count, dtype=np.int64)
        self._upload(tree, prev_leaf=ident, expected=np.zeros(tree.count))
        self._prev_nodes = self._nodes
        self.prev_leaf_count = tree.count

    # ------------------------------------------------------------------ host helpers
    def _finish(self, depth, ijk):
        """Rebuild + the node part of augment: node buffer, parents, leaves in breadth-first order."""
        nodes, parent, ndepth, perm = _build_nodes(depth, ijk)
        tree = _Tree(depth[perm], ijk[perm])
        tree.nodes, tree.node_parent, tree.node_depth = nodes, parent, ndepth
        return tree, perm

    def _neighbours(self, tree: _Tree) -> np.ndarray:
        """Augment (leaves): 6 face neighbours per leaf, same size or coarser, INVALID otherwise."""
        L = tree.count
        d = np.repeat(tree.depth, 6)
        c = (tree.ijk[:, None, :] + _FACES[None]).reshape(-1, 3)
        inside = np.all((c >= 0) & (c < (np.int64(1) << d)[:, None]), 1)
        out = np.full(6 * L, -1, np.int64)
        todo = inside.copy()
        for up in range(0, self.max_depth + 1):     # same depth first, then coarser; the root is never a leaf
            idx = np.nonzero(todo & (d - up >= 1))[0]
            if not len(idx):
                break
            hit = self._tree_find(tree, d[idx] - up, c[idx] >> up)
            found = hit >= 0
            out[idx[found]] = hit[found]
            todo[idx[found]] = False
        # what is left has a finer neighbour side: ignored (Sec. 6.2)
        return np.where(out >= 0, out, INVALID).astype(np.uint32)

    @staticmethod
    def _tree_find(tree, depth, ijk):
        return tree.find(_pack(depth, *ijk.T))

    def _upload(self, tree: _Tree, prev_leaf: np.ndarray, expected: np.ndarray) -> None:
        """Upload the device arrays of ``tree`` (augment + allocate results)."""
        L = tree.count
        self.leaf_count = L
        self._nodes = mi.UInt32(tree.nodes.astype(np.uint32))
        self.prev_leaf = mi.UInt32(prev_leaf.astype(np.uint32))
        self._host_neighbours = self._neighbours(tree)
        self.neighbours = mi.UInt32(self._host_neighbours)
        ext = (self.bounds_max.astype(np.float64) - self.bounds_min.astype(np.float64))
        size = ext[None, :] / (2.0 ** tree.depth)[:, None]
        lo = self.bounds_min[None, :].astype(np.float64) + tree.ijk * size
        self.leaf_lo = mi.Point3f(*[mi.Float(lo[:, k].astype(np.float32)) for k in range(3)])
        self.leaf_size = mi.Vector3f(*[mi.Float(size[:, k].astype(np.float32)) for k in range(3)])
        self.leaf_depth = mi.UInt32(tree.depth.astype(np.uint32))
        self.node_parent = mi.UInt32(tree.node_parent.astype(np.uint32))
        # -- allocate (Fig. 7 e): sample-buffer slots from the observed counts --
        cap = np.maximum(np.ceil(self.capacity_slack * np.asarray(expected, np.float64)), self.min_capacity)
        cap = cap.astype(np.int64)
        off = np.concatenate([[0], np.cumsum(cap)])
        self.sample_offset = mi.UInt32(off[:-1].astype(np.uint32))
        self.sample_capacity = mi.UInt32(cap.astype(np.uint32))
        self.sample_total = int(off[-1])
        self.sample_size = dr.zeros(mi.UInt32, L)
        self.counts = dr.zeros(mi.UInt32, L)
        dr.eval(self._nodes, self.prev_leaf, self.neighbours, self.leaf_lo, self.leaf_size, self.leaf_depth,
                self.node_parent, self.sample_offset, self.sample_capacity, self.sample_size, self.counts)

    # ------------------------------------------------------------------ device traversal (Sec. 6.3)
    def _q(self, p):
        q = (mi.Point3f(p) - self._bmin) * self._inv
        return dr.clip(q, 0.0, _ONE_MINUS)

    @staticmethod
    def _octant(q):
        """One level down: double q, split off the octant bits (exact in floating point)."""
        q = q * 2.0
        bx, by, bz = q.x >= 1.0, q.y >= 1.0, q.z >= 1.0
        q = mi.Vector3f(dr.select(bx, q.x - 1.0, q.x), dr.select(by, q.y - 1.0, q.y), dr.select(bz, q.z - 1.0, q.z))
        octant = mi.UInt32(dr.select(bx, 1, 0) | dr.select(by, 2, 0) | dr.select(bz, 4, 0))
        return q, octant

    def _traverse(self, nodes, p, active):
        q = self._q(p)
        active = mi.Bool(active) & dr.full(mi.Bool, True, dr.width(q))
        code = dr.gather(mi.UInt32, nodes, dr.zeros(mi.UInt32, dr.width(q)), active)

        def cond(q, code, active):
            return active & ((code & LEAF_BIT) == 0)

        def body(q, code, active):
            go = active & ((code & LEAF_BIT) == 0)
            q2, octant = self._octant(q)
            c2 = dr.gather(mi.UInt32, nodes, code + octant, go)
            return dr.select(go, q2, q), dr.select(go, c2, code), active

        q, code, active = dr.while_loop((q, code, active), cond, body, labels=("q", "code", "active"),
                                        label="octree_lookup")
        return dr.select(active, code & ~mi.UInt32(LEAF_BIT), INVALID)

    def lookup(self, p, active=True) -> mi.UInt32:
        """Leaf index of ``p`` in the CURRENT tree (INVALID on inactive lanes)."""
        return self._traverse(self._nodes, p, active)

    def lookup_prev(self, p, active=True) -> mi.UInt32:
        """Leaf index of ``p`` in the PREVIOUS frame's tree (the tree the last frame's samples were placed in)."""
        return self._traverse(self._prev_nodes, p, active)

    def lookup_pair(self, p_sample, p_place, active=True) -> tuple[mi.UInt32, mi.UInt32]:
        """Combined traversal of Sec. 6.3 in the current tree: (leaf of ``p_sample``, leaf of ``p_place``).

        ``p_sample`` is the shading point's previous-frame position (its leaf's
        estimators, carried over by ``prev_leaf``, are used for sampling),
        ``p_place`` its current position (where this frame's samples go). Both
        descend in one loop; while their paths coincide only one node gather is
        made per level, after they diverge each lane gathers its second node too.
        """
        nodes = self._nodes
        qa, qb = self._q(p_sample), self._q(p_place)
        n = dr.width(qa)
        active = mi.Bool(active) & dr.full(mi.Bool, True, n)
        ca = dr.gather(mi.UInt32, nodes, dr.zeros(mi.UInt32, n), active)
        cb = mi.UInt32(ca)
        same = mi.Bool(active)

        def cond(qa, qb, ca, cb, same, active):
            return active & (((ca & LEAF_BIT) == 0) | ((cb & LEAF_BIT) == 0))

        def body(qa, qb, ca, cb, same, active):
            ga = active & ((ca & LEAF_BIT) == 0)
            gb = active & ((cb & LEAF_BIT) == 0)
            qa2, oa = self._octant(qa)
            qb2, ob = self._octant(qb)
            ca2 = dr.gather(mi.UInt32, nodes, ca + oa, ga)
            still = same & ga & gb & (oa == ob)
            cb2 = dr.select(still, ca2, dr.gather(mi.UInt32, nodes, cb + ob, gb & ~still))
            return (dr.select(ga, qa2, qa), dr.select(gb, qb2, qb), dr.select(ga, ca2, ca),
                    dr.select(gb, cb2, cb), still, active)

        qa, qb, ca, cb, same, active = dr.while_loop(
            (qa, qb, ca, cb, same, active), cond, body,
            labels=("qa", "qb", "ca", "cb", "same", "active"), label="octree_lookup_pair")
        mask = ~mi.UInt32(LEAF_BIT)
        return dr.select(active, ca & mask, INVALID), dr.select(active, cb & mask, INVALID)

    # ------------------------------------------------------------------ samples of this frame
    def place(self, p, active=True) -> None:
        """Count samples placed at ``p`` this frame (device scatter_reduce into ``counts``)."""
        self.place_leaf(self.lookup(p, active), active)

    def place_leaf(self, leaf, active=True) -> None:
        """Count samples in already looked-up leaves (``INVALID`` lanes are ignored)."""
        leaf = mi.UInt32(leaf)
        ok = mi.Bool(active) & (leaf != INVALID)
        # ReduceMode.Local: the LLVM default for small targets (Expand) bakes the target size (the leaf
        # count, which changes every frame) into the kernel and would recompile every frame
        dr.scatter_reduce(dr.ReduceOp.Add, self.counts, mi.UInt32(1), leaf, ok, mode=dr.ReduceMode.Local)

    def reserve(self, leaf, active=True) -> tuple[mi.UInt32, mi.Bool]:
        """Allocate one sample slot in ``leaf``'s buffer region (Fig. 7 e): (global slot, fits).

        Slots are ``sample_offset[leaf] + k`` for the k-th reservation of the
        frame (``dr.scatter_inc`` on ``sample_size``); ``fits`` is False once
        the leaf's ``sample_capacity`` is used up (the sample is then dropped,
        as the paper bounds the samples per region). Buffers of
        ``sample_total`` entries hold all leaves' samples. As with any
        ``dr.scatter_inc``, evaluate ``leaf`` before and use the returned slot
        in the same kernel (or ``dr.eval`` it at once).
        """
        leaf = mi.UInt32(leaf)
        ok = mi.Bool(active) & (leaf != INVALID)
        k = dr.scatter_inc(self.sample_size, leaf, ok)
        cap = dr.gather(mi.UInt32, self.sample_capacity, leaf, ok)
        off = dr.gather(mi.UInt32, self.sample_offset, leaf, ok)
        fits = ok & (k < cap)
        return dr.select(fits, off + k, INVALID), fits

    # ------------------------------------------------------------------ adaptation (Sec. 6.2)
    def adapt(self) -> None:
        """End of frame: mark, rebuild, augment, allocate (Fig. 7); then counts reset."""
        t0 = time.perf_counter()
        dr.eval(self.counts)
        dr.sync_thread()                 # pending place() kernels are the frame's cost, not the adaptation's
        t1 = time.perf_counter()
        self.count_ms = 1e3 * (t1 - t0)
        counts = np.asarray(self.counts.numpy(), np.int64)   # the one host round trip per frame
        self._prev_nodes = self._nodes
        self.prev_leaf_count = self.leaf_count
        old = self._tree
        depth, ijk = old.depth, old.ijk
        # -- mark --
        split = (counts > self.split_threshold) & (depth < self.max_depth)
        pd = depth - 1
        pkey = _pack(pd, *(ijk >> 1).T)
        uk, inv, nsib = np.unique(pkey, return_inverse=True, return_counts=True)
        psum = np.bincount(inv, weights=counts, minlength=len(uk))
        pdepth = (uk >> 48)
        coll_group = (nsib == 8) & (psum < self.collapse_threshold) & (pdepth >= 1)
        collapse = coll_group[inv]          # never a split leaf: its count > split > collapse threshold
        keep = ~split & ~collapse
        # -- rebuild: new leaf set, with its correspondence and expected counts --
        n_split = int(split.sum())
        oct_ = np.arange(8)
        offs = np.stack([oct_ & 1, (oct_ >> 1) & 1, (oct_ >> 2) & 1], 1)
        s_idx = np.nonzero(split)[0]
        ch_ijk = (2 * ijk[s_idx][:, None, :] + offs[None]).reshape(-1, 3)
        ch_depth = np.repeat(depth[s_idx] + 1, 8)
        ch_prev = np.repeat(s_idx, 8)
        ch_exp = np.repeat(counts[s_idx] / 8.0, 8)
        g_idx = np.nonzero(coll_group)[0]
        c_idx = np.nonzero(collapse)[0]
        # the former child with the largest count (ties: lowest index) per collapsed group
        order = np.lexsort((c_idx, -counts[c_idx], inv[c_idx]))
        grp_of = inv[c_idx][order]
        first = np.ones(len(order), bool)
        first[1:] = grp_of[1:] != grp_of[:-1]
        best_child = c_idx[order][first]                      # one per group, in group order
        g_sorted = grp_of[first]
        co_ijk = ijk[best_child] >> 1
        co_depth = depth[best_child] - 1
        co_exp = psum[g_sorted]
        k_idx = np.nonzero(keep)[0]
        new_depth = np.concatenate([depth[k_idx], ch_depth, co_depth])
        new_ijk = np.concatenate([ijk[k_idx], ch_ijk, co_ijk]).reshape(-1, 3)
        new_prev = np.concatenate([k_idx, ch_prev, best_child])
        new_exp = np.concatenate([counts[k_idx], ch_exp, co_exp])
        tree, perm = self._finish(new_depth, new_ijk)
        # -- augment (correspondence, neighbours) + allocate: upload --
        self._prev_tree = old
        self._tree = tree
        self.splits, self.collapses = n_split, int(len(g_idx))
        self.placed_last = int(counts.sum())
        self._last_counts = counts
        self._upload(tree, prev_leaf=new_prev[perm], expected=new_exp[perm])
        self.frame += 1
        self.adapt_ms = 1e3 * (time.perf_counter() - t1)

    # ------------------------------------------------------------------ inspection
    def host_leaves(self, previous: bool = False) -> dict:
        """NumPy view of the leaves: depth, ijk (integer cell coordinates), lo, size (world)."""
        t = self._prev_tree if previous else self._tree
        ext = (self.bounds_max.astype(np.float64) - self.bounds_min.astype(np.float64))
        size = ext[None, :] / (2.0 ** t.depth)[:, None]
        return {"depth": t.depth.copy(), "ijk": t.ijk.copy(), "size": size,
                "lo": self.bounds_min[None, :].astype(np.float64) + t.ijk * size}

    def host_lookup(self, p: np.ndarray, previous: bool = False) -> np.ndarray:
        """NumPy brute force of :meth:`lookup`: the leaf whose integer cell contains q (tests)."""
        t = self._prev_tree if previous else self._tree
        q = (np.asarray(p, np.float32) - self.bounds_min[None, :]) * self.inv_extent[None, :]
        q = np.clip(q, 0.0, np.float32(_ONE_MINUS)).astype(np.float64)
        out = np.full(len(q), -1, np.int64)
        for d in np.unique(t.depth):
            cell = np.floor(q * float(2 ** int(d))).astype(np.int64)
            hit = t.find(_pack(np.full(len(q), d), *cell.T))
            out = np.where((out < 0) & (hit >= 0), hit, out)
        return out

    def stats(self) -> dict:
        return {"leaves": self.leaf_count, "nodes": int(len(self._tree.nodes)), "splits": self.splits,
                "collapses": self.collapses, "adapt_ms": self.adapt_ms, "count_sync_ms": self.count_ms,
                "max_depth": int(self._tree.depth.max()), "placed": self.placed_last, "sample_slots": self.sample_total}
