"""SMC-IR Sec. 5.2 measurement: 8 tracked pixels, their per-pixel reference, E_tracked / E_prime_tracked."""
from __future__ import annotations

import numpy as np
import pytest

from dyngi.metrics.temporal import pick_tracked_pixels, temporal_errors

TCAS_BRIGHTNESS_MIN = 0.25
"""tcas carries a single bounce of the reference's three (Hedman et al. Sec. 5.2: "TCAS ... does not support
multi-bounce"), and the quick run's 4 Metropolis iterations from a cold start over 4 frames leave its chains
short of their target: measured 0.32 (maze) and 0.47 (corridor-walk) in the quick run, 0.48-0.63 at 160x90
with 16 iterations (docs/techniques/smcir.md). Every other row: within 25 % of the reference."""


def test_pick_tracked_pixels_one_lit_median_pixel_per_cell():
    rng = np.random.default_rng(0)
    img = rng.random((24, 32, 3)).astype(np.float32)
    img[:12, :8] = 0.0                         # a dark cell: its centre stands in
    pix = pick_tracked_pixels(img)
    assert pix.shape == (8, 2) and len({tuple(p) for p in pix}) == 8
    assert tuple(pix[0]) == (6, 4)
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    for k, (r, c) in enumerate(pix[1:], start=1):
        cy, cx = divmod(k, 4)
        assert cy * 12 <= r < (cy + 1) * 12 and cx * 8 <= c < (cx + 1) * 8
        cell = lum[cy * 12:(cy + 1) * 12, cx * 8:(cx + 1) * 8].ravel()
        assert lum[r, c] == np.sort(cell)[len(cell) // 2]
    assert np.array_equal(pick_tracked_pixels(img), pix)       # deterministic


def test_tracked_reference_agrees_with_the_image_reference(backend):
    """The per-pixel reference (only the tracked pixels' rays) and the path tracer's indirect image agree
    within noise at those pixels (mean over the 8: within 6%, measured ~1-2%)."""
    from dyngi.experiments.references.tracked import tracked_reference
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique

    sc = load_scene("cornell-static")
    res = (32, 24)
    sc.at(0.0)
    img = create_technique("path", sc, {"spp": 2048, "max_depth": 5}).step(
        Frame(0, 0.0, sc.camera(0.0), res, seed=1)).indirect
    pix = pick_tracked_pixels(img)
    vals = tracked_reference(sc, 0.0, res, pix, 8192, 5, indirect=True)
    a, b = vals.mean(), img[pix[:, 0], pix[:, 1]].mean()
    assert vals.shape == (8, 3) and abs(a / b - 1.0) < 0.06, (a, b)
    full = tracked_reference(sc, 0.0, res, pix, 512, 5, indirect=False)
    assert np.all(full.mean(1) >= vals.mean(1) * 0.8)         # the full image holds the indirect part


def test_evaluate_sequence_reports_tracked_errors():
    from dyngi.experiments.evaluate import ReferenceList, evaluate_sequence

    class Seq:
        pass

    rng = np.random.default_rng(2)
    refs = ReferenceList([rng.random((6, 8, 3)).astype(np.float32) for _ in range(3)])
    pix = np.array([[0, 0], [2, 3], [5, 7]])
    vals = rng.random((3, 3, 3)).astype(np.float32)
    refs.tracked = {"pixels": pix, "values": vals, "spp": 64}
    seq = Seq()
    seq.images = [rng.random((6, 8, 3)).astype(np.float32) for _ in range(3)]
    seq.stats = [{"ms": {}, "total_rays": 0}] * 3
    seq.times = [0.0, 0.1, 0.2]
    seq.wall_ms = [1.0] * 3
    seq.steady = lambda: (seq.stats[1:], seq.wall_ms[1:])
    _, s = evaluate_sequence("x", seq, refs, ["mse"])
    want = temporal_errors(np.stack([x[pix[:, 0], pix[:, 1]] for x in seq.images])[:, :, None],
                           vals[:, :, None])
    assert s["E_tracked"] == pytest.approx(want["E"]) and s["E_prime_tracked"] == pytest.approx(want["E_prime"])
    assert s["tracked_pixels"] == pix.tolist() and s["tracked_spp"] == 64
    assert s["E_tracked"] != pytest.approx(s["E"])


@pytest.mark.slow
def test_reproduce_smcir_quick(backend, tmp_path):
    import json

    from dyngi.experiments.reproduce import run_experiment

    out = run_experiment("smcir", str(tmp_path / "r"), quick=True)
    d = json.load(open(f"{out}/paper.json"))
    assert d["experiment"] == "smcir" and len(d["rows"]) >= 6
    for sc, runs in d["figures"].items():
        assert len(runs) == len(d["config"]["seeds"])
        for figs in runs:
            for label, f in figs.items():
                assert np.isfinite(f["E_tracked"]) and np.isfinite(f["E_prime_tracked"]) and not f["failed"], \
                    (sc, label)
                # within 25 % of the reference; tcas carries one bounce of the reference's three (Barak et
                # al.; Hedman et al. Sec. 5.2: "TCAS ... does not support multi-bounce"): its own lower bound
                lo = TCAS_BRIGHTNESS_MIN if label.startswith("tcas") else 0.75
                assert lo < f["brightness"] < 1.25, (sc, label, f["brightness"])
                assert f["tracked_spp"] >= 65536 and f["floor_E_prime_tracked"] < f["E_prime_tracked"], (sc, label)
        assert set(d["ranking"][sc]) >= {"ranks", "ci95", "stable", "lowest"}
    quantities = [r["quantity"] for r in d["rows"]]
    assert "targets (the paper's ranking)" in quantities and any("Table 2" in q for q in quantities)
    # the paper's Table 1 stands beside ours, and the plots sit at the top level of the report
    assert any("0.0075" in r["paper"] for r in d["rows"] if r["quantity"].startswith("maze: |E'|"))
    assert (tmp_path / "r" / "flicker.png").exists() and (tmp_path / "r" / "error.png").exists()
    assert "flicker.png" in open(f"{out}/report.html").read()


@pytest.mark.slow   # CI budget (10-30 s on a cold cache); runs in CI's slow subset
def test_clamped_path_tracing_reference(backend):
    """Sec. 5.4: unclamped, the clamped estimator equals the indirect-only path tracer (same three
    bounces; means within 4%); clamped, it loses energy; exhaustive VPLs approach it (Fig. 8/10)."""
    from dyngi.experiments.references.clamped import clamped_indirect
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    from dyngi.vpl.shading import clamp_value

    sc = load_scene("cornell-static")
    res = (32, 24)
    sc.at(0.0)
    ref = create_technique("path", sc, {"spp": 1024, "max_depth": 5, "rr_depth": 50}).step(
        Frame(0, 0.0, sc.camera(0.0), res, seed=4)).indirect
    free = clamped_indirect(sc, 0.0, res, 1024, 5)
    assert abs(free.mean() / ref.mean() - 1.0) < 0.04, (free.mean(), ref.mean())
    gmax = clamp_value(sc, 0.1)
    clamped = clamped_indirect(sc, 0.0, res, 1024, 5, gmax)
    assert clamped.mean() < 0.97 * free.mean()
    tech = create_technique("smcir", sc, {"vpls": 1024, "warmup": 4, "shading": "exhaustive",
                                          "clamp_distance": 0.1, "density_k": 16})
    ind = tech.step(Frame(0, 0.0, sc.camera(0.0), res, seed=0)).indirect
    e_clamped = np.mean((ind - clamped) ** 2) / np.mean(clamped ** 2)
    e_free = np.mean((ind - free) ** 2) / np.mean(free ** 2)
    assert e_clamped < e_free, (e_clamped, e_free)


def test_tracked_reference_floor_estimates_the_references_own_flicker():
    """Two independent halves of a noisy reference: half their |E|, |E'| against each other equals the |E|,
    |E'| of the full reference (their mean) against the truth, within the sampling error (synthetic:
    Gaussian noise on a smooth truth, 400 frames x 8 pixels)."""
    from dyngi.experiments.evaluate import tracked_reference_floor

    rng = np.random.default_rng(7)
    T, n = 400, 8
    truth = 0.3 + 0.1 * np.sin(np.linspace(0, 6, T))[:, None, None] * np.ones((T, n, 3))
    sd_half = 0.004
    a = truth + rng.normal(0, sd_half, truth.shape)
    b = truth + rng.normal(0, sd_half, truth.shape)
    fl = tracked_reference_floor(a, b, exposure=1.0)
    want = temporal_errors(0.5 * (a + b)[:, :, None, :], truth[:, :, None, :], exposure=1.0)
    assert fl["E"] == pytest.approx(want["E"], rel=0.1) and fl["E_prime"] == pytest.approx(want["E_prime"], rel=0.1)
    # a noiseless pair has no floor
    assert tracked_reference_floor(truth, truth, 1.0)["E_prime"] == 0.0


def test_tracked_temporal_normalises_brightness_and_skips_failed_runs():
    from dyngi.experiments.evaluate import tracked_temporal

    rng = np.random.default_rng(3)
    pix = np.array([[0, 0], [1, 2], [3, 3]])
    imgs = [rng.random((4, 4, 3)) for _ in range(5)]
    vals = np.stack([x[pix[:, 0], pix[:, 1]] for x in imgs])
    assert tracked_temporal(imgs, vals, pix, 1.0)["E_prime"] == 0.0
    twice = [2.0 * x for x in imgs]
    assert tracked_temporal(twice, vals, pix, 1.0)["E_prime"] > 0.0
    assert tracked_temporal(twice, vals, pix, 1.0, scale=0.5)["E_prime"] == pytest.approx(0.0, abs=1e-12)
    imgs[2][1, 2, 0] = np.nan
    assert np.isnan(tracked_temporal(imgs, vals, pix, 1.0)["E"])
