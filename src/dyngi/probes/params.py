"""The probe techniques' parameters, declared once as data (``ddgi``'s table; the others change defaults).

:data:`COMMON_SPECS` (grid, query biases, light routing, primary shading: every probe technique),
:data:`LIGHT_SPECS` (the light sampler of the probe techniques' NEE; apart, because the DDGI+ volume's
table is built from :data:`COMMON_SPECS` and the DDGI Resampling family has a ``lights=`` of its own),
:data:`DDGI_SPECS` (DDGI's probe update, Majercik et al., JCGT 2019 and 2021) and :data:`PLUS_SPECS`
(the DDGI+ update's own, Majercik et al. 2022, Sec. 3.3-3.5) are plain keyword dicts
``{name: dict(default=, doc=, choices=, min=, max=)}``. :data:`DDGI_PLUS_SPECS` is the DDGI+ volume's
table (:class:`dyngi.probes.ddgi_plus.DDGIPlusVolume`): ``ddgi``'s less primary shading, plus
:data:`PLUS_SPECS`. The technique layer turns them into its ``Param`` entries
(:func:`dyngi.techniques.probe_base.params_from`); the DDGI+ volume validates its parameters against the
same table (:func:`parse_params`). Keeping them here lets :mod:`dyngi.probes` hold the table without
importing a technique.
"""
from __future__ import annotations

from .. import lights as light_samplers
from ..errors import DyngiError
from ..registry import Param
from .trace import (DEFAULT_DIRECT, DEFAULT_HIT_LOBES, DEFAULT_TWO_SIDED, DIRECT_MODES, HIT_LOBES,
                    HIT_LOOKUPS, TWO_SIDED_RULES)


def spec(default, doc: str = "", choices: tuple | None = None, min: float | None = None,
         max: float | None = None, **marks) -> dict:
    """One parameter as data: the keyword arguments of the technique layer's ``Param`` (``marks``: its
    ``ours=`` / ``paper=``, issue 40)."""
    return {"default": default, "doc": doc, "choices": choices, "min": min, "max": max, **marks}


def parse_probe_counts(text: str, scene) -> tuple:
    """'' -> the scene's counts; 'n' -> (n, n, n); 'nx,ny,nz' -> tuple."""
    text = str(text).strip()
    if not text:
        return tuple(int(c) for c in scene.meta.probe_counts)
    try:
        parts = [int(p) for p in text.replace("x", ",").split(",") if p.strip()]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts = parts * 3
    if len(parts) != 3 or min(parts) < 2:
        raise DyngiError(f"parameter 'probe_counts' must be 'n' or 'nx,ny,nz' with counts >= 2, got '{text}'")
    return tuple(parts)


COMMON_SPECS = {
    "probe_counts": spec("", "probe grid counts: 'nx,ny,nz' or 'n' (default: the scene's grid)"),
    "normal_bias": spec(0.05, "query offset along the normal, in units of the smallest probe spacing", min=0.0),
    "view_bias": spec(0.2, "query offset towards the viewer, in units of the smallest probe spacing", min=0.0),
    "visibility": spec(True, "Chebyshev visibility test at query time"),
    "max_distance": spec(1.5, "distance clamp, in units of the largest probe spacing; never below the "
                          "cell diagonal", min=0.1),
    "direct": spec(DEFAULT_DIRECT, "light handled by NEE (the rest by the probes, see dyngi.probes.trace): "
                    "'sun' all emitters and a sunsky's sun, not the sky; 'sky' all but the environment; "
                    "'nee' all; 'emissive' delta lights only", choices=DIRECT_MODES),
    "jitter": spec(True, "jitter primary rays uniformly inside the pixel, as the box-filtered reference "
                    "integrates (False: pixel centres, which counts aliasing at edges as error)"),
    "direct_samples": spec(1, "NEE samples per pixel for direct light at the primary hit", min=1, max=64),
    "two_sided": spec(DEFAULT_TWO_SIDED, "how a probe ray that hits the back of a two-sided surface counts for "
                       "the distance moments, relocation and classification: 'enclosed' a back face iff the "
                       "probe is enclosed by something thinner than a cell along that line (a slab, a thick "
                       "wall), else a front face; 'front' always a front face; 'back' always a back face "
                       "(dyngi.probes.trace, 'The two-sided rule'; ours: the papers treat every back face as a "
                       "back face, i.e. 'back')", choices=TWO_SIDED_RULES, ours=True, paper="back"),
    "hit_lobes": spec(DEFAULT_HIT_LOBES, "which lobes a probe-ray hit reflects as diffuse light: 'layered' (ours) "
                      "the diffuse lobe plus a coated BSDF's (plastic, roughplastic, principled) rough glossy "
                      "reflection albedo, one BSDF sample per ray; 'diffuse' the diffuse lobe only (DDGI, "
                      "Majercik et al. 2019, Sec. 3.1). The DDGI+ volume's Eq. 5 hits (mode 'plus') "
                      "read the diffuse lobe and Eq. 6's glossy term instead (dyngi.probes.trace, 'the hit-lobe "
                      "rule')", choices=HIT_LOBES, ours=True, paper="diffuse"),
    "glossy": spec(False, "add the glossy probe lookup (DDGI Resampling Eq. 6: one glossy-lobe BSDF sample, "
                    "the probe irradiance along it / pi) at the primary hit; False: diffuse indirect only, "
                    "as DDGI (dyngi.probes.primary)"),
}


LIGHT_SPECS = {
    "lights": spec("scene", "light sampler of the NEE at the primary hit and at probe-ray hits (dyngi.lights "
                   "through dyngi.lights.nee.TracedNEE; its samples weighted by the direct= routing, so NEE "
                   "still carries only the light the probes do not; 'scene': Mitsuba's emitter sampling over "
                   "exactly that light)", choices=("scene",) + light_samplers.names()),
}


DDGI_SPECS = {
    "rays_per_probe": spec(256, "rays per active probe per frame", min=1, max=1 << 14),
    "warmup": spec(8, "extra probe updates on the first frame, blended without hysteresis, so that "
                    "multi-bounce light exists in the first image (0: start from empty probes)",
                    min=0, max=256),
    "hysteresis": spec(0.97, "weight of the old texel value in the blend", min=0.0, max=1.0),
    "irradiance_texels": spec(8, "irradiance texels per side incl. the 1-texel border", min=3, max=64),
    "distance_texels": spec(16, "distance texels per side incl. the 1-texel border", min=3, max=64),
    "distance_power": spec(50.0, "cosine power of the distance blend", min=1.0),
    "irradiance_gamma": spec(5.0, "perceptual blending exponent (1: linear blend)", min=1.0),
    "change_threshold": spec(0.25, "per-texel change that lowers the hysteresis (perceptual space)", min=0.0),
    "brightness_threshold": spec(1e30, "luminance of a brightening step that is damped by 0.25 "
                                  "(RTXGI's firefly guard, 0.1 there; default 1e30 = off: the DDGI paper "
                                  "has no such damping and it slows the reaction to new light ~4x)",
                                  min=0.0),
    "encoding": spec("fp32", "texel storage encoding", choices=("fp32", "qddgi", "adgi")),
    "estimator": spec("auto", "per-texel estimate of the frame's rays: 'matrix' (BLAS, CPU), 'scatter' "
                       "(Dr.Jit scatter-reduce, deterministic), 'auto' (matrix on the CPU backend)",
                       choices=("auto", "matrix", "scatter")),
    "hit_lookup": spec("stochastic", "how probe-ray hits read the previous probes (multi-bounce): "
                        "'stochastic' one texel of one probe with the filtered value as expectation "
                        "(Pharr et al. 2024), 'filtered' DDGI's 8 probes x bilinear texels",
                        choices=HIT_LOOKUPS),
    "update_offscreen": spec(True, "update probes outside the (extended) camera frustum"),
    "relocate": spec(True, "move probes out of geometry (ours: never through a surface, and a probe inside "
                     "geometry leaves through a face on the grid's side; dyngi.probes.states; the rule is ours, "
                     "relocation itself Majercik et al. 2021)", ours=True),
    "classify": spec(True, "deactivate probes inside geometry or far from any surface"),
    "reclassify_interval": spec(8, "frames between re-tests of inactive probes (0: never)", min=0),
}


# -- the DDGI+ volume (DDGI Resampling, Majercik et al. 2022; dyngi.probes.ddgi_plus) --
ATTENUATIONS = ("ratio", "inverse-square", "none")
DEFAULT_ATTENUATION = "ratio"
DEFAULT_EMISSION_SCALE = 1.0
DEFAULT_UPDATE_VIEW_PATH_BIAS = 0.0
"""Sec. 3.5's offset at probe-ray hits, in smallest probe spacings; 0 (none) by default, our choice by
measurement: 0.2 (the secondary-vertex shading's factor) over-lights the two-storey stair hall by 13 %
against Mitsuba (0 by 3 %) and does not lower the per-frame error (docs/techniques/ddgi-resampling.md)."""

PLUS_SPECS = {
    "emission_attenuation": spec(DEFAULT_ATTENUATION, "DDGI+ emission heuristic (Sec. 3.3): 'ratio' "
                                 "(t/(t+d))^2 (decided by test), 'inverse-square' 1/(t+d)^2, 'none'",
                                 choices=ATTENUATIONS),
    "emission_scale": spec(DEFAULT_EMISSION_SCALE, "user scale of the attenuated emission (the paper's "
                           "slider)", min=0.0, max=1e6),
    "probe_glossy": spec(True, "glossy term of Eq. 6 at probe-ray hits"),
    "update_view_path_bias": spec(DEFAULT_UPDATE_VIEW_PATH_BIAS, "Sec. 3.5 at probe-ray hits: the previous "
                                  "probes are read this many smallest probe spacings back along the probe "
                                  "ray (at most half of it) instead of at the hit with DDGI's normal/view "
                                  "offsets; 0 (default, measured): at the hit with the query's offsets",
                                  min=0.0, max=10.0),
}

PRIMARY_SHADING_KEYS = ("jitter", "direct_samples", "encoding", "glossy")
"""``ddgi``'s parameters of primary shading and storage, which the DDGI+ volume has not (fp32 texels)."""

DDGI_PLUS_SPECS = {**{k: v for k, v in {**COMMON_SPECS, **DDGI_SPECS}.items() if k not in PRIMARY_SHADING_KEYS},
                   **PLUS_SPECS}
"""The DDGI+ volume's parameters: ``ddgi``'s probe parameters less :data:`PRIMARY_SHADING_KEYS`, plus
:data:`PLUS_SPECS`."""


def parse_params(specs: dict, params: dict | None, what: str) -> dict:
    """Validated values of ``params`` against ``specs`` (this module's tables), missing keys at their defaults;
    an unknown key raises a :class:`~dyngi.errors.DyngiError` naming ``what`` and the valid keys."""
    params = dict(params or {})
    unknown = [k for k in params if k not in specs]
    if unknown:
        raise DyngiError(f"unknown {what} parameter '{unknown[0]}'; valid: {', '.join(sorted(specs))}")
    return {k: (Param(**v).parse(k, params[k]) if k in params else v["default"]) for k, v in specs.items()}
