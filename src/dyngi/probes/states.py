"""Probe relocation and classification (Majercik et al., JCGT 2021, "Scaling Probe-Based Real-Time
Dynamic Global Illumination for Production", Sec. 5; conventions of the RTXGI SDK).

From one frame's rays of a probe (directions and signed hit distances, back
faces negative as ``-0.2 t``):

* **relocation**: if more than ``backface_threshold`` of the rays hit back
  faces the probe is inside geometry and moves through the closest back face
  (to ``t + 0.5 * min_frontface``); otherwise, if the closest front face is
  nearer than ``min_frontface``, it moves away from it. The offset is clamped
  to ``max_offset`` cells per axis (0.45: a probe never leaves its cell).
  **A move never passes through a surface** (ours; issue 22): where the
  volume knows the geometry its rays were traced in (``volume.geometry``), every
  wanted move is checked by a ray along it -- a probe moving away from a front
  face stops short of the first surface behind it (keeping ``min(min_frontface,
  s / 2)`` from it, ``s`` that surface's distance), and a probe leaving geometry
  crosses exactly the one surface it is inside of and stops short of the next
  the same way. Which back hits mean "inside" is the tracer's two-sided rule
  (:mod:`dyngi.probes.trace`): without the check a probe inside a slab thinner
  than ``min_frontface`` (or pushed from one face of a thin wall) left through
  the other side -- the roof layer of a sealed room ended above the sunlit roof.
  **The exit is a face on the grid's side** (ours; issue 36): of the back faces a probe
  inside geometry sees, the closest one whose ray does not point out of the grid through
  a boundary side of the probe's neighbourhood (see classification) is its exit; only a probe
  with no such back face takes the closest one. A boundary layer that starts inside a wall,
  floor or roof (a loaded scene's bounding-box grid around thick slabs) otherwise left through
  the slab's nearer *outer* face and the room lost that layer (``sunlit-classroom``: ddgi
  1.12 of Mitsuba's mean; docs/probes.md).
* **classification**: a probe is inactive when its back-face ratio exceeds the
  threshold or no front-face hit lies within its cell neighbourhood
  (``|t w_i| <= spacing_i`` on every axis, unbounded outwards for probes on the
  grid boundary, which serve the space beyond it); inactive probes trace no update rays
  and get zero weight at query time. They are re-tested with a few fixed rays
  every few frames (see the techniques), so they wake up when geometry moves.
"""
from __future__ import annotations

import numpy as np

from ..backend import dr, mi
from ..rays import intersect
from ..scene.passthrough import intersect_through_glass, scene_has_glass
from .arrays import upload
from .grid import PROBE_ACTIVE, PROBE_INACTIVE
from .trace import BACKFACE_DISTANCE_SCALE
from .volume import ProbeVolume


class ProbeStates:
    """Relocation + classification policy.

    Parameters
    ----------
    relocate : bool = True
    classify : bool = True
    backface_threshold : float = 0.25   fraction of back-face hits marking a probe as inside geometry
    min_frontface : float = 0.3         wanted clearance to the nearest front face, in units of the smallest spacing
    max_offset : float = 0.45           bound of the relocation offset, in cells per axis
    """

    def __init__(self, relocate: bool = True, classify: bool = True, backface_threshold: float = 0.25,
                 min_frontface: float = 0.3, max_offset: float = 0.45):
        self.relocate = bool(relocate)
        self.classify = bool(classify)
        self.backface_threshold = float(backface_threshold)
        self.min_frontface = float(min_frontface)
        self.max_offset = float(max_offset)

    def update(self, volume: ProbeVolume, probe_ids: np.ndarray, dirs: np.ndarray, dist) -> dict:
        """Apply relocation then classification for ``probe_ids`` from their rays.

        ``dirs`` (N, 3) shared directions or (P, N, 3); ``dist`` (P, N) signed distances,
        as a NumPy array or as the flat Dr.Jit Float of the traced rays (probe-major), in
        which case the per-ray work runs as Dr.Jit block reductions and only (P,) summaries
        come back to the host.
        Returns counts ``{'moved', 'deactivated', 'activated'}``.
        """
        return self.begin(volume, probe_ids, dirs, dist)()

    def begin(self, volume: ProbeVolume, probe_ids: np.ndarray, dirs: np.ndarray, dist):
        """:meth:`update` in two halves: launch the per-ray Dr.Jit reductions now and return ``finish()``,
        which waits for their (P,) summaries and applies relocation and classification.

        In between the kernels run on Dr.Jit's pool while the host does other
        work (the probe update's blend products), instead of after it.
        """
        pid = np.asarray(probe_ids, np.int64)
        if len(pid) == 0 or not (self.relocate or self.classify):
            return lambda: {"moved": 0, "deactivated": 0, "activated": 0}
        shared = np.ndim(dirs) == 2
        dirs = np.asarray(dirs, np.float32)
        if isinstance(dist, np.ndarray) or not shared:
            return lambda: self._apply(volume, pid, dirs, shared, _summaries_numpy(
                volume, pid, dirs, np.asarray(dist, np.float32).reshape(len(pid), -1), shared))
        pending = _summaries_drjit(volume, pid, dirs, dist)
        return lambda: self._apply(volume, pid, dirs, shared, pending())

    def _apply(self, volume: ProbeVolume, pid: np.ndarray, dirs: np.ndarray, shared: bool, sm: dict) -> dict:
        st = volume.state
        back_ratio, tb, tf, near_any = sm["back_ratio"], sm["t_back"], sm["t_front"], sm["near_any"]
        rows = np.arange(len(pid))
        moved = np.zeros(len(pid), bool)
        spacing = volume.grid.spacing_np

        if self.relocate:
            min_front = self.min_frontface * volume.grid.min_spacing
            db = dirs[sm["i_back"]] if shared else dirs[rows, sm["i_back"]]
            df = dirs[sm["i_front"]] if shared else dirs[rows, sm["i_front"]]
            off = st.offsets[pid].astype(np.float64)
            inside = (back_ratio > self.backface_threshold) & np.isfinite(tb)
            close = ~inside & np.isfinite(tf) & (tf < min_front)
            new = off.copy()
            new[inside] += db[inside] * (tb[inside] + 0.5 * min_front)[:, None]
            new[close] -= df[close] * (min_front - tf[close])[:, None]
            lim = self.max_offset * spacing
            clamped = np.any(np.abs(new) > lim, axis=1)
            new = np.clip(new, -lim, lim)
            if volume.geometry is not None:
                want = (inside | close) & (np.max(np.abs(new - off) / spacing, axis=1) > 1e-4)
                if want.any():
                    base = volume.grid.base_positions()[pid[want]]
                    new[want] = safe_moves(volume.geometry, base + off[want], base + new[want],
                                           inside[want], min_front) - base
            # a probe whose wanted move hit the bound cannot escape: let classification decide now
            moved = (np.max(np.abs(new - off) / spacing, axis=1) > 1e-4) & ~(inside & clamped)
            st.offsets[pid] = new.astype(np.float32)

        old_state = st.states[pid].copy()
        if self.classify:
            active = (back_ratio <= self.backface_threshold) & near_any
            # a probe that just moved keeps its state until rays from its new place decide
            new_state = np.where(moved, old_state, np.where(active, PROBE_ACTIVE, PROBE_INACTIVE)).astype(np.uint8)
            st.states[pid] = new_state
            woke = (old_state == PROBE_INACTIVE) & (new_state == PROBE_ACTIVE)
            st.updates[pid[woke]] = 0       # stale history: take the next estimate directly
        counts = {"moved": int(moved.sum()),
                  "deactivated": int(((old_state == PROBE_ACTIVE) & (st.states[pid] == PROBE_INACTIVE)).sum()),
                  "activated": int(((old_state == PROBE_INACTIVE) & (st.states[pid] == PROBE_ACTIVE)).sum())}
        if counts["moved"] or counts["deactivated"] or counts["activated"]:
            volume.sync(("positions", "states"))
        return counts


def cell_extents(volume: ProbeVolume, pid: np.ndarray):
    """Per probe, the distance to its neighbourhood's faces on the - and + side of each axis.

    One cell (the spacing) inside the grid; unbounded outwards for probes on the
    grid boundary, which serve everything beyond it (queries clamp onto them).
    """
    spacing = volume.grid.spacing_np
    coords = volume.grid.probe_coords(pid)
    last = np.asarray(volume.grid.counts) - 1
    lo = np.where(coords == 0, np.inf, spacing).astype(np.float32)
    hi = np.where(coords == last, np.inf, spacing).astype(np.float32)
    return lo, hi


def _summaries_numpy(volume, pid, dirs, dist, shared):
    """Per-probe summaries of the rays (host): back-face ratio, closest back/front hit and its ray,
    whether any front-face hit lies within the cell neighbourhood."""
    back = dist < 0.0
    front = (dist > 0.0) & np.isfinite(dist)
    n = dist.shape[1]
    t_back = np.where(back, dist * np.float32(-1.0 / BACKFACE_DISTANCE_SCALE), np.float32(np.inf))
    t_front = np.where(front, dist, np.float32(np.inf))
    rows = np.arange(len(pid))
    i_front = np.argmin(t_front, 1)
    lo, hi = cell_extents(volume, pid)
    # per ray: distance at which it leaves the neighbourhood box, min over axes
    t_exit = np.full(dist.shape, np.inf, np.float32)
    outward = np.zeros(dist.shape, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(3):
            di = dirs[:, i][None, :] if shared else dirs[..., i]
            inv = np.float32(1.0) / np.abs(di)
            lim = np.where(di > 0, hi[:, i:i + 1] * inv, lo[:, i:i + 1] * inv)
            np.minimum(t_exit, np.nan_to_num(lim, nan=np.inf), out=t_exit)
            outward |= (di != 0) & np.isinf(np.where(di > 0, hi[:, i:i + 1], lo[:, i:i + 1]))
    # the exit of a probe inside geometry: the closest back face not out of the grid (ours), else the closest
    t_in = np.where(outward, np.float32(np.inf), t_back)
    i_back = np.where(np.isfinite(t_in).any(1), np.argmin(t_in, 1), np.argmin(t_back, 1))
    return {"back_ratio": back.sum(1) / n, "t_back": t_back[rows, i_back], "t_front": t_front[rows, i_front],
            "i_back": i_back, "i_front": i_front, "near_any": (front & (dist <= t_exit)).any(1)}


def _summaries_drjit(volume, pid, dirs, dist):
    """The same summaries as :func:`_summaries_numpy` from the device distances of a shared
    direction set: one lane per probe walks its ``N`` rays in a symbolic loop (``N`` opaque: a budget
    changes it per frame, and a block reduction over ``N`` rays would bake it into the kernels);
    launched here without waiting; returns a function that collects the (P,) arrays on the host."""
    P, N = len(pid), len(dirs)
    d = mi.Float(dist)
    nn = dr.opaque(mi.UInt32, N)
    inf = dr.inf
    dset = mi.Float(np.ascontiguousarray(dirs, np.float32).ravel())
    lo, hi = cell_extents(volume, pid)
    lo_d = dr.gather(mi.Vector3f, mi.Float(np.ascontiguousarray(lo).ravel()), dr.arange(mi.UInt32, P))
    hi_d = dr.gather(mi.Vector3f, mi.Float(np.ascontiguousarray(hi).ravel()), dr.arange(mi.UInt32, P))
    base = dr.arange(mi.UInt32, P) * nn

    def body(r, n_back, n_near, tb, tf, ib, i_f, b_out):
        x = dr.gather(mi.Float, d, base + r)
        back = x < 0.0
        front = (x > 0.0) & dr.isfinite(x)
        t_back = dr.select(back, x * (-1.0 / BACKFACE_DISTANCE_SCALE), inf)
        t_front = dr.select(front, x, inf)
        w = dr.gather(mi.Vector3f, dset, r)
        ext = dr.select(w > 0.0, hi_d, lo_d)
        t_axis = dr.select(dr.abs(w) > 0.0, ext / dr.abs(w), inf)
        t_exit = dr.minimum(dr.minimum(t_axis.x, t_axis.y), t_axis.z)
        out = (((dr.abs(w.x) > 0.0) & ~dr.isfinite(ext.x)) | ((dr.abs(w.y) > 0.0) & ~dr.isfinite(ext.y))
               | ((dr.abs(w.z) > 0.0) & ~dr.isfinite(ext.z)))      # out of the grid's boundary side
        n_back += mi.UInt32(back)
        n_near += mi.UInt32(front & (x <= t_exit))
        # strict: the first ray reaching the minimum (argmin); a back face not out of the grid first (ours)
        nb = back & ((b_out & ~out) | ((b_out == out) & (t_back < tb)))
        nf = front & (t_front < tf)
        tb = dr.select(nb, t_back, tb)
        ib = dr.select(nb, r, ib)
        b_out = dr.select(nb, out, b_out)
        tf = dr.select(nf, t_front, tf)
        i_f = dr.select(nf, r, i_f)
        return r + 1, n_back, n_near, tb, tf, ib, i_f, b_out

    big = dr.zeros(mi.UInt32, P) + nn   # N when the probe has no such hit
    init = (mi.UInt32(0), dr.zeros(mi.UInt32, P), dr.zeros(mi.UInt32, P), dr.full(mi.Float, inf, P),
            dr.full(mi.Float, inf, P), big, mi.UInt32(big), dr.full(mi.Bool, True, P))
    _, n_back, n_near, tb, tf, ib, i_f, _ = dr.while_loop(init, lambda r, *_: r < nn, body)
    dr.eval(n_back, n_near, tb, tf, ib, i_f)
    return lambda: {"back_ratio": np.asarray(n_back, np.float64) / N, "t_back": np.asarray(tb, np.float32),
                    "t_front": np.asarray(tf, np.float32), "i_back": np.minimum(np.asarray(ib, np.int64), N - 1),
                    "i_front": np.minimum(np.asarray(i_f, np.int64), N - 1), "near_any": np.asarray(n_near) > 0}


def _pad(n: int) -> int:
    """Lane count for ``n`` checked moves: the next power of two (at least 16), so that the checks of
    differently many moving probes reuse a few kernels."""
    return max(16, 1 << (int(n) - 1).bit_length())


def safe_moves(mscene, p0: np.ndarray, p1: np.ndarray, cross: np.ndarray, clearance: float) -> np.ndarray:
    """(M, 3) positions the probes may move to on the segments ``p0 -> p1`` without passing through a
    surface: lanes with ``cross`` (a probe inside geometry) pass the first surface on the way and stop
    before the second, the others stop before the first. Before a surface at distance ``s`` from the
    segment's start (or from the crossed surface) a probe keeps ``min(clearance, s / 2)``. Clear
    surfaces (glass) are no geometry here, as for the probe rays. Two masked ray casts (Dr.Jit)."""
    p0 = np.asarray(p0, np.float64)
    p1 = np.asarray(p1, np.float64)
    M = len(p0)
    d = p1 - p0
    L = np.linalg.norm(d, axis=1)
    u = d / np.maximum(L, 1e-30)[:, None]
    W = _pad(M)
    buf = np.zeros((W, 7), np.float32)
    buf[:M, :3] = p0
    buf[:M, 3:6] = u
    buf[M:, 3] = 1.0
    buf[:M, 6] = np.asarray(cross, np.float32)
    flat = upload(buf)
    idx = dr.arange(mi.UInt32, W)
    ray = mi.Ray3f(mi.Point3f(dr.gather(mi.Float, flat, idx * 7), dr.gather(mi.Float, flat, idx * 7 + 1),
                              dr.gather(mi.Float, flat, idx * 7 + 2)),
                   mi.Vector3f(dr.gather(mi.Float, flat, idx * 7 + 3), dr.gather(mi.Float, flat, idx * 7 + 4),
                               dr.gather(mi.Float, flat, idx * 7 + 5)))
    go2 = dr.gather(mi.Float, flat, idx * 7 + 6) > 0.5
    glass = scene_has_glass(mscene)

    def first_hit(r, active):
        if glass:
            si, _, t, _ = intersect_through_glass(mscene, r, active, stage="relocation")
            return si, dr.select(active & si.is_valid(), t, dr.inf)
        si = intersect(mscene, r, mi.RayFlags.Minimal, False, active, stage="relocation")
        return si, dr.select(active & si.is_valid(), si.t, dr.inf)

    si1, s1 = first_hit(ray, mi.Bool(True))
    again = go2 & dr.isfinite(s1)
    ray2 = si1.spawn_ray(ray.d)
    _, t2 = first_hit(ray2, again)
    s2 = s1 + t2
    dr.eval(s1, s2)
    s1 = np.asarray(s1, np.float64)[:M]
    s2 = np.asarray(s2, np.float64)[:M]
    cross = np.asarray(cross, bool)
    # the surface the move must not reach, and where the free stretch before it begins
    stop = np.where(cross, np.where(s1 < L, s2, np.inf), s1)
    start = np.where(cross & (s1 < L), s1, 0.0)
    room = stop - start
    with np.errstate(invalid="ignore"):
        limit = stop - np.minimum(clearance, 0.5 * room)
    Lf = np.where(np.isfinite(stop), np.clip(np.minimum(L, limit), 0.0, None), L)
    return p0 + u * Lf[:, None]
