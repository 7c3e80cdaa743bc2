"""Light (next-event) sampling strategies, pluggable into the path tracer.

A strategy provides the pair used by NEE with multiple importance sampling:

* ``sample(scene, si, u2, active) -> (ds, weight)``: a direction sample towards
  an emitter with its solid-angle pdf in ``ds.pdf`` and ``weight`` = emitted
  radiance / pdf, already multiplied by visibility (a shadow ray);
* ``pdf(scene, ref_si, ds, active) -> Float``: the solid-angle pdf with which
  ``sample`` would have produced ``ds`` (for the BSDF-sampled MIS weight).

Optionally ``sample_traced(scene, si, u2, active, receiver=None) -> (ds, weight,
traced)`` also returns the mask of lanes that cast a shadow ray (ray counts
are measured, not assumed) and, given a ``receiver`` normal, skips the shadow
ray of samples below it; :func:`sample_traced` falls back to ``sample`` for
strategies without it.

Shadow rays are traced through :mod:`dyngi.rays` and counted there (issue 40; Mitsuba's own visibility
test in ``sample_emitter_direction``, whose rays no wrapper sees, is not used):
``sample_traced(..., stage=, lanes=)`` counts them under ``stage``; with ``lanes=True`` (a caller inside a
symbolic loop, the path walk) it does not, and returns a fourth value, the rays traced per lane, for the
caller's per-lane count.

ReSTIR, the light BVH, the VLC and the CDQ replace :class:`EmitterSampling`.
"""
from __future__ import annotations

import numpy as np

from .. import rays
from ..backend import dr, mi
from ..scene.passthrough import count_lanes, scene_has_glass, shadow_transmittance


class EmitterSampling:
    """Mitsuba's emitter sampling: an emitter chosen by ``sampling_weight``, then a point on it."""

    name = "emitter"

    def sample(self, scene, si, u2, active):
        ds, spec, _ = self.sample_traced(scene, si, u2, active)
        return ds, spec

    def sample_traced(self, scene, si, u2, active, receiver=None, *, stage: str = "shadow", lanes: bool = False):
        """Mitsuba's ``scene.sample_emitter_direction`` with its visibility test: the shadow ray traced here, as
        Mitsuba traces it (``spawn_ray_to(ds.p)`` where ``ds.pdf != 0``; weight and pdf 0 where occluded),
        and counted (:mod:`dyngi.rays`). Returns (ds, weight, lanes whose sample is unoccluded with a nonzero
        pdf: the mask Mitsuba's result leaves) and with ``lanes`` the shadow rays per lane. With a ``receiver``
        normal, samples below it get weight 0 (their shadow ray is still traced, as before)."""
        active = mi.Bool(active)
        ds, spec = scene.sample_emitter_direction(si, u2, False, active)
        shot = active & (ds.pdf != 0.0)
        occ = rays.occluded(scene, si.spawn_ray_to(ds.p), shot, stage=stage, lanes=lanes)
        spec = dr.select(occ, 0.0, spec)
        ds.pdf = dr.select(occ, 0.0, ds.pdf)
        w = mi.Color3f(spec)
        if receiver is not None:
            w = dr.select(dr.dot(receiver, ds.d) > 0.0, w, 0.0)
        traced = active & (ds.pdf != 0.0)
        if lanes:
            return ds, w, traced, mi.UInt32(shot)
        return ds, w, traced

    def pdf(self, scene, ref_si, ds, active):
        return scene.pdf_emitter_direction(ref_si, ds, active)


class EmitterSubsetSampling:
    """Next-event estimation restricted to a subset of the scene's emitters.

    Used when another estimator already carries some emitters' light (DDGI's
    probes carry the sky in ``direct='sky'`` mode, or all emissive surfaces
    in ``'emissive'`` mode): NEE then samples only the others, chosen in
    proportion to their ``sampling_weight``, instead of sampling all of them
    and discarding part of the samples (same expectation, less noise). A scene
    lit only by a sun and a sky thus gets noise-free direct sunlight.

    ``keep(emitter) -> bool`` selects the emitters (host side, once per scene);
    ``extra`` adds emitters that are not the scene's own (the sun part of a
    ``sunsky``, :mod:`dyngi.scene.sunsky`). Shadow rays pass through clear
    surfaces (glass) attenuated by their transmittance where the scene has any
    (:mod:`dyngi.scene.passthrough`; a deliberate bias).
    With a single emitter in the subset (a Cornell box, a sun) the emitter's
    own ``sample_direction`` is traced into the kernel directly instead of
    through a virtual call on a gathered emitter pointer (about 2 ms less per
    258k probe-ray hits on the 2-core machine, docs/techniques/ddgi.md).
    """

    name = "emitter-subset"

    def __init__(self, mi_scene, keep, extra=()):
        emitters = list(mi_scene.emitters())
        chosen = [e for e in emitters if keep(e)] + [e for e in extra if e is not None]
        self.count = len(chosen)
        self.emitters = chosen          # keeps ``extra`` emitters (not owned by the scene) alive
        self.single = chosen[0] if self.count == 1 else None   # sampled without dispatch
        self.glass = scene_has_glass(mi_scene)
        if self.count:
            w = [float(e.sampling_weight()) for e in chosen]
            if sum(w) <= 0:
                w = [1.0] * len(chosen)
            self.table = mi.DiscreteDistribution(w)
            self.ptrs = mi.EmitterPtr(chosen)
            # selection pmf by emitter registry id (what an EmitterPtr holds), for pdf()
            ids = np.asarray(dr.reinterpret_array(mi.UInt32, self.ptrs), np.int64)
            table = np.zeros(int(ids.max()) + 1, np.float32)
            table[ids] = np.asarray(w, np.float64) / sum(w)
            self.pmf_by_id = mi.Float(table)

    def sample(self, scene, si, u2, active):
        ds, w, _ = self.sample_traced(scene, si, u2, active)
        return ds, w

    def sample_traced(self, scene, si, u2, active, receiver=None, *, stage: str = "shadow", lanes: bool = False):
        """``sample``, plus the mask of lanes that cast a shadow ray (counted under ``stage``,
        :mod:`dyngi.rays`; with ``lanes`` not counted, and a fourth value: the rays traced per lane).

        With a ``receiver`` normal, samples with ``dot(receiver, d) <= 0`` get
        weight 0 and no shadow ray: exact for a receiver that only reflects
        light arriving above it (a diffuse surface, ``receiver`` its shading
        normal), as pbrt skips the shadow ray of a zero BSDF value.
        """
        if not self.count:
            out = dr.zeros(mi.DirectionSample3f), mi.Color3f(0.0), mi.Bool(False)
            return out + (mi.UInt32(0),) if lanes else out
        active = mi.Bool(active)
        if self.single is not None:      # no selection, no virtual call
            ds, spec = self.single.sample_direction(si, u2, active)
        else:
            k, ux, pmf = self.table.sample_reuse_pmf(u2.x, active)
            em = dr.gather(mi.EmitterPtr, self.ptrs, k, active)
            ds, spec = em.sample_direction(si, mi.Point2f(ux, u2.y), active)
            ds.pdf *= pmf                # the selection pmf (> 0 for the selected emitter)
            spec = spec / pmf
        active &= ds.pdf != 0.0
        if receiver is not None:
            active &= dr.dot(receiver, ds.d) > 0.0
        shadow = si.spawn_ray_to(ds.p)
        if self.glass:      # clear surfaces pass light, attenuated (dyngi.scene.passthrough)
            T, n = shadow_transmittance(scene, shadow, active, stage=stage, lanes=True)
            spec = mi.Color3f(spec) * T
            count_lanes(stage, n, lanes)
        else:
            spec = dr.select(active & ~rays.occluded(scene, shadow, active, stage=stage, lanes=lanes), spec, 0.0)
            n = mi.UInt32(active)
        if lanes:
            return ds, mi.Color3f(spec), active, n
        return ds, mi.Color3f(spec), active

    def pdf(self, scene, ref_si, ds, active):
        if not self.count:
            return mi.Float(0.0)
        # the emitter's selection probability, looked up by its registry id (0 outside the subset)
        rid = dr.reinterpret_array(mi.UInt32, ds.emitter)
        pmf = dr.gather(mi.Float, self.pmf_by_id, rid, active & (rid < dr.width(self.pmf_by_id)))
        return ds.emitter.pdf_direction(ref_si, ds, active & (pmf > 0.0)) * pmf


def sample_traced(lights, scene, si, u2, active, receiver=None, *, stage: str = "shadow", lanes: bool = False):
    """``lights.sample_traced(...)``: (ds, weight, lanes that cast a shadow ray), its shadow rays counted under
    ``stage`` (:mod:`dyngi.rays`; with ``lanes`` not counted, and a fourth value: the rays per lane). A
    strategy without ``sample_traced`` must trace through :mod:`dyngi.rays` itself; its shadow-ray mask is
    taken as the lanes with a nonzero pdf."""
    if hasattr(lights, "sample_traced"):
        return lights.sample_traced(scene, si, u2, active, receiver, stage=stage, lanes=lanes)
    ds, w = lights.sample(scene, si, u2, active)
    if receiver is not None:
        w = dr.select(dr.dot(receiver, ds.d) > 0.0, w, 0.0)
    traced = mi.Bool(active) & (ds.pdf != 0.0)
    return (ds, w, traced, mi.UInt32(traced)) if lanes else (ds, w, traced)
