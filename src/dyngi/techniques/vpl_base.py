"""Shared frame of the VPL techniques (``ir``, ``smcir``): VPLs -> G-buffer shading -> image.

A subclass implements :meth:`VPLTechnique.update_vpls` (this frame's VPL set as
positions, normals and shading weights ``flux = L / (I p)``); the base renders
the frame: emission seen directly + direct light by NEE over every emitter
(:func:`dyngi.probes.primary.shade_primary`, routing ``'nee'``, pixel-centre
camera rays; through the ``lights=`` sampler when one is chosen: :class:`~dyngi.lights.nee.TracedNEE`)
+ the VPLs' indirect light ``albedo / pi * E_vpl``
(:class:`dyngi.vpl.shading.VPLShader`). ``FrameResult.indirect`` is the VPL part:
light that reflected at least once before the primary vertex (VPL radiosities
never contain the VPL surface's own emission).

Common parameters
-----------------
vpls : int = 0          VPL budget I; 0: the scene's (512 for ``maze``, else 2048, as Table 1)
max_depth : int = 5     path vertices, Mitsuba's count (camera hit x = 1): 5 = three bounces of
                        indirect light (Sec. 5); 2 = direct light only, 3 = one bounce
shading : str = 'interleaved'  'interleaved' (4x4 tiles + cross-bilateral filter) or 'exhaustive'
clamp_distance : float = 0.05  geometry-term clamp G_max = 1 / (c * diagonal)^2 (0: no clamp), the same
                               for every budget (the rule: :mod:`dyngi.vpl.shading`)
direct_samples : int = 1       NEE samples per pixel for the direct light
lights : str = 'scene'          light sampler (:mod:`dyngi.lights` through :class:`~dyngi.lights.nee.LightNEE`;
                               'scene': Mitsuba's emitter sampling) of the direct light's NEE at the camera's
                               hit and of the VPLs' light: ``smcir`` and ``mir`` estimate radiosity with the
                               path walk, whose NEE it is (every sampler); ``ir`` and ``tcas`` carry radiosity
                               on photons leaving the lights, whose lights it chooses (:mod:`dyngi.vpl.emission`;
                               'scene', 'uniform', 'power': a photon has no shading point).
"""
from __future__ import annotations

import numpy as np

from .. import lights as light_samplers
from ..backend import dr
from ..lights.nee import PRIMARY_NEE_STREAM, LightNEE, TracedNEE
from ..probes.primary import shade_primary
from ..vpl.emission import EMISSION_SAMPLERS
from ..vpl.shading import MODES, VPLShader, clamp_value
from .base import Frame, FrameResult, Param, StageTimer, Technique, to_image

SCENE_VPL_BUDGETS = {"maze": 512}
"""VPL budgets of Table 1 by scene (the maze: 512); every other scene: :data:`DEFAULT_VPLS`."""
DEFAULT_VPLS = 2048

COMMON_PARAMS = {
    "vpls": Param(0, "VPL budget I (0: the scene's: 512 for maze, else 2048)", min=0, max=1 << 16),
    "max_depth": Param(5, "path vertices (camera hit = 1); 5 = three indirect bounces", min=2, max=16),
    "shading": Param("interleaved", "VPL shading: 4x4 interleaved + bilateral filter, or all VPLs", choices=MODES),
    "clamp_distance": Param(0.05, "geometry-term clamp distance, fraction of the scene diagonal (0: none)",
                            min=0.0, max=1.0),
    "direct_samples": Param(1, "NEE samples per pixel for direct light", min=1, max=64),
    "filter_sigma_px": Param(2.0, "bilateral filter: position sigma in pixel footprints", min=0.01),
    "filter_normal_power": Param(16.0, "bilateral filter: exponent of the normals' dot product", min=0.0),
    "lights": Param("scene", "light sampler of the direct light's and the VPL radiosity's NEE ('scene': "
                    "Mitsuba's emitter sampling)", choices=("scene",) + light_samplers.names()),
}
EMISSION_LIGHTS = Param("scene", "light sampler of the direct light's NEE and of the photons' lights ('scene': "
                        "Mitsuba's emitter sampling)", choices=("scene",) + EMISSION_SAMPLERS)
"""``lights=`` of the photon techniques (``ir``, ``tcas``): :mod:`dyngi.vpl.emission`."""


def scene_vpl_budget(scene) -> int:
    """The scene's VPL budget: ``scene.vpl_budget`` if set, else :data:`SCENE_VPL_BUDGETS`, else 2048."""
    b = getattr(scene, "vpl_budget", None)
    if b:
        return int(b)
    return SCENE_VPL_BUDGETS.get(getattr(scene, "name", ""), DEFAULT_VPLS)


class VPLTechnique(Technique):
    """Base of the VPL techniques; subclasses implement ``update_vpls``."""

    HAS_INDIRECT = True
    PARAMS = dict(COMMON_PARAMS)

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        self.budget = int(self.params["vpls"]) or scene_vpl_budget(scene)
        self.gmax = clamp_value(scene, self.params["clamp_distance"])
        kind = self.params["lights"]
        self.lights = LightNEE(scene, kind) if kind != "scene" else None

    def walk_lanes(self) -> int:
        """Path-walk lanes per frame (a learning light sampler sizes its octree from it)."""
        return 16 * self.budget

    @property
    def bounces(self) -> int:
        """Bounces of indirect light (max_depth - 2)."""
        return int(self.params["max_depth"]) - 2

    def step(self, frame: Frame) -> FrameResult:
        """Shade this frame with the VPLs of the subclass's ``update_vpls(frame, timer) -> (pos[n,3],
        nrm[n,3], flux[n,3], stats dict)`` (each of ``ir``, ``mir``, ``tcas``, ``smcir`` defines it): NumPy
        rows or Dr.Jit arrays (kept on the device); stats may hold Dr.Jit scalars, read after the image."""
        p = self.params
        t = StageTimer()
        if self.lights is not None:     # the light sampler's per-frame hook (table refresh, cache build)
            with t.stage("lights"):
                self.lights.begin_frame(self.scene, frame, self.walk_lanes())
        pos, nrm, flux, extra = self.update_vpls(frame, t)
        if self.lights is not None:
            with t.stage("lights"):
                self.lights.end_frame()
        with t.stage("shading"):
            shader = VPLShader(self.scene, frame.res, frame.camera, pos, nrm, flux, p["shading"], self.gmax,
                               p["filter_normal_power"], p["filter_sigma_px"])
            # the light sampler's NEE at the camera's hit, its selection numbers from a stream of its own
            direct = (TracedNEE.stream(self.lights, frame.res[0] * frame.res[1], frame.seed, frame.index,
                                       PRIMARY_NEE_STREAM) if self.lights is not None else None)
            L, ind, rays = shade_primary(self.scene, frame.camera, frame.res, shader, frame.seed, frame.index,
                                         "nee", False, lights=direct, direct_samples=p["direct_samples"])
            dr.eval(L, ind)
        t.add_rays("shading", rays)
        t.add_rays("shading", shader.rays)
        stats = t.as_dict()
        # device counts (a VPL set built on the device) are read here, once, after the image
        stats.update({k: (v if isinstance(v, (int, float, str, type(None), np.integer, np.floating))
                          else float(np.asarray(v).ravel()[0])) for k, v in extra.items()})
        img = to_image(L, frame.res)
        indirect = to_image(ind, frame.res)
        return FrameResult(image=np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0),
                           indirect=np.nan_to_num(indirect, nan=0.0, posinf=0.0, neginf=0.0), stats=stats)
