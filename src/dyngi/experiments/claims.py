"""Claims decided by code (issue 40): one declared protocol per paper claim, its rows built from the marks on
the technique's :class:`~dyngi.registry.Param` table, every ray of every frame counted, and one verdict word
computed from per-seed values and their intervals. Nobody writes a verdict by hand.

A :class:`Claim` is declared once, beside its reproduction in :mod:`dyngi.experiments.reproductions`: the
paper's words (quoted, with the table or figure), the technique and baseline specs, the metric, the cost
rule, the :class:`Criterion`, the seeds (at least 3) and the paper's scale beside ours.

**Rows** (:func:`claim_rows`): the *default* row (the claim's technique spec), the *paper-literal* row (every
setting marked ``ours=True`` that has a paper value set to it) and one *ablation* row per such setting (only
that one set to its paper value); the baseline is its own row. A marked setting without a paper value gets
no row; the verdict's conditions list it.

**Values**: a reproduction measures each row and seed (:class:`Measurement`: the metric, the rays of every
frame from frame 0, the resolved parameters); the claim compares the per-seed ratio row / baseline (paired
by seed). **Cost** (:func:`check_cost`): under ``equal-rays`` a row's rays over all frames, warm-up included,
may exceed the baseline's by at most :data:`MAX_OVERSPEND`; more fails the run (:class:`ClaimCostError`).

**Verdict** (:func:`decide`), one of :data:`VERDICTS`:

* ``reproduced``: the paper-literal row meets the criterion (its interval lies on the claim's side);
* ``reproduced only with ours``: the paper-literal row does not, the default row does; the ablation rows
  that do not meet it name the settings that carry the gain;
* ``not reproduced``: the default and the paper-literal rows fail, their intervals excluding the criterion;
* ``undecided``: an interval straddles the criterion, fewer than 2 seeds, or the declared scale cannot
  decide the claim (:attr:`Claim.undecidable` says why); ``--quick`` runs the default and baseline rows
  only and says ``undecided (quick)``.

Intervals (our choice, stated here and in every output): a Student-t interval of the mean log ratio over
seeds at :data:`CONFIDENCE` (two-sided 90 %: each one-sided test and each of the two one-sided tests of an
equivalence claim at the 5 % level). A claim of similarity is an equivalence test within a stated margin
(``Criterion('equivalent', 1.15)``: the ratio within [1/1.15, 1.15]).
"""
from __future__ import annotations

import dataclasses
import math
import os
import subprocess
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import DyngiError
from ..registry import NO_PAPER_VALUE
from ..techniques.base import get_technique, parse_spec, resolve_params
from .compare import execute, prepare
from .runner import frame_rays

VERDICTS = ("reproduced", "reproduced only with ours", "not reproduced", "undecided")
"""The verdict words (:func:`decide`)."""
QUICK = "undecided (quick)"
"""The verdict of a ``--quick`` run: the default and baseline rows only, never a decision."""
CONFIDENCE = 0.90
"""Two-sided confidence of the per-row intervals (ours: 5 % per one-sided test)."""
MAX_OVERSPEND = 0.05
"""Largest spend over the baseline's rays (fraction, all frames from frame 0) of a row under equal rays."""
MIN_SEEDS = 3
"""A claim declares at least this many seeds (issue 40)."""
COST_RULES = ("equal-rays", "equal-time", "equal-frames", "declared")
"""How a claim's rows are made comparable; ``declared``: a fixed ratio of rays the paper states (the claim's
``cost_note`` says which), checked like equal rays against that ratio."""


class ClaimCostError(DyngiError):
    """A row spent more than its budget allows (:func:`check_cost`): the run fails, no verdict is written."""


@dataclass(frozen=True)
class Criterion:
    """What the paper claims of the ratio row / baseline of the metric, per seed.

    ``kind``: ``'below'`` (ratio < ``threshold``: e.g. error or time lower by a factor), ``'above'``
    (ratio > ``threshold``) or ``'equivalent'`` (ratio within [1/``threshold``, ``threshold``], two one-sided
    tests).
    """
    kind: str
    threshold: float

    def __post_init__(self):
        if self.kind not in ("below", "above", "equivalent"):
            raise ValueError(f"criterion kind '{self.kind}' is invalid; valid: below, above, equivalent")
        if not (self.threshold > 0 and math.isfinite(self.threshold)):
            raise ValueError("criterion threshold must be a positive finite ratio")
        if self.kind == "equivalent" and self.threshold <= 1.0:
            raise ValueError("an equivalence margin must be > 1 (e.g. 1.15)")

    def text(self) -> str:
        t = f"1/{1 / self.threshold:.3g}" if self.threshold < 1 else f"{self.threshold:.3g}"
        if self.kind == "below":
            return f"ratio < {t}"
        if self.kind == "above":
            return f"ratio > {t}"
        return f"ratio within [{1 / self.threshold:.3g}, {self.threshold:g}] (equivalence)"

    def judge(self, ratios) -> "Judgement":
        """Meets / fails / straddles from the per-seed ratios (their log mean's t interval)."""
        r = np.asarray([float(x) for x in ratios], np.float64)
        n = len(r)
        if n == 0 or not np.all(np.isfinite(r)) or np.any(r <= 0):
            return Judgement(n, float("nan"), (float("nan"), float("nan")), False, False,
                             "no finite positive ratio per seed" if n else "no seed measured")
        x = np.log(r)
        mean = float(np.mean(x))
        if n < 2:
            return Judgement(n, math.exp(mean), (float("nan"), float("nan")), False, False, "fewer than 2 seeds")
        from scipy import stats
        half = float(stats.t.ppf(0.5 + CONFIDENCE / 2, n - 1) * np.std(x, ddof=1) / math.sqrt(n))
        lo, hi = mean - half, mean + half
        t = math.log(self.threshold)
        if self.kind == "below":
            meets, fails = hi < t, lo > t
        elif self.kind == "above":
            meets, fails = lo > t, hi < t
        else:
            meets, fails = (lo > -t and hi < t), (lo > t or hi < -t)
        why = "" if meets or fails else "the interval straddles the criterion"
        return Judgement(n, math.exp(mean), (math.exp(lo), math.exp(hi)), bool(meets), bool(fails), why)


@dataclass(frozen=True)
class Judgement:
    """One row against the criterion: seeds, geometric-mean ratio, its interval, meets / fails (both False:
    the interval straddles the criterion, or too few seeds, ``why``)."""
    n: int
    ratio: float
    interval: tuple
    meets: bool
    fails: bool
    why: str = ""

    def word(self) -> str:
        return "meets" if self.meets else "fails" if self.fails else "straddles"

    def as_json(self) -> dict:
        return {"seeds": self.n, "ratio": self.ratio, "interval": list(self.interval), "judged": self.word(),
                "why": self.why}


@dataclass(frozen=True)
class Claim:
    """One paper claim, declared once beside its reproduction (module docstring).

    ``technique`` / ``baseline``: spec texts (``name:key=value``); ``metric``: what is measured per seed and
    row (its text says how); ``cost``: one of :data:`COST_RULES` (``cost_note`` says how the paper spends);
    ``scale_paper`` / ``scale_ours``: the same keys (probes, rays per pixel, resolution, frames, ...) with
    the paper's and our values; ``undecidable``: non-empty where the declared scale cannot decide the claim
    (why), which makes the verdict ``undecided`` whatever the intervals say.
    """
    key: str
    paper: str
    quote: str
    where: str
    technique: str
    baseline: str
    metric: str
    cost: str
    criterion: Criterion
    seeds: tuple
    scale_paper: dict
    scale_ours: dict
    cost_note: str = ""
    undecidable: str = ""
    declared_ratio: float | None = None
    """Under ``cost='declared'``: the rays of the technique over the baseline's that the paper states."""
    needs: dict = field(default_factory=dict)
    """The least scale that can decide the claim (``{key of scale_ours: number}``, e.g. frames that hold a
    whole rotation of the uniform rays); a smaller ``scale_ours`` value makes the verdict ``undecided``."""

    def scale_gaps(self) -> list:
        """Why the declared scale cannot decide the claim (empty: it can)."""
        out = [self.undecidable] if self.undecidable else []
        for k, need in self.needs.items():
            have = self.scale_ours.get(k)
            if not isinstance(have, (int, float)) or have < need:
                out.append(f"{k} {have} < {need} needed")
        return out

    def at_scale(self, **scale) -> "Claim":
        """This claim at another scale of ours (the demo's, a quick run's): ``scale_ours`` updated."""
        return dataclasses.replace(self, scale_ours={**self.scale_ours, **scale})

    def __post_init__(self):
        if len(tuple(self.seeds)) < MIN_SEEDS:
            raise ValueError(f"claim '{self.key}' declares {len(tuple(self.seeds))} seeds; at least {MIN_SEEDS}")
        if self.cost not in COST_RULES:
            raise ValueError(f"claim '{self.key}': cost '{self.cost}' is invalid; valid: {', '.join(COST_RULES)}")
        if self.cost == "declared" and not self.declared_ratio:
            raise ValueError(f"claim '{self.key}': cost 'declared' needs declared_ratio")
        parse_spec(self.technique)
        parse_spec(self.baseline)


@dataclass(frozen=True)
class Row:
    """One row of a claim: ``label``, ``role`` (``default``, ``paper-literal``, ``ablation``, ``baseline``),
    the spec text it runs and, for an ablation, the marked setting it sets to its paper value."""
    label: str
    role: str
    spec: str
    param: str = ""


def _spec_text(name: str, params: dict) -> str:
    return ":".join([name] + [f"{k}={_fmt(v)}" for k, v in params.items()])


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def marked_params(spec_text: str) -> dict:
    """The settings of the spec's technique marked ours: ``name -> Param``."""
    cls = get_technique(parse_spec(spec_text).name)
    return {k: p for k, p in cls.PARAMS.items() if p.ours}


def shared_marks(claim: "Claim") -> list:
    """Settings of ours that the technique and the baseline both have (the probe techniques' shared
    substrate: hit lobes, the two-sided rule, relocation). They stay at the same value in every row on both
    sides (a paper-literal row that changed them for the technique only would compare unlike baselines);
    the verdict's conditions name them."""
    bname = parse_spec(claim.baseline).name
    if bname == parse_spec(claim.technique).name:      # a technique against its own other settings
        return []
    base = get_technique(bname).PARAMS
    return [k for k, p in marked_params(claim.technique).items() if k in base and base[k].ours]


def claim_rows(claim: Claim, quick: bool = False) -> list[Row]:
    """The rows of ``claim`` (module docstring): default, paper-literal (when it differs from the default),
    one ablation per marked setting whose paper value differs from the default row's, the baseline.
    ``quick``: the default and baseline rows only."""
    spec = parse_spec(claim.technique)
    cls = get_technique(spec.name)
    resolved = resolve_params(cls, spec.params)
    shared = set(shared_marks(claim))
    rows = [Row("default", "default", claim.technique)]
    if not quick:
        lit = {}
        for k, p in cls.PARAMS.items():
            if k not in shared and p.has_paper_value and p.parse(k, p.paper) != resolved[k]:
                lit[k] = p.parse(k, p.paper)
        if lit:
            rows.append(Row("paper-literal", "paper-literal", _spec_text(spec.name, {**spec.params, **lit}),
                            ",".join(lit)))
            if len(lit) > 1:
                for k, v in lit.items():
                    rows.append(Row(f"ablation: {k}={_fmt(v)}", "ablation",
                                    _spec_text(spec.name, {**spec.params, k: v}), k))
    rows.append(Row("baseline", "baseline", claim.baseline))
    return rows


@dataclass
class Measurement:
    """One row and seed: the metric's ``value``, the rays of every frame from frame 0 (``rays``), the
    resolved parameters (``params``) and anything else the reproduction reports (``extra``)."""
    value: float
    rays: list = field(default_factory=list)
    params: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)


def check_cost(claim: Claim, row: Row, m: Measurement, base: Measurement, quick: bool = False) -> dict:
    """Every ray of every frame from frame 0 of ``row`` against the baseline's (one seed). Returns the
    accounting; raises :class:`ClaimCostError` when an equal-rays (or declared-ratio) row spends more than
    :data:`MAX_OVERSPEND` over its budget (``quick``: records it in the accounting, ``over``, instead: a
    quick run decides nothing). Under a declared ratio the rays both spend alike (``extra['shared_rays']``
    of the baseline, e.g. the warm-up both techniques share on frame 0) count once, the ratio applies to
    the rest."""
    spent, budget = float(np.sum(m.rays)), float(np.sum(base.rays))
    out = {"rays": spent, "baseline_rays": budget, "ratio": spent / budget if budget > 0 else float("inf")}
    if claim.cost in ("equal-rays", "declared") and row.role != "baseline":
        shared = float(base.extra.get("shared_rays", 0.0)) if claim.cost == "declared" else 0.0
        target = shared + (budget - shared) * (claim.declared_ratio if claim.cost == "declared" else 1.0)
        out["budget"] = target
        if target <= 0 or spent > target * (1.0 + MAX_OVERSPEND):
            if quick:
                out["over"] = spent / max(target, 1.0)
                return out
            raise ClaimCostError(
                f"claim '{claim.key}', row '{row.label}' ({row.spec}) traced {spent:.0f} rays over "
                f"{len(m.rays)} frames (every frame from frame 0), {spent / max(target, 1):.3f}x its budget of "
                f"{target:.0f} ({claim.cost}); at most {1 + MAX_OVERSPEND:.2f}x is allowed")
    return out


@dataclass
class Verdict:
    """The claim's computed verdict: ``word`` (:data:`VERDICTS` or :data:`QUICK`), the ``conditions`` that
    qualify it (why undecided, which settings carry a gain), and the per-row judgements."""
    word: str
    conditions: list
    rows: dict


def decide(claim: Claim, ratios: dict, quick: bool = False, rows: list | None = None) -> Verdict:
    """The verdict word from per-seed ratios ``{row label: [ratio per seed]}`` (module docstring); ``rows``
    (default :func:`claim_rows`) name the settings each row sets. A row of the full set that was not run
    (a paper-literal or ablation row), or fewer than :data:`MIN_SEEDS` seeds, makes the verdict undecided."""
    rows = claim_rows(claim, quick) if rows is None else rows
    judged = {label: claim.criterion.judge(r) for label, r in ratios.items()}
    conds = []
    gaps = claim.scale_gaps()
    n = min((j.n for j in judged.values()), default=0)
    if n < MIN_SEEDS:
        gaps.append(f"seeds {n} < {MIN_SEEDS}")
    missing = [r.label for r in claim_rows(claim) if r.role in ("paper-literal", "ablation") and r.label not in judged]
    if quick:
        return Verdict(QUICK, ["--quick runs the default and baseline rows only"]
                       + (["scale cannot decide: " + "; ".join(gaps)] if gaps else []), judged)
    if missing:
        gaps.append("rows not run: " + ", ".join(missing))
    default = judged["default"]
    literal = judged.get("paper-literal", default)
    shared = shared_marks(claim)
    no_value = [k for k, p in marked_params(claim.technique).items() if not p.has_paper_value and k not in shared]
    if no_value:
        conds.append("settings of ours without a paper value (at our default in every row): " + ", ".join(no_value))
    if shared:
        conds.append("settings of ours shared with the baseline (the same in both, every row): " + ", ".join(shared))
    if "paper-literal" not in judged and not missing:
        conds.append("the default row is the paper-literal row (no marked setting with a paper value differs)")
    if gaps:
        return Verdict("undecided", ["scale cannot decide: " + "; ".join(gaps)] + conds, judged)
    if literal.meets:
        return Verdict("reproduced", conds, judged)
    if default.meets:
        ablations = [r for r in rows if r.role == "ablation" and r.label in judged]
        if ablations:
            names = [r.param for r in ablations if not judged[r.label].meets]
            conds.append("carried by ours: " + (", ".join(names) if names else "no single setting (only together)")
                         + " at the paper's value loses the criterion")
        else:
            lit_row = next((r for r in rows if r.role == "paper-literal"), None)
            conds.append("carried by ours: " + (lit_row.param if lit_row else "?")
                         + " at the paper's value loses the criterion")
        return Verdict("reproduced only with ours", conds, judged)
    if default.fails and literal.fails:
        return Verdict("not reproduced", conds, judged)
    why = [f"{lb}: {j.why}" for lb, j in (("default", default), ("paper-literal", literal)) if not j.meets
           and not j.fails]
    return Verdict("undecided", why + conds, judged)


def current_commit() -> str:
    """The commit of the code that ran (``git rev-parse HEAD`` beside this package), or 'unknown'."""
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=os.path.dirname(__file__), capture_output=True,
                              text=True, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@dataclass
class ClaimResult:
    """A claim run: its rows, per-row per-seed measurements and cost accounting, and the verdict."""
    claim: Claim
    rows: list
    measurements: dict
    cost: dict
    verdict: Verdict

    def as_json(self) -> dict:
        c = self.claim
        return {"claim": c.key, "paper": c.paper, "quote": c.quote, "where": c.where, "technique": c.technique,
                "baseline": c.baseline, "metric": c.metric, "cost_rule": c.cost, "cost_note": c.cost_note,
                "criterion": c.criterion.text(), "confidence": CONFIDENCE, "seeds": list(c.seeds),
                "scale": {"paper": c.scale_paper, "ours": c.scale_ours, "needs": c.needs},
                "scale_gaps": c.scale_gaps(),
                "verdict": self.verdict.word, "conditions": self.verdict.conditions,
                "rows": [{"label": r.label, "role": r.role, "spec": r.spec, "param": r.param,
                          "judged": (self.verdict.rows[r.label].as_json() if r.label in self.verdict.rows else None),
                          "per_seed": [{"seed": s, "value": m.value, "rays": float(np.sum(m.rays)),
                                        "frames": len(m.rays), "params": m.params, **m.extra}
                                       for s, m in self.measurements[r.label].items()],
                          "cost": self.cost.get(r.label, {})} for r in self.rows]}

    def markdown(self) -> list[str]:
        """Lines of ``summary.md``: the claim, the verdict word and its conditions, one line per row, the
        paper's scale beside ours."""
        c = self.claim
        out = [f"### {c.key}: **{self.verdict.word}**", "",
               f"> {c.quote} ({c.where})", "",
               f"{c.technique} vs {c.baseline}; metric: {c.metric}; cost: {c.cost}"
               + (f" ({c.cost_note})" if c.cost_note else "") + f"; criterion: {c.criterion.text()} "
               f"({int(CONFIDENCE * 100)} % t interval over seeds {list(c.seeds)}).", ""]
        out += [f"* {cond}" for cond in self.verdict.conditions]
        out += ["", "| row | spec | ratio to baseline | interval | judged | seeds |", "|---|---|---|---|---|---|"]
        for r in self.rows:
            j = self.verdict.rows.get(r.label)
            if j is None:
                vals = ", ".join(f"{m.value:.4g}" for m in self.measurements[r.label].values())
                out.append(f"| {r.label} | `{r.spec}` | (baseline: {vals}) | | | |")
                continue
            out.append(f"| {r.label} | `{r.spec}` | {j.ratio:.3g} | [{j.interval[0]:.3g}, {j.interval[1]:.3g}] "
                       f"| {j.word()} | {j.n} |")
        keys = list(dict.fromkeys([*c.scale_paper, *c.scale_ours, *c.needs]))
        out += ["", "| scale | paper | ours | needed to decide |", "|---|---|---|---|"]
        out += [f"| {k} | {c.scale_paper.get(k, '-')} | {c.scale_ours.get(k, '-')} | {c.needs.get(k, '')} |"
                for k in keys]
        return out + [""]


def run_claim(claim: Claim, measure: Callable, quick: bool = False, seeds=None) -> ClaimResult:
    """Measure every row of ``claim`` on every seed and decide.

    ``measure(row, seed, baseline)`` -> :class:`Measurement`: runs ``row.spec`` (``baseline`` is the
    baseline's measurement on that seed, ``None`` for the baseline itself: an equal-rays row takes its
    per-frame budget from ``baseline.rays``). The baseline is measured first on each seed.
    """
    rows = claim_rows(claim, quick)
    seeds = tuple(claim.seeds if seeds is None else seeds)
    base_row = next(r for r in rows if r.role == "baseline")
    meas = {r.label: {} for r in rows}
    cost = {r.label: {} for r in rows}
    for s in seeds:
        base = measure(base_row, int(s), None)
        meas[base_row.label][int(s)] = base
        for r in rows:
            if r.role == "baseline":
                continue
            m = measure(r, int(s), base)
            meas[r.label][int(s)] = m
            cost[r.label][int(s)] = check_cost(claim, r, m, base, quick)
    ratios = {r.label: [meas[r.label][int(s)].value / meas[base_row.label][int(s)].value for s in seeds]
              for r in rows if r.role != "baseline"}
    verdict = decide(claim, ratios, quick, rows)
    over = sorted({f"{lb} {c['over']:.2f}x" for lb, per in cost.items() for c in per.values() if "over" in c})
    if over:
        verdict.conditions.append("over its ray budget (a full run fails on this): " + ", ".join(over))
    return ClaimResult(claim, rows, meas, cost, verdict)


def result_from_values(claim: Claim, values: dict, quick: bool = False) -> ClaimResult:
    """A claim decided from values a reproduction measured with its own protocol: ``values`` is
    ``{row label ('default', 'paper-literal', 'ablation: ...', 'baseline'): {seed: value}}`` (a missing or
    non-finite value: that seed decides nothing). Rows the reproduction did not run stay out, and
    :func:`decide` says so (``rows not run``)."""
    rows = [r for r in claim_rows(claim, quick) if r.label in values]
    base = values["baseline"]
    seeds = sorted(base)

    def ratio(a, b):
        try:
            q = float(a) / float(b)
        except (TypeError, ValueError, ZeroDivisionError):
            return float("nan")
        return q
    meas = {r.label: {int(s): Measurement(float("nan") if v is None else float(v), [], resolved_params(r.spec))
                      for s, v in values[r.label].items()} for r in rows}
    ratios = {r.label: [q for q in (ratio(values[r.label].get(s), base[s]) for s in seeds) if np.isfinite(q)]
              for r in rows if r.role != "baseline"}
    return ClaimResult(claim, rows, meas, {}, decide(claim, ratios, quick, rows))


def rays_per_frame(stats: list) -> list:
    """The rays of every frame from frame 0 as the harness counted them (``counted_rays``, :mod:`dyngi.rays`)."""
    return [frame_rays(st) for st in stats]


def run_on_harness(claims: list, scene_name: str, frames: int, res, ref_spp: int, out_dir: str, metric: Callable,
                   quick: bool = False, quiet: bool = True, budget: str = "equal-frames", ref_depth=None,
                   indirect: bool = False, scene_factory: Callable | None = None, seeds=None,
                   on_seed: Callable | None = None, metrics=("mse", "relmse", "ssim")) -> list:
    """Decide ``claims`` that share one scene and protocol from comparison runs of the shared harness.

    Per seed, one :func:`~dyngi.experiments.compare.prepare` / ``execute`` of every claim's rows (the
    baseline first: under ``equal-rays`` it sets the per-frame budget), the reference cached and shared by
    the seeds; ``metric(claim, rs, label) -> float`` reads a row's value from ``execute``'s result;
    ``on_seed(seed, run, rs)`` (e.g. the first seed's report) is called after each seed; ``metrics``: the
    harness's per-frame metrics. Returns the
    :class:`ClaimResult` list.
    """
    seeds = tuple(claims[0].seeds if seeds is None else seeds)
    specs: list = []
    for c in claims:
        rows = claim_rows(c, quick)
        for r in [x for x in rows if x.role == "baseline"] + [x for x in rows if x.role != "baseline"]:
            if r.spec not in specs:
                specs.append(r.spec)
    by_seed = {}
    for s in seeds:
        scene = scene_factory() if scene_factory is not None else None
        run = prepare(scene_name, specs, out_dir, frames, budget, ref_spp, {}, list(metrics),
                      ref_depth, indirect, scene=scene, tracked=False)
        rs = execute(run, res, seed=int(s), quiet=quiet)
        if on_seed is not None:
            on_seed(int(s), run, rs)
        by_seed[int(s)] = rs
    out = []
    for c in claims:
        def measure(row, seed, base, c=c):
            rs = by_seed[seed]
            return Measurement(float(metric(c, rs, row.spec)), rays_per_frame(rs["results"][row.spec].stats),
                               resolved_params(row.spec))
        out.append(run_claim(c, measure, quick, seeds))
    return out


def verdict_table(results: list) -> list[str]:
    """One markdown table: claim, where, verdict word, conditions (the top of a reproduction's summary)."""
    out = ["| claim | paper | verdict | conditions |", "|---|---|---|---|"]
    for r in results:
        out.append(f"| {r.claim.key} | {r.claim.where} | **{r.verdict.word}** | "
                   + "; ".join(r.verdict.conditions).replace("|", "/") + " |")
    return out


def claims_json(results: list) -> dict:
    """``summary.json``'s claim part: main's commit and every claim with its rows' resolved parameters."""
    return {"commit": current_commit(), "confidence": CONFIDENCE, "claims": [r.as_json() for r in results]}


def resolved_params(spec_text: str) -> dict:
    """Every parameter of a spec's technique, defaults included (``summary.json`` records them per row)."""
    spec = parse_spec(spec_text)
    return {k: (v if isinstance(v, (bool, int, float, str)) or v is None else repr(v))
            for k, v in resolve_params(get_technique(spec.name), spec.params).items()}


__all__ = ["CONFIDENCE", "COST_RULES", "Claim", "ClaimCostError", "ClaimResult", "Criterion", "Judgement",
           "MAX_OVERSPEND", "MIN_SEEDS", "Measurement", "NO_PAPER_VALUE", "QUICK", "Row", "VERDICTS", "Verdict",
           "check_cost", "claim_rows", "claims_json", "decide", "rays_per_frame", "result_from_values", "run_on_harness", "marked_params", "resolved_params", "run_claim",
           "verdict_table"]
