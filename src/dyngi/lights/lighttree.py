"""Light hierarchy (LH) baseline of Dittebrandt et al. Sec. 7: a light BVH, stochastic traversal, no splitting.

``lights=lighttree`` of ``nee-pt``. As in the paper's baseline ("as proposed by
[CK18] and [MC19] but without splitting", Sec. 7):

* **build, every frame** (dynamic lights are handled transparently): a binary
  BVH over the emitter triangles by *binned SAH* ([Wal07]: 16 centroid bins on
  the widest centroid axis, cost = surface area x light count per side), then
  a top-down pass that **collapses** it to **8 children per node** (a node's
  children are expanded, largest surface area first, until 8 or all are
  leaves; [YKL17] "widening") with **at most 2 lights per leaf**;
* **traversal**: from the root, one child is chosen at every node with
  probability proportional to its importance; at the leaf one of its (<= 2)
  lights is chosen by the unoccluded irradiance of the triangle,
  :func:`~dyngi.lights.importance.triangle_irradiance` (the importance of
  the VLC and the SLL; VLC paper Sec. 4). One uniform number is reused by
  rescaling it at every level.

Node importance (ours, following the light-BVH literature [CK18]): a cluster
with bounding box B (centre c, half-diagonal r), power Phi (sum of the lights'
``power``) and an orientation cone (axis a, half-angle theta_o, emission
half-angle theta_e = pi/2 for one-sided area lights) has, at the receiver p
with normal n, d = |c - p| and theta_u = asin(r / d) (the angle B's bounding
sphere subtends),

    I = Phi * cos(theta') * cos(theta_i') / d^2,
    theta'   = max(0, angle(a, p - c) - theta_o - theta_u)   (0 if theta' >= theta_e),
    theta_i' = max(0, angle(n, c - p) - theta_u)              (0 if theta_i' >= pi/2),

with I = Phi / r^2 when p lies inside B's bounding sphere (d <= r: the
distance term is continuous there, the cone terms become 1). The cone bounds
are conservative: I = 0 only where no light of the cluster can reach the
receiver's upper hemisphere from its emitting side (tested: every light with
positive irradiance has a positive pmf).
Where all children of a node (or both lights of a leaf) have zero importance,
the choice falls back to power-proportional (our choice; such a point gets
no light from that subtree, any choice is unbiased).

``pmf`` is exact: every light stores its leaf and slot, every leaf and node its
parent and slot, and ``pmf(light)`` multiplies the branch probabilities along
that chain bottom-up with the same importance code that ``sample`` evaluates
top-down (equal up to float rounding of the product order).

Rebuild policy: ``rebuild="frame"`` (default) rebuilds every frame, as the paper's baseline does (Sec. 7);
``rebuild="change"`` (ours, labelled so) rebuilds only when a light's triangle or power changed. The build
has no per-node Python loop. ``build="device"`` (the default on CUDA) runs it on the device: the binary SAH
levels (:func:`_build_binary_device`, Dr.Jit scatter reductions per node and per bin, a prefix-sum partition)
and the 8-wide collapse (:func:`_collapse_device`, one pass per wide level over all its nodes, compaction by
``dr.compress``), with no read-back of the tree (one host read of a count per level; the triangles come from
the emitter table's host arrays); the host copy ``_host`` is read back only when inspected.
``build="host"``: NumPy array passes per level (the declared CPU fast path and the default there). The device
collapse gives exactly the host collapse's tree from the same binary tree (tested); the two builds' binary
trees agree up to equal-cost SAH ties (float32 vs float64 binning) and, where binning finds no split, the
fallback (device: middle of the current order; host: coordinate median).

CPU fast path (documented): the build runs in NumPy/Python on the host over
the L triangle lights (a few hundred; O(L) nodes, level-synchronous NumPy) from the host arrays
of :class:`~dyngi.lights.emitter_table.EmitterTable`; the flattened
tree is uploaded once per frame. Sampling and pmf are Dr.Jit loops.
"""
from __future__ import annotations

import time

import numpy as np

from ..backend import dr, mi, upload
from ..errors import DyngiError
from .base import pmf_inputs, register
from .emitter_table import INVALID
from .importance import triangle_irradiance

BUILDS = ("auto", "host", "device")
"""Where the binary SAH levels are built: auto (device on CUDA, host on the CPU), host (NumPy), device (Dr.Jit)."""
REBUILD = ("frame", "change")
"""When the tree is rebuilt: every frame (the paper's baseline, default) or when a light changed (ours)."""
LEAF_BIT = 0x80000000
WIDTH = 8            # children per node (Sec. 7)
LEAF_SIZE = 2        # lights per leaf (Sec. 7)
SAH_BINS = 16        # binned SAH (our choice of bin count)
_ONE_MINUS = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
_HALF_PI = float(np.pi / 2)


def _seg_reduce(x, cs, op):
    """Per-segment reduction of rows of ``x`` over contiguous segments starting at ``cs`` (all non-empty)."""
    return op.reduceat(x, cs, axis=0)


def _build_binary(tlo, thi, cen, power, normal):
    """Binary BVH by binned SAH (Wald 2007), built level by level with NumPy (all nodes of a level at
    once); leaves hold <= LEAF_SIZE lights. Every node covers a contiguous range of the final light
    order ``perm``. Returns arrays over the binary nodes (children, ranges, bounds, power, cone) and perm."""
    L = len(cen)
    perm = np.arange(L)
    M = max(2 * L - 1, 1)           # a binary tree with >= 1 light per leaf has at most 2L - 1 nodes
    start, end = np.zeros(M, np.int64), np.zeros(M, np.int64)
    end[0] = L
    left, right = np.full(M, -1, np.int64), np.full(M, -1, np.int64)
    c_lo, c_hi, c_axis = np.zeros((M, 3)), np.zeros((M, 3)), np.zeros((M, 3))
    c_pow, c_cos = np.zeros(M), np.zeros(M)
    nb = 1
    level = np.array([0])
    while len(level):
        s = start[level]
        e = end[level]
        n = e - s
        cs = np.concatenate([[0], np.cumsum(n)[:-1]])
        seg = np.repeat(np.arange(len(level)), n)
        idx = np.repeat(s - cs, n) + np.arange(n.sum())
        lid = perm[idx]
        # -- cluster data of this level's nodes (bounds, power, orientation cone) --
        lo = _seg_reduce(tlo[lid], cs, np.minimum)
        hi = _seg_reduce(thi[lid], cs, np.maximum)
        pw = _seg_reduce(power[lid], cs, np.add)
        wsum = _seg_reduce(normal[lid] * np.maximum(power[lid], 1e-30)[:, None], cs, np.add)
        wn = np.linalg.norm(wsum, axis=1)
        tot_w = _seg_reduce(np.maximum(power[lid], 1e-30), cs, np.add)
        degenerate = wn < 1e-6 * tot_w
        axis = np.where(degenerate[:, None], [0.0, 0.0, 1.0], wsum / np.maximum(wn, 1e-300)[:, None])
        cos_o = _seg_reduce(np.einsum("ij,ij->i", normal[lid], axis[seg]), cs, np.minimum)
        cos_o = np.where(degenerate, -1.0, np.clip(cos_o, -1.0, 1.0))
        c_lo[level], c_hi[level], c_pow[level], c_axis[level], c_cos[level] = lo, hi, pw, axis, cos_o
        # -- split the nodes with more than LEAF_SIZE lights --
        sp = n > LEAF_SIZE
        if not sp.any():
            break
        keep = sp[seg]
        seg_s = np.cumsum(sp) - 1                 # index among the split nodes
        n2 = n[sp]
        cs2 = np.concatenate([[0], np.cumsum(n2)[:-1]])
        idx2, sg = idx[keep], seg_s[seg[keep]]
        lid2 = perm[idx2]
        c = cen[lid2]
        cmin, cmax = _seg_reduce(c, cs2, np.minimum), _seg_reduce(c, cs2, np.maximum)
        ext = cmax - cmin
        ax = np.argmax(ext, 1)
        ea = ext[np.arange(len(n2)), ax]
        ca = c[np.arange(len(c)), ax[sg]]
        flat = ea <= 1e-12
        b = np.floor(SAH_BINS * (ca - cmin[sg, ax[sg]]) / np.where(flat, 1.0, ea)[sg]).astype(np.int64)
        b = np.clip(np.where(flat[sg], 0, b), 0, SAH_BINS - 1)
        key = sg * SAH_BINS + b
        K = len(n2)
        blo = np.full((K * SAH_BINS, 3), np.inf)
        bhi = np.full((K * SAH_BINS, 3), -np.inf)
        np.minimum.at(blo, key, tlo[lid2])
        np.maximum.at(bhi, key, thi[lid2])
        cnt = np.bincount(key, minlength=K * SAH_BINS).reshape(K, SAH_BINS).astype(np.float64)
        blo, bhi = blo.reshape(K, SAH_BINS, 3), bhi.reshape(K, SAH_BINS, 3)

        def sweep(lo_, hi_, cn):
            lo_, hi_ = np.minimum.accumulate(lo_, 1), np.maximum.accumulate(hi_, 1)
            d = hi_ - lo_
            d = np.where(np.isfinite(d), np.maximum(d, 0.0), 0.0)
            return 2.0 * (d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0]), np.cumsum(cn, 1)

        la, ln = sweep(blo, bhi, cnt)
        ra, rn = sweep(blo[:, ::-1], bhi[:, ::-1], cnt[:, ::-1])
        ra, rn = ra[:, ::-1][:, 1:], rn[:, ::-1][:, 1:]         # bins j+1.. for a split after bin j
        cost = la[:, :-1] * ln[:, :-1] + ra * rn
        cost = np.where((ln[:, :-1] > 0) & (rn > 0), cost, np.inf)
        best = np.argmin(cost, 1)
        ok = np.isfinite(cost[np.arange(K), best]) & ~flat
        # median split (by the axis coordinate, ties by order) where binning found no split
        order = np.lexsort((np.arange(len(ca)), ca, sg))
        rank = np.empty(len(ca), np.int64)
        rank[order] = np.arange(len(ca)) - cs2[sg[order]]
        go_right = np.where(ok[sg], b > best[sg], rank >= (n2 // 2)[sg])
        new = np.lexsort((np.arange(len(sg)), go_right, sg))
        perm[idx2] = lid2[new]
        nL = np.bincount(sg, weights=~go_right, minlength=K).astype(np.int64)
        parents = level[sp]           # children ids in order: (left, right) of each split node
        lc = nb + 2 * np.arange(K)
        rc = lc + 1
        m = start[parents] + nL
        start[lc], end[lc], start[rc], end[rc] = start[parents], m, m, end[parents]
        left[parents], right[parents] = lc, rc
        nb += 2 * K
        level = np.stack([lc, rc], 1).ravel()
    return dict(perm=perm, start=start[:nb], end=end[:nb], left=left[:nb], right=right[:nb], lo=c_lo[:nb],
                hi=c_hi[:nb], power=c_pow[:nb], axis=c_axis[:nb], cos_o=c_cos[:nb])


def _build_binary_device(tlo, thi, cen, power, normal, read_back: bool = True):
    """:func:`_build_binary` on the device (Dr.Jit): the same binned SAH, level by level, every node of a level in
    one pass (scatter reductions per node and per (node, bin); the 16-bin sweeps unrolled over bins, not nodes;
    a stable partition by exclusive prefix sums). Where binning finds no split (flat centroids) a node splits
    at the middle of its current order (ours; the host version takes the coordinate median). One host read per
    level (how many nodes split). ``read_back``: the result as NumPy arrays over the ``nb`` binary nodes (for the
    host collapse); else the device arrays (width ``2 L - 1``, the first ``nb`` used) and ``nb``, for
    :func:`_collapse_device`."""
    L = len(cen)
    M = max(2 * L - 1, 2)
    F, U = mi.Float, mi.UInt32
    inf = float("inf")
    # host inputs copied into Dr.Jit's own (aligned) memory: a mapped NumPy buffer's alignment changes the
    # kernels that read it (dyngi.backend.upload), and every level reads these
    ups = upload(F, *[a[:, k] for a in (tlo, thi, cen, normal) for k in range(3)], np.maximum(power, 0.0))
    TLO, THI, CEN, NRM = [list(ups[3 * i:3 * i + 3]) for i in range(4)]
    PW = ups[12]
    Add, Min, Max = dr.ReduceOp.Add, dr.ReduceOp.Min, dr.ReduceOp.Max
    perm = dr.arange(U, L)
    seg = dr.zeros(U, L)
    pos = dr.arange(U, L)
    node = dr.arange(U, M)
    start = dr.zeros(U, M)
    end = dr.select(dr.arange(U, M) == 0, dr.opaque(U, L), U(0))
    left = dr.full(mi.Int32, -1, M)
    right = dr.full(mi.Int32, -1, M)
    c_lo = [dr.full(F, inf, M) for _ in range(3)]
    c_hi = [dr.full(F, -inf, M) for _ in range(3)]
    c_pw = dr.zeros(F, M)
    c_ax = [dr.zeros(F, M), dr.zeros(F, M), dr.full(F, 1.0, M)]
    c_cos = dr.full(F, -1.0, M)
    a, b, nb = 0, 1, 1
    # evaluated up front, so that every level's kernels see the same inputs (a steady build compiles nothing)
    dr.eval(perm, seg, pos, node, start, end, left, right, c_lo, c_hi, c_pw, c_ax, c_cos, TLO, THI, CEN, NRM, PW)
    while b > a:
        a_o, b_o = dr.opaque(U, a), dr.opaque(U, b)       # frame-/level-varying: no literal, no recompile
        act = (seg >= a_o) & (seg < b_o)
        in_lvl = (node >= a_o) & (node < b_o)
        gl = (lambda arr: dr.gather(F, arr, perm))
        # -- cluster data of this level's nodes (bounds, power, orientation cone) --
        for k in range(3):
            dr.scatter_reduce(Min, c_lo[k], gl(TLO[k]), seg, act)
            dr.scatter_reduce(Max, c_hi[k], gl(THI[k]), seg, act)
        pwl = gl(PW)
        dr.scatter_reduce(Add, c_pw, pwl, seg, act)
        wpl = dr.maximum(pwl, 1e-30)
        nrm = [gl(NRM[k]) for k in range(3)]
        wsum = [dr.zeros(F, M) for _ in range(3)]
        for k in range(3):
            dr.scatter_reduce(Add, wsum[k], nrm[k] * wpl, seg, act)
        totw = dr.zeros(F, M)
        dr.scatter_reduce(Add, totw, wpl, seg, act)
        dr.eval(c_lo, c_hi, c_pw, wsum, totw)
        wn = dr.sqrt(wsum[0] * wsum[0] + wsum[1] * wsum[1] + wsum[2] * wsum[2])
        deg = wn < 1e-6 * totw
        ax = [dr.select(deg, 1.0 if k == 2 else 0.0, wsum[k] / dr.maximum(wn, 1e-30)) for k in range(3)]
        dots = sum(nrm[k] * dr.gather(F, ax[k], seg, act) for k in range(3))
        cmin_dot = dr.full(F, inf, M)
        dr.scatter_reduce(Min, cmin_dot, dots, seg, act)
        c_cos = dr.select(in_lvl, dr.select(deg, -1.0, dr.clip(cmin_dot, -1.0, 1.0)), c_cos)
        c_ax = [dr.select(in_lvl, ax[k], c_ax[k]) for k in range(3)]
        dr.eval(c_cos, c_ax)
        # -- split the nodes with more than LEAF_SIZE lights --
        n_node = end - start
        sp_node = in_lvl & (n_node > LEAF_SIZE)
        K = int(dr.count(sp_node)[0]) if dr.width(sp_node) else 0
        if K == 0:
            break
        sp = act & dr.gather(mi.Bool, sp_node, seg)
        cp = [gl(CEN[k]) for k in range(3)]
        cmin = [dr.full(F, inf, M) for _ in range(3)]
        cmax = [dr.full(F, -inf, M) for _ in range(3)]
        for k in range(3):
            dr.scatter_reduce(Min, cmin[k], cp[k], seg, sp)
            dr.scatter_reduce(Max, cmax[k], cp[k], seg, sp)
        dr.eval(cmin, cmax)
        ext = [cmax[k] - cmin[k] for k in range(3)]
        axis = dr.select(ext[1] > ext[0], U(1), U(0))
        ea = dr.select(ext[1] > ext[0], ext[1], ext[0])
        axis = dr.select(ext[2] > ea, U(2), axis)
        ea = dr.select(ext[2] > ea, ext[2], ea)
        cm_a = dr.select(axis == 0, cmin[0], dr.select(axis == 1, cmin[1], cmin[2]))
        flat_node = ea <= 1e-12
        axp = dr.gather(U, axis, seg, sp)
        ca = dr.select(axp == 0, cp[0], dr.select(axp == 1, cp[1], cp[2]))
        eap, cmp_ = dr.gather(F, ea, seg, sp), dr.gather(F, cm_a, seg, sp)
        flat = dr.gather(mi.Bool, flat_node, seg, sp)
        bin_f = dr.floor(SAH_BINS * (ca - cmp_) / dr.select(flat, 1.0, eap))
        bpos = U(dr.clip(mi.Int32(bin_f), 0, SAH_BINS - 1))
        bpos = dr.select(flat, U(0), bpos)
        key = seg * SAH_BINS + bpos
        blo = [dr.full(F, inf, M * SAH_BINS) for _ in range(3)]
        bhi = [dr.full(F, -inf, M * SAH_BINS) for _ in range(3)]
        bcnt = dr.zeros(F, M * SAH_BINS)
        for k in range(3):
            dr.scatter_reduce(Min, blo[k], gl(TLO[k]), key, sp)
            dr.scatter_reduce(Max, bhi[k], gl(THI[k]), key, sp)
        dr.scatter_reduce(Add, bcnt, dr.full(F, 1.0, L), key, sp)
        dr.eval(blo, bhi, bcnt)

        def area(lo_, hi_):
            d = [dr.select(dr.isfinite(hi_[k] - lo_[k]), dr.maximum(hi_[k] - lo_[k], 0.0), 0.0) for k in range(3)]
            return 2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])

        def sweep(order):    # running bounds and counts over the bins in ``order`` (unrolled over 16 bins)
            rl = [dr.full(F, inf, M) for _ in range(3)]
            rh = [dr.full(F, -inf, M) for _ in range(3)]
            rn = dr.zeros(F, M)
            out = {}
            for j in order:
                idx = node * SAH_BINS + j
                rl = [dr.minimum(rl[k], dr.gather(F, blo[k], idx, sp_node)) for k in range(3)]
                rh = [dr.maximum(rh[k], dr.gather(F, bhi[k], idx, sp_node)) for k in range(3)]
                rn = rn + dr.gather(F, bcnt, idx, sp_node)
                out[j] = (area(rl, rh), rn)
            return out

        lsw = sweep(range(SAH_BINS))
        rsw = sweep(range(SAH_BINS - 1, -1, -1))
        best = dr.zeros(U, M)
        best_cost = dr.full(F, inf, M)
        for j in range(SAH_BINS - 1):        # split after bin j: bins <= j left, > j right
            (la, ln), (ra, rn) = lsw[j], rsw[j + 1]
            cost = dr.select((ln > 0) & (rn > 0), la * ln + ra * rn, inf)
            better = cost < best_cost
            best = dr.select(better, U(j), best)
            best_cost = dr.select(better, cost, best_cost)
        ok_node = dr.isfinite(best_cost) & ~flat_node
        # -- stable partition of each split node's range: left lights first, then right --
        st = dr.gather(U, start, seg, sp)
        rank_in = pos - st
        half = dr.gather(U, n_node, seg, sp) // 2
        go_right = dr.select(dr.gather(mi.Bool, ok_node, seg, sp), bpos > dr.gather(U, best, seg, sp),
                             rank_in >= half)
        is_l, is_r = sp & ~go_right, sp & go_right
        pl, pr = dr.prefix_sum(U(is_l)), dr.prefix_sum(U(is_r))
        dr.eval(pl, pr)
        nL_node = dr.zeros(U, M)
        dr.scatter_reduce(Add, nL_node, U(is_l), seg, sp)
        dr.eval(nL_node)
        nLp = dr.gather(U, nL_node, seg, sp)
        new_pos = dr.select(is_l, st + (pl - dr.gather(U, pl, st, sp)),
                            st + nLp + (pr - dr.gather(U, pr, st, sp)))
        rank_node = dr.prefix_sum(U(sp_node))
        lc = dr.opaque(U, nb) + 2 * rank_node
        s_n = start
        m_n = start + nL_node
        new_start, new_end = U(start), U(end)
        dr.scatter(new_start, s_n, lc, sp_node)
        dr.scatter(new_end, m_n, lc, sp_node)
        dr.scatter(new_start, m_n, lc + 1, sp_node)
        dr.scatter(new_end, end, lc + 1, sp_node)
        left = dr.select(sp_node, mi.Int32(lc), left)
        right = dr.select(sp_node, mi.Int32(lc + 1), right)
        lcp = dr.gather(U, lc, seg, sp)
        new_perm, new_seg = U(perm), U(seg)
        dr.eval(new_perm, new_seg, new_pos, lcp)
        dr.scatter(new_perm, perm, new_pos, sp)
        dr.scatter(new_seg, dr.select(is_l, lcp, lcp + 1), new_pos, sp)
        perm, seg, start, end = new_perm, new_seg, new_start, new_end
        dr.eval(perm, seg, start, end, left, right)
        a, b = nb, nb + 2 * K
        nb += 2 * K
    if not read_back:
        return dict(perm=perm, start=start, end=end, left=left, right=right, lo=c_lo, hi=c_hi, power=c_pw,
                    axis=c_ax, cos_o=c_cos, nb=nb, L=L)
    h = lambda x: np.asarray(x)
    return dict(perm=h(perm).astype(np.int64), start=h(start)[:nb].astype(np.int64), end=h(end)[:nb].astype(np.int64),
                left=h(left)[:nb].astype(np.int64), right=h(right)[:nb].astype(np.int64),
                lo=np.stack([h(c_lo[k])[:nb] for k in range(3)], 1).astype(np.float64),
                hi=np.stack([h(c_hi[k])[:nb] for k in range(3)], 1).astype(np.float64),
                power=h(c_pw)[:nb].astype(np.float64),
                axis=np.stack([h(c_ax[k])[:nb] for k in range(3)], 1).astype(np.float64),
                cos_o=h(c_cos)[:nb].astype(np.float64))


def _collapse_device(bt: dict) -> dict:
    """The 8-wide collapse of :meth:`LightTreeSelector.build` on the device, from the device result of
    :func:`_build_binary_device` (``read_back=False``): one wide level at a time, all its nodes at once (the
    WIDTH - 2 expansions unrolled over the 8 slots: the largest-area inner child, first slot on ties, as
    ``np.argmax``), leaves and inner children of a level in row-major (node, slot) order by ``dr.compress``
    (one host read of their count per level), rows appended into buffers sized for the worst case; then the
    flattened node, leaf and light arrays by gathers and scatters. The same tree as the host collapse of the
    same binary tree. Returns the device arrays :meth:`LightTreeSelector.build` uploads, and the counts."""
    U, I, F = mi.UInt32, mi.Int32, mi.Float
    L, nb = bt["L"], bt["nb"]
    left, right = bt["left"], bt["right"]
    lo, hi = bt["lo"], bt["hi"]
    # surface area (up to the factor 2) in double precision, as the host collapse: equal areas tie alike
    d = [dr.maximum(mi.Float64(hi[k]) - mi.Float64(lo[k]), 0.0) for k in range(3)]
    area = d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
    n_max, l_max = max(L - 1, 1), max(L, 1)      # wide nodes <= binary inner nodes; leaves <= lights
    inner_b = dr.full(U, 0, n_max)               # binary node of each wide node
    par_n, par_s = dr.full(U, INVALID, n_max), dr.zeros(U, n_max)
    slots = dr.full(I, -1, n_max * WIDTH)        # binary node in each (wide node, slot), -1 empty
    leaves_b = dr.zeros(U, l_max)
    lpar_n, lpar_s = dr.zeros(U, l_max), dr.zeros(U, l_max)
    frontier = U([0])
    f_pn, f_ps = U([INVALID]), U([0])
    n_wide = n_leaf = depth = 0
    gl = (lambda arr, idx: dr.gather(type(arr), arr, U(dr.maximum(idx, 0))))
    while True:
        F_ = dr.width(frontier)
        fi = I(frontier)
        is_in = gl(left, fi) >= 0
        kids = [dr.select(is_in, gl(left, fi), fi), dr.select(is_in, gl(right, fi), -1)] + \
               [dr.full(I, -1, F_) for _ in range(WIDTH - 2)]
        cnt = dr.select(is_in, I(2), I(1))
        for _ in range(WIDTH - 2):                # at most WIDTH - 2 expansions, every node at once
            best, big, bn = dr.full(mi.Float64, -float("inf"), F_), dr.zeros(I, F_), dr.full(I, -1, F_)
            for j in range(WIDTH):
                kj = kids[j]
                inner = (kj >= 0) & (gl(left, kj) >= 0)
                ar = dr.select(inner, gl(area, kj), -float("inf"))
                better = ar > best                # strict: the first maximum wins, as np.argmax
                best, big, bn = dr.select(better, ar, best), dr.select(better, I(j), big), dr.select(better, kj, bn)
            go = dr.isfinite(best) & (cnt < WIDTH)
            bl, br = gl(left, bn), gl(right, bn)
            kids = [dr.select(go & (big == j), bl, dr.select(go & (cnt == j), br, kids[j])) for j in range(WIDTH)]
            cnt = cnt + dr.select(go, I(1), I(0))
        # -- this level's rows --
        rows = dr.arange(U, F_)
        off = dr.opaque(U, n_wide)
        dr.scatter(inner_b, frontier, off + rows)
        dr.scatter(par_n, f_pn, off + rows)
        dr.scatter(par_s, f_ps, off + rows)
        flat = dr.empty(I, F_ * WIDTH)
        for j in range(WIDTH):
            dr.scatter(flat, kids[j], rows * WIDTH + j)
            dr.scatter(slots, kids[j], (off + rows) * WIDTH + j)
        dr.eval(flat, inner_b, par_n, par_s, slots)
        k_ok = flat >= 0
        leaf_k = k_ok & (gl(left, flat) < 0)
        q_leaf = dr.compress(leaf_k)              # row-major (node, slot): the order a BFS visits them
        q_in = dr.compress(k_ok & ~leaf_k)
        nl_, ni_ = dr.width(q_leaf), dr.width(q_in)
        if nl_:
            lo_ = dr.opaque(U, n_leaf) + dr.arange(U, nl_)
            dr.scatter(leaves_b, U(dr.gather(I, flat, q_leaf)), lo_)
            dr.scatter(lpar_n, off + q_leaf // WIDTH, lo_)
            dr.scatter(lpar_s, q_leaf % WIDTH, lo_)
            dr.eval(leaves_b, lpar_n, lpar_s)
        n_wide, n_leaf, depth = n_wide + F_, n_leaf + nl_, depth + 1
        if ni_ == 0:
            break
        frontier = U(dr.gather(I, flat, q_in))
        f_pn, f_ps = off + q_in // WIDTH, q_in % WIDTH
        dr.eval(frontier, f_pn, f_ps)
    N, nl = n_wide, n_leaf
    # -- flattened child slots: index, bounds, power, cone --
    j = dr.arange(U, N * WIDTH)
    kb = dr.gather(I, slots, j)
    ok = kb >= 0
    wide_of = dr.full(U, INVALID, max(nb, 1))
    dr.scatter(wide_of, dr.arange(U, N), dr.gather(U, inner_b, dr.arange(U, N)))
    leaf_of = dr.full(U, INVALID, max(nb, 1))
    lb = dr.gather(U, leaves_b, dr.arange(U, nl))
    dr.scatter(leaf_of, dr.arange(U, nl), lb)
    is_leaf = gl(left, kb) < 0
    child = dr.select(ok, dr.select(is_leaf, LEAF_BIT | gl(leaf_of, kb), gl(wide_of, kb)), INVALID)
    clo = [dr.select(ok, gl(lo[k], kb), 0.0) for k in range(3)]
    chi = [dr.select(ok, gl(hi[k], kb), 0.0) for k in range(3)]
    cpow = dr.select(ok, dr.maximum(gl(bt["power"], kb), 1e-30), 0.0)
    caxis = [dr.select(ok, gl(bt["axis"][k], kb), 1.0 if k == 2 else 0.0) for k in range(3)]
    ccos = dr.select(ok, gl(bt["cos_o"], kb), -1.0)
    # -- leaves: their (<= 2) lights in id order; each light's leaf and slot --
    ls, le = dr.gather(U, bt["start"], lb), dr.gather(U, bt["end"], lb)
    first = dr.gather(U, bt["perm"], ls)
    two = le - ls > 1
    second = dr.gather(U, bt["perm"], dr.minimum(ls + 1, L - 1))
    a0 = dr.select(two, dr.minimum(first, second), first)
    a1 = dr.select(two, dr.maximum(first, second), INVALID)
    light_leaf, light_slot = dr.zeros(U, L), dr.zeros(U, L)
    li = dr.arange(U, nl)
    dr.scatter(light_leaf, li, a0)
    dr.scatter(light_slot, U(0), a0)
    dr.scatter(light_leaf, li, a1, two)
    dr.scatter(light_slot, U(1), a1, two)
    n_i = dr.arange(U, N)
    out = dict(child=child, lo=mi.Point3f(*clo), hi=mi.Point3f(*chi), power=cpow, axis=mi.Vector3f(*caxis),
               cos_o=ccos, leaf_l0=a0, leaf_l1=a1, light_leaf=light_leaf, light_slot=light_slot,
               node_par=dr.gather(U, par_n, n_i), node_pslot=dr.gather(U, par_s, n_i),
               leaf_par=dr.gather(U, lpar_n, li), leaf_pslot=dr.gather(U, lpar_s, li))
    dr.eval(*out.values())
    out.update(nodes=N, leaves=nl, depth=depth)
    return out


class LightTreeSelector:
    """``lights=lighttree``: an 8-wide light BVH rebuilt every frame, traversed stochastically (no splitting).

    Parameters (keywords; the rest are accepted and ignored, contract of ``nee-pt``):
    ``tris`` the :class:`EmitterTable`; ``mi_scene``, ``bounds`` unused.
    """

    name = "lighttree"

    def __init__(self, tris, mi_scene=None, bounds=None, rebuild: str = "frame", build: str = "auto", **opts):
        if rebuild not in REBUILD:
            raise DyngiError(f"lighttree: rebuild must be one of {', '.join(REBUILD)}, got '{rebuild}'")
        if build not in BUILDS:
            raise DyngiError(f"lighttree: build must be one of {', '.join(BUILDS)}, got '{build}'")
        # auto: the device build on CUDA; on the CPU the host build is the declared fast path (the device
        # build's ~1000 small kernel launches per build cost several times the NumPy levels there,
        # docs/techniques/nee-pt.md)
        self.device_build = build == "device" or (build == "auto" and "cuda" in mi.variant())
        self.tris = tris
        self.count = int(tris.count)
        self.rebuild = rebuild
        self.build_ms = 0.0
        self.builds = 0
        self.build()
        self._state = self._light_state()

    # ------------------------------------------------------------------ build (host)
    def build(self) -> None:
        """Binned SAH binary BVH, collapsed to 8-wide with <= 2 lights per leaf; upload."""
        t0 = time.perf_counter()
        L = self.count
        if L == 0:
            self._empty()
            self.build_ms = 1e3 * (time.perf_counter() - t0)
            return
        h = self.tris.host_arrays()
        p0, e1, e2 = h["p0"], h["e1"], h["e2"]
        v = np.stack([p0, p0 + e1, p0 + e2], 1)
        tlo, thi = v.min(1), v.max(1)
        power = np.maximum(h["power"], 0.0)
        normal = h["normal"]
        if self.device_build:      # binary SAH levels and the 8-wide collapse on the device: no read-back
            c = _collapse_device(_build_binary_device(tlo, thi, h["centroid"], power, normal, read_back=False))
            self._child, self._clo, self._chi, self._cpow = c["child"], c["lo"], c["hi"], c["power"]
            self._caxis, self._ccos, self._leaf_l0, self._leaf_l1 = c["axis"], c["cos_o"], c["leaf_l0"], c["leaf_l1"]
            self._light_leaf, self._light_slot = c["light_leaf"], c["light_slot"]
            self._node_par, self._node_pslot = c["node_par"], c["node_pslot"]
            self._leaf_par, self._leaf_pslot = c["leaf_par"], c["leaf_pslot"]
            self.nodes, self.leaves, self.depth = c["nodes"], c["leaves"], c["depth"]
            self._host_tree = None
            self.build_ms = 1e3 * (time.perf_counter() - t0)
            self.builds += 1
            return
        bt = _build_binary(tlo, thi, h["centroid"], power, normal)
        b_left, b_right = bt["left"], bt["right"]
        d = np.maximum(bt["hi"] - bt["lo"], 0.0)
        b_area = d[:, 0] * d[:, 1] + d[:, 1] * d[:, 2] + d[:, 2] * d[:, 0]
        # -- collapse to WIDTH children per node, one wide level at a time (all its nodes at once): a node's
        #    children are expanded, the largest-area inner child first, until WIDTH or all are leaves --
        inner_nodes, par_rows, slot_rows, leaf_rows, leaf_par_rows = [], [], [], [], []
        frontier = np.array([0], np.int64)              # binary node of each wide node of this level
        fpar = np.array([[INVALID, 0]], np.int64)       # (parent wide node, slot) of each
        n_wide = 0
        while len(frontier):
            F = len(frontier)
            kids = np.full((F, WIDTH), -1, np.int64)
            is_in = b_left[frontier] >= 0
            kids[:, 0] = np.where(is_in, b_left[frontier], frontier)
            kids[:, 1] = np.where(is_in, b_right[frontier], -1)
            cnt = np.where(is_in, 2, 1)
            for _ in range(WIDTH - 2):                  # at most WIDTH - 2 more expansions (vectorized over F)
                k_ok = kids >= 0
                inner = k_ok & (b_left[np.maximum(kids, 0)] >= 0)
                ar = np.where(inner, b_area[np.maximum(kids, 0)], -np.inf)
                big = np.argmax(ar, 1)
                go = np.isfinite(ar[np.arange(F), big]) & (cnt < WIDTH)
                if not go.any():
                    break
                rows = np.nonzero(go)[0]
                bn = kids[rows, big[rows]]
                kids[rows, big[rows]] = b_left[bn]
                kids[rows, cnt[rows]] = b_right[bn]
                cnt[rows] += 1
            ids = n_wide + np.arange(F)
            inner_nodes.append(frontier)
            par_rows.append(fpar)
            slot_rows.append(kids)
            k_ok = kids >= 0
            leaf_k = k_ok & (b_left[np.maximum(kids, 0)] < 0)
            r, c = np.nonzero(leaf_k)                   # row-major: (node, slot) order, as a BFS visits them
            leaf_rows.append(kids[r, c])
            leaf_par_rows.append(np.stack([ids[r], c], 1))
            r, c = np.nonzero(k_ok & ~leaf_k)
            frontier = kids[r, c]
            fpar = np.stack([ids[r], c], 1)
            n_wide += F
        inner_nodes = np.concatenate(inner_nodes)
        slots_arr = np.concatenate(slot_rows)
        parents = np.concatenate(par_rows)
        leaves = np.concatenate(leaf_rows)
        leaf_par = np.concatenate(leaf_par_rows)
        N = len(slots_arr)
        wide_of = np.full(len(b_left), -1, np.int64)
        wide_of[inner_nodes] = np.arange(N)
        leaf_of = np.full(len(b_left), -1, np.int64)
        leaf_of[leaves] = np.arange(len(leaves))
        r, c = np.nonzero(slots_arr >= 0)
        j = r * WIDTH + c
        kb = slots_arr[r, c]
        child = np.full(N * WIDTH, INVALID, np.int64)
        clo = np.zeros((N * WIDTH, 3))
        chi = np.zeros((N * WIDTH, 3))
        cpow = np.zeros(N * WIDTH)
        caxis = np.tile([0.0, 0.0, 1.0], (N * WIDTH, 1))
        ccos = np.full(N * WIDTH, -1.0)
        is_leaf = bt["left"][kb] < 0
        child[j] = np.where(is_leaf, LEAF_BIT | np.maximum(leaf_of[kb], 0), wide_of[kb])
        clo[j], chi[j], caxis[j], ccos[j] = bt["lo"][kb], bt["hi"][kb], bt["axis"][kb], bt["cos_o"][kb]
        cpow[j] = np.maximum(bt["power"][kb], 1e-30)     # > 0: the power fallback never picks an empty slot
        nl = len(leaves)
        lb = leaves
        ls, le = bt["start"][lb], bt["end"][lb]
        leaf_lights = np.full((nl, LEAF_SIZE), INVALID, np.int64)
        perm = bt["perm"]
        first = perm[ls]
        second = np.where(le - ls > 1, perm[np.minimum(ls + 1, L - 1)], INVALID)
        two = second != INVALID
        a0 = np.where(two, np.minimum(first, np.where(two, second, 0)), first)
        a1 = np.where(two, np.maximum(first, np.where(two, second, 0)), INVALID)
        leaf_lights[:, 0], leaf_lights[:, 1] = a0, a1
        light_leaf = np.zeros(L, np.int64)
        light_slot = np.zeros(L, np.int64)
        light_leaf[a0], light_slot[a0] = np.arange(nl), 0
        light_leaf[a1[two]], light_slot[a1[two]] = np.arange(nl)[two], 1
        par = parents.reshape(-1, 2)
        lpar = leaf_par.reshape(-1, 2)
        depth = len(par_rows)              # wide levels (one per pass of the collapse)
        # -- upload --
        f32 = lambda a: upload(mi.Float, a)       # Dr.Jit's own memory: see dyngi.backend.upload
        u32 = lambda a: upload(mi.UInt32, a)
        self._child = u32(child)
        self._clo = mi.Point3f(*[f32(clo[:, k]) for k in range(3)])
        self._chi = mi.Point3f(*[f32(chi[:, k]) for k in range(3)])
        self._cpow = f32(cpow)
        self._caxis = mi.Vector3f(*[f32(caxis[:, k]) for k in range(3)])
        self._ccos = f32(ccos)
        self._leaf_l0, self._leaf_l1 = u32(leaf_lights[:, 0]), u32(leaf_lights[:, 1])
        self._light_leaf, self._light_slot = u32(light_leaf), u32(light_slot)
        self._node_par, self._node_pslot = u32(par[:, 0]), u32(par[:, 1])
        self._leaf_par, self._leaf_pslot = u32(lpar[:, 0]), u32(lpar[:, 1])
        dr.eval(self._child, self._clo, self._chi, self._cpow, self._caxis, self._ccos, self._leaf_l0,
                self._leaf_l1, self._light_leaf, self._light_slot, self._node_par, self._node_pslot,
                self._leaf_par, self._leaf_pslot)
        self.nodes, self.leaves, self.depth = N, nl, depth
        self._host_tree = dict(child=child, lo=clo, hi=chi, power=cpow, axis=caxis, cos_o=ccos, leaf_lights=leaf_lights,
                          light_leaf=light_leaf, node_parent=par, leaf_parent=lpar)
        self.build_ms = 1e3 * (time.perf_counter() - t0)
        self.builds += 1

    @property
    def _host(self) -> dict:
        """Host copy of the flattened tree (child slots, bounds, power, cone, leaf lights, parents), for tests
        and inspection; after a device build it is read back on first use."""
        if self._host_tree is None:
            h = lambda x: np.asarray(x.numpy())
            v3 = lambda x: np.stack([h(x[k]) for k in range(3)], 1).astype(np.float64)
            child = h(self._child).astype(np.int64)
            self._host_tree = dict(
                child=child, lo=v3(self._clo), hi=v3(self._chi), power=h(self._cpow).astype(np.float64),
                axis=v3(self._caxis), cos_o=h(self._ccos).astype(np.float64),
                leaf_lights=np.stack([h(self._leaf_l0), h(self._leaf_l1)], 1).astype(np.int64),
                light_leaf=h(self._light_leaf).astype(np.int64),
                node_parent=np.stack([h(self._node_par), h(self._node_pslot)], 1).astype(np.int64),
                leaf_parent=np.stack([h(self._leaf_par), h(self._leaf_pslot)], 1).astype(np.int64))
        return self._host_tree

    def _empty(self):
        self.nodes = self.leaves = self.depth = 0
        self._host_tree = {}
        z = mi.UInt32(np.array([INVALID], np.uint32))
        self._child = z

    # ------------------------------------------------------------------ importance (device)
    def _child_importance(self, j, p, n, active):
        """Importance of child slot j (see the module docstring) at receiver (p, n)."""
        lo = dr.gather(mi.Point3f, self._clo, j, active)
        hi = dr.gather(mi.Point3f, self._chi, j, active)
        phi = dr.gather(mi.Float, self._cpow, j, active)
        axis = dr.gather(mi.Vector3f, self._caxis, j, active)
        cos_o = dr.gather(mi.Float, self._ccos, j, active)
        c = 0.5 * (lo + hi)
        r = 0.5 * dr.norm(hi - lo)
        v = c - p
        d2 = dr.squared_norm(v)
        d = dr.sqrt(d2)
        inside = d <= r
        inv_d = dr.rcp(dr.maximum(d, 1e-20))
        theta_u = dr.asin(dr.clip(r * inv_d, 0.0, 1.0))
        theta = dr.acos(dr.clip(-dr.dot(axis, v) * inv_d, -1.0, 1.0))
        theta_o = dr.acos(dr.clip(cos_o, -1.0, 1.0))
        tp = dr.maximum(theta - theta_o - theta_u, 0.0)
        emit = dr.select(tp < _HALF_PI, dr.cos(tp), 0.0)
        ti = dr.acos(dr.clip(dr.dot(n, v) * inv_d, -1.0, 1.0))
        tip = dr.maximum(ti - theta_u, 0.0)
        recv = dr.select(tip < _HALF_PI, dr.cos(tip), 0.0)
        far = phi * emit * recv / dr.maximum(d2, 1e-20)
        near = phi / dr.maximum(r * r, 1e-20)
        w = dr.select(inside, near, far)
        return dr.select(active & dr.isfinite(w), w, 0.0), dr.select(active, phi, 0.0)

    def _node_weights(self, node, p, n, active):
        """The 8 child weights of ``node`` and their total (power-proportional fallback where all are 0)."""
        ws, ps = [], []
        for k in range(WIDTH):
            w, ph = self._child_importance(node * WIDTH + k, p, n, active)
            ws.append(w)
            ps.append(ph)
        tot = ws[0]
        ptot = ps[0]
        for k in range(1, WIDTH):
            tot = tot + ws[k]
            ptot = ptot + ps[k]
        fb = tot <= 0.0
        ws = [dr.select(fb, ps[k], ws[k]) for k in range(WIDTH)]
        return ws, dr.select(fb, ptot, tot)

    def _leaf_weights(self, leaf, p, n, active):
        l0 = dr.gather(mi.UInt32, self._leaf_l0, leaf, active)
        l1 = dr.gather(mi.UInt32, self._leaf_l1, leaf, active)
        has1 = active & (l1 != INVALID)
        ws = []
        pw = []
        for l, a in ((l0, active), (l1, has1)):
            t = self.tris
            w = triangle_irradiance(p, n, dr.gather(mi.Point3f, t.p0, l, a), dr.gather(mi.Vector3f, t.e1, l, a),
                                    dr.gather(mi.Vector3f, t.e2, l, a), dr.gather(mi.Color3f, t.radiance, l, a), a)
            ws.append(dr.select(a, w, 0.0))
            pw.append(dr.select(a, dr.maximum(dr.gather(mi.Float, t.power, l, a), 1e-30), 0.0))
        tot = ws[0] + ws[1]
        fb = tot <= 0.0
        ws = [dr.select(fb, pw[k], ws[k]) for k in range(2)]
        return (l0, l1), ws, dr.select(fb, pw[0] + pw[1], tot)

    # ------------------------------------------------------------------ LightSampler protocol
    def _light_state(self):
        """Host copy of what the tree depends on: triangle vertices and power (for ``rebuild="change"``)."""
        if self.count == 0:
            return np.zeros((0, 10))
        h = self.tris.host_arrays()
        return np.concatenate([h["p0"], h["e1"], h["e2"], h["power"][:, None]], 1)

    def begin_frame(self, ctx) -> None:
        """Rebuild the hierarchy over this frame's light positions: every frame (``rebuild="frame"``, Sec. 7:
        the paper's baseline, "construction ... each frame"), or only when a light moved or changed its power
        (``rebuild="change"``, ours; the build time then drops to a host comparison for static lights)."""
        self.tris = ctx.tris
        if self.rebuild == "change":
            state = self._light_state()
            if state.shape == self._state.shape and np.array_equal(state, self._state):
                self.build_ms = 0.0
                return
            self._state = state
        self.build()

    def sample(self, p, n, u, active, p_prev=None):
        """(light id, pmf) by stochastic top-down traversal with one uniform ``u`` (rescaled per level)."""
        p, n = mi.Point3f(p), mi.Vector3f(n)
        u = mi.Float(u)
        width = dr.width(u)
        active = mi.Bool(active) & dr.full(mi.Bool, self.count > 0, width)
        if self.count == 0:
            return dr.full(mi.UInt32, INVALID, width), dr.zeros(mi.Float, width)
        node = dr.zeros(mi.UInt32, width)
        pmf = dr.full(mi.Float, 1.0, width)
        leaf = dr.full(mi.UInt32, INVALID, width)
        going = mi.Bool(active)

        def cond(node, leaf, pmf, u, going):
            return going

        def body(node, leaf, pmf, u, going):
            ws, tot = self._node_weights(node, p, n, going)
            x = u * tot
            acc = mi.Float(0.0)
            pick = mi.UInt32(WIDTH - 1)
            wsel = ws[WIDTH - 1]
            lo_sel = acc
            found = mi.Bool(False)
            for k in range(WIDTH):
                nxt = acc + ws[k]
                take = ~found & (x < nxt) & (ws[k] > 0.0)
                pick = dr.select(take, k, pick)
                wsel = dr.select(take, ws[k], wsel)
                lo_sel = dr.select(take, acc, lo_sel)
                found |= take
                acc = nxt
            # guard against rounding: the last child with positive weight
            last = mi.UInt32(0)
            for k in range(WIDTH):
                last = dr.select(ws[k] > 0.0, k, last)
            wl = ws[0]
            lol = mi.Float(0.0)
            a2 = mi.Float(0.0)
            for k in range(WIDTH):
                wl = dr.select(last == k, ws[k], wl)
                lol = dr.select(last == k, a2, lol)
                a2 = a2 + ws[k]
            pick = dr.select(found, pick, last)
            wsel = dr.select(found, wsel, wl)
            lo_sel = dr.select(found, lo_sel, lol)
            u2 = dr.clip((x - lo_sel) / dr.maximum(wsel, 1e-30), 0.0, _ONE_MINUS)
            ok = going & (wsel > 0.0) & (tot > 0.0)
            ref = dr.gather(mi.UInt32, self._child, node * WIDTH + pick, ok)
            is_leaf = (ref & LEAF_BIT) != 0
            pmf = dr.select(going, dr.select(ok, pmf * (wsel / tot), 0.0), pmf)
            leaf = dr.select(ok & is_leaf, ref & ~mi.UInt32(LEAF_BIT), leaf)
            node = dr.select(ok & ~is_leaf, ref, node)
            u = dr.select(going, u2, u)
            going = ok & ~is_leaf
            return node, leaf, pmf, u, going

        node, leaf, pmf, u, going = dr.while_loop((node, leaf, pmf, u, going), cond, body,
                                                  labels=("node", "leaf", "pmf", "u", "going"),
                                                  label="lighttree_sample")
        ok = active & (leaf != INVALID)
        (l0, l1), ws, tot = self._leaf_weights(leaf, p, n, ok)
        first = u * tot < ws[0]
        light = dr.select(first | (ws[1] <= 0.0), l0, l1)
        w = dr.select(first | (ws[1] <= 0.0), ws[0], ws[1])
        pmf = pmf * w / dr.maximum(tot, 1e-30)
        ok &= (w > 0.0) & (pmf > 0.0)
        return dr.select(ok, light, INVALID), dr.select(ok, pmf, 0.0)

    def pmf(self, p, n, light_id, active, p_prev=None):
        """Exact probability that :meth:`sample` returns ``light_id`` at (p, n): product of the branch
        probabilities along the light's leaf-to-root chain."""
        p, n, light_id, active = pmf_inputs(p, n, light_id, active, self.count)
        if self.count == 0:
            return dr.zeros(mi.Float, dr.width(light_id))
        leaf = dr.gather(mi.UInt32, self._light_leaf, light_id, active)
        slot = dr.gather(mi.UInt32, self._light_slot, light_id, active)
        (l0, l1), ws, tot = self._leaf_weights(leaf, p, n, active)
        prob = dr.select(slot == 0, ws[0], ws[1]) / dr.maximum(tot, 1e-30)
        node = dr.gather(mi.UInt32, self._leaf_par, leaf, active)
        kslot = dr.gather(mi.UInt32, self._leaf_pslot, leaf, active)
        going = active & (prob > 0.0)

        def cond(node, kslot, prob, going):
            return going

        def body(node, kslot, prob, going):
            ws, tot = self._node_weights(node, p, n, going)
            w = ws[0]
            for k in range(1, WIDTH):
                w = dr.select(kslot == k, ws[k], w)
            prob = dr.select(going, dr.select(tot > 0.0, prob * (w / tot), 0.0), prob)
            par = dr.gather(mi.UInt32, self._node_par, node, going)
            ps = dr.gather(mi.UInt32, self._node_pslot, node, going)
            node = dr.select(going, par, node)
            kslot = dr.select(going, ps, kslot)
            going = going & (par != INVALID) & (prob > 0.0)
            return node, kslot, prob, going

        node, kslot, prob, going = dr.while_loop((node, kslot, prob, going), cond, body,
                                                 labels=("node", "kslot", "prob", "going"), label="lighttree_pmf")
        return dr.select(active, prob, 0.0)

    def record(self, p, n, light_id, visible, active) -> None:
        """The light hierarchy learns nothing from samples."""

    def end_frame(self) -> None:
        pass

    def stats(self) -> dict:
        return {"lights": self.count, "nodes": self.nodes, "leaves": self.leaves, "depth": self.depth,
                "build_ms": self.build_ms, "preprocess_ms": self.build_ms, "builds": self.builds,
                "rebuild": self.rebuild, "device_build": self.device_build}


register("lighttree", LightTreeSelector, "light BVH with importance per node (Conty & Kulla 2018; pbrt-v4 12.6.3)")
