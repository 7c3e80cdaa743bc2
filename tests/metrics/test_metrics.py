"""dyngi.metrics: hand-computed cases for every metric, input validation, temporal |E|/|E'|, time to error."""
import math

import numpy as np
import pytest

from dyngi.errors import DyngiError
from dyngi.metrics import (METRICS, TemporalTracker, auto_exposure, compute_all, flip, mape, mse, pick_pixels,
                           relmse, ssim, temporal_errors, time_to_error)


def _rand(h=24, w=32, seed=0, scale=1.0):
    return (np.random.default_rng(seed).random((h, w, 3)) * scale).astype(np.float32)


def _const(v, h=8, w=10):
    return np.full((h, w, 3), v, np.float32)


# -- MSE, relMSE, MAPE ----------------------------------------------------------

def test_mse_constant_offset():
    ref = _rand()
    assert mse(ref + 0.25, ref) == pytest.approx(0.0625, rel=1e-6)
    assert mse(ref - 0.25, ref) == pytest.approx(0.0625, rel=1e-6)
    assert mse(ref, ref) == 0.0


def test_mse_mixed_pixels():
    ref = np.zeros((2, 2, 3), np.float32)
    img = ref.copy()
    img[0, 0, 0] = 3.0                 # one value of 12 off by 3 -> 9 / 12
    assert mse(img, ref) == pytest.approx(0.75)


def test_relmse_hand_computed():
    ref, img = _const(2.0), _const(2.5)
    assert relmse(img, ref) == pytest.approx(0.25 / (4.0 + 1e-2), rel=1e-6)
    assert relmse(img, ref, eps=1.0) == pytest.approx(0.25 / 5.0, rel=1e-6)
    # black reference: the eps floor decides
    assert relmse(_const(0.1), _const(0.0)) == pytest.approx(0.01 / 1e-2, rel=1e-5)
    # scale aware: the same relative error at 10x the level gives (almost) the same relMSE
    assert relmse(_const(25.0), _const(20.0)) == pytest.approx(relmse(_const(2.5), _const(2.0)), rel=3e-3)


def test_relmse_bad_eps():
    with pytest.raises(DyngiError, match="eps"):
        relmse(_const(1.0), _const(1.0), eps=0.0)


def test_mape_as_ddgi_resampling_defines_it():
    # |v - vref| / (vref + 0.01): 50 % too bright on vref = 0.49 -> 0.245 / 0.5
    assert mape(_const(0.735), _const(0.49)) == pytest.approx(0.49, rel=1e-5)
    # a black reference pixel with value 0.01 counts as 100 %
    assert mape(_const(0.01), _const(0.0)) == pytest.approx(1.0, rel=1e-5)
    # mixed image: half the values exact, half with error 0.5 on vref = 0.99 -> mean 0.25
    ref = _const(0.99, 4, 4)
    img = ref.copy()
    img[:2] += 0.5
    assert mape(img, ref) == pytest.approx(0.25, rel=1e-5)
    # symmetric in the sign of the error, not in the roles of img and ref
    assert mape(_const(0.49 - 0.245), _const(0.49)) == pytest.approx(0.49, rel=1e-5)
    assert mape(_const(0.49), _const(0.735)) != pytest.approx(0.49, rel=1e-2)


def test_mape_needs_nonnegative_reference():
    with pytest.raises(DyngiError, match="negative"):
        mape(_const(0.0), _const(-0.01))


# -- input validation ----------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(METRICS))
def test_bad_inputs_raise_dyngi_error(name):
    f = METRICS[name]
    ref = _rand(8, 8)
    bad = [
        (ref[..., 0], ref[..., 0], "H x W x 3"),                 # 2-D
        (np.zeros((8, 8, 4)), np.zeros((8, 8, 4)), "H x W x 3"),  # 4 channels
        (ref[:4], ref, "differs"),                              # shape mismatch
        (np.where(ref > 0.5, np.nan, ref), ref, "NaN"),
        (ref, np.where(ref > 0.5, np.inf, ref), "NaN"),
        ("hello", ref, "H x W x 3|numeric"),
    ]
    for img, r, msg in bad:
        with pytest.raises(DyngiError, match=msg):
            f(img, r)


# -- FLIP ------------------------------------------------------------------------------

def test_flip_identical_is_zero_and_different_is_positive():
    a = _rand(seed=1, scale=2.0)
    assert flip(a, a) == 0.0
    m, emap = flip(a * 1.1, a, return_map=True)
    assert 0.0 < m < 1.0
    assert emap.shape == a.shape[:2] and emap.dtype == np.float32
    assert float(emap.mean()) == pytest.approx(m, rel=1e-4)
    # a larger error gives a larger FLIP
    assert flip(a * 2.0, a) > m
    # a genuinely different image is far worse than a slightly scaled one
    assert flip(_rand(seed=2, scale=2.0), a) > flip(a * 1.05, a)


def test_flip_bad_input_raises_not_exits():
    a = _rand()
    with pytest.raises(DyngiError, match="negative"):
        flip(a - 0.5, a)
    with pytest.raises(DyngiError, match="negative"):
        flip(a, a - 0.5)
    with pytest.raises(DyngiError, match="differs"):
        flip(a[:10], a)
    with pytest.raises(DyngiError, match="ppd"):
        flip(a, a * 1.1, ppd=-1.0)


def test_flip_black_and_dark_references():
    """flip-evaluator exits the process on a black reference; our wrapper must not."""
    a = _rand(seed=3)
    z = np.zeros_like(a)
    assert flip(z, z) == 0.0
    assert flip(a, z) > 0.5                     # something where there should be nothing
    assert flip(z, a) > 0.5
    # a dark reference is rescaled; HDR-FLIP with automatic exposures is scale invariant
    b = a * 1.3
    assert flip(b * 1e-7, a * 1e-7) == pytest.approx(flip(b, a), rel=1e-3)
    assert flip(b * 1e-30, a * 1e-30) == pytest.approx(flip(b, a), rel=1e-3)


# -- SSIM ---------------------------------------------------------------------------------

def test_ssim_identical_is_one_and_symmetric():
    a, b = _rand(seed=4), _rand(seed=5)
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    s = ssim(a, b)
    assert s < 0.5
    assert ssim(b, a) == pytest.approx(s, rel=1e-12)
    assert ssim(a, a + 0.01 * _rand(seed=6)) > ssim(a, a + 0.3 * _rand(seed=6)) > s
    v, smap = ssim(a, b, return_map=True)
    assert smap.shape == a.shape[:2] and v == pytest.approx(s)


def test_ssim_constant_images_hand_computed():
    # constants: sigma = 0, so SSIM = (2 mx my + C1) / (mx^2 + my^2 + C1) of the tone-mapped values
    # reinhard(1) = 0.5, reinhard(3) = 0.75, C1 = (0.01 * 1)^2
    c1 = 1e-4
    want = (2 * 0.5 * 0.75 + c1) / (0.25 + 0.5625 + c1)
    assert ssim(_const(1.0, 16, 16), _const(3.0, 16, 16)) == pytest.approx(want, rel=1e-9)
    # exposure 2 maps 1 -> 2/3 and 3 -> 6/7
    x, y = 2 / 3, 6 / 7
    want2 = (2 * x * y + c1) / (x * x + y * y + c1)
    assert ssim(_const(1.0, 16, 16), _const(3.0, 16, 16), exposure=2.0) == pytest.approx(want2, rel=1e-9)


# -- registry ----------------------------------------------------------------------------------

def test_compute_all_and_unknown_metric():
    ref = _rand(seed=7)
    img = ref + 0.1
    out = compute_all(img, ref)
    assert set(out) == {"mse", "relmse", "mape", "flip", "ssim"}
    assert out["mse"] == pytest.approx(0.01, rel=1e-5)
    assert compute_all(img, ref, ["mape"]) == {"mape": pytest.approx(mape(img, ref))}
    assert set(compute_all(img, ref, "mse, ssim")) == {"mse", "ssim"}
    with pytest.raises(DyngiError, match=r"unknown metric 'psnr'; valid metrics: flip, mape, mse, relmse, ssim"):
        compute_all(img, ref, ["mse", "psnr"])


# -- temporal |E| and |E'| (SMC-IR Sec. 5.2) ------------------------------------------

def _reinhard(x, k=1.0):
    return k * x / (1 + k * x)


def test_temporal_alternating_flicker_known_answer():
    """Reference constant r, estimate alternating r + d, r - d: |E| and |E'| in closed form."""
    r, d, T = 1.0, 0.5, 10
    refs = np.stack([_const(r)] * T)                      # grey: luminance = r
    frames = np.stack([_const(r + d if i % 2 == 0 else r - d) for i in range(T)])
    e_plus = _reinhard(r + d) - _reinhard(r)             # 0.1
    e_minus = _reinhard(r - d) - _reinhard(r)            # -1/6
    out = temporal_errors(frames, refs)
    assert out["E"] == pytest.approx((abs(e_plus) + abs(e_minus)) / 2, rel=1e-6)   # 0.1333
    assert out["E_prime"] == pytest.approx(abs(e_plus - e_minus), rel=1e-6)        # 0.2667
    assert out["error"].shape == (T, 80)
    # per second instead of per frame
    out30 = temporal_errors(frames, refs, dt=1 / 30)
    assert out30["E_prime"] == pytest.approx(30 * abs(e_plus - e_minus), rel=1e-6)
    # exposure enters the tone map
    k = 4.0
    outk = temporal_errors(frames, refs, exposure=k)
    ep, em = _reinhard(r + d, k) - _reinhard(r, k), _reinhard(r - d, k) - _reinhard(r, k)
    assert outk["E_prime"] == pytest.approx(abs(ep - em), rel=1e-6)


def test_temporal_constant_bias_has_no_flicker():
    r, d, T = 0.5, 0.2, 6
    refs = np.stack([_const(r)] * T)
    frames = refs + d
    out = temporal_errors(frames, refs)
    assert out["E"] == pytest.approx(_reinhard(r + d) - _reinhard(r), rel=1e-6)
    assert out["E_prime"] == pytest.approx(0.0, abs=1e-12)


def test_temporal_tracks_the_chosen_pixels_row_col():
    T = 4
    refs = np.stack([_const(0.5, 6, 9)] * T)
    frames = refs.copy()
    frames[:, 2, 5] = 1.5                                  # only pixel (row 2, col 5) is wrong
    hit = temporal_errors(frames, refs, pixels=np.array([[2, 5]]))
    miss = temporal_errors(frames, refs, pixels=np.array([[5, 2]]))
    assert hit["E"] == pytest.approx(_reinhard(1.5) - _reinhard(0.5))
    assert miss["E"] == 0.0
    with pytest.raises(DyngiError, match="out of range"):
        temporal_errors(frames, refs, pixels=np.array([[6, 0]]))


def test_temporal_streaming_single_frame_and_errors():
    rng = np.random.default_rng(0)
    refs = rng.random((5, 6, 7, 3))
    frames = refs + rng.normal(0, 0.05, refs.shape).clip(-0.5, 0.5)
    frames = np.abs(frames)
    tr = TemporalTracker(pixels=pick_pixels(6, 7, 8, seed=1))
    for f, r in zip(frames, refs):
        tr.add(f, r)
    assert tr.result()["E_prime"] == pytest.approx(
        temporal_errors(frames, refs, pixels=pick_pixels(6, 7, 8, seed=1))["E_prime"])
    one = temporal_errors(frames[:1], refs[:1])
    assert math.isnan(one["E_prime"]) and one["E"] > 0
    with pytest.raises(DyngiError, match="frames but"):
        temporal_errors(frames[:3], refs)
    with pytest.raises(DyngiError, match="exposure"):
        temporal_errors(frames, refs, exposure="bright")


def test_auto_exposure_is_reinhard_key_over_log_average():
    refs = np.stack([_const(0.5)] * 3)
    assert auto_exposure(refs) == pytest.approx(0.18 / (0.5 + 1e-4), rel=1e-9)
    out = temporal_errors(refs * 1.2, refs, exposure="auto")
    assert out["exposure"] == pytest.approx(0.18 / (0.5 + 1e-4), rel=1e-9)


def test_pick_pixels_deterministic_distinct_in_range():
    a, b = pick_pixels(24, 32, 8, seed=3), pick_pixels(24, 32, 8, seed=3)
    assert np.array_equal(a, b) and a.shape == (8, 2)
    assert len({tuple(p) for p in a}) == 8
    assert a[:, 0].max() < 24 and a[:, 1].max() < 32 and a.min() >= 0
    assert not np.array_equal(a, pick_pixels(24, 32, 8, seed=4))
    with pytest.raises(DyngiError):
        pick_pixels(2, 2, 5)


# -- time to equal error --------------------------------------------------------------------

def test_time_to_error_interpolates_first_crossing():
    t = [0.0, 1.0, 2.0, 3.0]
    e = [1.0, 0.5, 0.25, 0.125]
    assert time_to_error(t, e, 0.375) == pytest.approx(1.5)
    assert time_to_error(t, e, 0.5) == pytest.approx(1.0)
    assert time_to_error(t, e, 2.0) == 0.0
    assert time_to_error(t, e, 0.1) == math.inf
    # noisy curve: the first crossing counts
    assert time_to_error([0, 1, 2, 3], [1.0, 0.2, 0.6, 0.1], 0.3) == pytest.approx(0.875)
    # 1/t convergence sampled every 10 ms: error 1/(k+1) after k+1 frames reaches 0.04 at frame 25
    ts = np.arange(1, 101) * 0.010
    es = 1.0 / np.arange(1, 101)
    assert time_to_error(ts, es, 0.04) == pytest.approx(0.25)


def test_time_to_error_bad_input():
    with pytest.raises(DyngiError, match="equal length"):
        time_to_error([0, 1], [1.0], 0.5)
    with pytest.raises(DyngiError, match="non-decreasing"):
        time_to_error([1, 0], [1.0, 0.5], 0.5)
    with pytest.raises(DyngiError, match="NaN"):
        time_to_error([0, 1], [np.nan, 0.5], 0.5)
