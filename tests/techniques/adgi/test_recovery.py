"""ADGI's purpose (Datta et al. 2022, Secs. 1, 4.9, Fig. 8): a faster response to a dynamic change than
Q-DDGI. The recovery test on ``tunnel-gate`` (the Bistro tunnel whose gate opens), at equal rays
(ADGI gets Q-DDGI's rays on every frame, as ``dyngi compare --budget equal-rays``), against the
path-traced ground truth."""
import numpy as np
import pytest


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "measured (docs/techniques/adgi.md, the recovery at equal rays): ADGI's relMSE is below Q-DDGI's on "
    "every frame after the gate opens and ends at ~0.4x of it, but it keeps falling longer: by the 10% band "
    "around each technique's own final value ADGI settles in a median 79 frames against Q-DDGI's 76"))
def test_equal_rays_recovery_on_the_opening_tunnel(backend):
    """Frames from gate-open (t = 0.5 s) until the ground-truth relMSE enters and stays within 10% of its
    final value (:func:`~dyngi.experiments.reproductions.adgi.settle_frames`), median of 3 seeds at 64x48
    (:func:`~dyngi.experiments.reproductions.adgi.equal_rays_recovery`: every other frame of the scene's
    30 fps, 30 frames held open, 128-spp ground truth): ADGI fewer than the paper's Q-DDGI (``qddgi`` at its
    defaults), and at a final relMSE no worse than 1.1x Q-DDGI's -- "within 10% of its own final value"
    alone would reward a technique that settles at a worse level."""
    from dyngi.experiments.reproductions.adgi import equal_rays_recovery

    out = equal_rays_recovery(("adgi",))
    runs = out["runs"]
    for seed in runs["adgi"]:
        a, q = runs["adgi"][seed], runs["qddgi"][seed]
        assert np.all(np.isfinite(a["relmse"])) and np.all(np.isfinite(q["relmse"]))
        assert abs(a["steady_rays"] / q["steady_rays"] - 1) < 0.05, "not at equal rays"
    med = {k: float(np.median([r["settle"] for r in v.values()])) for k, v in runs.items()}
    fin = {k: float(np.median([r["final"] for r in v.values()])) for k, v in runs.items()}
    assert med["adgi"] < med["qddgi"] and fin["adgi"] <= 1.1 * fin["qddgi"], (med, fin)
