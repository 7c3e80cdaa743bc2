"""What every probe technique of the DDGI family shares at the technique layer (as :mod:`.vpl_base` for
the VPL techniques): the volume set-up from the parameters, primary shading (NEE direct + probe
indirect, :func:`dyngi.probes.primary.shade_primary`) and the probe view; the parameters common to all
of them (:data:`COMMON_PARAMS`, declared as data in :mod:`dyngi.probes.params`). A technique module
imports this, never another technique.
"""
from __future__ import annotations

from ..probes import ProbeGrid, ProbeQuery, ProbeVolume
from ..probes.debug import render_probe_view
from ..probes.params import COMMON_SPECS, parse_probe_counts
from ..probes.primary import shade_primary
from ..probes.trace import check_direct_mode
from .base import Frame, Param, StageTimer, Technique, to_image


def params_from(specs: dict) -> dict:
    """``Param`` entries from :mod:`dyngi.probes.params`' data."""
    return {k: Param(**v) for k, v in specs.items()}


COMMON_PARAMS = params_from(COMMON_SPECS)


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
                                                   self.grid.cell_diagonal), two_sided=p["two_sided"])
        self.query = ProbeQuery(self.volume, p["normal_bias"], p["view_bias"], visibility=p["visibility"])

    def _primary(self, frame: Frame, t: StageTimer):
        p = self.params
        with t.stage("primary"):
            L, ind, rays = shade_primary(self.scene, frame.camera, frame.res, self.query, frame.seed,
                                         frame.index, p["direct"], p["jitter"],
                                         direct_samples=p["direct_samples"], glossy=p["glossy"])
        t.add_rays("primary", rays)
        return to_image(L, frame.res), to_image(ind, frame.res)

    def debug_view(self, camera, res, radius: float = 0.15):
        """Image of the probes as spheres shaded by their stored irradiance (see :func:`render_probe_view`)."""
        return render_probe_view(self.scene, self.volume, camera, res, radius)


ProbeTechniqueBase = _ProbeTechniqueBase
