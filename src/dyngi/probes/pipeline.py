"""One probe-volume pipeline for the DDGI family: plan, trace/shade, estimate, accumulate, encode.

``ProbePipeline(volume, planner, shader, blend, states, query)`` runs one frame's update from the
five parts of :mod:`.protocols` (Majercik et al., JCGT 2019, Sec. 3; relocation and classification
of Majercik et al., JCGT 2021, Sec. 5):

1. the **planner** chooses rays for the active probes (optionally masked, e.g. Q-DDGI's
   camera-frustum culling), seeing the previous update's per-ray results (:attr:`last_results`);
2. the pipeline traces them in one batch and the **shader** shades the hits, reading the previous
   frame's probes through ``query`` for multi-bounce (:meth:`trace`: the one caller of
   :func:`~dyngi.probes.trace.trace_probe_rays`);
3. the **blend** (an estimator + a temporal accumulator + an encoding, :mod:`.blend`) merges
   them into the texels (:meth:`merge`: the one caller of
   :func:`~dyngi.probes.accumulator.merge_into_volume` outside :mod:`.blend`);
4. the **state update** relocates / classifies probes (:class:`~dyngi.probes.states.ProbeStates`):
   ``state_rays='update'`` (``ddgi``) from the same rays (the probes of a plan without a shared set
   grouped by ray count), and every ``reclassify_interval`` frames the inactive probes trace
   ``classify_rays`` fixed directions so that they can wake up when the scene changes;
   ``state_rays='fixed'`` (``probes-reference``) from the fixed classification rays of every probe
   each frame, before the update.

A separate ``distance_planner`` (``probes-reference``: cosine-power lobes for the moments) is traced
after the irradiance plan without the multi-bounce query; the blend then receives both results.

**Warm-up** (:meth:`warm_up`, shared by every probe technique): ``n`` updates before the first
image with the accumulator's hysteresis at 0 and brightness damping off (our choice: what an engine
does when it loads a level), each reading the previous one's probes, so that after ``k`` updates the
cache holds ``k`` bounces. The warm-up updates *every* probe, whatever the frame's ``probe_mask``
(ours): a technique that culls its updates to the camera frustum (Q-DDGI, ``update_offscreen=False``)
never updates a probe outside it afterwards, and a probe left at zero there darkens every bounce that
reads it (the wooden staircase's hall; docs/probes.md, "The wooden staircase").
A planner's optional ``begin_warmup`` / ``end_warmup`` hooks run around
it; a technique with its own per-update step (IS-DDGI's set integration) passes it as ``step``.

**One frame** (:meth:`step`, shared by ``ddgi``, ``qddgi``, the DDGI+ volume, ``isddgi`` and ``adgi``): the
frame's probe mask (``update_offscreen=False``: the extended camera frustum), the scene's signature (a
change re-tests every inactive probe), the warm-up on the first frame, then the update -- :meth:`update`,
a technique's own update step (IS-DDGI's set integration and states), or a multi-pass update.

**Several traces per frame** (ADGI's pilot, static and dynamic chains, each merged with its own count cap):
the planner is a :class:`~dyngi.probes.protocols.MultiPassPlanner` that yields :class:`ProbePass` es and the
pipeline has a :class:`~dyngi.probes.protocols.PassAccumulator` (:meth:`update_passes`): the pipeline
traces each pass (and its ``-w`` distance rays), the accumulator merges it through :meth:`merge` /
:meth:`merge_slots`, the planner sees the results before it plans the next pass. :meth:`merge_slots` is
:meth:`merge` for a masked plan (:meth:`RayPlan.masked <dyngi.probes.rays.RayPlan.masked>`): its slots and
the probes' update counts stay on the device (ADGI's device path, a frame without a host read).
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ..backend import mi
from ..errors import unknown_choice
from ..timing import StageTimer, maybe_stage
from .accumulator import merge_into_volume, merge_slots_into_volume
from .arrays import upload
from .protocols import check_part
from .rays import FixedSFDirections, RayPlan
from .states import ProbeStates
from .trace import ProbeRayResults, trace_probe_distances, trace_probe_rays, vector_to_numpy
from .volume import ProbeVolume

UPDATE_STAGES = ("trace probes", "shade probes", "blend", "states")   # the timer stages of one update
WARMUP_FRAME_BASE = 1 << 24   # frame indices of warm-up updates: distinct RNG streams from real frames
STATE_RAYS = ("update", "fixed")
_NO_STATE = {"moved": 0, "deactivated": 0, "activated": 0}
_DEFAULT = object()


@dataclass
class ProbePass:
    """One pass of a multi-pass update (:meth:`ProbePipeline.update_passes`), as a
    :class:`~dyngi.probes.protocols.MultiPassPlanner` yields it. Exactly one of three kinds:

    * a **trace** (``plan`` given): the plan traced from the volume's probes and shaded (random stream
      ``stream``, RNG frame ``frame`` -- None: the update's --, ``shader`` -- None: the pipeline's); with
      ``reverse_distances`` a second, unshaded trace along ``-w`` gives the distances (ADGI's shadow rays,
      Sec. 4.8). The accumulator merges the results; the planner receives a :class:`PassResult`;
    * a **state re-test** (``classify`` given: probe ids): relocation/classification from the fixed rays
      (:meth:`ProbePipeline.classify`); the planner receives the state counts;
    * an **accumulator step** (neither): ``accumulator.accumulate(pipeline, pass, None, None)``, its return
      value to the planner (ADGI: the end-of-frame count cap and convolution).

    ``options``: what the accumulator needs to know of this pass (ADGI: N_max, per-lane caps, merge or not).
    """
    name: str
    plan: RayPlan | None = None
    stream: int | None = None
    frame: int | None = None
    shader: Any = None
    reverse_distances: bool = False
    classify: np.ndarray | None = None
    options: dict = field(default_factory=dict)


class PassResult(NamedTuple):
    """What a multi-pass planner receives for a traced :class:`ProbePass`: the shaded results, the distance
    results (``reverse_distances``; else None) and the trace's own timer (its ray counts, stages
    ``trace probes`` / ``shade probes``)."""
    results: ProbeRayResults
    distances: ProbeRayResults | None
    timer: StageTimer


class ProbePipeline:
    """The probe update of the DDGI family; see the module docstring.

    Parameters
    ----------
    volume : ProbeVolume
    planner : RayPlanner          (``directions`` is its older name, kept as an alias)
    shader : HitShader
    blender : Blend               estimator + accumulator + encoding
    states : ProbeStates | None   relocation / classification (None: probes stay where they are)
    query : ProbeQuery | None     the previous probes read at hits (None: one bounce)
    reclassify_interval : int = 8 frames between re-tests of inactive probes (0: never)
    classify_rays : int = 32      fixed spherical-Fibonacci rays of a re-test
    distance_planner : RayPlanner | None   a separate plan for the distance moments
    state_rays : str = 'update'   'update' (from the update's rays) | 'fixed' (classification rays, every frame)
    trace_inactive : bool = False trace every probe (the reference), not only the active ones
    streams : (int, int) = (11, 12)  random streams of the irradiance and distance traces
    plan_stage : str | None = None   timer stage of the planner (None: untimed; IS-DDGI: 'plan')
    warmup : int = 0              updates of :meth:`step`'s warm-up (on its first call)
    accumulator : PassAccumulator | None   with a :class:`~dyngi.probes.protocols.MultiPassPlanner` as the
                                  planner: :meth:`step` runs :meth:`update_passes` (ADGI); the warm-up's
                                  updates stay single-pass (the planner's ``plan``, the ``blender``)
    update_offscreen : bool = True   False: :meth:`step` updates only the probes in the extended camera
                                  frustum (:func:`probes_in_frustum`; Q-DDGI)

    Optional hook of a shader: ``prepare(plan)`` before the plan is traced and ``prepare(None)`` after
    (IS-DDGI's per-ray shading keys).
    """

    def __init__(self, volume: ProbeVolume, planner, shader, blender, states: ProbeStates | None = None,
                 query=None, reclassify_interval: int = 8, classify_rays: int = 32, distance_planner=None,
                 state_rays: str = "update", trace_inactive: bool = False, streams: tuple = (11, 12),
                 plan_stage: str | None = None, warmup: int = 0, update_offscreen: bool = True,
                 accumulator=None):
        check_part("planner", planner)
        check_part("shader", shader)
        if accumulator is not None:
            check_part("multipass", planner)
            check_part("pass accumulator", accumulator)
        if state_rays not in STATE_RAYS:
            raise unknown_choice("state_rays", state_rays, STATE_RAYS)
        self.volume = volume
        self.planner = planner
        self.shader = shader
        self.blender = blender
        self.states = states
        self.query = query
        self.reclassify_interval = int(reclassify_interval)
        self.classify_dirs = FixedSFDirections(classify_rays, stream=3)
        self.distance_planner = distance_planner
        self.state_rays = state_rays
        self.trace_inactive = bool(trace_inactive)
        self.streams = tuple(streams)
        self.plan_stage = plan_stage
        self.warmup = int(warmup)
        self.update_offscreen = bool(update_offscreen)
        self.accumulator = accumulator
        self.last_results = None
        self.last_plan = None
        self.last_warmup_rays = {}  # rays per stage of the warm-up :meth:`step` ran this frame ({}: none)
        self.warmed = False         # has :meth:`step` run its warm-up?
        self.moved = False          # did the scene's signature change since the last :meth:`begin_frame`?
        self._signature = None
        self._history = None      # device update counts of merge_slots (None: the host's are current)

    # -- which probes ---------------------------------------------------------------------------
    def probes_to_trace(self, probe_mask: np.ndarray | None = None) -> np.ndarray:
        """Ids (uint32) of the probes the next update traces: active ones (all with ``trace_inactive``),
        within ``probe_mask``."""
        live = np.ones(self.volume.n_probes, bool) if self.trace_inactive else self.volume.state.states != 0
        if probe_mask is not None:
            live &= probe_mask
        return np.flatnonzero(live).astype(np.uint32)

    def probes_to_reclassify(self, frame: int, probe_mask: np.ndarray | None = None,
                             force: bool = False) -> np.ndarray:
        """Ids (uint32) of the inactive probes that re-test their state this frame (none on most frames)."""
        if self.state_rays != "update" or self.states is None or not self.states.classify or \
                not (force or (self.reclassify_interval > 0 and frame % self.reclassify_interval == 0)):
            return np.zeros(0, np.uint32)
        dead = np.flatnonzero(self.volume.state.states == 0).astype(np.uint32)
        return dead if probe_mask is None else dead[probe_mask[dead]]

    # -- the stages -----------------------------------------------------------------------------
    def trace(self, scene, plan, seed: int, frame: int, stream: int | None = None, timer=None,
              query=_DEFAULT, shader=None):
        """Trace ``plan`` from the volume's probes and shade the hits (stages ``trace probes`` and
        ``shade probes``); ``query`` (default: the pipeline's) feeds multi-bounce, ``shader`` (default:
        the pipeline's) another shading of the same volume (ADGI's pilot rays)."""
        shader = shader or self.shader
        prepare = getattr(shader, "prepare", None)
        if prepare is not None:
            prepare(plan)
        try:
            return trace_probe_rays(scene, self.volume, plan, shader, self.query if query is _DEFAULT else query,
                                    seed, frame, stream=self.streams[0] if stream is None else stream, timer=timer)
        finally:
            if prepare is not None:
                prepare(None)

    def trace_distances(self, scene, plan):
        """Signed hit distances of ``plan``'s rays (no shading): classification rays, ADGI's ``-w`` rays."""
        return trace_probe_distances(scene, self.volume, plan)

    def merge(self, est_irr, est_dist, probe_ids: np.ndarray, rays: np.ndarray | None = None,
              accumulator=None, encoding=None) -> None:
        """Merge per-texel estimates of ``probe_ids`` into the volume through the blend's accumulator and
        encoding (or the given ones: ADGI merges with Algorithm 3's count caps per stage)."""
        b = self.blender
        merge_into_volume(self.volume, est_irr, est_dist, accumulator or b.accumulator, encoding or b.encoding,
                          probe_ids, rays)

    # -- the device path: merges of masked plans, with the update counts on the device --
    @property
    def history(self):
        """Per probe (UInt32, on the device) its update count, for :meth:`merge_slots`: uploaded from the
        host counts on first use and after :meth:`history_to_host` / :meth:`history_from_host`."""
        if self._history is None:
            self._history = upload(self.volume.state.updates.astype(np.uint32), mi.UInt32)
        return self._history

    def history_to_host(self) -> None:
        """Copy the device update counts into the host's (a host read: before a host pass, e.g. relocation
        and classification, that resets the counts of woken probes); then :meth:`history_from_host`."""
        if self._history is not None:
            self.volume.state.updates[:] = np.asarray(self._history, np.int64)

    def history_from_host(self) -> None:
        """Drop the device counts: the next :meth:`merge_slots` uploads the host's again."""
        self._history = None

    def merge_slots(self, est_irr, est_dist, slot_probe, slot_valid, accumulator=None, encoding=None) -> None:
        """:meth:`merge` for estimates over the device slots of a masked plan (``plan.probe_ids`` /
        ``plan.slot_valid``): no host read (:func:`~dyngi.probes.accumulator.merge_slots_into_volume`). The
        update counts live on the device meanwhile (:attr:`history`)."""
        b = self.blender
        merge_slots_into_volume(self.volume, est_irr, est_dist, accumulator or b.accumulator,
                                encoding or b.encoding, slot_probe, slot_valid, self.history)

    def classify(self, scene, probe_ids: np.ndarray, frame: int, seed: int, timer=None) -> dict:
        """Relocation / classification of ``probe_ids`` from ``classify_rays`` fixed rays (stage ``states``).
        With device update counts (:attr:`history`) they are copied to the host before and re-uploaded after."""
        if self.states is None or len(probe_ids) == 0 or not (self.states.relocate or self.states.classify):
            return dict(_NO_STATE)
        device = self._history is not None   # the host pass resets the counts of woken probes: device counts go
        if device:                           # through it (merge_slots' device path)
            self.history_to_host()
        with maybe_stage(timer, "states"):
            plan = self.classify_dirs.plan(frame, seed, probe_ids)
            c = self.states.update(self.volume, probe_ids, plan.shared_directions,
                                   self.trace_distances(scene, plan))
        if device:
            self.history_from_host()
        if timer is not None:
            timer.add_rays("states", len(probe_ids) * self.classify_dirs.n)
        return c

    def begin_states(self, plan, res, states: ProbeStates | None = None):
        """Launch relocation/classification from a trace's own rays; returns ``finish() -> counts`` or None.

        A plan with a shared direction set hands its device distances over (per-ray work stays in
        Dr.Jit); a ragged plan is grouped by ray count (:class:`ProbeStates` takes one count per call;
        one call per distinct count, not per probe; probes without rays keep their state)."""
        states = self.states if states is None else states
        if states is None:
            return None
        dirs = plan.shared_directions
        if dirs is not None:
            return states.begin(self.volume, plan.probe_ids, dirs, res.distance)
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
            pending.append(states.begin(self.volume, plan.probe_ids[slots], dirs[rows], dist[rows]))

        def finish():
            total = dict(_NO_STATE)
            for f in pending:
                for k, v in f().items():
                    total[k] += v
            return total
        return finish

    # -- one update -----------------------------------------------------------------------------
    def update(self, scene, frame: int, seed: int, probe_mask: np.ndarray | None = None, timer=None,
               force_reclassify: bool = False, probe_ids: np.ndarray | None = None, **hints) -> dict:
        """Run one update; returns counts (probes traced, rays, state changes). ``hints`` go to the planner;
        ``probe_ids`` (default :meth:`probes_to_trace`) the probes the planner plans for (IS-DDGI also
        re-tests its inactive ones). :attr:`last_plan` is this update's plan (None: no probe)."""
        vol = self.volume
        info = {"probes_traced": 0, **_NO_STATE}
        if self.state_rays == "fixed":      # -- states from fixed rays, before the update (the reference) --
            _add(info, self.classify(scene, self.probes_to_trace(probe_mask), frame, seed, timer))
        # -- 1. plan --
        ids = self.probes_to_trace(probe_mask) if probe_ids is None else probe_ids
        info["probes_traced"] = int(len(ids))
        plan = None
        if len(ids):
            with maybe_stage(timer if self.plan_stage else None, self.plan_stage):
                plan = self.planner.plan(frame, seed, ids, previous=self.last_results, **hints)
        self.last_plan = plan
        if plan is not None and plan.n_rays:      # (a planner may give every probe 0 rays)
            # -- 2. trace and shade (a separate distance plan without multi-bounce) --
            res = self.trace(scene, plan, seed, frame, timer=timer)
            self.last_results = res
            extra = ()
            if self.distance_planner is not None:
                dplan = self.distance_planner.plan(frame, seed, ids)
                extra = (self.trace(scene, dplan, seed, frame, stream=self.streams[1], timer=timer, query=None),)
            est = getattr(self.blender, "estimator_for", None)
            if est is not None and est(plan).name == "matrix":
                with maybe_stage(timer, "blend"):
                    res.host()      # the blend's host copies, pulled before anything else is queued
            info["rays"] = plan.n_rays
            # -- 4. relocation / classification from the same rays (launched before the blend) --
            finish_states = None
            if self.state_rays == "update" and self.states is not None:
                # the state summaries' kernels run on Dr.Jit's pool beside the blend's host products
                with maybe_stage(timer, "states", sync=False):
                    finish_states = self.begin_states(plan, res)
            # -- 3. estimate, accumulate, encode --
            with maybe_stage(timer, "blend"):
                self.blender.update(vol, res, *extra)
            if finish_states is not None:
                with maybe_stage(timer, "states"):
                    _add(info, finish_states())
        # -- re-test inactive probes with fixed rays --
        dead = self.probes_to_reclassify(frame, probe_mask, force_reclassify)
        if len(dead):
            _add(info, self.classify(scene, dead, frame, seed, timer))
        info.setdefault("rays", 0)
        return info

    # -- one frame: mask, signature, warm-up, update -----------------------------------------------
    def begin_frame(self, scene, frame, timer=None, update=None) -> np.ndarray | None:
        """Steps 1-3 of :meth:`step`; returns the frame's probe mask (None: every probe)."""
        mask = None if self.update_offscreen else probes_in_frustum(self.volume, frame.camera, frame.res)
        sig = scene.signature(frame.time) if hasattr(scene, "signature") else None
        self.moved = sig != self._signature and self._signature is not None
        self._signature = sig
        self.last_warmup_rays = {}
        if not self.warmed:
            self.warmed = True
            step = None if update is None else (lambda k, f, wt: update(f, frame.seed, wt, True, None))
            self.last_warmup_rays = self.warm_up(scene, self.warmup, frame.seed, mask, timer, step=step)
        return mask

    def step(self, scene, frame, timer=None, update=None, before_update=None) -> dict:
        """One frame's probe update, as every probe technique runs it (``ddgi``, ``qddgi``, the DDGI+ volume,
        ``isddgi``); ``frame`` a :class:`~dyngi.techniques.base.Frame` (index, time, camera, res, seed):

        1. the frame's probe mask: with ``update_offscreen=False`` only the probes in the extended camera
           frustum (:func:`probes_in_frustum`);
        2. the scene's signature (``scene.signature(frame.time)``, where the scene has one): a change since the
           last frame (:attr:`moved`) re-tests every inactive probe (``force_reclassify``);
        3. on the first call the shared warm-up (:meth:`warm_up`, ``warmup`` updates), its rays per stage in
           :attr:`last_warmup_rays` (``{}`` on the other frames);
        4. ``before_update(mask)``, when given (``ddgi``'s budget chooses the planner of the frame);
        5. the update: :meth:`update`, or ``update(frame_index, seed, timer, warm, frame)``, a technique's own
           update step (IS-DDGI: the pipeline's update, then its set integration and probe states), which the
           warm-up then runs too (``warm=True``, ``frame=None``).

        Returns the update's counts (probes traced, rays, state changes)."""
        mask = self.begin_frame(scene, frame, timer, update)
        if before_update is not None:
            before_update(mask)
        if update is not None:
            return update(frame.index, frame.seed, timer, False, frame)
        if self.accumulator is not None:
            return self.update_passes(scene, frame, timer)
        return self.update(scene, frame.index, frame.seed, mask, timer, force_reclassify=self.moved)

    def update_passes(self, scene, frame, timer=None) -> dict:
        """A multi-pass update (ADGI's pilot, static and dynamic chains): ``planner.passes(frame, timer)`` is a
        generator of :class:`ProbePass` es; each is run (traced and merged by the accumulator, or a state
        re-test, or an accumulator step) and what it gives (:class:`PassResult`, state counts, the
        accumulator's return) is sent back, so that the next pass may depend on it (ADGI's budget, its
        heuristics from the pilot rays). Returns the generator's return value (the update's counts).
        The planner times its passes itself (a timer stage may enclose a ``yield``)."""
        gen = self.planner.passes(frame, timer)
        reply = None
        while True:
            try:
                ps = gen.send(reply)
            except StopIteration as stop:
                return dict(stop.value or {})
            if ps.classify is not None:
                reply = self.classify(scene, ps.classify, frame.index, frame.seed, timer)
            elif ps.plan is None:
                reply = self.accumulator.accumulate(self, ps, None, None)
            else:
                tt = StageTimer()
                res = self.trace(scene, ps.plan, frame.seed, frame.index if ps.frame is None else ps.frame,
                                 stream=ps.stream, timer=tt, shader=ps.shader)
                dist = None
                if ps.reverse_distances:
                    back = ps.plan.reversed()
                    dist = ProbeRayResults(res.radiance, self.trace_distances(scene, back), back)
                self.accumulator.accumulate(self, ps, res, dist)
                reply = PassResult(res, dist, tt)

    # -- the shared warm-up ---------------------------------------------------------------------
    @contextmanager
    def without_history(self):
        """Inside: the accumulator blends without hysteresis or brightness damping (the warm-up)."""
        acc = getattr(self.blender, "accumulator", None)
        keys = [k for k in ("hysteresis", "brightness_threshold") if hasattr(acc, k)]
        saved = {k: getattr(acc, k) for k in keys}
        off = {"hysteresis": 0.0, "brightness_threshold": float("inf")}
        for k in keys:
            setattr(acc, k, off[k])
        try:
            yield
        finally:
            for k, v in saved.items():
                setattr(acc, k, v)

    def warm_up(self, scene, n: int, seed: int, probe_mask: np.ndarray | None = None, timer=None,
                step=None) -> dict:
        """``n`` updates before the first image (module docstring); returns the warm-up's rays per stage.

        ``probe_mask`` is not applied (module docstring: every probe is warmed, ours); it is accepted so that
        a technique passes its frame's arguments unchanged.
        ``step(k, frame, timer)`` replaces the pipeline's own update for techniques whose update adds
        work of its own (IS-DDGI); the frames are ``WARMUP_FRAME_BASE + k`` (RNG streams apart from real
        frames). The warm-up's stages run under a timer of their own (its kernels are the steady frames'
        ones) and count as one stage ``warmup`` of ``timer``."""
        if n <= 0:
            return {}
        pl = self.planner
        if hasattr(pl, "begin_warmup"):
            pl.begin_warmup()
        wt = StageTimer()
        try:
            with self.without_history(), maybe_stage(timer, "warmup"):
                for k in range(n):
                    f = WARMUP_FRAME_BASE + k
                    if step is None:
                        self.update(scene, f, seed, None, wt, force_reclassify=(k == 0))
                    else:
                        step(k, f, wt)
                end = getattr(self.accumulator, "end_warmup", None)
                if end is not None and self.last_results is not None:
                    end(self, self.last_results)
        finally:
            if hasattr(pl, "end_warmup"):
                pl.end_warmup()
        rays = wt.as_dict()["rays"]
        if timer is not None:
            timer.add_rays("warmup", sum(rays.values()))
        return rays


def _add(info: dict, counts: dict) -> None:
    for k in counts:
        info[k] += counts[k]


def probes_in_frustum(volume: ProbeVolume, camera, res, margin: float = 1.4) -> np.ndarray:
    """(P,) bool: probes inside the camera frustum extended to ``|clip xy| <= margin`` (ADGI Fig. 6b).

    Probes behind the camera but within one cell diagonal of it also count, so
    that probes around the viewer (which light what it sees) keep updating.
    """
    pos = volume.positions()
    x, y, z = camera.project(res, pos)          # the camera's one projection
    with np.errstate(invalid="ignore"):
        inside = (z > 0) & (np.abs(x) <= margin) & (np.abs(y) <= margin)
    near = np.linalg.norm(pos - np.asarray(camera.origin, np.float64), axis=1) <= volume.grid.cell_diagonal
    return inside | near
