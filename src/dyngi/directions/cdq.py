"""Compressed Directional Quadtree (CDQ) path guiding (Dittebrandt, Hanika, Dachsbacher, Sec. 5).

Each leaf of the world-space octree (:mod:`dyngi.directions.octree`, Sec. 6) holds a tiny quadtree
over the octahedral map of directions, stored implicitly in a 32/64/96/128-bit field
(default 128; device storage: 4 x ``UInt32`` per octree leaf, unused words zero).

Bit field (Sec. 5, Fig. 3)
--------------------------
Nodes are numbered breadth first, the root is node 0 and always inner, so it is not stored
(Sec. 5: "always zero and does not need to be stored"); node ``k >= 1`` is bit ``k - 1``
(bit ``i`` = bit ``i % 32`` of word ``i // 32``), 1 = inner, 0 = leaf. Every tree is full (each
inner node has 4 children) and uses all ``B`` bits: ``B/4`` inner nodes (root included) and
``3B/4 + 1`` leaves (97 for 128 bits). With ``rank1(i)`` = number of ones in bits ``[0, i)``:

* the children of inner node ``k`` are nodes ``4 j + 1 .. 4 j + 4`` with ``j = 1 + rank1(k - 1)``
  (``j = 0`` for the root): ``j`` is the inner node's position in breadth-first order;
* the parent of node ``k`` is the ``j``-th inner node, ``j = (k - 1) // 4``: the root for
  ``j = 0``, else node ``select1(j - 1) + 1``;
* leaf ``i`` (``0 <= i < 3B/4 + 1``) is node ``select0(i) + 1``.

Child ``c`` (0..3) of a node covers the quadrant ``(c & 1, c >> 1)`` (x, y) of its square.
Popcounts are ``dr.popcnt``; select within a word is a 5-step binary search over popcounts.

Directions and pdf (Sec. 5.2)
-----------------------------
Directions map to the unit square by ``u = (oct_encode(d) + 1) / 2`` (:mod:`.octahedral`, the
Praun-Hoppe / Cigolle octahedral map with the lower hemisphere folded over the diagonals).
Jacobian of OUR map: a point ``p`` of ``[-1, 1]^2`` maps to the octahedron point ``q`` with
``|q_x| + |q_y| + |q_z| = 1`` (the fold is a piecewise isometry of the square, Jacobian 1). An
octahedron face has normal ``(±1, ±1, ±1)/sqrt 3``, so its area element is ``sqrt 3 dA``; seen
from the origin it subtends ``dw = sqrt 3 dA cos(theta) / |q|^2`` with
``cos(theta) = (n . q)/|q| = 1 / (sqrt 3 |q|)``: ``dw = dA / |q|^3`` on ``[-1, 1]^2``
(area 4), i.e. ``dw = 4 dA_unit / |q|^3`` on the unit square. With ``|q| = |d|_2 / |d|_1``,
sampling a leaf uniformly (probability ``1/|leaves|``) and a point uniformly in it gives

    pdf(w) = 1 / (A_leaf |leaves|) * |q|^3 / 4          (Sec. 5.2, A_leaf on the unit square)

Sampling is bottom up (Fig. 5): the leaf is drawn with ``u.x`` (rescaled and reused for the point,
our choice: the contract gives 2 numbers, the paper uses 3), then ``select`` walks up to the
root, rescaling the leaf's bounds into each parent frame. ``pdf`` walks top down from the root.
Bounds are dyadic and exact in float32 down to ``MAX_DEPTH``.

Adaptation (Sec. 5.1)
---------------------
From last frame's INDIRECT samples only (NEE samples are never recorded: lights are NEE's job).
``record`` scatter-adds each sample's squared contribution into a per-(octree leaf, quadtree
node) buffer on the device (``dr.scatter_reduce``). ``end_frame`` then performs at most ONE leaf
migration per octree leaf (Sec. 7.3 limitation 3): the quadtree leaf with the largest summed
squared contribution ``C_leaf`` is split and the inner node whose children are all leaves with
the smallest combined ``C_inner`` (root excluded; its own children excluded from the leaf
candidates) is collapsed, if ``stability * C_leaf > C_inner`` -- the stability factor 0.1
multiplies the LEAF side (Sec. 5.1: "a configurable factor (i.e. 0.1) on the leaf contribution").
On the bit field this is Fig. 4: flip the two bits, delete the collapsed node's 4 child bits,
insert 4 zero bits at the split leaf's children position (two partial shifts), so the number of
nodes never changes.

Contribution (our choice, documented as the issue asks): ``record`` receives the luminance of the
indirect sample's Monte Carlo estimate ``f cos L_i / p_mix`` (the throughput-weighted value that
nee-pt passes). Summed squares over a node estimate ``N * integral(Y(f cos L)^2 / p_mix)`` over
that node's directions, the node's share of the estimator's second moment (the "high-variance as
well as high-energy" target of [VKK18] Eq. 5 the paper cites). This measure is self-correcting:
splitting raises the density of a region 4x and lowers its share, whereas plain ``L^2`` sums would
reward regions merely for being sampled more often. For a pure CDQ the break-even of a migration
is ``C_leaf > 4 C_inner`` (split: ``-3/4 C_leaf``, collapse: ``+3 C_inner``); the paper's 0.1
(> 10x) adds a hysteresis margin. Passing the plain radiance luminance instead works too but is
biased toward already refined regions. nee-pt passes, at its primary and secondary hit,
``Y(bw * R)`` with ``bw = f cos / p_mix`` (no camera-path prefix) and ``R`` the radiance its
indirect ray brought back WITHOUT the emission of lights (NEE's job: "we ignore light samples
entirely", Sec. 5.1) but with the environment (not NEE'd, as in Quake 2 RTX) and what the next
vertex reflects (its NEE and its own indirect ray); NEE samples themselves are never recorded.

Evidence (ours, ``min_records``; 0 = the paper; nee-pt's ``cdq_min_records``, default 8): with sparse
records most collapsible nodes have ``C_inner = 0`` only because nothing was recorded under them, so
``stability * C_leaf > C_inner`` always holds, a migration happens every frame and argmin ties go to the
shallowest empty node: the paper's hysteresis does nothing at our counts. With ``min_records = m`` a quadtree
leaf splits only if it received at least ``m`` records this frame (zero contributions included: a record
below the surface is evidence too) and an inner node collapses only if its four children received at least
``m``; a per-(octree leaf, node) count buffer is scatter-added beside the contributions.

Temporal memory (our extension, ``memory``, default 0 = the paper): the decaying prior the paper lacks
(its migration sees the last frame only; nee-pt marks ``cdq_memory`` ours). The migration may use
``S = memory * S_prev + S_frame``. Each node then keeps three sums (c^2, c^2 x, c^2 y): a split
hands the leaf's memory to the child that holds its contribution-weighted centroid, a collapse
sums its children, the octree's correspondence carries them over. At our sample counts an octree
leaf sees a 0.5-degree sun a few times per hundred frames; memory keeps those rare hits.

Device buffers are padded to a power of two (>= 1024) octree leaves: a Dr.Jit kernel that scatters
into a buffer of a new size compiles anew, and the octree's leaf count changes most frames.

Initial tree (our choice; the paper is silent): breadth first, every level full while the bits
allow, the remaining inner nodes of the last, partial level spread evenly over that level
(e.g. 128 bits: levels 1 and 2 inner, 11 of the 64 level-3 nodes inner). This is the most uniform
tree a full quadtree with ``B`` nodes admits; octree leaves created by a split inherit their
parent's tree through ``octree.prev_leaf`` (Sec. 6.2 "populate").

``MAX_DEPTH`` = 16 (our choice): no split below a leaf of side 2^-16 of the map (about 0.005
degrees), which keeps every bound exact in float32; the sun of ``sky-pit-sun-disc`` (0.5 degrees)
needs about 8 levels.

Where the state lives (``adapt``): ``"device"`` (default) keeps the fields and statistics on the
device: ``begin_frame`` carries the fields over by a gather through ``octree.prev_leaf`` and
``end_frame`` runs the migration as one Dr.Jit kernel (:func:`migrate_dr`, one lane per octree
leaf), with no host round trip; the per-frame migration count stays a device scalar and is read only
by :meth:`CDQDirections.stats` (``report_migrations``, inspection). ``"host"``: the CPU fast path,
the migration decision and the bit shifts as vectorised NumPy (:func:`migrate_np`; one download of
the statistics buffer, one upload of the fields per frame). The temporal ``memory`` extension runs on
the host path only (its centroid-carrying statistics are NumPy). Sampling, pdf and statistics
accumulation run on the device in both.

As a direction sampler: :class:`CDQComponent` draws from the CDQ of a vertex's octree leaf; it is a
component of ``directions=cdq`` (:mod:`dyngi.directions.mixture`): alone it would miss the directions it
has not learned, so it is not registered on its own.
"""
from __future__ import annotations

import time

import numpy as np

from ..backend import dr, mi
from ..errors import DyngiError
from ..sampling.octahedral import oct_decode, oct_encode
from .base import Vertex

BIT_CHOICES = (32, 64, 96, 128)
WORDS = 4                 # device storage per octree leaf: 4 x UInt32 (128 bits)
MAX_DEPTH = 16            # deepest quadtree leaf (our choice, see module docstring)
DEFAULT_STABILITY = 0.1   # Sec. 5.1
INVALID = 0xFFFFFFFF
ADAPT_CHOICES = ("device", "host")   # where CDQDirections updates its state (module docstring)
_ONE_MINUS = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


def _to_host(x) -> np.ndarray:
    """The module's one device -> host transfer (tests count its calls to check the device path)."""
    return np.asarray(x.numpy())


def leaf_count(bits: int) -> int:
    """Number of quadtree leaves of a full tree stored in ``bits`` bits: ``3 bits / 4 + 1``."""
    return 3 * int(bits) // 4 + 1


def check_bits(bits) -> int:
    try:
        b = int(bits)
    except (TypeError, ValueError):
        b = None
    if b not in BIT_CHOICES:
        raise DyngiError(f"CDQ bit count '{bits}' is invalid; valid values: "
                         + ", ".join(map(str, BIT_CHOICES)))
    return b


# ===============================================================================================
# host side (NumPy): bit arrays, initial tree, reference traversal, migration
# ===============================================================================================

def pack_np(bitarr: np.ndarray) -> np.ndarray:
    """(..., B) bool -> (..., 4) uint32 words (bit i = bit i%32 of word i//32). Inverse: :func:`unpack_np`."""
    bitarr = np.asarray(bitarr, bool)
    B = bitarr.shape[-1]
    full = np.zeros(bitarr.shape[:-1] + (32 * WORDS,), bool)
    full[..., :B] = bitarr
    w = full.reshape(bitarr.shape[:-1] + (WORDS, 32)).astype(np.uint64)
    return (w << np.arange(32, dtype=np.uint64)).sum(-1).astype(np.uint32)


def unpack_np(words: np.ndarray, bits: int) -> np.ndarray:
    """(..., 4) uint32 -> (..., bits) bool. Inverse: :func:`pack_np`."""
    words = np.asarray(words, np.uint32)
    b = (words[..., :, None] >> np.arange(32, dtype=np.uint32)) & np.uint32(1)
    return b.reshape(words.shape[:-1] + (32 * WORDS,))[..., :bits].astype(bool)


def initial_bits_np(bits: int) -> np.ndarray:
    """(bits,) bool: the documented initial tree (full levels, last level's inner nodes spread evenly)."""
    bits = check_bits(bits)
    inner_left = bits // 4 - 1          # non-root inner nodes
    out = np.zeros(bits, bool)
    start, width = 1, 4                 # node index range of the current level
    while inner_left > 0:
        if inner_left >= width:
            out[start - 1:start - 1 + width] = True
            inner_left -= width
        else:
            pick = np.floor((np.arange(inner_left) + 0.5) * width / inner_left).astype(int)
            out[start - 1 + pick] = True
            inner_left = 0
        start, width = start + width, 4 * width
    assert out.sum() == bits // 4 - 1
    return out


def is_valid_tree_np(bitarr: np.ndarray) -> bool:
    """Whether a (bits,) bool array is a full breadth-first quadtree using all bits."""
    bitarr = np.asarray(bitarr, bool)
    B = bitarr.size
    if B % 4 or int(bitarr.sum()) != B // 4 - 1:
        return False
    # every node's parent must be inner and come earlier: the j-th inner node (in order) must
    # precede its children 4j+1..4j+4
    inner = np.concatenate([[0], np.nonzero(bitarr)[0] + 1])
    return bool(np.all(inner < 4 * np.arange(inner.size) + 1))


def tree_topology_np(bitarr: np.ndarray) -> dict:
    """Vectorised topology of (L, B) bool fields. Returns per node k = 0..B (root 0):
    ``inner`` (L, B+1), ``parent`` (L, B+1; -1 for the root), ``depth`` (L, B+1),
    ``inner_nodes`` (L, B/4): node index of the j-th inner node (breadth-first order)."""
    bitarr = np.atleast_2d(np.asarray(bitarr, bool))
    L, B = bitarr.shape
    inner = np.concatenate([np.ones((L, 1), bool), bitarr], axis=1)
    rows, cols = np.nonzero(inner)
    inner_nodes = cols.reshape(L, B // 4)
    k = np.arange(1, B + 1)
    parent = np.concatenate([np.full((L, 1), -1), inner_nodes[:, (k - 1) // 4]], axis=1)
    # depth of the j-th inner node: its parent is inner node (node - 1) // 4 < j (a loop over the
    # <= 32 inner nodes, vectorised over the L fields); then every node's depth in one gather
    d_inner = np.zeros((L, B // 4), np.int64)
    for j in range(1, B // 4):
        d_inner[:, j] = d_inner[np.arange(L), (inner_nodes[:, j] - 1) // 4] + 1
    depth = np.concatenate([np.zeros((L, 1), np.int64), d_inner[:, (k - 1) // 4] + 1], axis=1)
    return {"inner": inner, "parent": parent, "depth": depth, "inner_nodes": inner_nodes}


def node_bounds_np(bitarr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(B,) bool -> origin x, origin y, side of every node 0..B on the unit square (reference)."""
    bitarr = np.asarray(bitarr, bool)
    t = tree_topology_np(bitarr[None])
    par = t["parent"][0]
    B = bitarr.size
    ox, oy, s = np.zeros(B + 1), np.zeros(B + 1), np.ones(B + 1)
    for k in range(1, B + 1):   # parents precede children (reference code, small)
        c = (k - 1) % 4
        p = par[k]
        s[k] = s[p] / 2
        ox[k] = ox[p] + (c & 1) * s[k]
        oy[k] = oy[p] + (c >> 1) * s[k]
    return ox, oy, s


def leaf_nodes_np(bitarr: np.ndarray) -> np.ndarray:
    """Node indices of the leaves in order (leaf i = node select0(i) + 1)."""
    return np.nonzero(~np.asarray(bitarr, bool))[0] + 1


def random_tree_np(bits: int, rng: np.random.Generator, max_depth: int = MAX_DEPTH) -> np.ndarray:
    """A random full tree in ``bits`` bits (random splits from the root), for tests."""
    B = check_bits(bits)
    depth = {0: 0}
    children: dict[int, list] = {}
    leaves = [0]
    nodes_left = B
    while nodes_left > 0:
        cand = [n for n in leaves if depth[n] < max_depth]
        n = cand[rng.integers(len(cand))]
        leaves.remove(n)
        children[n] = []
        for c in range(4):
            new = (n, c)
            depth[new] = depth[n] + 1
            children[n].append(new)
            leaves.append(new)
        nodes_left -= 4
    # breadth-first serialisation
    out, queue = [], [0]
    while queue:
        n = queue.pop(0)
        for c in children.get(n, []):
            out.append(c in children)
            queue.append(c)
    return np.asarray(out, bool)


def migrate_np(bitarr: np.ndarray, node_stats: np.ndarray, stability: float = DEFAULT_STABILITY,
               max_depth: int = MAX_DEPTH, return_stats: bool = False, counts=None, min_records: float = 0.0):
    """One leaf migration per row (Sec. 5.1, Fig. 4), vectorised over octree leaves.

    bitarr: (L, B) bool fields; node_stats: (L, B+1) summed squared contributions per node
    (only leaf entries are used), or (L, B+1, 3) with the channels (C, sum c^2 x, sum c^2 y), or (L, B+1, 4)
    with the record counts as a fourth channel. A row migrates iff ``stability * max C_leaf > min C_inner``.
    Evidence (ours, ``min_records``; 0 = the paper): only a quadtree leaf with at least ``min_records``
    records may split and only an inner node whose children hold at least ``min_records`` records may
    collapse (``counts``: (L, B+1) records per node, else the fourth channel).
    Returns (new (L, B) bool fields, (L,) bool mask of rows that migrated) and, with
    ``return_stats``, the (L, B+1) statistics carried over to the new nodes (see :class:`CDQDirections`
    ``memory``).
    """
    bitarr = np.atleast_2d(np.asarray(bitarr, bool))
    S_in = np.asarray(node_stats, np.float64)
    S_in = S_in[None] if S_in.ndim == 1 else S_in
    S = S_in[..., 0] if S_in.ndim == 3 else S_in          # the decision uses C only
    if counts is None and S_in.ndim == 3 and S_in.shape[-1] > 3:
        counts = S_in[..., 3]
    N = None if counts is None or min_records <= 0 else np.asarray(counts, np.float64).reshape(S.shape)
    L, B = bitarr.shape
    r = np.arange(L)
    t = tree_topology_np(bitarr)
    inner, depth, inner_nodes = t["inner"], t["depth"], t["inner_nodes"]
    # -- min search over collapsible inner nodes (all 4 children leaves; not the root) --
    child_inner = inner[:, 1:].reshape(L, B // 4, 4).any(-1)
    c_inner = np.where(inner[:, 1:], 0.0, S[:, 1:]).reshape(L, B // 4, 4).sum(-1)
    collapsible = ~child_inner
    if N is not None:     # evidence: the node's children hold min_records records (ours)
        collapsible &= np.where(inner[:, 1:], 0.0, N[:, 1:]).reshape(L, B // 4, 4).sum(-1) >= min_records
    collapsible[:, 0] = False
    c_inner = np.where(collapsible, c_inner, np.inf)
    j_min = np.argmin(c_inner, axis=1)
    c_min = c_inner[r, j_min]
    # -- max search over splittable leaves (not children of the collapsed node) --
    k = np.arange(B + 1)
    in_block = (k[None, :] >= 4 * j_min[:, None] + 1) & (k[None, :] <= 4 * j_min[:, None] + 4)
    splittable = ~inner & (depth < max_depth) & ~in_block
    if N is not None:     # evidence: the leaf holds min_records records (ours)
        splittable &= N >= min_records
    c_leaf = np.where(splittable, S, -np.inf)
    k_max = np.argmax(c_leaf, axis=1)
    c_max = c_leaf[r, k_max]
    go = np.isfinite(c_min) & np.isfinite(c_max) & (stability * c_max > c_min)
    # -- apply on the bit field: flip, delete 4 child bits, insert 4 zero bits (Fig. 4) --
    x = inner_nodes[r, j_min]                     # node collapsed
    b = bitarr.copy()
    b[r, x - 1] = False
    p_del = 4 * j_min                             # bit position of its first child
    idx = np.arange(B - 4)[None, :]
    b = np.take_along_axis(b, idx + 4 * (idx >= p_del[:, None]), axis=1)
    kl = np.where(k_max > 4 * j_min + 4, k_max - 4, k_max)   # split leaf after the deletion
    b[r, kl - 1] = True
    ones_before = 1 + np.cumsum(np.concatenate([np.zeros((L, 1), np.int64), b.astype(np.int64)], 1), 1)[r, kl - 1]
    p_ins = 4 * ones_before                       # bit position of its first child
    idx = np.arange(B)[None, :]
    src = np.clip(idx - 4 * (idx >= p_ins[:, None] + 4), 0, B - 5)
    newb = np.take_along_axis(b, src, axis=1)
    newb &= ~((idx >= p_ins[:, None]) & (idx < p_ins[:, None] + 4))
    out = np.where(go[:, None], newb, bitarr)
    if not return_stats:
        return out, go
    # -- statistics of the new nodes (for a temporal memory): unchanged leaves keep theirs, the
    #    collapsed node gets its children's sum; the split leaf's statistics go to the child that
    #    holds their contribution-weighted centroid (channels (C, C x, C y)), or a quarter to each
    #    child when only C is given --
    S3 = S_in if S_in.ndim == 3 else S_in[..., None]
    m = np.arange(B + 1)[None, :]
    new_kid = (m >= p_ins[:, None] + 1) & (m <= p_ins[:, None] + 4)
    mi_ = m - 4 * (m > p_ins[:, None] + 4)
    old = np.clip(mi_ + 4 * (mi_ >= 4 * j_min[:, None] + 1), 0, B)
    S_new = np.take_along_axis(S3, old[..., None], axis=1)
    kids = 4 * j_min[:, None] + 1 + np.arange(4)[None, :]
    kids_sum = np.take_along_axis(S3, kids[..., None], axis=1).sum(1)
    S_new = np.where((old == x[:, None])[..., None], kids_sum[:, None, :], S_new)
    leaf_s = S3[r, k_max]                                        # (L, channels)
    if S3.shape[-1] >= 3:
        d = depth[r, k_max] + 1
        cen = leaf_s[:, 1:3] / np.maximum(leaf_s[:, :1], 1e-300)
        q = (np.floor(np.clip(cen, 0.0, 1.0 - 1e-12) * (2.0 ** d)[:, None]).astype(np.int64) & 1)
        slot = q[:, 0] + 2 * q[:, 1]
        kid_val = np.where((m - p_ins[:, None] - 1 == slot[:, None])[..., None], leaf_s[:, None, :], 0.0)
    else:
        kid_val = np.broadcast_to(leaf_s[:, None, :] / 4.0, S_new.shape)
    S_new = np.where(new_kid[..., None], kid_val, S_new)
    S_new[:, 0] = 0.0
    S_new = np.where(go[:, None, None], S_new, S3)
    return out, go, (S_new if S_in.ndim == 3 else S_new[..., 0])


# ===============================================================================================
# device side (Dr.Jit): rank, select, locate, sample, pdf
# ===============================================================================================

def _u32(v):
    return mi.UInt32(v)


def rank1(words, i):
    """Number of ones among bits [0, i) of the 4-word field ``words`` (list of UInt32)."""
    wi = i >> 5
    m = (_u32(1) << (i & 31)) - 1
    r = _u32(0)
    for j, w in enumerate(words):
        r += dr.select(wi > j, dr.popcnt(w), dr.select(wi == j, dr.popcnt(w & m), 0))
    return r


def bit(words, i):
    """Bit ``i`` of the field (UInt32 0/1)."""
    wi = i >> 5
    w = words[0]
    for j in range(1, len(words)):
        w = dr.select(wi == j, words[j], w)
    return (w >> (i & 31)) & 1


def _select_in_word(x, r):
    pos = _u32(0)
    for step in (16, 8, 4, 2, 1):
        c = dr.popcnt((x >> pos) & ((1 << step) - 1))
        go = r >= c
        r = dr.select(go, r - c, r)
        pos = dr.select(go, pos + step, pos)
    return pos


def select_bits(words, r):
    """Position of the ``r``-th (0-based) set bit of the field (``words`` already masked/inverted)."""
    # find the word first (prefix popcounts), then one in-word binary search
    base = _u32(0)
    found = dr.zeros(mi.Bool, dr.width(r))
    rr = mi.UInt32(r)
    wsel = mi.UInt32(words[0])
    for j, w in enumerate(words):
        c = dr.popcnt(w)
        here = ~found & (rr < c)
        wsel = dr.select(here, w, wsel)
        base = dr.select(here, _u32(32 * j), base)
        found |= here
        rr = dr.select(found, rr, rr - c)
    return base + _select_in_word(wsel, rr)


def select1(words, r):
    return select_bits(words, r)


def select0(words, r, bits: int):
    inv = [dr.select(_u32(32 * j) < bits, ~w, 0) for j, w in enumerate(words)]
    return select_bits(inv, r)


@dr.syntax
def locate(words, x, y, active=True):
    """Top-down traversal: the leaf node containing unit-square point (x, y) and its bounds.

    Returns (node, origin x, origin y, side); lanes outside ``active`` do not walk (node 0, side 1)."""
    node = _u32(0)
    ob = _u32(0)
    ox = dr.zeros(mi.Float, dr.width(x))
    oy = dr.zeros(mi.Float, dr.width(x))
    s = dr.ones(mi.Float, dr.width(x))
    go = dr.full(mi.Bool, True, dr.width(x)) & mi.Bool(active)
    depth = _u32(0)
    while go:
        s = s * 0.5
        cx = x >= ox + s
        cy = y >= oy + s
        ox = dr.select(cx, ox + s, ox)
        oy = dr.select(cy, oy + s, oy)
        child = 4 * ob + 1 + dr.select(cx, _u32(1), 0) + dr.select(cy, _u32(2), 0)
        inner = bit(words, child - 1) != 0
        ob = dr.select(inner, 1 + rank1(words, child - 1), ob)
        node = child
        depth += 1
        go = inner & (depth < 40)
    return node, ox, oy, s


@dr.syntax
def leaf_bounds(words, node):
    """Bottom-up reconstruction (Fig. 5): origin x, origin y, side of ``node`` on the unit square."""
    k = mi.UInt32(node)
    ox = dr.zeros(mi.Float, dr.width(k))
    oy = dr.zeros(mi.Float, dr.width(k))
    s = dr.ones(mi.Float, dr.width(k))
    it = dr.zeros(mi.UInt32, dr.width(k))
    while (k != 0) & (it < 40):     # a valid tree needs <= MAX_DEPTH steps; the cap ends a corrupt field's walk
        it += 1
        c = (k - 1) & 3
        ox = (ox + mi.Float(c & 1)) * 0.5
        oy = (oy + mi.Float(c >> 1)) * 0.5
        s = s * 0.5
        j = (k - 1) >> 2
        k = dr.select(j == 0, _u32(0), select1(words, dr.maximum(j, 1) - 1) + 1)
    return ox, oy, s


def solid_angle_factor(d):
    """``|q|^3 / 4`` for direction ``d`` (unit or not): unit-square density -> solid-angle density."""
    l1 = dr.abs(d.x) + dr.abs(d.y) + dr.abs(d.z)
    q = dr.norm(d) / dr.maximum(l1, 1e-30)
    return q * q * q * 0.25


def to_unit_square(d):
    p = oct_encode(d)
    return (dr.clip(dr.fma(p.x, 0.5, 0.5), 0.0, _ONE_MINUS), dr.clip(dr.fma(p.y, 0.5, 0.5), 0.0, _ONE_MINUS))


def sample_field(words, bits: int, u2, active=None, with_node: bool = False):
    """Leaf-uniform sampling of one field per lane: (unit direction, solid-angle pdf[, leaf node]).
    ``active``: lanes outside it do not walk up the tree (their result is unused)."""
    n = leaf_count(bits)
    t = u2.x * n
    i = dr.minimum(mi.UInt32(t), n - 1)
    ux = dr.clip(t - mi.Float(i), 0.0, _ONE_MINUS)   # reuse of u.x (our choice, see docstring)
    node = select0(words, i, bits) + 1
    ox, oy, s = leaf_bounds(words, node if active is None else dr.select(mi.Bool(active), node, 0))
    px = dr.fma(ux, s, ox)
    py = dr.fma(dr.clip(u2.y, 0.0, _ONE_MINUS), s, oy)
    d = oct_decode(mi.Point2f(dr.fma(px, 2.0, -1.0), dr.fma(py, 2.0, -1.0)))
    pdf = solid_angle_factor(d) / (s * s * n)
    return (d, pdf, node) if with_node else (d, pdf)


def pdf_field(words, bits: int, d, active=True, with_node: bool = False):
    """Solid-angle pdf of direction ``d`` under the field (Sec. 5.2)[, and its leaf node]."""
    x, y = to_unit_square(d)
    node, _, _, s = locate(words, x, y, active)
    pdf = solid_angle_factor(d) / (s * s * leaf_count(bits))
    return (pdf, node) if with_node else pdf


# -- device migration (Sec. 5.1, Fig. 4) on 4-word fields ------------------------------------------

def _lowmask(j: int, p):
    """Word ``j`` of the 128-bit mask of bits ``[0, p)`` (``p`` a UInt32 array or an int)."""
    pi = mi.Int32(p)
    lo = 32 * j
    part = (mi.UInt32(1) << mi.UInt32(dr.clip(pi - lo, 0, 31))) - 1
    return dr.select(pi >= lo + 32, mi.UInt32(0xFFFFFFFF), dr.select(pi <= lo, mi.UInt32(0), part))


def _delete4(w, p):
    """Delete the 4 bits ``[p, p + 4)`` of the 128-bit field ``w`` (bits above move down by 4, zeros enter)."""
    m = [_lowmask(j, p) for j in range(WORDS)]
    r = [(w[j] >> 4) | ((w[j + 1] << 28) if j + 1 < WORDS else mi.UInt32(0)) for j in range(WORDS)]
    return [(w[j] & m[j]) | (r[j] & ~m[j]) for j in range(WORDS)]


def _insert4(w, p):
    """Insert 4 zero bits at ``p`` (bits ``>= p`` move up by 4, the top 4 bits of the 128 are dropped)."""
    m0 = [_lowmask(j, p) for j in range(WORDS)]
    m4 = [_lowmask(j, mi.UInt32(p) + 4) for j in range(WORDS)]
    sh = [(w[j] << 4) | ((w[j - 1] >> 28) if j > 0 else mi.UInt32(0)) for j in range(WORDS)]
    return [(w[j] & m0[j]) | (sh[j] & ~m4[j]) for j in range(WORDS)]


def _put_bit(w, i, value: bool):
    """Field ``w`` with bit ``i`` (UInt32 array) set to ``value``."""
    i = mi.UInt32(i)
    out = []
    for j in range(WORDS):
        here = (i >> 5) == j
        m = mi.UInt32(1) << (i & 31)
        out.append(dr.select(here, (w[j] | m) if value else (w[j] & ~m), w[j]))
    return out


@dr.syntax
def migrate_dr(words, stats, base, bits: int, stability, max_depth: int, active, counts=None, min_records=None):
    """Device version of :func:`migrate_np` (statistics channel C only; ``return_stats`` is host-only).

    One lane per octree leaf: ``words`` its 4-word field (words beyond ``bits`` zero), ``stats`` the
    flat per-(leaf, node) buffer of summed squared contributions, ``base`` the lane's offset into it
    (``leaf * (bits + 1)``). Two loops over the field (Sec. 5.1): the collapsible inner node with the
    smallest summed children ``C_inner`` (root excluded; first minimum), then the splittable leaf with
    the largest ``C_leaf`` (depth below ``max_depth``, not a child of that node; first maximum); node
    depths come from the breadth-first level ends ``end(d + 1) = 4 (1 + rank1(end(d)))``. If
    ``stability * C_leaf > C_inner`` the bit field is rewritten as in Fig. 4 (clear, delete 4, set,
    insert 4). Returns (new words, migrated mask). Same decisions as :func:`migrate_np` up to float32
    rounding of the sums (the host sums in float64). ``counts`` (the flat per-(leaf, node) record counts) and
    ``min_records`` (a Float): the evidence rule of :func:`migrate_np` (None: the paper, no minimum).
    """
    ev = counts is not None and min_records is not None
    n = dr.width(base)
    active = mi.Bool(active) & dr.full(mi.Bool, True, n)
    w0, w1, w2, w3 = (mi.UInt32(w) for w in words)
    field = [w0, w1, w2, w3]
    q = bits // 4
    c_min = dr.full(mi.Float, dr.inf, n)
    j_min = dr.zeros(mi.UInt32, n)
    j = dr.full(mi.UInt32, 1, n)
    while active & (j < q):
        pos = 4 * j                                   # bits of the children 4j+1..4j+4 (one nibble)
        wsel = dr.select((pos >> 5) == 1, w1, w0)
        wsel = dr.select((pos >> 5) == 2, w2, wsel)
        wsel = dr.select((pos >> 5) == 3, w3, wsel)
        nib = (wsel >> (pos & 31)) & 0xF
        k0 = base + pos + 1
        c = (dr.gather(mi.Float, stats, k0, active) + dr.gather(mi.Float, stats, k0 + 1, active)) + \
            (dr.gather(mi.Float, stats, k0 + 2, active) + dr.gather(mi.Float, stats, k0 + 3, active))
        better = (nib == 0) & (c < c_min)
        if ev:
            nc = (dr.gather(mi.Float, counts, k0, active) + dr.gather(mi.Float, counts, k0 + 1, active)) + \
                (dr.gather(mi.Float, counts, k0 + 2, active) + dr.gather(mi.Float, counts, k0 + 3, active))
            better &= nc >= min_records
        c_min = dr.select(better, c, c_min)
        j_min = dr.select(better, j, j_min)
        j += 1
    c_max = dr.full(mi.Float, -dr.inf, n)
    k_max = dr.zeros(mi.UInt32, n)
    k = dr.full(mi.UInt32, 1, n)
    depth = dr.full(mi.UInt32, 1, n)
    level_end = dr.full(mi.UInt32, 4, n)
    while active & (k <= bits):
        nxt = k > level_end
        level_end = dr.select(nxt, 4 * (1 + rank1([w0, w1, w2, w3], level_end)), level_end)
        depth = dr.select(nxt, depth + 1, depth)
        leaf = bit([w0, w1, w2, w3], k - 1) == 0
        blk = (k >= 4 * j_min + 1) & (k <= 4 * j_min + 4)
        s = dr.gather(mi.Float, stats, base + k, active)
        better = leaf & (depth < max_depth) & ~blk & (s > c_max)
        if ev:
            better &= dr.gather(mi.Float, counts, base + k, active) >= min_records
        c_max = dr.select(better, s, c_max)
        k_max = dr.select(better, k, k_max)
        k += 1
    go = active & (c_min < dr.inf) & (c_max > -dr.inf) & (stability * c_max > c_min)
    # Fig. 4 on the bit field
    xbit = select1(field, dr.maximum(j_min, 1) - 1)     # bit of the collapsed inner node
    b = _put_bit(field, xbit, False)
    b = _delete4(b, 4 * j_min)
    kl = dr.select(k_max > 4 * j_min + 4, k_max - 4, k_max)
    b = _put_bit(b, kl - 1, True)
    b = _insert4(b, 4 * (1 + rank1(b, kl - 1)))
    out = [dr.select(go, b[i] & _lowmask(i, bits), field[i]) for i in range(WORDS)]
    return out, go


def words_from_numpy(field: np.ndarray):
    """(N, 4) uint32 -> list of 4 UInt32 arrays (one field per lane)."""
    field = np.asarray(field, np.uint32).reshape(-1, WORDS)
    return [mi.UInt32(np.ascontiguousarray(field[:, j])) for j in range(WORDS)]


# ===============================================================================================
# per-octree-leaf guiding (interface §4)
# ===============================================================================================

class CDQDirections:
    """One CDQ per octree leaf; sampling, pdf, statistics on the device, migration on the host.

    Parameters
    ----------
    octree : AdaptiveOctree   leaf indices come from ``octree.lookup``; fields follow ``prev_leaf``
    bits : int = 128          32, 64, 96 or 128 (Sec. 7.3)
    stability : float = 0.1   migrate iff ``stability * C_leaf > C_inner`` (Sec. 5.1)
    max_depth : int = 16      deepest quadtree leaf (our choice)
    adapt : str = "device"    where the state is updated: "device" (no host read-back) or "host" (the NumPy CPU
                              fast path); ``memory > 0`` uses "host" (module docstring)
    min_records : float = 0   evidence for a migration (ours; 0 = the paper): a quadtree leaf splits only
                              with at least this many records of the frame (zero contributions included), an
                              inner node collapses only when its children hold at least this many (module
                              docstring, "Evidence")
    memory : float = 0.0      temporal memory of the statistics (our extension; 0 = the paper's "samples
                              of the last frame" only): the migration uses ``S = memory * S_prev + S_frame``,
                              ``S_prev`` carried through migrations (a collapsed node gets its children's
                              sum, a split leaf's statistics go to the child holding their
                              contribution-weighted centroid) and octree adaptation (``prev_leaf``). Helps where a leaf sees few samples of a rare feature
                              per frame (our low resolutions), at the price of slower readaptation.
    """

    report_migrations = True   # stats() reads the device migration counters back (inspection only)

    def __init__(self, octree, bits: int = 128, stability: float = DEFAULT_STABILITY,
                 max_depth: int = MAX_DEPTH, memory: float = 0.0, adapt: str = "device", min_records: float = 0.0,
                 **_ignored):
        self.bits = check_bits(bits)
        if adapt not in ADAPT_CHOICES:
            raise DyngiError(f"CDQ adapt '{adapt}' is unknown; valid choices: {', '.join(ADAPT_CHOICES)}")
        if not (0.0 < float(stability) <= 1.0):
            raise DyngiError(f"CDQ stability {stability} is out of range (0, 1]")
        if not (2 <= int(max_depth) <= MAX_DEPTH):
            raise DyngiError(f"CDQ max_depth {max_depth} is out of range [2, {MAX_DEPTH}]")
        self.stability = float(stability)
        if not (0.0 <= float(memory) < 1.0):
            raise DyngiError(f"CDQ memory {memory} is out of range [0, 1)")
        self.memory = float(memory)
        if not (0.0 <= float(min_records) <= 1e6):
            raise DyngiError(f"CDQ min_records {min_records} is out of range [0, 1e6]")
        self.min_records = float(min_records)
        self.device = adapt == "device" and self.memory == 0.0
        self.adapt = "device" if self.device else "host"
        self.max_depth = int(max_depth)
        self.octree = octree
        self.n_leaves = leaf_count(self.bits)
        self._init_words = pack_np(initial_bits_np(self.bits))
        self._init_dev = mi.UInt32(self._init_words.astype(np.uint32))    # 4 words, gathered (not literals)
        n = int(octree.leaf_count)
        self._field_np = np.tile(self._init_words, (n, 1))
        self._seen_prev = getattr(octree, "prev_leaf", None)
        self._acc = np.zeros((n, self.bits + 1, self._channels))
        self._upload()
        self._reset_stats()
        self._mig_last_h = 0
        self._mig_total_h = 0
        self._mig_last_d = dr.zeros(mi.UInt32, 1)
        self._mig_total_d = dr.zeros(mi.UInt32, 1)
        self.adapt_ms = 0.0
        self.remaps = 0

    @property
    def _channels(self) -> int:
        """Statistics channels the host memory keeps: C, C x, C y and, with evidence, the record count."""
        return 4 if self.min_records > 0.0 else 3

    # -- device buffers ---------------------------------------------------------------------
    def _upload(self):
        self._rows = self._field_np.shape[0]
        # device buffers are padded to a power-of-two number of rows: Dr.Jit kernels that scatter into
        # (or gather from) a buffer of a new size compile anew, and the octree's leaf count changes often
        self._cap = 1 << max(10, int(np.ceil(np.log2(max(self._rows, 1)))))   # >= 1024 rows
        pad = np.zeros((self._cap, WORDS), np.uint32)
        pad[:self._rows] = self._field_np
        self.field = mi.UInt32(np.ascontiguousarray(pad.ravel()))
        self._rows_dev = dr.opaque(mi.UInt32, self._rows)   # the leaf count changes: never a literal
        dr.eval(self.field)

    def _reset_stats(self):
        self.node_stats = dr.zeros(mi.Float, self._cap * (self.bits + 1))
        self._touched = dr.zeros(mi.UInt32, self._cap)      # device path: fields that got a sample
        dr.eval(self.node_stats, self._touched)
        if self.min_records > 0.0:     # records per node (evidence, ours)
            self.node_counts = dr.zeros(mi.Float, self._cap * (self.bits + 1))
            dr.eval(self.node_counts)
        if self.memory > 0.0:
            self.node_stats_x = dr.zeros(mi.Float, self._cap * (self.bits + 1))
            self.node_stats_y = dr.zeros(mi.Float, self._cap * (self.bits + 1))
            dr.eval(self.node_stats_x, self.node_stats_y)   # buffers, not size-baked literals, for the scatters

    def _words(self, leaf, active):
        ok = mi.Bool(active) & (leaf < self._rows_dev)
        base = dr.select(ok, leaf, 0) * WORDS
        out = []
        for j in range(self.bits // 32):   # words beyond the bit count are zero: not read
            w = dr.gather(mi.UInt32, self.field, base + j, ok)
            out.append(dr.select(ok, w, int(self._init_words[j])))   # invalid leaf: initial tree
        return out

    # -- migration counters (device scalars on the device path) -----------------------------
    @property
    def migrations_last(self) -> int:
        return int(_to_host(self._mig_last_d)[0]) if self.device else self._mig_last_h

    @property
    def migrations_total(self) -> int:
        return int(_to_host(self._mig_total_d)[0]) if self.device else self._mig_total_h

    def set_field(self, leaf: int, words) -> None:
        """Overwrite octree leaf ``leaf``'s field with 4 uint32 ``words`` (tests, tools)."""
        if self.device:
            dr.scatter(self.field, mi.UInt32(np.asarray(words, np.uint32)),
                       mi.UInt32(WORDS * int(leaf) + np.arange(WORDS, dtype=np.uint32)))
            dr.eval(self.field)
        else:
            self._field_np = self._field_np.copy()
            self._field_np[int(leaf)] = words
            self._upload()

    def _remap_device(self, pl, n: int) -> None:
        """Populate on the device: field row i of the new tree = old row ``pl[i]`` (initial tree where
        ``pl[i]`` is no old row); one gather kernel over the padded buffer, no host transfer."""
        cap = 1 << max(10, int(np.ceil(np.log2(max(n, 1)))))
        idx = dr.arange(mi.UInt32, cap * WORDS)
        row, wj = idx // WORDS, idx % WORDS
        n_d = dr.opaque(mi.UInt32, n)
        valid = row < n_d
        src = dr.gather(mi.UInt32, mi.UInt32(pl), row, valid)
        ok = valid & (src < self._rows_dev)
        val = dr.select(ok, dr.gather(mi.UInt32, self.field, src * WORDS + wj, ok),
                        dr.gather(mi.UInt32, self._init_dev, wj, valid))
        self.field = dr.select(valid, val, 0)
        self._rows, self._cap, self._rows_dev = n, cap, n_d
        dr.eval(self.field)

    # -- frame protocol ---------------------------------------------------------------------
    def begin_frame(self, ctx=None) -> None:
        """Carry the fields over to the adapted octree (Sec. 6.2 populate): new leaf i takes
        the field of previous leaf ``octree.prev_leaf[i]``."""
        pl = getattr(self.octree, "prev_leaf", None)
        n = int(self.octree.leaf_count)
        if self.device:
            if pl is not None and pl is not self._seen_prev:
                self._remap_device(pl, n)
                self._seen_prev = pl
                self.remaps += 1
                self._reset_stats()
            elif n != self._rows:
                self._remap_device(dr.full(mi.UInt32, INVALID, max(n, 2)), n)
                self._reset_stats()
            return
        if pl is not None and pl is not self._seen_prev:
            src = np.asarray(pl.numpy() if hasattr(pl, "numpy") else pl, np.int64).ravel()
            ok = (src >= 0) & (src < self._field_np.shape[0])
            new = np.tile(self._init_words, (src.size, 1))
            new[ok] = self._field_np[src[ok]]
            self._field_np = new
            acc = np.zeros((src.size, self.bits + 1, self._channels))
            acc[ok] = self._acc[src[ok]]
            self._acc = acc
            self._seen_prev = pl
            self.remaps += 1
            self._upload()
            self._reset_stats()
        elif n != self._rows:   # no correspondence given: start over with initial trees
            self._field_np = np.tile(self._init_words, (n, 1))
            self._acc = np.zeros((n, self.bits + 1, self._channels))
            self._upload()
            self._reset_stats()

    def sample(self, leaf, u2, active=True):
        """World direction and its solid-angle pdf from the leaf's quadtree."""
        d, pdf = sample_field(self._words(leaf, active), self.bits, u2)
        return d, dr.select(mi.Bool(active), pdf, 0.0)

    def pdf(self, leaf, wo, active=True):
        return dr.select(mi.Bool(active), pdf_field(self._words(leaf, active), self.bits, wo), 0.0)

    def sample_located(self, leaf, u2, take, other, wo_other):
        """One walk per lane for the mixture (Sec. 5.2): lanes ``take`` draw a direction from the leaf's
        quadtree (bottom up) and keep its pdf and leaf node; lanes ``other`` locate ``wo_other`` (top down)
        for its pdf and node. Returns (direction, pdf, node) per lane (``wo_other``, 0, INVALID elsewhere). The
        node is the one :meth:`record` would locate for the direction (up to float32 rounding on a leaf's
        border), so the record reuses it instead of walking again."""
        take, other = mi.Bool(take), mi.Bool(other) & ~mi.Bool(take)
        words = self._words(leaf, take | other)
        d_t, p_t, n_t = sample_field(words, self.bits, u2, take, with_node=True)
        wo = dr.select(take, d_t, wo_other)
        p_o, n_o = pdf_field(words, self.bits, wo, other, with_node=True)
        pdf = dr.select(take, p_t, dr.select(other, p_o, 0.0))
        node = dr.select(take, n_t, dr.select(other, n_o, mi.UInt32(INVALID)))
        return wo, pdf, node

    def record(self, leaf, wo, contribution, active=True, node=None) -> None:
        """Indirect samples of this frame (direction + luminance contribution), NEE excluded. ``node``: the
        direction's quadtree leaf node where the caller located it already (:meth:`sample_located`; INVALID
        lanes are located here)."""
        ok = mi.Bool(active) & (leaf < self._rows_dev) & dr.isfinite(contribution)
        x, y = to_unit_square(wo)
        if node is None:
            words = self._words(leaf, ok)
            node, _, _, _ = locate(words, x, y)
        else:
            node = mi.UInt32(node)
            need = ok & (node == INVALID)
            words = self._words(leaf, need)
            node = dr.select(need, locate(words, x, y, need)[0], node)
        c = dr.maximum(mi.Float(contribution), 0.0)
        c2 = c * c
        slot = leaf * (self.bits + 1) + node
        dr.scatter_reduce(dr.ReduceOp.Add, self.node_stats, c2, slot, ok)
        if self.min_records > 0.0:
            dr.scatter_reduce(dr.ReduceOp.Add, self.node_counts, mi.Float(1.0), slot, ok)
        if self.device:
            dr.scatter(self._touched, mi.UInt32(1), leaf, ok & (c2 > 0.0))
        if self.memory > 0.0:     # centroid channels, so that a split hands memory to the right child
            dr.scatter_reduce(dr.ReduceOp.Add, self.node_stats_x, c2 * x, slot, ok)
            dr.scatter_reduce(dr.ReduceOp.Add, self.node_stats_y, c2 * y, slot, ok)

    def end_frame(self) -> None:
        """One leaf migration per octree leaf from this frame's statistics (device kernel, or the CPU
        fast path with ``adapt="host"``)."""
        t0 = time.perf_counter()
        if self.device:
            leaf = dr.arange(mi.UInt32, self._cap)
            # only fields that received a sample can migrate (0.1 * 0 > C_inner never holds): the others
            # leave both loops at once (the octree pool has many slots that are no leaf)
            valid = leaf < self._rows_dev
            ok = valid & (self._touched != 0)
            words = [dr.gather(mi.UInt32, self.field, leaf * WORDS + j, valid) for j in range(WORDS)]
            ev = (self.node_counts, dr.opaque(mi.Float, self.min_records)) if self.min_records > 0.0 else (None, None)
            new, go = migrate_dr(words, self.node_stats, leaf * (self.bits + 1), self.bits,
                                 dr.opaque(mi.Float, self.stability), self.max_depth, ok, *ev)
            field = dr.empty(mi.UInt32, self._cap * WORDS)
            for j in range(WORDS):
                dr.scatter(field, new[j], leaf * WORDS + j)
            self.field = field
            self._mig_last_d = dr.block_reduce(dr.ReduceOp.Add, dr.select(go, mi.UInt32(1), mi.UInt32(0)), self._cap)
            self._mig_total_d = self._mig_total_d + self._mig_last_d
            dr.eval(self.field, self._mig_last_d, self._mig_total_d)
            self._reset_stats()
            self.adapt_ms = 1e3 * (time.perf_counter() - t0)     # launch time (not synchronised)
            return
        shp = (self._cap, self.bits + 1)
        S = self.node_stats.numpy().reshape(shp)[:self._rows]
        N = self.node_counts.numpy().reshape(shp)[:self._rows] if self.min_records > 0.0 else None
        if self.memory > 0.0:     # the decaying prior: C, C x, C y (and the counts) carried over (ours)
            S = np.stack([S] + [a.numpy().reshape(shp)[:self._rows] for a in (self.node_stats_x, self.node_stats_y)]
                         + ([N] if N is not None else []), -1)
            S = self.memory * self._acc + S
            N = None
        # only fields with some contribution can migrate (0.1 * 0 > C_inner never holds): skip the rest
        rows = np.nonzero((S[..., 0] if S.ndim == 3 else S).any(axis=1))[0]
        moved = np.zeros(self._rows, bool)
        if rows.size:
            bits_arr = unpack_np(self._field_np[rows], self.bits)
            if self.memory > 0.0:
                new_bits, mv, acc = migrate_np(bits_arr, S[rows], self.stability, self.max_depth, return_stats=True,
                                               min_records=self.min_records)
                self._acc = S.copy()
                self._acc[rows] = acc
            else:
                new_bits, mv = migrate_np(bits_arr, S[rows], self.stability, self.max_depth,
                                          counts=None if N is None else N[rows], min_records=self.min_records)
            moved[rows] = mv
            if mv.any():
                self._field_np = self._field_np.copy()
                self._field_np[rows[mv]] = pack_np(new_bits[mv])
        elif self.memory > 0.0:
            self._acc = S.copy()
        self._mig_last_h = int(moved.sum())
        self._mig_total_h += self._mig_last_h
        if self.migrations_last:
            self._upload()
        self._reset_stats()
        self.adapt_ms = 1e3 * (time.perf_counter() - t0)

    def field_bits(self) -> np.ndarray:
        """(leaf_count, bits) bool copy of the fields (for tests and visualisation; reads back on the
        device path)."""
        if self.device:
            w = _to_host(self.field).reshape(-1, WORDS)[:self._rows]
            return unpack_np(w, self.bits)
        return unpack_np(self._field_np, self.bits)

    def stats(self) -> dict:
        rep = self.report_migrations or not self.device
        return {"cdq_bits": self.bits, "cdq_migrations": self.migrations_last if rep else None,
                "cdq_migrations_total": self.migrations_total if rep else None, "cdq_adapt_ms": self.adapt_ms,
                "cdq_fields": self._rows, "cdq_adapt": self.adapt}


class CDQComponent:
    """Directions from the CDQ of the vertex's octree leaf; not used where the BSDF has a delta lobe."""

    name = "cdq-component"

    def __init__(self, guide):
        self.guide = guide

    def usable(self, v: Vertex):
        """Lanes where the CDQ takes part: every active lane but those whose real BSDF has a delta lobe
        (the mixture's pdf would be undefined there, nee-pt module docstring)."""
        if v.bsdf is not None:
            return mi.Bool(v.active) & ~mi.has_flag(v.bsdf.flags(), mi.BSDFFlags.Delta)
        return mi.Bool(v.active)

    def sample(self, v: Vertex, u2, active):
        wo, _ = self.guide.sample(v.leaf, u2, active)
        return wo

    def sample_located(self, v: Vertex, u2, take, other, wo_other):
        """(direction, CDQ pdf, quadtree node) in one walk per lane (:meth:`CDQDirections.sample_located`)."""
        return self.guide.sample_located(v.leaf, u2, take, other, wo_other)

    def pdf(self, v: Vertex, wo, active):
        return self.guide.pdf(v.leaf, wo, active)
