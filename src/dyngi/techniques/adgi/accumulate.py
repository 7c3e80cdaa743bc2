"""ADGI's accumulator of the probe pipeline: the passes' samples into the texels with Algorithm 3 (Datta et al.
2022, Sec. 3.5, Table 3), a :class:`~dyngi.probes.protocols.PassAccumulator`.

:class:`ADGIAccumulator` receives every traced pass of :class:`.passes.ADGIPasses` from the pipeline
(:meth:`ProbePipeline.update_passes <dyngi.probes.pipeline.ProbePipeline.update_passes>`):

* the radiance along ``w`` into the volume's radiance layer (:class:`.radiance.RadianceUpdate`: the one radiance texel
  ``w`` falls in, Algorithm 3's batch rule with the pass's N_max, per sample where the pass gives lane caps),
  or with ``cache_update='closest-entry'`` into the irradiance texel it falls in (Algorithm 2 literally);
* the distance of the ``-w`` ray (the pilot rays: their own) into the one visibility texel ``-w`` falls in
  (``bin`` mode), Algorithm 3 through the volume's encoding (:meth:`ProbePipeline.merge
  <dyngi.probes.pipeline.ProbePipeline.merge>`; on the device path :meth:`~dyngi.probes.pipeline.ProbePipeline
  .merge_slots`, with the update counts on the device);
* the end-of-frame step (a pass without a plan, ``'finish'``): ``N <- min(N, 16)`` for the probes of
  ``V_out - V_in`` (Sec. 4.8), then every probe updated this frame convolved from its radiance texels to its
  irradiance texels (:mod:`.radiance`) and stored through the encoding (a plain mean: the convolution already
  is the temporal estimate); returns the number of probes updated.

The warm-up's last rays seed the radiance layer (:meth:`ADGIAccumulator.end_warmup`). The radiance layer is
ADGI's working state between frames (per radiance texel a mean and a count), the probe volume's third atlas
(:meth:`ProbeVolume.add_radiance_layer <dyngi.probes.volume.ProbeVolume.add_radiance_layer>`, asked for by the
technique; the accumulator adds one of ``radiance_texels`` when the volume has none); the texels the query
reads are the volume's irradiance and visibility atlases, through the encoding.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ...backend import dr, mi
from ...probes import RayPlan, ScatterEstimator
from ...probes.accumulator import MeanAccumulator, pull_from
from ...probes.arrays import upload
from ...probes.rays import compact
from ...probes.trace import ProbeRayResults
from .moving_average import Algorithm3Accumulator
from .radiance import RadianceUpdate
from .sparse import LazyCountCap, SparseKeys, merge_distance_sparse


class ADGIAccumulator:
    """Algorithm 3 merges of ADGI's passes (module docstring).

    ``volume``: the probe volume; ``params``: the technique's (``n_max_static``, ``n_max_dynamic``,
    ``radiance_texels``, ``distance_power``, ``cache_update``); ``encoding``: the texels' encoding;
    ``device``: the device path (update counts on the device, masked plans' slots, device convolution).
    """

    def __init__(self, volume, params: dict, encoding, device: bool):
        p = params
        self.params = p
        self.volume = volume
        self.encoding = encoding
        self.device = bool(device)
        self.acc_static = Algorithm3Accumulator(p["n_max_static"])
        self.acc_dynamic = Algorithm3Accumulator(p["n_max_dynamic"])
        self._mean = MeanAccumulator()
        n = volume.n_probes
        n_dist = n * (volume.distance_texels - 2) ** 2
        self.dist_keys = SparseKeys(n_dist)          # the distance merges' (probe, texel) keys (.sparse)
        # Sec. 4.8's outer count cap, lazily at merge (.sparse.LazyCountCap)
        self.cap_rad = LazyCountCap(n, n * volume.radiance_interior, p["outer_count_cap"])
        self.cap_dist = LazyCountCap(n, n_dist, p["outer_count_cap"])
        self.frame = 0                               # the frame being merged (set by the technique)
        self.est_irr = ScatterEstimator(p["distance_power"], "bin")     # closest-entry: one texel per sample
        n = volume.n_probes
        volume.add_radiance_layer(p["radiance_texels"])      # the volume's third atlas (kept if already there)
        self.radiance = RadianceUpdate(volume)
        self.radiance.device = self.device
        self._updated = np.zeros(n, bool)                 # probes merged this frame (host path)
        self._updated_dev = dr.zeros(mi.UInt32, n)        # probes merged this frame (device path)
        self._slots_merged = 0                            # slots merged this frame (device: the convolve width)

    # -- the pipeline's calls -----------------------------------------------------------------------
    def end_warmup(self, pipeline, results) -> None:
        """The warm-up's last rays seed the radiance texels (N_max static)."""
        self.radiance.merge(results, self.params["n_max_static"], lazy_cap=self.cap_rad, frame=self.frame)

    def accumulate(self, pipeline, probe_pass, results, distance_results):
        """One pass into the texels: ``'pilot'`` (when its ``merge`` option is set), ``'static'`` and
        ``'dynamic'`` with their N_max (and the static pass's per-lane caps); ``'finish'`` (no results):
        the outer count cap and the convolution, returns the probes updated (a device count on the device
        path)."""
        o = probe_pass.options
        p = self.params
        if probe_pass.name == "finish":
            self.cap_outer(o["outer"])
            return self.convolve_updated(pipeline)
        if probe_pass.name == "pilot":
            if o.get("merge"):
                self.merge(pipeline, results, None, self.acc_static, p["n_max_static"])
            return None
        static = probe_pass.name == "static"
        if distance_results is None:          # D's distance rays, traced apart (their own plan)
            distance_results = o.get("distances")
        self.merge(pipeline, results, distance_results, self.acc_static if static else self.acc_dynamic,
                   p["n_max_static"] if static else p["n_max_dynamic"], o.get("lane_cap"))
        return None

    # -- merges ---------------------------------------------------------------------------------------
    def merge(self, pipeline, irr_res, dist_res, acc, n_max: int, lane_cap=None) -> None:
        """Radiance of ``irr_res`` into the radiance texels (:mod:`.radiance`), distance moments of
        ``dist_res`` (or of ``irr_res`` when None: the pilot rays' own distances) into the visibility texels,
        both with Algorithm 3's batch rule; the probes are convolved to irradiance at the end of the frame."""
        vol = self.volume
        plan = irr_res.plan
        if self.params["cache_update"] == "closest-entry":
            self._merge_closest(pipeline, irr_res, acc, lane_cap)
        else:
            self.radiance.merge(irr_res, n_max, lane_cap, lazy_cap=self.cap_rad, frame=self.frame)
        dres = dist_res if dist_res is not None else irr_res
        dplan = dres.plan                # the distance rays' own plan (D's: apart from the radiance rays')
        # the distances: Algorithm 3 on the visibility texels that received samples (.sparse); the probes'
        # update counts as the dense merge's (one per probe with a ray)
        if self.device:
            slot_probe, slot_valid = self._slots(dplan)
            history = pipeline.history
            merge_distance_sparse(self.dist_keys, vol, dres, acc, self.encoding, history, device=True,
                                  lazy_cap=self.cap_dist, frame=self.frame)
            dr.scatter_reduce(dr.ReduceOp.Add, history, mi.UInt32(1), slot_probe, slot_valid,
                              mode=dr.ReduceMode.Local)
            dr.eval(history)
            dr.scatter(self._updated_dev, mi.UInt32(1), slot_probe, slot_valid)
            self._slots_merged += dr.width(slot_probe)
            if dplan.probe is not plan.probe:       # D's two plans: their probes are the same set
                slot_probe, slot_valid = self._slots(plan)
                dr.scatter(self._updated_dev, mi.UInt32(1), slot_probe, slot_valid)
            return
        merge_distance_sparse(self.dist_keys, vol, dres, acc, self.encoding, lazy_cap=self.cap_dist,
                              frame=self.frame)
        traced = dplan.probe_ids[dplan.counts > 0]
        vol.state.updates[traced] += 1
        self._updated[traced] = True
        self._updated[plan.probe_ids[plan.counts > 0]] = True

    @staticmethod
    def _slots(plan: RayPlan):
        """(probe per slot, slot used) on the device: a masked plan's own, a host plan's uploaded."""
        if plan.is_masked:
            return plan.probe_ids, plan.slot_valid
        return (upload(np.asarray(plan.probe_ids, np.uint32), mi.UInt32),
                upload((plan.counts > 0).astype(np.uint32), mi.UInt32) != 0)

    def _merge_closest(self, pipeline, res, acc, lane_cap=None) -> None:
        """``cache_update='closest-entry'``: each sample's radiance updates the irradiance texel its direction
        falls in (Algorithm 2's closest entry) with Algorithm 3's batch form through the encoding (the word
        stores the texel's mean radiance, not a cosine integral: biased where radiance varies over the
        hemisphere); with ``lane_cap`` the samples of changed octants merge with the dynamic N_max."""
        plan = res.plan
        w = mi.Float(1.0) + dr.zeros(mi.Float, plan.n_rays) if plan.weight is None else plan.weight
        parts = [(w, acc)]
        if lane_cap is not None:
            changed = lane_cap < int(self.params["n_max_static"])
            parts = [(dr.select(changed, 0.0, w), acc), (dr.select(changed, w, 0.0), self.acc_dynamic)]
        for wp, a in parts:
            sub = ProbeRayResults(res.radiance, res.distance, dataclasses.replace(plan, weight=wp))
            est = self.est_irr.irradiance(self.volume, sub)
            est = dataclasses.replace(est, count=mi.UInt32(dr.round(est.weight)))
            if self.device:
                pipeline.merge_slots(est, None, *self._slots(plan), accumulator=a, encoding=self.encoding)
            else:
                pipeline.merge(est, None, plan.probe_ids, plan.counts, accumulator=a, encoding=self.encoding)

    # -- the end of a frame ---------------------------------------------------------------------------
    def convolve_updated(self, pipeline):
        """The per-texel convolution pass (:mod:`.radiance`) for the probes updated this frame. Device path:
        those probes packed on the device (at most the slots merged this frame), the device convolution, a
        slot merge; returns a device count."""
        if self.device:
            S = max(min(self.volume.n_probes, self._slots_merged), 1)
            self._slots_merged = 0
            ids, ok = compact(self._updated_dev != 0, S)
            n = dr.count(ok)
            if self.params["cache_update"] == "convolve":
                est = self.radiance.irradiance_estimate_device(ids)
                pipeline.merge_slots(est, None, ids, ok, accumulator=self._mean, encoding=self.encoding)
            self._updated_dev = dr.zeros(mi.UInt32, self.volume.n_probes)
            return n
        ids = np.flatnonzero(self._updated).astype(np.uint32)
        self._updated[:] = False
        if len(ids) and self.params["cache_update"] == "convolve":
            est = self.radiance.irradiance_estimate(ids)
            pipeline.merge(est, None, ids, accumulator=self._mean, encoding=self.encoding)
        return len(ids)

    def cap_outer(self, mask: np.ndarray) -> None:
        """``N <- min(N, outer_count_cap)`` for the texels of probes in ``mask`` (V_out - V_in, Sec. 4.8), after
        the frame's updates: recorded per probe and applied lazily by the next merges of their texels
        (:class:`.sparse.LazyCountCap`; work over the probes of the mask, not the grid's texels). With
        ``cache_update='closest-entry'`` the irradiance texels' counts (Algorithm 3 there, the dense merge)
        are capped at once."""
        ids = np.flatnonzero(mask).astype(np.uint32)
        if not len(ids):
            return
        self.cap_rad.mark_outer(ids, self.frame)
        self.cap_dist.mark_outer(ids, self.frame)
        if self.params["cache_update"] != "closest-entry":
            return
        vol = self.volume
        dev = vol.device
        T = vol.irradiance_texels
        cap = dr.opaque(mi.UInt32, int(self.params["outer_count_cap"]))
        k = dr.arange(mi.UInt32, len(ids) * T * T)
        slot = k // (T * T)
        g = dr.gather(mi.UInt32, upload(ids, mi.UInt32), slot) * (T * T) + (k - slot * (T * T))
        c = dr.minimum(dr.gather(mi.UInt32, dev.irradiance_count, g), cap)
        dr.eval(c)
        dr.scatter(dev.irradiance_count, c, g)
        dr.eval(dev.irradiance_count)
        vol.state.device_is_newer(pull_from(dev))
