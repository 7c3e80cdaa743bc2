"""Probe volumes shared by the DDGI family (DDGI, Q-DDGI, ADGI, IS-DDGI, DDGI Resampling).

One pipeline, five parts (Majercik et al., JCGT 2019 and 2021; docs/probes.md):

* :mod:`.pipeline`  -- :class:`ProbePipeline`: plan -> trace/shade -> estimate -> accumulate -> encode, the
  shared warm-up and the state update; every probe technique builds one
* :mod:`.protocols` -- the five parts as declared interfaces (``RayPlanner``, ``HitShader``, ``Estimator``,
  ``TemporalAccumulator``, ``Encoding``)
* :mod:`.rays`      -- ray planners (uniform rotated spherical Fibonacci, fixed, per-texel lobes) and ``RayPlan``
* :mod:`.trace`     -- tracing + hit shading of probe rays (:class:`DiffuseHitShader`) and the routing of
  light between NEE and the probes (the ``direct`` modes, :class:`~.trace.LightRouting`)
* :mod:`.estimator` -- this frame's rays -> per-texel means and counts (BLAS matrix path, Dr.Jit scatter path)
* :mod:`.accumulator` -- temporal merge with the stored texels (hysteresis, capped mean, mean)
* :mod:`.encoding`  -- storage encodings (fp32, Q-DDGI, ADGI), one Dr.Jit store/load pair each
* :mod:`.blend`     -- estimator + accumulator + encoding: :class:`HysteresisBlend`, :class:`CappedMeanBlend`,
  :class:`TrueAverage`, :class:`ProbeBlend`

and around them:

* :mod:`.grid`, :mod:`.volume` -- :class:`ProbeGrid`; :class:`ProbeVolume` / :class:`ProbeVolumeState`
  (texel atlases, offsets, states)
* :mod:`.states`    -- relocation and classification
* :mod:`.params`    -- the probe techniques' parameter table, as data
* :mod:`.query`     -- the Dr.Jit irradiance query (:class:`ProbeQuery`)
* :mod:`.lookup`, :mod:`.glossy` -- the one probe lookup of every consumer: ``albedo / pi * E`` and Eq. 6's
  glossy term
* :mod:`.primary`   -- the consumer: primary-vertex shading, NEE direct + probe indirect (:func:`shade_primary`)
* :mod:`.ddgi_plus` -- the DDGI+ volume of DDGI Resampling (Eq. 5 update, Eq. 6 queries)
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
from .pipeline import ProbePipeline, probes_in_frustum
from .volume import ProbeVolume, ProbeVolumeState

__all__ = ["ProbeGrid", "ProbeVolume", "ProbeVolumeState", "ProbeQuery", "UniformSFDirections",
           "FixedSFDirections", "LobeDirections", "RayPlan", "DiffuseHitShader", "trace_probe_rays",
           "HysteresisBlend", "TrueAverage", "blend_matrix", "ProbeBlend", "CappedMeanBlend",
           "HysteresisAccumulator", "CappedMeanAccumulator", "MeanAccumulator", "MatrixEstimator",
           "ScatterEstimator", "TexelEstimate", "ProbeStates", "ProbePipeline",
           "probes_in_frustum", "ENCODINGS", "get_encoding", "DIRECT_MODES", "HIT_LOOKUPS", "PROBE_ACTIVE",
           "PROBE_INACTIVE", "shade_primary", "render_probe_view"]
