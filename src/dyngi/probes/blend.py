"""Blending probe-ray results into the texels (replaceable piece #3: accumulation).

A blend is an **estimator** (:mod:`.estimator`: this frame's rays -> per-texel
means and counts) followed by a **temporal accumulator** (:mod:`.accumulator`:
merge with the stored texels through the encoding). :class:`ProbeBlend`
composes any pair; :class:`HysteresisBlend` (DDGI), :class:`CappedMeanBlend`
(a count-capped running mean, our choice) and :class:`TrueAverage` (the reference) are the named ones.

DDGI (Majercik et al., JCGT 2019, Sec. 3.2) updates texel ``t`` of a probe
from that probe's ``N`` rays ``(w_r, L_r, d_r)`` of this frame:

* irradiance: ``E_t/pi = sum_r max(0, n_t . w_r) L_r / sum_r max(0, n_t . w_r)``;
* distance moments: ``sum_r max(0, n_t . w_r)^p (d_r, d_r^2) / sum_r max(0, n_t . w_r)^p``
  with the sharp power ``p`` (50), distances clamped to ``max_distance``;
* hysteresis: ``new = lerp(blend, old, h)``, ``h = 0.97`` by default;
* back-face hits (negative distance) are left out of the irradiance sums
  (issue 11 item 2; RTXGI skips them too) and kept in the moments as ``0.2 t``.

Faster reaction (Majercik et al., JCGT 2021, Sec. 6, and the RTXGI reference
conventions): irradiance is blended in a perceptual space ``E^(1/gamma)``
(gamma 5); when any channel of a texel moves by more than
``change_threshold`` (0.25) in that space the hysteresis of that texel drops
by 0.75, and a brightening step whose luminance exceeds
``brightness_threshold`` is scaled by 0.25 to suppress fireflies (RTXGI uses 0.1;
the ``ddgi`` technique turns it off by default, see its parameter).
Probes without history (first update) take the new value directly.

When every probe traced the same direction set (DDGI's shared rotated
spherical-Fibonacci set), the weights form one matrix ``W[N x T^2]`` shared
by all probes and the estimate is a dense matrix product
``radiance[P x N] @ W`` (NumPy/BLAS) -- see DESIGN.md for the measurements;
``estimator='auto'`` takes it on the CPU backend, and the all-Dr.Jit scatter
estimator otherwise (other plans, ``cuda_ad_rgb``: no host round trip).
Border texels take the value of the interior texel they copy.
"""
from __future__ import annotations

import numpy as np

from .accumulator import (BRIGHTNESS_DAMPING, CHANGE_HYSTERESIS_DROP, HysteresisAccumulator, MeanAccumulator,
                          CappedMeanAccumulator, interior_source_index, merge_into_volume)
from .encoding import get_encoding
from .estimator import (ESTIMATORS, MIN_BLEND_WEIGHT, MatrixEstimator, ScatterEstimator, blend_matrix,
                        choose_estimator)
from .trace import ProbeRayResults
from .volume import ProbeVolume
from ..errors import unknown_choice

__all__ = ["ProbeBlend", "HysteresisBlend", "CappedMeanBlend", "TrueAverage", "blend_matrix", "MatrixEstimator",
           "interior_source_index", "ESTIMATORS", "CHANGE_HYSTERESIS_DROP", "BRIGHTNESS_DAMPING",
           "MIN_BLEND_WEIGHT"]


class ProbeBlend:
    """An estimator and a temporal accumulator, storing through an encoding.

    Parameters
    ----------
    accumulator          :class:`~dyngi.probes.accumulator.HysteresisAccumulator` or any with its interface
    encoding : str = 'fp32'
    estimator : str = 'auto'    'matrix' (BLAS, shared sets only), 'scatter' (Dr.Jit, any plan), 'auto':
                                matrix for a shared set on the CPU backend, scatter otherwise
    distance_power : float = 50
    scatter_mode : str = 'auto' how the scatter estimator assigns rays to texels ('kernel', 'bin')
    """

    def __init__(self, accumulator, encoding: str = "fp32", estimator: str = "auto", distance_power: float = 50.0,
                 scatter_mode: str = "auto"):
        if estimator not in ESTIMATORS:
            raise unknown_choice("estimator", estimator, ESTIMATORS)
        self.accumulator = accumulator
        self.encoding = get_encoding(encoding)
        self.estimator = estimator
        self.distance_power = float(distance_power)
        self.scatter_mode = scatter_mode
        self._estimators = {}
        self.last_estimator = None      # name of the path the last update took ('matrix' / 'scatter')

    def estimator_for(self, plan):
        e = choose_estimator(self.estimator, plan, self.distance_power, self.scatter_mode)
        # one instance per kind: the matrix path caches its weights
        e = self._estimators.setdefault(e.name, e)
        self.last_estimator = e.name
        return e

    def new_estimates(self, volume: ProbeVolume, results: ProbeRayResults):
        """(irradiance, distance) :class:`~dyngi.probes.estimator.TexelEstimate` of this frame's rays."""
        e = self.estimator_for(results.plan)
        return e.irradiance(volume, results), e.distance(volume, results)

    def update(self, volume: ProbeVolume, results: ProbeRayResults) -> None:
        """Blend this frame's rays into the probes they came from (device atlases and counts, in place)."""
        if results.plan.n_rays == 0:        # no probe traced a ray: nothing changes
            return
        est_i, est_d = self.new_estimates(volume, results)
        plan = results.plan
        merge_into_volume(volume, est_i, est_d, self.accumulator, self.encoding, plan.probe_ids, plan.counts)


class HysteresisBlend(ProbeBlend):
    """DDGI's per-texel exponential blend; see the module docstring.

    Parameters
    ----------
    hysteresis : float = 0.97
    distance_power : float = 50
    irradiance_gamma : float = 5    perceptual blending space (1: linear)
    change_threshold : float = 0.25 per-channel change (in that space) that lowers the hysteresis
    brightness_threshold : float = 0.1  luminance of a brightening step that gets damped (inf: off)
    encoding : str = 'fp32'         storage encoding applied after each blend (see :mod:`.encoding`)
    estimator : str = 'auto'        see :class:`ProbeBlend`
    """

    def __init__(self, hysteresis: float = 0.97, distance_power: float = 50.0, irradiance_gamma: float = 5.0,
                 change_threshold: float = 0.25, brightness_threshold: float = 0.1, encoding: str = "fp32",
                 estimator: str = "auto"):
        super().__init__(HysteresisAccumulator(hysteresis, irradiance_gamma, change_threshold,
                                               brightness_threshold), encoding, estimator, distance_power)

    # the accumulator's settings, readable and settable here (the warm-up switches hysteresis off)
    def _acc_property(name):
        return property(lambda self: getattr(self.accumulator, name),
                        lambda self, v: setattr(self.accumulator, name, float(v)))

    hysteresis = _acc_property("hysteresis")
    irradiance_gamma = _acc_property("irradiance_gamma")
    change_threshold = _acc_property("change_threshold")
    brightness_threshold = _acc_property("brightness_threshold")
    del _acc_property


class CappedMeanBlend(ProbeBlend):
    """Count-capped running mean of the samples each texel receives (:class:`CappedMeanAccumulator`; not
    ADGI's Algorithm 3, which :mod:`dyngi.techniques.adgi.moving_average` implements).

    Parameters: ``encoding`` (its count bits cap the count; 'adgi': 63), ``max_count`` (a lower cap),
    ``estimator``, ``distance_power``, ``scatter_mode`` ('bin': each sample updates the texel it
    falls in, as ADGI bins; 'kernel': DDGI's cosine weights).
    """

    def __init__(self, encoding: str = "adgi", max_count: int | None = None, estimator: str = "auto",
                 distance_power: float = 50.0, scatter_mode: str = "auto"):
        super().__init__(CappedMeanAccumulator(max_count), encoding, estimator, distance_power, scatter_mode)


class TrueAverage:
    """Per-texel plain mean of lobe-sampled rays (the fp32 reference of ADGI Sec. 5): no history.

    Expects a :class:`~dyngi.probes.rays.LobeDirections` plan for irradiance
    (cosine lobe) and one for distance (cosine-power lobe); each ray enters the
    texel it was drawn for (scatter estimator, 'bin'), interior texels are the
    means, borders copy them.
    """

    def __init__(self, encoding: str = "fp32"):
        self.encoding = get_encoding(encoding)
        self.accumulator = MeanAccumulator()
        self.estimator = ScatterEstimator(mode="bin")

    def update(self, volume: ProbeVolume, irr_results: ProbeRayResults, dist_results: ProbeRayResults,
               k_irr: int | None = None, k_dist: int | None = None) -> None:
        """``k_irr`` / ``k_dist`` (rays per texel) are implied by the plans and kept for compatibility."""
        pid = irr_results.plan.probe_ids
        if len(pid) == 0 or irr_results.plan.n_rays == 0 or dist_results.plan.n_rays == 0:
            return
        if not np.array_equal(pid, dist_results.plan.probe_ids):
            raise ValueError("TrueAverage: the irradiance and distance plans must trace the same probes")
        est_i = self.estimator.irradiance(volume, irr_results)
        est_d = self.estimator.distance(volume, dist_results)
        merge_into_volume(volume, est_i, est_d, self.accumulator, self.encoding, pid)
