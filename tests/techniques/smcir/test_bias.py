"""The brightness bias of ``smcir`` at its shipped defaults (Hedman et al. 2017, Eq. 7-8).

Eq. 8 gives k = 1 for the rendering density (line 19) at the paper's budgets (2048, 512 VPLs). On the
blue-noise-like VPL set that the replacements produce, nearest-neighbour areas ``pi r_1^2`` exceed each
VPL's share of the surface, so 1/p and the indirect light come out too bright: the paper's estimator's
own bias (Sec. 3.3: "biased but consistent"), kept as the default and documented in
:mod:`dyngi.techniques.smcir`. Every other energy test of smcir sets ``density_k`` (the furnace: 32;
test_technique.py: 16); this one runs the defaults unchanged, so it fails if the default's bias grows.

Measured (2026-12-02, 32x24, cornell-static, defaults: 2048 VPLs, 100 warm-up iterations, interleaved
shading, candidate k = 1; mean indirect / the path-traced indirect reference at 1024 spp): 1.39, 1.42,
1.39 for seeds 0-2 (``density_k=16``: 1.09, 1.09, 1.06).
"""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique

RES = (32, 24)
BIAS_MAX = 1.55
"""Upper bound of the default's mean indirect / reference on every seed (measured 1.39-1.42)."""
BIAS_MIN = 1.2
"""Lower bound: the bias the docstrings state is there (if it vanished, they are stale: update them)."""


def _indirect(spec, params, sc, seed):
    tech = create_technique(spec, sc, params)
    sc.at(0.0)
    return tech.step(Frame(0, 0.0, sc.camera(0.0), RES, seed=seed)).indirect


@pytest.mark.slow
def test_default_smcir_brightness_bias_is_bounded(backend):
    sc = load_scene("cornell-static")
    ref = _indirect("path", {"spp": 1024, "max_depth": 5, "rr_depth": 50}, sc, 99)
    ratios = [float(_indirect("smcir", {}, sc, seed).mean() / ref.mean()) for seed in (0, 1, 2)]
    assert all(BIAS_MIN < r < BIAS_MAX for r in ratios), ratios
