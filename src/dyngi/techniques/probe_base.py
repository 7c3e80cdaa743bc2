"""What every probe technique of the DDGI family shares at the technique layer (as :mod:`.vpl_base` for
the VPL techniques): the volume set-up from the parameters, primary shading (NEE direct + probe
indirect, :func:`dyngi.probes.primary.shade_primary`) and the probe view; the parameters common to all
of them (:data:`COMMON_PARAMS`, declared as data in :mod:`dyngi.probes.params`). A technique module
imports this, never another technique.

Light sampler (``lights=``, issue 24 item 3): ``'scene'`` (default) is Mitsuba's emitter sampling over the
light the ``direct=`` routing gives NEE, bit for bit as before the parameter; a :mod:`dyngi.lights` name
builds one :class:`~dyngi.lights.nee.LightNEE` (:attr:`_ProbeTechniqueBase.light_nee`) that drives both the
primary-vertex NEE (:func:`~dyngi.probes.primary.shade_primary`) and the NEE at probe-ray hits (a technique
passes ``lights=self.light_nee`` to its :class:`~dyngi.probes.trace.DiffuseHitShader`). Its samples are
weighted by the routing (:meth:`~dyngi.probes.trace.LightRouting.nee_weight`), so the image's mean does not
depend on the sampler. The sampler's per-frame hooks: :meth:`_ProbeTechniqueBase._lights_begin` before the
frame's first probe ray (a technique's ``step`` calls it first; :meth:`_primary` calls it too, for a
technique that does not) and ``end_frame`` after the primary shading (:meth:`_primary`), which ends every
technique's frame.
"""
from __future__ import annotations

from ..lights.nee import LightNEE
from ..probes import ProbeGrid, ProbeQuery, ProbeVolume
from ..probes.debug import render_probe_view
from ..probes.params import COMMON_SPECS, LIGHT_SPECS, parse_probe_counts
from ..probes.primary import shade_primary
from ..probes.trace import check_direct_mode
from .base import Frame, Param, StageTimer, Technique, to_image


def params_from(specs: dict) -> dict:
    """``Param`` entries from :mod:`dyngi.probes.params`' data."""
    return {k: Param(**v) for k, v in specs.items()}


COMMON_PARAMS = params_from({**COMMON_SPECS, **LIGHT_SPECS})


class _ProbeTechniqueBase(Technique):
    """Shared set-up: grid, volume, query and primary shading."""

    HAS_INDIRECT = True   # FrameResult.indirect: albedo/pi * probe irradiance at the primary hit
    PROBE_TECHNIQUE = True  # traces a DDGI probe volume (the probe-leak tests run on every such technique)
    # Known limitation: under direct='sun'|'sky'|'emissive' the light the probes carry directly (the sky on
    # a probe ray's miss) is part of the probe irradiance, hence of FrameResult.indirect: the volume has
    # no bounced-only channel. ``compare --indirect`` warns; direct='nee' gives a true indirect image.
    INDIRECT_INCLUDES_PROBE_SKY = True

    def _setup_volume(self, irradiance_texels: int, distance_texels: int):
        p = self.params
        check_direct_mode(p["direct"])
        counts = parse_probe_counts(p["probe_counts"], self.scene)
        self.grid = ProbeGrid.from_scene(self.scene, counts)
        # the clamp never goes below the cell diagonal (issue 11, item 2): a shorter one caps the stored
        # mean distance below the distance from a probe to points of its own cell, and the Chebyshev test
        # then rejects probes that see the point
        self.volume = ProbeVolume(self.grid, irradiance_texels, distance_texels,
                                  max_distance=max(p["max_distance"] * self.grid.max_spacing,
                                                   self.grid.cell_diagonal), two_sided=p["two_sided"],
                                  hit_lobes=p["hit_lobes"])
        self.query = ProbeQuery(self.volume, p["normal_bias"], p["view_bias"], visibility=p["visibility"])
        kind = p.get("lights", "scene")
        self.light_nee = LightNEE(self.scene, kind) if kind != "scene" else None
        self._lights_open = False

    def walk_lanes(self, frame: Frame) -> int:
        """NEE shading points per frame, for a learning light sampler's octree thresholds: the pixels'
        ``direct_samples`` plus :meth:`probe_rays_hint` rays per probe (our choice)."""
        return (frame.res[0] * frame.res[1] * int(self.params.get("direct_samples", 1))
                + self.volume.n_probes * self.probe_rays_hint())

    def probe_rays_hint(self) -> int:
        """About how many rays a probe traces per frame (``rays_per_probe`` where the technique has it)."""
        return int(self.params.get("rays_per_probe", 64))

    def _lights_begin(self, frame: Frame, t: StageTimer) -> None:
        """The light sampler's ``begin_frame`` (table refresh, octree or hierarchy build), once per frame."""
        if self.light_nee is None or self._lights_open:
            return
        with t.stage("lights"):
            self.light_nee.begin_frame(self.scene, frame, self.walk_lanes(frame))
        self._lights_open = True

    def _primary(self, frame: Frame, t: StageTimer):
        p = self.params
        self._lights_begin(frame, t)
        with t.stage("primary"):
            L, ind, rays = shade_primary(self.scene, frame.camera, frame.res, self.query, frame.seed,
                                         frame.index, p["direct"], p["jitter"], lights=self.light_nee,
                                         direct_samples=p["direct_samples"], glossy=p["glossy"])
        t.add_rays("primary", rays)
        if self.light_nee is not None:      # the frame's NEE samples to a learning sampler; octree adapts
            with t.stage("lights"):
                self.light_nee.end_frame()
            self._lights_open = False
        return to_image(L, frame.res), to_image(ind, frame.res)

    def debug_view(self, camera, res, radius: float = 0.15):
        """Image of the probes as spheres shaded by their stored irradiance (see :func:`render_probe_view`)."""
        return render_probe_view(self.scene, self.volume, camera, res, radius)


ProbeTechniqueBase = _ProbeTechniqueBase
