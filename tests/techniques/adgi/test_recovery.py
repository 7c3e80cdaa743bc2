"""ADGI's purpose (Datta et al. 2022, Secs. 1, 4.9, Fig. 8): a faster response to a dynamic change than
Q-DDGI. The recovery test of issue 25 on ``tunnel-gate`` (the Bistro tunnel whose gate opens), at equal rays
(ADGI gets Q-DDGI's rays on every frame, as ``dyngi compare --budget equal-rays``), against the
path-traced ground truth."""
import numpy as np
import pytest

from dyngi.scene import load_scene
from dyngi.techniques import create_technique

RES = (64, 48)
DT = 1.0 / 15.0            # every other frame of the scene's 30 fps (the full reproduction's sampling)
HOLD = 30                  # frames held open after the gate stops (t = 4 s)
FINAL = 5                  # the final value: the median of the last FINAL frames
SEEDS = (0, 1, 2)
REF_SPP = 128


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "measured (docs/benchmarks.md, issue 25 recovery): ADGI's relMSE is below Q-DDGI's on every frame after "
    "the gate opens and ends at ~0.4x of it, but it keeps falling longer: by the 10% band around each "
    "technique's own final value ADGI settles in a median 79 frames against Q-DDGI's 76"))
def test_equal_rays_recovery_on_the_opening_tunnel(backend):
    """Frames from gate-open (t = 0.5 s) until the ground-truth relMSE enters and stays within 10% of its
    final value (:func:`~dyngi.experiments.reproductions.adgi.settle_frames`), median of 3 seeds at 64x48:
    ADGI fewer than the paper's Q-DDGI (``qddgi`` at its defaults), and at a final relMSE no worse than 1.1x
    Q-DDGI's -- "within 10% of its own final value" alone would reward a technique that settles at a
    worse level."""
    from dyngi.experiments.reference import reference_halves, scene_max_depth
    from dyngi.experiments.reproductions.adgi import GATE_END, GATE_OPEN, run_frames, settle_frames
    from dyngi.metrics import relmse

    sc = load_scene("tunnel-gate")
    times = [min(i * DT, GATE_END) for i in range(int(round(GATE_END / DT)) + 1 + HOLD)]
    opened = next(i for i, t in enumerate(times) if t >= GATE_OPEN)
    depth = scene_max_depth(sc)
    refs = [reference_halves(sc, t, RES, REF_SPP, depth)[0] for t in times]
    settle = {"qddgi": [], "adgi": []}
    final = {"qddgi": [], "adgi": []}
    for seed in SEEDS:
        q = run_frames(sc, create_technique("qddgi", sc), times, RES, seed=seed)
        a = run_frames(sc, create_technique("adgi", sc), times, RES, seed=seed,
                       budgets=[st["total_rays"] for st in q["stats"]])
        steady = [st["total_rays"] for st in a["stats"][1:]], [st["total_rays"] for st in q["stats"][1:]]
        assert abs(sum(steady[0]) / sum(steady[1]) - 1) < 0.05, "not at equal rays"
        for name, run in (("qddgi", q), ("adgi", a)):
            e = np.array([relmse(np.maximum(img, 0.0), ref) for img, ref in zip(run["images"], refs)])
            assert np.all(np.isfinite(e)), name
            f = float(np.median(e[-FINAL:]))
            final[name].append(f)
            settle[name].append(settle_frames(e[opened:], f))
    med = {k: float(np.median(v)) for k, v in settle.items()}
    fin = {k: float(np.median(v)) for k, v in final.items()}
    assert med["adgi"] < med["qddgi"] and fin["adgi"] <= 1.1 * fin["qddgi"], (settle, final)
