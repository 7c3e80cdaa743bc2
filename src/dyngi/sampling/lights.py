"""Light (next-event) sampling strategies, pluggable into the path tracer.

A strategy provides the pair used by NEE with multiple importance sampling:

* ``sample(scene, si, u2, active) -> (ds, weight)``: a direction sample towards
  an emitter with its solid-angle pdf in ``ds.pdf`` and ``weight`` = emitted
  radiance / pdf, already multiplied by visibility (a shadow ray);
* ``pdf(scene, ref_si, ds, active) -> Float``: the solid-angle pdf with which
  ``sample`` would have produced ``ds`` (for the BSDF-sampled MIS weight).

ReSTIR, the light BVH, the VLC and the CDQ replace :class:`EmitterSampling`.
"""
from __future__ import annotations

from ..backend import mi


class EmitterSampling:
    """Mitsuba's emitter sampling: an emitter chosen by ``sampling_weight``, then a point on it."""

    name = "emitter"

    def sample(self, scene, si, u2, active):
        return scene.sample_emitter_direction(si, u2, True, active)

    def pdf(self, scene, ref_si, ds, active):
        return scene.pdf_emitter_direction(ref_si, ds, active)
