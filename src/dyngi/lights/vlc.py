"""Visibility Light Cache (Dittebrandt, Hanika, Dachsbacher: "Temporal Sample Reuse for Next Event
Estimation and Path Guiding for Real-Time Path Tracing", Sec. 4 and Algorithm 1): ``lights=vlc``.

Per octree leaf (Sec. 6, :mod:`dyngi.directions.octree`) the VLC holds the lights
that had an *unoccluded* NEE sample in that region in the previous frame, and
NEE selects from it by per-shading-point importance; a cheap global
exploration strategy, combined by MIS, keeps the estimator unbiased.

Frame protocol (driven by ``nee-pt``)
-------------------------------------
1. ``record(p, n, light, visible, active)`` during the frame: every NEE sample
   (light id + visibility bit, Sec. 4.1) is keyed by the leaf of its *current*
   position ``octree.lookup(p)`` (the placing traversal of Sec. 6.3). Device arrays.
2. ``octree.adapt()`` at the end of the frame (nee-pt): the tree the records were
   keyed in becomes the previous tree; ``octree.prev_leaf`` maps every new leaf
   to its previous leaf (Sec. 6.2 populate).
3. ``begin_frame`` (construction, Sec. 4.1/4.2, Fig. 2 b-d) -- on the device by default (see "Device
   construction" below); the host (NumPy) pass, the CPU fast path, whose time is reported as
   ``preprocess_ms``:

   * (b) deduplication: visible records only, one entry per (leaf, light): an
     exact dedup over the key ``leaf * L + light`` by a direct-address table
     (a perfect hash; ``np.unique`` for huge key spaces); the paper's
     per-region shared-memory hash table has the same result; all samples are
     processed, our choice: the host pass is cheap at our counts;
   * populate + (c) neighbour merge: new leaf ``c`` takes the set of
     ``prev_leaf[c]`` united with the sets of the previous leaves of its six
     face neighbours (``octree.neighbours``), deduplicated again;
   * (d) buckets: light ``k`` goes into bucket ``k mod B`` (modulo hashing); the
     buckets of the hash table are merged bottom-up (B halves, power-of-two B,
     so bucket ``i`` and ``i + B/2`` merge) while no bucket exceeds the
     capacity (32, Sec. 7); *hysteresis*: a bucket count lower than the leaf's
     previous one is accepted only if it fits 75% of the capacity (Sec. 4.2);
     lights inside a bucket are sorted by id. A leaf with no lights has B = 0.
4. ``sample`` / ``pmf`` (device): Algorithm 1. With probability ``fraction``
   (exploration, 10%) a light from the global exploration table, else a bucket
   uniformly (1/B) and in it a light by importance (two traversals of the
   bucket: accumulate, then select). The first traversal keeps each light's id and
   importance in per-lane local arrays (``dr.alloc_local``; a bucket holds at most
   ``capacity`` lights), and the second scans the kept weights in the same order
   with the same float sums instead of evaluating every importance again: the
   selection is the paper's two-pass one, bit for bit (a one-pass streaming
   selection would change the sampling). The exact pmf of either outcome is
   ``fraction * p_explore(k) + (1 - fraction) * w_k / (acc_b * B)`` with ``b = k
   mod B``; ``pmf`` recomputes it with one traversal of that bucket. In a leaf
   with an empty VLC the fraction is 1 (exploration only: our choice, the paper's
   Fig. 9 "initial state"). A VLC-chosen bucket whose lights all have importance 0
   at the point yields no light (``INVALID``, pmf 0): unbiased, since such lights
   send nothing to a diffuse receiver there; the pmf over the lights then sums to
   ``1 - (1 - fraction) * (#such buckets) / B`` (tested exactly in tests/sampling/test_vlc.py).

Device construction (``adapt="device"``, the default where the octree keeps its topology on the device,
:mod:`dyngi.directions.octree`): the caches never leave the device. A cache is a bit set per octree slot
(``ceil(L / 32)`` words; bit k = light k). ``record`` ORs the bit of each visible record into the set of
its placing leaf (a ``dr.scatter_reduce`` that runs inside the frame's path-tracing kernel; (b)'s
deduplication is implied by the bit set). ``begin_frame`` then runs, as Dr.Jit kernels over all
slots: populate + (c) merge (per slot and word, the OR of the words of ``prev_leaf`` and of the
previous leaves of its six neighbours), and (d) the bucket count: per slot the 32 counters of
``id mod 32`` (popcounts over the words), merged pairwise down to B = 1 (the paper's bottom-up merge of
a modulo table) and the smallest power of two B whose fullest bucket fits the capacity, with the same
hysteresis. Bucket ``b`` of a slot is then the lights whose bit is set and ``id mod B == b``, walked in
increasing id by the first traversal of Algorithm 1 (``_bucket_walk``: a loop over the slot's nonempty words
(a per-slot word mask) and, in each, over the set bits under a precomputed residue mask; the second scans
what the first kept), which is the order of the host tables, so the two paths give the same pmfs and
bit-identical images. It needs ``L <= 1024`` (B <= 32 then always fits
a capacity >= L / 32) and ``memory = 1``; otherwise the host pass below is used (``adapt`` reports
which). ``stats()`` reads a few device counters back (``report_stats``, inspection only).

Importance ``w_k``: the unoccluded irradiance (luminance) of triangle k at the
shading point, analytic for a diffuse receiver
(:func:`dyngi.lights.importance.triangle_irradiance`, Lambert's formula with
horizon clipping). The paper uses LTCs for glossy receivers; after nee-pt's primary
hit every surface is diffuse (Sec. 7), and at the primary hit we use the diffuse
measure too (not implemented: LTC for glossy; documented limitation). A light whose
importance is 0 at a point (behind it or below its horizon) contributes nothing to
a diffuse receiver there, so skipping it is unbiased.

Exploration (Sec. 4.3): a global alias table (Walker 1977; Vose's construction,
host, every frame) over a blend of three normalised pmfs: light energy (power),
change (power or position changed since the last frame) and camera distance
(1 / max(d^2, (0.05 * scene diagonal)^2)); blend weights (our choice, the paper
gives none) 0.6 / 0.2 / 0.2, renormalised over the heuristics that are non-zero.
Every light with power > 0 keeps a positive exploration pmf (unbiasedness).

Extension (ours, off by default: ``memory = 1`` is the paper's last-frame-only cache):
``memory = M > 1`` keeps a light in a leaf's own set for M frames after its last
visible sample there (ages carried through ``prev_leaf``; the neighbour merge is
applied afresh each frame, so lights do not diffuse further over time).

Exploration by a light tree (ours, ``explorer = "lighttree"``; default ``"global"``, the paper's and the
issue's global alias table): the exploration strategy is the light hierarchy of ``lights=lighttree``
(:class:`dyngi.lights.lighttree.LightTreeSelector`, rebuilt only when a light moved or changed), i.e. a
*local* exploration strategy that knows the shading point, as the paper's Sec. 8 (limitation 3) suggests
("local exploration strategies per leaf, e.g. through clustering"). The pmf stays exact:
``fraction * p_LH(k) + (1 - fraction) * p_VLC(k)``; ``sample`` draws the light-tree sample in the exploration
lanes and evaluates ``p_LH`` of the VLC's light in the others (one more tree traversal per NEE and per
BSDF-hit pmf). Lights with zero light-tree importance at a point (behind it) then have exploration pmf 0:
unbiased for the same reason as above (they send nothing to a diffuse receiver; behind a transmissive
primary BSDF BSDF sampling reaches them). Why (vlctune ablation, /tmp/figs/vlctune.md): at our resolutions
the octree leaves hold ~256-512 samples (the issue's floor; the paper's 1080p leaves 2048-4096), far
regions seen through doors sit in coarse leaves (a depth-1 leaf on warehouse-lights at 160x90) whose VLC
misses visible lights; the global table reaches a missing light with pmf ~0.1/256, so its NEE or BSDF hit
is a firefly: 54% of the VLC's squared error in 0.1% of the pixels. With the light-tree explorer:
warehouse-lights 160x90, frames 1..19, MSE 0.00477 -> 0.00174 (SLL 0.00125, LH 0.00337; firefly share
54% -> 25%); covered-lights 0.00312 -> 0.00271 (SLL 0.00445, LH 0.00471). Not the default: the issue
specifies the global alias table.

Sampling uses the shading point's previous-frame position (Sec. 6.3) to find the
leaf when the caller passes ``p_prev`` (or a ``leaf`` looked up with it): ``nee-pt`` looks up its primary
hits' sampling leaf at the previous position given by the motion vectors of animated meshes
(:mod:`dyngi.directions.motion`, ``octree.lookup_pair``) and records at the current one (issue 28).

Samples per leaf: the paper's leaves hold 2048-4096 samples per frame (split 4096, collapse 2048 at
1080p); ours hold what the octree's thresholds give at the rendered resolution (``nee-pt``, ``path``,
``restir-pt``: ``octree.paper_thresholds``, the paper's from 8 x 4096 records per frame, scaled down below
that); ``reproduce vlc`` states the count beside each figure. With few samples per
leaf a light visible from a small part of a leaf is often missing from its cache and is then reached
only by exploration: fireflies (docs/techniques/nee-pt.md, "VLC against SLL and the light tree").
"""
from __future__ import annotations

import time

import numpy as np

from ..backend import dr, mi
from ..color import luminance
from ..errors import DyngiError
from .base import FrameCtx, register
from .emitter_table import INVALID, EmitterTable
from .importance import triangle_irradiance
from .lighttree import LightTreeSelector

CAPACITY = 32          # bucket capacity (Sec. 7)
HYSTERESIS = 0.75      # capacity factor when the bucket count would drop (Sec. 4.2: "e.g., 75%")
EXPLORATION = 0.1      # exploration fraction (Sec. 7)
EXPLORE_WEIGHTS = (0.6, 0.2, 0.2)   # energy, change, camera distance (our choice)
EXPLORERS = ("global", "lighttree")
ADAPT_CHOICES = ("device", "host")   # where the caches are built (module docstring, "Device construction")


def _to_host(x) -> np.ndarray:
    """The module's device -> host transfer on the device path (tests count its calls)."""
    return np.asarray(x.numpy())   # exploration strategy: the paper's global alias table, or (ours) a light tree


# ---------------------------------------------------------------------------------------------
# alias table (Walker 1977), built on the host, sampled on the device in O(1)
# ---------------------------------------------------------------------------------------------
def build_alias(pmf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vose's alias construction: (prob[n] float32, alias[n] uint32) for ``pmf`` (sums to 1)."""
    p = np.asarray(pmf, np.float64)
    n = p.size
    q = p * n
    prob = np.ones(n)
    alias = np.arange(n, dtype=np.int64)
    small = [i for i in np.nonzero(q < 1.0)[0]]
    large = [i for i in np.nonzero(q >= 1.0)[0]]
    # host loop over lights: O(L) once per frame, small topology (allowed: few hundred lights)
    while small and large:
        s, g = small.pop(), large.pop()
        prob[s] = q[s]
        alias[s] = g
        q[g] = (q[g] + q[s]) - 1.0
        (small if q[g] < 1.0 else large).append(g)
    for i in small + large:
        prob[i] = 1.0
    return prob.astype(np.float32), alias.astype(np.uint32)


class AliasTable:
    """Device alias table over ``pmf`` (host NumPy array); ``sample(u) -> index``, ``pmf`` exact."""

    def __init__(self, pmf: np.ndarray):
        pmf = np.asarray(pmf, np.float64)
        pmf = pmf / pmf.sum()
        prob, alias = build_alias(pmf)
        self.n = int(pmf.size)
        pad = max(0, 2 - self.n)      # >= 2 entries (a 1-element array may become a kernel literal)
        self.prob = mi.Float(np.concatenate([prob, np.ones(pad, np.float32)]))
        self.alias = mi.UInt32(np.concatenate([alias, np.zeros(pad, np.uint32)]))
        self.pmf_host = pmf
        self.pmf = mi.Float(np.concatenate([pmf, np.zeros(pad)]).astype(np.float32))

    def sample(self, u, active=True):
        x = mi.Float(u) * self.n
        i = dr.minimum(mi.UInt32(x), self.n - 1)
        f = x - mi.Float(i)
        pr = dr.gather(mi.Float, self.prob, i, active)
        al = dr.gather(mi.UInt32, self.alias, i, active)
        return dr.select(f < pr, i, al)


def _dedup(keys: np.ndarray, space: int) -> np.ndarray:
    """Sorted distinct ``keys`` in [0, space): a direct-address table (a perfect hash of leaf * L + light) when
    the key space is small (< 2^25 entries: a boolean scatter, O(n + space)), else ``np.unique``."""
    if space <= (1 << 25):
        mark = np.zeros(space, bool)
        mark[keys] = True
        return np.flatnonzero(mark).astype(np.int64)
    return np.unique(keys)


def _pad2(a) -> np.ndarray:
    """uint32 copy of ``a`` padded with zeros to at least 2 entries (device tables, see _set_tables)."""
    a = np.asarray(a).astype(np.uint32)
    return a if a.size >= 2 else np.concatenate([a, np.zeros(2 - a.size, np.uint32)])


def _merge_sets(src_of_new: np.ndarray, nb: np.ndarray | None, start: np.ndarray, cnt: np.ndarray,
                lights: np.ndarray, L: int, merge: bool):
    """Per new leaf c: the union of the old sets of src[c] and (``merge``) of src[neighbour]; deduplicated.

    Returns (leaf[m], light[m]) sorted by (leaf, light)."""
    Nc = src_of_new.size
    cols = [src_of_new]
    if merge and nb is not None:
        nbm = nb.reshape(Nc, 6)
        for k in range(6):
            j = nbm[:, k]
            ok = j != INVALID
            s = np.full(Nc, INVALID, np.int64)
            s[ok] = src_of_new[j[ok]]
            cols.append(s)
    C = np.repeat(np.arange(Nc, dtype=np.int64)[None, :], len(cols), 0).ravel()
    O = np.stack(cols).ravel()
    ok = (O != INVALID) & (O >= 0) & (O < cnt.size)
    C, O = C[ok], O[ok]
    n = cnt[O]
    tot = int(n.sum())
    if tot == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    rep_c = np.repeat(C, n)
    first = np.repeat(start[O] - np.concatenate([[0], np.cumsum(n)[:-1]]), n)
    idx = first + np.arange(tot)
    key = _dedup(rep_c * L + lights[idx], Nc * L)
    return key // L, key % L


def bucket_counts(leaf: np.ndarray, light: np.ndarray, n_leaves: int, prev_b: np.ndarray,
                  capacity: int = CAPACITY, hysteresis: float = HYSTERESIS) -> np.ndarray:
    """Bucket count per leaf (Sec. 4.2, Fig. 2 d): the smallest power of two B such that no bucket
    ``light mod B`` holds more than the capacity, where a B below the leaf's previous count ``prev_b``
    must fit ``floor(hysteresis * capacity)`` (flicker hysteresis). Leaves without lights: 0.

    Merging bottom-up from a large table (B -> B/2 merges buckets i and i + B/2 under modulo hashing)
    stops at the same B as this search upward, which is what is computed."""
    per = np.bincount(leaf, minlength=n_leaves) if leaf.size else np.zeros(n_leaves, np.int64)
    B = np.zeros(n_leaves, np.int64)
    todo = per > 0
    b = 1
    cap_low = max(1, int(np.floor(hysteresis * capacity)))
    while np.any(todo):
        sel = todo[leaf]
        lf, lt = leaf[sel], light[sel]
        occ = np.bincount(lf * b + lt % b, minlength=n_leaves * b).reshape(n_leaves, b).max(axis=1)
        cap = np.where(b >= prev_b, capacity, cap_low)
        ok = todo & (occ <= cap)
        B[ok] = b
        todo &= ~ok
        b *= 2
        if b > (1 << 24):      # cannot happen (B >= L puts one light per bucket)
            raise DyngiError("VLC: bucket search did not terminate")
    return B


class VLCSelector:
    """Visibility Light Cache light selector (``lights=vlc``); see the module docstring.

    Parameters: ``tris`` (EmitterTable), ``octree`` (AdaptiveOctree; else taken from the FrameCtx),
    ``exploration`` (fraction, 0.1), ``capacity`` (32), ``hysteresis`` (0.75), ``merge_neighbours``
    (True), ``explore_weights`` ((energy, change, distance) = (0.6, 0.2, 0.2)), ``memory`` (1),
    ``explorer`` ("global" | "lighttree", module docstring), ``adapt`` ("device" | "host": where the
    caches are built, module docstring "Device construction").
    """

    name = "vlc"
    accepts_leaf = True     # sample/pmf/record take an optional looked-up ``leaf=`` (nee-pt passes it)
    report_stats = True     # device construction: stats() reads its counters back (inspection only)

    def __init__(self, tris: EmitterTable, mi_scene=None, bounds=None, octree=None,
                 exploration: float = EXPLORATION, capacity: int = CAPACITY, hysteresis: float = HYSTERESIS,
                 merge_neighbours: bool = True, explore_weights=EXPLORE_WEIGHTS, memory: int = 1,
                 explorer: str = "global", adapt: str = "device", **_ignored):
        if adapt not in ADAPT_CHOICES:
            raise DyngiError(f"VLC adapt '{adapt}' is unknown; valid choices: {', '.join(ADAPT_CHOICES)}")
        self.adapt_request = adapt
        if not 0.0 < float(exploration) <= 1.0:
            raise DyngiError(f"VLC exploration fraction {exploration} is out of range (0, 1]")
        if int(capacity) < 1:
            raise DyngiError(f"VLC bucket capacity {capacity} must be >= 1")
        self.tris = tris
        self.L = int(tris.count)
        self.octree = octree
        self.fraction = float(exploration)
        self.capacity = int(capacity)
        self.hysteresis = float(hysteresis)
        self.merge = bool(merge_neighbours)
        self.explore_weights = tuple(float(w) for w in explore_weights)
        self.memory = max(1, int(memory))
        if explorer not in EXPLORERS:
            raise DyngiError(f"VLC explorer '{explorer}' is unknown; valid choices: {', '.join(EXPLORERS)}")
        self.explorer = explorer
        self._lh = None
        if explorer == "lighttree" and self.L:
            self._lh = LightTreeSelector(tris)
        self._lights_changed = False
        self._carry = None
        self.bounds = bounds
        self._records: list = []
        self._rec_prev_obj = None
        self._prev_power = None
        self._prev_cen = None
        self.preprocess_ms = 0.0
        self.explore_ms = 0.0
        self._b_old = np.zeros(0, np.int64)       # bucket count per leaf of the tree the records are keyed in
        lum = luminance(tris.host_arrays()["radiance"]) if self.L else np.zeros(0)
        self._lum = mi.Float(np.concatenate([lum, np.zeros(max(0, 2 - lum.size))]).astype(np.float32))
        self._build_exploration(None)
        self._upload_empty(self._n_leaves())
        self.last = {"lights_mean": 0.0, "lights_max": 0, "buckets_mean": 0.0, "records": 0, "visible": 0}
        self.device = False
        self._dev_setup()

    # -- device construction (module docstring) -------------------------------------------------
    def _device_possible(self) -> bool:
        oc = self.octree
        return (self.adapt_request == "device" and self.memory == 1 and 0 < self.L <= 32 * 32
                and self.capacity * 32 >= self.L and (oc is None or getattr(oc, "device", False)))

    def _dev_setup(self) -> None:
        """Choose the construction path; (re)allocate the device bit sets for the octree's slot count."""
        self.device = self._device_possible()
        self.adapt = "device" if self.device else "host"
        if not self.device:
            return
        self._W = (self.L + 31) // 32
        self._N = self._n_leaves()
        self._dev_n = self._N
        NW = max(self._N * self._W, 2)
        self._vis = dr.zeros(mi.UInt32, NW)             # this frame's visible records, keyed by the placing leaf
        self._bits = dr.zeros(mi.UInt32, NW)            # the caches of the current tree
        self.leaf_bcnt = dr.zeros(mi.UInt32, max(self._N, 2))
        self._bold = dr.zeros(mi.UInt32, max(self._N, 2))
        self._wmask = dr.zeros(mi.UInt32, max(self._N, 2))
        self._rec_cnt = dr.zeros(mi.UInt32, 2)          # records, visible records (device counters)
        self._dev_stats = None
        masks = np.zeros(64, np.uint32)                 # masks[B + b]: bits j of a word with j mod B == b
        for B in (1, 2, 4, 8, 16, 32):
            for b in range(B):
                masks[B + b] = sum(1 << j for j in range(b, 32, B))
        self._masks = mi.UInt32(masks)
        self._rec_prev_obj = getattr(self.octree, "prev_leaf", None)
        dr.eval(self._vis, self._bits, self.leaf_bcnt, self._bold, self._rec_cnt)

    def _construct_device(self) -> None:
        """Populate, neighbour merge, buckets with hysteresis (Sec. 4.1/4.2) as Dr.Jit kernels over the
        octree's slots; no host transfer. Same caches and bucket counts as the host pass."""
        oc, N, W = self.octree, self._N, self._W
        pl = getattr(oc, "prev_leaf", None)
        c = dr.arange(mi.UInt32, N)
        if pl is not None and pl is not self._rec_prev_obj:
            src = mi.UInt32(pl)
        else:
            src = mi.UInt32(c)
        src = dr.select(src < N, src, INVALID)
        # populate + (c) merge: per (leaf, word) the OR of the previous leaf's and its neighbours' words
        lane = dr.arange(mi.UInt32, N * W)
        cl, wj = lane // W, lane % W
        s0 = dr.gather(mi.UInt32, src, cl)
        word = dr.gather(mi.UInt32, self._vis, s0 * W + wj, s0 != INVALID)
        if self.merge and oc is not None:
            for f in range(6):
                j = dr.gather(mi.UInt32, oc.neighbours, cl * 6 + f)
                sj = dr.gather(mi.UInt32, src, j, j != INVALID)
                okj = (j != INVALID) & (sj != INVALID)
                word |= dr.gather(mi.UInt32, self._vis, sj * W + wj, okj)
        bits = word
        dr.eval(bits)
        # (d) bucket counts: 32 residue counters per leaf, merged pairwise down to B = 1 (Sec. 4.2)
        cnt = [dr.zeros(mi.UInt32, N) for _ in range(32)]
        wmask = dr.zeros(mi.UInt32, N)      # bit w: word w of the slot's set is not empty (traversals skip the rest)
        for w in range(W):      # W <= 32 words, unrolled (the light count is fixed per selector)
            x = dr.gather(mi.UInt32, bits, c * W + w)
            wmask |= dr.select(x != 0, mi.UInt32(1 << w), 0)
            for b in range(32):
                cnt[b] += (x >> b) & 1
        occ = {32: cnt}
        B = 32
        while B > 1:
            h = B // 2
            occ[h] = [occ[B][b] + occ[B][b + h] for b in range(h)]
            B = h
        total = occ[1][0]
        prev_b = dr.select(src != INVALID, dr.gather(mi.UInt32, self._bold, src, src != INVALID), 0)
        cap_low = max(1, int(np.floor(self.hysteresis * self.capacity)))
        bcnt = dr.zeros(mi.UInt32, N)
        done = total == 0
        for B in (1, 2, 4, 8, 16, 32):
            m = occ[B][0]
            for b in range(1, B):
                m = dr.maximum(m, occ[B][b])
            cap = dr.select(B >= prev_b, self.capacity, cap_low)
            take = ~done & (m <= cap)
            bcnt = dr.select(take, B, bcnt)
            done |= take
        bcnt = dr.select(done, bcnt, 32)       # unreachable: capacity * 32 >= L (_device_possible)
        nonempty = total > 0
        one = mi.UInt32(1)
        self._dev_stats = [dr.block_reduce(dr.ReduceOp.Add, total, N),
                           dr.block_reduce(dr.ReduceOp.Add, dr.select(nonempty, one, 0), N),
                           dr.block_reduce(dr.ReduceOp.Max, total, N),
                           dr.block_reduce(dr.ReduceOp.Add, bcnt, N), self._rec_cnt]
        self._bits, self.leaf_bcnt, self._bold, self._wmask = bits, bcnt, bcnt, wmask
        self._vis = dr.zeros(mi.UInt32, max(N * W, 2))
        self._rec_cnt = dr.zeros(mi.UInt32, 2)
        self._rec_prev_obj = pl
        dr.eval(self._bits, self.leaf_bcnt, self._wmask, self._vis, self._rec_cnt, *self._dev_stats[:4])

    @dr.syntax
    def _bucket_walk(self, p, n, leaf, bidx, B, target, active, kept=None):
        """First traversal of Algorithm 1 over the bit set of bucket ``bidx`` of ``leaf`` (lights with
        ``id mod B == bidx``, in increasing id: the order of the host tables): (sum of importances, importance
        of ``target``, number of lights visited). With ``kept`` (:meth:`_kept`) each visited light's (id,
        importance) is kept in order for the second traversal (:meth:`_select_kept`), which then evaluates no
        importance again. Words of the bit set without a light of the bucket are skipped by an inner loop
        that only loads words, so the triangle irradiance is evaluated once per light of the bucket and never
        on a load-only iteration."""
        W = self._W
        mask = dr.gather(mi.UInt32, self._masks, B + bidx, active)
        rem = dr.gather(mi.UInt32, self._wmask, leaf, active)     # the slot's nonempty words still to visit
        base = leaf * W
        acc = mi.Float(0.0)
        w = mi.Float(0.0)
        m = mi.UInt32(0)
        cur = mi.UInt32(0)
        wi = mi.UInt32(0)
        act = mi.Bool(active)
        while act & ((cur != 0) | (rem != 0)):
            while act & (cur == 0) & (rem != 0):     # load the next word holding a light of the bucket
                nw = dr.tzcnt(rem)
                cur = dr.gather(mi.UInt32, self._bits, base + nw, act & (rem != 0)) & mask
                wi = nw + 1
                rem = rem & (rem - 1)
            has = act & (cur != 0)
            k = (wi - 1) * 32 + dr.tzcnt(cur)
            wk = dr.select(has, self._importance(p, n, k, has), 0.0)
            acc += wk
            w = dr.select(has & (k == target), wk, w)
            if kept is not None:
                self._keep(kept, m, k, wk, has)
            m = dr.select(has, m + 1, m)
            cur = dr.select(has, cur & (cur - 1), cur)
        return acc, w, m

    # -- host build ----------------------------------------------------------------------------
    def _n_leaves(self):
        return int(self.octree.leaf_count) if self.octree is not None else 1

    def _upload_empty(self, n):
        self._set_tables(np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(0, np.int64),
                         np.zeros(0, np.int64), np.zeros(0, np.int64))
        self._host_sets = (np.zeros(0, np.int64), np.zeros(0, np.int64))

    def _set_tables(self, boff, bcnt, bstart, blen, lights):
        # padded to >= 2 entries: a 1-element array may enter a kernel as a literal (another kernel)
        self.leaf_boff = mi.UInt32(_pad2(boff))
        self.leaf_bcnt = mi.UInt32(_pad2(bcnt))
        self.b_start = mi.UInt32(_pad2(bstart))
        self.b_len = mi.UInt32(_pad2(blen))
        self.lights = mi.UInt32(_pad2(lights))
        self._b_cur = bcnt.astype(np.int64)
        dr.eval(self.leaf_boff, self.leaf_bcnt, self.b_start, self.b_len, self.lights)

    def _build_exploration(self, ctx):
        """Global exploration pmf (energy, change, camera distance) and its alias table (Sec. 4.3)."""
        t0 = time.perf_counter()
        if not self.L:
            self.explore = AliasTable(np.ones(1))
            return
        h = self.tris.host_arrays()
        power = np.maximum(h["power"], 0.0)
        if power.sum() <= 0:
            power = np.ones_like(power)
        parts, ws = [power / power.sum()], [self.explore_weights[0]]
        moved = None
        if self._prev_power is not None:
            moved = (np.abs(power - self._prev_power) > 1e-6 * (power + 1e-30)) | \
                    np.any(np.abs(h["centroid"] - self._prev_cen) > 1e-6, axis=1)
        self._lights_changed = bool(moved is not None and np.any(moved))
        if moved is not None and self.explore_weights[1] > 0:
            ch = np.where(moved, power, 0.0)
            if ch.sum() > 0:
                parts.append(ch / ch.sum())
                ws.append(self.explore_weights[1])
        cam = getattr(ctx, "camera_pos", None) if ctx is not None else None
        if cam is not None and self.explore_weights[2] > 0:
            lo, hi = (np.asarray(b, np.float64) for b in (ctx.bounds if len(ctx.bounds) == 2 else
                                                         (h["centroid"].min(0), h["centroid"].max(0) + 1)))
            r0 = 0.05 * max(float(np.linalg.norm(hi - lo)), 1e-3)
            d2 = np.sum((h["centroid"] - np.asarray(cam, np.float64)) ** 2, axis=1)
            dist = np.where(power > 0, 1.0 / np.maximum(d2, r0 * r0), 0.0)
            if dist.sum() > 0:
                parts.append(dist / dist.sum())
                ws.append(self.explore_weights[2])
        ws = np.asarray(ws) / np.sum(ws)
        pmf = sum(w * q for w, q in zip(ws, parts))
        self.explore = AliasTable(pmf)
        self._prev_power, self._prev_cen = power, h["centroid"].copy()
        self.explore_ms = 1e3 * (time.perf_counter() - t0)

    def begin_frame(self, ctx: FrameCtx) -> None:
        """Construct every leaf's VLC from the last frame's records (host pass, timed: ``preprocess_ms``)."""
        t0 = time.perf_counter()
        if ctx is not None:
            self.tris = ctx.tris
            if getattr(ctx, "octree", None) is not None:
                self.octree = ctx.octree
        self._build_exploration(ctx)
        if self._lh is not None and self._lights_changed:    # the explorer's hierarchy follows moving lights
            self._lh.tris = self.tris
            self._lh.build()
        if self._device_possible() != self.device or (self.device and self._n_leaves() != self._dev_n):
            self._dev_setup()         # the octree came with the context, or changed its pool
        if self.device:
            self._construct_device()
            self.preprocess_ms = 1e3 * (time.perf_counter() - t0)    # launch time (not synchronised)
            return
        Nc = self._n_leaves()
        oc = self.octree
        if not self._records or not self.L:
            self._records = []
            self._b_old = np.zeros(Nc, np.int64)
            self._upload_empty(Nc)
            self.last = {"lights_mean": 0.0, "lights_max": 0, "buckets_mean": 0.0, "records": 0, "visible": 0}
            self._rec_prev_obj = getattr(oc, "prev_leaf", None)
            self.preprocess_ms = 1e3 * (time.perf_counter() - t0)
            return
        leaf = np.concatenate([np.asarray(r[0].numpy(), np.int64) for r in self._records])
        light = np.concatenate([np.asarray(r[1].numpy(), np.int64) for r in self._records])
        vis = np.concatenate([np.asarray(r[2].numpy(), bool) for r in self._records])
        n_rec = int(leaf.size)
        No = self._rec_leaves
        self._records = []
        ok = vis & (leaf != INVALID) & (leaf < No) & (light < self.L)
        # (b) dedup: one entry per (previous leaf, light)
        key = _dedup(leaf[ok] * self.L + light[ok], No * self.L)
        age = np.zeros(key.size, np.int64)
        if self.memory > 1 and self._carry is not None and self._carry[3] == No:
            # (our extension, off by default) lights seen visible in this leaf within the last `memory` frames
            ck = self._carry[0] * self.L + self._carry[1]
            key, age = np.concatenate([key, ck]), np.concatenate([age, self._carry[2]])
            order = np.lexsort((age, key))
            key, age = key[order], age[order]
            first = np.concatenate([[True], key[1:] != key[:-1]]) if key.size else np.zeros(0, bool)
            key, age = key[first], age[first]
        o_leaf, o_light = key // self.L, key % self.L
        cnt = np.bincount(o_leaf, minlength=No)
        start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
        # populate: correspondence new leaf -> previous leaf
        pl = getattr(oc, "prev_leaf", None)
        if pl is not None and pl is not self._rec_prev_obj:
            src = np.asarray(pl.numpy(), np.int64).ravel()
        else:
            src = np.arange(Nc, dtype=np.int64)
        src = np.where((src >= 0) & (src < No), src, INVALID)
        if self.memory > 1:     # carry each leaf's own set (not the merged one) into the new tree, one frame older
            okc = src != INVALID
            cs = np.nonzero(okc)[0]
            n = cnt[src[cs]]
            tot = int(n.sum())
            first = np.repeat(start[src[cs]] - np.concatenate([[0], np.cumsum(n)[:-1]]), n) + np.arange(tot)
            keep = age[first] + 1 < self.memory
            self._carry = (np.repeat(cs, n)[keep], o_light[first][keep], age[first][keep] + 1, Nc)
        nb = np.asarray(oc.neighbours.numpy(), np.int64) if (oc is not None and self.merge) else None
        # (c) merge with the neighbours' caches
        c_leaf, c_light = _merge_sets(src, nb, start, cnt, o_light, self.L, self.merge)
        # (d) buckets with hysteresis
        b_old = self._b_old if self._b_old.size == No else np.zeros(No, np.int64)
        prev_b = np.where(src != INVALID, b_old[np.clip(src, 0, max(No - 1, 0))], 0)
        B = bucket_counts(c_leaf, c_light, Nc, prev_b, self.capacity, self.hysteresis)
        boff = np.concatenate([[0], np.cumsum(B)[:-1]]).astype(np.int64)
        gb = boff[c_leaf] + c_light % np.maximum(B[c_leaf], 1)
        order = np.lexsort((c_light, gb))
        lights_sorted = c_light[order]
        nbk = int(B.sum())
        blen = np.bincount(gb, minlength=nbk) if nbk else np.zeros(0, np.int64)
        bstart = np.concatenate([[0], np.cumsum(blen)[:-1]]) if nbk else np.zeros(0, np.int64)
        self._set_tables(boff, B, bstart, blen, lights_sorted)
        self._host_sets = (c_leaf, c_light)
        self._b_old = B
        self._rec_prev_obj = pl
        per = np.bincount(c_leaf, minlength=Nc)
        nonempty = per[per > 0]
        self.last = {"lights_mean": float(nonempty.mean()) if nonempty.size else 0.0,
                     "lights_max": int(per.max()) if per.size else 0,
                     "buckets_mean": float(B[B > 0].mean()) if np.any(B > 0) else 0.0,
                     "records": n_rec, "visible": int(ok.sum()), "leaves_with_vlc": int(nonempty.size)}
        self.preprocess_ms = 1e3 * (time.perf_counter() - t0)

    def _host_bits(self, leaf: int) -> np.ndarray:
        W = self._W
        words = _to_host(self._bits)[leaf * W:(leaf + 1) * W].astype(np.uint64)
        bits = ((words[:, None] >> np.arange(32, dtype=np.uint64)) & 1).astype(bool).ravel()
        return np.nonzero(bits)[0].astype(np.int64)

    def host_caches(self) -> np.ndarray:
        """(leaves, L) bool: light k is in leaf c's VLC (current tree; tests; one read-back on the device path)."""
        Nc = self._n_leaves()
        if self.device:
            words = _to_host(self._bits)[:Nc * self._W].reshape(Nc, self._W).astype(np.uint64)
            bits = ((words[:, :, None] >> np.arange(32, dtype=np.uint64)) & 1).astype(bool)
            return bits.reshape(Nc, -1)[:, :self.L]
        out = np.zeros((Nc, self.L), bool)
        c_leaf, c_light = self._host_sets
        out[c_leaf, c_light] = True
        return out

    def host_bucket_counts(self) -> np.ndarray:
        """(leaves,) bucket count B per leaf (tests)."""
        return _to_host(self.leaf_bcnt)[:self._n_leaves()].astype(np.int64)

    def host_cache(self, leaf: int) -> np.ndarray:
        """Light ids in ``leaf``'s VLC (current tree), sorted (for tests; reads back on the device path)."""
        if self.device:
            return self._host_bits(int(leaf))
        c_leaf, c_light = self._host_sets
        return np.sort(c_light[c_leaf == leaf])

    def host_buckets(self, leaf: int) -> list:
        """[array of light ids] per bucket of ``leaf`` (for tests)."""
        if self.device:
            lt = self._host_bits(int(leaf))
            B = int(_to_host(self.leaf_bcnt)[int(leaf)])
            return [lt[lt % B == b] for b in range(B)]
        boff = np.asarray(self.leaf_boff.numpy(), np.int64)
        bcnt = np.asarray(self.leaf_bcnt.numpy(), np.int64)
        bs, bl = np.asarray(self.b_start.numpy(), np.int64), np.asarray(self.b_len.numpy(), np.int64)
        lt = np.asarray(self.lights.numpy(), np.int64)
        return [lt[bs[g]:bs[g] + bl[g]] for g in range(boff[leaf], boff[leaf] + bcnt[leaf])]

    # -- device sampling (Algorithm 1) ---------------------------------------------------------
    def _leaf(self, p, p_prev, active):
        if self.octree is None:
            return dr.zeros(mi.UInt32, dr.width(p))
        q = p if p_prev is None else p_prev
        return self.octree.lookup(q, active)

    def _importance(self, p, n, k, active):
        p0 = dr.gather(mi.Point3f, self.tris.p0, k, active)
        e1 = dr.gather(mi.Vector3f, self.tris.e1, k, active)
        e2 = dr.gather(mi.Vector3f, self.tris.e2, k, active)
        lum = dr.gather(mi.Float, self._lum, k, active)
        return triangle_irradiance(p, n, p0, e1, e2, lum, active)

    @dr.syntax
    def _accumulate(self, p, n, start, length, target, active, kept=None):
        """First traversal (host tables): sum of importances in the bucket, the importance of ``target``, the
        number of lights visited; with ``kept`` each light's (id, importance) is kept in order
        (:meth:`_bucket_walk`)."""
        acc = mi.Float(0.0)
        w = mi.Float(0.0)
        i = mi.UInt32(0)
        act = mi.Bool(active)
        while act & (i < length):
            k = dr.gather(mi.UInt32, self.lights, start + i, act)
            wk = self._importance(p, n, k, act)
            acc += wk
            w = dr.select(k == target, wk, w)
            if kept is not None:
                self._keep(kept, i, k, wk, act)
            i += 1
        return acc, w, i

    def _kept(self):
        """Per-lane local arrays (light id, importance) for one bucket: a bucket holds at most ``capacity``
        lights (and at most L), the construction's invariant (:func:`bucket_counts`, ``_construct_device``)."""
        size = self._kept_size()
        return dr.alloc_local(mi.UInt32, size), dr.alloc_local(mi.Float, size)

    def _kept_size(self) -> int:
        return max(1, min(self.capacity, self.L))

    def _keep(self, kept, i, k, wk, active):
        """Keep (light ``k``, importance ``wk``) at slot ``i`` of ``kept`` (indices past the size dropped)."""
        ok = active & (i < self._kept_size())
        kept[0].write(k, i, ok)
        kept[1].write(wk, i, ok)

    @dr.syntax
    def _select_kept(self, kept, m, target_acc, active):
        """Second traversal of Algorithm 1 over the ``m`` lights kept by the first (:meth:`_kept`), in the
        same order and with the same float sums: the first light whose running importance sum exceeds
        ``target_acc``, or (rounding: the target may reach the total) the last light with a nonzero
        importance; (light id, its importance)."""
        cum = mi.Float(0.0)
        chosen = mi.UInt32(INVALID)
        w = mi.Float(0.0)
        last_k = mi.UInt32(INVALID)
        last_w = mi.Float(0.0)
        found = mi.Bool(False)
        i = mi.UInt32(0)
        end = dr.minimum(m, self._kept_size())
        act = mi.Bool(active)
        while act & (i < end) & ~found:
            k = kept[0].read(i, act)
            wk = kept[1].read(i, act)
            cum += wk
            hit = (wk > 0.0) & (cum > target_acc)
            chosen = dr.select(hit, k, chosen)
            w = dr.select(hit, wk, w)
            found |= hit
            last_k = dr.select(wk > 0.0, k, last_k)
            last_w = dr.select(wk > 0.0, wk, last_w)
            i += 1
        chosen = dr.select(found, chosen, last_k)
        w = dr.select(found, w, last_w)
        return chosen, w

    def _bucket(self, leaf, bidx, active):
        off = dr.gather(mi.UInt32, self.leaf_boff, leaf, active)
        g = off + bidx
        return dr.gather(mi.UInt32, self.b_start, g, active), dr.gather(mi.UInt32, self.b_len, g, active)

    def sample(self, p, n, u, active, p_prev=None, leaf=None):
        """Algorithm 1: (light id, exact pmf); INVALID / 0 where nothing can be chosen.

        ``leaf`` (optional): the sampling leaf if the caller has looked it up already (saves a traversal)."""
        active = mi.Bool(active) & (self.L > 0)
        leaf = self._leaf(p, p_prev, active) if leaf is None else mi.UInt32(leaf)
        active &= leaf != INVALID
        B = dr.gather(mi.UInt32, self.leaf_bcnt, leaf, active)
        has = active & (B > 0)
        frac = dr.select(has, self.fraction, 1.0)
        u = mi.Float(u)
        explore = u < frac
        # exploration: a global alias-table sample (u rescaled to [0, 1)), or a light-tree sample (explorer)
        u_e = dr.minimum(u / frac, 0.99999994)
        if self._lh is not None:
            k_e, pe_e = self._lh.sample(p, n, u_e, active & explore)
        else:
            k_e = self.explore.sample(u_e, active & explore)
        # VLC: bucket uniformly, then (second traversal) a light by importance
        uv = dr.minimum((u - frac) / dr.maximum(1.0 - frac, 1e-12), 0.99999994)
        Bf = mi.Float(B)
        b_v = dr.minimum(mi.UInt32(uv * Bf), dr.maximum(B, 1) - 1)
        u_l = uv * Bf - mi.Float(b_v)
        bidx = dr.select(explore, k_e % dr.maximum(B, 1), b_v)
        tgt = dr.select(explore, k_e, mi.UInt32(INVALID))
        # first traversal: the bucket's importances, kept; second: the selection over the kept weights
        kept = self._kept()
        if self.device:
            acc, w_e, m = self._bucket_walk(p, n, leaf, bidx, B, tgt, has, kept)
        else:
            start, length = self._bucket(leaf, bidx, has)
            length = dr.select(has, length, 0)
            acc, w_e, m = self._accumulate(p, n, start, length, tgt, has, kept)
        k_v, w_v = self._select_kept(kept, m, u_l * acc, has & ~explore & (acc > 0.0))
        k = dr.select(explore, k_e, k_v)
        w = dr.select(explore, w_e, w_v)
        if self._lh is not None:
            pe = dr.select(explore, pe_e, self._lh.pmf(p, n, k, active & ~explore & (k != INVALID)))
        else:
            pe = dr.gather(mi.Float, self.explore.pmf, k, active & (k != INVALID))
        pv = dr.select(has & (acc > 0.0), w / (acc * Bf), 0.0)
        pmf = frac * pe + (1.0 - frac) * pv
        ok = active & (k != INVALID) & (pmf > 0.0)
        return dr.select(ok, k, mi.UInt32(INVALID)), dr.select(ok, pmf, 0.0)

    def pmf(self, p, n, light_id, active, p_prev=None, leaf=None):
        """Exact probability that ``sample`` returns ``light_id`` at (p, n): one traversal of its bucket."""
        light_id = mi.UInt32(light_id)
        active = mi.Bool(active) & (self.L > 0) & (light_id < max(self.L, 1))
        leaf = self._leaf(p, p_prev, active) if leaf is None else mi.UInt32(leaf)
        active &= leaf != INVALID
        B = dr.gather(mi.UInt32, self.leaf_bcnt, leaf, active)
        has = active & (B > 0)
        frac = dr.select(has, self.fraction, 1.0)
        if self.device:
            acc, w, _ = self._bucket_walk(p, n, leaf, light_id % dr.maximum(B, 1), B, light_id, has)
        else:
            start, length = self._bucket(leaf, light_id % dr.maximum(B, 1), has)
            length = dr.select(has, length, 0)
            acc, w, _ = self._accumulate(p, n, start, length, light_id, has)
        if self._lh is not None:
            pe = self._lh.pmf(p, n, light_id, active)
        else:
            pe = dr.gather(mi.Float, self.explore.pmf, light_id, active)
        pv = dr.select(has & (acc > 0.0), w / (acc * mi.Float(B)), 0.0)
        return dr.select(active, frac * pe + (1.0 - frac) * pv, 0.0)

    def record(self, p, n, light_id, visible, active, leaf=None) -> None:
        """This frame's NEE samples (light id + visibility bit), keyed by the placing leaf ``lookup(p)``."""
        active = mi.Bool(active) & (mi.UInt32(light_id) != INVALID)
        leaf = self._leaf(p, None, active) if leaf is None else mi.UInt32(leaf)
        leaf = dr.select(active, leaf, mi.UInt32(INVALID))
        vis = mi.Bool(visible) & active
        if self.device:
            # (b) dedup by construction: one bit per (placing leaf, light); a side effect of the frame's kernel
            k = mi.UInt32(light_id)
            ok = vis & (leaf != INVALID) & (leaf < self._N) & (k < self.L)
            dr.scatter_reduce(dr.ReduceOp.Or, self._vis, mi.UInt32(1) << (k & 31), leaf * self._W + (k >> 5), ok,
                              mode=dr.ReduceMode.Local)
            z = dr.zeros(mi.UInt32, dr.width(ok))
            dr.scatter_reduce(dr.ReduceOp.Add, self._rec_cnt, mi.UInt32(1), z, True, mode=dr.ReduceMode.Local)
            dr.scatter_reduce(dr.ReduceOp.Add, self._rec_cnt, mi.UInt32(1), z + 1, ok, mode=dr.ReduceMode.Local)
            return
        self._records.append((leaf, mi.UInt32(light_id), vis))
        self._rec_leaves = self._n_leaves()

    def pending(self) -> list:
        """This frame's record arrays (nee-pt evaluates them in the path-tracing kernel; device
        construction: none, its records are scatters evaluated with that kernel)."""
        return [x for r in self._records for x in r]

    def end_frame(self) -> None:
        if self.device:
            dr.eval(self._vis, self._rec_cnt)
            return
        if self._records:
            dr.eval(*[x for r in self._records for x in r])

    def stats(self) -> dict:
        if self.device:
            st = {"preprocess_ms": self.preprocess_ms, "explore_ms": self.explore_ms, "vlc_adapt": "device"}
            if self.report_stats and self._dev_stats is not None:
                tot, ne, mx, bs = (int(_to_host(x)[0]) for x in self._dev_stats[:4])
                rec = _to_host(self._dev_stats[4])
                st.update(lights_in_cache=tot / ne if ne else 0.0, lights_in_cache_max=mx,
                          buckets_mean=bs / ne if ne else 0.0, leaves_with_vlc=ne, records=int(rec[0]),
                          visible_records=int(rec[1]))
            else:
                st.update(lights_in_cache=None, lights_in_cache_max=None, buckets_mean=None, leaves_with_vlc=None,
                          records=None, visible_records=None)
            return st
        return {"preprocess_ms": self.preprocess_ms, "explore_ms": self.explore_ms,
                "lights_in_cache": self.last.get("lights_mean", 0.0),
                "lights_in_cache_max": self.last.get("lights_max", 0),
                "buckets_mean": self.last.get("buckets_mean", 0.0),
                "leaves_with_vlc": self.last.get("leaves_with_vlc", 0),
                "records": self.last.get("records", 0), "visible_records": self.last.get("visible", 0)}


register("vlc", VLCSelector, "Visibility Light Cache: learned visible lights per octree leaf (VLC paper Sec. 4)",
         learns=True, needs_octree=True)
