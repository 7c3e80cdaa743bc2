"""Temporal accumulators: merge a frame's :class:`~dyngi.probes.estimator.TexelEstimate` into the stored
texels (accumulation, second half). All Dr.Jit, on the volume's device atlases and texel counts.

Per texel an accumulator sees the stored value ``old`` and count ``n``, this
frame's mean ``x`` of ``m`` samples and whether the probe has history, and
returns the new value and count. :func:`merge` then stores it through the
volume's encoding (``load(store(.))``, see :mod:`dyngi.probes.encoding`), so
the atlas holds exactly what the query reads; texels that received no sample
keep their value and count.

* :class:`HysteresisAccumulator` -- DDGI (Majercik et al., JCGT 2019, Sec. 3.2):
  ``new = lerp(x, old, h)``; irradiance in the perceptual space ``E^(1/gamma)``
  with the change threshold and brightness damping of Majercik et al. (JCGT 2021,
  Sec. 6) and RTXGI (see :mod:`dyngi.probes.blend`). The count only tracks
  ``min(n + m, cap)``.
* :class:`CappedMeanAccumulator` -- a count-capped running mean (our choice; not ADGI's Algorithm 3,
  which is :class:`dyngi.techniques.adgi.moving_average.Algorithm3Accumulator`): per sample
  ``n = min(n + 1, cap); new = old + (x_i - old) / n``, i.e. the mean of the first ``cap`` samples, then
  an exponential average of weight ``1/cap`` per sample (one sample off Algorithm 3's ``1/(n + 1)``),
  with the cap the encoding's count bits (63 for the 6-bit counts of ``adgi``). The ``m`` samples of a
  frame are merged at once as ``m`` equal samples of value ``x`` (the frame's samples are unordered;
  ours): ``new = old + (1 - keep) (x - old)`` with ``keep = n / (n + s) * (1 - 1/cap)^(m - s)``,
  ``s = min(m, cap - n)`` -- exactly the sequential updates when the samples are equal.
* :class:`MeanAccumulator` -- the plain mean of this frame's samples, no history
  (ADGI's fp32 reference, Sec. 5; :class:`~dyngi.probes.blend.TrueAverage`).

:func:`merge_into_volume` merges the probes of a host plan and counts their updates on the host;
:func:`merge_slots_into_volume` merges the slots of a masked plan (device probe ids) and counts them in
a device array, so that a frame never waits for the host (ours).
"""
from __future__ import annotations

import functools

import numpy as np

from ..backend import dr, mi
from ..sampling.octahedral import border_source_index
from .arrays import upload

CHANGE_HYSTERESIS_DROP = 0.75
BRIGHTNESS_DAMPING = 0.25
ACCUMULATORS = ("hysteresis", "capped-mean", "mean")


class HysteresisAccumulator:
    """DDGI hysteresis; parameters as :class:`~dyngi.probes.blend.HysteresisBlend`."""

    name = "hysteresis"

    def __init__(self, hysteresis: float = 0.97, irradiance_gamma: float = 5.0, change_threshold: float = 0.25,
                 brightness_threshold: float = 0.1):
        self.hysteresis = float(hysteresis)
        self.irradiance_gamma = float(irradiance_gamma)
        self.change_threshold = float(change_threshold)
        self.brightness_threshold = float(brightness_threshold)

    def irradiance(self, old, new, n_old, m, fresh, cap: int):
        h = dr.opaque(mi.Float, self.hysteresis)
        inv_g = dr.opaque(mi.Float, 1.0 / self.irradiance_gamma)
        g = dr.opaque(mi.Float, self.irradiance_gamma)
        new_g = dr.power(dr.maximum(new, 0.0), inv_g)
        old_g = dr.power(dr.maximum(old, 0.0), inv_g)
        delta = new_g - old_g
        h0 = dr.select(fresh, 0.0, h)
        big = dr.max(dr.abs(delta)) > dr.opaque(mi.Float, self.change_threshold)
        hh = dr.select(big, dr.maximum(h0 - CHANGE_HYSTERESIS_DROP, 0.0), h0)
        lum = mi.luminance(delta)
        bright = (lum > dr.opaque(mi.Float, min(self.brightness_threshold, 3e38))) & ~fresh
        delta = dr.select(bright, delta * BRIGHTNESS_DAMPING, delta)
        res_g = dr.maximum(old_g + (1.0 - hh) * delta, 0.0)
        res = dr.select(res_g > 0.0, dr.power(res_g, g), 0.0)
        return res, count_sum(n_old, m, fresh, cap)

    def distance(self, old, new, n_old, m, fresh, cap: int):
        hd = dr.select(fresh, 0.0, dr.opaque(mi.Float, self.hysteresis))
        return dr.fma(1.0 - hd, new - old, old), count_sum(n_old, m, fresh, cap)


class CappedMeanAccumulator:
    """Count-capped running mean; see the module docstring (not ADGI's Algorithm 3).

    max_count : int | None   cap of the count (default: the encoding's, 63 for 'adgi')
    """

    name = "capped-mean"

    def __init__(self, max_count: int | None = None):
        self.max_count = None if max_count is None else max(int(max_count), 1)

    def _blend(self, old, new, n_old, m, fresh, cap: int):
        cap = min(cap, self.max_count or cap)
        capf = float(cap)
        n0 = dr.select(fresh, 0.0, dr.minimum(mi.Float(n_old), capf))
        mf = mi.Float(m)
        s = dr.clip(capf - n0, 0.0, mf)                      # samples before the cap
        rest = mf - s                                          # samples at the cap
        keep = dr.select(n0 + s > 0.0, n0 / (n0 + s), 0.0)
        if cap > 1:
            keep *= dr.select(rest > 0.0, dr.exp(rest * float(np.log1p(-1.0 / capf))), 1.0)
        else:
            keep = dr.select(rest > 0.0, 0.0, keep)
        return old + (1.0 - keep) * (new - old), count_sum(n_old, m, fresh, cap)

    irradiance = _blend
    distance = _blend


class MeanAccumulator:
    """The plain mean of this frame's samples (no history); the count is this frame's.

    ``keeps_history = False``: :func:`merge` stores its value without the encodings' minimum-step rule
    (that rule moves a code at least one step towards a value that differs from the stored one, so that a
    *hysteresis* step smaller than a code is not swallowed; with no history there is no such step, and the
    rule instead turned a constant estimate below one code into a code that toggles 0, 1, 0, 1 frame after
    frame -- ADGI's sealed room lit and alternating, issue 36; ours)."""

    name = "mean"
    keeps_history = False

    def _blend(self, old, new, n_old, m, fresh, cap: int):
        return new, dr.minimum(m, cap)

    irradiance = _blend
    distance = _blend


def count_sum(n_old, m, fresh, cap: int):
    n0 = dr.select(fresh, 0, n_old)
    return dr.minimum(n0 + m, cap)


# -- merging into the volume ----------------------------------------------------------

def interior_source_index(texels: int) -> np.ndarray:
    """(T*T,) uint32: index ``(y-1) * (T-2) + (x-1)`` of the interior texel that each bordered texel copies."""
    T = int(texels)
    src = border_source_index(T).ravel()
    sy, sx = src // T, src % T
    return ((sy - 1) * (T - 2) + (sx - 1)).astype(np.uint32)


@functools.lru_cache(maxsize=None)
def _source_table(texels: int):
    return mi.UInt32(interior_source_index(texels))


def texel_indices(pid_dr, n_probes: int, texels: int):
    """Per bordered texel of the traced probes: its probe slot, global texel index and the
    interior texel it copies (:func:`interior_source_index`)."""
    texels2 = texels * texels
    k = dr.arange(mi.UInt32, n_probes * texels2)
    probe_local = k // texels2
    texel = k - probe_local * texels2
    probe = dr.gather(mi.UInt32, pid_dr, probe_local)
    src = dr.gather(mi.UInt32, _source_table(texels), texel)
    return probe_local, probe * texels2 + texel, src


def gather_planar(cls, flat, n: int, k):
    """``cls`` values at entries ``k`` of a channel-planar flat Float (channel ``c`` at ``c * n + k``)."""
    # the channel offset depends on the number of traced probes: opaque, or every count recompiles
    return cls(*[dr.gather(mi.Float, flat, k + dr.opaque(mi.UInt32, c * n)) for c in range(len(cls()))])


def merge(volume, kind: str, est, accumulator, encoding, pid_dr, fresh_dr, n_probes: int):
    """New values, counts and atlas indices of every bordered texel of the traced probes (not scattered yet).

    ``kind`` 'irradiance' or 'distance'; border texels take the estimate of the
    interior texel they copy, so they stay consistent with no separate pass.
    """
    dev = volume.device
    irr = kind == "irradiance"
    T = volume.irradiance_texels if irr else volume.distance_texels
    cls = mi.Color3f if irr else mi.Vector2f
    atlas = dev.irradiance if irr else dev.distance
    counts = dev.irradiance_count if irr else dev.distance_count
    probe_local, gidx, src = texel_indices(pid_dr, n_probes, T)
    entry = probe_local * (T - 2) ** 2 + src
    new = gather_planar(cls, est.value, est.n, entry)
    idx = src if est.per_texel else entry
    ok = dr.gather(mi.Bool, est.ok, idx) & dr.all(dr.isfinite(new))
    m = dr.gather(mi.UInt32, est.count, idx)
    old = dr.gather(cls, atlas, gidx)
    n_old = dr.gather(mi.UInt32, counts, gidx)
    fresh = dr.gather(mi.Bool, fresh_dr, probe_local)
    cap = int(encoding.count_max)
    if irr:
        val, cnt = accumulator.irradiance(old, new, n_old, m, fresh, cap)
    else:
        val, cnt = accumulator.distance(old, new, n_old, m, fresh, cap)
    # the minimum-step rule moves from the stored value; a probe without history has none, and neither
    # has an accumulator that keeps none (MeanAccumulator.keeps_history)
    ref = dr.select(fresh, val, old) if getattr(accumulator, "keeps_history", True) else None
    if irr:
        val, cnt = encoding.roundtrip_irradiance(val, cnt, ref)
    else:
        val, cnt = encoding.roundtrip_distance(val, cnt, dr.opaque(mi.Float, volume.grid.cell_diagonal), ref)
    return dr.select(ok, val, old), dr.select(ok, mi.UInt32(cnt), n_old), gidx


def merge_into_volume(volume, est_irr, est_dist, accumulator, encoding, probe_ids: np.ndarray,
                      rays: np.ndarray | None = None) -> None:
    """Merge this frame's estimates of the probes ``probe_ids`` (plan order) into the device atlases and
    counts in place; the host copies are refreshed from the device when read. ``est_irr`` or ``est_dist``
    may be ``None`` (that atlas is left as it is). ``rays`` (per probe, the plan's counts): probes that
    traced none keep their texels and do not count as updated."""
    st = volume.state
    pid = np.asarray(probe_ids, np.int64)
    if len(pid) == 0:
        return
    dev = volume.device
    # uploaded copies, not aliases of NumPy memory (whose alignment can change the kernels; arrays.upload)
    pid_dr = upload(pid.astype(np.uint32), mi.UInt32)
    fresh_dr = upload((st.updates[pid] == 0).astype(np.uint32), mi.UInt32) != 0
    parts = []
    for kind, est in (("irradiance", est_irr), ("distance", est_dist)):
        if est is not None:
            parts.append((kind, merge(volume, kind, est, accumulator, encoding, pid_dr, fresh_dr, len(pid))))
    # the merged texels are evaluated before they are scattered: a pending gather of an atlas
    # would make the scatter copy the whole atlas first (5.5 MB per frame)
    dr.eval(*[x for _, (v, c, _) in parts for x in (v, c)])
    for kind, (val, cnt, gidx) in parts:
        dr.scatter(getattr(dev, kind), val, gidx)
        dr.scatter(getattr(dev, kind + "_count"), cnt, gidx)
    dr.eval(dev.irradiance, dev.distance, dev.irradiance_count, dev.distance_count)
    st.device_is_newer(pull_from(dev))
    st.updates[pid if rays is None else pid[np.asarray(rays) > 0]] += 1


def merge_slots_into_volume(volume, est_irr, est_dist, accumulator, encoding, slot_probe, slot_valid,
                            history) -> None:
    """:func:`merge_into_volume` for estimates over device *slots* (a masked
    :class:`~dyngi.probes.rays.RayPlan`'s ``probe_ids`` / ``slot_valid``; ours): no host array is read or
    written. ``history`` (UInt32 per probe, on the device) replaces the host update counts: a probe with
    0 has no history (the accumulator takes its first estimate directly) and every used slot adds 1 to its
    probe's (``dr.scatter_reduce``). Unused slots scatter nothing."""
    dev = volume.device
    S = dr.width(slot_probe)
    fresh_dr = dr.gather(mi.UInt32, history, slot_probe) == 0
    parts = []
    for kind, est in (("irradiance", est_irr), ("distance", est_dist)):
        if est is not None:
            T = volume.irradiance_texels if kind == "irradiance" else volume.distance_texels
            val, cnt, gidx = merge(volume, kind, est, accumulator, encoding, slot_probe, fresh_dr, S)
            used = dr.gather(mi.Bool, slot_valid, dr.arange(mi.UInt32, S * T * T) // dr.opaque(mi.UInt32, T * T))
            parts.append((kind, (val, cnt, gidx, used)))
    dr.eval(*[x for _, (v, c, _, u) in parts for x in (v, c, u)])
    for kind, (val, cnt, gidx, used) in parts:
        dr.scatter(getattr(dev, kind), val, gidx, used)
        dr.scatter(getattr(dev, kind + "_count"), cnt, gidx, used)
    dr.scatter_reduce(dr.ReduceOp.Add, history, mi.UInt32(1), slot_probe, slot_valid, mode=dr.ReduceMode.Local)
    dr.eval(dev.irradiance, dev.distance, dev.irradiance_count, dev.distance_count, history)
    volume.state.device_is_newer(pull_from(dev))


def pull_from(dev):
    """Copier of the device atlases and counts (as they are when read) into host arrays.

    It holds the device mirror, not its arrays: a second reference to an atlas
    would make the next frame's in-place ``dr.scatter`` copy it first (5.5 MB).
    """
    def pull(name: str, out: np.ndarray) -> None:
        out[...] = np.asarray(getattr(dev, name), out.dtype).reshape(out.shape)
    return pull
