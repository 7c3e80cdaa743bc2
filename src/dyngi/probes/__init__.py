"""Probe volumes shared by the DDGI family (DDGI, Q-DDGI, ADGI, IS-DDGI, DDGI Resampling).

Replaceable pieces (Majercik et al., JCGT 2019 and 2021):

* :mod:`.grid`      -- :class:`ProbeGrid` (origin, spacing, counts)
* :mod:`.volume`    -- :class:`ProbeVolume` / :class:`ProbeVolumeState` (texel atlases, offsets, states)
* :mod:`.rays`      -- ray-direction strategies (uniform rotated spherical Fibonacci, fixed, per-texel lobes)
* :mod:`.trace`     -- tracing + hit shading of probe rays (:class:`DiffuseHitShader`)
* :mod:`.blend`     -- accumulation (:class:`HysteresisBlend` as a dense matrix product, :class:`TrueAverage`)
* :mod:`.encoding`  -- storage encodings (fp32, Q-DDGI, ADGI)
* :mod:`.states`    -- relocation and classification
* :mod:`.query`     -- the Dr.Jit irradiance query (:class:`ProbeQuery`)
* :mod:`.update`    -- :class:`ProbeUpdater`, one frame's update from these pieces
* :mod:`.debug`     -- a view of the probes as shaded spheres
"""
from .blend import HysteresisBlend, TrueAverage, blend_matrix
from .encoding import ENCODINGS, get_encoding
from .grid import PROBE_ACTIVE, PROBE_INACTIVE, ProbeGrid
from .query import ProbeQuery
from .rays import FixedSFDirections, LobeDirections, RayPlan, UniformSFDirections
from .states import ProbeStates
from .trace import DIRECT_MODES, HIT_LOOKUPS, DiffuseHitShader, trace_probe_rays
from .update import ProbeUpdater, probes_in_frustum
from .volume import ProbeVolume, ProbeVolumeState

__all__ = ["ProbeGrid", "ProbeVolume", "ProbeVolumeState", "ProbeQuery", "UniformSFDirections",
           "FixedSFDirections", "LobeDirections", "RayPlan", "DiffuseHitShader", "trace_probe_rays",
           "HysteresisBlend", "TrueAverage", "blend_matrix", "ProbeStates", "ProbeUpdater",
           "probes_in_frustum", "ENCODINGS", "get_encoding", "DIRECT_MODES", "HIT_LOOKUPS", "PROBE_ACTIVE",
           "PROBE_INACTIVE"]
