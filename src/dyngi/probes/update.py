"""One probe-volume update per frame, assembled from replaceable pieces.

``ProbeUpdater(volume, directions, shader, blender, states, query)``:

1. choose rays (``directions.plan(frame, seed, ids, previous=last_results)``)
   for the active probes, optionally masked (e.g. Q-DDGI's camera-frustum
   culling); the planner sees the previous update's per-ray results
   (:attr:`ProbeUpdater.last_results`: radiance, distance and their plan);
2. trace them in one batch and shade the hits (``shader``), reading the
   previous frame's probes through ``query`` for multi-bounce;
3. blend into the texels (``blender``: an estimator + a temporal accumulator);
4. relocate / classify from the same rays (``states``; the probes of a plan
   without a shared set are handed over grouped by their ray count); every
   ``reclassify_interval`` frames the inactive probes trace ``classify_rays``
   fixed directions so that they can wake up when the scene changes.

Any piece can be swapped: ADGI replaces 1 and 3 (a Metropolis-chain planner
returning a ragged plan, :class:`~dyngi.probes.blend.MovingAverageBlend` with the
binned scatter estimator), IS-DDGI replaces 1 (ragged counts per probe),
DDGI Resampling consumes the volume through another ``query`` call site.
"""
from __future__ import annotations

import numpy as np

from .rays import FixedSFDirections
from .states import ProbeStates
from .trace import trace_probe_distances, trace_probe_rays, vector_to_numpy
from .volume import ProbeVolume
from ..timing import maybe_stage

UPDATE_STAGES = ("trace probes", "shade probes", "blend", "states")   # the timer stages of one update


class ProbeUpdater:
    def __init__(self, volume: ProbeVolume, directions, shader, blender, states: ProbeStates | None = None,
                 query=None, reclassify_interval: int = 8, classify_rays: int = 32):
        self.volume = volume
        self.directions = directions
        self.shader = shader
        self.blender = blender
        self.states = states
        self.query = query
        self.reclassify_interval = int(reclassify_interval)
        self.classify_dirs = FixedSFDirections(classify_rays, stream=3)
        self.last_results = None

    def probes_to_trace(self, probe_mask: np.ndarray | None = None) -> np.ndarray:
        """Ids (uint32) of the probes the next update traces: active ones, within ``probe_mask``."""
        live = self.volume.state.states != 0
        if probe_mask is not None:
            live &= probe_mask
        return np.flatnonzero(live).astype(np.uint32)

    def probes_to_reclassify(self, frame: int, probe_mask: np.ndarray | None = None,
                             force: bool = False) -> np.ndarray:
        """Ids (uint32) of the inactive probes that re-test their state this frame (none on most frames)."""
        if self.states is None or not self.states.classify or \
                not (force or (self.reclassify_interval > 0 and frame % self.reclassify_interval == 0)):
            return np.zeros(0, np.uint32)
        dead = np.flatnonzero(self.volume.state.states == 0).astype(np.uint32)
        return dead if probe_mask is None else dead[probe_mask[dead]]

    def update(self, scene, frame: int, seed: int, probe_mask: np.ndarray | None = None, timer=None,
               force_reclassify: bool = False) -> dict:
        """Run one update; returns counts (probes traced, rays, state changes)."""
        vol = self.volume
        ids = self.probes_to_trace(probe_mask)
        info = {"probes_traced": int(len(ids)), "moved": 0, "deactivated": 0, "activated": 0}
        plan = self.directions.plan(frame, seed, ids, previous=self.last_results) if len(ids) else None
        if plan is not None and plan.n_rays:      # (a planner may give every probe 0 rays)
            res = trace_probe_rays(scene, vol, plan, self.shader, self.query, seed, frame, timer=timer)
            self.last_results = res
            matrix = getattr(self.blender, "estimator_for", None)
            if matrix is None or matrix(plan).name == "matrix":
                with maybe_stage(timer, "blend"):
                    res.host()      # the blend's host copies, pulled before anything else is queued
            info["rays"] = plan.n_rays
            finish_states = None
            if self.states is not None:
                # the state summaries' kernels run on Dr.Jit's pool beside the blend's host products
                with maybe_stage(timer, "states", sync=False):
                    dirs = plan.shared_directions
                    if dirs is None:
                        finish_states = _states_by_count(self.states, vol, plan, res)
                    else:
                        dist = res.distance    # device array: per-ray work stays in Dr.Jit
                        finish_states = self.states.begin(vol, ids, dirs, dist)
            with maybe_stage(timer, "blend"):
                self.blender.update(vol, res)
            if finish_states is not None:
                with maybe_stage(timer, "states"):
                    c = finish_states()
                    for k in c:
                        info[k] += c[k]
        # -- re-test inactive probes with fixed rays --
        dead = self.probes_to_reclassify(frame, probe_mask, force_reclassify)
        if len(dead):
            with maybe_stage(timer, "states"):
                plan = self.classify_dirs.plan(frame, seed, dead)
                dist = trace_probe_distances(scene, vol, plan)
                c = self.states.update(vol, dead, plan.shared_directions, dist)
                for k in c:
                    info[k] += c[k]
            if timer is not None:
                timer.add_rays("states", len(dead) * self.classify_dirs.n)
        info.setdefault("rays", 0)
        return info


def _states_by_count(states: ProbeStates, volume: ProbeVolume, plan, res):
    """Relocation/classification for a plan without a shared set: ``ProbeStates`` takes a constant ray
    count per call, so the probes are grouped by their count (one call per distinct count, not per
    probe; probes without rays keep their state). Host arrays (the per-ray directions come back)."""
    counts = plan.counts
    groups = [c for c in np.unique(counts) if c > 0]
    if not groups:
        return None
    dirs = vector_to_numpy(plan.direction).T          # (R, 3)
    dist = res.host()[1]
    pending = []
    for c in groups:
        slots = np.flatnonzero(counts == c)
        rows = plan.offsets[slots][:, None] + np.arange(c)[None, :]
        pending.append(states.begin(volume, plan.probe_ids[slots], dirs[rows], dist[rows]))

    def finish():
        total = {"moved": 0, "deactivated": 0, "activated": 0}
        for f in pending:
            for k, v in f().items():
                total[k] += v
        return total
    return finish




def probes_in_frustum(volume: ProbeVolume, camera, res, margin: float = 1.4) -> np.ndarray:
    """(P,) bool: probes inside the camera frustum extended to ``|clip xy| <= margin`` (ADGI Fig. 6b).

    Probes behind the camera but within one cell diagonal of it also count, so
    that probes around the viewer (which light what it sees) keep updating.
    """
    left, up, d = camera.frame()
    o = np.asarray(camera.origin, np.float64)
    w, h = res
    tanx = np.tan(np.radians(camera.fov) * 0.5)
    tany = tanx * h / w
    rel = volume.positions() - o
    z = rel @ d
    x = (rel @ left) / np.maximum(z, 1e-9) / tanx
    y = (rel @ up) / np.maximum(z, 1e-9) / tany
    inside = (z > 0) & (np.abs(x) <= margin) & (np.abs(y) <= margin)
    near = np.linalg.norm(rel, axis=1) <= volume.grid.cell_diagonal
    return inside | near
