"""The furnace at ``smcir``'s shipped defaults (2048 VPLs, 100 warm-up iterations, interleaved shading,
Eq. 8 read as ``eq8='root-of-ratio'``: k = 8).

The battery's furnace (tests/techniques/test_battery.py) runs smcir at ``density_k=32`` to check the rest of
the machinery; this one runs the defaults unchanged, so the rendering density's k-NN bias (Sec. 3.3: "biased
but consistent") is bounded where users meet it. A closed diffuse sphere (albedo 0.6, emission 0.3:
radiance 0.75 everywhere, its indirect part at max depth 5 known in closed form), the mean of 3 frames.

Measured (2026-12-06, 24x16, seeds 5 and 6): indirect / expected 1.098, 1.095 (the printed reading, k = 1:
1.306, 1.266); full image / expected 1.029, 1.029 (k = 1: 1.093, 1.082).
"""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.techniques import Frame, create_technique
from tests.techniques.test_battery import FURNACES, furnace_expected, furnace_indirect_expected, furnace_scene

INDIRECT_TOL = 0.15
"""|indirect / expected - 1| at the defaults (measured +9.5-9.8 %: the k = 8 density on the blue-noise-like
set; the printed reading's k = 1 gives +27-31 % and fails it)."""
IMAGE_TOL = 0.05
"""|image / expected - 1| (measured +2.9 %: the indirect part is a third of the sphere's radiance)."""


@pytest.mark.slow
@pytest.mark.parametrize("seed", [5, 6])
def test_smcir_furnace_at_the_defaults(backend, seed):
    sc = furnace_scene("sphere")
    a, e = FURNACES["sphere"]
    tech = create_technique("smcir", sc, {})
    assert tech.params["eq8"] == "root-of-ratio" and tech.params["density_k"] == 0
    ind, img = [], []
    for i in range(3):
        sc.at(0.0)
        r = tech.step(Frame(i, 0.0, sc.camera(0.0), (24, 16), seed=seed, static=i > 0))
        assert np.all(np.isfinite(r.image)) and np.all(np.isfinite(r.indirect))
        ind.append(float(r.indirect.mean()))
        img.append(float(r.image.mean()))
    depth = tech.params.get("max_depth")
    got_ind = np.mean(ind) / furnace_indirect_expected(a, e, depth)
    got_img = np.mean(img) / furnace_expected(a, e, depth)
    assert abs(got_ind - 1.0) < INDIRECT_TOL, got_ind
    assert abs(got_img - 1.0) < IMAGE_TOL, got_img
