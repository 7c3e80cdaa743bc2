"""Secondary DDGI and DDGI Resampling (Majercik, Mueller, Keller, Nowrouzezahrai, McGuire 2022).

Both techniques hold the transport layer's ReSTIR DI component (G-buffer, reservoirs, area-measure light
candidates; :class:`~dyngi.transport.restir_di.ReSTIRDI`, as ``restir-pt`` does) and replace the rest
of the path after the secondary vertex by the DDGI+ probes of
:class:`~dyngi.probes.ddgi_plus.DDGIPlusVolume` (Sec. 3.3, Eq. 5: the probes hold ``L_DDGI+ ~ T_f L``,
direct light from emitting surfaces and the sky included; delta lights and a sunsky's sun are added by
NEE at every point where the probes are read, since no probe ray can hit them).

The package, by concept:

* :mod:`.shading`: ``S(x_n)``, the shading of a secondary vertex (Sec. 3.4-3.5: footprint, probes,
  glossy recursion, view-path bias), and the frame set-up both techniques share (ReSTIR DI component,
  DDGI+ volume, G-buffer, the BSDF sample at the primary vertex, progressive accumulation);
* :mod:`.secondary`: technique ``ddgi-secondary`` (Secondary DDGI, Sec. 4 item 3);
* :mod:`.resampling`: technique ``ddgi-resampling`` (DDGI Resampling, Sec. 3.2, 3.6, 3.7: one reservoir
  over emitter samples and BSDF-sampled secondary hits, bounded geometry term, query caching);
* :mod:`.control_variate`: the control variates of Sec. 5.1 (the nearest-ray one and its spherical
  geometry: cube-map bins, exact clipped cosine integrals).

Stats: per stage (``ms``/``rays``) and ``table2_ms`` = {trace & shade, resampling, update} as the
paper's Table 2 groups them.

Parameters (both; ``ddgi-resampling`` adds ``gmax``, ``gmax_scale``, ``target_bsdf``, ``reuse_visibility``,
``target_floor``, ``control_variate``, ``cv_kind``)
-----------------------------------------------------------------------------------------------------
candidates, temporal, m_cap, spatial, radius, combine, visibility_reuse, progressive : as ``restir-pt``
                               (``ddgi-resampling``'s ``m_cap`` default: :data:`.resampling.M_CAP`)
footprint_c : float = 0.2      Eq. 8 threshold c
max_glossy : int = 3           most glossy recursion steps after the secondary vertex
view_path_bias : float = 0.2   Sec. 3.5 offset, in units of the smallest probe spacing
exact_radiance, exact_depth    the test hook (:mod:`.shading`)
probe parameters               those of :data:`dyngi.probes.params.DDGI_PLUS_SPECS` (DDGI's, the
                               emission heuristic, Sec. 3.5's ``update_view_path_bias`` at probe-ray
                               hits, ...); ``normal_bias``/``view_bias`` default 0

Measured frame times, errors and leaks: docs/techniques/ddgi-resampling.md.

Bias: the probes' (blur at the probe spacing, leaks through thin walls, hysteresis lag), hidden behind
one diffuse bounce (or a footprint-limited glossy chain); temporal reuse of part-1 samples keeps the
cached ``L_y`` of the previous frame (an approximation only in the resampling weights, Sec. 3.7).
"""
from .control_variate import NearestRayCV, clipped_cosine_integral, cube_bin, cube_texel_corners
from .resampling import M_CAP, DDGIResamplingTechnique, bounded_fraction
from .secondary import DDGISecondaryTechnique
from .shading import FOOTPRINT_C, camera_footprint, footprint_np, footprint_term

__all__ = ["DDGISecondaryTechnique", "DDGIResamplingTechnique", "camera_footprint", "footprint_term",
           "footprint_np", "bounded_fraction", "NearestRayCV", "cube_bin", "cube_texel_corners",
           "clipped_cosine_integral", "FOOTPRINT_C", "M_CAP"]
