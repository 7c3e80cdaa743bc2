"""Probe relocation and classification (Majercik et al., JCGT 2021, "Scaling Probe-Based Real-Time
Dynamic Global Illumination for Production", Sec. 5; conventions of the RTXGI SDK).

From one frame's rays of a probe (directions and signed hit distances, back
faces negative as ``-0.2 t``):

* **relocation**: if more than ``backface_threshold`` of the rays hit back
  faces the probe is inside geometry and moves through the closest back face
  (to ``t + 0.5 * min_frontface``); otherwise, if the closest front face is
  nearer than ``min_frontface``, it moves away from it. The offset is clamped
  to ``max_offset`` cells per axis (0.45: a probe never leaves its cell).
* **classification**: a probe is inactive when its back-face ratio exceeds the
  threshold or no front-face hit lies within its cell neighbourhood
  (``|t w_i| <= spacing_i`` on every axis, unbounded outwards for probes on the
  grid boundary, which serve the space beyond it); inactive probes trace no update rays
  and get zero weight at query time. They are re-tested with a few fixed rays
  every few frames (see the techniques), so they wake up when geometry moves.
"""
from __future__ import annotations

import numpy as np

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

    def update(self, volume: ProbeVolume, probe_ids: np.ndarray, dirs: np.ndarray, dist: np.ndarray) -> dict:
        """Apply relocation then classification for ``probe_ids`` from their rays.

        ``dirs`` (N, 3) shared directions or (P, N, 3); ``dist`` (P, N) signed distances.
        Returns counts ``{'moved', 'deactivated', 'activated'}``.
        """
        st = volume.state
        pid = np.asarray(probe_ids, np.int64)
        if len(pid) == 0 or not (self.relocate or self.classify):
            return {"moved": 0, "deactivated": 0, "activated": 0}
        dist = np.asarray(dist, np.float32)
        shared = np.ndim(dirs) == 2
        dirs = np.asarray(dirs, np.float32)
        back = dist < 0.0
        front = (dist > 0.0) & np.isfinite(dist)
        n = dist.shape[1]
        back_ratio = back.sum(1) / n
        t_back = np.where(back, dist * np.float32(-1.0 / BACKFACE_DISTANCE_SCALE), np.float32(np.inf))
        t_front = np.where(front, dist, np.float32(np.inf))
        rows = np.arange(len(pid))
        moved = np.zeros(len(pid), bool)
        spacing = volume.grid.spacing_np

        if self.relocate:
            min_front = self.min_frontface * volume.grid.min_spacing
            i_back = np.argmin(t_back, 1)
            i_front = np.argmin(t_front, 1)
            tb, tf = t_back[rows, i_back], t_front[rows, i_front]
            db = dirs[i_back] if shared else dirs[rows, i_back]
            df = dirs[i_front] if shared else dirs[rows, i_front]
            off = st.offsets[pid].astype(np.float64)
            inside = (back_ratio > self.backface_threshold) & np.isfinite(tb)
            close = ~inside & np.isfinite(tf) & (tf < min_front)
            new = off.copy()
            new[inside] += db[inside] * (tb[inside] + 0.5 * min_front)[:, None]
            new[close] -= df[close] * (min_front - tf[close])[:, None]
            lim = self.max_offset * spacing
            clamped = np.any(np.abs(new) > lim, axis=1)
            new = np.clip(new, -lim, lim)
            # a probe whose wanted move hit the bound cannot escape: let classification decide now
            moved = (np.max(np.abs(new - off) / spacing, axis=1) > 1e-4) & ~(inside & clamped)
            st.offsets[pid] = new.astype(np.float32)

        old_state = st.states[pid].copy()
        if self.classify:
            # hit offsets from the probe must lie within one cell on every axis; a probe on the
            # boundary of the grid also serves everything beyond it (queries clamp onto it).
            # Per ray: distance at which it leaves that box, min over axes (P x N, no P x N x 3 arrays)
            coords = volume.grid.probe_coords(pid)
            last = np.asarray(volume.grid.counts) - 1
            lo = np.where(coords == 0, np.inf, spacing).astype(np.float32)      # extent on the - side
            hi = np.where(coords == last, np.inf, spacing).astype(np.float32)   # extent on the + side
            t_exit = np.full(dist.shape, np.inf, np.float32)
            with np.errstate(divide="ignore", invalid="ignore"):
                for i in range(3):
                    di = dirs[:, i][None, :] if shared else dirs[..., i]
                    inv = np.float32(1.0) / np.abs(di)
                    lim = np.where(di > 0, hi[:, i:i + 1] * inv, lo[:, i:i + 1] * inv)
                    np.minimum(t_exit, np.nan_to_num(lim, nan=np.inf), out=t_exit)
            near = front & (dist <= t_exit)
            active = (back_ratio <= self.backface_threshold) & near.any(1)
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
