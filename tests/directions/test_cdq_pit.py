"""The CDQ must earn its keep where the paper's claim is (VLC paper Fig. 8 b: "the CDQ improves sampling by two
to three orders of magnitude" for the regions the sun, out of NEE, lights indirectly): the claim's own
condition at a stated reduced scale. ``sky-pit-sun-disc`` (the paper's ~0.5-degree sun), nee-pt's defaults
(the paper's octree thresholds 4096 / 2048 hold from 8 x 4096 records per frame: 192x108 records 41472; the CDQ's
evidence rule), MSE at 1 spp on the pixels the sun lights indirectly (the reproduction's mask: indirect reference
luminance > half the full reference's), mean over the frames after the CDQ's adaptation:
``nee-pt:directions=cdq`` has at most 1/:data:`PIT_FACTOR` of ``directions=bsdf``'s (3 seeds, one-sided t-test
on the log ratios, the helpers of test_learned_gains). The claim's 100x is decided by ``dyngi reproduce cdq``
at 320x180 over 120 frames; this reduced scale asserts the direction of the gain and a factor that a CDQ which
found nothing (a BSDF twin) fails.
"""
from __future__ import annotations

import numpy as np
import pytest

PIT_FACTOR = 2.0
"""directions=cdq must have at most 1/2 of directions=bsdf's MSE on the sunlit indirect region of the 0.5-degree
pit at 192x108, frames 15-44 (reduced scale; the claim: 100x at 320x180)."""
RES, WARMUP, FRAMES = (192, 108), 15, 30


@pytest.mark.slow
def test_cdq_beats_bsdf_on_the_sunlit_region_of_the_pit_with_the_papers_sun(backend):
    from dyngi.color import LUMINANCE
    from dyngi.experiments.references.path import reference_image
    from dyngi.scene.library import make_builtin
    from tests.lights.test_learned_gains import _mse_ratios, _one_sided_below

    sc = make_builtin("sky-pit-sun-disc")
    ref = reference_image(sc, 0.0, RES, 256, 3).astype(np.float64)
    ind = reference_image(sc, 0.0, RES, 256, 3, indirect=True).astype(np.float64)
    mask = ind @ LUMINANCE > 0.5 * (ref @ LUMINANCE)
    assert mask.mean() > 0.02, mask.mean()          # the overhang's shadow: the region the claim is about
    ratios = _mse_ratios(sc, "nee-pt:directions=cdq", "nee-pt:directions=bsdf", RES, WARMUP, FRAMES, mask=mask)
    ok, p = _one_sided_below(ratios, PIT_FACTOR)
    assert ok, f"CDQ/BSDF MSE ratios (sunlit indirect region) {ratios} not below 1/{PIT_FACTOR} (one-sided p = {p:.3g})"
