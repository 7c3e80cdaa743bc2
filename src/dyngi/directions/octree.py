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

Where the topology lives (``adapt``):

* ``"device"`` (default): the tree is a fixed pool of ``1 + 8 * node_blocks``
  node slots on the device and every step of ``adapt()`` is a Dr.Jit kernel over
  the pool (no host read-back, no upload; the host never learns the leaf count).
  A leaf's index is its node slot (our choice: no compaction pass), so
  ``leaf_count`` is the pool size and per-leaf arrays have unused entries (inner
  nodes, free slots: ``prev_leaf`` INVALID, no neighbours, zero capacity). The
  children of a split take a free 8-slot block from a device stack
  (``dr.scatter_inc`` on a pop counter), a collapse pushes its children's block
  back after this frame's splits (no block is reused in the frame it is freed,
  so ``prev_leaf`` of the previous tree stays valid); when the pool is empty a
  leaf does not split (our choice; 511 blocks hold up to 3578 leaves, the
  paper's 1080p with 4096 samples per leaf needs ~1000-2000). Neighbours: a
  depth-limited traversal of the new tree to the cell of the same size across
  each face. Allocation: capacities as below, offsets by an exclusive
  ``dr.prefix_sum``, clipped to a fixed pool of ``sample_total`` slots.
  ``stats()`` reads a few counters back (``report_stats``, inspection only).
* ``"host"``: the CPU fast path: the topology update runs in NumPy on the host;
  the per-leaf counts are read back once per frame inside ``adapt()`` (one host
  round trip of ``leaf_count`` integers) and the new node/leaf arrays are
  uploaded once. Leaves are numbered densely (below).

Both make the same trees, correspondences and neighbours (up to the leaf
numbering; tests/sampling/test_octree.py compares them frame by frame). All
per-sample work (traversal, counting) is Dr.Jit on the device in both.

Memory layout of the host path (our choice, a simplification of Fig. 6): one node buffer
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

Thresholds: the paper uses 4096 (split) / 2048 (collapse) at 1080p (Sec. 7); its collapse
threshold is over 8 siblings, so its leaves hold ~256-4096 records per frame.
:func:`paper_thresholds` (nee-pt) keeps them wherever the frame records at least 8 x 4096
samples and scales them down below that (ours, a marked parameter ``leaf_scaling`` of nee-pt, path and
restir-pt, which choose the rule with :func:`octree_rule`); :func:`scaled_thresholds` (the octrees that
the light and direction strategies build themselves: the probe and VPL techniques' ``lights=vlc``) scales
them by the number of path vertices placed per frame relative to 1080p with two placed vertices per path
(primary and secondary hit), but never below 512 / 256 samples per leaf (issue 17 item 2). Splits are limited to
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
MIN_SPLIT, MIN_COLLAPSE = 512, 256                 # issue 17 item 2: floor per leaf (ours)
"""Floors of :func:`scaled_thresholds` (ours, not the paper's: the paper splits at 4096 and collapses at 2048
samples per leaf, Sec. 7): the rule of the octrees that a light or direction strategy builds itself (the probe
and VPL techniques' ``lights=vlc``); nee-pt, path and restir-pt use :func:`paper_thresholds`."""
_ONE_MINUS = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
ADAPT_CHOICES = ("device", "host")
NODE_BLOCKS = 511                                  # device pool: 1 + 8 * 511 node slots (our choice)
_FACES = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], np.int64)


def _to_host(x) -> np.ndarray:
    """The module's device -> host transfer on the device path (tests count its calls)."""
    return np.asarray(x.numpy())


def scaled_thresholds(vertices_per_frame: int) -> tuple[int, int]:
    """(split, collapse) thresholds for ``vertices_per_frame`` placed samples per frame.

    The paper's 4096 / 2048 at 1080p (Sec. 7; 2 placed vertices per path there)
    scaled by ``vertices_per_frame / (2 * 1920 * 1080)``, floored at 512 / 256
    (issue 17 item 2: fewer samples per leaf make a meaningless VLC).
    """
    s = float(vertices_per_frame) / PAPER_VERTICES
    return max(MIN_SPLIT, int(round(PAPER_SPLIT * s))), max(MIN_COLLAPSE, int(round(PAPER_COLLAPSE * s)))


PAPER_MIN_RECORDS = 8 * PAPER_SPLIT
"""Records per frame from which :func:`paper_thresholds` keeps the paper's 4096 / 2048: the initial split's
8 leaves (Sec. 7.2) can each reach the split threshold (32768 records: ~128x128 pixels at nee-pt's two recording
vertices per path)."""
MIN_SCALED_SPLIT = 64
"""Floor of :func:`paper_thresholds`' scaled split threshold (collapse: half; ours): 8 leaves of a frame of fewer
than 512 records."""


def paper_thresholds(records_per_frame: int, scaling: bool = True) -> tuple[int, int]:
    """(split, collapse) thresholds: the paper's 4096 / 2048 (Sec. 7) wherever the frame records at least
    :data:`PAPER_MIN_RECORDS` samples (the resolution allows them: each of the initial 8 leaves can split);
    below that, with ``scaling`` (ours: ``leaf_scaling`` of nee-pt, path and restir-pt,
    ``Param(ours=True, paper=False)``), scaled down to ``records / 8`` / ``records / 16`` (floored at
    :data:`MIN_SCALED_SPLIT` / half), so that the tree still adapts; without it the paper's thresholds at
    every resolution (a small frame then keeps its 8 initial leaves)."""
    r = max(int(records_per_frame), 1)
    if not scaling or r >= PAPER_MIN_RECORDS:
        return PAPER_SPLIT, PAPER_COLLAPSE
    split = max(MIN_SCALED_SPLIT, r // 8)
    return split, split // 2


def octree_rule(leaf_scaling: bool) -> str:
    """The :func:`make_octree` rule of the ``leaf_scaling`` parameter (nee-pt, path, restir-pt; ours, marked
    ``paper=False``): ``"paper"`` (the paper's thresholds, scaled below :data:`PAPER_MIN_RECORDS`) or
    ``"paper-only"`` (the paper's at every resolution)."""
    return "paper" if leaf_scaling else "paper-only"


def octree_bounds(scene) -> tuple:
    """The box an octree over ``scene`` covers (lo[3], hi[3], float64): ``scene.meta.bounds`` (else the
    Mitsuba scene's bounding box), grown on an axis of (near) zero extent to 1% of the largest extent (a
    flat scene, one plane: the octree needs max > min; our choice). ``scene``: a dyngi Scene or an
    ``mi.Scene``."""
    ms = scene.mi_scene if hasattr(scene, "mi_scene") else scene
    meta = getattr(scene, "meta", None)
    if meta is not None and getattr(meta, "bounds", None) is not None:
        lo, hi = (np.asarray(b, np.float64) for b in meta.bounds)
    else:
        bb = ms.bbox()
        lo, hi = np.array(bb.min, np.float64), np.array(bb.max, np.float64)
    ext = hi - lo
    grow = np.maximum(0.01 * max(float(ext.max()), 1e-3) - ext, 0.0)
    return lo - 0.5 * grow, hi + 0.5 * grow


def make_octree(bounds, vertices_per_frame: int, leaf_samples: int = 0, rule: str = "scaled") -> "AdaptiveOctree":
    """The one construction of the adaptive octree (the VLC's, the CDQ's, nee-pt's shared one): over
    ``bounds`` (:func:`octree_bounds`) with the thresholds of ``rule`` for ``vertices_per_frame`` placed
    vertices (at least 1): ``"scaled"`` (:func:`scaled_thresholds`, an octree a strategy builds itself),
    ``"paper"`` (:func:`paper_thresholds` with scaling below :data:`PAPER_MIN_RECORDS`, the default of nee-pt,
    path and restir-pt) or ``"paper-only"`` (the paper's at every resolution, their ``leaf_scaling=false``;
    :func:`octree_rule`); ``leaf_samples > 0``
    raises the split threshold to that many samples per leaf and the collapse threshold to half of it (the
    ``leaf_samples`` parameter of nee-pt, path and restir-pt)."""
    if rule not in ("scaled", "paper", "paper-only"):
        raise DyngiError(f"octree threshold rule '{rule}' is unknown; valid choices: scaled, paper, paper-only")
    if rule == "scaled":
        split, collapse = scaled_thresholds(max(int(vertices_per_frame), 1))
    else:
        split, collapse = paper_thresholds(vertices_per_frame, scaling=rule == "paper")
    if leaf_samples > 0:
        split, collapse = max(split, int(leaf_samples)), max(collapse, int(leaf_samples) // 2)
    return AdaptiveOctree(bounds[0], bounds[1], split, collapse)


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
    adapt : str = "device"               "device" (state on the device, no read-back) or "host" (NumPy fast path)
    node_blocks : int = 511              device pool size in 8-node blocks (our choice)
    """

    report_stats = True     # device path: stats() reads the leaf/split/collapse counters back (inspection)

    def __init__(self, bounds_min, bounds_max, split_threshold=MIN_SPLIT, collapse_threshold=MIN_COLLAPSE,
                 max_depth: int = 12, capacity_slack: float = 1.5, min_capacity: int = 64, adapt: str = "device",
                 node_blocks: int = NODE_BLOCKS, **_ignored):
        if adapt not in ADAPT_CHOICES:
            raise DyngiError(f"octree: adapt '{adapt}' is unknown; valid choices: {', '.join(ADAPT_CHOICES)}")
        if int(node_blocks) < 2:
            raise DyngiError(f"octree: node_blocks must be >= 2, got {node_blocks}")
        self.device = adapt == "device"
        self.adapt_mode = adapt
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
        if self.device:
            self._init_device(int(node_blocks))
            return
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

    # ------------------------------------------------------------------ device topology (adapt="device")
    def _init_device(self, nb: int) -> None:
        """The initial tree (root + 8 leaves) in a pool of ``1 + 8 nb`` slots; blocks 1.. on the free stack."""
        N = 1 + 8 * nb
        self._N, self._nb = N, nb
        self.leaf_count = self.prev_leaf_count = N
        idx = np.arange(N, dtype=np.int64)
        code = (LEAF_BIT | idx).astype(np.uint32)
        code[0] = 1                                   # the root's children: block 0 = slots 1..8
        alive = idx <= 8
        depth = np.where((idx >= 1) & (idx <= 8), 1, 0).astype(np.uint32)
        k = np.clip(idx - 1, 0, 7)
        ijk = np.where(((idx >= 1) & (idx <= 8))[:, None], np.stack([k & 1, (k >> 1) & 1, (k >> 2) & 1], 1), 0)
        parent = np.where((idx >= 1) & (idx <= 8), 0, INVALID).astype(np.uint32)
        self._nodes = mi.UInt32(code)
        self._alive = mi.Bool(alive)
        self._depth = mi.UInt32(depth)
        self._ijk = [mi.UInt32(ijk[:, a].astype(np.uint32)) for a in range(3)]
        self.node_parent = mi.UInt32(parent)
        # free stack: blocks nb-1 .. 1 (the top, popped first, is block 1)
        self._free = mi.UInt32(np.concatenate([np.arange(nb - 1, 0, -1), [0]]).astype(np.uint32))
        self._top = mi.UInt32(np.array([nb - 1, 0], np.uint32))        # 2 entries: never a kernel literal
        self._split_d = dr.opaque(mi.UInt32, self.split_threshold)
        self._coll_d = dr.opaque(mi.UInt32, self.collapse_threshold)
        # fixed pool of sample slots (our choice): room for 1024 leaves at the split threshold
        self.sample_total = min(int(np.ceil(self.capacity_slack * self.split_threshold)) * 1024, 1 << 28)
        prev = np.where(alive & ((code & LEAF_BIT) != 0), idx, INVALID).astype(np.uint32)
        self.prev_leaf = mi.UInt32(prev)
        self._prev_nodes = self._nodes
        self._prev_state = (self._nodes, self._alive, self._depth, self._ijk)
        self._counters = [mi.UInt32(np.array([v, 0], np.uint32)) for v in (8, 0, 0, 1, 0)]
        self._derive(dr.zeros(mi.Float, N))

    def _derive(self, expected) -> None:
        """Augment (neighbours, leaf boxes) + allocate for the device tree; counts reset."""
        N = self._N
        leaf = self._alive & ((self._nodes & LEAF_BIT) != 0)
        # -- leaf boxes (world) --
        ext = self.bounds_max.astype(np.float64) - self.bounds_min.astype(np.float64)
        scale = dr.select(leaf, dr.rcp(mi.Float(mi.UInt32(1) << self._depth)), 0.0)
        size = [scale * float(ext[a]) for a in range(3)]
        self.leaf_size = mi.Vector3f(*size)
        self.leaf_lo = mi.Point3f(*[float(self.bounds_min[a]) + mi.Float(self._ijk[a]) * size[a] for a in range(3)])
        self.leaf_depth = dr.select(leaf, self._depth, 0)
        # -- neighbours: the leaf containing the same-size cell across each face, if not finer --
        lane = dr.arange(mi.UInt32, 6 * N)
        slot, face = lane // 6, lane % 6
        ok = dr.gather(mi.Bool, leaf, slot)
        d = dr.gather(mi.UInt32, self._depth, slot, ok)
        axis, sign = face // 2, face % 2
        c = []
        for a in range(3):
            v = mi.Int32(dr.gather(mi.UInt32, self._ijk[a], slot, ok))
            v = dr.select(axis == a, dr.select(sign == 1, v + 1, v - 1), v)
            ok &= (v >= 0) & (v < mi.Int32(mi.UInt32(1) << d))
            c.append(mi.UInt32(dr.select(ok, v, 0)))
        self.neighbours = self._descend(c, d, ok)
        # -- allocate (Fig. 7 e) --
        cap = mi.UInt32(dr.maximum(dr.ceil(self.capacity_slack * expected), float(self.min_capacity)))
        cap = dr.select(leaf, cap, 0)
        off = dr.prefix_sum(cap)
        pool = dr.opaque(mi.UInt32, self.sample_total)
        off = dr.minimum(off, pool)
        self.sample_offset = off
        self.sample_capacity = dr.minimum(cap, pool - off)
        self.sample_size = dr.zeros(mi.UInt32, N)
        self.counts = dr.zeros(mi.UInt32, N)
        dr.eval(self.leaf_size, self.leaf_lo, self.leaf_depth, self.neighbours, self.sample_offset,
                self.sample_capacity, self.sample_size, self.counts)

    def _descend(self, c, d, active):
        """Device: slot of the leaf containing integer cell ``c`` of depth ``d`` if it is at depth <= d, else INVALID."""
        nodes = self._nodes
        node = dr.zeros(mi.UInt32, dr.width(d))
        code = dr.gather(mi.UInt32, nodes, node, active)
        lvl = dr.zeros(mi.UInt32, dr.width(d))

        def cond(code, lvl, active):
            return active & ((code & LEAF_BIT) == 0) & (lvl < d)

        def body(code, lvl, active):
            go = active & ((code & LEAF_BIT) == 0) & (lvl < d)
            lvl2 = lvl + 1
            sh = d - lvl2
            octant = ((c[0] >> sh) & 1) | (((c[1] >> sh) & 1) << 1) | (((c[2] >> sh) & 1) << 2)
            code2 = dr.gather(mi.UInt32, nodes, code + octant, go)
            return dr.select(go, code2, code), dr.select(go, lvl2, lvl), active

        code, lvl, active = dr.while_loop((code, lvl, active), cond, body, labels=("code", "lvl", "active"),
                                          label="octree_neighbour")
        return dr.select(active & ((code & LEAF_BIT) != 0), code & ~mi.UInt32(LEAF_BIT), INVALID)

    def _adapt_device(self) -> None:
        """Mark, rebuild, augment, allocate (Fig. 7) as Dr.Jit kernels over the node pool; no host transfer."""
        t0 = time.perf_counter()
        N = self._N
        i = dr.arange(mi.UInt32, N)
        code, alive, depth, ijk = self._nodes, self._alive, self._depth, self._ijk
        counts = self.counts
        is_leaf = alive & ((code & LEAF_BIT) != 0)
        inner = alive & ((code & LEAF_BIT) == 0)
        # -- mark --
        split = is_leaf & (counts > self._split_d) & (depth < self.max_depth)
        first = dr.select(inner, code, 0)
        all_leaf = mi.Bool(inner)
        csum = dr.zeros(mi.UInt32, N)
        best = dr.full(mi.UInt32, INVALID, N)
        bestc = dr.zeros(mi.UInt32, N)
        for k in range(8):
            ck = dr.gather(mi.UInt32, code, first + k, inner)
            cc = dr.gather(mi.UInt32, counts, first + k, inner)
            all_leaf &= (ck & LEAF_BIT) != 0
            csum += cc
            better = (best == INVALID) | (cc > bestc)     # largest count, ties: the lowest slot (octant)
            best = dr.select(better, first + k, best)
            bestc = dr.select(better, cc, bestc)
        collapse = all_leaf & (depth >= 1) & (csum < self._coll_d)
        dr.eval(split, collapse, best, csum, first)
        # -- rebuild: pop a free block per split (deterministic rank by prefix sum), push collapsed blocks --
        one = mi.UInt32(1)
        zero_idx = dr.zeros(mi.UInt32, N)
        top = dr.gather(mi.UInt32, self._top, zero_idx)
        rank = dr.prefix_sum(dr.select(split, one, 0))
        ok = split & (rank < top)
        blk = dr.gather(mi.UInt32, self._free, top - 1 - rank, ok)
        child0 = 1 + 8 * blk
        n_split = dr.block_reduce(dr.ReduceOp.Add, dr.select(ok, one, 0), N)
        n_coll = dr.block_reduce(dr.ReduceOp.Add, dr.select(collapse, one, 0), N)
        top_after = dr.gather(mi.UInt32, self._top, dr.zeros(mi.UInt32, 1)) - n_split
        crank = dr.prefix_sum(dr.select(collapse, one, 0))
        free = mi.UInt32(self._free)
        dr.scatter(free, (first - 1) // 8, dr.gather(mi.UInt32, top_after, zero_idx) + crank, collapse)
        new_top = dr.zeros(mi.UInt32, 2)
        dr.scatter(new_top, top_after + n_coll, dr.zeros(mi.UInt32, 1))
        code_n = dr.select(ok, child0, dr.select(collapse, LEAF_BIT | i, code))
        alive_n = mi.Bool(alive)
        depth_n = mi.UInt32(depth)
        ijk_n = [mi.UInt32(a) for a in ijk]
        parent_n = mi.UInt32(self.node_parent)
        prev = dr.select(is_leaf & ~ok, i, dr.select(collapse, best, INVALID))
        cnt_f = mi.Float(counts)
        expected = dr.select(is_leaf & ~ok, cnt_f, dr.select(collapse, mi.Float(csum), 0.0))
        for k in range(8):
            j = child0 + k
            dr.scatter(code_n, LEAF_BIT | j, j, ok)
            dr.scatter(alive_n, True, j, ok)
            dr.scatter(depth_n, depth + 1, j, ok)
            for a in range(3):
                dr.scatter(ijk_n[a], 2 * ijk[a] + ((k >> a) & 1), j, ok)
            dr.scatter(parent_n, i, j, ok)
            dr.scatter(prev, i, j, ok)
            dr.scatter(expected, cnt_f * 0.125, j, ok)
            dead = first + k
            dr.scatter(alive_n, False, dead, collapse)
            dr.scatter(prev, mi.UInt32(INVALID), dead, collapse)
        # -- counters for stats() (device scalars; read only there) --
        leaf_n = alive_n & ((code_n & LEAF_BIT) != 0)
        self._counters = [dr.block_reduce(dr.ReduceOp.Add, dr.select(leaf_n, one, 0), N), n_split, n_coll,
                          dr.block_reduce(dr.ReduceOp.Max, dr.select(leaf_n, depth_n, 0), N),
                          dr.block_reduce(dr.ReduceOp.Add, counts, N)]
        self._prev_state = (code, alive, depth, ijk)
        self._prev_nodes = code
        self._nodes, self._alive, self._depth, self._ijk = code_n, alive_n, depth_n, ijk_n
        self._free, self._top = free, new_top
        self.node_parent = parent_n
        self.prev_leaf = prev
        dr.eval(self._nodes, self._alive, self._depth, *self._ijk, self._free, self._top, self.node_parent,
                self.prev_leaf, *self._counters)
        self._derive(expected)
        self.frame += 1
        self.adapt_ms = 1e3 * (time.perf_counter() - t0)      # launch time (not synchronised)

    def _host_slots(self, previous: bool = False) -> dict:
        """Device path, read back (inspection): per slot depth (-1 off the tree), ijk, lo, size, leaf mask."""
        code, alive, depth, ijk = self._prev_state if previous else (self._nodes, self._alive, self._depth, self._ijk)
        code, alive = _to_host(code).astype(np.int64), _to_host(alive).astype(bool)
        leaf = alive & ((code & LEAF_BIT) != 0)
        d = np.where(leaf, _to_host(depth).astype(np.int64), -1)
        ij = np.stack([_to_host(a).astype(np.int64) for a in ijk], 1)
        ext = (self.bounds_max.astype(np.float64) - self.bounds_min.astype(np.float64))
        size = np.where(leaf[:, None], ext[None, :] / (2.0 ** np.maximum(d, 0))[:, None], 0.0)
        return {"depth": d, "ijk": ij, "size": size, "leaf": leaf,
                "lo": self.bounds_min[None, :].astype(np.float64) + ij * size}

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
        if self.device:
            self._adapt_device()
            return
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
        """NumPy view of the leaves: depth, ijk (integer cell coordinates), lo, size (world).

        Device path: arrays over all ``leaf_count`` slots (reads back), ``leaf`` marks the slots that are
        leaves (elsewhere depth -1, size 0)."""
        if self.device:
            return self._host_slots(previous)
        t = self._prev_tree if previous else self._tree
        ext = (self.bounds_max.astype(np.float64) - self.bounds_min.astype(np.float64))
        size = ext[None, :] / (2.0 ** t.depth)[:, None]
        return {"depth": t.depth.copy(), "ijk": t.ijk.copy(), "size": size,
                "lo": self.bounds_min[None, :].astype(np.float64) + t.ijk * size}

    def host_lookup(self, p: np.ndarray, previous: bool = False) -> np.ndarray:
        """NumPy brute force of :meth:`lookup`: the leaf whose integer cell contains q (tests)."""
        if self.device:
            h = self._host_slots(previous)
            slots = np.nonzero(h["leaf"])[0]
            t = _Tree(h["depth"][slots], h["ijk"][slots])
        else:
            t = self._prev_tree if previous else self._tree
        q = (np.asarray(p, np.float32) - self.bounds_min[None, :]) * self.inv_extent[None, :]
        q = np.clip(q, 0.0, np.float32(_ONE_MINUS)).astype(np.float64)
        out = np.full(len(q), -1, np.int64)
        for d in np.unique(t.depth):
            cell = np.floor(q * float(2 ** int(d))).astype(np.int64)
            hit = t.find(_pack(np.full(len(q), d), *cell.T))
            out = np.where((out < 0) & (hit >= 0), hit, out)
        return slots[out] if self.device else out

    def stats(self) -> dict:
        if self.device:
            st = {"leaves": None, "nodes": self.leaf_count, "splits": None, "collapses": None,
                  "adapt_ms": self.adapt_ms, "count_sync_ms": 0.0, "max_depth": None, "placed": None,
                  "sample_slots": self.sample_total, "adapt": "device"}
            if self.report_stats:
                c = [int(_to_host(x)[0]) for x in self._counters]
                st.update(leaves=int(c[0]), splits=int(c[1]), collapses=int(c[2]), max_depth=int(c[3]),
                          placed=int(c[4]))
            return st
        return {"leaves": self.leaf_count, "nodes": int(len(self._tree.nodes)), "splits": self.splits,
                "collapses": self.collapses, "adapt_ms": self.adapt_ms, "count_sync_ms": self.count_ms,
                "max_depth": int(self._tree.depth.max()), "placed": self.placed_last, "sample_slots": self.sample_total}
