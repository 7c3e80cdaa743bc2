"""The pure pieces of ``dyngi reproduce ddgi-resampling``'s Table 1 protocol (NumPy only, no rendering):
the MAPE(N) = a/sqrt(N) + b fit and its extrapolation, the target selection, the reference's noise
estimate from its halves, the emission-scale secant step, frames to target (measured or fitted), bias and
variance apart over seeds, the saved scenes that ``--only`` splits a full run into."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.errors import DyngiError
from dyngi.experiments.reproductions.ddgi_resampling import (FULL, QUICK, TARGET_TOL, accumulated_mapes, bias_variance,
                                                             calibrated_scale, decide_claims, load_scene_figure,
                                                             run_only, save_scene,
                                                             fit_inverse_sqrt, frames_from_fit, frames_needed,
                                                             reference_noise_mape, scaled_frame_ms, select_target)
from dyngi.metrics.image import mape


def test_fit_recovers_a_and_b_and_extrapolates():
    rng = np.random.default_rng(1)
    n = np.arange(4, 257)
    a, b = 1.3, 0.04
    m = a / np.sqrt(n) + b + rng.normal(0.0, 0.002, n.size)
    fa, fb = fit_inverse_sqrt(n, m)
    assert abs(fa - a) < 0.03 and abs(fb - b) < 0.003, (fa, fb)
    # (a / (target - b))^2 inverts the curve; a target at or below the floor is never reached
    N = frames_from_fit(a, b, a / np.sqrt(4000.0) + b)
    assert N == pytest.approx(4000.0, rel=1e-9)
    assert frames_from_fit(a, b, b) is None and frames_from_fit(a, b, 0.5 * b) is None
    assert frames_from_fit(-1.0, b, 1.0) is None and frames_from_fit(float("nan"), b, 1.0) is None
    # the floor known (an unbiased method's: the reference's noise): only a is fitted
    fa, fb = fit_inverse_sqrt(n, m, b=b)
    assert fb == b and abs(fa - a) < 0.01, fa


def test_frames_needed_measured_first_then_fitted():
    acc = [0.5, 0.3, 0.2, 0.15, 0.12]
    assert frames_needed(acc, 0.2) == {"frames": 3.0, "measured": True, "fit": None}
    assert frames_needed(acc, 0.2 * (1 + TARGET_TOL) ** 2)["frames"] == 3.0   # within the tolerance
    n = np.arange(1, 65)
    curve = list(0.8 / np.sqrt(n) + 0.05)
    out = frames_needed(curve, 0.06, fit_from=4)
    assert not out["measured"] and out["fit"]["a"] == pytest.approx(0.8, rel=1e-6)
    assert out["frames"] == pytest.approx((0.8 / (0.06 * (1 + TARGET_TOL) - 0.05)) ** 2, rel=1e-6)
    assert frames_needed(curve, 0.04, fit_from=4)["frames"] is None        # below the floor b: never
    fixed = frames_needed(curve, 0.06, fit_from=4, floor=0.05)
    assert fixed["fit"]["b_fixed"] and fixed["frames"] == pytest.approx(out["frames"], rel=1e-6)
    assert fixed["fit"]["free"]["b"] == pytest.approx(0.05, abs=1e-9)


def test_target_is_the_best_mean_one_frame_mape():
    assert select_target({"restir-pt": [0.9, 1.1], "ddgi-secondary": [0.3, 0.34], "ddgi-resampling": [0.33, 0.29]}) \
        == ("ddgi-resampling", pytest.approx(0.31))
    assert select_target({"restir-pt": 0.2, "ddgi-secondary": [float("nan")], "ddgi-resampling": 0.4})[0] == "restir-pt"
    with pytest.raises(ValueError):
        select_target({"restir-pt": [float("nan")]})


def test_reference_noise_estimate_matches_the_true_error():
    rng = np.random.default_rng(2)
    truth = rng.uniform(0.05, 2.0, (90, 160, 3))
    sigma = 0.5 * truth          # per-sample std
    n1, n2 = 512, 512
    a = truth + rng.normal(0.0, 1.0, truth.shape) * sigma / np.sqrt(n1)
    b = truth + rng.normal(0.0, 1.0, truth.shape) * sigma / np.sqrt(n2)
    r = (n1 * a + n2 * b) / (n1 + n2)
    est = reference_noise_mape(a, b, n1, n2)
    true = mape(r.astype(np.float32), truth.astype(np.float32))
    assert est == pytest.approx(true, rel=0.05), (est, true)


def test_calibrated_scale_secant():
    # image mean linear in the scale: m(s) = 0.1 + 0.05 s; the reference mean 0.2 needs s = 2
    m = lambda s: 0.1 + 0.05 * s  # noqa: E731
    assert calibrated_scale(1.0, m(1.0), 2.0, m(2.0), 0.2, 16.0) == pytest.approx(2.0)
    assert calibrated_scale(1.0, m(1.0), 2.0, m(2.0), 10.0, 16.0) == 16.0       # clamped
    assert calibrated_scale(1.0, m(1.0), 0.5, m(0.5), 0.0, 16.0) == 0.0
    assert calibrated_scale(1.0, 0.3, 2.0, 0.3, 0.2, 16.0) == 1.0                # emission has no effect


def test_update_time_scaled_to_the_papers_rays_per_pixel():
    # 10x the paper's rays per pixel: 90 % of the update's 60 ms goes
    assert scaled_frame_ms(100.0, 60.0, 2.5, paper_ratio=0.25) == pytest.approx(46.0)
    assert scaled_frame_ms(100.0, 60.0, 0.2, paper_ratio=0.25) == 100.0          # already below the paper's


def test_accumulated_mapes_is_the_running_mean():
    rng = np.random.default_rng(3)
    ref = rng.uniform(0.1, 1.0, (9, 16, 3)).astype(np.float32)
    imgs = [ref + rng.normal(0, 0.2, ref.shape).astype(np.float32) for _ in range(4)]
    acc = accumulated_mapes(imgs, ref)
    assert acc[0] == pytest.approx(mape(imgs[0], ref))
    assert acc[3] == pytest.approx(mape(np.mean(imgs, axis=0).astype(np.float32), ref), rel=1e-5)
    assert acc[3] < acc[0]


def test_bias_and_variance_apart_over_seeds():
    """Seeds of an unbiased estimate: the seed mean's MAPE is its noise alone (within 10 %), the spread is the
    per-sample relative std; 20 % too bright: the seed mean's MAPE and image-mean error show the 20 %, well above
    the noise alone."""
    rng = np.random.default_rng(4)
    ref = rng.uniform(0.2, 1.0, (36, 64, 3))
    rel = 0.3                                          # per-seed std = rel x (ref + 0.01)
    noise = [rng.normal(0.0, 1.0, ref.shape) * rel * (ref + 0.01) for _ in range(16)]
    fair = bias_variance([ref + e for e in noise], ref)
    assert fair["seeds"] == 16 and fair["spread"] == pytest.approx(rel, rel=0.05)
    assert fair["seed_mean_mape"] == pytest.approx(fair["noise_in_mean"], rel=0.1)
    assert abs(fair["mean_error"]) < 0.01
    high = bias_variance([1.2 * ref + e for e in noise], ref)
    assert high["mean_error"] == pytest.approx(0.2, abs=0.01) and high["spread"] == pytest.approx(rel, rel=0.05)
    assert high["seed_mean_mape"] == pytest.approx(0.2, abs=0.02) and high["seed_mean_mape"] > 2 * high["noise_in_mean"]


def test_saved_scenes_are_read_back_with_their_configuration_only(tmp_path):
    """``--only SCENE`` saves a scene's figures; the full run reads them back only under the same configuration
    (the scene list aside), so a quick scene never enters a full table."""
    fig = {"scene": "room-door", "target_mape": 0.2, "speedup": {"restir-pt": {"median": float("inf")}}}
    save_scene(str(tmp_path), FULL, fig)
    got, note = load_scene_figure(str(tmp_path), dict(FULL, scenes=("room-door",)), "room-door")
    assert got == fig and note is None
    got, note = load_scene_figure(str(tmp_path), QUICK, "room-door")
    assert got is None and "another configuration" in note
    assert load_scene_figure(str(tmp_path), FULL, "villa-sun") == (None, None)
    with pytest.raises(DyngiError, match="unknown scene.*valid: .*room-door"):
        run_only(str(tmp_path), ["room-dor"])


def _fig(times: dict, rows: dict, res=(320, 180)) -> dict:
    seeds = lambda ts: [{"seed": k, "time_ms": t} for k, t in enumerate(ts)]  # noqa: E731
    return {"scene": "villa-sun", "res": list(res), "probe_rays_per_pixel": 0.89,
            "techniques": {n: {"seeds": seeds(ts)} for n, ts in times.items()},
            "rows": {spec: seeds(ts) for spec, ts in rows.items()}}


def test_verdicts_need_320x180_and_read_the_rows_run():
    """vs-secondary is decided from the default and paper-literal rows at 320x180 with 256 measured frames; at
    64x36 it is undecided (pixels); vs-restir-pt stays undecided at 0.89 probe rays per pixel (the paper's 0.25)."""
    times = {"restir-pt": [24000.0, 24100.0, 24200.0], "ddgi-secondary": [1130.0, 1270.0, 1420.0],
             "ddgi-resampling": [100.0, 110.0, 105.0]}
    lit = {"ddgi-resampling:visibility_reuse=none": [120.0, 115.0, 118.0]}
    got = {r.claim.key.rsplit(".", 1)[1]: r for r in decide_claims(_fig(times, lit), FULL, False)}
    assert got["vs-secondary"].verdict.word == "reproduced", got["vs-secondary"].verdict
    assert "paper-literal" in got["vs-secondary"].verdict.rows
    assert got["vs-restir-pt"].verdict.word == "undecided"
    assert any("pixels per probe ray" in c for c in got["vs-restir-pt"].verdict.conditions)
    slower = {"ddgi-resampling:visibility_reuse=none": [600.0, 650.0, 700.0]}
    assert decide_claims(_fig(times, slower), FULL, False)[1].verdict.word != "reproduced"
    small = decide_claims(_fig(times, lit, (64, 36)), dict(FULL, res=(64, 36)), False)[1].verdict
    assert small.word == "undecided" and any("pixels 2304 < 57600" in c for c in small.conditions)
    assert decide_claims(_fig(times, {}), FULL, False)[1].verdict.word == "undecided"     # the row not run
