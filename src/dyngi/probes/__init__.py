"""Probe volumes shared by the DDGI family (DDGI, Q-DDGI, ADGI, IS-DDGI, DDGI Resampling).

Replaceable pieces (Majercik et al., JCGT 2019 and 2021):

* :mod:`.grid`      -- :class:`ProbeGrid` (origin, spacing, counts)
* :mod:`.volume`    -- :class:`ProbeVolume` / :class:`ProbeVolumeState` (texel atlases, offsets, states)
* :mod:`.rays`      -- ray-direction strategies (uniform rotated spherical Fibonacci, fixed, per-texel lobes)
* :mod:`.trace`     -- tracing + hit shading of probe rays (:class:`DiffuseHitShader`) and the routing of
  light between NEE and the probes (the ``direct`` modes, :class:`~.trace.LightRouting`)
* :mod:`.estimator` -- this frame's rays -> per-texel means and counts (BLAS matrix path, Dr.Jit scatter path)
* :mod:`.accumulator` -- temporal merge with the stored texels (hysteresis, moving average, mean)
* :mod:`.blend`     -- estimator + accumulator: :class:`HysteresisBlend`, :class:`CappedMeanBlend`,
  :class:`TrueAverage`, :class:`ProbeBlend`
* :mod:`.encoding`  -- storage encodings (fp32, Q-DDGI, ADGI), one Dr.Jit store/load pair each
* :mod:`.states`    -- relocation and classification
* :mod:`.query`     -- the Dr.Jit irradiance query (:class:`ProbeQuery`)
* :mod:`.update`    -- :class:`ProbeUpdater`, one frame's update from these pieces
* :mod:`.primary`   -- the consumer: primary-vertex shading, NEE direct + probe indirect (:func:`shade_primary`)
* :mod:`.debug`     -- a view of the probes as shaded spheres (:func:`render_probe_view`)
"""
from .accumulator import HysteresisAccumulator, MeanAccumulator, CappedMeanAccumulator
from .blend import HysteresisBlend, CappedMeanBlend, ProbeBlend, TrueAverage, blend_matrix
from .estimator import MatrixEstimator, ScatterEstimator, TexelEstimate
from .encoding import ENCODINGS, get_encoding
from .grid import PROBE_ACTIVE, PROBE_INACTIVE, ProbeGrid
from .query import ProbeQuery
from .rays import FixedSFDirections, LobeDirections, RayPlan, UniformSFDirections
from .states import ProbeStates
from .trace import DIRECT_MODES, HIT_LOOKUPS, DiffuseHitShader, trace_probe_rays
from .primary import shade_primary
from .debug import render_probe_view
from .update import ProbeUpdater, probes_in_frustum
from .volume import ProbeVolume, ProbeVolumeState

__all__ = ["ProbeGrid", "ProbeVolume", "ProbeVolumeState", "ProbeQuery", "UniformSFDirections",
           "FixedSFDirections", "LobeDirections", "RayPlan", "DiffuseHitShader", "trace_probe_rays",
           "HysteresisBlend", "TrueAverage", "blend_matrix", "ProbeBlend", "CappedMeanBlend",
           "HysteresisAccumulator", "CappedMeanAccumulator", "MeanAccumulator", "MatrixEstimator",
           "ScatterEstimator", "TexelEstimate", "ProbeStates", "ProbeUpdater",
           "probes_in_frustum", "ENCODINGS", "get_encoding", "DIRECT_MODES", "HIT_LOOKUPS", "PROBE_ACTIVE",
           "PROBE_INACTIVE", "shade_primary", "render_probe_view"]
