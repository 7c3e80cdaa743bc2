"""ADGI's purpose (Datta et al. 2022, Secs. 1, 4.9, Fig. 8): a faster response to a dynamic change than
Q-DDGI. On ``tunnel-gate`` (the Bistro tunnel whose gate opens), at equal rays (ADGI gets Q-DDGI's rays on
every frame, as ``dyngi compare --budget equal-rays``), against the path-traced ground truth.

Whether ADGI *settles* faster (frames until its relMSE stays within 10 % of its own final value) is a claim,
decided by the claim machinery (``adgi.fig8.settle`` and ``adgi.fig8.level`` of
:func:`dyngi.experiments.reproductions.adgi.claims_fig8`, each technique at its defaults, verdict computed);
the former strict xfail on it is gone. What stays here is the technique's behaviour at equal rays that
the issue's measurements rest on, which can fail without any defect being required: its error after the
gate opens is below Q-DDGI's, and it ends no worse than 1.1x Q-DDGI's final level."""
import numpy as np
import pytest


@pytest.mark.slow
def test_equal_rays_level_on_the_opening_tunnel(backend):
    """Median over 3 seeds at 64x48 (:func:`~dyngi.experiments.reproductions.adgi.equal_rays_recovery`: every
    other frame of the scene's 30 fps, 30 frames held open, 128-spp ground truth): at equal rays (steady rays
    within 5 % of Q-DDGI's), ADGI's mean relMSE from gate-open on is below Q-DDGI's (``qddgi`` at its defaults)
    and its final relMSE (median of the last 5 frames) at most 1.1x Q-DDGI's. The settling frames of both are
    printed (the claim decides them)."""
    from dyngi.experiments.reproductions.adgi import equal_rays_recovery

    out = equal_rays_recovery(("adgi",))
    runs, o = out["runs"], out["opened"]
    for seed in runs["adgi"]:
        a, q = runs["adgi"][seed], runs["qddgi"][seed]
        assert np.all(np.isfinite(a["relmse"])) and np.all(np.isfinite(q["relmse"]))
        assert abs(a["steady_rays"] / q["steady_rays"] - 1) < 0.05, "not at equal rays"
    after = {k: float(np.median([r["relmse"][o:].mean() for r in v.values()])) for k, v in runs.items()}
    fin = {k: float(np.median([r["final"] for r in v.values()])) for k, v in runs.items()}
    settle = {k: [r["settle"] for r in v.values()] for k, v in runs.items()}
    print("after gate-open", after, "final", fin, "settle frames", settle)
    assert after["adgi"] < after["qddgi"] and fin["adgi"] <= 1.1 * fin["qddgi"], (after, fin, settle)
