"""Algorithm 1, line 18 of SMC-IR: the rendering radiosity is re-estimated independently of the estimate
the selection (lines 7-16) saw, so the winner's curse of selecting on noisy estimates does not bias it."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.vpl.radiosity import stream_seeds
from dyngi.color import luminance


def test_stream_seeds_are_fixed_distinct_and_62_bit():
    s = np.arange(1000, dtype=np.uint64) * np.uint64(7919)
    a, b = stream_seeds(s, 1), stream_seeds(s, 1)
    assert np.array_equal(a, b) and np.array_equal(stream_seeds(s, 0), s)
    assert len(np.unique(a)) == len(s) and not np.any(a == s) and int(a.max()) < (1 << 62)
    assert not np.array_equal(stream_seeds(s, 2), a)


def test_streams_give_independent_radiosity_estimates(backend):
    """Same point, 512 VPL seeds: stream 0 and stream 1 estimates (4 paths each) have the same mean
    (z-test) and no correlation (|r| < 4 / sqrt(n)); the same stream twice is identical (r = 1)."""
    from dyngi.vpl.radiosity import estimate_radiosity

    sc = load_scene("cornell-static")
    sc.at(0.0)
    n = 512
    pos = np.tile(np.array([[0.3, 1.2, -1.0]], np.float32), (n, 1))     # a point on the back wall
    nrm = np.tile(np.array([[0.0, 0.0, 1.0]], np.float32), (n, 1))
    seeds = np.random.default_rng(5).integers(0, 1 << 62, n, dtype=np.uint64)
    a, _ = estimate_radiosity(sc.mi_scene, pos, nrm, seeds, 4, 4)
    b, _ = estimate_radiosity(sc.mi_scene, pos, nrm, stream_seeds(seeds, 1), 4, 4)
    la, lb = luminance(a), luminance(b)
    assert la.std() > 0.05 * la.mean()                 # noisy enough for the test to mean something
    r = np.corrcoef(la, lb)[0, 1]
    assert abs(r) < 4.0 / np.sqrt(n), r
    z = (la.mean() - lb.mean()) / np.sqrt((la.var() + lb.var()) / n)
    assert abs(z) < 4.0, z
    a2, _ = estimate_radiosity(sc.mi_scene, pos, nrm, seeds, 4, 4)
    assert np.array_equal(a, a2)


def _fake_radiosity(pos, nrm, seeds):
    """A noisy unbiased estimator of a constant radiosity 1: 2u, u uniform from the seed (mean 1, var 1/3)."""
    u = (stream_seeds(seeds, 7) >> np.uint64(9)).astype(np.float64) / float(1 << 53)
    return np.repeat((2.0 * u)[:, None], 3, axis=1).astype(np.float32), 0


def _fake_radiosity_device(pos, nrm, seeds, active):
    """:func:`_fake_radiosity` on the device (``impl='device'``), 0 where inactive."""
    from dyngi.backend import dr, mi
    from dyngi.vpl.smc_device import stream_seeds_device

    u = mi.Float(mi.Float64(stream_seeds_device(seeds, 7) >> 9) / float(1 << 53))
    return dr.select(active, mi.Color3f(2.0 * u), 0.0), 0


def test_stream_seeds_device_match_the_host_ones(backend):
    from dyngi.backend import mi
    from dyngi.vpl.smc_device import stream_seeds_device

    s = np.random.default_rng(3).integers(0, 1 << 62, 257, dtype=np.uint64)
    for k in (0, 1, 7):
        assert np.array_equal(np.asarray(stream_seeds_device(mi.UInt64(s), k), np.uint64), stream_seeds(s, k))


@pytest.mark.parametrize("mode, impl", [("independent", "device"),
                                        pytest.param("same-seed", "device", marks=pytest.mark.slow),
                                        pytest.param("independent", "host", marks=pytest.mark.slow)])
def test_selection_on_noisy_estimates_does_not_bias_the_rendered_radiosity(backend, mode, impl):
    """Synthetic winner's curse: every VPL's true radiosity is 1, its estimate 2u (fixed per seed).
    Replacement keeps the highest and drops the lowest estimates, so the survivors' selection estimates
    average well above 1; the independent stream-1 re-estimate of line 18 averages 1 (z-test), while
    re-using the selection's seed (``reestimate=same-seed``) keeps the bias."""
    sc = load_scene("cornell-static")
    n = 256
    tech = create_technique("smcir", sc, {"vpls": n, "warmup": 30, "reestimate": mode, "candidate_rate": 8,
                                          "impl": impl})
    tech._radiosity = _fake_radiosity
    tech._radiosity_device = _fake_radiosity_device
    sc.at(0.0)
    tech.update_vpls(Frame(0, 0.0, sc.camera(0.0), (32, 24), seed=1), __import__(
        "dyngi.techniques.base", fromlist=["StageTimer"]).StageTimer())
    st = tech.store
    used = st.used
    assert st.count == n
    sigma = np.sqrt(1.0 / 3.0 / n)
    sel = float(st.sel_radiosity[used, 0].mean())
    ren = float(st.radiosity[used, 0].mean())
    assert sel > 1.0 + 5.0 * sigma, sel                 # the selection really is biased
    if mode == "independent":
        assert abs(ren - 1.0) < 4.0 * sigma, ren
    else:
        assert ren == pytest.approx(sel) and ren > 1.0 + 5.0 * sigma
