"""ADGI heuristics: frusta, pilot rays and the per-octant heuristic tables (Datta et al. 2022, Sec. 4.1-4.4).

Every probe has 8 octant entries (Fig. 5a), stored as flat Dr.Jit arrays of
``P * 8`` floats, entry ``probe * 8 + o``. Octant ``o`` has bit 0 set for
``x < 0``, bit 1 for ``y < 0``, bit 2 for ``z < 0``; the opposite octant is
``o ^ 7``.

Frusta (Fig. 6b)
----------------
``V_in``: ``|clip xy| <= 1.2`` and ``f_c >= 0.75``; ``V_out``: ``|clip xy| <= 1.4``
and ``f_c >= 0.5`` (:func:`frusta`; the clip test is
:func:`~dyngi.probes.pipeline.probes_in_frustum`, which also keeps probes within
one cell diagonal of the camera: ours). The four numbers are the labels of Fig. 6b (the arXiv text gives
them only there; its extraction loses which boundary each label sits on): the pairing (1.2 and 0.75 the
inner volume, 1.4 and 0.5 the outer) is our reading of the figure, so they are the technique's parameters
``v_in_clip``, ``v_in_fc``, ``v_out_clip``, ``v_out_fc``, marked ours with the figure's values as the
paper's (the default is the paper-literal value: no ablation row).

Pilot rays (Sec. 4.4)
---------------------
One ray per octant per probe of ``V_out`` (:class:`PilotRays`): uniformly
random inside its octant, keyed on (seed, frame // 2, probe, octant), so
frames ``2j`` and ``2j + 1`` trace identical rays (the AABBCCDD pattern) and
the time differences of Eqs. 13 and 16 are taken between them, i.e. on odd
frames only, and only for probes that were also traced the frame before.

Heuristics
----------
* ``f_c`` (Eq. 10): 1 if ``|p - c| < k``, else ``exp(-(|p - c| - k))``
  (world units, as the paper). ``k`` is the user's threshold; our default is the
  ``K_QUANTILE`` = 0.9 quantile of the camera distances of the active probes inside
  the ``V_out`` clip frustum (:func:`view_distances`, :meth:`ADGIHeuristics.k_for`;
  ours, the paper leaves k to the user): the nearest 90% of the probes the view
  holds get ``f_c = 1``, the farthest 10% fall off, so f_c varies over every view
  while ``V_out`` (``f_c >= 0.5``, i.e. ``|p - c| <= k + ln 2``) keeps at least 90%
  of them -- whatever the scene's scale or where the camera stands (the real
  Cornell box's camera is outside its probe volume; a fixed k in metres would
  either cut the view or never fall off). Without a view (no probe in the
  frustum) the fallback is the probe box diagonal plus the camera's distance to
  the box (f_c = 1 everywhere).
* ``f_v`` (Eq. 11): ``exp(-2 t / s)``, ``t = trace(p, -w)``, ``s`` the cell
  diagonal. The pilot ray of octant ``o`` along ``w_o`` measures ``t`` for the
  opposite octant ``o ^ 7`` (ours: no extra ray). A miss gives ``f_v = 0``; a
  back-face hit uses its true distance (``|d| / 0.2``, the tracer's convention).
* ``f_r`` (Eq. 12): ``min(r, beta) / beta``, ``beta = 5``, ``r`` the luminance
  of the radiance the pilot hit reflects from *direct* light (the caller's
  shading with no probe lookup).
* ``f_dv``, ``f_dr`` (Eqs. 13-18): ``f0 = |f_v^t - f_v^(t-1)|`` (the absolute
  change; ours, a change of either sign matters), through the temporal trigger
  ``Tr`` (Fig. 6a, :func:`trigger_step`): a pulse sets the signal to its height
  ``A``, which then decays linearly by ``A / theta`` per frame (``theta`` in
  frames, default 16, ours; a larger pulse restarts it). The triggered signal
  is convolved with a 5x5x5 box over the probe grid (zero outside the grid)
  times a directional kernel on the 8-octant table: the octant itself and its
  three edge neighbours (octants differing in one sign; ours -- an octant has
  no 3x3 neighbourhood, this is the 2x2x2 octant cube's analogue). Both are
  plain sums as in Eq. 15 (the scale cancels in Metropolis ratios).
* ``f_s = f_c f_v`` (Eq. 19), ``f_d = f_c f_v (f_dv + mu f_dr)``, ``mu = 2`` (Eq. 20).
* The guide of the static chains (Sec. 4.8): ``h = exp(min(g / f_s, 1)) f_s``
  (:func:`static_guide`; ``g`` the cached irradiance's luminance, our scalar of
  the RGB cache).

Probes outside ``V_out`` keep their last ``f_v``/``f_r``; their triggers decay.

Storage: the 6-10-10 word (Sec. 4.3)
------------------------------------
"We store the quantities f_v, f_s, f_d as a 6-10-10 bit encoded 32 bit integer at each octant of the
probes. The remaining 6 bits are used for other flags." :func:`pack_heuristics` builds that word per
octant entry, in that order from the low bits: ``f_v`` in bits 0-5, ``f_s`` in bits 6-15, ``f_d`` in
bits 16-25, flags in bits 26-31 (bit 26: the probe is in ``V_in``; the others are 0). The chains read
``f_s``, ``f_d`` and the ``V_in`` flag from the word (:func:`unpack_heuristics`), so they see the
quantised values, as on the GPU. Ours, the paper being silent on the scales:

* ``f_v``, ``f_s`` lie in [0, 1] (Eqs. 11, 19) and are stored linearly; ``f_d`` (Eq. 20) is a sum over
  the convolution window with no fixed bound, so it is stored relative to this frame's maximum
  ``F = max f_d`` (one device reduction, kept beside the table as a Float; Metropolis ratios do not
  see the scale);
* ``f_v`` rounds to nearest (63 steps); ``f_s`` and ``f_d`` round *up*: a non-zero value never becomes
  0, so "``f_d > 0``" (the texel-centre snap, the dynamic chains' support) and the static chains'
  support are exactly those of the fp32 values (a round-up changes the guide by < 1/1023 of its range,
  a sampling density only: the estimates are texel means and do not depend on it).

The state (:class:`HeuristicState`) keeps ``f_v``, ``f_r`` and the triggers in fp32 for the time
differences of Eqs. 13 and 16 (the paper does not say at what precision it takes them).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...backend import dr, mi
from ...errors import DyngiError
from ...probes.arrays import upload
from ...probes.rays import RayPlan
from ...sampling.rng import mix_seed

OCTANTS = 8
V_IN_CLIP, V_IN_FC = 1.2, 0.75         # Fig. 6b's labels; the technique's params v_in_clip, v_in_fc (marked)
V_OUT_CLIP, V_OUT_FC = 1.4, 0.5         # Fig. 6b's labels; v_out_clip, v_out_fc
BETA = 5.0                              # Eq. 12
MU = 2.0                                # Eq. 20
THETA = 16.0                            # trigger decay in frames (ours)
K_QUANTILE = 0.9                        # Eq. 10's default k: this quantile of the view's probe distances (ours)
SPATIAL_RADIUS = 2                      # 5x5x5 (Sec. 4.1.4)
BACKFACE_DISTANCE_SCALE = 0.2           # the tracer's -0.2 t for back faces
FV_BITS, FS_BITS, FD_BITS = 6, 10, 10   # Sec. 4.3: the 6-10-10 word (+ 6 flag bits)
FLAG_V_IN = 1 << 26                     # flag bit: the probe is in V_in (ours)


def octant_of(d):
    """Octant index (Dr.Jit UInt32) of a direction: bit 0 ``x < 0``, bit 1 ``y < 0``, bit 2 ``z < 0``."""
    one, zero = mi.UInt32(1), mi.UInt32(0)
    return (dr.select(d.x < 0.0, one, zero) | dr.select(d.y < 0.0, one << 1, zero)
            | dr.select(d.z < 0.0, one << 2, zero))


def octant_of_np(d: np.ndarray) -> np.ndarray:
    d = np.asarray(d)
    return ((d[..., 0] < 0) * 1 + (d[..., 1] < 0) * 2 + (d[..., 2] < 0) * 4).astype(np.int64)


def octant_signs(o):
    """(sx, sy, sz) in {-1, 1} of octant ``o`` (Dr.Jit)."""
    return mi.Vector3f(dr.select((o & 1) != 0, -1.0, 1.0), dr.select((o & 2) != 0, -1.0, 1.0),
                       dr.select((o & 4) != 0, -1.0, 1.0))


def camera_falloff(distance, k: float):
    """``f_c`` (Eq. 10) of distances to the camera (NumPy)."""
    d = np.asarray(distance, np.float64)
    return np.exp(-np.maximum(d - k, 0.0))


def view_geometry(volume, camera, res) -> tuple:
    """One projection of the probes for a frame (host): ``(x, y, z, dist, near)`` -- image-plane coordinates and
    depth (:meth:`Camera.project <dyngi.scene.camera.Camera.project>`), camera distances, and the probes within
    one cell diagonal of the camera; :func:`frusta` and :func:`view_distances` share it (one pass over the
    probes' positions per frame instead of one per clip test)."""
    pos = volume.positions()
    x, y, z = camera.project(res, pos)
    dist = np.linalg.norm(pos - np.asarray(camera.origin, np.float64), axis=1)
    return x, y, z, dist, dist <= volume.grid.cell_diagonal


def _in_clip(geo, margin: float) -> np.ndarray:
    """:func:`~dyngi.probes.pipeline.probes_in_frustum` from a :func:`view_geometry`: inside the frustum extended
    to ``|clip xy| <= margin``, or within one cell diagonal of the camera."""
    x, y, z, _, near = geo
    with np.errstate(invalid="ignore"):
        inside = (z > 0) & (np.abs(x) <= margin) & (np.abs(y) <= margin)
    return inside | near


def view_distances(volume, camera, res, active=None, out_clip: float = V_OUT_CLIP, geo=None) -> np.ndarray:
    """Camera distances of the probes inside the ``V_out`` clip frustum (``|clip xy| <= out_clip``, 1.4 in
    Fig. 6b), of the ``active`` ones when given: what Eq. 10's default k is taken from
    (:meth:`ADGIHeuristics.k_for`). ``geo``: the frame's :func:`view_geometry` (computed when None)."""
    geo = view_geometry(volume, camera, res) if geo is None else geo
    inside = _in_clip(geo, out_clip)
    if active is not None:
        inside &= np.asarray(active, bool)
    return geo[3][inside]


def frusta(volume, camera, res, k: float, cuts: tuple = (V_IN_CLIP, V_IN_FC, V_OUT_CLIP, V_OUT_FC), geo=None):
    """(f_c (P,) float64, V_in (P,) bool, V_out (P,) bool) of Fig. 6b (host arrays); ``cuts``: ``(in_clip,
    in_fc, out_clip, out_fc)``, the technique's ``v_in_clip``, ``v_in_fc``, ``v_out_clip``, ``v_out_fc``.
    ``geo``: the frame's :func:`view_geometry` (computed when None)."""
    in_clip, in_fc, out_clip, out_fc = cuts
    geo = view_geometry(volume, camera, res) if geo is None else geo
    fc = camera_falloff(geo[3], k)
    v_in = _in_clip(geo, in_clip) & (fc >= in_fc)
    v_out = _in_clip(geo, out_clip) & (fc >= out_fc)
    return fc, v_in, v_out | v_in


class PilotRays:
    """One stratified random ray per octant per probe, identical on frames ``2j`` and ``2j+1`` (Sec. 4.4)."""

    name = "adgi-pilot"

    def __init__(self, stream: int = 0x9170):
        self.stream = int(stream)

    def plan(self, frame: int, seed: int, probe_ids, previous=None) -> RayPlan:
        pids = np.asarray(probe_ids, np.uint32)
        n = len(pids) * OCTANTS
        idx = dr.arange(mi.UInt32, n)
        slot = idx // OCTANTS
        o = idx - slot * OCTANTS
        probe = dr.gather(mi.UInt32, upload(pids, mi.UInt32), slot) if len(pids) else mi.UInt32()
        pair = int(frame) // 2
        key = probe * OCTANTS + o
        s0 = dr.opaque(mi.UInt32, mix_seed(seed, pair, self.stream))
        s1 = dr.opaque(mi.UInt32, mix_seed(seed, pair, self.stream + 1))
        u = mi.Point2f(mi.sample_tea_float32(key, s0, 6), mi.sample_tea_float32(key, s1, 6))
        d = dr.abs(mi.warp.square_to_uniform_sphere(u)) * octant_signs(o)
        return RayPlan(probe, d, OCTANTS, None, pids, slot=slot)


@dataclass
class HeuristicState:
    """Per-octant tables (``P * 8`` Floats, entry ``probe * 8 + o``) and per-probe stamps.

    fv, fr : Float           latest f_v (Eq. 11) and f_r (Eq. 12)
    trig_v, peak_v : Float   trigger signal and pulse height of the visibility change (Eq. 14)
    trig_r, peak_r : Float   the same for the radiance change (Eq. 17)
    fdv, fdr : Float         convolved triggers (Eqs. 15, 18)
    fc : Float               f_c per probe (Eq. 10), this frame
    stamp : UInt32           per probe: 1 + the frame its pilot rays were last traced (0: never)
    tick : UInt32            per probe: 1 + the frame its triggers last advanced (0: never); a probe outside the
                             frame's box (:meth:`ADGIHeuristics.update`) decays lazily, by the frames since
    """

    fv: "mi.Float"
    fr: "mi.Float"
    trig_v: "mi.Float"
    peak_v: "mi.Float"
    trig_r: "mi.Float"
    peak_r: "mi.Float"
    fdv: "mi.Float"
    fdr: "mi.Float"
    fc: "mi.Float"
    stamp: "mi.UInt32"
    tick: "mi.UInt32" = None

    @staticmethod
    def zeros(n_probes: int) -> "HeuristicState":
        n = int(n_probes) * OCTANTS
        z = [dr.zeros(mi.Float, n) for _ in range(8)]
        fc, stamp = dr.full(mi.Float, 1.0, int(n_probes)), dr.zeros(mi.UInt32, int(n_probes))
        tick = dr.zeros(mi.UInt32, int(n_probes))
        # evaluated, not literal zeros: a literal folds into the first frames' kernels, which then differ
        # from the steady ones (a recompile on frames 3-4)
        dr.make_opaque(*z, fc, stamp, tick)
        return HeuristicState(*z, fc, stamp, tick)

    def fc_entries(self):
        return dr.gather(mi.Float, self.fc, dr.arange(mi.UInt32, dr.width(self.fv)) // OCTANTS)

    @property
    def fs(self):
        """``f_s = f_c f_v`` per entry (Eq. 19)."""
        return self.fc_entries() * self.fv

    def fd(self, mu: float = MU):
        """``f_d = f_c f_v (f_dv + mu f_dr)`` per entry (Eq. 20)."""
        return self.fs * (self.fdv + dr.opaque(mi.Float, mu) * self.fdr)


def trigger_step(trig, peak, pulse, theta: float, steps=None):
    """Temporal trigger ``Tr`` (Eq. 14, Fig. 6a), one frame: the signal decays linearly by ``peak / theta``;
    a pulse above the decayed signal restarts it at the pulse's height. Returns (signal, peak). ``steps``
    (Float per lane, >= 1): the frames since the lane last advanced, the last one with ``pulse`` -- the same
    as that many one-frame steps with no pulse before it (a linear decay; the peak drops to 0 with it)."""
    rate = peak * dr.opaque(mi.Float, 1.0 / max(float(theta), 1e-6))
    decayed = dr.maximum(trig - (rate if steps is None else rate * steps), 0.0)
    fire = pulse > decayed
    return dr.select(fire, pulse, decayed), dr.select(fire, pulse, dr.select(decayed > 0.0, peak, 0.0))


def convolve(table, counts, radius: int = SPATIAL_RADIUS, opaque: bool = False):
    """Eq. 15: box sum over ``(2r+1)^3`` probes (zero outside the grid) x the 4-octant directional kernel.
    ``table`` a Float, or a tuple of Floats convolved in the same kernels (one launch per axis for all).
    ``opaque``: the counts enter the kernels as opaque values (a box whose size changes every frame)."""
    many = isinstance(table, (tuple, list))
    tables = list(table) if many else [table]
    nx, ny, nz = (int(c) for c in counts)
    if opaque:
        nx, ny, nz = (dr.opaque(mi.UInt32, c) for c in (nx, ny, nz))
    n = dr.width(tables[0])
    e = dr.arange(mi.UInt32, n)
    probe = e // OCTANTS
    o = e - probe * OCTANTS
    cx = probe % nx
    cy = (probe // nx) % ny
    cz = probe // (nx * ny)
    xs = tables
    for c, size, stride in ((cx, nx, 1), (cy, ny, nx), (cz, nz, nx * ny)):
        accs = [dr.zeros(mi.Float, n) for _ in xs]
        ci = mi.Int32(c)
        for d in range(-radius, radius + 1):
            ok = (ci + d >= 0) & (ci + d < mi.Int32(size))
            src = dr.select(ok, mi.UInt32(mi.Int32(e) + d * mi.Int32(stride) * OCTANTS), e)
            for a, x in zip(accs, xs):
                a += dr.gather(mi.Float, x, src, ok)
        dr.eval(*accs)
        xs = accs
    base = probe * OCTANTS
    outs = [x + dr.gather(mi.Float, x, base + (o ^ 1)) + dr.gather(mi.Float, x, base + (o ^ 2))
            + dr.gather(mi.Float, x, base + (o ^ 4)) for x in xs]
    dr.eval(*outs)
    return tuple(outs) if many else outs[0]


class ADGIHeuristics:
    """Builds and updates :class:`HeuristicState` from pilot-ray results (see the module docstring).

    grid : ProbeGrid     the probe grid (its counts and cell diagonal)
    k : float | None     Eq. 10's threshold (world units); None = from the view (:meth:`k_for`)
    beta, mu, theta      Eq. 12's range (5), Eq. 20's weight (2), the trigger's decay in frames (16)
    """

    def __init__(self, grid, k: float | None = None, beta: float = BETA, mu: float = MU, theta: float = THETA):
        self.grid = grid
        box = np.asarray(grid.spacing) * (np.asarray(grid.counts) - 1)
        self.user_k = None if k is None else float(k)
        self.k = float(np.linalg.norm(box)) if k is None else float(k)
        self._box = (np.asarray(grid.origin, np.float64), np.asarray(grid.origin, np.float64) + box)
        for name, v in (("beta", beta), ("theta", theta)):
            if not (np.isfinite(v) and v > 0):
                raise DyngiError(f"ADGI heuristic parameter '{name}' must be > 0, got {v}")
        if not (np.isfinite(mu) and mu >= 0):
            raise DyngiError(f"ADGI heuristic parameter 'mu' must be >= 0, got {mu}")
        self.beta, self.mu, self.theta = float(beta), float(mu), float(theta)
        self.pilot = PilotRays()

    def k_for(self, camera_origin, view=None) -> float:
        """Eq. 10's ``k`` for a camera at ``camera_origin``: the user's value, else (ours, module docstring)
        the ``K_QUANTILE`` quantile of ``view`` (the camera distances of the probes in view,
        :func:`view_distances`); with no probe in view (or ``view`` None) the probe box diagonal plus the
        camera's distance to the probe box (0 inside it), so that f_c = 1 for every probe."""
        if self.user_k is not None:
            return self.user_k
        if view is not None and len(view):
            return float(np.quantile(np.asarray(view, np.float64), K_QUANTILE))
        c = np.asarray(camera_origin, np.float64)
        lo, hi = self._box
        return self.k + float(np.linalg.norm(np.maximum(np.maximum(lo - c, c - hi), 0.0)))

    def initial_state(self) -> HeuristicState:
        return HeuristicState.zeros(self.grid.n_probes)

    def box_of(self, mask: np.ndarray):
        """The grid-index bounding box ``(lo, hi)`` (3 ints each, ``hi`` exclusive) of the probes in ``mask``
        (host), or None when it is empty."""
        ids = np.flatnonzero(mask)
        if not len(ids):
            return None
        nx, ny, _ = (int(c) for c in self.grid.counts)
        ijk = np.stack([ids % nx, (ids // nx) % ny, ids // (nx * ny)], -1)
        return tuple(int(v) for v in ijk.min(0)), tuple(int(v) + 1 for v in ijk.max(0))

    def update(self, state: HeuristicState, frame: int, probe_ids, distance, direct_luminance,
               fc: np.ndarray | None = None, box=None) -> HeuristicState:
        """One frame: the pilot results of ``probe_ids`` (plan order, 8 rays each: ``distance`` signed as
        the tracer returns it, ``direct_luminance`` per ray) -> the new state (``state`` is not modified).
        ``fc``: this frame's f_c per probe (default: unchanged). An empty ``probe_ids`` only decays.

        ``box``: ``(lo, hi)`` grid-index bounds (``hi`` exclusive) of the probes whose f_dv / f_dr this frame
        needs (V_out's bounding box, :meth:`box_of`; None: the whole grid); the pilot probes must lie in it.
        The triggers advance and the convolution runs over the box grown by the convolution's radius (clamped
        to the grid; Eqs. 14-15 exact on the box), f_dv / f_dr are written for the box only (elsewhere they
        keep older values, which no chain reads: the chains sample V_in), and a probe's triggers decay lazily
        by the frames since they last advanced (:func:`trigger_step`'s ``steps``): work that follows the view."""
        pids = np.asarray(probe_ids, np.uint32)
        counts = np.asarray([int(c) for c in self.grid.counts])
        nx, ny, nz = (int(c) for c in counts)
        lo_in, hi_in = (np.zeros(3, int), counts) if box is None else (np.asarray(box[0]), np.asarray(box[1]))
        r = SPATIAL_RADIUS
        lo = np.maximum(lo_in - r, 0)
        hi = np.minimum(hi_in + r, counts)
        bx, by, bz = (int(v) for v in hi - lo)
        frame_o = dr.opaque(mi.UInt32, int(frame))
        fv, fr = mi.Float(state.fv), mi.Float(state.fr)
        stamp = mi.UInt32(state.stamp)
        tick0 = state.tick if state.tick is not None else dr.zeros(mi.UInt32, nx * ny * nz)
        # -- the box's entries: local lane -> global probe and entry --
        L = bx * by * bz * OCTANTS
        lane = dr.arange(mi.UInt32, L)
        lp = lane // OCTANTS
        o = lane - lp * OCTANTS
        bxo, byo = dr.opaque(mi.UInt32, bx), dr.opaque(mi.UInt32, by)
        li, lj, lk = lp % bxo, (lp // bxo) % byo, lp // (bxo * byo)
        gi = li + dr.opaque(mi.UInt32, int(lo[0]))
        gj = lj + dr.opaque(mi.UInt32, int(lo[1]))
        gk = lk + dr.opaque(mi.UInt32, int(lo[2]))
        gprobe = gi + nx * (gj + ny * gk)
        g = gprobe * OCTANTS + o
        pulse_v = dr.zeros(mi.Float, L)
        pulse_r = dr.zeros(mi.Float, L)
        if len(pids):
            ijk = np.stack([pids % nx, (pids // nx) % ny, pids // (nx * ny)], -1).astype(np.int64) - lo
            local = (ijk[:, 0] + bx * (ijk[:, 1] + by * ijk[:, 2])).astype(np.uint32)
            n = len(pids) * OCTANTS
            i = dr.arange(mi.UInt32, n)
            slot = i // OCTANTS
            oo = i - slot * OCTANTS
            probe = dr.gather(mi.UInt32, upload(pids, mi.UInt32), slot)
            lprobe = dr.gather(mi.UInt32, upload(local, mi.UInt32), slot)
            d = mi.Float(distance)
            t = dr.select(d < 0.0, -d / BACKFACE_DISTANCE_SCALE, d)
            s = dr.opaque(mi.Float, self.grid.cell_diagonal)
            fv_new = dr.select(dr.isfinite(t), dr.exp(-2.0 * t / s), 0.0)          # Eq. 11, for octant o ^ 7
            lum = dr.maximum(mi.Float(direct_luminance), 0.0)
            beta = dr.opaque(mi.Float, self.beta)
            fr_new = dr.minimum(dr.select(dr.isfinite(lum), lum, 0.0), beta) / beta   # Eq. 12
            ev = probe * OCTANTS + (oo ^ 7)
            er = probe * OCTANTS + oo
            # -- time differences between identical rays (second frame of a pair, Eqs. 13, 16) --
            if int(frame) % 2 == 1:
                same = dr.gather(mi.UInt32, state.stamp, probe) == frame_o       # traced at frame - 1
                dr.scatter(pulse_v, dr.abs(fv_new - dr.gather(mi.Float, state.fv, ev)), lprobe * OCTANTS + (oo ^ 7),
                           same)
                dr.scatter(pulse_r, dr.abs(fr_new - dr.gather(mi.Float, state.fr, er)), lprobe * OCTANTS + oo, same)
            dr.scatter(fv, fv_new, ev)
            dr.scatter(fr, fr_new, er)
            dr.scatter(stamp, frame_o + 1, probe)
        # -- temporal trigger (Eqs. 14, 17) on the box, each lane by the frames since it last advanced --
        tk = dr.gather(mi.UInt32, tick0, gprobe)
        steps = mi.Float(dr.select(tk > 0, frame_o + 1 - tk, 1))
        tv, pv = trigger_step(dr.gather(mi.Float, state.trig_v, g), dr.gather(mi.Float, state.peak_v, g), pulse_v,
                              self.theta, steps)
        tr, pr = trigger_step(dr.gather(mi.Float, state.trig_r, g), dr.gather(mi.Float, state.peak_r, g), pulse_r,
                              self.theta, steps)
        dr.eval(fv, fr, tv, pv, tr, pr, stamp)
        trig_v, peak_v, trig_r, peak_r = (mi.Float(x) for x in (state.trig_v, state.peak_v, state.trig_r, state.peak_r))
        for dst, src in ((trig_v, tv), (peak_v, pv), (trig_r, tr), (peak_r, pr)):
            dr.scatter(dst, src, g)
        tick = mi.UInt32(tick0)
        dr.scatter(tick, frame_o + 1, gprobe, o == 0)
        # -- convolution (Eqs. 15, 18) on the box; written for the inner box (V_out's) --
        cv, cr = convolve((tv, tr), (bx, by, bz), opaque=True)     # one launch per axis for both
        inner = mi.Bool(True)
        if box is not None:      # the bounds change every frame: opaque, not literals
            ob = [dr.opaque(mi.UInt32, int(v)) for v in (*lo_in, *hi_in)]
            inner = (gi >= ob[0]) & (gi < ob[3]) & (gj >= ob[1]) & (gj < ob[4]) & (gk >= ob[2]) & (gk < ob[5])
        fdv, fdr = mi.Float(state.fdv), mi.Float(state.fdr)
        dr.scatter(fdv, cv, g, inner)
        dr.scatter(fdr, cr, g, inner)
        dr.eval(trig_v, peak_v, trig_r, peak_r, tick, fdv, fdr)
        fc_dr = state.fc if fc is None else upload(np.asarray(fc, np.float32), mi.Float)
        return HeuristicState(fv, fr, trig_v, peak_v, trig_r, peak_r, fdv, fdr, fc_dr, stamp, tick)


def static_guide(fs, g):
    """The static chains' target ``h = exp(min(g / f_s, 1)) f_s`` (Sec. 4.8; 0 where ``f_s = 0``)."""
    ratio = dr.select(fs > 0.0, dr.minimum(g / dr.maximum(fs, 1e-30), 1.0), 0.0)
    return dr.exp(ratio) * fs


def pack_heuristics(fv, fs, fd, v_in=None):
    """The 6-10-10 word per octant entry (module docstring, Sec. 4.3) -> ``(word UInt32, F Float)``,
    ``F = max f_d`` the scale of the f_d field. ``v_in``: per-entry mask (Bool/Float > 0) for the flag bit.
    Inverse: :func:`unpack_heuristics`."""
    mv, ms, md = (1 << FV_BITS) - 1, (1 << FS_BITS) - 1, (1 << FD_BITS) - 1
    F = dr.max(fd)
    qv = mi.UInt32(dr.round(dr.clip(fv, 0.0, 1.0) * mv))
    qs = mi.UInt32(dr.ceil(dr.clip(fs, 0.0, 1.0) * ms))
    rel = dr.select(F > 0.0, fd / dr.maximum(F, 1e-30), 0.0)
    qd = mi.UInt32(dr.ceil(dr.clip(rel, 0.0, 1.0) * md))
    word = qv | (qs << FV_BITS) | (qd << (FV_BITS + FS_BITS))
    if v_in is not None:
        flag = v_in if isinstance(v_in, mi.Bool) else (mi.Float(v_in) > 0.0)
        word = word | dr.select(flag, mi.UInt32(FLAG_V_IN), mi.UInt32(0))
    dr.eval(word, F)
    return word, F


def unpack_heuristics(word, F):
    """``(f_v, f_s, f_d, v_in)`` of 6-10-10 words (``F`` the f_d scale). Inverse: :func:`pack_heuristics`."""
    mv, ms, md = (1 << FV_BITS) - 1, (1 << FS_BITS) - 1, (1 << FD_BITS) - 1
    w = mi.UInt32(word)
    fv = mi.Float(w & mv) / mv
    fs = mi.Float((w >> FV_BITS) & ms) / ms
    fd = mi.Float((w >> (FV_BITS + FS_BITS)) & md) / md * F
    return fv, fs, fd, (w & FLAG_V_IN) != 0
