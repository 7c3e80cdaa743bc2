"""The verdict machinery (issue 40, dyngi.experiments.claims): the word is computed from per-seed intervals,
rows come from the marks on a technique's Param table, and the harness counts every ray (dyngi.rays).

Fake techniques run through the real frame loop (``run_sequence``) on a stub scene; their images are the
truth plus Gaussian noise of a chosen scale, and they trace real rays through ``dyngi.rays`` against a
one-sphere Mitsuba scene, so the counted rays are the harness's, not the technique's report.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dyngi.experiments import claims as C
from dyngi.registry import Param
from dyngi.techniques import base as T


class _StubScene:
    def __init__(self):
        from dyngi.backend import mi
        self.mi_scene = mi.load_dict({"type": "scene", "s": {"type": "sphere"}})

    def at(self, t):
        pass

    def frame_time(self, i):
        return i / 30.0

    def signature(self, t):
        return t

    def camera(self, t):
        return None


class _Fake(T.Technique):
    """Truth 1.0 plus noise of scale ``noise`` (times ``gain`` where ``trick``, a setting of ours whose
    paper value is off); ``warmup`` rays at frame 0, 64 rays per frame, all traced through dyngi.rays;
    ``hide_warmup`` leaves the warm-up out of its own ``total_rays``."""
    name = "fake-claim"
    PARAMS = {"noise": Param(1.0, "noise scale"),
              "gain": Param(1.0, "noise factor of the trick"),
              "trick": Param(True, "ours: multiplies the noise by gain (the paper has no trick)", ours=True,
                             paper=False),
              "knob": Param(1, "ours: a setting whose value the paper does not give", ours=True),
              "warmup": Param(0, "rays traced at frame 0"),
              "hide_warmup": Param(False, "report the warm-up rays as 0")}

    def step(self, frame):
        from dyngi import rays
        from dyngi.backend import dr, mi
        p = self.params
        n = 64 + (p["warmup"] if frame.index == 0 else 0)
        o = mi.Point3f(dr.zeros(mi.Float, n) - 3.0, dr.zeros(mi.Float, n), dr.zeros(mi.Float, n))
        rays.intersect(self.scene.mi_scene, mi.Ray3f(o, mi.Vector3f(1, 0, 0)), active=dr.full(mi.Bool, True, n))
        rng = np.random.default_rng([frame.seed, frame.index, int(p["noise"] * 1000), int(p["gain"] * 1000),
                                     int(p["trick"])])
        sigma = p["noise"] * (p["gain"] if p["trick"] else 1.0)
        img = (1.0 + sigma * rng.standard_normal((8, 8, 3))).astype(np.float32)
        reported = 64 + (0 if p["hide_warmup"] else (p["warmup"] if frame.index == 0 else 0))
        return T.FrameResult(img, None, {"total_rays": reported})


@pytest.fixture
def fake(monkeypatch, backend):
    T.technique_names()
    monkeypatch.setitem(T.REGISTRY, "fake-claim", _Fake)
    return _StubScene()


def _measure(scene):
    from dyngi.experiments.runner import run_sequence

    def measure(row, seed, base):
        spec = T.parse_spec(row.spec)
        tech = T.create_technique(spec, scene)
        r = run_sequence(scene, tech, 3, (8, 8), seed=seed)
        mse = float(np.mean([np.mean((im - 1.0) ** 2) for im in r.images]))
        return C.Measurement(mse, [st["counted_rays"] for st in r.stats], C.resolved_params(row.spec))
    return measure


def _claim(technique, baseline="fake-claim:trick=false", cost="equal-frames", seeds=(0, 1, 2), ratio=None):
    return C.Claim("fake.claim", "a paper", "lower error than the baseline", "Fig. 0", technique, baseline,
                   "MSE of 3 frames vs the truth", cost, C.Criterion("below", 1.0), tuple(seeds),
                   {"frames": "3"}, {"frames": "3"}, declared_ratio=ratio)


def test_rows_come_from_the_marks_on_the_param_table(fake):
    rows = C.claim_rows(_claim("fake-claim:gain=0.5"))
    assert [r.role for r in rows] == ["default", "paper-literal", "baseline"]
    assert "trick=false" in rows[1].spec and rows[1].param == "trick"
    assert [r.role for r in C.claim_rows(_claim("fake-claim:gain=0.5"), quick=True)] == ["default", "baseline"]
    # a spec already at the paper's value: the default row is the paper-literal one
    assert [r.role for r in C.claim_rows(_claim("fake-claim:trick=false"))] == ["default", "baseline"]


def test_a_technique_equal_to_its_baseline_is_undecided_at_the_nominal_rate(fake):
    """Equal in distribution: the 90 % interval straddles 1 on ~90 % of seed triples (a t interval's
    coverage); 'reproduced' or 'not reproduced' on more than 25 % of 40 triples fails (binomial tail
    probability < 1e-3 at the nominal 10 %)."""
    measure = _measure(fake)
    words = [C.run_claim(_claim("fake-claim:trick=false", seeds=(3 * k, 3 * k + 1, 3 * k + 2)), measure).verdict.word
             for k in range(40)]
    decided = sum(w != "undecided" for w in words)
    assert decided <= 10, words
    assert set(words) <= {"undecided", "reproduced", "not reproduced"}


def test_a_worse_technique_is_not_reproduced(fake):
    r = C.run_claim(_claim("fake-claim:noise=2.0:trick=false"), _measure(fake))
    assert r.verdict.word == "not reproduced", r.verdict
    assert r.verdict.rows["default"].interval[0] > 1.0


def test_a_gain_that_needs_a_marked_setting_is_reproduced_only_with_ours(fake):
    r = C.run_claim(_claim("fake-claim:gain=0.5"), _measure(fake))
    assert r.verdict.word == "reproduced only with ours", r.verdict
    assert any("trick" in c for c in r.verdict.conditions), r.verdict.conditions
    assert any("knob" in c for c in r.verdict.conditions), r.verdict.conditions   # ours, no paper value: said
    js = r.as_json()
    assert js["rows"][0]["per_seed"][0]["params"]["knob"] == 1            # defaults recorded per row


def test_a_gain_without_ours_is_reproduced(fake):
    r = C.run_claim(_claim("fake-claim:noise=0.5:trick=false"), _measure(fake))
    assert r.verdict.word == "reproduced", r.verdict


def test_a_row_that_hides_its_warmup_rays_fails_the_equal_rays_check(fake):
    claim = _claim("fake-claim:trick=false:warmup=512:hide_warmup=true", cost="equal-rays")
    with pytest.raises(C.ClaimCostError, match="every frame from frame 0"):
        C.run_claim(claim, _measure(fake))
    # the same spend declared honestly is over budget too (the harness counts, not the report); at the
    # baseline's warm-up it passes
    ok = C.run_claim(_claim("fake-claim:trick=false:warmup=512", "fake-claim:trick=false:warmup=512",
                            cost="equal-rays"), _measure(fake))
    assert ok.cost["default"][0]["ratio"] == pytest.approx(1.0)


def test_quick_runs_default_and_baseline_only_and_says_so(fake):
    r = C.run_claim(_claim("fake-claim:gain=0.5"), _measure(fake), quick=True)
    assert r.verdict.word == C.QUICK and [row.role for row in r.rows] == ["default", "baseline"]


def test_undecidable_scale_and_equivalence():
    crit = C.Criterion("equivalent", 1.15)
    assert crit.judge([1.01, 0.99, 1.02]).meets
    assert crit.judge([1.5, 1.6, 1.55]).fails
    assert not crit.judge([1.0, 1.3, 0.8]).meets and not crit.judge([1.0, 1.3, 0.8]).fails
    assert not C.Criterion("below", 1.0).judge([0.5]).meets          # one seed decides nothing
    with pytest.raises(ValueError, match="at least 3"):
        C.Claim("k", "p", "q", "w", "path", "path", "m", "equal-frames", crit, (0, 1), {}, {})


def test_param_marks_are_checked():
    with pytest.raises(ValueError):
        Param(1, "x", paper=2)                       # a paper value is only for a setting of ours
    with pytest.raises(ValueError):
        Param(1, ours=True)                          # ours needs its reason


def test_a_scale_below_the_claims_need_is_undecided_whatever_the_intervals(fake):
    claim = _claim("fake-claim:noise=0.5:trick=false")
    small = dataclasses.replace(claim, needs={"frames": 30}, scale_ours={"frames": 3})
    r = C.run_claim(small, _measure(fake))
    assert r.verdict.word == "undecided" and r.verdict.rows["default"].meets
    assert "frames 3 < 30" in r.verdict.conditions[0]
    assert C.run_claim(small.at_scale(frames=30), _measure(fake)).verdict.word == "reproduced"


def test_settings_of_ours_shared_with_the_baseline_stay_equal_in_every_row(backend):
    """adgi vs qddgi share the probe substrate's marked settings (hit lobes, the two-sided rule): no row
    changes them for the technique alone, and the verdict names them."""
    claim = C.Claim("k", "p", "q", "w", "adgi", "qddgi", "m", "equal-frames", C.Criterion("below", 1.0), (0, 1, 2),
                    {}, {})
    shared = C.shared_marks(claim)
    assert {"hit_lobes", "two_sided"} <= set(shared), shared
    rows = C.claim_rows(claim)
    assert not any(f"{k}=" in r.spec for r in rows for k in shared), [r.spec for r in rows]
    assert any(r.role == "paper-literal" for r in rows)            # adgi's own marks still make rows
    v = C.decide(claim, {r.label: [0.5, 0.6, 0.55] for r in rows if r.role != "baseline"}, rows=rows)
    assert v.word == "reproduced" and any("shared with the baseline" in c for c in v.conditions), v


def test_a_quick_run_records_an_overspend_and_a_declared_ratio_counts_shared_rays_once(fake):
    """Under a declared ratio the rays both rows spend alike (the baseline's ``shared_rays``) count once;
    a quick run records a row over its budget in the conditions instead of failing."""
    claim = _claim("fake-claim:trick=false:warmup=512", "fake-claim:trick=false:warmup=512", cost="declared",
                   ratio=0.5)
    base = _measure(fake)

    def shared(row, seed, b):
        m = base(row, seed, b)
        m.extra["shared_rays"] = 512
        return m
    r = C.run_claim(claim, shared, quick=True)
    assert any("over its ray budget" in c for c in r.verdict.conditions), r.verdict.conditions   # 704 > 608
    with pytest.raises(C.ClaimCostError):
        C.run_claim(claim, shared)
    ok = dataclasses.replace(claim, declared_ratio=1.0)
    assert C.run_claim(ok, shared).cost["default"][0]["budget"] == pytest.approx(64 * 3 + 512)
