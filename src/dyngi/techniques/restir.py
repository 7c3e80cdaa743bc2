"""PT + ReSTIR (technique ``restir-pt``): ReSTIR DI at the primary vertex, path tracing for the rest.

The DDGI Resampling paper's baseline ("all rendering techniques are based on
an unbiased path tracer that uses ReSTIR [BWP*20] to estimate direct
illumination at the primary vertex", Sec. 5), built from Bitterli et al. 2020
("Spatiotemporal reservoir resampling", ReSTIR DI) where the paper is silent:

1. **G-buffer** (:mod:`dyngi.transport.gbuffer`): one jittered primary ray per
   pixel, motion by each shape's own rigid transform, disocclusion mask.
2. **Initial candidates** (Bitterli Alg. 3): ``candidates`` (M = 32) light
   samples per pixel from :class:`~dyngi.lights.candidates.EmitterCandidates`
   (area lights in area measure, environment in solid angle, delta lights as
   point masses), streamed through a reservoir with target
   ``p_hat(y) = lum(Lg(y)) * cos+(n, wi)`` (``|cos|`` on transmissive
   surfaces) -- the unshadowed contribution without the BSDF, our choice (it
   needs only the G-buffer's position and normal, so the target of any
   neighbour or of the previous frame is exact and cheap, see Bias below).
   **Visibility** (``visibility_reuse``, default ``'unbiased'``): one shadow ray to the chosen candidate
   before reuse, ``W = 0`` if occluded (Bitterli Alg. 5), and the reuse's MIS weights over
   ``p_hat_j(y) V_j(y)`` of the final sample at every other domain (Bitterli et al.'s unbiased variant; see
   :mod:`dyngi.transport.restir_di`).
3. **Temporal reuse** (Alg. 4/5 with the reprojected previous pixel's
   reservoir; M capped at ``m_cap`` x M, the "20x" of Bitterli Sec. 6);
   skipped where the disocclusion mask rejects the previous pixel.
4. **Spatial reuse**: ``spatial`` (3: the DDGI Resampling paper's "1 temporal
   and 3 spatial candidates", Sec. 3.5; Bitterli's 5 as an option) neighbours
   uniformly in a disk of ``radius`` (30) px at 1080p, scaled with the image width
   (at least 2 px), accepted by the depth (10 %) /
   normal (25 deg) similarity test (Bitterli Sec. 6). Its output is the next
   frame's temporal input.
5. **Shading**: one shadow ray for the final sample; the BSDF (Mitsuba's
   ``eval``) times ``Lg`` times the reservoir's ``W``.
6. **Rest of the path**: an unbiased path tracer (BSDF sampling + NEE with
   MIS, Russian roulette; :func:`dyngi.transport.restir_di.continue_paths`) continues from the
   primary vertex, counting light from vertex 3 on (and the emission seen
   through a *delta* lobe at the primary vertex, which ReSTIR's light samples
   cannot reach). ``max_depth`` as in ``path``: 1 emission only, 2 direct light.

Parameters
----------
candidates : int = 32     initial light candidates per pixel (M)
temporal : bool = True    temporal reuse
m_cap : float = 20        temporal M cap, in multiples of ``candidates``
spatial : int = 3         spatial neighbours per pixel (0: none; Bitterli: 5)
radius : float = 30       spatial reuse radius in pixels of a 1920-wide image (scaled with the width)
visibility_reuse : str = 'unbiased'  unbiased: 'unbiased' (visibility in the MIS weights, +4 shadow rays
                          per pixel) and 'none' (no visibility; 4x the accumulated block error of
                          'unbiased' in a room lit through a window); biased: 'candidate' (Alg. 5) and
                          'final' (20-64% dark there; docs/techniques/restir-pt.md)
combine : str = 'mis'     'mis' | '1/z' (unbiased) | 'biased' (:mod:`dyngi.sampling.reservoir`)
max_depth : int = 12      maximum path depth (-1: unbounded), Mitsuba's convention
rr_depth : int = 5        Russian roulette start depth
progressive : bool = True accumulate frames while the scene is static (like ``path``)
lights : str = 'scene'    light sampler of the candidates and of the path's NEE: Mitsuba's emitter
                          sampling, or a :mod:`dyngi.lights` sampler (:mod:`dyngi.lights.candidates`)
directions : str = 'bsdf' indirect directions of the path after the primary vertex: the BSDF, or 'cdq'
                          (:class:`dyngi.directions.walk.WalkDirections`; ReSTIR DI at the primary vertex
                          is unchanged)
leaf_scaling : bool = True  the octree thresholds of ``lights=vlc`` / ``directions=cdq``: ``nee-pt``'s rule
                          (:func:`dyngi.directions.octree.paper_thresholds`: the VLC paper's 4096 / 2048, Sec. 7,
                          from 8 x 4096 placed vertices per frame; below that scaled down, ours); false: the
                          paper's always. ``leaf_samples > 0`` raises the split threshold to it (collapse: half).
                          Each strategy keeps its own octree, built here at the first frame for 2 placed
                          vertices per pixel, handed over with ``share_octree`` and adapted here after the
                          strategy's end of frame (what the strategy did when it built its own)

Bias: none with ``combine='mis'`` or ``'1/z'`` and ``visibility_reuse='unbiased'`` (the default) or
``'none'`` (tested per region on ``living-room-sky`` and per pixel on the Cornell box against Mitsuba's
``path``). ``'candidate'`` (Bitterli's Alg. 5) and ``'final'`` are biased: the sample's visibility at its own
pixel decides its reuse while the MIS weights count every domain whose unshadowed target is positive, a
darkening wherever neighbours or the previous pixel cannot see the light (20-64 % per block in a room lit
through a window, docs/techniques/restir-pt.md). Besides, two documented approximations on
*dynamic* scenes: (a) the previous pixel's target is evaluated with the lights
as they are now (its emitter may have changed since), (b) a reservoir's ``W``
from the previous frame is reused although the lights may have moved; both
vanish on static frames. ``combine='biased'`` darkens where neighbours or the
previous pixel cannot see the sample (normal/depth edges, disocclusions); its
bias is measured in ``tests/techniques/test_restir.py`` (Cornell box, direct light: image mean -1.3 % +- 0.7 %,
30 of 432 pixels rejected by the per-pixel test). Shadow rays do not pass through
glass (unlike the DDGI family's NEE), so the reference is Mitsuba's ``path``.

Measured frame times and errors against ``path``: docs/techniques/restir-pt.md.
"""
from __future__ import annotations

from .. import directions as direction_samplers
from ..backend import mi
from ..directions.walk import WalkDirections
from ..errors import DyngiError
from ..lights.nee import octree_params, share_octrees
from ..transport.accumulate import ProgressiveMean
from ..transport.restir_di import MIN_RADIUS_PARAM, PARAM_SPECS, ReSTIRDI
from .base import Frame, FrameResult, Param, StageTimer, Technique, register, to_image

@register
class ReSTIRPTTechnique(Technique):
    """PT + ReSTIR: ReSTIR DI at the primary vertex (candidates, temporal, spatial), PT for the rest."""

    name = "restir-pt"
    description = ("path tracer with ReSTIR DI at the primary vertex (32 candidates, unbiased visibility reuse, "
                   "temporal x20 cap, 3 spatial neighbours, MIS), progressive")
    HAS_INDIRECT = True
    PARAMS = {
        **{k: Param(**v) for k, v in PARAM_SPECS.items()},
        "visibility_reuse": Param(**{**PARAM_SPECS["visibility_reuse"], "default": "unbiased",
                                     "doc": "visibility in the reservoirs: 'unbiased' (the default; Bitterli et "
                                     "al.'s unbiased variant, the DDGI Resampling paper's 'unbiased path tracer "
                                     "that uses ReSTIR', Sec. 5) the MIS weights over p_hat_j V_j of the final "
                                     "sample, one shadow ray per other domain; 'none' unbiased, no visibility "
                                     "(its accumulated blocks 4x noisier in a room lit through a window); "
                                     "'candidate' (Alg. 5) and 'final' biased: 20-64% dark in that room "
                                     "(docs/techniques/restir-pt.md)"}),
        "min_radius_px": Param(**MIN_RADIUS_PARAM),
        **octree_params("2 per pixel"),
        "max_depth": Param(12, "maximum path depth (-1: unbounded; 1 emission, 2 direct light)", min=-1),
        "rr_depth": Param(5, "Russian roulette start depth", min=1),
        "progressive": Param(True, "accumulate over frames while the scene is static"),
        "directions": Param("bsdf", "indirect directions of the path after the primary vertex (dyngi.directions): "
                            "the BSDF's own sampling, or 'cdq' (CDQ/BSDF one-sample MIS mixture, learned per "
                            "octree leaf)", choices=direction_samplers.names()),
    }

    def __init__(self, scene, params=None):
        super().__init__(scene, params)
        if self.params["max_depth"] == 0:
            raise DyngiError("parameter 'max_depth' = 0 renders nothing; use -1 (unbounded) or >= 1")
        # the light sampler of the candidates and the rest of the path (the component's ``lights``)
        self.restir = ReSTIRDI.from_params(scene, self.params, min_radius_px=self.params["min_radius_px"])
        self.lights = self.restir.lights
        # the BSDF's own sampling is the walk's default (None): bit-identical to before
        self.directions = None if self.params["directions"] == "bsdf" else WalkDirections(
            scene, self.params["directions"])
        self.octrees = None     # (light strategy's, direction strategy's) octree or None, built at frame 0
        self.accum = ProgressiveMean()

    def _share_octrees(self, records: int) -> None:
        """Build each octree-based strategy's octree with ``nee-pt``'s threshold rule for ``records`` placed
        vertices per frame and hand it over (``leaf_scaling`` in the module docstring)."""
        p = self.params
        self.octrees = share_octrees(self.lights, self.directions, records, p["leaf_samples"], p["leaf_scaling"])

    def step(self, frame: Frame) -> FrameResult:
        p = self.params
        t = StageTimer()
        if self.octrees is None:
            self._share_octrees(2 * frame.res[0] * frame.res[1])
        self.restir.lights_begin(frame, t)     # the light sampler's per-frame hook (rebuild, caches)
        if self.directions is not None:
            with t.stage("directions"):
                self.directions.begin_frame(self.scene, frame, 2 * frame.res[0] * frame.res[1])
        # -- G-buffer and reprojection --
        pv = self.restir.begin(frame, t)
        # -- ReSTIR DI: candidates, temporal, spatial, one shadow ray --
        direct = mi.Color3f(0.0)
        if (p["max_depth"] < 0 or p["max_depth"] >= 2) and self.restir.cand.count > 0:
            direct = self.restir.direct(pv, t)
        # -- emission at the primary vertex (and the environment where the ray escapes); the rest of the path --
        Le0, L_d, L_ind = self.restir.path_after(pv, frame, self.lights, p["max_depth"], p["rr_depth"], t,
                                                 self.directions)
        self.restir.lights_end(t)
        if self.octrees[0] is not None:     # the octree's owner adapts it (leaf_scaling, module docstring)
            with t.stage("lights adapt"):
                self.octrees[0].adapt()
        if self.directions is not None:
            with t.stage("directions adapt"):
                self.directions.end_frame()
                if self.octrees[1] is not None:
                    self.octrees[1].adapt()
        # -- accumulation --
        with t.stage("accumulate"):
            self.accum.add(mi.Color3f(Le0 + direct + L_d + L_ind), mi.Color3f(L_ind),
                           accumulate=p["progressive"] and frame.static)
        stats = t.as_dict()
        stats["accumulated_frames"] = self.accum.frames
        stats["spp"] = 1
        return FrameResult(image=to_image(self.accum.mean, frame.res),
                           indirect=to_image(self.accum.mean_ind, frame.res), stats=stats)
